"""Who is who: group id-less detections into tracks — within a stereo pair, over frames and across pairs.

Entry point::

    associate(detections, calibrations, config=None, clouds=None, ground=None) -> list[DetectedTrack]

``detections``: :class:`~pedx_graph.detections.types.Detection` of every camera and frame (raw-image pixels,
no ids needed; ids in the files are ignored); ``calibrations``: pair name -> :class:`StereoCalibration`
(with the raw K/D when the detections were made on raw images); ``clouds``: optional ``{frame: (N, 3)}`` full
LiDAR scenes (world frame) — a stereo-matched person's centre then comes from its LiDAR cut
(:mod:`pedx_graph.detections.lidar_cut`) when the cut holds ``lidar_min_points`` and agrees with the stereo
centre (far more precise in depth than stereo at range); ``ground``: the sequence's
:class:`~pedx_graph.data.ground.GroundFrame` (derived from the calibrations when None — and from the clouds
when they are given and it has no ground height, :func:`~pedx_graph.detections.lidar_cut.ground_with_plane`;
distances are measured in its ground plane).  Returns :class:`DetectedTrack` s with ids ``"det000001"``, ... in order of first frame, each holding per frame the detections of every camera
that saw the person (raw pixels as read, ``track_id`` set) and the person's 3D centre — what the import
writer turns into PedX-layout label files.

Steps:

1. **Rectify** every detection (:func:`pedx_graph.detections.undistort.rectified`: K, D, R_rect, P_rect).
2. **Duplicates** in one image (a detector reporting a person twice, or a fragment: legs alone) are dropped:
   two detections sharing at least ``min_shared_keypoints`` keypoints whose median distance is below
   ``duplicate_frac`` of the larger one's height keep only the higher score.
3. **Stereo** (per pair and frame, :func:`match_stereo`): a left and a right detection of one person lie on
   the same rectified rows, with a positive disparity giving a depth within the rig's range, and the same
   size.  Over the keypoints present in both (confidence >= ``min_confidence``):

   - row residual ``median(v_l - v_r) / (1.2533 sqrt(2) sigma / sqrt(n))`` over the ``n`` shared keypoints
     (the standard error of a median of differences of two detections), ``sigma = keypoint_sigma_px +
     keypoint_sigma_frac * h``;
   - disparity spread ``1.4826 MAD(u_l - u_r) / (sqrt(2) sigma)`` (a person's points share one depth);
   - size ``log(span_l / span_r) / size_sigma`` (keypoint spans: vertical extents of the shared keypoints);

   a pair is gated out when a residual exceeds ``gate_sigmas``, the disparity is not positive or the depth
   ``f b / median(u_l - u_r)`` lies outside ``[min_depth_m, max_depth_m]``; the mean squared residual is
   the cost; :func:`scipy.optimize.linear_sum_assignment` picks the pairs.  An unmatched detection stays a
   one-image observation.  A matched pair is triangulated at its median disparity (depth uncertainty from the
   disparities' spread, :func:`triangulate_centre`).
4. **Over frames**: one :class:`~pedx_graph.detections.tracker.Tracker` per pair (keypoints in both images
   + the 3D centre, constant-velocity prediction, birth/death, minimum length and score).
5. **Across pairs** (:func:`merge_pair_tracks`): tracks of different pairs whose 3D centres agree are one
   person: over at least ``merge_min_shared_frames`` shared frames (a track's centre between two of its 3D
   frames is interpolated), the median of the horizontal distance
   divided by ``sqrt(sigma_a^2 + sigma_b^2 + merge_distance_m^2)`` (the two centres' depth uncertainties) is
   at most 1; merged greedily, best agreement first, never two tracks of one pair.
6. Tracks whose median horizontal distance from the rig lies outside ``[min_distance_m, max_distance_m]``
   are dropped (the labelled range of the data set; people beyond it are bystanders).
"""
from __future__ import annotations

import dataclasses
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Mapping

import numpy as np
from scipy.optimize import linear_sum_assignment

