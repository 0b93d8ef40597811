"""Fitting tracks and datasets (the ``fit`` command's work) with the solver chosen per run: batch LM
(:mod:`pedx_graph.solvers.track_lm`) or ADMM (:mod:`pedx_graph.solvers.admm`).

``fit_dataset``: every track of every sequence as one task each (:func:`fit_task`, run by
:mod:`pedx_graph.execution` in this process, on a local process pool or on a Dask cluster; graphs holding
CustomFactors cannot be pickled, so each worker builds its own graph from the track's numpy data), results
written in the PedX SMPL layout as each track completes, with a manifest, completion markers,
``summary.json`` and the resolved config beside them (resumable).  One failing track is reported in the
summary and never stops the run.

The names of one track's fit are importable from here too (``fit_track``, ``TrackResult``, ``solve_staged``,
...): they live in :mod:`~pedx_graph.solvers.track_lm`, :mod:`~pedx_graph.solvers.result`,
:mod:`~pedx_graph.solvers.staging` and :mod:`~pedx_graph.solvers.context`.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import traceback

from pedx_graph.data.noise_estimate import resolve_noise
from pedx_graph.data.types import Track
from pedx_graph.execution.executors import ExecutorSpec, map_ordered
from pedx_graph.execution.runner import RunSpec, run_dataset
from pedx_graph.execution.tasks import result_output
from pedx_graph.graph.config import FitConfig
from pedx_graph.solvers.admm import fit_track_admm
from pedx_graph.solvers.context import estimator_context
from pedx_graph.solvers.context import estimator_context as _context
from pedx_graph.solvers.result import TrackResult, record_depth_sources
from pedx_graph.solvers.staging import coarse_stage_config, heading_ray_angle_deg, solve_staged, track_distance_m
from pedx_graph.solvers.staging import solver_parts as _solver_parts
from pedx_graph.solvers.track_lm import fit_track

__all__ = ["SOLVERS", "TrackResult", "_context", "_solver_parts", "coarse_stage_config", "estimator_context",
           "fit_dataset", "fit_task", "fit_track", "fit_tracks", "fit_warm_up", "heading_ray_angle_deg",
           "map_tracks", "record_depth_sources", "solve_staged", "track_distance_m", "track_failure"]

log = logging.getLogger(__name__)


#: Solvers of ``pedx-graph fit --solver``: batch LM over the joint graph, or the paper's ADMM.
SOLVERS = ("lm", "admm")


def track_failure(track: Track, exc: BaseException) -> tuple[str, str, str, str]:
    """The error record of a track that failed: (sequence, tracking_id, message, short traceback)."""
    return (track.sequence, track.tracking_id, f"{type(exc).__name__}: {exc}", traceback.format_exc(limit=4))


def map_tracks(job_fn, jobs: list, workers: int = 1):
    """``job_fn`` over ``jobs`` in order, in a local process pool when ``workers > 1`` (``job_fn`` must be a
    module-level function returning (result or None, error or None)); the workers ignore SIGINT and exit
    with this process (:func:`pedx_graph.execution.executors.map_ordered`)."""
    yield from map_ordered(job_fn, jobs, workers)


def _fit_one(args):
    track, config, solver = args
    try:
        return _fit_result(track, config, solver), None
    except Exception as exc:  # one bad track never kills the run
        return None, track_failure(track, exc)


def _fit_result(track: Track, config: FitConfig, solver: str) -> TrackResult:
    if solver == "admm":
        return fit_track_admm(track, config, estimator_context(config), marginals=config.covariances,
                              diagnostics=config.diagnostics)
    return fit_track(track, config)


def fit_tracks(tracks: list[Track], config: FitConfig, workers: int = 1, solver: str = "lm"):
    """Fit tracks (process pool when ``workers > 1``); yields (result or None, error or None) in order."""
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")
    yield from map_tracks(_fit_one, [(tr, config, solver) for tr in tracks], workers)


def fit_task(track: Track, params: tuple):
    """The task of one track in ``fit_dataset`` (run in a worker): ``params = (config, solver)`` ->
    :class:`~pedx_graph.execution.tasks.TrackOutput` (its labels as bytes, its summary record, timings)."""
    config, solver = params
    return result_output([_fit_result(track, config, solver)], track=track)


def fit_warm_up(params: tuple) -> None:
    """Load the estimator context (body model, priors) of ``params = (config, solver)`` in this worker."""
    estimator_context(params[0])


def fit_dataset(dataset: str | os.PathLike, out: str | os.PathLike, config: FitConfig | None = None,
                workers: int = 1, sequences: list[str] | None = None, solver: str = "lm", *,
                cluster: str | None = None, resume: bool = False, overwrite: bool = False,
                progress: bool = False, keep_records: bool = True, on_track=None) -> dict:
    """Fit every track of ``dataset`` and write results under ``out`` (PedX SMPL layout); returns the summary.

    ``workers`` local processes (1: this process) or a Dask ``cluster`` (address, scheduler file or
    ``local:N``) run one task per track; ``resume`` skips the tracks a previous run of the same work
    completed, ``overwrite`` replaces a previous run's results (an existing non-empty ``out`` is refused
    otherwise); ``progress``: a progress bar on stderr.  See :func:`pedx_graph.execution.runner.run_dataset`
    (interrupts raise ``RunInterrupted`` after writing the summary).
    """
    config = config or FitConfig()
    if solver not in SOLVERS:
        raise ValueError(f"solver must be one of {SOLVERS}, got {solver!r}")

    def make_params(tracks):
        # click noise per keypoint and LiDAR range noise from the data, once per dataset, into the config the
        # workers get (fit_config.yaml keeps the config as given); what was used goes into summary.json
        resolved = resolve_noise(tracks, config.noise)
        return (dataclasses.replace(config, noise=resolved.noise), solver), {"noise": resolved.record}

    spec = RunSpec(command="fit", method=solver, method_key="solver", dataset=dataset, task_fn=fit_task,
                   configs={"fit_config": config}, make_params=make_params, sequences=sequences,
                   reader_config=config.reader_config(), warm_up=fit_warm_up)
    return run_dataset(spec, out, ExecutorSpec(workers=workers, cluster=cluster), resume=resume,
                       overwrite=overwrite, progress=progress, keep_records=keep_records, on_track=on_track)

