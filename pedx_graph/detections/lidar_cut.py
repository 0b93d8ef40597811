"""LiDAR for detections: cut each detected person's points out of the frame's full scene cloud.

Detector output has no per-person LiDAR segment, only the scene clouds (``pointclouds/<seq>/<seq>_<frame>.ply``).
The labelling path cuts a segment with the annotator's polygon (:func:`pedx_graph.sim.labels.
segment_indices_from_projection`: scene points in front of the camera projecting inside the polygon); here the
polygon is the detection's *hull*:

* the convex hull (OpenCV) of the detection's rectified keypoints, grown about its centroid by
  ``dilate_frac`` of the person's image height plus ``dilate_px`` (keypoints are joints and surface points;
  the silhouette reaches past them: head top, feet, arms' width);
* **depth gate**: with a depth ``Z`` for the person (stereo, along the rectified optical axis) only points with
  ``Z - gate_front_m <= z <= Z + gate_back_m`` are kept (each gate at least ``depth_gate_sigmas`` times the
  depth's uncertainty when that is known and large: a stereo centre at range), and of those the depth
  cluster (depths sorted, split at gaps over ``cluster_gap_m``) whose median is nearest ``Z`` (an occluder just in front, a wall just
  behind are clusters of their own); without a depth, the nearest cluster with ``min_cluster_points``;
* **past the image's border**: where the hull reaches within its own dilation of a border, the person may go on
  where the camera does not see it, but the LiDAR does: the scene points in a band past that border
  (``beyond_border_m`` at the person's depth) that pass the same gates, lie within ``body_radius_m`` of the
  person's centre (when it is known to ``claim_sigma_m``) and connect to the cut through points closer than
  ``beyond_border_gap_m`` (3D) join it, so a walker entering or leaving the view keeps its whole body's points
  while a neighbour standing apart, or a wall the walker passes, stays out;
* **ground**: points less than ``ground_clearance_m`` above the ground plane of the sequence's
  :class:`~pedx_graph.data.ground.GroundFrame` are removed (kept when its ground height is unknown);
* non-finite points (the release's ``inf`` dropouts) never enter.

:func:`write_track_segments` writes the cuts of :class:`~pedx_graph.detections.association.DetectedTrack` s in
the release layout (``labels/3d/segment/<seq>/<seq>_<frame:07d>_<tid>.ply``), one file per track and frame
with points (union over the pairs that saw the person, each pair's left keypoints completed by its right
image's at the person's disparity: where the detector found only part of the body in one image, the other
image's detection adds the rest; none for a frame the association gave no centre), each point
given to one person only (:func:`exclusive_cuts`: the claimant whose body most likely holds it).
"""
from __future__ import annotations

import logging
import os
from itertools import chain
from dataclasses import dataclass
from typing import Callable, Collection, Mapping

import cv2
import numpy as np

from pedx_graph.data.ground import GroundFrame
from pedx_graph.data.segment_cut import segment_indices_from_projection
from pedx_graph.data.types import StereoCalibration

log = logging.getLogger(__name__)