from pedx_graph.data.ground import GroundFrame, ground_from_calibrations
from pedx_graph.data.types import StereoCalibration
from pedx_graph.detections.lidar_cut import LidarCutConfig, ground_with_plane
from pedx_graph.detections.tracker import Observation, Tracker, TrackerConfig
from pedx_graph.detections.types import Detection
from pedx_graph.detections.undistort import find_camera, rectified

_GATED = 1e9


@dataclass
class AssociationConfig:
    """Stereo matching, duplicates, merging across pairs and the distance range (pixels, metres)."""

    min_confidence: float = 0.1
    """Keypoints with a lower confidence are ignored by the association."""
    min_shared_keypoints: int = 3
    """Two detections are compared only on at least this many keypoints present in both."""
    duplicate_frac: float = 0.1
    """Two detections in one image whose shared keypoints lie within this fraction of the larger one's
    height (median distance) are one person: the lower score is dropped."""
    keypoint_sigma_px: float = 3.0
    """Size-independent part of one detected keypoint's noise per axis, pixels (the rectification error of a
    real pair adds a little)."""
    keypoint_sigma_frac: float = 0.015
    """Size-dependent part: this fraction of the person's image height (detector noise grows with size)."""
    size_sigma: float = 0.12
    """Expected spread of ``log(span_left / span_right)`` for one person (noise, a keypoint missing in one
    image)."""
    gate_sigmas: float = 3.5
    """A stereo pair whose normalised residual (any term) exceeds this is never matched."""
    min_depth_m: float = 1.5
    """Nearest depth a matched pair may have (the rig's range), metres."""
    max_depth_m: float = 80.0
    """Farthest depth a matched pair may have, metres."""
    merge_distance_m: float = 0.8
    """Tracks of two pairs are one person when their centres agree to this, metres, beyond their depth
    uncertainties (step 5)."""
    merge_min_shared_frames: int = 3
    """... over at least this many shared frames."""
    min_distance_m: float = 0.0
    """Tracks whose median horizontal distance from the rig is below this are dropped, metres."""
    max_distance_m: float = 60.0
    """Tracks whose median horizontal distance from the rig is above this are dropped, metres (bystanders
    beyond the labelled range)."""
    lidar_min_points: int = 8
    """A LiDAR cut with at least this many points replaces the stereo centre (when clouds are given) ..."""
    lidar_agreement_m: float = 0.3
    """... when its median lies within ``gate_sigmas`` stereo depth sigmas plus this of the stereo centre, in
    the ground plane, metres."""
    lidar_sigma_m: float = 0.1
    """Uncertainty of a LiDAR centre along the ray (the median of a person's points vs its centre), metres."""
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    """The across-frame tracker of each pair."""
    lidar_cut: LidarCutConfig = field(default_factory=LidarCutConfig)
    """How a person's LiDAR points are cut from a scene cloud (when clouds are given)."""


@dataclass
class DetectedTrackFrame:
    """One person at one frame: the detections of every camera that saw it and its 3D centre."""

    frame: int
    """Frame number."""
    detections: dict[str, Detection]
    """Camera name -> the detection (raw pixels as read, ``track_id`` set to the track's id)."""
    world_p: np.ndarray | None = None
    """(3,) centre of the person in the world (LiDAR) frame, metres (stereo or LiDAR), or None."""
    depth_sigma_m: float = float("inf")
    """Uncertainty of ``world_p`` along the viewing ray, metres."""


@dataclass
class DetectedTrack:
    """One person found in id-less detections: a track id and its frames in increasing order."""

    track_id: str
    """``det000001``, ... in order of first frame (deterministic)."""
    frames: list[DetectedTrackFrame]
    """The frames the person was observed in."""
    pairs: tuple[str, ...]
    """Stereo pairs that saw the person (sorted)."""

    @property
    def mean_score(self) -> float:
        """Mean detection score over every detection of the track."""
        scores = [d.score for fr in self.frames for d in fr.detections.values()]
        return float(np.mean(scores)) if scores else 0.0

    def __len__(self) -> int:
        return len(self.frames)


# ---------------------------------------------------------------------------------------------- helpers

