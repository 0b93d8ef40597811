"""Baseline "Left+disp" (paper Sec. V): left-image keypoints back-projected at a depth from stereo disparity.

Every keypoint labelled in the rectified left image is back-projected along its left-camera ray (rect =
rectified left camera frame, metres)::

    rect_p = Z [(u_l - c_x) / f, (v_l - c_y) / f, 1],     world_p = world_T_rect @ [rect_p; 1]

with the depth ``Z`` chosen per keypoint as the paper describes:

* keypoint **visible** in the left image with a disparity ``d > 0`` at it: ``Z = f b / d`` (``disparity``);
* keypoint **not visible** in the left image but labelled in both images: triangulated, ``Z = f b / (u_l - u_r)``
  from the two labels (``triangulated``; a dense disparity map would give the occluder's depth there);
* otherwise (visible but no disparity, or occluded and labelled only on the left): the median depth of the
  frame's ``disparity`` keypoints (``median_depth``).

The disparity "at the joint" comes from a :data:`DisparityLookup`.  The default,
:func:`label_disparity`, is the disparity of the two labels, ``u_l - u_r`` (PedX releases carry labels in
both images; images may be absent), where the right label is flagged visible: like a dense stereo matcher,
it has no disparity at a joint hidden in the right image (that label is the annotator's guess, several
times noisier), so such a joint takes the median depth.  Callers with rectified images can pass a lookup
built on a dense disparity map with :func:`disparity_map_lookup`.  Keypoints not labelled on the left, or
frames with no depth at all, are filled exactly as in the triangulation baseline
(:func:`pedx_graph.baselines.triangulation.fill_missing_keypoints`); only ``keypoints_3d`` is meaningful.
"""
from __future__ import annotations

import time
from typing import Callable

import numpy as np

from pedx_graph.baselines.triangulation import (NUM_KEYPOINTS, SRC_DISPARITY, SRC_MEDIAN_DEPTH, SRC_MISSING,
                                                SRC_TRIANGULATED, fill_missing_keypoints, keypoints_only_result)
from pedx_graph.data.types import StereoCalibration, Track, TrackFrame

#: ``lookup(track, frame) -> (18,)`` disparity in pixels at the left-image keypoints, NaN where unknown.
DisparityLookup = Callable[[Track, TrackFrame], np.ndarray]


def label_pair_disparity(frame: TrackFrame) -> np.ndarray:
    """(18,) disparity ``u_l - u_r`` of the 2D labels, pixels; NaN unless labelled in both images."""
    if frame.left is None or frame.right is None:
        return np.full(NUM_KEYPOINTS, np.nan)
    return np.asarray(frame.left.keypoints, float)[:, 0] - np.asarray(frame.right.keypoints, float)[:, 0]


def label_disparity(track: Track, frame: TrackFrame) -> np.ndarray:
    """Default :data:`DisparityLookup`: the labels' disparity (18,) where the right label is flagged visible.

    NaN where the keypoint is not labelled in both images or is hidden in the right image.
    """
    disp = label_pair_disparity(frame)
    if frame.right is not None:
        disp[~np.asarray(frame.right.visible, bool)] = np.nan
    return disp