@dataclass
class LidarCutConfig:
    """How a detection's LiDAR points are cut from the scene cloud (pixels, metres)."""

    dilate_frac: float = 0.08
    """The keypoint hull grows by this fraction of the person's image height (keypoints lie inside the
    silhouette)."""
    dilate_px: float = 4.0
    """... plus this many pixels."""
    min_keypoints: int = 3
    """A detection with fewer usable keypoints is not cut."""
    gate_front_m: float = 0.6
    """Points nearer than the person's depth by more than this are dropped, metres (half a body's depth
    plus stereo depth noise)."""
    gate_back_m: float = 0.8
    """Points farther than the person's depth by more than this are dropped, metres (background seen past
    the silhouette)."""
    depth_gate_sigmas: float = 3.0
    """Where the person's depth is uncertain (a stereo centre at range, sigma ``s``), each gate is at least this
    many ``s`` wide: a centre 2 m off no longer gates out every one of the person's points."""
    cluster_gap_m: float = 0.35
    """A gap this large between consecutive point depths separates two clusters, metres (a person's points
    span ~0.3 m in depth)."""
    min_cluster_points: int = 5
    """Without a depth: the nearest cluster with at least this many points is the person."""
    ground_clearance_m: float = 0.08
    """Points lower than this above the ground plane are removed (ground at the feet), metres."""
    min_depth_m: float = 0.5
    """Only points at least this far in front of the camera are projected, metres."""
    body_radius_m: float = 0.4
    """A person whose centre is known (:attr:`claim_sigma_m`) claims the cut points within this horizontal
    distance of it, metres (a body's LiDAR points lie within ~0.3 m of its centre); half of it is the spread
    of a body's points about its centre by which :func:`exclusive_cuts` ranks the claimants of a point."""
    claim_sigma_m: float = 0.3
    """A centre known to within this (its depth uncertainty) claims points by :attr:`body_radius_m`, metres."""
    beyond_border_m: float = 1.0
    """A person cut off by the image's border goes on beyond it, where the LiDAR (which sees all around) still
    sees it: where the dilated hull reaches within its own dilation of a border, the scene points in a band
    from there to ``f * beyond_border_m / Z`` pixels past the border (``Z`` the person's depth), along the
    hull's extent grown by as much (:func:`past_border_mask`), that pass the same gates, lie within
    :attr:`body_radius_m` of the person's centre (known to :attr:`claim_sigma_m`; else nothing is added) and
    connect to the cut (:attr:`beyond_border_gap_m`) join it, metres; 0 = off."""
    beyond_border_gap_m: float = 0.3
    """... a point past the border joins the cut when it lies within this of a cut point (3D, repeatedly: a
    body's scan lines stay much closer; a neighbour standing apart does not join), metres."""


def ground_with_plane(ground: GroundFrame, calibrations: Mapping[str, StereoCalibration],
                      clouds: Mapping[int, np.ndarray], max_frames: int = 6) -> GroundFrame:
    """``ground`` itself when it knows the ground height; else the ground re-derived from up to ``max_frames``
    scene clouds (evenly spaced; :func:`pedx_graph.data.ground.estimate_ground`), so the cuts can remove the
    ground at the feet."""
    from pedx_graph.data.ground import estimate_ground

    if ground.ground_offset_m is not None or not len(clouds):
        return ground
    frames = sorted(clouds)
    chosen = [frames[int(i)] for i in np.unique(np.linspace(0, len(frames) - 1, min(max_frames, len(frames))).round())]
    points = []
    for frame in chosen:
        try:
            points.append(np.asarray(clouds[frame], dtype=float).reshape(-1, 3))
        except Exception as exc:  # noqa: BLE001 - an unreadable cloud is left out of the fit
            log.warning("frame %d: scene cloud unreadable for the ground fit (%s)", frame, exc)
    fitted = estimate_ground(dict(calibrations), scene_points=points)
    return fitted if fitted.ground_offset_m is not None else ground


def hull_polygon(rect_uv: np.ndarray, config: LidarCutConfig) -> np.ndarray | None:
    """(H, 2) dilated convex hull of the present keypoints of (K, 2) rectified pixels, or None when fewer
    than ``min_keypoints``."""
    present = rect_uv[np.all(np.isfinite(rect_uv), axis=1)]
    if len(present) < max(config.min_keypoints, 3):
        return None
    hull = cv2.convexHull(present.astype(np.float32)).reshape(-1, 2).astype(float)
    height = float(np.ptp(present[:, 1]))
    centre = hull.mean(axis=0)
    offset = hull - centre
    norm = np.maximum(np.linalg.norm(offset, axis=1, keepdims=True), 1e-9)
    grown = hull + offset / norm * (config.dilate_frac * height + config.dilate_px)
    if len(hull) < 3:                               # collinear keypoints: a thin box around the segment
        lo, hi = present.min(axis=0), present.max(axis=0)
        pad = config.dilate_frac * max(height, float(np.ptp(present[:, 0]))) + config.dilate_px
        grown = np.array([[lo[0] - pad, lo[1] - pad], [hi[0] + pad, lo[1] - pad], [hi[0] + pad, hi[1] + pad],
                          [lo[0] - pad, hi[1] + pad]])
    return grown