def _usable(uv: np.ndarray, confidence: np.ndarray, min_confidence: float) -> np.ndarray:
    uv = np.where((np.asarray(confidence) >= min_confidence)[:, None], uv, np.nan)
    return uv


def _height(uv: np.ndarray) -> float:
    v = uv[np.all(np.isfinite(uv), axis=1), 1]
    return float(np.ptp(v)) if len(v) >= 2 else 0.0


def drop_duplicates(items: list[tuple[Detection, np.ndarray]], config: AssociationConfig
                    ) -> list[tuple[Detection, np.ndarray]]:
    """The (detection, rectified uv) of one image without duplicates (module docstring, step 2); order kept."""
    order = sorted(range(len(items)), key=lambda i: -items[i][0].score)
    kept: list[int] = []
    for i in order:
        uv_i = items[i][1]
        duplicate = False
        for j in kept:
            uv_j = items[j][1]
            both = np.all(np.isfinite(uv_i), axis=1) & np.all(np.isfinite(uv_j), axis=1)
            if both.sum() < config.min_shared_keypoints:
                continue
            scale = max(_height(uv_i), _height(uv_j), 1.0)
            if np.median(np.linalg.norm(uv_i[both] - uv_j[both], axis=1)) < config.duplicate_frac * scale:
                duplicate = True
                break
        if not duplicate:
            kept.append(i)
    return [items[i] for i in sorted(kept)]


def stereo_cost(uv_left: np.ndarray, uv_right: np.ndarray, calib: StereoCalibration,
                config: AssociationConfig) -> float:
    """Cost of matching a left and a right detection (rectified (K, 2) pixels, unusable keypoints NaN); a
    value >= 1e9 means gated out (module docstring, step 3)."""
    both = np.all(np.isfinite(uv_left), axis=1) & np.all(np.isfinite(uv_right), axis=1)
    if both.sum() < config.min_shared_keypoints:
        return _GATED
    left, right = uv_left[both], uv_right[both]
    height = max(np.ptp(left[:, 1]), np.ptp(right[:, 1]))
    sigma = config.keypoint_sigma_px + config.keypoint_sigma_frac * height
    row = float(np.median(left[:, 1] - right[:, 1])) / (1.2533 * np.sqrt(2.0) * sigma / np.sqrt(len(left)))
    disparity = left[:, 0] - right[:, 0]
    d_med = float(np.median(disparity))
    if d_med <= 0:
        return _GATED
    depth = calib.focal_px * calib.baseline_m / d_med
    if not config.min_depth_m <= depth <= config.max_depth_m:
        return _GATED
    spread = 1.4826 * float(np.median(np.abs(disparity - d_med))) / (np.sqrt(2.0) * sigma)
    span_l, span_r = np.ptp(left[:, 1]), np.ptp(right[:, 1])
    size = float(np.log(max(span_l, 1.0) / max(span_r, 1.0))) / config.size_sigma if min(span_l, span_r) > 4 else 0.0
    terms = np.array([row, spread, size])
    if np.any(np.abs(terms) > config.gate_sigmas):
        return _GATED
    return float(np.mean(terms ** 2))


def triangulate_centre(uv_left: np.ndarray, uv_right: np.ndarray, calib: StereoCalibration,
                       ground: GroundFrame, sigma_disparity_px: float) -> tuple[np.ndarray, float]:
    """(3,) world centre of a matched person (median in the level frame of its keypoints triangulated at the
    median disparity) and its depth uncertainty ``Z^2 / (f b) * 1.2533 s / sqrt(n)`` (the standard error of a
    median of ``n`` disparities), metres; ``s`` = the disparities' robust spread ``1.4826 MAD``, at least
    ``sigma_disparity_px`` (what the detector noise alone gives)."""
    both = np.all(np.isfinite(uv_left), axis=1) & np.all(np.isfinite(uv_right), axis=1)
    left, right = uv_left[both], uv_right[both]
    d_med = float(np.median(left[:, 0] - right[:, 0]))
    P = calib.left_P_rect
    f_u, f_v, c_u, c_v = P[0, 0], P[1, 1], P[0, 2], P[1, 2]
    depth = calib.focal_px * calib.baseline_m / d_med
    rect_p = np.stack([(left[:, 0] - c_u) * depth / f_u, (left[:, 1] - c_v) * depth / f_v,
                       np.full(len(left), depth)], axis=1)
    world_T_rect = np.asarray(calib.world_T_cam, dtype=float).copy()
    world_T_rect[:3, :3] = world_T_rect[:3, :3] @ np.asarray(calib.rect_R_cam).T
    world_p = rect_p @ world_T_rect[:3, :3].T + world_T_rect[:3, 3]
    disparity = left[:, 0] - right[:, 0]
    spread = max(1.4826 * float(np.median(np.abs(disparity - d_med))), sigma_disparity_px)
    sigma = depth ** 2 / (calib.focal_px * calib.baseline_m) * 1.2533 * spread / np.sqrt(max(len(left), 1))
    return ground.median_point(world_p), float(sigma)


