"""Batch LM fit of one track (offline smoothing): track -> staged LM over its graph -> :class:`TrackResult`."""
from __future__ import annotations

import time

from pedx_graph.data.types import Track
from pedx_graph.detections.fit_layout import fit_layout
from pedx_graph.graph.build import extract_estimate
from pedx_graph.graph.config import FitConfig
from pedx_graph.solvers.context import estimator_context
from pedx_graph.solvers.diagnostics import track_extras
from pedx_graph.solvers.plausibility import check_track_result
from pedx_graph.solvers.result import TrackResult, record_depth_sources
from pedx_graph.solvers.staging import single_frame_search, solve_staged


def fit_track(track: Track, config: FitConfig | None = None, context=None) -> TrackResult:
    """Fit one track with batch LM (the whole track at once)."""
    config = config or FitConfig()
    ctx = context or estimator_context(config)
    t0 = time.perf_counter()
    report_ctx = ctx                          # results: PedX keypoints of the original model, whatever the labels
    track, ctx, config = fit_layout(track, ctx, config)   # detector sets: their own points, 18 + E rows
    if len(track.frames) == 1:
        problem, values, report = single_frame_search(track, ctx, config)
    else:
        problem, values, report = solve_staged(track, ctx, config)
    est = extract_estimate(problem, values, report_ctx)
    seconds = time.perf_counter() - t0
    t1 = time.perf_counter()       # the body plausibility fields always, covariances / diagnostics if asked
    per_frame, per_track = track_extras(problem, values, ctx, marginals=config.covariances,
                                        diagnostics=config.diagnostics, fit_config=config, frames=track.frames)
    per_track["extras_seconds"] = time.perf_counter() - t1
    record_depth_sources(problem.init, per_frame, per_track)
    if report.flips:
        per_track["flips"] = report.flips
    if report.dropped_views:
        per_track["dropped_views"] = report.dropped_views
    if report.mirrored_labels:
        per_track["mirrored_labels"] = report.mirrored_labels
    result = TrackResult(sequence=track.sequence, tracking_id=track.tracking_id,
                         frames=[fr.frame for fr in track.frames], pose=est.pose, betas=est.betas,
                         trans=est.trans, world_keypoints=est.world_keypoints,
                         final_error=report.final_error, initial_error=report.initial_error,
                         iterations=report.iterations, seconds=seconds, solver=f"lm-{report.backend}",
                         extra_per_frame=per_frame, extra_track=per_track)
    return check_track_result(result, track, config, problem, values)    # ImplausibleEstimateError: a failed track

