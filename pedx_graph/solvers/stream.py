"""Streaming estimation: frames arrive in timestamp order across all tracks; one iSAM2 per active track.

:class:`StreamingEstimator` (the live API)::

    est = StreamingEstimator(ctx, config)
    current = est.add_frame(timestamp, {tracking_id: TrackFrame, ...}, calibrations)   # -> {tid: FrameEstimate}
    results = est.finish()                                                            # -> [TrackResult]

A track begins when its id is first seen and ends when it has not been seen for ``track_timeout_s``
(or at :meth:`StreamingEstimator.finish`); an ended track is finalised (smoothed over all its frames,
:meth:`IncrementalTrack.finalize`) and returned as a :class:`~pedx_graph.solvers.fit.TrackResult` with
marginal covariances and diagnostics.

Causality: a frame's factors use only that frame and earlier ones.  They are the batch graph's factors
(:mod:`pedx_graph.graph.build`, same noise, same seeded LiDAR subsample per track, the translation prior
on the points' core; ``StreamingEstimator._frame_factors`` mirrors ``build_track_graph`` and must follow
its changes: ``test_stream_factors_match_batch_graph`` checks it) except the heading prior,
whose trajectory heading is estimated from the frames up to now (a one-sided window of ``half_window_s``)
instead of a centred one.  New variables start from the previous frame's estimate (root; the body pose
extrapolated at constant joint-angle velocity, ``StreamConfig.predict_body_pose``) and the frame's LiDAR /
stereo centre (translation), then a damped Gauss-Newton step on the new frame alone
(``IsamConfig.presolve_iterations`` / ``presolve_method``; without the chamfer term,
``StreamConfig.presolve_exclude``) before the iSAM2 update.

Speed: each frame's initialisation measurements are taken once and kept; a frame's own factors enter iSAM2
linearised once, as one Hessian-form factor (``IsamConfig.linearize_frame_factors``); the pedestrians of
a sample go through the steps together so the body model is evaluated for all of them in one batched call
per step (see :meth:`StreamingEstimator.add_frame`), and the new frames' Gauss-Newton systems (presolve and
update) are formed for all of them in one batched pass without GTSAM callbacks
(:mod:`pedx_graph.solvers.frame_system`, ``StreamConfig.batched_frame_systems``); measured in
``benchmarks/bench_solvers.py``.
"""
from __future__ import annotations

import dataclasses

import logging
import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from factors.common import FrameKeys
from factors.shape_prior import shape_factors
from pedx_graph.data.ground import GroundFrame, ground_from_calibrations
from pedx_graph.data.types import StereoCalibration, Track, TrackFrame
from pedx_graph.graph.batch import BatchedBodyModel
from pedx_graph.graph.build import frame_factors
from pedx_graph.graph.config import FitConfig
from pedx_graph.graph.init import FrameMeasurements, initialise_from_measurements, measure_frame
from pedx_graph.solvers.frame_system import (OWN_KINDS, RecordingBody, SpecRecorder, add_temporal_new_frame,
                                             frame_systems, register_sample, temporal_terms)
from pedx_graph.solvers.isam import IncrementalTrack, IsamConfig

log = logging.getLogger(__name__)


@dataclass
class StreamConfig:
    """Settings of the streaming estimator (besides the estimator's :class:`FitConfig`)."""

    isam: IsamConfig = field(default_factory=IsamConfig)
    """iSAM2 settings."""
    track_timeout_s: float = 1.0
    """A track not seen for this long (seconds of stream time) ends and is finalised."""
    heading_half_window_s: float = 0.35
    """Trajectory heading from the frames of the last ``heading_half_window_s`` seconds (one-sided)."""
    causal_covariance: bool = False
    """Also give each causal estimate its translation and keypoint covariances (iSAM2 joint marginal)."""
    marginals: bool = True
    """Marginal covariances of each finalised track."""
    diagnostics: bool = True
    """Residual / information diagnostics of each finalised track."""
    predict_body_pose: bool = True
    """Start a new frame's body pose at constant joint-angle velocity from the two previous estimates (scaled
    by the time steps, at most one previous step ahead) instead of at the previous estimate."""
    presolve_exclude: tuple = ("lidar_chamfer",)
    """Factor kinds left out of the presolve (they still enter the iSAM2 update): the chamfer term is half
    the cost of linearising a frame, and its nearest-vertex correspondences are poor before the frame is
    placed by the other terms."""
    batched_frame_systems: bool = True
    """Form the new frames' own factors' Gauss-Newton systems (for the presolve and for iSAM2) for all
    pedestrians of a sample in one batched pass (:mod:`pedx_graph.solvers.frame_system`; the same systems
    as GTSAM's linearisation) instead of through one GTSAM callback per factor and frame.  Used with the
    Gauss-Newton presolve of one iteration and ``IsamConfig.linearize_frame_factors``."""
    final_restart: bool = True
    """When a track ends, also solve it from scratch with the batch fit (staged LM, centred headings) and
    keep whichever estimate has the lower error on the track's streamed graph: the incremental path can
    end in a worse local optimum than a batch solve (measured on the simulator, see docs/solvers.md)."""