def sample_disparity_map(disparity_map: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear samples (N,) of a dense disparity image (H, W) (pixels) at ``uv`` (N, 2); NaN outside/invalid.

    Non-positive or non-finite map values (a stereo matcher's "no match") make the sample NaN.
    """
    disp = np.asarray(disparity_map, dtype=float)
    uv = np.asarray(uv, dtype=float)
    out = np.full(len(uv), np.nan)
    height, width = disp.shape
    ok = np.all(np.isfinite(uv), axis=1)
    ok &= (uv[:, 0] >= 0) & (uv[:, 0] <= width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= height - 1)
    if not ok.any():
        return out
    u, v = uv[ok, 0], uv[ok, 1]
    u0 = np.minimum(np.floor(u).astype(int), width - 2) if width > 1 else np.zeros(len(u), int)
    v0 = np.minimum(np.floor(v).astype(int), height - 2) if height > 1 else np.zeros(len(v), int)
    du, dv = u - u0, v - v0
    u1, v1 = np.minimum(u0 + 1, width - 1), np.minimum(v0 + 1, height - 1)
    corners = np.stack([disp[v0, u0], disp[v0, u1], disp[v1, u0], disp[v1, u1]], axis=1)
    weights = np.stack([(1 - du) * (1 - dv), du * (1 - dv), (1 - du) * dv, du * dv], axis=1)
    valid = np.all(np.isfinite(corners) & (corners > 0), axis=1)
    vals = (np.nan_to_num(corners) * weights).sum(axis=1)
    out[np.flatnonzero(ok)[valid]] = vals[valid]
    return out


def disparity_map_lookup(maps: dict[tuple[str, int], np.ndarray]) -> DisparityLookup:
    """A :data:`DisparityLookup` over dense maps keyed by ``(sequence, frame)`` (rectified left image, px)."""
    def lookup(track: Track, frame: TrackFrame) -> np.ndarray:
        disp = maps.get((track.sequence, frame.frame))
        if disp is None or frame.left is None:
            return np.full(NUM_KEYPOINTS, np.nan)
        return sample_disparity_map(disp, frame.left.keypoints)
    return lookup


def back_project(calib: StereoCalibration, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """World points (N, 3) of left-image pixels ``uv`` (N, 2) at rectified depths ``depth`` (N,), metres.

    Assumes the rectified left projection has no translation column (``P_rect_00[:, 3] = 0``, KITTI's
    reference camera), as :func:`pedx_graph.graph.init.triangulate_frame` does.
    """
    f = calib.focal_px
    cx, cy = calib.left_P_rect[0, 2], calib.left_P_rect[1, 2]
    rect_p = np.stack([(uv[:, 0] - cx) * depth / f, (uv[:, 1] - cy) * depth / f, depth], axis=-1)
    world_T_rect = np.linalg.inv(calib.rect_T_world)
    return rect_p @ world_T_rect[:3, :3].T + world_T_rect[:3, 3]


def disparity_depths(track: Track, frame: TrackFrame,
                     disparity: DisparityLookup | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-keypoint rectified depth (18,) in metres and its source code (18,), before back-projection.

    Implements the three cases of the module docstring; NaN / ``SRC_MISSING`` where the keypoint is not
    labelled in the left image or the frame has no disparity keypoint to take a median from.
    """
    depth = np.full(NUM_KEYPOINTS, np.nan)
    source = np.full(NUM_KEYPOINTS, SRC_MISSING, dtype=np.int8)
    if frame.left is None:
        return depth, source
    calib = track.calibrations[frame.pair]
    fb = calib.focal_px * calib.baseline_m
    labelled = frame.left.labelled
    visible = np.asarray(frame.left.visible, bool) & labelled
    disp = np.asarray((disparity or label_disparity)(track, frame), dtype=float)
    if disp.shape != (NUM_KEYPOINTS,):
        raise ValueError(f"disparity lookup returned shape {disp.shape}, expected ({NUM_KEYPOINTS},)")
    use_disp = visible & np.isfinite(disp) & (disp > 1e-3)
    depth[use_disp] = fb / disp[use_disp]
    source[use_disp] = SRC_DISPARITY
    pair_disp = label_pair_disparity(frame)
    use_tri = labelled & ~visible & np.isfinite(pair_disp) & (pair_disp > 1e-3)
    depth[use_tri] = fb / pair_disp[use_tri]
    source[use_tri] = SRC_TRIANGULATED
    rest = labelled & (source == SRC_MISSING)
    if rest.any() and use_disp.any():
        depth[rest] = np.median(depth[use_disp])
        source[rest] = SRC_MEDIAN_DEPTH
    return depth, source


def left_disparity_keypoints(track: Track,
                             disparity: DisparityLookup | None = None) -> tuple[np.ndarray, np.ndarray]:
    """World keypoints (T, 18, 3) (NaN where no depth) and their source codes (T, 18), before filling."""
    n = len(track.frames)
    out = np.full((n, NUM_KEYPOINTS, 3), np.nan)
    source = np.full((n, NUM_KEYPOINTS), SRC_MISSING, dtype=np.int8)
    for i, fr in enumerate(track.frames):
        depth, src = disparity_depths(track, fr, disparity)
        ok = src != SRC_MISSING
        if ok.any():
            out[i, ok] = back_project(track.calibrations[fr.pair], np.asarray(fr.left.keypoints, float)[ok],
                                      depth[ok])
            source[i] = src
    return out, source


def left_disparity_baseline(track: Track, model, disparity: DisparityLookup | None = None):
    """Run the Left+disp baseline on one track: a keypoints-only ``TrackResult`` (see the module docstring)."""
    if len(track.frames) == 0:
        raise ValueError(f"track {track.sequence}/{track.tracking_id} has no frames")
    t0 = time.perf_counter()
    world_keypoints, source = left_disparity_keypoints(track, disparity)
    world_keypoints, source = fill_missing_keypoints(track, world_keypoints, source, model)
    return keypoints_only_result(track, world_keypoints, source, "baseline-left_disp",
                                 time.perf_counter() - t0, model.num_betas)