def past_border_mask(uv: np.ndarray, polygon: np.ndarray, image_size: tuple[int, int], margin_px: float,
                     extend_px: float) -> np.ndarray:
    """(N,) bool: the pixels ``uv`` (N, 2) where a person whose hull ``polygon`` (H, 2) reaches within
    ``margin_px`` of an image border (``image_size`` = width, height) may go on past it: for each such border,
    the band from ``margin_px`` inside it to ``extend_px`` past it, along the hull's extent grown by
    ``extend_px`` (all False when the hull reaches no border)."""
    width, height = float(image_size[0]), float(image_size[1])
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    left, right, top, bottom = _borders_reached(polygon, image_size, margin_px)
    mask = np.zeros(len(uv), dtype=bool)
    if not (left or right or top or bottom):           # most detections: nothing to test point by point
        return mask
    u, v = uv[:, 0], uv[:, 1]
    along_u = (u >= lo[0] - extend_px) & (u <= hi[0] + extend_px)
    along_v = (v >= lo[1] - extend_px) & (v <= hi[1] + extend_px)
    if left:
        mask |= along_v & (u >= -extend_px) & (u <= margin_px)
    if right:
        mask |= along_v & (u >= width - margin_px) & (u <= width + extend_px)
    if top:
        mask |= along_u & (v >= -extend_px) & (v <= margin_px)
    if bottom:
        mask |= along_u & (v >= height - margin_px) & (v <= height + extend_px)
    return mask


def _borders_reached(polygon: np.ndarray, image_size: tuple[int, int], margin_px: float) -> tuple[bool, ...]:
    """Whether the hull ``polygon`` (H, 2) reaches within ``margin_px`` of the image's left, right, top and
    bottom border (``image_size`` = width, height)."""
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    return (bool(lo[0] < margin_px), bool(hi[0] > image_size[0] - margin_px), bool(lo[1] < margin_px),
            bool(hi[1] > image_size[1] - margin_px))


def border_margin_px(rect_uv: np.ndarray, config: LidarCutConfig) -> float:
    """How near an image border a detection's hull must reach for the person to be taken as cut off by it:
    the hull's own dilation (``dilate_frac`` of the keypoints' height plus ``dilate_px``), pixels."""
    present = np.asarray(rect_uv, dtype=float)
    present = present[np.all(np.isfinite(present), axis=1)]
    return config.dilate_frac * (float(np.ptp(present[:, 1])) if len(present) else 0.0) + config.dilate_px


def reaches_border(rect_uv: np.ndarray, calib: StereoCalibration, config: LidarCutConfig) -> bool:
    """Whether a detection's dilated hull reaches within :func:`border_margin_px` of its image's border."""
    polygon = hull_polygon(np.asarray(rect_uv, dtype=float), config)
    if polygon is None:
        return False
    return any(_borders_reached(polygon, calib.image_size, border_margin_px(rect_uv, config)))


def _grown_past_border(index: np.ndarray, outside: np.ndarray, world_points: np.ndarray,
                       gap_m: float) -> np.ndarray:
    """``index`` (rows of ``world_points``) plus the rows of ``outside`` connected to them by chains of points
    closer than ``gap_m`` (3D)."""
    from scipy.spatial import cKDTree

    outside = np.setdiff1d(outside, index)
    if not len(index) or not len(outside):
        return index
    tree = cKDTree(world_points[outside])
    joined = np.zeros(len(outside), dtype=bool)
    front = world_points[index]
    while len(front):
        near = np.unique(np.fromiter(chain.from_iterable(tree.query_ball_point(front, gap_m)), dtype=np.int64))
        new = near[~joined[near]]
        joined[new] = True
        front = world_points[outside[new]]
    return np.union1d(index, outside[joined])


