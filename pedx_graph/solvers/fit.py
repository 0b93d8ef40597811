"""Batch fit of whole tracks (offline smoothing) and of whole datasets.

``fit_track``: track -> graph -> LM -> :class:`TrackResult`.  ``fit_dataset``: every track of every
sequence as one task each (:func:`fit_task`, run by :mod:`pedx_graph.execution` in this process, on a local
process pool or on a Dask cluster; graphs holding CustomFactors cannot be pickled, so each worker builds its
own graph from the track's numpy data), results written in the PedX SMPL layout as each track completes,
with a manifest, completion markers, ``summary.json`` and the resolved config beside them (resumable).  One
failing track is reported in the summary and never stops the run.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import threading
import time
import traceback
from dataclasses import dataclass, field

import numpy as np

from pedx_graph.data.types import SmplLabel, Track
from pedx_graph.graph.config import FitConfig

log = logging.getLogger(__name__)


@dataclass
class TrackResult:
    """Estimate of one track (world frame), with solver statistics."""

    sequence: str
    tracking_id: str
    frames: list[int]
    pose: np.ndarray
    """(T, 72) axis-angle, root first (root = world_R_body)."""
    betas: np.ndarray
    """(10,) the track's shared shape."""
    trans: np.ndarray
    """(T, 3) smplx translation (added after skinning), metres."""
    world_keypoints: np.ndarray
    """(T, 18, 3) PedX keypoints of the fitted model in the world frame, metres."""
    final_error: float
    initial_error: float
    iterations: int
    seconds: float
    solver: str
    extra_per_frame: list[dict] = field(default_factory=list)
    """Per-frame extra fields written with each label (covariances, diagnostics)."""
    extra_track: dict = field(default_factory=dict)
    """Per-track extra fields (shape covariance, residual totals, ...)."""

    def to_labels(self) -> list[SmplLabel]:
        """One PedX SMPL label per frame, with our extra fields (no timings: result files are the same for
        the same input, whatever ran them; times go to the summary)."""
        labels = []
        for i, frame in enumerate(self.frames):
            extra = {"keypoints_3d": self.world_keypoints[i], "keypoint_names": _names(),
                     "track_final_error": self.final_error, "track_iterations": self.iterations,
                     "solver": self.solver}
            if self.extra_per_frame:
                extra.update(self.extra_per_frame[i])
            labels.append(SmplLabel(sequence=self.sequence, frame=int(frame), tracking_id=self.tracking_id,
                                    betas=self.betas, pose=self.pose[i], trans=self.trans[i], extra=extra))
        return labels


def _names() -> list[str]:
    from pedx_graph.keypoints import PEDX_KEYPOINTS
    return list(PEDX_KEYPOINTS)


# --- per-process state (body model and priors are loaded once per worker) -------------------------------
_WORKER: dict = {}
_WORKER_LOCK = threading.Lock()


def _context(config: FitConfig):
    """The estimator context (body model, priors) of ``config``, made once per process (per config)."""
    from pedx_graph.execution.tasks import limit_blas_threads

    key = (config.body_model, config.pose_prior, config.temporal_prior, config.prior_covariance_scale,
           config.chamfer_vertices, config.noise.shape_sigma)
    limit_blas_threads()       # small dense products: processes over tracks use the cores instead
    with _WORKER_LOCK:         # a Dask worker may run tasks in several threads
        if _WORKER.get("key") != key:
            from pedx_graph.graph.build import EstimatorContext
            _WORKER["ctx"] = EstimatorContext.create(config)
            _WORKER["key"] = key
        return _WORKER["ctx"]


def fit_track(track: Track, config: FitConfig | None = None, context=None) -> TrackResult:
    """Fit one track with batch LM (the whole track at once)."""
    from pedx_graph.graph.build import extract_estimate

    config = config or FitConfig()
    ctx = context or _context(config)
    t0 = time.perf_counter()
    report_ctx = ctx                          # results: PedX keypoints of the original model, whatever the labels
    if track.keypoint_set != "pedx18":        # detector labels: the set's own points in the 18-row fit layout
        from pedx_graph.detections.fit_layout import fit_layout
        track, ctx, config = fit_layout(track, ctx, config)
    if len(track.frames) == 1:
        problem, values, report = _single_frame_search(track, ctx, config)
    else:
        problem, values, report = solve_staged(track, ctx, config)
    est = extract_estimate(problem, values, report_ctx)
    seconds = time.perf_counter() - t0
    from pedx_graph.solvers.diagnostics import track_extras

    t1 = time.perf_counter()       # the body plausibility fields always, covariances / diagnostics if asked
    per_frame, per_track = track_extras(problem, values, ctx, marginals=config.covariances,
                                        diagnostics=config.diagnostics, fit_config=config, frames=track.frames)
    per_track["extras_seconds"] = time.perf_counter() - t1
    record_depth_sources(problem.init, per_frame, per_track)
    if report.flips:
        per_track["flips"] = report.flips
    result = TrackResult(sequence=track.sequence, tracking_id=track.tracking_id,
                         frames=[fr.frame for fr in track.frames], pose=est.pose, betas=est.betas,
                         trans=est.trans, world_keypoints=est.world_keypoints,
                         final_error=report.final_error, initial_error=report.initial_error,
                         iterations=report.iterations, seconds=seconds, solver=f"lm-{report.backend}",
                         extra_per_frame=per_frame, extra_track=per_track)
    from pedx_graph.solvers.plausibility import check_track_result
    return check_track_result(result, track, config, problem, values)    # ImplausibleEstimateError: a failed track


