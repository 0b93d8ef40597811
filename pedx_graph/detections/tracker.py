"""Across frames: a multi-person tracker over one stereo pair's observations (Hungarian matching, birth, death).

An :class:`Observation` is what :mod:`pedx_graph.detections.association` makes of one person at one frame in
one pair: its rectified keypoints in the left and/or right image and, when the two images were matched (or a
LiDAR cut gave a depth), a 3D centre in the world (LiDAR) frame with its depth uncertainty along the viewing
ray.  :class:`Tracker` links them over frames:

* **prediction**: constant velocity, per image side in pixels per frame and in 3D in metres per frame (both
  smoothed, ``TrackerConfig.velocity_smoothing``);
* **cost** of a (track, observation) pair = the mean of the squared normalised residuals available:

  - keypoints, per image side both carry: the median over shared keypoints of ``|uv_pred - uv_obs|``
    divided by ``sigma_2d = keypoint_sigma_px + motion_frac * h * sqrt(df) * frame_interval_s / 0.1 s``
    (:func:`image_sigma_px`; ``h`` the person's image height in pixels, ``df`` the frames since the track's
    last observation on that side: how far limbs and an unknown walking velocity move the keypoints grows with
    the time between frames), and with ``size_sigma`` > 0
    the log ratio of the shared keypoints' vertical spans divided by it;
  - 3D centre, when both have one: the residual split along the viewing ray (divided by the two depth
    uncertainties and the motion noise, added in quadrature) and across it (divided by
    ``lateral_sigma_m`` and the motion noise) — stereo depth is poor at range, bearings are not;
  - LiDAR range, when the track and the observation have one (``range_sigma_m``; with ``range_claims`` left
    out where it is the range of someone else the tracker follows, missed at this frame, in front);

  a pair is *gated out* (never matched) when any normalised residual exceeds ``gate_sigmas`` or when no
  image side and no 3D centre are shared, or when the boxes of every shared side overlap less than
  ``min_box_iou``.  Matching: :func:`scipy.optimize.linear_sum_assignment` on the gated cost matrix;
* **birth**: an unmatched observation with score >= ``birth_min_score`` starts a *tentative* track, confirmed
  after ``confirm_hits`` observations; a tentative track that misses ``tentative_max_misses`` consecutive
  frames dies, a confirmed one after ``max_misses`` (given for 0.1 s between frames: at a higher rate the
  same time, :func:`frames_for`);
* **output** (:meth:`Tracker.tracks`): confirmed tracks with at least ``min_track_frames`` observations and a
  mean detection score >= ``min_mean_score`` — single false detections and flickering clutter never become
  tracks.

Frames are integers; ``frame_interval_s`` turns speeds (m/s) into metres per frame.  Deterministic: the same
observations in the same order give the same tracks.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from pedx_graph.small_arrays import median

#: Cost given to gated-out pairs in the assignment (never accepted).
_GATED = 1e9


def _predicted(state, uv_obs: np.ndarray, df: int) -> tuple[np.ndarray, np.ndarray]:
    """A side's keypoints predicted ``df`` frames ahead at constant velocity (K, 2) pixels, and the (K,) mask
    of keypoints finite in both the prediction and ``uv_obs``."""
    uv_pred = state.uv + state.velocity * df
    return uv_pred, np.all(np.isfinite(uv_pred), axis=1) & np.all(np.isfinite(uv_obs), axis=1)


#: The frame interval :attr:`TrackerConfig.motion_frac` is given for, seconds (it was measured at 10 Hz).
MOTION_REFERENCE_INTERVAL_S = 0.1


def image_sigma_px(config: "TrackerConfig", height_px: float, frames: float) -> float:
    """The keypoints' expected frame-to-frame residual after prediction, pixels: ``keypoint_sigma_px +
    motion_frac * height_px * sqrt(frames) * frame_interval_s / MOTION_REFERENCE_INTERVAL_S`` (``frames`` at
    least 1)."""
    scale = config.frame_interval_s / MOTION_REFERENCE_INTERVAL_S
    return config.keypoint_sigma_px + config.motion_frac * height_px * float(np.sqrt(max(frames, 1))) * scale


def frames_for(config: "TrackerConfig", frames: int) -> int:
    """A frame count given for frames :data:`MOTION_REFERENCE_INTERVAL_S` apart (how long a track coasts), at
    ``config.frame_interval_s``: as many frames as cover the same time at a higher rate, never fewer than
    given at a lower one (at 5 Hz, per-camera tracklets coasting 2 frames instead of 4 switched people 32
    times instead of 20 on the association benchmark's seeds 0-3)."""
    return max(int(frames), int(round(frames * MOTION_REFERENCE_INTERVAL_S / config.frame_interval_s)))


@dataclass
class TrackerConfig:
    """Matching, birth and death of the across-frame tracker (pixels, metres, seconds, frames)."""

    frame_interval_s: float = 0.1
    """Time between consecutive frame numbers, seconds (PedX: ~0.1-0.17 s; keep it explicit)."""
    keypoint_sigma_px: float = 4.0
    """Size-independent part of a keypoint's frame-to-frame residual after prediction, pixels per axis."""
    motion_frac: float = 0.04
    """Size-dependent part: this fraction of the person's image height per sqrt(frame) at frames
    :data:`MOTION_REFERENCE_INTERVAL_S` apart, in proportion to ``frame_interval_s`` at other rates (limbs
    swing while walking, and a track just begun has no velocity yet: both move the keypoints by more the
    longer between frames; the median over keypoints absorbs the wrists)."""
    lateral_sigma_m: float = 0.2
    """Uncertainty of a 3D centre across the viewing ray (keypoint noise, limb motion), metres."""
    accel_sigma_mps: float = 0.6
    """Unpredicted change of walking velocity per second (start, stop, turn), m/s per s."""
    max_speed_mps: float = 3.0
    """A person never moves faster than this (a jogger); 3D residuals beyond ``max_speed * dt`` plus the
    noise are gated out, m/s."""
    gate_sigmas: float = 3.0
    """A pair whose normalised residual (any term) exceeds this is never matched."""
    min_box_iou: float = 0.0
    """Extra gate: predicted and observed keypoint boxes of each shared image side overlap at least this much
    (intersection over union); 0 = off (the keypoint and 3D residuals gate)."""
    size_sigma: float = 0.0
    """Expected frame-to-frame spread of ``log(span_observed / span_predicted)`` (vertical spans of the shared
    keypoints of each image side: a person's image size changes slowly, two people at different depths differ);
    0 = no size term."""
    range_sigma_m: float = 0.0
    """Expected frame-to-frame spread of a person's LiDAR range (:attr:`Observation.lidar_range_m`, after the
    predicted walking change), metres: two people overlapping in the image but a metre apart in range are told
    apart by their LiDAR points; 0 = no range term.  The term is capped at ``gate_sigmas`` (it never gates: a
    detection's range can lie on a neighbour)."""
    range_claims: bool = False
    """Leave the range term out of a track's cost where the observation's range is another person's: another
    live track, missed at this frame (its predicted keypoint box covers half of no other observation's box),
    lies over the observation in the image (covering half of the smaller box) and predicts the observation's
    range within its ``range_sigma_m`` (grown by the walking change since).  The LiDAR cluster under the
    detection is then that person's, standing in front of the one detected, whose own returns it hides; it
    says nothing against this track.  Only a range more than one sigma from this track's prediction is
    judged."""
    velocity_smoothing: float = 0.5
    """Weight of the newest velocity measurement in the smoothed velocity (1 = no smoothing)."""
    birth_min_score: float = 0.2
    """An unmatched observation starts a track only when its score (mean keypoint confidence) is at least
    this."""
    confirm_hits: int = 3
    """A tentative track is confirmed after this many observations."""
    tentative_max_misses: int = 1
    """A tentative track dies after this many consecutive frames without an observation."""
    max_misses: int = 5
    """A confirmed track dies after this many consecutive frames without an observation (occlusion), given
    for frames :data:`MOTION_REFERENCE_INTERVAL_S` apart: at a higher rate as many frames as cover the same
    time (:func:`frames_for`)."""
    min_track_frames: int = 5
    """Only tracks with at least this many observations are output."""
    min_mean_score: float = 0.35
    """Only tracks whose mean observation score is at least this are output."""


@dataclass
class Observation:
    """One person at one frame in one stereo pair (rectified pixels, world metres)."""

    frame: int
    """Frame number."""
    uv: dict
    """Image side (``"left"`` / ``"right"``) -> (K, 2) rectified pixels, NaN where absent."""
    score: float
    """Detection score (the best of the two images' scores)."""
    world_p: np.ndarray | None = None
    """(3,) centre of the person in the world frame, metres, or None (one image, no LiDAR)."""
    world_p_camera: np.ndarray | None = None
    """(3,) the centre of the camera ``world_p`` was seen from (defines the viewing ray), metres."""
    depth_sigma_m: float = np.inf
    """Uncertainty of ``world_p`` along the viewing ray, metres."""
    disparity_px: float | None = None
    """Median disparity ``u_left - u_right`` of the keypoints when both images saw the person, pixels."""
    lidar_range_m: float | None = None
    """Range (depth along the rectified optical axis) of the LiDAR points under the detection's keypoints,
    metres, or None (no cloud, too few points)."""
    payload: object = None
    """What the caller attaches (the association keeps the raw detections here)."""
    fallback: tuple | None = None
    """``(world_p, world_p_camera, depth_sigma_m)`` the centre had before the LiDAR last replaced it (a one-image
    frame's cluster-range centre replaced by its cut goes back to that range centre) — the association may
    take it back —, else None."""

    def height_px(self, side: str) -> float:
        """Vertical extent of the present keypoints in ``side``, pixels (0 when fewer than two)."""
        uv = self.uv.get(side)
        if uv is None:
            return 0.0
        v = uv[np.all(np.isfinite(uv), axis=1), 1]
        return float(np.ptp(v)) if len(v) >= 2 else 0.0


def keypoint_box(uv: np.ndarray) -> np.ndarray | None:
    """(4,) ``u0, v0, u1, v1`` of the present keypoints of (K, 2) pixels, or None when fewer than two."""
    present = uv[np.all(np.isfinite(uv), axis=1)]
    if len(present) < 2:
        return None
    return np.concatenate([present.min(axis=0), present.max(axis=0)])


def _box_intersection(a: np.ndarray, b: np.ndarray) -> float:
    """Area of the intersection of two ``u0, v0, u1, v1`` boxes."""
    return float(np.clip(np.minimum(a[2:], b[2:]) - np.maximum(a[:2], b[:2]), 0.0, None).prod())


def box_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two ``u0, v0, u1, v1`` boxes (0 when either is degenerate)."""
    inter = _box_intersection(a, b)
    union = np.prod(a[2:] - a[:2]) + np.prod(b[2:] - b[:2]) - inter
    return float(inter / union) if union > 0 else 0.0


def box_cover(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection of two ``u0, v0, u1, v1`` boxes over the smaller one's area (0 when either is degenerate):
    1 when one lies inside the other."""
    smaller = min(np.prod(a[2:] - a[:2]), np.prod(b[2:] - b[:2]))
    return _box_intersection(a, b) / float(smaller) if smaller > 0 else 0.0


@dataclass
class _SideState:
    uv: np.ndarray
    frame: int
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(2))
    height_px: float = 0.0


