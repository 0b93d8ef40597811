"""Finalisation of an ended streamed track: smoothing (iSAM2 warm start or batch restart), estimate,
covariances, diagnostics and the plausibility check -> ``TrackResult``."""
from __future__ import annotations

import logging
import time

import gtsam

from pedx_graph.data.ground import GroundFrame
from pedx_graph.data.types import Track
from pedx_graph.graph.build import TrackProblem, extract_estimate
from pedx_graph.graph.config import FitConfig
from pedx_graph.solvers.diagnostics import track_extras
from pedx_graph.solvers.plausibility import check_track_result
from pedx_graph.solvers.result import TrackResult
from pedx_graph.solvers.staging import solve_staged
from pedx_graph.solvers.stream.config import StreamConfig
from pedx_graph.solvers.stream.latency import track_latencies, track_latency_fields
from pedx_graph.solvers.stream.state import ActiveTrack

log = logging.getLogger(__name__)


def restart_if_better(state: ActiveTrack, values: gtsam.Values, ctx, config: FitConfig,
                      ground: GroundFrame | None) -> tuple[gtsam.Values, str]:
    """The batch fit of the track's frames if it has a lower error on the streamed graph."""
    track = Track(state.sequence, state.tracking_id, list(state.frames), dict(state.calibrations), ground=ground)
    try:
        _, batch_values, _ = solve_staged(track, ctx, config)
        if state.smoother.factors.error(batch_values) < state.smoother.factors.error(values):
            return batch_values, "batch_restart"
    except Exception as exc:          # the warm-started estimate stands
        log.warning("stream: batch restart of %s failed: %s", state.tracking_id, exc)
    return values, "isam_warm_start"


def finalise_track(state: ActiveTrack, ctx, config: FitConfig, stream_config: StreamConfig,
                   ground: GroundFrame | None) -> TrackResult | None:
    """The smoothed :class:`TrackResult` of an ended track (None without frames); raises
    :class:`~pedx_graph.solvers.plausibility.ImplausibleEstimateError` when the estimate is implausible."""
    if not state.frames:
        return None
    t0 = time.perf_counter()
    latencies, isam_only = track_latencies(state)
    values = state.smoother.finalize(config.solver)
    final_from = "isam_warm_start"
    if stream_config.final_restart and len(state.frames) >= 2:
        values, final_from = restart_if_better(state, values, ctx, config, ground)
    finalize_s = time.perf_counter() - t0
    problem = TrackProblem(graph=state.smoother.factors, initial=values, keys=state.keys, init=None,
                           factor_kinds=state.kinds, factor_frames=state.factor_frames, ground=ground)
    est = extract_estimate(problem, values, ctx)
    extra_track = track_latency_fields(latencies, isam_only)
    extra_track.update({"stream_finalize_seconds": finalize_s, "stream_final_from": final_from})
    # the body plausibility fields always, covariances / diagnostics when asked
    extra_frames, track_fields = track_extras(problem, values, ctx, stream_config.marginals,
                                              stream_config.diagnostics, fit_config=config, frames=state.frames)
    extra_track.update(track_fields)
    graph_error = float(problem.graph.error(values))
    result = TrackResult(sequence=state.sequence, tracking_id=state.tracking_id,
                         frames=[fr.frame for fr in state.frames], pose=est.pose, betas=est.betas,
                         trans=est.trans, world_keypoints=est.world_keypoints, final_error=graph_error,
                         initial_error=float("nan"), iterations=len(state.smoother.updates),
                         seconds=float(latencies.sum()) + finalize_s, solver="isam2-stream",
                         extra_per_frame=extra_frames, extra_track=extra_track)
    track = Track(state.sequence, state.tracking_id, list(state.frames), dict(state.calibrations), ground=ground)
    return check_track_result(result, track, config, problem, values)   # raises when implausible
