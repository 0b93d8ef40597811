"""Streaming estimation: frames arrive in timestamp order across all tracks; one iSAM2 per active track.

:class:`StreamingEstimator` (the live API)::

    est = StreamingEstimator(ctx, config)
    current = est.add_frame(timestamp, {tracking_id: TrackFrame, ...}, calibrations)   # -> {tid: FrameEstimate}
    results = est.finish()                                                            # -> [TrackResult]

A track begins when its id is first seen and ends when it has not been seen for ``track_timeout_s``
(or at :meth:`StreamingEstimator.finish`); an ended track is finalised (smoothed over all its frames,
:mod:`pedx_graph.solvers.stream.finalise`) and returned as a :class:`~pedx_graph.solvers.fit.TrackResult`
with marginal covariances and diagnostics.

Causality: a frame's factors use only that frame and earlier ones.  They are the batch graph's factors
(:mod:`pedx_graph.graph.build`, same noise, same seeded LiDAR subsample per track, the translation prior
on the points' core; ``StreamingEstimator._frame_factors`` mirrors ``build_track_graph`` and must follow
its changes: ``test_stream_factors_match_batch_graph`` checks it) except the heading prior,
whose trajectory heading is estimated from the frames up to now (a one-sided window of ``half_window_s``)
instead of a centred one.  New variables start from the previous frame's estimate (root; the body pose
extrapolated at constant joint-angle velocity, ``StreamConfig.predict_body_pose``,
:mod:`pedx_graph.solvers.stream.prediction`) and the frame's LiDAR / stereo centre (translation,
:mod:`pedx_graph.solvers.stream.causal_init`), then a damped Gauss-Newton step on the new frame alone
(``IsamConfig.presolve_iterations`` / ``presolve_method``; without the chamfer term,
``StreamConfig.presolve_exclude``) before the iSAM2 update.

Speed: each frame's initialisation measurements are taken once and kept; a frame's own factors enter iSAM2
linearised once, as one Hessian-form factor (``IsamConfig.linearize_frame_factors``); the pedestrians of
a sample go through the steps together so the body model is evaluated for all of them in one batched call
per step (see :meth:`StreamingEstimator.add_frame`), and the new frames' Gauss-Newton systems (presolve and
update) are formed for all of them in one batched pass without GTSAM callbacks
(:mod:`pedx_graph.solvers.stream.systems`, ``StreamConfig.batched_frame_systems``); measured in
``benchmarks/bench_solvers.py``.
"""
from __future__ import annotations

import logging
import time

import gtsam
import numpy as np

from factors.common import FrameKeys
from factors.shape_prior import shape_factors
from pedx_graph.data.ground import GroundFrame, ground_from_calibrations
from pedx_graph.data.types import StereoCalibration, TrackFrame
from pedx_graph.graph.build import frame_factors
from pedx_graph.graph.config import FitConfig
from pedx_graph.graph.init import FrameMeasurements, measure_frame
from pedx_graph.solvers.frame_system import OWN_KINDS, RecordingBody, SpecRecorder
from pedx_graph.solvers.isam import IncrementalTrack
from pedx_graph.solvers.marginals import frame_fields, isam_frame_covariance
from pedx_graph.solvers.plausibility import ImplausibleEstimateError
from pedx_graph.solvers.stream.causal_init import best_facing, causal_init, initial_values
from pedx_graph.solvers.stream.config import StreamConfig
from pedx_graph.solvers.stream.finalise import finalise_track
from pedx_graph.solvers.stream.state import ActiveTrack, FrameEstimate, FrameInit
from pedx_graph.solvers.stream.step import Step
from pedx_graph.solvers.stream.systems import StreamBody, form_systems, prefetch_states

log = logging.getLogger(__name__)