def match_stereo(left: list[tuple[Detection, np.ndarray]], right: list[tuple[Detection, np.ndarray]],
                 calib: StereoCalibration, config: AssociationConfig) -> list[tuple[int | None, int | None]]:
    """Pairs ``(left index, right index)`` of one frame's detections of one pair; unmatched detections appear
    with None on the other side.  Gated Hungarian matching on :func:`stereo_cost`."""
    pairs: list[tuple[int | None, int | None]] = []
    used_l, used_r = set(), set()
    if left and right:
        cost = np.array([[stereo_cost(l_uv, r_uv, calib, config) for _, r_uv in right] for _, l_uv in left])
        rows, cols = linear_sum_assignment(cost)
        for r, c in zip(rows, cols):
            if cost[r, c] < _GATED:
                pairs.append((int(r), int(c)))
                used_l.add(int(r))
                used_r.add(int(c))
    pairs += [(i, None) for i in range(len(left)) if i not in used_l]
    pairs += [(None, j) for j in range(len(right)) if j not in used_r]
    return sorted(pairs, key=lambda p: (p[0] is None, p[0] if p[0] is not None else p[1]))


def _camera_centre(calib: StereoCalibration, side: str) -> np.ndarray:
    centre = np.asarray(calib.world_T_cam, dtype=float)[:3, 3].copy()
    if side == "right":
        world_R_rect = np.asarray(calib.world_T_cam)[:3, :3] @ np.asarray(calib.rect_R_cam).T
        centre = centre + world_R_rect[:, 0] * calib.baseline_m
    return centre


# ---------------------------------------------------------------------------------------------- observations

def pair_observations(detections: list[Detection], calib: StereoCalibration, config: AssociationConfig,
                      ground: GroundFrame, clouds: Mapping[int, np.ndarray] | None = None
                      ) -> dict[int, list[Observation]]:
    """``{frame: [Observation]}`` of one pair: rectified, de-duplicated, stereo-matched, triangulated (or
    centred on their LiDAR cut when ``clouds`` holds the frame)."""
    left_name, right_name = calib.name.split("-")
    per_image: dict[tuple[int, str], list[tuple[Detection, np.ndarray]]] = defaultdict(list)
    for det in detections:
        if det.camera not in (left_name, right_name):
            continue
        uv = _usable(rectified(det, calib), det.confidence, config.min_confidence)
        per_image[(det.frame, "left" if det.camera == left_name else "right")].append((det, uv))
    frames = sorted({frame for frame, _ in per_image})
    out: dict[int, list[Observation]] = {}
    sigma_disparity = config.keypoint_sigma_px * np.sqrt(2.0)
    for frame in frames:
        left = drop_duplicates(per_image.get((frame, "left"), []), config)
        right = drop_duplicates(per_image.get((frame, "right"), []), config)
        observations = []
        projections: dict[str, tuple[np.ndarray, np.ndarray]] = {}       # scene cloud in each image, once
        for i, j in match_stereo(left, right, calib, config):
            uv, payload, score = {}, {}, 0.0
            if i is not None:
                uv["left"], payload["left"] = left[i][1], left[i][0]
                score = max(score, left[i][0].score)
            if j is not None:
                uv["right"], payload["right"] = right[j][1], right[j][0]
                score = max(score, right[j][0].score)
            obs = Observation(frame=frame, uv=uv, score=float(score), payload=payload)
            if i is not None and j is not None:
                obs.world_p, obs.depth_sigma_m = triangulate_centre(uv["left"], uv["right"], calib, ground,
                                                                    sigma_disparity)
                obs.world_p_camera = _camera_centre(calib, "left")
                both = np.all(np.isfinite(uv["left"]), axis=1) & np.all(np.isfinite(uv["right"]), axis=1)
                obs.disparity_px = float(np.median(uv["left"][both, 0] - uv["right"][both, 0]))
            if clouds is not None and obs.world_p is not None and frame in clouds:
                _lidar_centre(obs, calib, clouds[frame], ground, config, projections)
            observations.append(obs)
        out[frame] = observations
    return out


