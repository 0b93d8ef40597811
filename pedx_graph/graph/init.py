"""Initial values of a track's graph, as the paper initialises (Sec. IV-B).

* translation from the LiDAR instance points (median, robust to mislabeled points), or from the triangulation
  of the labelled keypoints over every camera that labels them (both stereo pairs: a ~1 m baseline on the
  PedX rig) when a frame has no LiDAR points or its points' depth contradicts the keypoints' (a segment that
  is mostly background), or — one camera, no LiDAR — from the body's size
  (:mod:`pedx_graph.graph.monocular`); each frame records which (``TrackInit.depth_source``); the depths are
  smoothed over time along one reference pair's axis when the track's frames are measured by several pairs;
* heading from the LiDAR (or triangulated) trajectory, smoothed over neighbouring frames; at low speed from
  the triangulated torso (left-right shoulder/hip line); the body stands upright (body +Y = the sequence's
  up axis, :class:`~pedx_graph.data.ground.GroundFrame`: derived from the data, never a fixed world axis);
  headings and speeds are measured in the ground plane (the level frame);
* body pose: the template (the pose prior's dominant mean when a prior is given, else zeros);
* shape: betas = 0.

A single-frame track (no trajectory) gets a torso-only orientation search in :mod:`pedx_graph.graph.build`.
"""
from __future__ import annotations

import dataclasses
import warnings
from dataclasses import dataclass

import numpy as np

from pedx_graph.data.ground import GroundFrame
from pedx_graph.data.types import Track, TrackFrame
from pedx_graph.graph.monocular import frame_monocular_depth
from pedx_graph.graph.triangulate import triangulate_views
from pedx_graph.keypoints import PEDX_KEYPOINTS

_IDX = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}
_TORSO_LEFT = (_IDX["lsho"], _IDX["lhip"])
_TORSO_RIGHT = (_IDX["rsho"], _IDX["rhip"])


def world_R_body_from_yaw(yaw: float | np.ndarray, ground: GroundFrame) -> np.ndarray:
    """Upright body orientation (..., 3, 3): body +Y -> ``ground.world_up``, body +Z (forward) -> the level
    direction of heading ``yaw`` (:meth:`GroundFrame.world_R_body_from_yaw`)."""
    return ground.world_R_body_from_yaw(yaw)


def yaw_of(world_R_body: np.ndarray, ground: GroundFrame) -> np.ndarray:
    """Heading angle (radians, level frame) of the body's forward axis projected on the ground plane."""
    return ground.yaw_of(world_R_body)


def triangulate_frame(track: Track, frame: TrackFrame) -> np.ndarray:
    """Triangulate the 18 keypoints of one frame from the rectified stereo pair.

    Returns (18, 3) world points, NaN where the joint is not labelled in both images or the disparity is
    not positive.  Rectified geometry: ``Z = f * b / (u_l - u_r)``, ``X = (u_l - c_x) Z / f``,
    ``Y = (v_l - c_y) Z / f`` in the rectified left frame.
    """
    return _triangulate(track.calibrations[frame.pair], frame)


def _triangulate(calib, frame: TrackFrame) -> np.ndarray:
    """:func:`triangulate_frame` with the frame's calibration."""
    out = np.full((len(PEDX_KEYPOINTS), 3), np.nan)
    if frame.left is None or frame.right is None:
        return out
    f = calib.focal_px
    cx, cy = calib.left_P_rect[0, 2], calib.left_P_rect[1, 2]
    uv_l, uv_r = frame.left.keypoints, frame.right.keypoints
    disparity = uv_l[:, 0] - uv_r[:, 0]
    ok = np.isfinite(disparity) & (disparity > 1e-3)
    if not ok.any():
        return out
    depth = f * calib.baseline_m / disparity[ok]
    rect_p = np.stack([(uv_l[ok, 0] - cx) * depth / f, (uv_l[ok, 1] - cy) * depth / f, depth], axis=-1)
    world_T_rect = np.linalg.inv(calib.rect_T_world)
    out[ok] = rect_p @ world_T_rect[:3, :3].T + world_T_rect[:3, 3]
    return out