def _nearest_cluster(depth: np.ndarray, config: LidarCutConfig) -> np.ndarray:
    """Bool mask of the nearest depth cluster with enough points (all False when none)."""
    order = np.argsort(depth, kind="stable")
    sorted_depth = depth[order]
    breaks = np.flatnonzero(np.diff(sorted_depth) > config.cluster_gap_m) + 1
    keep = np.zeros(len(depth), dtype=bool)
    for chunk in np.split(np.arange(len(depth)), breaks):
        if len(chunk) >= config.min_cluster_points:
            keep[order[chunk]] = True
            break
    return keep


def _cluster_nearest_depth(depth: np.ndarray, depth_m: float, config: LidarCutConfig) -> np.ndarray:
    """Bool mask of the depth cluster (gaps over ``cluster_gap_m`` split) whose median depth is nearest
    ``depth_m``: a car passing just in front of the person, inside the gate, is a cluster of its own."""
    keep = np.zeros(len(depth), dtype=bool)
    if len(depth) == 0:
        return keep
    order = np.argsort(depth, kind="stable")
    breaks = np.flatnonzero(np.diff(depth[order]) > config.cluster_gap_m) + 1
    chunks = np.split(order, breaks)
    best = min(chunks, key=lambda chunk: abs(float(np.median(depth[chunk])) - depth_m))
    keep[best] = True
    return keep


