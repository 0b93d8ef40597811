"""Left and right: undo a detector's whole-body left/right confusion, from the direction the person walks.

Detectors often take a person's left for its right on the whole body (every left/right keypoint pair
swapped), most on people seen from behind.  A swapped detection is a mirror image of the body: fitted as it
is, it twists the pose or turns the body around.  A pedestrian faces the way it walks, so once a track's
centres give its walking direction the image order of its left and right torso keypoints is known
wherever the camera sees the person more from the front or the back than from the side.

For each detection of a track at a frame where the person walks at least ``min_speed_mps`` (its velocity:
a line through the track's centres within ``velocity_window_frames``, in the ground plane) in a direction
known to within ``max_direction_deg`` (two standard deviations, from the centres' uncertainty: their
``depth_sigma_m`` along the viewing ray, ``lateral_sigma_m`` across it):

* the expected separation ``e_k`` (rectified px) of each torso pair ``k`` (shoulders, hips): the left and
  the right keypoint of a standing body (:func:`~pedx_graph.body.templates.open_standing_keypoints_3d`, the
  open model) placed at the track's centre facing the walking direction, projected into the detection's
  image;
* the observed separation ``o_k = uv_left_k - uv_right_k`` of the detection's keypoints;
* with ``s_k^2 = 2 sigma^2 + (body_sigma_m f / Z)^2`` (``sigma`` the association's keypoint noise at the
  person's size, ``Z`` its depth: the torso's twist and sway), the log likelihood ratio of "swapped"
  (``o = -e``) over "as it is" (``o = e``) is ``sum_k -2 o_k . e_k / s_k^2``;

(off by default: ``enabled``) a detection whose ratio exceeds ``min_log_odds`` for the walking direction and for it turned either way by
its uncertainty gets its left and right swapped back (keypoints and
confidences; :func:`~pedx_graph.keypoints.mirror_order`).  Seen from the side ``e`` is small and nothing is
decided; a person standing still or walking backwards is not judged either way by the first rule, and the
second is not modelled.
"""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from pedx_graph.body.templates import open_standing_keypoints_3d
from pedx_graph.data.ground import GroundFrame
from pedx_graph.data.types import StereoCalibration
from pedx_graph.detections.undistort import find_camera, rectified
from pedx_graph.keypoints import load_keypoint_set, mirror_index, mirror_order

#: Parts of keypoint names that make a torso pair (the body's own width, not a swinging limb).
_TORSO_NAMES = ("shoulder", "sho", "hip")


@dataclass
class FlipConfig:
    """When a detection's left and right are swapped back (module docstring)."""

    enabled: bool = False
    """Swap back the detections whose left and right the detector confused.  Off by default: on simulated
    scenes not used while building it (benchmark seeds 3-5, no flips), a few walkers judged against their
    walking direction over a third of their frames had 5 % of all detections swapped wrongly
    (docs/detections.md); turn it on for a detector known to flip back views."""
    min_speed_mps: float = 0.4
    """The person's facing is taken from its walking direction only when it walks at least this fast, m/s."""
    velocity_window_frames: int = 3
    """The walking velocity at a frame is a line through the track's centres within this many frames."""
    body_sigma_m: float = 0.05
    """How far a torso keypoint leaves a standing body's across the person (the torso's twist and sway while
    walking), metres."""
    min_log_odds: float = 9.0
    """A detection is swapped back when swapped explains it better than as it is by at least this log
    likelihood ratio (natural log: 9 ~ 8000 to 1)."""
    min_confidence: float = 0.1
    """Keypoints with a lower confidence are not used."""
    lateral_sigma_m: float = 0.15
    """Uncertainty of a track's centre across the viewing ray (its uncertainty along the ray is the centre's
    own ``depth_sigma_m``), metres: with it the walking direction's uncertainty."""
    max_direction_deg: float = 60.0
    """The walking direction must be known to within this (two standard deviations of its angle), degrees;
    a detection is swapped back only when swapped wins at both ends of that range and in its middle."""


@functools.lru_cache(maxsize=None)
def _torso_pairs(keypoint_set: str) -> tuple[tuple[int, int], ...]:
    names = load_keypoint_set(keypoint_set).keypoints
    return tuple((a, b) for a, b in mirror_index(names)
                 if any(part in names[a].lower() for part in _TORSO_NAMES) and "mid" not in names[a].lower())


@functools.lru_cache(maxsize=None)
def _standing(keypoint_set: str) -> np.ndarray:
    """(K, 3) the open model's standing keypoints of the set (x left, y up, z forward), centred on the
    torso pairs' mean."""
    body_p = open_standing_keypoints_3d(keypoint_set)
    pairs = _torso_pairs(keypoint_set)
    torso = body_p[[i for pair in pairs for i in pair]] if pairs else body_p
    return body_p - torso.mean(axis=0)


def _velocity(frames: np.ndarray, centres: np.ndarray, covariances: np.ndarray, frame: int, window: int
              ) -> tuple[np.ndarray, np.ndarray] | None:
    """``((3,) metres per frame, (3, 3) its covariance)`` at ``frame``: the least-squares line through the
    centres within ``window`` frames (``covariances`` (n, 3, 3) each centre's); None with fewer than two
    distinct frames."""
    near = np.abs(frames - frame) <= window
    if near.sum() < 2 or np.ptp(frames[near]) == 0:
        return None
    t = frames[near] - frames[near].mean()
    weights = t / (t ** 2).sum()
    velocity = (weights[:, None] * (centres[near] - centres[near].mean(axis=0))).sum(axis=0)
    return velocity, np.einsum("n,nij->ij", weights ** 2, covariances[near])