@dataclass
class TrackInit:
    """Initial estimate and derived measurements of a track (arrays over the track's frames)."""

    world_R_body: np.ndarray
    """(T, 3, 3) upright root orientations."""
    world_p_centre: np.ndarray
    """(T, 3) body centre (pelvis) estimates in the world frame, metres."""
    heading_yaw: np.ndarray
    """(T,) heading from the trajectory (radians, in the ground frame's level frame); NaN where unknown."""
    speed_mps: np.ndarray
    """(T,) speed of the smoothed trajectory, m/s (0 for a single frame)."""
    lidar_centroid: np.ndarray
    """(T, 3) median of the instance LiDAR points, NaN where a frame has none."""
    times: np.ndarray
    """(T,) seconds."""
    depth_source: list[str] | None = None
    """(T,) what placed each frame in depth (:attr:`FrameMeasurements.depth_source`); None: not recorded."""
    heading_sigma_rad: np.ndarray | None = None
    """(T,) standard deviation of ``heading_yaw`` from the uncertainty of the trajectory's depth trend
    (LiDAR or stereo depth), radians (inf where unknown); None: not estimated."""


def _lidar_centroid(frame: TrackFrame, ground: GroundFrame) -> np.ndarray:
    """Median (in the level frame, :meth:`GroundFrame.median_point`) of the frame's finite instance LiDAR
    points (3,), NaN when it has fewer than 3."""
    pts = np.asarray(frame.world_lidar_points, dtype=float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    return ground.median_point(pts) if len(pts) >= 3 else np.full(3, np.nan)


def _smoothed_velocity(times: np.ndarray, points: np.ndarray, half_window_s: float) -> np.ndarray:
    """Velocity (T, 2) of the horizontal trajectory (``points`` (T, 3) in the level frame: z along the derived
    up) by a local linear fit; NaN where undetermined."""
    vel = np.full((len(times), 2), np.nan)
    ok = np.all(np.isfinite(points[:, :2]), axis=1)
    for i in range(len(times)):
        sel = ok & (np.abs(times - times[i]) <= half_window_s)
        if sel.sum() < 2:
            continue
        dt = times[sel] - times[sel].mean()
        denom = float(dt @ dt)
        if denom < 1e-9:
            continue
        xy = points[sel, :2] - points[sel, :2].mean(axis=0)
        vel[i] = dt @ xy / denom
    return vel


def _centre_pixel(frame: TrackFrame) -> tuple[np.ndarray, str] | None:
    """Image position of the body centre: the hips' mid-point (else the torso joints' mean) in the left
    image, else in the right image; returns (uv, "left"|"right") or None."""
    for view, side in ((frame.left, "left"), (frame.right, "right")):
        if view is None:
            continue
        kp = view.keypoints
        hips = kp[[_IDX["lhip"], _IDX["rhip"]]]
        if np.all(np.isfinite(hips)):
            return hips.mean(axis=0), side
        torso = kp[[_IDX["lsho"], _IDX["rsho"], _IDX["lhip"], _IDX["rhip"]]]
        torso = torso[np.all(np.isfinite(torso), axis=1)]
        if len(torso):
            return torso.mean(axis=0), side
    return None


def _back_project(calib, uv: np.ndarray, side: str, depth: float) -> np.ndarray:
    """World point at rectified depth ``depth`` on the ray of pixel ``uv`` of the left/right image."""
    f = calib.focal_px
    cx, cy = calib.left_P_rect[0, 2], calib.left_P_rect[1, 2]
    shift = calib.baseline_m if side == "right" else 0.0     # right camera centre at +b along rect x
    rect_p = np.array([(uv[0] - cx) * depth / f + shift, (uv[1] - cy) * depth / f, depth])
    world_T_rect = np.linalg.inv(calib.rect_T_world)
    return world_T_rect[:3, :3] @ rect_p + world_T_rect[:3, 3]


def _median_filter_nan(x: np.ndarray, half_window: int) -> np.ndarray:
    """Running median over +-half_window samples, ignoring NaN (NaN stays NaN)."""
    out = x.copy()
    for i in np.flatnonzero(np.isfinite(x)):
        window = x[max(0, i - half_window): i + half_window + 1]
        out[i] = np.median(window[np.isfinite(window)])
    return out


def _local_linear(times: np.ndarray, obs: np.ndarray, sigma: np.ndarray, half_window_s: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Weighted local-linear fit (weights 1/sigma^2) of ``obs`` over +-half_window_s around every time;
    NaN observations are skipped; a window with one observation gives that value (or the nearest one).
    Returns the fitted values (T,) and the standard deviation of the fitted slope (T,; inf when the window
    does not determine a slope), from the fit's covariance ``(A^T W A)^-1``."""
    ok = np.isfinite(obs) & np.isfinite(sigma)
    out = np.empty(len(times))
    slope_sigma = np.full(len(times), np.inf)
    for i, t in enumerate(times):
        sel = ok & (np.abs(times - t) <= half_window_s)
        if sel.sum() == 0:
            j = np.flatnonzero(ok)[np.argmin(np.abs(times[ok] - t))]
            out[i] = obs[j]
            continue
        w = 1.0 / sigma[sel] ** 2
        dt = times[sel] - t
        if sel.sum() == 1 or np.ptp(dt) < 1e-9:
            out[i] = float(np.sum(w * obs[sel]) / np.sum(w))
            continue
        a = np.stack([np.ones_like(dt), dt], axis=1) * np.sqrt(w)[:, None]
        coef, *_ = np.linalg.lstsq(a, obs[sel] * np.sqrt(w), rcond=None)
        out[i] = float(coef[0])
        slope_sigma[i] = float(np.sqrt(np.linalg.inv(a.T @ a)[1, 1]))
    return out, slope_sigma


def _reference_depth_maps(measurements: list, centroids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame ``(offset, gain)`` (T,) mapping its depth measured along its own pair's rectified axis to
    the depth along the reference pair's axis (the pair most frames use), ``ref = offset + gain * own``:
    exact on the frame's centre ray (depths along two axes are affine in each other on one ray); a frame
    without a centre pixel is shifted by its LiDAR centroid's depth difference.  ``(0, 1)`` for the
    reference pair's own frames, and where the ray runs nearly across the reference axis (gain < 0.2)."""
    n = len(measurements)
    offset, gain = np.zeros(n), np.ones(n)
    names = [m.calibration.name for m in measurements]
    ref_name = max(dict.fromkeys(names), key=names.count)
    ref = next(m.calibration for m in measurements if m.calibration.name == ref_name)
    for i, m in enumerate(measurements):
        if names[i] == ref_name:
            continue
        if m.centre_pixel is not None:
            near = ref.world_to_rect(_back_project(m.calibration, m.centre_pixel[0], m.centre_pixel[1], 0.0))[2]
            far = ref.world_to_rect(_back_project(m.calibration, m.centre_pixel[0], m.centre_pixel[1], 1.0))[2]
            if far - near >= 0.2:
                offset[i], gain[i] = near, far - near
        elif np.all(np.isfinite(centroids[i])):
            offset[i] = ref.world_to_rect(centroids[i])[2] - m.calibration.world_to_rect(centroids[i])[2]
    return offset, gain


@dataclass
class FrameMeasurements:
    """What the initialisation measures in one frame on its own (:func:`measure_frame`); the streaming
    estimator keeps them per frame instead of re-measuring its window of recent frames every frame."""

    time: float
    """Seconds."""
    calibration: object
    """The frame's :class:`~pedx_graph.data.types.StereoCalibration`."""
    lidar_centroid: np.ndarray
    """(3,) median of the instance LiDAR points, NaN when the frame has fewer than 3."""
    lidar_depth: float
    """Rectified depth of ``lidar_centroid`` plus the surface offset, metres; NaN without points."""
    stereo_depth: float
    """Median rectified depth of the joints triangulated from both images, metres; NaN when none."""
    stereo_sigma: float
    """Standard deviation of ``stereo_depth`` (disparity noise), metres; NaN when none."""
    centre_pixel: tuple | None
    """``(uv, "left"|"right")`` of the body centre in the image (:func:`_centre_pixel`), or None."""
    torso_yaw: float
    """Facing (radians, level frame) from the triangulated shoulders / hips (forward = left x up); NaN when
    unknown."""
    placeable: bool
    """The frame can place the pedestrian on its own (>= 3 LiDAR points, a triangulated torso joint or a
    body-size depth)."""
    size_depth: float = float("nan")
    """Rectified depth of the body centre from the body's size in one image (:mod:`pedx_graph.graph.monocular`),
    metres; NaN when not needed (LiDAR or triangulation place the frame) or not available."""
    size_sigma: float = float("nan")
    """Standard deviation of ``size_depth``, metres (mostly the person's unknown size: the same every frame)."""
    depth_source: str = "none"
    """What places the frame in depth: ``lidar``, ``stereo`` (one pair), ``multi_view`` (cameras of several
    pairs), ``body_size`` (one camera, no LiDAR) or ``none``."""
    stereo_source: str = "none"
    """``stereo`` or ``multi_view`` when ``stereo_depth`` is known (what places the frame if its LiDAR depth
    is refused), else ``none``."""


def _effective_baseline(frame: TrackFrame, calibrations, world_p: np.ndarray, all_views: bool) -> float:
    """The widest separation, across the viewing ray to ``world_p`` (3,), of the optical centres of the cameras
    labelling ``frame``, metres (the in-pair baseline for one pair; ~1 m for both PedX pairs)."""
    centres = []
    for pair, side, _ in frame.labelled_views(all_views):
        centres.append(calibrations[pair].camera_centre(side))
    centres = np.asarray(centres)
    ray = world_p - centres.mean(axis=0)
    ray = ray / max(float(np.linalg.norm(ray)), 1e-9)
    across = centres - np.outer(centres @ ray, ray)
    diffs = across[:, None] - across[None]
    return float(np.max(np.linalg.norm(diffs, axis=-1))) if len(centres) > 1 else 0.0


def measure_frame(calibrations, frame: TrackFrame, ground: GroundFrame, surface_offset_m: float = 0.10,
                  stereo_px: float = 3.0, *, size_prior=None, all_views: bool = True,
                  sigma_px: float | np.ndarray = 3.0, occluded_sigma_px: float = 12.0) -> FrameMeasurements:
    """The per-frame measurements of :func:`initialise_track` (see its docstring for the parameters).

    ``calibrations``: the track's stereo pairs by name (``Track.calibrations``); ``size_prior``: a
    :class:`~pedx_graph.graph.monocular.BodySizePrior` for frames that neither LiDAR nor two cameras place
    (None: such frames stay unplaced); ``all_views``: triangulate over every labelled camera (else the
    primary pair's only); ``sigma_px`` / ``occluded_sigma_px``: click noise for the body-size depth.
    Measures the 18 PedX rows only (a detector track's fit layout has more: :meth:`TrackFrame.pedx_rows`).
    """
    frame = frame.pedx_rows()
    calib = calibrations[frame.pair]
    centroid = _lidar_centroid(frame, ground)
    lidar_depth = float(calib.world_to_rect(centroid)[2] + surface_offset_m) if np.all(np.isfinite(centroid)) \
        else float("nan")
    tri = triangulate_views(frame, calibrations, all_pairs=all_views, visible_only=True)
    ok = np.all(np.isfinite(tri), axis=1)
    stereo_depth = stereo_sigma = float("nan")
    source = "lidar" if np.isfinite(lidar_depth) else "none"
    stereo_source = "none"
    if ok.any():
        z = float(np.median(calib.world_to_rect(tri[ok])[:, 2]))
        stereo_depth = z
        baseline = _effective_baseline(frame, calibrations, np.median(tri[ok], axis=0), all_views)
        stereo_sigma = max(0.2, z * z / (calib.focal_px * max(baseline, 1e-3)) * stereo_px / np.sqrt(ok.sum()))
        stereo_source = "multi_view" if len({p for p, _, _ in frame.labelled_views(all_views)}) > 1 else "stereo"
        if source == "none":
            source = stereo_source
    with np.errstate(invalid="ignore"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)      # all-NaN rows: no torso this frame
            left = np.nanmean(tri[list(_TORSO_LEFT)], axis=0) - np.nanmean(tri[list(_TORSO_RIGHT)], axis=0)
    level_left = ground.level_directions(left)
    torso_yaw = float(np.arctan2(-level_left[0], level_left[1]))   # forward = (l_y, -l_x) for left = (l_x, l_y)
    torso = tri[list(_TORSO_LEFT + _TORSO_RIGHT)]
    placeable = bool(np.all(np.isfinite(centroid)) or np.isfinite(torso).any())
    centre_pixel = _centre_pixel(frame)
    size_depth = size_sigma = float("nan")
    if not placeable and not np.isfinite(stereo_depth) and size_prior is not None:
        views = frame if all_views else dataclasses.replace(frame, other_views={})
        est = frame_monocular_depth(views, calibrations, size_prior,
                                    world_up=ground.world_up, sigma_px=sigma_px,
                                    occluded_sigma_px=occluded_sigma_px)
        if est is not None:
            calib = calibrations[est.pair]
            size_depth, size_sigma = est.depth_m, est.sigma_m
            centre_pixel = (est.centre_uv, est.side)
            placeable, source = True, "body_size"
    return FrameMeasurements(time=float(frame.timestamp), calibration=calib, lidar_centroid=centroid,
                             lidar_depth=lidar_depth, stereo_depth=stereo_depth, stereo_sigma=stereo_sigma,
                             centre_pixel=centre_pixel, torso_yaw=torso_yaw, placeable=placeable,
                             size_depth=size_depth, size_sigma=size_sigma, depth_source=source,
                             stereo_source=stereo_source)


def initialise_track(track: Track, *, surface_offset_m: float = 0.10, half_window_s: float = 0.35,
                     min_speed_mps: float = 0.3, lidar_sigma_m: float = 0.15, stereo_px: float = 3.0,
                     depth_window_s: float = 1.0, size_prior=None, all_views: bool = True,
                     sigma_px: float | np.ndarray = 3.0, occluded_sigma_px: float = 12.0) -> TrackInit:
    """Initial orientation and centre (pelvis) of every frame of ``track``.

    Centre: on the camera ray of the labelled hips (so the image position is right), at a depth smoothed
    over time (weighted local-linear fit over +-``depth_window_s``) from per-frame measurements: the
    instance's LiDAR points plus ``surface_offset_m`` (the visible surface is in front of the pelvis;
    ``lidar_sigma_m``), else the median stereo depth of the joints visible in both images (sigma from
    ``stereo_px`` of disparity noise).  Stereo disparity of hand-clicked keypoints is poor at range (a few
    pixels of independent click noise are metres at 30 m), so LiDAR dominates where it exists, but frames
    without points follow the stereo trend instead of a flat extrapolation (which, through the heading
    taken from the same trajectory, used to lock walking-towards-the-camera tracks at a wrong depth).
    A frame seen by one camera without LiDAR points takes the body-size depth (``size_prior``,
    :mod:`pedx_graph.graph.monocular`) with its sigma; a track of such frames only is still placed.

    The per-frame part is :func:`measure_frame`, the rest :func:`initialise_from_measurements`.
    """
    measurements = [measure_frame(track.calibrations, fr, track.ground, surface_offset_m, stereo_px,
                                  size_prior=size_prior, all_views=all_views, sigma_px=sigma_px,
                                  occluded_sigma_px=occluded_sigma_px)
                    for fr in track.frames]
    return initialise_from_measurements(measurements, track.ground, f"{track.sequence}/{track.tracking_id}",
                                        half_window_s=half_window_s, min_speed_mps=min_speed_mps,
                                        lidar_sigma_m=lidar_sigma_m, depth_window_s=depth_window_s)


def initialise_from_measurements(measurements: list[FrameMeasurements], ground: GroundFrame, name: str = "", *,
                                 half_window_s: float = 0.35, min_speed_mps: float = 0.3,
                                 lidar_sigma_m: float = 0.15, depth_window_s: float = 1.0,
                                 lidar_stereo_gate: float = 4.0) -> TrackInit:
    """:func:`initialise_track` from the frames' :class:`FrameMeasurements` and the sequence's ground frame
    (``name``: for the errors).  ``lidar_stereo_gate``: a frame's LiDAR depth farther than this many
    standard deviations (``hypot(lidar_sigma_m, stereo_sigma)``) from its keypoints' stereo depth is refused
    and the frame placed by stereo: its points are mostly not the person's (a polygon or a detection's hull
    that caught the background or an occluder) — unless as many of the track's frames disagree as agree:
    then the keypoints or the calibration are what is off, and LiDAR keeps the lead."""
    n = len(measurements)
    times = np.array([m.time for m in measurements], dtype=float)
    centroids = np.array([m.lidar_centroid for m in measurements], dtype=float).reshape(n, 3)

    # Per-frame depth measurements with their standard deviations: LiDAR (running median against stray
    # clusters) where the frame has points that agree with the keypoints' stereo depth, else the median
    # stereo depth of the joints visible in both images (sigma from the disparity noise: Z^2 / (f b) *
    # sigma_px / sqrt(n)).
    lidar_depth = np.array([m.lidar_depth for m in measurements], dtype=float)
    stereo_depth = np.array([m.stereo_depth for m in measurements], dtype=float)
    stereo_sigma = np.array([m.stereo_sigma for m in measurements], dtype=float)
    with np.errstate(invalid="ignore"):
        gap = np.abs(lidar_depth - stereo_depth) / np.hypot(lidar_sigma_m, stereo_sigma)
    refused = gap > lidar_stereo_gate
    if refused.sum() >= np.sum(gap <= lidar_stereo_gate):
        refused[:] = False          # most frames disagree: the keypoints (or the calibration) are what is off
    lidar_depth[refused] = np.nan
    centroids[refused] = np.nan
    sources = [m.stereo_source if gone else m.depth_source for m, gone in zip(measurements, refused)]
    lidar_depth = _median_filter_nan(lidar_depth, half_window=2)
    size_depth = np.array([m.size_depth for m in measurements], dtype=float)
    size_sigma = np.array([m.size_sigma for m in measurements], dtype=float)
    depth_obs = np.where(np.isfinite(lidar_depth), lidar_depth, np.where(np.isfinite(stereo_depth), stereo_depth,
                                                                         size_depth))
    depth_sigma = np.where(np.isfinite(lidar_depth), lidar_sigma_m, np.where(np.isfinite(stereo_depth),
                                                                             stereo_sigma, size_sigma))
    good = np.isfinite(depth_obs)
    if not good.any():
        raise ValueError(f"track {name}: no LiDAR points, no keypoint seen by two cameras and no body-size "
                         "depth to place the pedestrian")
    # Each frame's depth is measured along its own pair's rectified axis; a track seen by several pairs
    # (the PedX pairs' axes are ~30 degrees apart) is smoothed along one reference axis (the pair most of
    # its frames use: depth along a fixed axis is linear in time for a straight walk), then each frame's
    # depth is read back on its own ray.
    offset, gain = _reference_depth_maps(measurements, centroids)
    depth_ref, depth_rate_sigma = _local_linear(times, offset + gain * depth_obs, np.abs(gain) * depth_sigma,
                                                depth_window_s)
    depth = (depth_ref - offset) / gain

    centre = np.full((n, 3), np.nan)
    for i, m in enumerate(measurements):
        if m.centre_pixel is not None:
            centre[i] = _back_project(m.calibration, m.centre_pixel[0], m.centre_pixel[1], depth[i])
        elif np.all(np.isfinite(centroids[i])):
            centre[i] = centroids[i]
    missing = ~np.all(np.isfinite(centre), axis=1)
    if missing.all():
        raise ValueError(f"track {name}: nothing places the pedestrian")
    if missing.any():          # interpolate over frames with neither labels nor points
        known = np.flatnonzero(~missing)
        for axis in range(3):
            centre[missing, axis] = np.interp(times[missing], times[known], centre[known, axis])

    level_centre = ground.to_level(centre)
    vel = _smoothed_velocity(times, level_centre, half_window_s)
    speed = np.linalg.norm(np.nan_to_num(vel), axis=1)
    heading = np.where(np.isfinite(vel[:, 0]), np.arctan2(vel[:, 1], vel[:, 0]), np.nan)
    # Uncertainty of that heading: the trajectory's depth trend is uncertain by depth_rate_sigma (m/s)
    # along the horizontal viewing ray (the image pins the lateral position); its component across the
    # direction of motion turns the heading by ~ sigma_across / speed.
    heading_sigma = np.full(n, np.inf)
    for i, m in enumerate(measurements):
        if not (np.isfinite(heading[i]) and speed[i] > 0):
            continue
        camera = ground.to_level(m.calibration.camera_centre("left"))
        ray = level_centre[i, :2] - camera[:2]
        ray = ray / max(float(np.hypot(*ray)), 1e-9)
        sin_across = abs(ray[0] * np.sin(heading[i]) - ray[1] * np.cos(heading[i]))
        heading_sigma[i] = float(np.arctan2(depth_rate_sigma[i] * sin_across, speed[i]))

    # Torso direction (body left = +X) from the triangulated shoulders/hips (measure_frame).
    torso_yaw = np.array([m.torso_yaw for m in measurements], dtype=float)
    yaw = np.where(speed >= min_speed_mps, heading, np.nan)
    use_torso = ~np.isfinite(yaw) & np.isfinite(torso_yaw)
    yaw[use_torso] = torso_yaw[use_torso]
    if not np.isfinite(yaw).any():
        yaw[:] = np.where(np.isfinite(heading), heading, 0.0)
    else:                                # carry the nearest known heading into unknown frames
        known = np.flatnonzero(np.isfinite(yaw))
        for i in np.flatnonzero(~np.isfinite(yaw)):
            yaw[i] = yaw[known[np.argmin(np.abs(known - i))]]
    return TrackInit(world_R_body=world_R_body_from_yaw(yaw, ground), world_p_centre=centre, heading_yaw=heading,
                     speed_mps=speed, lidar_centroid=centroids, times=times, heading_sigma_rad=heading_sigma,
                     depth_source=sources)
