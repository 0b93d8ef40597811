"""Simulated annotators: 2D keypoints with click noise, instance polygons, polygon-based LiDAR segments.

Keypoints (per image, PEDX_KEYPOINTS order)::

    uv_label = uv_true + n,   n ~ N(0, s^2 I2),   s = visible_noise_px if visible else occluded_noise_px

``uv_true`` is the exact projection of the body model's 3D keypoint; ``visible`` comes from ray tests
(:func:`pedx_graph.sim.cameras.point_visibility`).  Joints whose true projection falls outside the image
are not labelled (the key is absent from the JSON); occluded in-image joints are labelled
(``visible: false``) with probability ``occluded_label_prob``.  Noisy positions are clipped to the image.

Segments, as in the PedX paper: the LiDAR points of an instance are the points of the full sweep that
project inside its polygon in the *left* image of the pair (in front of the camera).  This keeps the
paper's mistakes: ground, background or other people seen through/around the silhouette, and points
visible to the LiDAR but hidden from the camera (the sensors sit ~0.3 m apart).  The exact membership
(hit object == this person) is kept separately under ``truth/``.

The labelling tool then applies a far-side depth gate (:func:`depth_gate`): points whose horizontal range
from the LiDAR exceeds the segment's median range by more than ``LabelConfig.segment_depth_gate_m`` are
dropped.  That removes the ground and walls seen *behind* the person through the silhouette edge (most of
them come from the camera-LiDAR parallax) but keeps every mistake at the person's own depth or in front
of it (occluders, ground at the feet, neighbours in a group).

Random draws are made for all 18 keypoints and every polygon vertex in a fixed order, whatever the
visibility, so a run is reproducible from its seed.
"""
from __future__ import annotations

import numpy as np

from pedx_graph.data.types import View2D
from pedx_graph.sim.cameras import CameraView, points_in_polygon
from pedx_graph.sim.config import LabelConfig


def keypoint_labels(uv_true: np.ndarray, visible: np.ndarray, in_image: np.ndarray, config: LabelConfig,
                    rng: np.random.Generator, image_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Noisy keypoint clicks: ((18, 2) pixels, NaN = not labelled; (18,) visible flags).

    ``uv_true`` (18, 2) exact projections, ``visible`` / ``in_image`` (18,) bool.
    """
    n = len(uv_true)
    unit_noise = rng.normal(size=(n, 2))
    keep_occluded = rng.random(n) < config.occluded_label_prob
    sigma = np.where(visible, config.visible_noise_px, config.occluded_noise_px)
    labelled = in_image & (visible | keep_occluded)
    uv = uv_true + sigma[:, None] * unit_noise
    width, height = image_size
    uv[:, 0] = np.clip(uv[:, 0], 0.0, width - 1e-3)
    uv[:, 1] = np.clip(uv[:, 1], 0.0, height - 1e-3)
    uv[~labelled] = np.nan
    return uv, visible & labelled


def noisy_polygon(polygon: np.ndarray, config: LabelConfig, rng: np.random.Generator,
                  image_size: tuple[int, int]) -> np.ndarray:
    """(K, 2) polygon with N(0, polygon_noise_px^2) added to every vertex, clipped to the image."""
    out = polygon + config.polygon_noise_px * rng.normal(size=polygon.shape)
    width, height = image_size
    out[:, 0] = np.clip(out[:, 0], 0.0, float(width))
    out[:, 1] = np.clip(out[:, 1], 0.0, float(height))
    return out


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


def segment_indices_from_projection(uv: np.ndarray, depth: np.ndarray, polygon: np.ndarray,
                                    min_depth_m: float = 0.5) -> np.ndarray:
    """:func:`segment_indices` from precomputed pixels (N, 2) and depths (N,) of the sweep points."""
    if polygon is None or len(uv) == 0:
        return np.zeros(0, dtype=np.int64)
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    u, v = uv[:, 0], uv[:, 1]
    cand = np.flatnonzero((u >= lo[0]) & (u <= hi[0]))
    cand = cand[(v[cand] >= lo[1]) & (v[cand] <= hi[1]) & (depth[cand] > min_depth_m)]
    return cand[points_in_polygon(uv[cand], polygon)]


def depth_gate(index: np.ndarray, world_points: np.ndarray, gate_m: float) -> np.ndarray:
    """The rows of ``index`` (into the (N, 3) LiDAR-frame ``world_points``) kept by the far-side depth gate.

    A point is kept when its horizontal range ``|p_xy|`` (metres, from the LiDAR) is at most
    ``median(|p_xy| over index) + gate_m``.  ``gate_m <= 0`` keeps everything.
    """
    index = np.asarray(index, dtype=np.int64)
    if gate_m <= 0 or len(index) == 0:
        return index
    ranges = np.hypot(world_points[index, 0], world_points[index, 1])
    return index[ranges <= np.median(ranges) + gate_m]
