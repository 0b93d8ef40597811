"""A 2D detector's typical errors, as a noise model applied to one instance's clean keypoints and polygon.

Per labelled instance and image (pixels; ``h`` = the instance's image height, the vertical extent of its
polygon, else of its keypoints; :func:`instance_height_px`):

* keypoint noise grows with the person's size: ``uv = uv_0 + n``, ``n ~ N(0, s^2 I2)``,
  ``s = sqrt(sigma_px^2 + (sigma_height_frac * h)^2)``, times ``occluded_sigma_factor`` for joints labelled
  not visible (and times a per-keypoint factor when one is given);
* missed joints: a visible joint is dropped with probability ``miss_prob_visible``, an occluded one with
  ``miss_prob_occluded``;
* left/right swaps: each left/right pair (eyes, shoulders, elbows, wrists, hips, knees, ankles) is swapped
  with probability ``swap_prob`` (the classic detector confusion on people seen from behind or the side);
* gross outliers: with probability ``outlier_prob`` a joint lands uniformly inside the instance's box;
* polygon errors (:func:`corrupt_polygon`): the silhouette polygon is scaled about its centroid by
  ``1 + N(0, polygon_scale_sigma^2)``, shifted by ``N(0, (polygon_shift_frac * h)^2)`` per axis and its
  vertices jittered by ``polygon_vertex_noise_px``.

Both users sit above this module: the simulator's detector files (:mod:`pedx_graph.sim.detections`) and the
evaluation's detector-label datasets (:mod:`pedx_graph.eval.detector_noise`, paper Table V).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pedx_graph.keypoints import PEDX_KEYPOINTS


#: Left/right keypoint pairs a detector can swap.
SWAP_PAIRS: tuple[tuple[str, str], ...] = (("leye", "reye"), ("lsho", "rsho"), ("lelb", "relb"),
                                           ("lwri", "rwri"), ("lhip", "rhip"), ("lknee", "rknee"),
                                           ("lankl", "rankl"))


@dataclass
class DetectorNoiseConfig:
    """How the simulated detector corrupts clean 2D labels (pixels unless stated)."""

    sigma_px: float = 3.0
    """Size-independent part of the keypoint noise (per axis), pixels."""
    sigma_height_frac: float = 0.015
    """Size-dependent part: this fraction of the instance's image height (per axis)."""
    occluded_sigma_factor: float = 2.5
    """Joints labelled not visible get this many times the noise."""
    miss_prob_visible: float = 0.05
    """Probability that a visible joint is not detected."""
    miss_prob_occluded: float = 0.4
    """Probability that an occluded (labelled, not visible) joint is not detected."""
    swap_prob: float = 0.05
    """Probability that a left/right pair is swapped (per pair, per instance and image)."""
    outlier_prob: float = 0.02
    """Probability that a joint is a gross outlier (uniform inside the instance's box)."""
    polygon_scale_sigma: float = 0.06
    """Std. dev. of the relative scale error of the polygon about its centroid."""
    polygon_shift_frac: float = 0.03
    """Std. dev. of the polygon's shift (per axis), fraction of the instance's image height."""
    polygon_vertex_noise_px: float = 3.0
    """Std. dev. of the extra noise on every polygon vertex, pixels."""
    use_truth: bool = True
    """Start from the exact projections of the simulator's true keypoints when ``truth/`` exists."""
    resegment: bool = True
    """Re-cut the LiDAR segments from the full sweeps (``pointclouds/``) with the noisy left polygons."""
    segment_depth_gate_m: float = 1.5
    """Far-side depth gate applied to the re-cut segments (as the simulator's
    ``labels.segment_depth_gate_m``), metres; 0 disables it."""


_IDX = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}


def instance_height_px(keypoints: np.ndarray, polygon: np.ndarray | None) -> float:
    """Vertical image extent of an instance, pixels: of its polygon, else of its labelled keypoints."""
    pts = polygon if polygon is not None and len(polygon) >= 3 else keypoints[np.all(np.isfinite(keypoints), 1)]
    if len(pts) < 2:
        return 0.0
    return float(np.ptp(pts[:, 1]))


