"""Simulated annotators: 2D keypoints with click noise, instance polygons, polygon-based LiDAR segments.

Keypoints (per image, PEDX_KEYPOINTS order)::

    uv_label = uv_true + (0, -d) + n,   n ~ N(0, s_j^2 I2),   s_j = keypoint_noise_px[j] (or visible_noise_px)
                                                              if visible, else occluded_noise_px

``uv_true`` is the exact projection of the body model's 3D keypoint; ``visible`` comes from ray tests
(:func:`pedx_graph.sim.cameras.point_visibility`); ``d`` is the pair's ``vertical_disparity_px`` in a right
image (0 in a left one).  Joints whose true projection falls outside the image are not labelled (the key is
absent from the JSON); occluded in-image joints are labelled with probability ``occluded_label_prob``, with
``visible: false`` (or ``true`` when ``occlusion_flags`` is off, as in real PedX).  Noisy positions are
clipped to the image and, with ``integer_clicks``, rounded to whole pixels (polygon vertices too).

File quirks (:func:`file_quirks`, real PedX): a file may carry no keypoints (polygon only) or miss one.

Segments, as in the PedX paper: the LiDAR points of an instance are the points of the full sweep that
project inside its polygon in the *left* image of the pair (in front of the camera; the cut itself is
:mod:`pedx_graph.data.segment_cut`, shared with the detections' LiDAR cut).  This keeps the
paper's mistakes: ground, background or other people seen through/around the silhouette, and points
visible to the LiDAR but hidden from the camera (the sensors sit ~0.3 m apart).  The exact membership
(hit object == this person) is kept separately under ``truth/``.

The labelling tool then applies a far-side depth gate
(:func:`pedx_graph.data.segment_cut.depth_gate`): points whose horizontal range
from the LiDAR exceeds the segment's median range by more than ``LabelConfig.segment_depth_gate_m`` are
dropped.  That removes the ground and walls seen *behind* the person through the silhouette edge (most of
them come from the camera-LiDAR parallax) but keeps every mistake at the person's own depth or in front
of it (occluders, ground at the feet, neighbours in a group).

Random draws are made for all 18 keypoints and every polygon vertex in a fixed order, whatever the
visibility, so a run is reproducible from its seed.
"""
from __future__ import annotations

import numpy as np

from pedx_graph.data.segment_cut import depth_gate, segment_indices_from_projection  # noqa: F401
from pedx_graph.data.types import View2D
from pedx_graph.sim.cameras import CameraView
from pedx_graph.sim.config import LabelConfig


def keypoint_sigma_px(visible: np.ndarray, config: LabelConfig) -> np.ndarray:
    """(18,) click noise per keypoint (px per axis): the visible profile where visible, else the occluded one."""
    visible_sigma = config.visible_noise_px if config.keypoint_noise_px is None else np.asarray(
        config.keypoint_noise_px, dtype=float)
    return np.where(visible, visible_sigma, config.occluded_noise_px)


def keypoint_labels(uv_true: np.ndarray, visible: np.ndarray, in_image: np.ndarray, config: LabelConfig,
                    rng: np.random.Generator, image_size: tuple[int, int],
                    v_shift_px: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Noisy keypoint clicks: ((18, 2) pixels, NaN = not labelled; (18,) ``visible`` flags as written).

    ``uv_true`` (18, 2) exact projections, ``visible`` / ``in_image`` (18,) bool; ``v_shift_px`` is added to
    every v (a right image's ``-vertical_disparity_px``).  Without ``occlusion_flags`` the flags are True
    wherever a keypoint is labelled.
    """
    n = len(uv_true)
    unit_noise = rng.normal(size=(n, 2))
    keep_occluded = rng.random(n) < config.occluded_label_prob
    sigma = keypoint_sigma_px(visible, config)
    labelled = in_image & (visible | keep_occluded)
    uv = uv_true + sigma[:, None] * unit_noise
    if v_shift_px:
        uv[:, 1] += v_shift_px
    width, height = image_size
    if config.integer_clicks:
        uv = np.round(uv)
        uv[:, 0] = np.clip(uv[:, 0], 0.0, width - 1.0)
        uv[:, 1] = np.clip(uv[:, 1], 0.0, height - 1.0)
    else:
        uv[:, 0] = np.clip(uv[:, 0], 0.0, width - 1e-3)
        uv[:, 1] = np.clip(uv[:, 1], 0.0, height - 1e-3)
    uv[~labelled] = np.nan
    flags = visible & labelled if config.occlusion_flags else labelled.copy()
    return uv, flags


def noisy_polygon(polygon: np.ndarray, config: LabelConfig, rng: np.random.Generator,
                  image_size: tuple[int, int], v_shift_px: float = 0.0) -> np.ndarray:
    """(K, 2) polygon with N(0, polygon_noise_px^2) added to every vertex (and ``v_shift_px`` to every v),
    clipped to the image; rounded to whole pixels with ``integer_clicks``."""
    out = polygon + config.polygon_noise_px * rng.normal(size=polygon.shape)
    if v_shift_px:
        out[:, 1] += v_shift_px
    if config.integer_clicks:
        out = np.round(out)
    width, height = image_size
    out[:, 0] = np.clip(out[:, 0], 0.0, float(width))
    out[:, 1] = np.clip(out[:, 1], 0.0, float(height))
    return out


def file_quirks(uv: np.ndarray, flags: np.ndarray, config: LabelConfig,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, str | None]:
    """Apply the real labels' file quirks to one file's keypoints: ``(uv, flags, quirk)`` copies.

    With probability ``polygon_only_prob`` every keypoint is removed (``quirk = "polygon_only"``, the file is
    written with ``keypoint: null``); else, with probability ``missing_keypoint_prob`` and at least two
    keypoints labelled, one labelled keypoint drawn uniformly is removed (``"missing_keypoint"``).  Always
    three draws from ``rng`` (fixed order), so the stream does not depend on the outcome.
    """
    u_polygon, u_missing, u_pick = rng.random(3)
    uv, flags = uv.copy(), flags.copy()
    labelled = np.flatnonzero(np.all(np.isfinite(uv), axis=1))
    if u_polygon < config.polygon_only_prob:
        uv[:] = np.nan
        flags[:] = False
        return uv, flags, "polygon_only"
    if u_missing < config.missing_keypoint_prob and len(labelled) >= 2:
        drop = labelled[min(int(u_pick * len(labelled)), len(labelled) - 1)]
        uv[drop] = np.nan
        flags[drop] = False
        return uv, flags, "missing_keypoint"
    return uv, flags, None


def make_view(uv: np.ndarray, visible: np.ndarray, polygon: np.ndarray | None) -> View2D:
    """A :class:`View2D` from labelled keypoints (NaN = unlabelled), flags and polygon."""
    return View2D(keypoints=np.asarray(uv, dtype=float), visible=np.asarray(visible, dtype=bool),
                  polygon=None if polygon is None else np.asarray(polygon, dtype=float))


def segment_indices(view: CameraView, world_points: np.ndarray, polygon: np.ndarray,
                    min_depth_m: float = 0.5) -> np.ndarray:
    """Indices (sorted) of the (N, 3) sweep points projecting inside ``polygon`` in ``view`` (a left camera).

    Only points at least ``min_depth_m`` in front of the camera count.
    """
    if len(world_points) == 0 or polygon is None:
        return np.zeros(0, dtype=np.int64)
    uv, depth = view.project(world_points)
    return segment_indices_from_projection(uv, depth, polygon, min_depth_m)
