"""Baseline "Triangulation" (paper Sec. V): the labelled 2D keypoints triangulated from the stereo pair.

No body model is fitted.  For each frame, a keypoint flagged *visible in both* rectified images is
triangulated by :func:`pedx_graph.graph.init.triangulate_frame` (rectified geometry, rect = rectified left
camera frame, pixels and metres)::

    d = u_l - u_r,   Z = f b / d,   X = (u_l - c_x) Z / f,   Y = (v_l - c_y) Z / f,
    world_p = world_T_rect @ [X, Y, Z, 1]

Every other keypoint (occluded in either image, not labelled, or ``d <= 0``) is not triangulable and
starts as NaN.  So that the evaluation can score every frame, those keypoints are then **filled**
(:func:`fill_missing_keypoints`), and the filled ones are counted in the result's extra fields:

1. ``temporal_fill``: the joint's value in the nearest frame of the track that has it (the previous frame on
   a tie), moved by the frame-to-frame displacement of the body (mean displacement of the keypoints both
   frames measured; the initial centre estimate of :func:`pedx_graph.graph.init.initialise_track` when they
   share none);
2. ``body_fill``: a joint the whole track never measured is placed at its mean offset from the hip midpoint
   in the body model's standing pose (:data:`STANDING_BODY_POSE`, betas 0), rotated by the frame's upright
   heading from :func:`~pedx_graph.graph.init.initialise_track`.

The result is a :class:`~pedx_graph.solvers.fit.TrackResult` whose only meaningful field is
``world_keypoints`` (written as ``keypoints_3d``): ``pose`` and ``betas`` are zeros, ``trans`` is the hip
midpoint of the output keypoints, and ``extra_track["keypoints_only"]`` is True.
"""
from __future__ import annotations

import time
import warnings

import numpy as np

from pedx_graph.data.types import Track
from pedx_graph.graph.init import initialise_track, triangulate_frame
from pedx_graph.keypoints import PEDX_KEYPOINTS

NUM_KEYPOINTS = len(PEDX_KEYPOINTS)
_IDX = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}
LHIP, RHIP = _IDX["lhip"], _IDX["rhip"]

#: Where each output keypoint came from (codes stored in the per-keypoint source arrays).
KEYPOINT_SOURCES: tuple[str, ...] = ("triangulated", "disparity", "median_depth", "temporal_fill", "body_fill")
SRC_TRIANGULATED, SRC_DISPARITY, SRC_MEDIAN_DEPTH, SRC_TEMPORAL_FILL, SRC_BODY_FILL = range(5)
#: Code of a keypoint that is still missing (never returned by :func:`fill_missing_keypoints`).
SRC_MISSING = -1


def _standing_body_pose() -> np.ndarray:
    """69-d SMPL body pose with the arms 70 degrees down from the T-pose (shoulders about body z)."""
    body_pose = np.zeros(69)
    angle = np.deg2rad(70.0)
    body_pose[3 * (16 - 1) + 2] = -angle      # left shoulder: body +X (left arm) rotated towards -Y
    body_pose[3 * (17 - 1) + 2] = angle       # right shoulder: body -X rotated towards -Y
    return body_pose


#: Body pose (69,) whose keypoint offsets fill joints a track never measured: standing, arms down.
STANDING_BODY_POSE = _standing_body_pose()


def visible_in_both(track: Track, frame_index: int) -> np.ndarray:
    """(18,) bool: the keypoint is flagged visible in the left and in the right image of that frame."""
    fr = track.frames[frame_index]
    if fr.left is None or fr.right is None:
        return np.zeros(NUM_KEYPOINTS, dtype=bool)
    return (np.asarray(fr.left.visible, bool) & fr.left.labelled
            & np.asarray(fr.right.visible, bool) & fr.right.labelled)


def triangulate_visible(track: Track) -> tuple[np.ndarray, np.ndarray]:
    """World keypoints (T, 18, 3) of the joints visible in both images (NaN elsewhere), and source codes (T, 18)."""
    n = len(track.frames)
    out = np.full((n, NUM_KEYPOINTS, 3), np.nan)
    for i, fr in enumerate(track.frames):
        tri = triangulate_frame(track, fr)
        use = visible_in_both(track, i) & np.all(np.isfinite(tri), axis=1)
        out[i, use] = tri[use]
    source = np.where(np.all(np.isfinite(out), axis=2), SRC_TRIANGULATED, SRC_MISSING).astype(np.int8)
    return out, source


def standing_offsets(model) -> np.ndarray:
    """(18, 3) keypoint offsets from the hip midpoint in the body frame (standing pose, betas 0), metres."""
    pose = np.concatenate([np.zeros(3), STANDING_BODY_POSE])
    kp = np.asarray(model.keypoints(pose, np.zeros(model.num_betas), np.zeros(3)), dtype=float)
    return kp - 0.5 * (kp[LHIP] + kp[RHIP])