def corrupt_keypoints(uv0: np.ndarray, labelled: np.ndarray, visible: np.ndarray, height_px: float,
                      box: tuple[np.ndarray, np.ndarray], config: DetectorNoiseConfig,
                      rng: np.random.Generator, image_size: tuple[int, int],
                      swap_index: tuple[tuple[int, int], ...] | None = None,
                      sigma_scale: np.ndarray | None = None, shared_unit: np.ndarray | None = None,
                      shared_fraction: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Detector keypoints of one instance in one image.

    ``uv0`` (K, 2) noise-free (or clean) pixels, ``labelled`` / ``visible`` (K,) bool, ``box`` (lo, hi)
    the instance's pixel box.  Returns ((K, 2) pixels with NaN = not detected, (K,) visible flags).
    K = 18 (PEDX_KEYPOINTS) unless another keypoint set is given by ``swap_index`` (its left/right index
    pairs) and ``sigma_scale`` ((K,) factor on each keypoint's noise; None = 1).  ``shared_unit`` (K, 2)
    standard-normal draws common to several images of the instance, of which ``shared_fraction`` of the
    noise variance is made (the same offset in every image that uses them: an error a detector makes alike
    from several viewpoints); None or 0: each image's own draws only.
    Draws are made for every joint in a fixed order whatever the flags (reproducible from the seed).
    """
    n = len(uv0)
    if swap_index is None:
        swap_index = tuple((_IDX[a], _IDX[b]) for a, b in SWAP_PAIRS)
    unit = rng.normal(size=(n, 2))
    if shared_unit is not None and shared_fraction > 0:
        unit = np.sqrt(1.0 - shared_fraction) * unit + np.sqrt(shared_fraction) * np.asarray(shared_unit)
    miss_draw = rng.random(n)
    swap_draw = rng.random(len(swap_index))
    outlier_draw = rng.random(n)
    outlier_pos = rng.random((n, 2))
    sigma = np.hypot(config.sigma_px, config.sigma_height_frac * height_px)
    sigmas = np.where(visible, sigma, sigma * config.occluded_sigma_factor)
    if sigma_scale is not None:
        sigmas = sigmas * np.asarray(sigma_scale, dtype=float)
    uv = np.asarray(uv0, dtype=float) + sigmas[:, None] * unit
    lo, hi = box
    outlier = outlier_draw < config.outlier_prob
    uv[outlier] = lo + outlier_pos[outlier] * (hi - lo)
    vis = np.asarray(visible, dtype=bool).copy()
    lab = np.asarray(labelled, dtype=bool).copy()
    for (ia, ib), draw in zip(swap_index, swap_draw):
        if draw < config.swap_prob:
            uv[[ia, ib]] = uv[[ib, ia]]
            vis[[ia, ib]] = vis[[ib, ia]]
            lab[[ia, ib]] = lab[[ib, ia]]
    missed = miss_draw < np.where(vis, config.miss_prob_visible, config.miss_prob_occluded)
    lab &= ~missed
    width, height = image_size
    uv[:, 0] = np.clip(uv[:, 0], 0.0, width - 1e-3)
    uv[:, 1] = np.clip(uv[:, 1], 0.0, height - 1e-3)
    uv[~lab] = np.nan
    return uv, vis & lab


def corrupt_polygon(polygon: np.ndarray, height_px: float, config: DetectorNoiseConfig,
                    rng: np.random.Generator, image_size: tuple[int, int]) -> np.ndarray:
    """(K, 2) polygon scaled about its centroid, shifted and jittered (see the module docstring)."""
    polygon = np.asarray(polygon, dtype=float)
    scale = 1.0 + config.polygon_scale_sigma * rng.normal()
    shift = config.polygon_shift_frac * height_px * rng.normal(size=2)
    jitter = config.polygon_vertex_noise_px * rng.normal(size=polygon.shape)
    centre = polygon.mean(axis=0)
    out = centre + max(scale, 0.2) * (polygon - centre) + shift + jitter
    width, height = image_size
    out[:, 0] = np.clip(out[:, 0], 0.0, float(width))
    out[:, 1] = np.clip(out[:, 1], 0.0, float(height))
    return out