@dataclass
class FrameEstimate:
    """The current (causal) estimate of one pedestrian in one frame."""

    tracking_id: str
    frame: int
    timestamp: float
    pose: np.ndarray
    """(72,) axis-angle, root first."""
    betas: np.ndarray
    """(B,) the track's current shape."""
    trans: np.ndarray
    """(3,) metres."""
    world_keypoints: np.ndarray
    """(18, 3) metres, world frame."""
    update_seconds: float
    """Wall time of this frame's update (causal initialisation, factors, initial values, presolve, iSAM2
    update, reading the estimate and its keypoints, plus an equal share of the sample's batched body-model
    calls, :meth:`StreamingEstimator.add_frame`; not the optional covariances)."""
    isam_seconds: float = 0.0
    """Wall time of the ``ISAM2.update`` call and of linearising the frame's own factors for it
    (:attr:`pedx_graph.solvers.isam.UpdateStats.isam_seconds`)."""
    cpu_seconds: float = 0.0
    """CPU time of the same work as ``update_seconds`` (this process; robust to a shared machine)."""
    extra: dict = field(default_factory=dict)
    """Covariances when ``causal_covariance`` is on."""


@dataclass
class _FrameInit:
    """Causal initialisation of the newest frame of a track."""

    world_p_centre: np.ndarray
    """(3,) pelvis estimate, metres."""
    world_R_body: np.ndarray
    """(3, 3) upright orientation."""
    heading_yaw: float
    """Trajectory heading (rad), NaN when unknown."""
    speed_mps: float
    """Trajectory speed, m/s."""
    heading_sigma_rad: float = 0.0
    """Uncertainty of the trajectory heading (``TrackInit.heading_sigma_rad``), radians."""


@dataclass
class _ActiveTrack:
    sequence: str
    tracking_id: str
    calibrations: dict
    smoother: IncrementalTrack
    rng: np.random.Generator
    frames: list[TrackFrame] = field(default_factory=list)
    measurements: list[FrameMeasurements] = field(default_factory=list)
    """Each frame's initialisation measurements (:func:`~pedx_graph.graph.init.measure_frame`), taken once."""
    keys: list[FrameKeys] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)
    factor_frames: list[int] = field(default_factory=list)
    last_seen: float = -np.inf
    frame_seconds: list[float] = field(default_factory=list)
    """Wall time of each frame's whole update (``FrameEstimate.update_seconds``)."""
    previous: tuple | None = None
    """Estimate ``(world_R_body, trans, body_pose, betas)`` of the newest frame right after its update."""
    before_previous: tuple | None = None
    """The same for the frame before (constant-velocity prediction of the body pose)."""
    last_pelvis: np.ndarray | None = None
    """Pelvis of the frame before ``previous`` (constant-velocity prediction of unplaceable frames)."""


class _StreamBody(BatchedBodyModel):
    """:class:`~pedx_graph.graph.batch.BatchedBodyModel` as the streamed factors' body model: its value cache
    (keypoints, their Jacobians, the chamfer vertex subset), prefetched for all pedestrians of a sample at
    once (:meth:`StreamingEstimator._prefetch`).  The factors do not register with it (a stream-long
    registry would grow without bound, and tracks share keys); its registry holds one sample's specs at a
    time, filed under per-pedestrian keys (:func:`~pedx_graph.solvers.frame_system.register_sample`), for
    the batched frame systems."""

    term_cache = None


@dataclass
class _Step:
    """One observation on its way through :meth:`StreamingEstimator.add_frame`."""

    tid: str
    fr: TrackFrame
    state: _ActiveTrack
    i: int
    """The frame's index in its track."""
    n_kinds: int
    """Number of the track's factors before this frame's."""
    graph: gtsam.NonlinearFactorGraph
    presolve_graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    """The new variables' initial values, then their presolved values."""
    specs: list | None = None
    """What the frame's factors measure (their :class:`~pedx_graph.solvers.frame_system.SpecRecorder`), when
    its own factors' systems are formed in a batch (``StreamConfig.batched_frame_systems``)."""
    recorder: SpecRecorder | None = None
    """The frame's factors' term cache (it serves the temporal prior's terms during the iSAM2 update)."""
    presolve_rest: gtsam.NonlinearFactorGraph | None = None
    """The presolve's factors outside the batched system (the shape prior)."""
    temporal: tuple | None = None
    """``(keys, (mixture, gap))`` of the frame's temporal prior (in the presolve's batched system)."""
    presolve_system: tuple | None = None
    """``(H, eta, f)`` in the presolve, at the initial values (batched): the frame's own factors but those
    of ``StreamConfig.presolve_exclude`` and its temporal prior's rows on the frame's variables."""
    own_system: tuple | None = None
    """``(H, eta, f)`` of the frame's own factors at the presolved values (batched), for iSAM2."""
    committed: bool = False
    stats: object = None
    seconds: float = 0.0
    cpu_seconds: float = 0.0

    def point(self, values: gtsam.Values) -> tuple:
        """The frame's ``(world_R_body, trans, body_pose, betas)`` in ``values`` (the shape at its estimate
        when ``values`` lacks it): the state its factors are evaluated at."""
        k, isam = self.state.keys[self.i], self.state.smoother.isam
        betas = values.atVector(k.betas) if values.exists(k.betas) else isam.calculateEstimateVector(k.betas)
        return values.atRot3(k.root), values.atVector(k.trans), values.atVector(k.body_pose), betas

    def presolve(self) -> gtsam.Values:
        keys, smoother = self.state.keys[self.i], self.state.smoother
        if self.presolve_system is not None:
            self.values = smoother.presolve(keys, self.presolve_rest, self.values, self.presolve_system[:2])
        else:
            self.values = smoother.presolve(keys, self.presolve_graph, self.values)
        return self.values

    def commit(self):
        try:
            self.stats = self.state.smoother.commit_frame(self.state.keys[self.i], self.graph, self.values,
                                                          own_system=self.own_system)
        finally:
            if self.recorder is not None:
                self.recorder.served.clear()         # the factors keep their recorder: free the arrays
        self.committed = True
        return self.stats