def flip_log_odds(uv: np.ndarray, keypoint_set: str, calib: StereoCalibration, side: str, world_centre: np.ndarray,
                  world_forward: np.ndarray, world_up: np.ndarray, keypoint_sigma_px: float,
                  body_sigma_m: float) -> float:
    """Log likelihood ratio of "left and right swapped" over "as it is" of one detection's rectified keypoints
    ``uv`` (K, 2; NaN where absent) of a person at ``world_centre`` facing ``world_forward`` (module
    docstring); 0 when no torso pair is seen."""
    standing = _standing(keypoint_set)
    left_dir = np.cross(world_up, world_forward)
    world_p = world_centre + standing[:, :1] * left_dir + standing[:, 1:2] * world_up + standing[:, 2:3] * world_forward
    projected = calib.project(world_p)[0 if side == "left" else 1]
    depth = float(calib.world_to_rect(np.asarray(world_centre, dtype=float))[2])
    if depth <= 0:
        return 0.0
    model_px = body_sigma_m * calib.focal_px / depth
    total = 0.0
    for a, b in _torso_pairs(keypoint_set):
        if not (np.all(np.isfinite(uv[[a, b]])) and np.all(np.isfinite(projected[[a, b]]))):
            continue
        observed, expected = uv[a] - uv[b], projected[a] - projected[b]
        total += -2.0 * float(observed @ expected) / (2.0 * keypoint_sigma_px ** 2 + model_px ** 2)
    return total


def _turned(forward: np.ndarray, up: np.ndarray, degrees: float) -> np.ndarray:
    """``forward`` turned about ``up`` by ``degrees``."""
    angle = np.radians(degrees)
    return np.cos(angle) * forward + np.sin(angle) * np.cross(up, forward)


def _centre_covariance(fr, calibrations: Mapping[str, StereoCalibration], up: np.ndarray,
                       config: FlipConfig) -> np.ndarray:
    """(3, 3) covariance of a track frame's centre in the ground plane: ``depth_sigma_m`` along the ray from
    the camera of the first pair that saw it, ``lateral_sigma_m`` across."""
    camera = next(iter(sorted(fr.detections)))
    calib, side = find_camera(calibrations, camera)
    ray = np.asarray(fr.world_p, dtype=float) - calib.camera_centre(side)
    ray = ray - (ray @ up) * up
    ray = ray / max(np.linalg.norm(ray), 1e-9)
    flat = np.eye(3) - np.outer(up, up)
    return (fr.depth_sigma_m ** 2 - config.lateral_sigma_m ** 2) * np.outer(ray, ray) + config.lateral_sigma_m ** 2 * flat


def unflip_tracks(tracks: list, calibrations: Mapping[str, StereoCalibration], ground: GroundFrame,
                  config: FlipConfig, keypoint_sigma_px: float, keypoint_sigma_frac: float,
                  frame_interval_s: float) -> tuple[list, int]:
    """The :class:`~pedx_graph.detections.association.DetectedTrack` s with each detection the module docstring
    finds swapped swapped back (a new track list; the detections replaced, never edited), and how many were.
    ``keypoint_sigma_px + keypoint_sigma_frac * h`` is a keypoint's noise for a person ``h`` px tall."""
    if not config.enabled:
        return tracks, 0
    up = np.asarray(ground.world_up, dtype=float)
    out, swapped = [], 0
    for track in tracks:
        known = [fr for fr in track.frames if fr.world_p is not None and np.isfinite(fr.depth_sigma_m)]
        frames = np.array([fr.frame for fr in known], dtype=float)
        centres = np.array([fr.world_p for fr in known], dtype=float).reshape(-1, 3)
        covariances = np.array([_centre_covariance(fr, calibrations, up, config) for fr in known]
                               ).reshape(-1, 3, 3)
        new_frames = []
        for fr in track.frames:
            fit = _velocity(frames, centres, covariances, fr.frame, config.velocity_window_frames) if known else None
            centre = fr.world_p if fr.world_p is not None else (
                centres[int(np.argmin(np.abs(frames - fr.frame)))] if known else None)
            if fit is None or centre is None:
                new_frames.append(fr)
                continue
            velocity, covariance = fit
            level = velocity - (velocity @ up) * up
            speed = float(np.linalg.norm(level))
            if speed / frame_interval_s < config.min_speed_mps:
                new_frames.append(fr)
                continue
            forward = level / speed
            across = np.cross(up, forward)
            spread = 2.0 * np.degrees(np.arctan2(np.sqrt(max(float(across @ covariance @ across), 0.0)), speed))
            if spread > config.max_direction_deg:
                new_frames.append(fr)
                continue
            headings = [_turned(forward, up, angle) for angle in (-spread, 0.0, spread)]
            detections = {}
            for camera, det in fr.detections.items():
                calib, side = find_camera(calibrations, camera)
                uv = np.where((det.confidence >= config.min_confidence)[:, None], rectified(det, calib), np.nan)
                present = uv[np.all(np.isfinite(uv), axis=1)]
                height = float(np.ptp(present[:, 1])) if len(present) >= 2 else 0.0
                odds = min(flip_log_odds(uv, det.keypoint_set, calib, side, np.asarray(centre, dtype=float), heading,
                                         up, keypoint_sigma_px + keypoint_sigma_frac * height, config.body_sigma_m)
                           for heading in headings)
                if odds > config.min_log_odds:
                    order = mirror_order(det.keypoint_set)
                    det = dataclasses.replace(
                        det, image_uv=det.image_uv[order], confidence=det.confidence[order],
                        occluded=None if det.occluded is None else det.occluded[order])
                    swapped += 1
                detections[camera] = det
            new_frames.append(dataclasses.replace(fr, detections=detections))
        out.append(dataclasses.replace(track, frames=new_frames))
    return out, swapped