def fill_missing_keypoints(track: Track, world_keypoints: np.ndarray, source: np.ndarray,
                           model) -> tuple[np.ndarray, np.ndarray]:
    """Fill the NaN keypoints of ``world_keypoints`` (T, 18, 3) so every frame can be evaluated.

    Temporal fill first, body-offset fill for joints the track never measured (see the module
    docstring).  ``source`` (T, 18) holds the codes of the measured keypoints (``SRC_MISSING`` where NaN);
    returns the filled copy and the updated codes.  ``model`` is a ``BodyModel`` (used only for the
    body-offset fill).  Raises ValueError when a frame cannot be placed at all (no keypoint and no LiDAR
    point in the whole track).
    """
    measured = np.all(np.isfinite(world_keypoints), axis=2)
    filled = world_keypoints.copy()
    source = source.copy()
    n = len(track.frames)
    if measured.all():
        return filled, source
    init = None

    def centres():
        nonlocal init
        if init is None:
            with warnings.catch_warnings():       # all-NaN torso slices of frames without stereo pairs
                warnings.simplefilter("ignore", RuntimeWarning)
                init = initialise_track(track)
        return init

    # 1. temporal: nearest frame that measured the joint, moved by the body's displacement.
    for i, k in zip(*np.nonzero(~measured)):
        have = np.flatnonzero(measured[:, k])
        if have.size == 0:
            continue
        dist = np.abs(have - i)
        j = int(have[np.argmin(dist + 0.5 * (have > i))])        # nearest; the previous one on a tie
        common = measured[i] & measured[j]
        if common.any():
            shift = (world_keypoints[i, common] - world_keypoints[j, common]).mean(axis=0)
        else:
            shift = centres().world_p_centre[i] - centres().world_p_centre[j]
        filled[i, k] = world_keypoints[j, k] + shift
        source[i, k] = SRC_TEMPORAL_FILL
    # 2. body offset: joints never measured in the track.
    never = ~measured.any(axis=0)
    if never.any():
        offsets = standing_offsets(model)
        rot = centres().world_R_body
        for i in range(n):
            hips = filled[i, [LHIP, RHIP]]
            anchor = hips.mean(axis=0) if np.all(np.isfinite(hips)) else centres().world_p_centre[i]
            filled[i, never] = anchor + offsets[never] @ rot[i].T
            source[i, never] = SRC_BODY_FILL
    return filled, source


def keypoints_only_result(track: Track, world_keypoints: np.ndarray, source: np.ndarray, solver: str,
                          seconds: float, num_betas: int = 10):
    """A :class:`TrackResult` carrying only keypoints: pose/betas zeros, trans = hip midpoint (see module doc).

    Per-frame extras: ``keypoint_source`` (18 names from :data:`KEYPOINT_SOURCES`) and ``filled_keypoints``
    (count); per-track extras: ``keypoints_only`` and the number of keypoints of each source.
    """
    from pedx_graph.solvers.fit import TrackResult

    if not np.all(np.isfinite(world_keypoints)):
        raise ValueError(f"track {track.sequence}/{track.tracking_id}: keypoints left unfilled")
    n = len(track.frames)
    filled_codes = (SRC_TEMPORAL_FILL, SRC_BODY_FILL)
    per_frame = [{"keypoint_source": [KEYPOINT_SOURCES[c] for c in source[i]],
                  "filled_keypoints": int(np.isin(source[i], filled_codes).sum())} for i in range(n)]
    counts = {f"keypoints_{name}": int((source == code).sum()) for code, name in enumerate(KEYPOINT_SOURCES)}
    extra_track = {"keypoints_only": True, "keypoints_filled": int(np.isin(source, filled_codes).sum()),
                   "keypoints_total": int(source.size), **counts}
    trans = 0.5 * (world_keypoints[:, LHIP] + world_keypoints[:, RHIP])
    return TrackResult(sequence=track.sequence, tracking_id=track.tracking_id,
                       frames=[fr.frame for fr in track.frames], pose=np.zeros((n, 72)),
                       betas=np.zeros(num_betas), trans=trans, world_keypoints=world_keypoints,
                       final_error=0.0, initial_error=0.0, iterations=0, seconds=seconds, solver=solver,
                       extra_per_frame=per_frame, extra_track=extra_track)


def triangulation_baseline(track: Track, model):
    """Run the triangulation baseline on one track: a keypoints-only :class:`TrackResult` (module docstring).

    ``final_error``/``initial_error`` are 0 and ``iterations`` 0: nothing is optimised.
    """
    if len(track.frames) == 0:
        raise ValueError(f"track {track.sequence}/{track.tracking_id} has no frames")
    t0 = time.perf_counter()
    world_keypoints, source = triangulate_visible(track)
    world_keypoints, source = fill_missing_keypoints(track, world_keypoints, source, model)
    return keypoints_only_result(track, world_keypoints, source, "baseline-triangulation",
                                 time.perf_counter() - t0, model.num_betas)