class StreamingEstimator:
    """Causal per-frame estimates of every visible pedestrian; smoothed tracks when they end."""

    def __init__(self, ctx, config: FitConfig | None = None, stream_config: StreamConfig | None = None,
                 sequence: str = "", ground: GroundFrame | None = None):
        self.ctx = ctx
        self.ground = ground
        """The sequence's up axis, level frame and viewpoint (None: derived from the first frame's calibrations)."""
        self.config = config or FitConfig()
        self.stream_config = stream_config or StreamConfig()
        self.stream_config.isam.num_betas = ctx.model.num_betas
        self.sequence = sequence
        self.active: dict[str, _ActiveTrack] = {}
        self.finished: list = []
        self.failed_tracks: list[dict] = []
        self._pelvis_rest0 = ctx.model.rest_joints(np.zeros(ctx.model.num_betas))[0]
        self.body = _StreamBody(ctx.model, ctx.chamfer_vertex_ids)
        """The body model the streamed factors evaluate (batched over each sample's pedestrians)."""
        self._recording = RecordingBody(self.body, SpecRecorder())
        """:attr:`body` as the factors see it when their specs are recorded (the recorder is swapped for each
        new frame before its factors are built; one object, so per-model caches such as
        :func:`factors.translation_prior.pelvis_shape_basis` keep hitting)."""

    # --- factors of one new frame (pedx_graph.graph.build.frame_factors, as the batch graph) -------------
    def _frame_factors(self, state: _ActiveTrack, i: int, fr: TrackFrame, window: list[FrameMeasurements],
                       model=None):
        noise, ctx, model = self.config.noise, self.ctx, model or self.body
        k = state.keys[i]
        graph = gtsam.NonlinearFactorGraph()

        def add(factor, kind):
            if factor is not None:
                graph.add(factor)
                state.kinds.append(kind)
                state.factor_frames.append(i if kind != "shape_prior" else -1)

        init = self._causal_init(state, window)
        previous = (state.keys[i - 1], state.frames[i - 1].timestamp) if i > 0 else None
        for factor, kind in frame_factors(k, fr, state.calibrations, previous, init.heading_yaw,
                                          init.speed_mps, model, ctx, self.config, state.rng,
                                          init.heading_sigma_rad, ground=self.ground):
            add(factor, kind)
        if i == 0:
            for factor in shape_factors(k.betas, model.num_betas, noise.shape_sigma, noise.shape_support_sd,
                                        noise.shape_support_sigma):
                add(factor, "shape_prior")
        return graph, init

    def _presolve_factors(self, graph: gtsam.NonlinearFactorGraph, kinds: list[str]):
        """The new frame's factors without the kinds in ``StreamConfig.presolve_exclude`` (None: all)."""
        exclude = set(self.stream_config.presolve_exclude or ())
        if not exclude.intersection(kinds):
            return None
        out = gtsam.NonlinearFactorGraph()
        for j, kind in enumerate(kinds):
            if kind not in exclude:
                out.add(graph.at(j))
        return out

    def _causal_init(self, state: _ActiveTrack, window: list[FrameMeasurements]) -> _FrameInit:
        """Centre, orientation, heading and speed of the newest frame from the recent frames only (the batch
        fit's initialisation on their cached measurements, ``window``).

        A frame with nothing to place it (neither LiDAR points nor a torso joint seen by two cameras, or a
        window the initialisation cannot place) takes its centre from the previous estimates (constant
        velocity) when the track has any, and so does a frame placed by the body's size alone; a track's
        first frame must be placeable, by the body's size at least (``ValueError``)."""
        # a frame that only the body's size places (one camera, no LiDAR: ~7 % depth sigma) is better predicted
        # from the track's previous estimates when it has any
        own = window[-1].placeable and window[-1].depth_source != "body_size"
        if own or state.previous is None:
            try:
                init = initialise_from_measurements(window, self.ground, f"{state.sequence}/{state.tracking_id}",
                                                    min_speed_mps=self.config.noise.heading_min_speed_mps,
                                                    half_window_s=self.stream_config.heading_half_window_s)
            except ValueError:
                if state.previous is None:
                    raise
            else:
                sigma = 0.0 if init.heading_sigma_rad is None else float(init.heading_sigma_rad[-1])
                return _FrameInit(init.world_p_centre[-1], init.world_R_body[-1], float(init.heading_yaw[-1]),
                                  float(init.speed_mps[-1]), sigma)
        rot, trans, _, betas = state.previous
        pelvis = self.ctx.model.rest_joints(betas)[0] + trans
        step = pelvis - state.last_pelvis if state.last_pelvis is not None else np.zeros(3)
        return _FrameInit(pelvis + step, rot, float("nan"), 0.0)

    def _starting_pose(self, state: _ActiveTrack, init: _FrameInit) -> np.ndarray:
        """A new track's first body pose: the candidate (pose prior means) reprojecting best onto its labels."""
        from pedx_graph.graph.build import select_template_poses

        track = Track(self.sequence, state.tracking_id, state.frames[-1:], state.calibrations, ground=self.ground)
        return select_template_poses(track, self.ctx, init.world_R_body[None], init.world_p_centre[None],
                                     all_views=self.config.terms.all_views)[0].copy()

    def _initial_values(self, state: _ActiveTrack, i: int, init) -> gtsam.Values:
        k = state.keys[i]
        values = gtsam.Values()
        if state.previous is None:
            values.insert(k.root, gtsam.Rot3(init.world_R_body))
            values.insert(k.body_pose, self._starting_pose(state, init))
            betas = np.zeros(self.ctx.model.num_betas)
            values.insert(k.betas, betas)
        else:
            rot, _, body_pose, betas = state.previous
            values.insert(k.root, gtsam.Rot3(rot))
            values.insert(k.body_pose, self._predicted_body_pose(state, i))
        pelvis_rest = self.ctx.model.rest_joints(betas)[0]
        values.insert(k.trans, np.asarray(init.world_p_centre - pelvis_rest, dtype=float))
        return values

    def _predicted_body_pose(self, state: _ActiveTrack, i: int) -> np.ndarray:
        """Body pose of frame ``i`` from the previous estimates: constant joint-angle velocity
        (``StreamConfig.predict_body_pose``) when the two frames before have estimates, else the previous
        estimate."""
        body_pose = np.asarray(state.previous[2], float)
        if not self.stream_config.predict_body_pose or state.before_previous is None or i < 2:
            return body_pose.copy()
        t0, t1, t2 = (state.frames[j].timestamp for j in (i - 2, i - 1, i))
        if not t1 > t0:
            return body_pose.copy()
        ratio = min(max((t2 - t1) / (t1 - t0), 0.0), 1.0)
        return body_pose + ratio * (body_pose - np.asarray(state.before_previous[2], float))

    def _best_facing(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: FrameKeys) -> gtsam.Values:
        """First frame without a trajectory heading: the torso-based facing can be reversed (front/back), so
        both it and its half-turn are solved on the frame alone and the lower error is kept."""
        from pedx_graph.solvers.isam import local_lm

        iters = max(self.stream_config.isam.presolve_iterations, 1)
        best = None
        for turn in (0.0, np.pi):
            candidate = gtsam.Values(values)
            candidate.update(keys.root, gtsam.Rot3.Rz(turn).compose(values.atRot3(keys.root)))
            solved, error, _ = local_lm(graph, candidate, list(candidate.keys()), max_iterations=iters)
            if best is None or error < best[1]:
                best = (solved, error)
        return best[0]

    # --- public API ----------------------------------------------------------------------------------------
    def add_frame(self, timestamp: float, observations: dict[str, TrackFrame],
                  calibrations: dict[str, StereoCalibration]) -> dict[str, FrameEstimate]:
        """Add one synchronised sample: ``observations`` maps tracking id -> that pedestrian's measurements.

        Returns the current (causal) estimate of every pedestrian observed in this sample.  Tracks not seen
        for ``track_timeout_s`` end here (finalised; collect them with :meth:`pop_finished`).

        The pedestrians of the sample go through each step together (initial values; presolve; iSAM2
        update; estimate), so the body model is evaluated for all of them in one batched call before the
        presolves, the updates and the keypoint read-out (:meth:`_prefetch`); each pedestrian's latency is
        its own work plus an equal share of those batched calls.
        """
        self._end_stale(timestamp, keep=observations.keys())
        steps: list[_Step] = []
        for tid, fr in observations.items():
            step = self._guarded(None, lambda: self._begin(timestamp, tid, fr, calibrations), tid, fr)
            if step is not None:
                steps.append(step)
        if self.stream_config.isam.presolve_iterations > 0:
            self._shared(steps, lambda: self._systems(steps, presolve=True))
        steps = [s for s in steps if self._guarded(s, lambda: s.presolve()) is not None]
        self._shared(steps, lambda: self._systems(steps, presolve=False))
        steps = [s for s in steps if self._guarded(s, lambda: s.commit()) is not None]
        self._shared(steps, lambda: self._prefetch([self._read(s.state, s.i) for s in steps], jacobians=False,
                                                   vertices=False))
        out = {}
        for step in steps:
            try:
                out[step.tid] = self._finish_step(step, timestamp)
            except Exception as exc:        # one bad observation never stops the stream
                log.warning("stream: %s frame %s: %s: %s", step.tid, step.fr.frame, type(exc).__name__, exc)
        return out

    def _guarded(self, step: "_Step | None", work, tid=None, fr=None):
        """``work()`` timed into ``step``; on failure the observation is dropped (logged, the track's state
        rolled back while its frame is not yet in iSAM2) and None returned."""
        c0, t0 = time.process_time(), time.perf_counter()
        try:
            result = work()
        except Exception as exc:            # one bad observation never stops the stream
            if step is not None:
                tid, fr = step.tid, step.fr
                if not step.committed:
                    self._rollback(step.state, step.i, step.n_kinds)
            log.warning("stream: %s frame %s: %s: %s", tid, fr.frame, type(exc).__name__, exc)
            return None
        target = result if step is None else step
        target.cpu_seconds += time.process_time() - c0
        target.seconds += time.perf_counter() - t0
        return result

    @staticmethod
    def _shared(steps: list["_Step"], work) -> None:
        """``work()`` (a batched call for all ``steps``), its time shared equally by the steps."""
        if not steps:
            return
        c0, t0 = time.process_time(), time.perf_counter()
        work()
        cpu, wall = (time.process_time() - c0) / len(steps), (time.perf_counter() - t0) / len(steps)
        for step in steps:
            step.cpu_seconds += cpu
            step.seconds += wall

    def _prefetch(self, states: list[tuple], jacobians: bool, vertices: bool, kinds=frozenset()) -> None:
        """Evaluate the body model at every ``(world_R_body, trans, body_pose, betas)`` of ``states`` in one
        batched call; the factors' own calls at exactly these values are then cache look-ups
        (:class:`~pedx_graph.graph.batch.BatchedBodyModel`, keyed by the values)."""
        values, keys = gtsam.Values(), []
        for j, (rot, trans, body_pose, betas) in enumerate(states):
            k = FrameKeys.for_frame(j, j)
            values.insert(k.root, rot if isinstance(rot, gtsam.Rot3) else gtsam.Rot3(rot))
            values.insert(k.trans, np.asarray(trans, float))
            values.insert(k.body_pose, np.asarray(body_pose, float))
            values.insert(k.betas, np.asarray(betas, float))
            keys.append(k)
        self.body.prefetch(values, keys, jacobians, vertices=vertices, kinds=kinds)

    def _begin(self, timestamp, tid, fr, calibrations) -> "_Step":
        if self.ground is None:
            self.ground = ground_from_calibrations(calibrations, self.sequence)
        """A new observation's causal initialisation, factors and initial values."""
        state = self.active.get(tid)
        if state is None:
            state = _ActiveTrack(sequence=self.sequence, tracking_id=tid, calibrations=dict(calibrations),
                                 smoother=IncrementalTrack.create(self.stream_config.isam),
                                 rng=np.random.default_rng(self.config.seed))
            self.active[tid] = state
        state.calibrations.update(calibrations)
        i = len(state.frames)
        state.frames.append(fr)
        state.keys.append(FrameKeys.for_frame(i))
        n_kinds = len(state.kinds)
        try:
            noise = self.config.noise
            state.measurements.append(measure_frame(state.calibrations, fr, self.ground,
                                                    noise.translation_depth_offset_m,
                                                    size_prior=self.ctx.size_prior,
                                                    all_views=self.config.terms.all_views,
                                                    sigma_px=noise.keypoint_sigma_px,
                                                    occluded_sigma_px=noise.occluded_keypoint_sigma_px))
            window = [m for m in state.measurements[-16:]
                      if fr.timestamp - m.time <= self.stream_config.heading_half_window_s + 1e-9]
            recorder = None
            if self._batched():
                recorder = self._recording.term_cache = SpecRecorder()
            graph, init = self._frame_factors(state, i, fr, window, None if recorder is None else self._recording)
            values = self._initial_values(state, i, init)
            if i == 0 and not np.isfinite(init.heading_yaw):
                values = self._best_facing(graph, values, state.keys[0])
            kinds = state.kinds[n_kinds:]
            presolve = self._presolve_factors(graph, kinds)
            specs = rest = temporal = None
            if recorder is not None and sorted(k for k in kinds if k in OWN_KINDS) == \
                    sorted(k for k, _, _ in recorder.specs if k in OWN_KINDS):
                specs = recorder.specs
                recorded = [(keys, spec) for kind, keys, spec in specs if kind == "temporal_prior"]
                if kinds.count("temporal_prior") == len(recorded) == 1:
                    temporal = recorded[0]
                rest = gtsam.NonlinearFactorGraph()
                for j, kind in enumerate(kinds):
                    if kind not in OWN_KINDS and not (kind == "temporal_prior" and temporal is not None):
                        rest.add(graph.at(j))
        except Exception:
            self._rollback(state, i, n_kinds)
            raise
        return _Step(tid=tid, fr=fr, state=state, i=i, n_kinds=n_kinds, graph=graph,
                     presolve_graph=graph if presolve is None else presolve, values=values, specs=specs,
                     presolve_rest=rest, temporal=temporal, recorder=recorder)

    def _batched(self) -> bool:
        """Whether the new frames' own factors' systems are formed in a batch (see
        ``StreamConfig.batched_frame_systems``)."""
        isam = self.stream_config.isam
        return bool(self.stream_config.batched_frame_systems and isam.linearize_frame_factors)

    def _systems(self, steps: list["_Step"], presolve: bool) -> None:
        """Prefetch the body model at the steps' current values (their keypoint Jacobians; for the update
        also the chamfer's vertices) and, when batched, form each step's own factors' system there: for the
        presolve without the kinds of ``StreamConfig.presolve_exclude`` (``presolve_system``), for the update
        all of them (``own_system``)."""
        states = [s.point(s.values) for s in steps]
        isam = self.stream_config.isam
        batched = self._batched() and (not presolve or (isam.presolve_method == "gn"
                                                        and isam.presolve_iterations == 1))
        served = [s for s in steps if s.specs is not None]
        if not batched or not served:
            self._prefetch(states, jacobians=True, vertices=not presolve)
            return
        exclude = set(self.stream_config.presolve_exclude or ()) if presolve else set()
        kinds = tuple(k for k in OWN_KINDS if k not in exclude)
        keys = register_sample(self.body, [(s.state.keys[s.i], s.specs or []) for s in steps])
        try:
            self._prefetch(states, jacobians=True, vertices=not presolve, kinds=frozenset(kinds))
            systems = frame_systems(self.body, keys, kinds)
        finally:
            self.body._specs = {}
        # the temporal priors to the tracks' previous frames, batched: in the presolve their rows on the new
        # frame (previous frame held at its estimate); for the update served to the factors' callbacks at
        # the point iSAM2 linearises them (the previous frame's linearisation point)
        pairs, owners = [], []
        for j, (step, (rot, trans, body_pose, _)) in enumerate(zip(steps, states)):
            if step.temporal is None or (presolve and systems is None):
                continue
            (kr, kt, kp, *_), (mixture, gap) = step.temporal
            isam = step.state.smoother.isam
            if presolve:
                previous = (isam.calculateEstimateRot3(kr).matrix(), isam.calculateEstimateVector(kt),
                            isam.calculateEstimateVector(kp))
            else:
                theta = isam.getLinearizationPoint()
                previous = (theta.atRot3(kr).matrix(), theta.atVector(kt), theta.atVector(kp))
            rot = rot.matrix() if isinstance(rot, gtsam.Rot3) else np.asarray(rot)
            pairs.append((previous, (rot, np.asarray(trans), np.asarray(body_pose)), mixture, gap))
            owners.append(j)
        terms = temporal_terms(pairs) if pairs else []
        if presolve and terms:
            add_temporal_new_frame(systems, owners, terms)
        elif terms:
            for j, pair, (r, blocks) in zip(owners, pairs, terms):
                step = steps[j]
                if step.recorder is not None:
                    step.recorder.serve("temporal_prior", step.temporal[0], [*pair[0], *pair[1]], r, blocks)
        for j, step in enumerate(steps):
            system = None if systems is None or step.specs is None else tuple(x[j] for x in systems)
            if presolve:
                step.presolve_system = system
            else:
                step.own_system = system

    def _read(self, state: _ActiveTrack, i: int) -> tuple:
        """Read frame ``i``'s new estimate into its track (``previous`` ...) and return it."""
        if state.previous is not None:
            state.last_pelvis = self.ctx.model.rest_joints(state.previous[3])[0] + state.previous[1]
        state.before_previous = state.previous
        state.previous = state.smoother.frame_estimate(state.keys[i])
        return state.previous

    def _rollback(self, state: _ActiveTrack, i: int, n_kinds: int) -> None:
        del state.measurements[i:], state.frames[i:], state.keys[i:]
        del state.kinds[n_kinds:], state.factor_frames[n_kinds:]
        if not state.frames:
            self.active.pop(state.tracking_id, None)

    def _finish_step(self, step: "_Step", timestamp: float) -> FrameEstimate:
        """The observation's estimate (keypoints from the batched read-out) and optional covariances."""
        c0, t0 = time.process_time(), time.perf_counter()
        state, i = step.state, step.i
        state.last_seen = timestamp
        rot, trans, body_pose, betas = state.previous
        pose = np.concatenate([gtsam.Rot3.Logmap(gtsam.Rot3(rot)), body_pose])
        kps = np.array(self.body.keypoints(pose, betas, trans))
        seconds = step.seconds + time.perf_counter() - t0
        cpu_seconds = step.cpu_seconds + time.process_time() - c0
        state.frame_seconds.append(seconds)
        extra = {}
        if self.stream_config.causal_covariance:
            extra = self._causal_covariance(state, i, pose, betas, trans)
        return FrameEstimate(tracking_id=step.tid, frame=step.fr.frame, timestamp=float(timestamp), pose=pose,
                             betas=betas, trans=trans, world_keypoints=kps, update_seconds=seconds,
                             cpu_seconds=cpu_seconds, isam_seconds=step.stats.isam_seconds, extra=extra)

    def _causal_covariance(self, state, i, pose, betas, trans) -> dict:
        from pedx_graph.solvers.marginals import MarginalsConfig, frame_fields, isam_frame_covariance

        try:
            cov = isam_frame_covariance(state.smoother.isam, state.keys[i], len(betas))
        except RuntimeError as exc:
            return {"covariance_status": f"failed: {exc}"}
        fields = frame_fields(self.ctx.model, pose, betas, trans, cov, False, MarginalsConfig())
        return {k: fields[k] for k in ("covariance_status", "cov_trans", "cov_root", "cov_keypoints_3d")}

    def _end_stale(self, now: float, keep=()) -> None:
        keep = set(keep)
        for tid in [t for t, s in self.active.items()
                    if t not in keep and now - s.last_seen > self.stream_config.track_timeout_s]:
            self.end_track(tid)

    def end_track(self, tracking_id: str):
        """Finalise one track now: smoothed estimate, marginals, diagnostics -> :class:`TrackResult`."""
        from pedx_graph.solvers.plausibility import ImplausibleEstimateError

        state = self.active.pop(tracking_id)
        try:
            result = self._finalise(state)
        except ImplausibleEstimateError as exc:     # recorded as a failed track (pop_failed), not written
            log.warning("stream: %s", exc)
            self.failed_tracks.append({"sequence": state.sequence, "tracking_id": state.tracking_id,
                                       "error": f"{type(exc).__name__}: {exc}", "reasons": exc.reasons})
            return None
        if result is not None:
            self.finished.append(result)
        return result

    def pop_failed(self) -> list[dict]:
        """Tracks whose smoothed estimate was refused as implausible since the last call
        (:mod:`pedx_graph.solvers.plausibility`): ``{"sequence", "tracking_id", "error", "reasons"}`` each."""
        out, self.failed_tracks = self.failed_tracks, []
        return out

    def pop_finished(self) -> list:
        """Track results finalised since the last call."""
        out, self.finished = self.finished, []
        return out

    def finish(self) -> list:
        """End every active track; returns all results not yet popped."""
        for tid in list(self.active):
            self.end_track(tid)
        return self.pop_finished()

    def _restart_if_better(self, state: _ActiveTrack, values: gtsam.Values) -> tuple[gtsam.Values, str]:
        """The batch fit of the track's frames if it has a lower error on the streamed graph."""
        from pedx_graph.solvers.fit import solve_staged

        track = Track(state.sequence, state.tracking_id, list(state.frames), dict(state.calibrations),
                      ground=self.ground)
        try:
            _, batch_values, _ = solve_staged(track, self.ctx, self.config)
            if state.smoother.factors.error(batch_values) < state.smoother.factors.error(values):
                return batch_values, "batch_restart"
        except Exception as exc:          # the warm-started estimate stands
            log.warning("stream: batch restart of %s failed: %s", state.tracking_id, exc)
        return values, "isam_warm_start"

    def _finalise(self, state: _ActiveTrack):
        from pedx_graph.graph.build import TrackProblem, extract_estimate
        from pedx_graph.solvers.fit import TrackResult

        if not state.frames:
            return None
        t0 = time.perf_counter()
        n_updates = len(state.smoother.updates)
        latencies = np.array(state.frame_seconds if len(state.frame_seconds) == n_updates
                             else [u.seconds for u in state.smoother.updates[:n_updates]])
        isam_only = np.array([u.isam_seconds for u in state.smoother.updates[:n_updates]])
        values = state.smoother.finalize(self.config.solver)
        final_from = "isam_warm_start"
        if self.stream_config.final_restart and len(state.frames) >= 2:
            values, final_from = self._restart_if_better(state, values)
        finalize_s = time.perf_counter() - t0
        problem = TrackProblem(graph=state.smoother.factors, initial=values, keys=state.keys, init=None,
                               factor_kinds=state.kinds, factor_frames=state.factor_frames, ground=self.ground)
        est = extract_estimate(problem, values, self.ctx)
        extra_frames = [{} for _ in state.frames]
        extra_track = {
            "stream_updates": int(len(latencies)),
            "stream_update_ms_median": float(np.median(latencies) * 1e3),
            "stream_update_ms_p90": float(np.percentile(latencies, 90) * 1e3),
            "stream_update_ms_max": float(latencies.max() * 1e3),
            "stream_isam_update_ms_median": float(np.median(isam_only) * 1e3),
            "stream_finalize_seconds": finalize_s,
            "stream_final_from": final_from,
        }
        from pedx_graph.solvers.diagnostics import track_extras

        # the body plausibility fields always, covariances / diagnostics when asked
        extra_frames, track_fields = track_extras(problem, values, self.ctx, self.stream_config.marginals,
                                                  self.stream_config.diagnostics, fit_config=self.config,
                                                  frames=state.frames)
        extra_track.update(track_fields)
        graph_error = float(problem.graph.error(values))
        result = TrackResult(sequence=state.sequence, tracking_id=state.tracking_id,
                             frames=[fr.frame for fr in state.frames], pose=est.pose, betas=est.betas,
                             trans=est.trans, world_keypoints=est.world_keypoints, final_error=graph_error,
                             initial_error=float("nan"), iterations=len(state.smoother.updates),
                             seconds=float(latencies.sum()) + finalize_s, solver="isam2-stream",
                             extra_per_frame=extra_frames, extra_track=extra_track)
        from pedx_graph.solvers.plausibility import check_track_result
        track = Track(state.sequence, state.tracking_id, list(state.frames), dict(state.calibrations),
                      ground=self.ground)
        return check_track_result(result, track, self.config, problem, values)   # raises when implausible


