"""The labelling's LiDAR cut: which sweep points belong to an instance, from its image polygon.

As in the PedX labelling (and in the simulator's annotators, :mod:`pedx_graph.sim.labels`), an instance's
LiDAR segment is the set of sweep points in front of a camera (depth > ``min_depth_m``, metres) whose pixels
(rectified, px) fall inside the instance's polygon in that image (:func:`segment_indices_from_projection`),
optionally thinned by a far-side depth gate (:func:`depth_gate`).  The simulator, the detector-label datasets
of the evaluation and the cut of real detections from scene clouds (:mod:`pedx_graph.detections.lidar_cut`)
all use these functions, so the three cut the same way.
"""
from __future__ import annotations

import cv2
import numpy as np


def points_in_polygon(uv: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """(N,) bool: pixel points (N, 2) inside the closed pixel polygon (K, 2) (boundary counts as inside).

    Rasterises the polygon over its bounding box at 1/8-px vertex precision and looks the points up.
    """
    inside = np.zeros(len(uv), dtype=bool)
    if len(uv) == 0 or polygon is None or len(polygon) < 3:
        return inside
    lo = np.floor(polygon.min(axis=0)).astype(int)
    hi = np.ceil(polygon.max(axis=0)).astype(int)
    size = hi - lo + 1
    mask = np.zeros((size[1], size[0]), dtype=np.uint8)
    shift = 3
    pts = np.round((polygon - lo - 0.5) * (1 << shift)).astype(np.int32)
    # pixel (i, j) of the mask covers image [lo + i, lo + i + 1): its centre lo + i + 0.5 is sampled
    cv2.fillPoly(mask, [pts.reshape(-1, 1, 2)], 1, lineType=cv2.LINE_8, shift=shift)
    idx = np.floor(uv - lo).astype(np.int64)
    ok = np.all(np.isfinite(uv), axis=1)
    ok &= (idx[:, 0] >= 0) & (idx[:, 0] < size[0]) & (idx[:, 1] >= 0) & (idx[:, 1] < size[1])
    inside[ok] = mask[idx[ok, 1], idx[ok, 0]] > 0
    return inside


def segment_indices_from_projection(uv: np.ndarray, depth: np.ndarray, polygon: np.ndarray,
                                    min_depth_m: float = 0.5) -> np.ndarray:
    """Indices (sorted) of the sweep points whose pixels ``uv`` (N, 2) fall inside ``polygon`` (K, 2) and whose
    depths ``depth`` (N,) along the camera's optical axis exceed ``min_depth_m`` (metres)."""
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