def cut_person(rect_uv: np.ndarray, calib: StereoCalibration, side: str, world_points: np.ndarray,
               ground: GroundFrame, config: LidarCutConfig | None = None, depth_m: float | None = None,
               projection: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """(M, 3) world points of one detected person (module docstring).

    ``rect_uv``: (K, 2) rectified pixels of the detection in the pair's ``side`` (``"left"``/``"right"``)
    image, NaN where absent; ``world_points``: (N, 3) scene cloud (world frame, may hold ``inf``);
    ``depth_m``: the person's depth along the rectified optical axis (None: nearest cluster);
    ``projection``: precomputed ``(uv (N, 2), depth (N,))`` of ``world_points`` in that image.
    """
    config = config or LidarCutConfig()
    return world_points[cut_indices(rect_uv, calib, side, world_points, ground, config, depth_m, projection)]


def project_cloud(calib: StereoCalibration, side: str, world_points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(uv (N, 2), depth (N,))`` of world points in the pair's rectified ``side`` image (non-finite points get
    NaN pixels and depth)."""
    world_points = np.asarray(world_points, dtype=float)
    finite = np.all(np.isfinite(world_points), axis=1)
    uv = np.full((len(world_points), 2), np.nan)
    depth = np.full(len(world_points), np.nan)
    if finite.any():
        rect_p = calib.world_to_rect(world_points[finite])
        P = calib.left_P_rect if side == "left" else calib.right_P_rect
        hom = rect_p @ P[:, :3].T + P[:, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv[finite] = hom[:, :2] / hom[:, 2:3]
        depth[finite] = rect_p[:, 2]
    return uv, depth


def cut_indices(rect_uv: np.ndarray, calib: StereoCalibration, side: str, world_points: np.ndarray,
                ground: GroundFrame, config: LidarCutConfig, depth_m: float | None = None,
                projection: tuple[np.ndarray, np.ndarray] | None = None,
                depth_sigma_m: float | None = None, world_centre: np.ndarray | None = None) -> np.ndarray:
    """Sorted row indices into ``world_points`` of :func:`cut_person`'s points (``depth_sigma_m``: the
    uncertainty of ``depth_m``, widening the gates to ``depth_gate_sigmas`` of it).  ``world_centre``: the
    person's (3,) centre when known to within ``claim_sigma_m``: only then does a cut reaching the image's
    border go on past it, with the points within ``body_radius_m`` of that centre on the ground plane (a
    wall or a parked car the person walks along stays out)."""
    polygon = hull_polygon(np.asarray(rect_uv, dtype=float), config)
    if polygon is None or len(world_points) == 0:
        return np.zeros(0, dtype=np.int64)
    uv, depth = projection if projection is not None else project_cloud(calib, side, world_points)
    safe_depth = np.where(np.isfinite(depth), depth, -1.0)
    safe_uv = np.where(np.isfinite(uv), uv, -1e9)
    index = segment_indices_from_projection(safe_uv, safe_depth, polygon, config.min_depth_m)
    # past the image's border: the person may go on where the camera does not see it
    outside = np.zeros(0, dtype=np.int64)
    known_depth = depth_m is not None and np.isfinite(depth_m) and depth_m > 0
    if config.beyond_border_m > 0 and known_depth and world_centre is not None:
        extend_px = calib.focal_px * config.beyond_border_m / depth_m
        margin = border_margin_px(rect_uv, config)
        near_border = past_border_mask(safe_uv, polygon, calib.image_size, margin, extend_px)
        outside = np.setdiff1d(np.flatnonzero(near_border & (safe_depth > config.min_depth_m)), index)
        centre_xy = ground.to_level(np.asarray(world_centre, dtype=float)[None])[0, :2]
        outside = outside[np.linalg.norm(ground.to_level(world_points[outside])[:, :2] - centre_xy, axis=1)
                          <= config.body_radius_m]
    index, outside = (_gated(idx, depth, world_points, ground, config, depth_m, depth_sigma_m)
                      for idx in (index, outside))
    if len(index) == 0:
        return index
    z = depth[index]
    if depth_m is not None and np.isfinite(depth_m):
        index = index[_cluster_nearest_depth(z, depth_m, config)]
    else:
        index = index[_nearest_cluster(z, config)]
    if len(outside):
        index = _grown_past_border(index, outside, world_points, config.beyond_border_gap_m)
    return np.sort(index)


def _gated(index: np.ndarray, depth: np.ndarray, world_points: np.ndarray, ground: GroundFrame,
           config: LidarCutConfig, depth_m: float | None, depth_sigma_m: float | None) -> np.ndarray:
    """The rows of ``index`` above the ground clearance and, with a person's depth ``depth_m``, within the
    depth gate about it (module docstring)."""
    if len(index) and ground.ground_offset_m is not None:
        index = index[ground.height(world_points[index]) >= config.ground_clearance_m]
    if len(index) and depth_m is not None and np.isfinite(depth_m):
        spread = config.depth_gate_sigmas * float(depth_sigma_m) if depth_sigma_m is not None and \
            np.isfinite(depth_sigma_m) else 0.0
        front, back = max(config.gate_front_m, spread), max(config.gate_back_m, spread)
        z = depth[index]
        index = index[(z >= depth_m - front) & (z <= depth_m + back)]
    return index


def track_frame_indices(frame, calibrations: Mapping[str, StereoCalibration], world_points: np.ndarray,
                        ground: GroundFrame, config: LidarCutConfig | None = None,
                        rectify: Callable | None = None) -> np.ndarray:
    """Sorted row indices into ``world_points`` of one
    :class:`~pedx_graph.detections.association.DetectedTrackFrame`'s points: the union over the pairs that saw
    it of one cut per pair, gated around its centre's depth — where both images of a pair saw the person, the
    left image's keypoints completed by the right image's at the person's disparity (a detection that found
    only the head and shoulders in one image is completed by the other's; the right one's silhouette alone
    would add its own fringe of background); else the one image's.  A frame without a centre gets no points:
    the association placed it neither by stereo nor by a LiDAR cluster of its own
    (:func:`~pedx_graph.detections.association.detection_ranges` found none, or none it could tell from the
    background), so the nearest points in its hull are as likely a wall behind it or someone in front; the
    fit places it by its body's size instead."""
    from pedx_graph.detections.undistort import find_camera, rectified

    config = config or LidarCutConfig()
    if frame.world_p is None:
        return np.zeros(0, dtype=np.int64)
    rectify = rectify or rectified
    pairs: dict[str, dict] = {}
    for camera, det in sorted(frame.detections.items()):
        calib, side = find_camera(calibrations, camera)
        uv = rectify(det, calibrations)
        pairs.setdefault(calib.name, {"calib": calib})[side] = np.where((np.asarray(det.confidence) > 0)[:, None],
                                                                         uv, np.nan)
    sigma = getattr(frame, "depth_sigma_m", None)
    index = []
    for views in pairs.values():
        calib = views["calib"]
        depth, centre = None, None
        if frame.world_p is not None:
            depth = float(calib.world_to_rect(np.asarray(frame.world_p, dtype=float))[2])
            if sigma is not None and sigma <= config.claim_sigma_m:
                centre = frame.world_p
        if "left" in views and "right" in views and depth is not None and depth > 0:
            # one silhouette: the left keypoints, those the left image lacks taken from the right one at the
            # person's disparity (past the left image's border, if that is where they fall)
            left_c, right_c = calib.project(np.asarray(frame.world_p, dtype=float))
            shift = np.array([left_c[0] - right_c[0], 0.0])
            cuts = [("left", completed_keypoints(views["left"], views["right"] + shift))]
        else:
            cuts = [(side, views[side]) for side in ("left", "right") if side in views]
        for side, uv in cuts:
            index.append(cut_indices(uv, calib, side, world_points, ground, config, depth, depth_sigma_m=sigma,
                                     world_centre=centre))
    if not index:
        return np.zeros(0, dtype=np.int64)
    return np.unique(np.concatenate(index))