def _causal_label(sequence: str, est: FrameEstimate):
    """The causal estimate of one frame as a result label (its update time goes to the summary's timings,
    never into the file)."""
    from pedx_graph.data.types import SmplLabel
    from pedx_graph.keypoints import PEDX_KEYPOINTS

    extra = {"keypoints_3d": est.world_keypoints, "keypoint_names": list(PEDX_KEYPOINTS),
             "timestamp": est.timestamp, "solver": "isam2-causal"}
    extra.update(est.extra)
    return SmplLabel(sequence=sequence, frame=int(est.frame), tracking_id=est.tracking_id, betas=est.betas,
                     pose=est.pose, trans=est.trans, extra=extra)


def stream_track(track: Track, ctx, config: FitConfig, stream_config: StreamConfig):
    """Stream one track's frames in timestamp order through its own :class:`StreamingEstimator`.

    Returns ``(smoothed results, causal estimates, failed)``: the smoothed :class:`TrackResult` of each piece
    of the track (one unless it paused longer than ``track_timeout_s``), the causal :class:`FrameEstimate`
    of every frame whose update succeeded, and ``{"frame" or "stage", "error"}`` of each failed update and
    of each piece refused as implausible."""
    import copy

    estimator = StreamingEstimator(ctx, config, copy.deepcopy(stream_config), sequence=track.sequence,
                                   ground=track.ground)
    results, causal, failed = [], [], []

    def collect():
        results.extend(estimator.pop_finished())
        failed.extend({"stage": "plausibility", "error": bad["error"]} for bad in estimator.pop_failed())

    for fr in sorted(track.frames, key=lambda f: (float(f.timestamp), f.frame)):
        current = estimator.add_frame(float(fr.timestamp), {track.tracking_id: fr}, track.calibrations)
        if track.tracking_id in current:
            causal.append(current[track.tracking_id])
        else:
            failed.append({"frame": int(fr.frame), "error": "update failed (see the log)"})
        collect()
    results.extend(estimator.finish())
    collect()
    return results, causal, failed


