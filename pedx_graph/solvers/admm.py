"""ADMM reference solver, as the PedX paper optimises a track (Sec. IV-B): per-frame problems with their own
shape copies, tied to a consensus shape.

Variables: per frame k the frame's state ``x_k`` (root, trans, body pose) and a shape copy ``beta_k``; the
consensus shape ``beta``; scaled duals ``u_k``.  One ADMM iteration t:

1. frame step, for every frame k:
   ``(x_k, beta_k) <- argmin E_k(x_k, beta_k) + rho/2 ||beta_k - beta + u_k||^2``
   where ``E_k`` is the sum of the graph's factors that involve frame k (its own terms and the temporal
   priors to frames k - 1 and k + 1, with the neighbours held at their latest values), solved to convergence
   by Levenberg-Marquardt warm-started from the previous iterate (``inner_iterations`` caps it).  Frames are updated in two
   colours (even, then odd): frames of one colour share no factor, so they are independent (a process pool
   solves them in parallel) and the temporal coupling is a block Gauss-Seidel sweep;
2. consensus step: ``beta <- argmin 0.5 ||beta / sigma_shape||^2 + sum_k rho/2 ||beta_k - beta + u_k||^2
   = rho sum_k (beta_k + u_k) / (1 / sigma_shape^2 + N rho)`` (the shape prior lives on the consensus;
   with its support hinge, ``noise.shape_support_sd``, the per-coefficient closed form of
   :func:`factors.shape_prior.consensus_shape`);
3. dual step: ``u_k <- u_k + beta_k - beta``.

Stop when ``max_k ||beta_k - beta|| < primal_tol`` and ``rho ||beta^t - beta^{t+1}|| < dual_tol``
(the paper: 0.05 each, rho = 2) or after ``max_iterations``.  The result is evaluated with the consensus
shape on the joint graph (same objective as batch LM).
"""
from __future__ import annotations

import logging
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import gtsam
import numpy as np

from factors.shape_prior import consensus_shape
from pedx_graph.detections.fit_layout import fit_layout
from pedx_graph.graph.build import build_track_graph, extract_estimate
from pedx_graph.graph.config import AdmmConfig, FitConfig
from pedx_graph.solvers.context import estimator_context
from pedx_graph.solvers.diagnostics import track_extras
from pedx_graph.solvers.lm import local_config, python_lm
from pedx_graph.solvers.plausibility import check_track_result
from pedx_graph.solvers.result import TrackResult, record_depth_sources
from pedx_graph.solvers.staging import coarse_stage_config

log = logging.getLogger(__name__)


@dataclass
class AdmmReport:
    """What an ADMM run did."""

    iterations: int
    converged: bool
    seconds: float
    initial_error: float
    final_error: float
    primal_residuals: list[float] = field(default_factory=list)
    """max_k ||beta_k - beta|| after each iteration."""
    dual_residuals: list[float] = field(default_factory=list)
    """rho ||beta^t - beta^{t+1}|| after each iteration."""
    errors: list[float] = field(default_factory=list)
    """Joint-graph error at the consensus after each iteration."""


def _frame_factor_indices(problem) -> list[list[int]]:
    """Indices of the graph factors involving frame k: its own (incl. the temporal prior to k-1) and the
    temporal prior from k+1.  The track-level shape prior is left to the consensus step."""
    n = len(problem.keys)
    out = [[] for _ in range(n)]
    for j, (kind, frame) in enumerate(zip(problem.factor_kinds, problem.factor_frames)):
        if frame < 0:
            continue
        out[frame].append(j)
        if kind == "temporal_prior" and frame > 0:
            out[frame - 1].append(j)
    return out