def record_depth_sources(init, per_frame: list[dict], per_track: dict) -> None:
    """What placed each frame in depth (``TrackInit.depth_source``: lidar, stereo, multi_view, body_size) into
    the per-frame fields, and their counts into the track's (``depth_sources``); a track placed by body size
    alone is flagged ``depth_from_body_size`` (its depth is as uncertain as the person's size)."""
    sources = None if init is None else init.depth_source
    if not sources:
        return
    for fields, source in zip(per_frame, sources):
        fields["depth_source"] = source
    counts: dict[str, int] = {}
    for source in sources:
        counts[source] = counts.get(source, 0) + 1
    per_track["depth_sources"] = dict(sorted(counts.items()))
    per_track["depth_from_body_size"] = set(counts) <= {"body_size", "none"} and "body_size" in counts


def coarse_stage_config(config: FitConfig) -> FitConfig:
    """The first stage's config: no LiDAR chamfer term, the stereo reprojection with
    ``solver.coarse_reprojection_loss``."""
    return dataclasses.replace(
        config, terms=dataclasses.replace(config.terms, lidar_chamfer=False),
        noise=dataclasses.replace(config.noise, reprojection_loss=config.solver.coarse_reprojection_loss))


def solve_staged(track: Track, ctx, config: FitConfig, yaw_override=None):
    """Solve in two stages, as the paper's staged fitting: first without the LiDAR chamfer term (its
    nearest-vertex correspondences only pull the right way once the body is roughly in place) and with the
    stereo reprojection's ``solver.coarse_reprojection_loss`` (graduated non-convexity), then with every
    term from that estimate.  Then, for tracks at range walking towards or away from the camera, the limb
    depth-flip search (:mod:`pedx_graph.solvers.flips`, ``solver.flip_*``), which only ever lowers the
    error; tracks labelled in one camera per frame always get the search.  Returns (problem, values, report) of the final stage; the report's iterations and seconds
    cover every stage and the search, its initial error is the full graph's at the first stage's
    estimate, ``report.flips`` records the search (empty when it did not run)."""
    problem, values, report = _two_stages(track, ctx, config, yaw_override)
    # one camera per frame: a limb mirrored across the viewing ray projects the same at any range and
    # heading, so such tracks always get the search; with stereo only far tracks walking along the ray do
    one_camera = all(len(fr.labelled_views(config.terms.all_views)) <= 1 for fr in track.frames)
    if config.solver.flip_segments and len(track.frames) > 1 and (one_camera or (
            track_distance_m(track, problem.init) >= config.solver.flip_min_distance_m and
            heading_ray_angle_deg(track, problem.init) <= config.solver.flip_max_heading_angle_deg)):
        from pedx_graph.solvers.flips import flip_search

        values, flips = flip_search(problem, values, track, ctx, config, _solver_parts(problem, config))
        report.final_error = flips.final_error
        report.iterations += flips.iterations
        report.seconds += flips.seconds
        report.flips = dataclasses.asdict(flips)
    return problem, values, report


def track_distance_m(track: Track, init) -> float:
    """Median distance (m) of the track's initial body centres from their frames' left cameras."""
    centres = np.stack([track.calibrations[fr.pair].world_T_cam[:3, 3] for fr in track.frames])
    dist = np.linalg.norm(np.asarray(init.world_p_centre, float) - centres, axis=1)
    dist = dist[np.isfinite(dist)]
    return float(np.median(dist)) if dist.size else float("nan")


def heading_ray_angle_deg(track: Track, init) -> float:
    """Median angle (degrees, 0-90) between the trajectory heading and the ray from the camera to the body,
    both laid on the ground plane (``track.ground``'s level frame): 0 walking straight towards or away
    from the camera, 90 walking across.  NaN (no frame with a known heading) compares false with every
    threshold."""
    centres = np.stack([track.calibrations[fr.pair].world_T_cam[:3, 3] for fr in track.frames])
    ray = track.ground.level_directions(np.asarray(init.world_p_centre, float) - centres)[:, :2]
    yaw = np.asarray(init.heading_yaw, float)
    heading = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    cos = np.abs(np.sum(ray * heading, axis=1)) / np.linalg.norm(ray, axis=1)
    cos = cos[np.isfinite(cos)]
    return float(np.degrees(np.arccos(np.clip(np.median(cos), 0.0, 1.0)))) if cos.size else float("nan")