def _lidar_centre(obs: Observation, calib: StereoCalibration, cloud: np.ndarray, ground: GroundFrame,
                  config: AssociationConfig, projections: dict) -> None:
    """Replace the observation's centre by the median of its LiDAR cut when the cut is large enough
    (``projections``: side -> the cloud projected into that image, filled on first use)."""
    from pedx_graph.detections.lidar_cut import cut_person, project_cloud

    side = "left" if "left" in obs.uv else "right"
    depth = None
    if obs.world_p is not None:
        depth = float(calib.world_to_rect(obs.world_p)[2])
    cloud = np.asarray(cloud, dtype=float).reshape(-1, 3)
    if side not in projections:
        projections[side] = project_cloud(calib, side, cloud)
    points = cut_person(obs.uv[side], calib, side, cloud, ground, config.lidar_cut, depth_m=depth,
                        projection=projections[side])
    if len(points) < config.lidar_min_points:
        return
    centre = ground.median_point(points)
    # accepted only where it agrees with the stereo centre (a cut that caught an occluder does not)
    offset = np.linalg.norm(ground.to_level(centre)[:2] - ground.to_level(obs.world_p)[:2])
    if offset <= config.gate_sigmas * obs.depth_sigma_m + config.lidar_agreement_m:
        obs.world_p = centre
        obs.world_p_camera = _camera_centre(calib, side)
        obs.depth_sigma_m = config.lidar_sigma_m


# ---------------------------------------------------------------------------------------------- across pairs

def _centres(track: list[Observation]) -> dict[int, tuple[np.ndarray, float]]:
    """Frame -> (3D centre, depth sigma) of every frame of the track between its first and last 3D centre:
    observed, or interpolated linearly in time between the neighbouring ones (with the larger sigma)."""
    known = [(o.frame, o.world_p, min(float(o.depth_sigma_m), 1e3)) for o in track if o.world_p is not None]
    if not known:
        return {}
    frames = np.array([k[0] for k in known], dtype=float)
    points = np.array([k[1] for k in known], dtype=float)
    sigmas = np.array([k[2] for k in known], dtype=float)
    out = {}
    for o in track:
        if not frames[0] <= o.frame <= frames[-1]:
            continue
        j = int(np.searchsorted(frames, o.frame))
        if frames[min(j, len(frames) - 1)] == o.frame:
            out[o.frame] = (points[j], float(sigmas[j]))
            continue
        w = (o.frame - frames[j - 1]) / (frames[j] - frames[j - 1])
        out[o.frame] = ((1 - w) * points[j - 1] + w * points[j], float(max(sigmas[j - 1], sigmas[j])))
    return out