class _FrameSolver:
    """Solves one frame's ADMM subproblem on a built track problem (lives in each worker)."""

    def __init__(self, problem, admm: AdmmConfig):
        self.problem = problem
        self.admm = admm
        self.indices = _frame_factor_indices(problem)
        self.num_betas = int(np.asarray(problem.initial.atVector(problem.keys[0].betas)).size)

    def solve(self, k: int, states: dict, beta_k: np.ndarray, target: np.ndarray):
        """``states``: frame index -> (world_R_body, trans, body_pose) of frame k and its neighbours;
        ``target = beta - u_k``.  Returns the new (world_R_body, trans, body_pose), beta_k, error."""
        problem, keys = self.problem, self.problem.keys
        graph = gtsam.NonlinearFactorGraph()
        for j in self.indices[k]:
            graph.add(problem.graph.at(j))
        betas_key = keys[k].betas
        graph.add(gtsam.PriorFactorVector(betas_key, np.asarray(target, float),
                                          gtsam.noiseModel.Isotropic.Sigma(self.num_betas,
                                                                           1.0 / np.sqrt(self.admm.rho))))
        values = gtsam.Values()
        for i, (rot, trans, body_pose) in states.items():
            values.insert(keys[i].root, gtsam.Rot3(rot))
            values.insert(keys[i].trans, np.asarray(trans, float))
            values.insert(keys[i].body_pose, np.asarray(body_pose, float))
        values.insert(betas_key, np.asarray(beta_k, float))
        free = [keys[k].root, keys[k].trans, keys[k].body_pose, betas_key]
        values, report = python_lm(graph, values, local_config(self.admm.inner_iterations,
                                                               self.admm.inner_relative_tol), free_keys=free)
        error = report.final_error
        state = (values.atRot3(keys[k].root).matrix(), np.asarray(values.atVector(keys[k].trans), float),
                 np.asarray(values.atVector(keys[k].body_pose), float))
        return state, np.asarray(values.atVector(betas_key), float), error


_WORKER: dict = {}


def _init_worker(track, config: FitConfig, ctx, admm: AdmmConfig) -> None:
    _WORKER["solver"] = _FrameSolver(build_track_graph(track, ctx, config), admm)


def _solve_job(job):
    k, states, beta_k, target = job
    return k, *_WORKER["solver"].solve(k, states, beta_k, target)


def admm_solve(problem, config: FitConfig, admm: AdmmConfig | None = None, track=None, ctx=None
               ) -> tuple[gtsam.Values, AdmmReport]:
    """Run ADMM on a built track problem.  ``track`` and ``ctx`` are needed only for ``admm.workers > 1``
    (each worker rebuilds the graph: CustomFactors cannot be pickled)."""
    admm = admm or config.admm
    t0 = time.perf_counter()
    keys = problem.keys
    n = len(keys)
    solver = _FrameSolver(problem, admm)
    init = problem.initial
    states = {i: (init.atRot3(k.root).matrix(), np.asarray(init.atVector(k.trans), float),
                  np.asarray(init.atVector(k.body_pose), float)) for i, k in enumerate(keys)}
    nb = solver.num_betas
    beta = np.asarray(init.atVector(keys[0].betas), float).copy()
    beta_k = np.tile(beta, (n, 1))
    duals = np.zeros((n, nb))
    sigma_shape = config.noise.shape_sigma
    support_sd = config.noise.shape_support_sd
    support = support_sd * sigma_shape if support_sd and np.isfinite(support_sd) and support_sd > 0 else None
    report = AdmmReport(iterations=0, converged=False, seconds=0.0,
                        initial_error=float(problem.graph.error(init)), final_error=float("nan"))
    pool = None
    if admm.workers > 1 and n > 1:
        if track is None or ctx is None:
            raise ValueError("admm.workers > 1 needs the track and the context (workers rebuild the graph)")
        pool = ProcessPoolExecutor(max_workers=admm.workers, initializer=_init_worker,
                                   initargs=(track, config, ctx, admm))
    try:
        for it in range(1, admm.max_iterations + 1):
            for colour in (0, 1):
                frames = list(range(colour, n, 2))
                jobs = [(k, {i: states[i] for i in (k - 1, k, k + 1) if 0 <= i < n}, beta_k[k], beta - duals[k])
                        for k in frames]
                results = pool.map(_solve_job, jobs) if pool is not None else \
                    (((job[0],) + solver.solve(*job)) for job in jobs)
                for k, state, new_beta, _ in results:
                    states[k] = state
                    beta_k[k] = new_beta
            new_beta = consensus_shape((beta_k + duals).mean(axis=0), n * admm.rho, sigma_shape, support,
                                       config.noise.shape_support_sigma)
            dual_res = float(admm.rho * np.linalg.norm(new_beta - beta))
            beta = new_beta
            duals += beta_k - beta
            primal_res = float(np.max(np.linalg.norm(beta_k - beta, axis=1)))
            report.primal_residuals.append(primal_res)
            report.dual_residuals.append(dual_res)
            report.iterations = it
            report.errors.append(float(problem.graph.error(_assemble(problem, states, beta))))
            if primal_res < admm.primal_tol and dual_res < admm.dual_tol:
                report.converged = True
                break
    finally:
        if pool is not None:
            pool.shutdown()
    values = _assemble(problem, states, beta)
    report.final_error = float(problem.graph.error(values))
    report.seconds = time.perf_counter() - t0
    return values, report