def completed_keypoints(uv: np.ndarray, other_uv: np.ndarray) -> np.ndarray:
    """(K, 2) ``uv`` with its missing keypoints (NaN rows) taken from ``other_uv`` (K, 2)."""
    missing = ~np.all(np.isfinite(uv), axis=1)
    return np.where(missing[:, None], other_uv, uv)


def exclusive_cuts(cuts: list[np.ndarray], world_points: np.ndarray, centres: list, sigmas: list,
                   ground: GroundFrame, config: LidarCutConfig) -> list[np.ndarray]:
    """One frame's cuts (row indices into ``world_points``, one array per person) with every point kept by
    one person only.  A point is claimed by every person whose cut holds it, and by every person whose
    centre (``centres``: (3,) world points or None, uncertain by ``sigmas`` metres) is known to within
    ``claim_sigma_m`` and lies within ``body_radius_m`` of it on the ground plane; it stays with the
    claimant whose body most likely holds it, whether or not that person's own cut held it: the point's
    ground-plane distance ``d`` from each claimant's centre under a 2D normal of variance ``s^2 = (body_radius_m
    / 2)^2 + sigma^2`` (a body's points about its centre, and where that centre may be), the smallest
    ``d^2 / s^2 + 2 ln s^2`` winning — among equally sure centres the nearest, while a centre placed to within
    a decimetre keeps its body's points against one that lies as near only by a guess (a stereo depth at
    range on top of a neighbour's LiDAR centre).  A claimant without a centre keeps a point only when it is
    the only one; shared by claimants none of whom has a centre, it goes to no one.  Two people one behind
    the other in an image share the hull's points; the near one's body is where they lie, whether or not
    that image saw all of the near one."""
    flat_centres = [None if c is None else ground.to_level(np.asarray(c, dtype=float))[:2] for c in centres]
    confident = [p for p, (c, s) in enumerate(zip(flat_centres, sigmas))
                 if c is not None and s is not None and s <= config.claim_sigma_m]
    used = np.unique(np.concatenate(cuts)) if cuts else np.zeros(0, dtype=np.int64)
    if not len(used):
        return cuts
    flat = ground.to_level(world_points[used])[:, :2]
    gap = np.full((len(cuts), len(used)), np.inf)
    for p, c in enumerate(flat_centres):
        if c is not None:
            gap[p] = np.linalg.norm(flat - c, axis=1)
    claims = np.zeros((len(cuts), len(used)), dtype=bool)
    for p, index in enumerate(cuts):
        claims[p, np.searchsorted(used, index)] = True
    for p in confident:
        claims[p] |= gap[p] <= config.body_radius_m
    # a centre without a finite uncertainty still ranks, behind every placed one
    sure = np.array([min(float(s), 1e3) if s is not None and not np.isnan(s) else 1e3 for s in sigmas])
    spread = ((0.5 * config.body_radius_m) ** 2 + sure ** 2)[:, None]
    cost = np.where(np.isfinite(gap), gap ** 2 / spread + 2.0 * np.log(spread), np.inf)   # -2 ln likelihood
    claimed_cost = np.where(claims, cost, np.inf)
    winner = np.argmin(claimed_cost, axis=0)
    winner = np.where(np.isfinite(claimed_cost.min(axis=0)), winner, -1)  # shared, no claimant placed: no one's
    winner = np.where(claims.sum(axis=0) == 1, np.argmax(claims, axis=0), winner)
    return [used[winner == p] for p in range(len(cuts))]