def stream_task(track: Track, params: tuple):
    """The task of one track in :func:`stream_dataset` (run in a worker): ``params = (config, stream_config,
    ctx or None)`` -> :class:`~pedx_graph.execution.tasks.TrackOutput` with the smoothed labels, the causal
    labels (under ``causal/``), the track's records (failed updates in the first one's ``failed_updates``)
    and its per-update latencies (``update_ms``, ``cpu_ms``, ``isam_ms``) as timings."""
    from pedx_graph.execution.tasks import label_files, result_output
    from pedx_graph.solvers.fit import _context

    config, stream_config, ctx = params
    results, causal, failed = stream_track(track, ctx or _context(config), config, stream_config)
    if not results:
        reasons = "; ".join(sorted({bad["error"] for bad in failed})) or "no frame"
        raise RuntimeError(f"no smoothed estimate of the track ({reasons})")
    causal_files = label_files([_causal_label(track.sequence, e) for e in causal], prefix="causal")
    output = result_output(results, extra_files=causal_files, extra_timings={
        "update_ms": [e.update_seconds * 1e3 for e in causal], "cpu_ms": [e.cpu_seconds * 1e3 for e in causal],
        "isam_ms": [e.isam_seconds * 1e3 for e in causal]})
    if failed:
        output.records[0]["failed_updates"] = failed
    return output