def presolve_factors(graph: gtsam.NonlinearFactorGraph, kinds: list[str], exclude) -> gtsam.NonlinearFactorGraph | None:
    """The new frame's factors without the kinds in ``exclude`` (``StreamConfig.presolve_exclude``; None:
    all of them are kept)."""
    exclude = set(exclude or ())
    if not exclude.intersection(kinds):
        return None
    out = gtsam.NonlinearFactorGraph()
    for j, kind in enumerate(kinds):
        if kind not in exclude:
            out.add(graph.at(j))
    return out


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
        self.active: dict[str, ActiveTrack] = {}
        self.finished: list = []
        self.failed_tracks: list[dict] = []
        self.body = StreamBody(ctx.model, ctx.chamfer_vertex_ids)
        """The body model the streamed factors evaluate (batched over each sample's pedestrians)."""
        self._recording = RecordingBody(self.body, SpecRecorder())
        """:attr:`body` as the factors see it when their specs are recorded (the recorder is swapped for each
        new frame before its factors are built; one object, so per-model caches such as
        :func:`factors.translation_prior.pelvis_shape_basis` keep hitting)."""

    # --- factors of one new frame (pedx_graph.graph.build.frame_factors, as the batch graph) -------------
    def _frame_factors(self, state: ActiveTrack, i: int, fr: TrackFrame, window: list[FrameMeasurements],
                       model=None) -> tuple[gtsam.NonlinearFactorGraph, FrameInit]:
        noise, ctx, model = self.config.noise, self.ctx, model or self.body
        k = state.keys[i]
        graph = gtsam.NonlinearFactorGraph()

        def add(factor, kind):
            if factor is not None:
                graph.add(factor)
                state.kinds.append(kind)
                state.factor_frames.append(i if kind != "shape_prior" else -1)

        init = causal_init(state, window, ctx.model, self.config, self.stream_config.heading_half_window_s,
                           self.ground)
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

    # --- public API ----------------------------------------------------------------------------------------
    def add_frame(self, timestamp: float, observations: dict[str, TrackFrame],
                  calibrations: dict[str, StereoCalibration]) -> dict[str, FrameEstimate]:
        """Add one synchronised sample: ``observations`` maps tracking id -> that pedestrian's measurements.

        Returns the current (causal) estimate of every pedestrian observed in this sample.  Tracks not seen
        for ``track_timeout_s`` end here (finalised; collect them with :meth:`pop_finished`).

        The pedestrians of the sample go through each step together (initial values; presolve; iSAM2
        update; estimate), so the body model is evaluated for all of them in one batched call before the
        presolves, the updates and the keypoint read-out (:func:`~pedx_graph.solvers.stream.systems.
        prefetch_states`); each pedestrian's latency is its own work plus an equal share of those batched
        calls.
        """
        self._end_stale(timestamp, keep=observations.keys())
        steps: list[Step] = []
        for tid, fr in observations.items():
            step = self._guarded(None, lambda: self._begin(timestamp, tid, fr, calibrations), tid, fr)
            if step is not None:
                steps.append(step)
        if self.stream_config.isam.presolve_iterations > 0:
            self._shared(steps, lambda: self._systems(steps, presolve=True))
        steps = [s for s in steps if self._guarded(s, lambda: s.presolve()) is not None]
        self._shared(steps, lambda: self._systems(steps, presolve=False))
        steps = [s for s in steps if self._guarded(s, lambda: s.commit()) is not None]
        self._shared(steps, lambda: prefetch_states(
            self.body, [s.state.read_estimate(s.i, self.ctx.model) for s in steps], jacobians=False,
            vertices=False))
        out = {}
        for step in steps:
            try:
                out[step.tid] = self._finish_step(step, timestamp)
            except Exception as exc:        # one bad observation never stops the stream
                log.warning("stream: %s frame %s: %s: %s", step.tid, step.fr.frame, type(exc).__name__, exc)
        return out

    def _guarded(self, step: Step | None, work, tid=None, fr=None):
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
    def _shared(steps: list[Step], work) -> None:
        """``work()`` (a batched call for all ``steps``), its time shared equally by the steps."""
        if not steps:
            return
        c0, t0 = time.process_time(), time.perf_counter()
        work()
        cpu, wall = (time.process_time() - c0) / len(steps), (time.perf_counter() - t0) / len(steps)
        for step in steps:
            step.cpu_seconds += cpu
            step.seconds += wall

    def _begin(self, timestamp, tid, fr, calibrations) -> Step:
        """A new observation's causal initialisation, factors and initial values."""
        if self.ground is None:
            self.ground = ground_from_calibrations(calibrations, self.sequence)
        state = self.active.get(tid)
        if state is None:
            state = ActiveTrack(sequence=self.sequence, tracking_id=tid, calibrations=dict(calibrations),
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
            if self.stream_config.batched():
                recorder = self._recording.term_cache = SpecRecorder()
            graph, init = self._frame_factors(state, i, fr, window, None if recorder is None else self._recording)
            values = initial_values(state, i, init, self.ctx, self.config, self.ground,
                                    self.stream_config.predict_body_pose)
            if i == 0 and not np.isfinite(init.heading_yaw):
                values = best_facing(graph, values, state.keys[0],
                                     max(self.stream_config.isam.presolve_iterations, 1))
            kinds = state.kinds[n_kinds:]
            presolve = presolve_factors(graph, kinds, self.stream_config.presolve_exclude)
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
        return Step(tid=tid, fr=fr, state=state, i=i, n_kinds=n_kinds, graph=graph,
                    presolve_graph=graph if presolve is None else presolve, values=values, specs=specs,
                    presolve_rest=rest, temporal=temporal, recorder=recorder)

    def _systems(self, steps: list[Step], presolve: bool) -> None:
        """The steps' systems for the presolve or the update (:func:`~pedx_graph.solvers.stream.systems.
        form_systems`)."""
        form_systems(self.body, steps, presolve, self.stream_config)

    def _rollback(self, state: ActiveTrack, i: int, n_kinds: int) -> None:
        state.rollback(i, n_kinds)
        if not state.frames:
            self.active.pop(state.tracking_id, None)

    def _finish_step(self, step: Step, timestamp: float) -> FrameEstimate:
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
        try:
            cov = isam_frame_covariance(state.smoother.isam, state.keys[i], len(betas))
        except RuntimeError as exc:
            return {"covariance_status": f"failed: {exc}"}
        fields = frame_fields(self.ctx.model, pose, betas, trans, cov, False, self.config.marginals)
        return {k: fields[k] for k in ("covariance_status", "cov_trans", "cov_root", "cov_keypoints_3d")}

    def _end_stale(self, now: float, keep=()) -> None:
        keep = set(keep)
        for tid in [t for t, s in self.active.items()
                    if t not in keep and now - s.last_seen > self.stream_config.track_timeout_s]:
            self.end_track(tid)

    def end_track(self, tracking_id: str):
        """Finalise one track now: smoothed estimate, marginals, diagnostics -> :class:`TrackResult`."""
        state = self.active.pop(tracking_id)
        try:
            result = finalise_track(state, self.ctx, self.config, self.stream_config, self.ground)
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