@dataclass
class _Track:
    index: int
    observations: list = field(default_factory=list)
    sides: dict = field(default_factory=dict)
    world_p: np.ndarray | None = None
    world_frame: int = 0
    world_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    has_world_velocity: bool = False
    depth_sigma_m: float = np.inf
    disparity_px: float | None = None
    range_m: float | None = None
    range_frame: int = 0
    range_velocity: float = 0.0
    misses: int = 0
    confirmed: bool = False
    alive: bool = True

    @property
    def last_frame(self) -> int:
        return self.observations[-1].frame


class Tracker:
    """Frame-by-frame multi-person tracker (module docstring); feed frames in increasing order."""

    def __init__(self, config: TrackerConfig | None = None, world_up: np.ndarray | None = None):
        """``world_up``: (3,) the sequence's up axis (:class:`~pedx_graph.data.ground.GroundFrame`); when
        given, 3D residuals are measured in the ground plane only (a centre's height moves with the keypoints
        a detector happens to find, not with the person)."""
        self.config = config or TrackerConfig()
        self._up = None if world_up is None else np.asarray(world_up, dtype=float) / np.linalg.norm(world_up)
        self._tracks: list[_Track] = []
        self._live: list[_Track] = []
        self._covers: dict[int, set[int]] = {}
        self._frame: int | None = None

    # ------------------------------------------------------------------------------------------ costs
    def _flat(self, world_d: np.ndarray) -> np.ndarray:
        """A world vector without its component along the up axis (unchanged without one)."""
        if self._up is None:
            return world_d
        return world_d - (world_d @ self._up) * self._up

    def _cost(self, track: _Track, obs: Observation) -> float:
        cfg = self.config
        terms = []
        shared_side = False
        for side, uv_obs in obs.uv.items():
            state = track.sides.get(side)
            if state is None:
                continue
            df = obs.frame - state.frame
            uv_pred, both = _predicted(state, uv_obs, df)
            if both.sum() < 2:
                continue
            shared_side = True
            height = max(state.height_px, obs.height_px(side), 1.0)
            sigma = image_sigma_px(cfg, height, df)
            residual = float(median(np.linalg.norm(uv_pred[both] - uv_obs[both], axis=1))) / sigma
            if residual > cfg.gate_sigmas:
                return _GATED
            if cfg.min_box_iou > 0:
                box_pred, box_obs = keypoint_box(uv_pred[both]), keypoint_box(uv_obs[both])
                if box_pred is None or box_obs is None or box_iou(box_pred, box_obs) < cfg.min_box_iou:
                    return _GATED
            terms.append(residual ** 2)
            if cfg.size_sigma > 0:
                span_pred, span_obs = np.ptp(uv_pred[both, 1]), np.ptp(uv_obs[both, 1])
                if min(span_pred, span_obs) > 4 * cfg.keypoint_sigma_px:
                    size = float(np.log(span_obs / span_pred)) / cfg.size_sigma
                    if abs(size) > cfg.gate_sigmas:
                        return _GATED
                    terms.append(size ** 2)
        if cfg.range_sigma_m > 0 and obs.lidar_range_m is not None and track.range_m is not None:
            predicted_range, sigma = self._predicted_range(track, obs.frame)
            residual = min(abs(obs.lidar_range_m - predicted_range) / sigma, cfg.gate_sigmas)
            if not (cfg.range_claims and residual > 1.0 and self._claimed(track, obs)):
                terms.append(residual ** 2)       # weighs, never gates: a range can lie on a neighbour
        has_3d = track.world_p is not None and obs.world_p is not None
        if has_3d:
            dt_frames = obs.frame - track.world_frame
            dt_s = dt_frames * cfg.frame_interval_s
            predicted = track.world_p + (track.world_velocity * dt_frames if track.has_world_velocity else 0.0)
            error = self._flat(predicted - obs.world_p)
            # never farther than a runner could go, whatever the depth noise says
            jump = np.linalg.norm(self._flat(obs.world_p - track.world_p))
            depth_slack = cfg.gate_sigmas * np.hypot(min(obs.depth_sigma_m, 1e3), min(track.depth_sigma_m, 1e3))
            if jump > cfg.max_speed_mps * dt_s + depth_slack + cfg.gate_sigmas * cfg.lateral_sigma_m:
                return _GATED
            ray = obs.world_p - (obs.world_p_camera if obs.world_p_camera is not None else 0.0)
            ray = self._flat(ray)
            ray = ray / max(np.linalg.norm(ray), 1e-9)
            along = float(error @ ray)
            across = float(np.linalg.norm(error - along * ray))
            motion = cfg.accel_sigma_mps * dt_s + (0.0 if track.has_world_velocity else cfg.max_speed_mps * dt_s / 2)
            sigma_along = float(np.sqrt(min(obs.depth_sigma_m, 1e3) ** 2 + min(track.depth_sigma_m, 1e3) ** 2
                                        + motion ** 2 + cfg.lateral_sigma_m ** 2))
            sigma_across = float(np.hypot(cfg.lateral_sigma_m * np.sqrt(2.0), motion))
            for value, sigma in ((along, sigma_along), (across, sigma_across)):
                if abs(value) / sigma > cfg.gate_sigmas:
                    return _GATED
                terms.append((value / sigma) ** 2)
        if not shared_side and not has_3d:
            # a track seen in one image, an observation in the other: rectified rows agree, disparity > 0
            cross = self._cross_side_residual(track, obs)
            if cross is None or cross > cfg.gate_sigmas:
                return _GATED
            terms.append(cross ** 2)
        return float(np.mean(terms))

    def _claimed(self, track: _Track, obs: Observation) -> bool:
        """Whether ``obs``'s LiDAR range is another person's (``TrackerConfig.range_claims``): a live track other
        than ``track``, covering no other observation of the frame (:meth:`step`), lies over ``obs`` in one of
        its image sides and predicts its range."""
        for other in self._live:
            if other is track or other.range_m is None or self._covers[id(other)] != {id(obs)}:
                continue
            predicted_range, sigma = self._predicted_range(other, obs.frame)
            if abs(obs.lidar_range_m - predicted_range) <= sigma:
                return True
        return False

    def _predicted_range(self, track: _Track, frame: int) -> tuple[float, float]:
        """A track's LiDAR range carried on to ``frame`` at its range velocity, and its sigma there
        (``range_sigma_m`` and the walking change since, in quadrature), metres."""
        cfg = self.config
        df = frame - track.range_frame
        return (track.range_m + track.range_velocity * df,
                float(np.hypot(cfg.range_sigma_m, cfg.accel_sigma_mps * df * cfg.frame_interval_s)))

    def _covering(self, track: _Track, observations: list[Observation]) -> set[int]:
        """Ids of the observations whose keypoint box, in an image side ``track`` holds, is at least half covered
        by (or covers half of) the track's keypoint box predicted to their frame."""
        out = set()
        for obs in observations:
            for side, uv_obs in obs.uv.items():
                state = track.sides.get(side)
                if state is None:
                    continue
                predicted = keypoint_box(state.uv + state.velocity * (obs.frame - state.frame))
                box = keypoint_box(uv_obs)
                if predicted is not None and box is not None and box_cover(predicted, box) >= 0.5:
                    out.add(id(obs))
                    break
        return out

    def _cross_side_residual(self, track: _Track, obs: Observation) -> float | None:
        """Normalised row residual between a one-image track and an observation in the other image of the pair
        (None when they share no keypoints or the disparity would not be positive)."""
        cfg = self.config
        for side, other in (("left", "right"), ("right", "left")):
            state, uv_obs = track.sides.get(other), obs.uv.get(side)
            if state is None or uv_obs is None:
                continue
            df = obs.frame - state.frame
            uv_pred, both = _predicted(state, uv_obs, df)
            if both.sum() < 2:
                continue
            left_u, right_u = (uv_obs[both, 0], uv_pred[both, 0]) if side == "left" else (uv_pred[both, 0], uv_obs[both, 0])
            if median(left_u - right_u) <= 0:
                return None
            height = max(state.height_px, obs.height_px(side), 1.0)
            sigma = image_sigma_px(cfg, height, df)
            return float(median(np.abs(uv_pred[both, 1] - uv_obs[both, 1]))) / sigma
        return None

    # ------------------------------------------------------------------------------------------ updates
    def _update(self, track: _Track, obs: Observation) -> None:
        cfg = self.config
        alpha = cfg.velocity_smoothing
        for side, uv in obs.uv.items():
            state = track.sides.get(side)
            height = obs.height_px(side)
            if state is not None:
                df = max(obs.frame - state.frame, 1)
                measured = (uv - state.uv) / df
                shared = np.all(np.isfinite(measured), axis=1)
                if shared.sum() >= 2:
                    step = median(measured[shared], axis=0)
                    state.velocity = alpha * step + (1 - alpha) * state.velocity
                # keypoints missing now keep their previous position moved by the velocity
                carried = state.uv + state.velocity * df
                uv = np.where(np.isfinite(uv), uv, carried)
            track.sides[side] = _SideState(uv=np.asarray(uv, dtype=float), frame=obs.frame,
                                           velocity=np.zeros(2) if state is None else state.velocity,
                                           height_px=height if height > 0 else (state.height_px if state else 0.0))
        if obs.lidar_range_m is not None:
            if track.range_m is not None:
                df = max(obs.frame - track.range_frame, 1)
                step = float(np.clip((obs.lidar_range_m - track.range_m) / df,
                                     -cfg.max_speed_mps * cfg.frame_interval_s, cfg.max_speed_mps * cfg.frame_interval_s))
                track.range_velocity = alpha * step + (1 - alpha) * track.range_velocity
            track.range_m, track.range_frame = float(obs.lidar_range_m), obs.frame
        if obs.world_p is not None:
            if track.world_p is not None:
                df = max(obs.frame - track.world_frame, 1)
                # a depth-noisy velocity is weighted down by the depth noise relative to the step
                step = (obs.world_p - track.world_p) / df
                trust = alpha if track.has_world_velocity else 1.0
                noise = np.hypot(min(obs.depth_sigma_m, 1e3), min(track.depth_sigma_m, 1e3)) / df
                scale = cfg.max_speed_mps * cfg.frame_interval_s
                trust *= scale ** 2 / (scale ** 2 + noise ** 2)
                track.world_velocity = trust * step + (1 - trust) * track.world_velocity
                track.has_world_velocity = True
            track.world_p = np.asarray(obs.world_p, dtype=float)
            track.world_frame = obs.frame
            track.depth_sigma_m = float(obs.depth_sigma_m)
        if obs.disparity_px is not None:
            track.disparity_px = float(obs.disparity_px)
        elif track.disparity_px is not None and len(obs.uv) == 1:
            # one image saw the person: move the other image's state along by the known disparity
            (side, uv), = obs.uv.items()
            shift = np.array([-track.disparity_px, 0.0]) if side == "left" else np.array([track.disparity_px, 0.0])
            other = "right" if side == "left" else "left"
            previous = track.sides.get(other)
            track.sides[other] = _SideState(uv=track.sides[side].uv + shift, frame=obs.frame,
                                            velocity=track.sides[side].velocity.copy(),
                                            height_px=previous.height_px if previous else track.sides[side].height_px)
        track.observations.append(obs)
        track.misses = 0
        if len(track.observations) >= cfg.confirm_hits:
            track.confirmed = True

    def step(self, frame: int, observations: list[Observation]) -> list[int]:
        """Match one frame's observations; returns the internal track index given to each observation (-1:
        none, the observation's score was below ``birth_min_score``)."""
        if self._frame is not None and frame <= self._frame:
            raise ValueError(f"frames must increase: {frame} after {self._frame}")
        cfg = self.config
        self._frame = frame
        for track in self._tracks:           # frames skipped since the last call count as misses
            if track.alive and frame - track.last_frame - 1 >= self._miss_limit(track):
                track.alive = False
        live = [t for t in self._tracks if t.alive]
        self._live = live
        self._covers = {id(t): self._covering(t, observations) for t in live} if cfg.range_claims else {}
        assigned = [-1] * len(observations)
        if live and observations:
            cost = np.array([[self._cost(t, o) for o in observations] for t in live])
            rows, cols = linear_sum_assignment(cost)
            for r, c in zip(rows, cols):
                if cost[r, c] < _GATED:
                    self._update(live[r], observations[c])
                    assigned[c] = live[r].index
        matched = set(assigned)
        for track in live:
            if track.index in matched:
                continue
            track.misses = frame - track.last_frame
            if track.misses >= self._miss_limit(track):
                track.alive = False
        for c, obs in enumerate(observations):
            if assigned[c] >= 0 or obs.score < cfg.birth_min_score:
                continue
            track = _Track(index=len(self._tracks))
            self._update(track, obs)
            self._tracks.append(track)
            assigned[c] = track.index
        return assigned

    def _miss_limit(self, track: _Track) -> int:
        cfg = self.config
        return frames_for(cfg, cfg.max_misses) if track.confirmed else cfg.tentative_max_misses

    def tracks(self) -> list[list[Observation]]:
        """The output tracks (module docstring), each a list of observations in frame order; ordered by first
        frame, then by the internal index."""
        cfg = self.config
        out = []
        for track in self._tracks:
            if not track.confirmed or len(track.observations) < cfg.min_track_frames:
                continue
            if float(np.mean([o.score for o in track.observations])) < cfg.min_mean_score:
                continue
            out.append((track.observations[0].frame, track.index, list(track.observations)))
        return [obs for _, _, obs in sorted(out, key=lambda item: item[:2])]


def track_frames(frames_observations: dict[int, list[Observation]], config: TrackerConfig | None = None
                 ) -> list[list[Observation]]:
    """Run a :class:`Tracker` over ``{frame: observations}`` in frame order; returns its output tracks."""
    tracker = Tracker(config)
    for frame in sorted(frames_observations):
        tracker.step(frame, frames_observations[frame])
    return tracker.tracks()