def stream_warm_up(params: tuple) -> None:
    """Load the estimator context of ``params = (config, stream_config, ctx or None)`` in this worker."""
    from pedx_graph.solvers.fit import _context

    if params[2] is None:
        _context(params[0])


def stream_timings(tracks: list[dict]) -> dict:
    """Whole-run latency figures (``update_ms``: median, p90, max, mean of the updates' wall time; CPU time;
    the ISAM2 update alone) from the tracks' per-update lists, which are then dropped from the entries."""
    lat, cpu, isam = [], [], []
    for entry in tracks:
        lat += entry.pop("update_ms", None) or []
        cpu += entry.pop("cpu_ms", None) or []
        isam += entry.pop("isam_ms", None) or []
    if not lat:
        return {}
    lat, cpu, isam = np.asarray(lat), np.asarray(cpu), np.asarray(isam)
    return {"update_ms": {"median": float(np.median(lat)), "p90": float(np.percentile(lat, 90)),
                          "max": float(lat.max()), "mean": float(lat.mean()),
                          "cpu_median": float(np.median(cpu)) if cpu.size else None,
                          "cpu_p90": float(np.percentile(cpu, 90)) if cpu.size else None,
                          "isam_update_median": float(np.median(isam)) if isam.size else None,
                          "isam_update_p90": float(np.percentile(isam, 90)) if isam.size else None}}