def merge_pair_tracks(pair_tracks: list[tuple[str, list[Observation]]], ground: GroundFrame,
                      config: AssociationConfig) -> list[list[int]]:
    """Groups of indices into ``pair_tracks`` (``(pair name, observations)``) that are one person (module
    docstring, step 5); every index is in exactly one group."""
    centres = [_centres(obs) for _, obs in pair_tracks]
    candidates = []
    for a in range(len(pair_tracks)):
        for b in range(a + 1, len(pair_tracks)):
            if pair_tracks[a][0] == pair_tracks[b][0]:
                continue
            shared = sorted(set(centres[a]) & set(centres[b]))
            if len(shared) < config.merge_min_shared_frames:
                continue
            pa = ground.to_level(np.array([centres[a][f][0] for f in shared]))[:, :2]
            pb = ground.to_level(np.array([centres[b][f][0] for f in shared]))[:, :2]
            sigma = np.sqrt(np.array([centres[a][f][1] ** 2 + centres[b][f][1] ** 2 for f in shared])
                            + config.merge_distance_m ** 2)
            score = float(np.median(np.linalg.norm(pa - pb, axis=1) / sigma))
            if score <= 1.0:
                candidates.append((score, a, b))
    group_of = list(range(len(pair_tracks)))
    members = {i: {i} for i in range(len(pair_tracks))}
    for _, a, b in sorted(candidates):
        ga, gb = group_of[a], group_of[b]
        if ga == gb:
            continue
        pairs_a = {pair_tracks[i][0] for i in members[ga]}
        pairs_b = {pair_tracks[i][0] for i in members[gb]}
        if pairs_a & pairs_b:
            continue                          # never two tracks of one pair in one person
        for i in members[gb]:
            group_of[i] = ga
        members[ga] |= members.pop(gb)
    return [sorted(m) for _, m in sorted(members.items())]


# ---------------------------------------------------------------------------------------------- entry point

def associate(detections: list[Detection], calibrations: Mapping[str, StereoCalibration],
              config: AssociationConfig | None = None, clouds: Mapping[int, np.ndarray] | None = None,
              ground: GroundFrame | None = None) -> list[DetectedTrack]:
    """Tracks with ids from id-less detections (module docstring)."""
    config = config or AssociationConfig()
    ground = ground or ground_from_calibrations(dict(calibrations))
    if clouds is not None:
        ground = ground_with_plane(ground, calibrations, clouds)
    by_pair: dict[str, list[Detection]] = defaultdict(list)
    for det in detections:
        try:
            calib, _ = find_camera(calibrations, det.camera)
        except KeyError:
            continue
        by_pair[calib.name].append(det)
    pair_tracks: list[tuple[str, list[Observation]]] = []
    for pair in sorted(by_pair):
        observations = pair_observations(by_pair[pair], calibrations[pair], config, ground, clouds)
        tracker = Tracker(config.tracker, world_up=ground.world_up)
        for frame in sorted(observations):
            tracker.step(frame, observations[frame])
        pair_tracks += [(pair, track) for track in tracker.tracks()]
    people = []
    for group in merge_pair_tracks(pair_tracks, ground, config):
        frames: dict[int, DetectedTrackFrame] = {}
        for index in group:
            pair, track = pair_tracks[index]
            left_name, right_name = pair.split("-")
            for obs in track:
                entry = frames.setdefault(obs.frame, DetectedTrackFrame(frame=obs.frame, detections={}))
                for side, det in obs.payload.items():
                    entry.detections[left_name if side == "left" else right_name] = det
                if obs.world_p is not None and obs.depth_sigma_m < entry.depth_sigma_m:
                    entry.world_p, entry.depth_sigma_m = obs.world_p, obs.depth_sigma_m
        centres = np.array([fr.world_p for fr in frames.values() if fr.world_p is not None]).reshape(-1, 3)
        if len(centres):
            distance = float(np.median(ground.horizontal_distance(centres)))
            if not config.min_distance_m <= distance <= config.max_distance_m:
                continue
        pairs = tuple(sorted({pair_tracks[i][0] for i in group}))
        people.append((min(frames), pairs, [frames[f] for f in sorted(frames)]))
    people.sort(key=lambda item: (item[0], item[1], sorted(item[2][0].detections)))
    out = []
    for number, (_, pairs, frames) in enumerate(people, start=1):
        track_id = f"det{number:06d}"
        for fr in frames:
            fr.detections = {cam: dataclasses.replace(det, track_id=track_id)
                             for cam, det in sorted(fr.detections.items())}
        out.append(DetectedTrack(track_id=track_id, frames=frames, pairs=pairs))
    return out
