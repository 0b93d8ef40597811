"""Linear triangulation of a frame's 18 keypoints from every camera that labels them (all stereo pairs).

For keypoint k labelled at pixel ``(u, v)`` in n >= 2 rectified images, each with its projection
``image_P_world`` (3, 4) (:func:`factors.stereo_reprojection.image_projection`: ``P_rect`` of the left or
right camera times the pair's ``rect_T_world``; world = LiDAR frame, metres), the direct linear transform
stacks two rows per image,

    (u P[2] - P[0]) X = 0,   (v P[2] - P[1]) X = 0,     X = [world_p; 1] homogeneous,

and takes X as the right singular vector of the smallest singular value.  For conditioning, the world
points are expressed relative to the mean centre of the cameras used, and each image's pixels are
normalised by its intrinsic matrix (``N = P_rect[:, :3]^-1``; ``image_P_world`` replaced by
``N @ image_P_world``), so every row is in comparable units (1 px weighs 1 / f in each image).  A keypoint
labelled in fewer than two images, with a degenerate solution, or behind one of its cameras stays NaN.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from factors.stereo_reprojection import image_projection
from pedx_graph.data.types import StereoCalibration, TrackFrame
from pedx_graph.keypoints import PEDX_KEYPOINTS

NUM_KEYPOINTS = len(PEDX_KEYPOINTS)


def _view_rays(calib: StereoCalibration, side: str) -> tuple[np.ndarray, np.ndarray]:
    """``(N, N @ image_P_world)`` of one rectified image: ``N = P_rect[:, :3]^-1`` maps its pixels to
    normalised image coordinates (``P_rect[:, :3]`` is the rectified camera's intrinsic matrix)."""
    proj_rect = calib.left_P_rect if side == "left" else calib.right_P_rect
    norm = np.linalg.inv(np.asarray(proj_rect, dtype=float)[:, :3])
    return norm, norm @ image_projection(calib, side)


def triangulate_views(frame: TrackFrame, calibrations: Mapping[str, StereoCalibration],
                      all_pairs: bool = True, visible_only: bool = False) -> np.ndarray:
    """World positions (18, 3), metres, of the frame's keypoints by linear (DLT) triangulation over every
    image that labels them (``frame.labelled_views(all_pairs)``); NaN where fewer than two images label the
    keypoint (``visible_only``: count only labels flagged visible) or where the solution is degenerate or
    behind a camera.  ``calibrations``: the stereo pairs by name (``Track.calibrations``)."""
    views = frame.labelled_views(all_pairs)
    out = np.full((NUM_KEYPOINTS, 3), np.nan)
    if len(views) < 2:
        return out
    norm_P, norm_uv, masks, centres = [], [], [], []
    for pair, side, view in views:
        calib = calibrations[pair]
        norm, proj = _view_rays(calib, side)
        uv = np.asarray(view.keypoints, dtype=float)
        ok = np.all(np.isfinite(uv), axis=1)
        if visible_only:
            ok &= np.asarray(view.visible, dtype=bool)
        hom = np.concatenate([uv, np.ones((len(uv), 1))], axis=1) @ norm.T
        norm_P.append(proj)
        norm_uv.append(hom[:, :2] / hom[:, 2:3])
        masks.append(ok)
        centres.append(-np.linalg.solve(proj[:, :3], proj[:, 3]))          # the camera centre, world
    origin = np.mean(centres, axis=0)
    local_P = np.stack(norm_P).copy()
    local_P[:, :, 3] += local_P[:, :, :3] @ origin                          # acts on [world_p - origin; 1]
    norm_uv = np.stack(norm_uv)                                             # (n, 18, 2)
    masks = np.stack(masks)                                                 # (n, 18)
    for k in np.flatnonzero(masks.sum(axis=0) >= 2):
        use = masks[:, k]
        proj, xy = local_P[use], norm_uv[use, k]
        rows = np.concatenate([xy[:, :1] * proj[:, 2] - proj[:, 0], xy[:, 1:2] * proj[:, 2] - proj[:, 1]])
        hom = np.linalg.svd(rows)[2][-1]
        if abs(hom[3]) <= 1e-12 * np.abs(hom[:3]).max():
            continue
        local = hom[:3] / hom[3]
        if np.any(proj[:, 2, :3] @ local + proj[:, 2, 3] <= 0):              # behind a camera
            continue
        out[k] = local + origin
    return out