def write_track_segments(root: str | os.PathLike, sequence: str, tracks: list,
                         calibrations: Mapping[str, StereoCalibration], ground: GroundFrame,
                         read_cloud: Callable[[int], np.ndarray], config: LidarCutConfig | None = None,
                         frames_with_cloud: Collection[int] | None = None) -> dict:
    """Write every track's per-frame cut as ``labels/3d/segment/<seq>/<seq>_<frame:07d>_<tid>.ply`` under
    ``root``; ``read_cloud(frame)`` gives the frame's (N, 3) scene (an exception: the frame is skipped with a
    warning).  ``frames_with_cloud``: the frames that have a scene cloud (None: all); the others — a LiDAR
    sampled at a lower rate than the cameras, PedX's at about half — are skipped with one warning for them
    all.  Returns counts (``segments``, ``points``, ``frames_without_cloud``)."""
    from pedx_graph.data.writer import write_segment

    config = config or LidarCutConfig()
    by_frame: dict[int, list] = {}
    for track in tracks:
        for fr in track.frames:
            by_frame.setdefault(fr.frame, []).append((track.track_id, fr))
    counts = {"segments": 0, "points": 0, "frames_without_cloud": 0}
    absent = sorted(f for f in by_frame if frames_with_cloud is not None and f not in frames_with_cloud)
    if absent:
        log.warning("%s: %d of %d track frames have no scene cloud (the LiDAR sampled less often than the cameras?"
                    " first: %s); no segments cut there", sequence, len(absent), len(by_frame),
                    ", ".join(map(str, absent[:5])))
        counts["frames_without_cloud"] = len(absent)
    missing = set(absent)
    clouded = [f for f in sorted(by_frame) if f not in missing]
    if ground.ground_offset_m is None:
        ground = ground_with_plane(ground, calibrations, _FrameClouds(read_cloud, clouded))
    for frame in clouded:
        try:
            cloud = np.asarray(read_cloud(frame), dtype=float).reshape(-1, 3)
        except Exception as exc:  # noqa: BLE001 - a missing or bad cloud costs this frame its segments only
            log.warning("%s frame %d: no scene cloud (%s); no segments cut", sequence, frame, exc)
            counts["frames_without_cloud"] += 1
            continue
        cuts = [track_frame_indices(fr, calibrations, cloud, ground, config) for _, fr in by_frame[frame]]
        cuts = exclusive_cuts(cuts, cloud, [fr.world_p for _, fr in by_frame[frame]],
                              [fr.depth_sigma_m for _, fr in by_frame[frame]], ground, config)
        for (track_id, fr), index in zip(by_frame[frame], cuts):
            points = cloud[index]
            if len(points):
                write_segment(root, sequence, frame, track_id, points)
                counts["segments"] += 1
                counts["points"] += int(len(points))
    return counts


class _FrameClouds(Mapping):
    """``read_cloud`` over the given frames as a read-only mapping (for :func:`ground_with_plane`)."""

    def __init__(self, read_cloud: Callable[[int], np.ndarray], frames: list[int]):
        self._read, self._frames = read_cloud, list(frames)

    def __getitem__(self, frame: int) -> np.ndarray:
        if frame not in self._frames:
            raise KeyError(frame)
        return self._read(frame)

    def __iter__(self):
        return iter(self._frames)

    def __len__(self) -> int:
        return len(self._frames)