def _assemble(problem, states: dict, beta: np.ndarray) -> gtsam.Values:
    values = gtsam.Values()
    for i, k in enumerate(problem.keys):
        rot, trans, body_pose = states[i]
        values.insert(k.root, gtsam.Rot3(rot))
        values.insert(k.trans, np.asarray(trans, float))
        values.insert(k.body_pose, np.asarray(body_pose, float))
    values.insert(problem.keys[0].betas, np.asarray(beta, float))
    return values


def fit_track_admm(track, config: FitConfig | None = None, context=None, admm: AdmmConfig | None = None,
                   marginals: bool = False, diagnostics: bool = False):
    """Fit one track with ADMM (same graph, staging and outputs as
    :func:`pedx_graph.solvers.track_lm.fit_track`; ``iterations`` counts the ADMM iterations of both stages)."""
    config = config or FitConfig()
    ctx = context or estimator_context(config)
    t0 = time.perf_counter()
    report_ctx = ctx                          # results: PedX keypoints of the original model, whatever the labels
    track, ctx, config = fit_layout(track, ctx, config)   # detector sets: their own points, 18 + E rows
    stage_iterations = 0
    initial = None
    if config.terms.lidar_chamfer:
        # staged as the batch fit: first without the chamfer term, then every term from that estimate
        coarse_cfg = coarse_stage_config(config)
        coarse = build_track_graph(track, ctx, coarse_cfg)
        initial, coarse_report = admm_solve(coarse, coarse_cfg, admm, track=track, ctx=ctx)
        stage_iterations = coarse_report.iterations
    problem = build_track_graph(track, ctx, config, initial=initial)
    values, report = admm_solve(problem, config, admm, track=track, ctx=ctx)
    report.iterations += stage_iterations
    est = extract_estimate(problem, values, report_ctx)
    # the body plausibility fields always, covariances / diagnostics when asked
    extra_frames, extra_track = track_extras(problem, values, ctx, marginals, diagnostics, fit_config=config,
                                             frames=track.frames)
    record_depth_sources(problem.init, extra_frames, extra_track)
    extra_track.update({"admm_iterations": report.iterations, "admm_converged": report.converged,
                        "admm_primal_residual": report.primal_residuals[-1] if report.primal_residuals else None,
                        "admm_dual_residual": report.dual_residuals[-1] if report.dual_residuals else None})
    result = TrackResult(sequence=track.sequence, tracking_id=track.tracking_id,
                         frames=[fr.frame for fr in track.frames], pose=est.pose, betas=est.betas,
                         trans=est.trans, world_keypoints=est.world_keypoints, final_error=report.final_error,
                         initial_error=report.initial_error, iterations=report.iterations,
                         seconds=time.perf_counter() - t0, solver="admm", extra_per_frame=extra_frames,
                         extra_track=extra_track)
    return check_track_result(result, track, config, problem, values)    # ImplausibleEstimateError: a failed track