def stream_dataset(dataset, out, config: FitConfig | None = None, stream_config: StreamConfig | None = None,
                   ctx=None, sequences: list[str] | None = None, *, workers: int = 1, cluster: str | None = None,
                   resume: bool = False, overwrite: bool = False, progress: bool = False,
                   keep_records: bool = True, on_track=None) -> dict:
    """Stream every track of ``dataset`` (its frames in timestamp order, one task per track) and write under
    ``out`` as each track completes:

    * ``causal/labels/3d/smpl/...``: the causal estimate of the track after each of its frames;
    * ``labels/3d/smpl/...``: the smoothed estimate of the track once it ends (with covariances);
    * ``summary.json``: per track errors, diagnostics, failed updates; the update latencies (per track and
      over the run) in its ``timings`` section;
    * ``fit_config.yaml`` / ``stream_config.yaml``, ``manifest.json``, ``done/`` (completion markers).

    Each track is its own task (as ``fit``): results do not depend on which tracks share a process or a
    run, a failing track stops nothing else, resume and scale-out are per track.  (:class:`StreamingEstimator`
    itself takes all pedestrians of a sample at once, as a live system would; here each task feeds one.)
    Executor, resume and overwrite as :func:`pedx_graph.solvers.fit.fit_dataset`; a given ``ctx`` (estimator
    context) is used in this process only (``workers=1``).
    """
    from pedx_graph.data.noise_estimate import resolve_noise
    from pedx_graph.execution.executors import ExecutorSpec
    from pedx_graph.execution.runner import RunSpec, run_dataset

    config = config or FitConfig()
    stream_config = stream_config or StreamConfig()

    def make_params(tracks):
        # the click and range noise from the data, as the batch fit (pedx_graph.data.noise_estimate)
        resolved = resolve_noise(tracks, config.noise)
        return (dataclasses.replace(config, noise=resolved.noise), stream_config, ctx), {"noise": resolved.record}

    spec = RunSpec(command="stream", method="isam2-stream", method_key="solver", dataset=dataset,
                   task_fn=stream_task, configs={"fit_config": config, "stream_config": stream_config},
                   make_params=make_params, sequences=sequences, reader_config=config.reader_config(),
                   summarise_timings=stream_timings, inline_only=ctx is not None, warm_up=stream_warm_up)
    return run_dataset(spec, out, ExecutorSpec(workers=workers, cluster=cluster), resume=resume,
                       overwrite=overwrite, progress=progress, keep_records=keep_records, on_track=on_track)