def _two_stages(track: Track, ctx, config: FitConfig, yaw_override=None):
    """The staged fit itself: (problem, values, report) as :func:`solve_staged` before the flip search."""
    from pedx_graph.graph.build import build_track_graph
    from pedx_graph.solvers.lm import solve

    if not config.terms.lidar_chamfer:
        problem = build_track_graph(track, ctx, config, yaw_override=yaw_override)
        values, report = solve(problem.graph, problem.initial, config.solver, *_solver_parts(problem, config))
        return problem, values, report
    coarse_config = coarse_stage_config(config)
    coarse_solver = dataclasses.replace(config.solver, max_iterations=config.solver.coarse_max_iterations,
                                        relative_error_tol=config.solver.coarse_relative_error_tol)
    one_graph = coarse_config.noise.reprojection_loss == config.noise.reprojection_loss
    if one_graph:
        problem = build_track_graph(track, ctx, config, yaw_override=yaw_override)
        coarse = problem.without({"lidar_chamfer"})          # the same factors, the chamfer left out
    else:
        coarse = build_track_graph(track, ctx, coarse_config, yaw_override=yaw_override)
    coarse_values, coarse_report = solve(coarse.graph, coarse.initial, coarse_solver,
                                         *_solver_parts(coarse, config))
    if one_graph:
        problem.initial = coarse_values
    else:
        problem = build_track_graph(track, ctx, config, initial=coarse_values, init=coarse.init)
    values, report = solve(problem.graph, problem.initial, config.solver, *_solver_parts(problem, config))
    report.iterations += coarse_report.iterations
    report.seconds += coarse_report.seconds
    return problem, values, report


def _solver_parts(problem, config: FitConfig) -> tuple:
    """``(prefetch, layout, linearizer)`` for :func:`pedx_graph.solvers.lm.solve` as ``config.solver`` asks."""
    from pedx_graph.solvers.batched import BatchedLinearizer

    solver = config.solver
    if solver.linear_solver not in ("chain", "gtsam"):
        raise ValueError(f"solver.linear_solver must be 'chain' or 'gtsam', got {solver.linear_solver!r}")
    if solver.linearization not in ("batched", "graph"):
        raise ValueError(f"solver.linearization must be 'batched' or 'graph', got {solver.linearization!r}")
    layout = problem.layout if solver.linear_solver == "chain" else None
    linearizer = BatchedLinearizer(problem) if solver.linearization == "batched" and layout is not None else None
    return problem.prefetch, layout, linearizer


def _single_frame_search(track: Track, ctx, config: FitConfig, n_headings: int = 8):
    """A single frame has no trajectory heading: start from the triangulated-torso heading and from
    ``n_headings`` evenly spaced headings, keep the solution of lowest final error."""
    from pedx_graph.graph.build import build_track_graph
    from pedx_graph.graph.init import yaw_of

    base = build_track_graph(track, ctx, config)
    start = yaw_of(base.init.world_R_body[0], track.ground)
    candidates = [np.array([start])] + [
        np.array([yaw]) for yaw in np.linspace(-np.pi, np.pi, n_headings, endpoint=False)
        if abs(np.angle(np.exp(1j * (yaw - start)))) > 1e-3]
    best = None
    for yaw in candidates:
        problem, values, report = solve_staged(track, ctx, config, yaw_override=yaw)
        if best is None or report.final_error < best[2].final_error:
            best = (problem, values, report)
    return best


#: Solvers of ``pedx-graph fit --solver``: batch LM over the joint graph, or the paper's ADMM.
SOLVERS = ("lm", "admm")


def track_failure(track: Track, exc: BaseException) -> tuple[str, str, str, str]:
    """The error record of a track that failed: (sequence, tracking_id, message, short traceback)."""
    return (track.sequence, track.tracking_id, f"{type(exc).__name__}: {exc}", traceback.format_exc(limit=4))


def map_tracks(job_fn, jobs: list, workers: int = 1):
    """``job_fn`` over ``jobs`` in order, in a local process pool when ``workers > 1`` (``job_fn`` must be a
    module-level function returning (result or None, error or None)); the workers ignore SIGINT and exit
    with this process (:func:`pedx_graph.execution.executors.map_ordered`)."""
    from pedx_graph.execution.executors import map_ordered

    yield from map_ordered(job_fn, jobs, workers)


def _fit_one(args):
    track, config, solver = args
    try:
        return _fit_result(track, config, solver), None
    except Exception as exc:  # one bad track never kills the run
        return None, track_failure(track, exc)


def _fit_result(track: Track, config: FitConfig, solver: str) -> TrackResult:
    if solver == "admm":
        from pedx_graph.solvers.admm import fit_track_admm
        return fit_track_admm(track, config, _context(config), marginals=config.covariances,
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
    from pedx_graph.execution.tasks import result_output

    config, solver = params
    return result_output([_fit_result(track, config, solver)])


def fit_warm_up(params: tuple) -> None:
    """Load the estimator context (body model, priors) of ``params = (config, solver)`` in this worker."""
    _context(params[0])


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
    from pedx_graph.data.noise_estimate import resolve_noise
    from pedx_graph.execution.executors import ExecutorSpec
    from pedx_graph.execution.runner import RunSpec, run_dataset

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
