"""Levenberg-Marquardt over a GTSAM nonlinear factor graph: the one LM loop of the project.

Every LM solve runs :func:`python_lm` (or gtsam's optimiser, :func:`gtsam_lm`, with the same stopping
rules): the batch fit's stages and flip search, the stream's finalisation and first-frame facing, ADMM's
frame subproblems and the stream's ``lm`` presolve (the last two over a subset of the keys, ``free_keys``,
the others held).

* :func:`python_lm` drives LM from Python: ``graph.linearize(values)`` once per iteration, the damped
  system ``(A^T A + lambda I) delta = A^T b`` solved either by GTSAM (damping added as unit-noise
  ``sqrt(lambda) * I`` Jacobian factors per variable, ``GaussianFactorGraph.optimize()``, sparse QR) or,
  for a track's chain + arrow graph (``layout``), by the block Cholesky sweep of
  :mod:`pedx_graph.solvers.chain`; then ``Values.retract``.  Every CustomFactor callback then runs from
  Python at ~10 us overhead, instead of the ~200 us (growing with the graph) it costs inside gtsam's
  optimisers (see docs/solver.md for the measured comparison).
* :func:`gtsam_lm` runs ``gtsam.LevenbergMarquardtOptimizer`` with matching parameters.
* :func:`gauss_newton_step`: LM's first iteration over a subset of the keys without its error checks
  (the stream's default presolve of a new frame).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import gtsam
import numpy as np

from scipy.linalg import LinAlgError

from pedx_graph.graph.config import SolverConfig
from pedx_graph.graph.layout import ChainLayout, NotAChainError
from pedx_graph.solvers.chain import solve_chain


@dataclass
class SolveReport:
    """What a solve did."""

    initial_error: float
    final_error: float
    iterations: int
    seconds: float
    converged: bool
    backend: str
    errors: list[float] = field(default_factory=list)
    """Error after each accepted iteration."""
    flips: dict = field(default_factory=dict)
    """The limb depth-flip search's record (:mod:`pedx_graph.solvers.flips`): segments tried, accepted,
    errors; empty when it did not run."""
    dropped_views: list = field(default_factory=list)
    """Images taken out of their frames' labels after the first stage (:func:`pedx_graph.solvers.staging.
    drop_outlier_views`): ``{"frame", "pair", "side", "median_sigmas"}`` each; empty when none was."""
    mirrored_labels: list = field(default_factory=list)
    """Left/right labels exchanged back after the second stage (:mod:`pedx_graph.solvers.mirror`):
    ``{"frame", "pair", "side", "keypoints", "gain"}`` each (``keypoints``: the pair's two row names, or
    ``"all"`` for a whole image); empty when none was."""


def _tangent_dims(values: gtsam.Values) -> dict[int, int]:
    zero = values.zeroVectors()
    return {int(k): int(zero.at(k).shape[0]) for k in values.keys()}


Prefetch = Callable[[gtsam.Values, bool], None]
"""``prefetch(values, jacobians)``: called before every ``graph.linearize`` (True) / ``graph.error`` (False)."""


#: Damping weight of a held key's delta (``free_keys`` of :func:`python_lm`): a stiff unit-noise prior.
HELD_WEIGHT = 1e6


def local_config(max_iterations: int, relative_error_tol: float = 1e-3) -> SolverConfig:
    """The LM settings of a local solve over a few keys (a frame subproblem, a presolve): damping from
    1e-2, given up past 1e6."""
    return SolverConfig(max_iterations=int(max_iterations), relative_error_tol=float(relative_error_tol),
                        lambda_initial=1e-2, lambda_max=1e6)


def python_lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
              config: SolverConfig | None = None,
              prefetch: Prefetch | None = None,
              layout: ChainLayout | None = None,
              linearizer=None, free_keys=None) -> tuple[gtsam.Values, SolveReport]:
    """Minimise ``graph.error`` from ``values`` with LM driven from Python; returns (estimate, report).

    ``prefetch`` lets the caller batch-evaluate what the factors will ask for (see
    :mod:`pedx_graph.graph.batch`); it never changes the result.  ``layout``: the track's
    :class:`~pedx_graph.graph.layout.ChainLayout` to solve each damped system by the block sweep (same
    step as GTSAM's QR up to round-off; falls back to GTSAM when the graph is not a chain).
    ``linearizer`` (with ``layout``): a :class:`~pedx_graph.solvers.batched.BatchedLinearizer` of this graph,
    which gives ``graph.error`` and the chain system of ``graph.linearize`` from batched evaluations.
    ``free_keys``: optimise these keys only; every other key of ``values`` is held (a stiff prior
    ``HELD_WEIGHT * I`` on its delta in the damped system, and a zero step; GTSAM's solve, no layout).
    ``report.errors`` has one entry per accepted iteration.
    """
    config = config or SolverConfig()
    prefetch = prefetch or (lambda values, jacobians: None)
    t0 = time.perf_counter()
    dims = _tangent_dims(values)
    damping_models = {d: gtsam.noiseModel.Unit.Create(d) for d in set(dims.values())}
    eyes = {d: np.eye(d) for d in set(dims.values())}
    zeros = {d: np.zeros(d) for d in set(dims.values())}
    free = None if free_keys is None else {int(k) for k in free_keys}
    if free is not None:
        layout = None
    if layout is None:
        linearizer = None

    def evaluate(at: gtsam.Values, jacobians: bool) -> float:
        if linearizer is not None:
            return linearizer.error(at, jacobians)
        prefetch(at, jacobians)
        return graph.error(at)

    err = evaluate(values, True)          # with derivatives: the first linearisation is at these values
    initial = err
    lam = config.lambda_initial
    errors: list[float] = []
    converged = False
    iterations = 0
    for iterations in range(1, config.max_iterations + 1):
        linear = system = None
        if linearizer is not None:
            system = linearizer.system(values)
        else:
            prefetch(values, True)
            linear = graph.linearize(values)
            if layout is not None:
                try:
                    system = layout.assemble(linear)
                except NotAChainError:
                    layout = None
        accepted = False
        while lam <= config.lambda_max:
            if system is not None:
                try:
                    delta = layout.to_vector_values(*solve_chain(system, lam))
                except LinAlgError:
                    lam *= 10.0
                    continue
            else:
                damped = linear.clone()
                sqrt_lam = math.sqrt(lam)
                for key, d in dims.items():
                    weight = sqrt_lam if free is None or key in free else HELD_WEIGHT
                    damped.add(gtsam.JacobianFactor(key, weight * eyes[d], zeros[d], damping_models[d]))
                try:
                    delta = damped.optimize()
                except RuntimeError:
                    lam *= 10.0
                    continue
                if free is not None:           # held keys do not move
                    step = gtsam.VectorValues()
                    for key, d in dims.items():
                        step.insert(key, delta.at(key) if key in free else zeros[d])
                    delta = step
            candidate = values.retract(delta)
            # With derivatives: an accepted step is linearised at this same point next (served from the cache).
            new_err = evaluate(candidate, True)
            if np.isfinite(new_err) and new_err <= err:
                accepted = True
                decrease = err - new_err
                values, err = candidate, new_err
                lam = max(lam / 10.0, 1e-9)
                break
            lam *= 10.0
        if not accepted:
            converged = True        # no step decreases the error at any damping: a (local) minimum
            break
        errors.append(err)
        if decrease <= config.relative_error_tol * max(err, 1e-12) or err < 1e-12:
            converged = True
            break
    return values, SolveReport(initial_error=float(initial), final_error=float(err), iterations=iterations,
                               seconds=time.perf_counter() - t0, converged=converged, backend="python",
                               errors=errors)


def gtsam_lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
             config: SolverConfig | None = None) -> tuple[gtsam.Values, SolveReport]:
    """Minimise with ``gtsam.LevenbergMarquardtOptimizer`` (same tolerances)."""
    config = config or SolverConfig()
    t0 = time.perf_counter()
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(config.max_iterations)
    params.setRelativeErrorTol(config.relative_error_tol)
    params.setAbsoluteErrorTol(0.0)
    params.setlambdaInitial(config.lambda_initial)
    params.setlambdaUpperBound(config.lambda_max)
    errors: list[float] = []
    params.iterationHook = lambda it, e0, e1: errors.append(float(e1))
    initial = graph.error(values)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, params)
    result = optimizer.optimize()
    final = graph.error(result)
    return result, SolveReport(initial_error=float(initial), final_error=float(final),
                               iterations=int(optimizer.iterations()), seconds=time.perf_counter() - t0,
                               converged=int(optimizer.iterations()) < config.max_iterations,
                               backend="gtsam", errors=errors)


def solve(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
          config: SolverConfig | None = None,
          prefetch: Prefetch | None = None,
          layout: ChainLayout | None = None, linearizer=None) -> tuple[gtsam.Values, SolveReport]:
    """Dispatch on ``config.backend`` (``prefetch``, ``layout`` and ``linearizer`` serve the Python-driven
    LM only)."""
    config = config or SolverConfig()
    if config.backend == "python":
        return python_lm(graph, values, config, prefetch, layout, linearizer)
    if config.backend == "gtsam":
        return gtsam_lm(graph, values, config)
    raise ValueError(f"solver.backend must be 'python' or 'gtsam', got {config.backend!r}")


def _free_normal_equations(linear: gtsam.GaussianFactorGraph, free: list[int], dims: list[int],
                           zero: gtsam.VectorValues) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``(A_f^T A_f, A_f^T b)`` of the Jacobian factors of ``linear`` restricted to the columns of the
    ``free`` keys (dimensions ``dims``): the free block of the Gauss-Newton system, without forming the
    held keys' blocks.  ``(None, None)`` when a factor is not a ``JacobianFactor``."""
    offsets = dict(zip(free, np.concatenate([[0], np.cumsum(dims)[:-1]]).astype(int)))
    n = int(sum(dims))
    rows, rhs_rows = [], []
    for j in range(linear.size()):
        factor = linear.at(j)
        if not isinstance(factor, gtsam.JacobianFactor):
            return None, None
        keys = [int(k) for k in factor.keys()]
        if not any(k in offsets for k in keys):
            continue
        a, b = factor.getA(), factor.getb()
        block = np.zeros((a.shape[0], n))
        col = 0
        for key in keys:
            d = int(zero.at(key).shape[0])
            if key in offsets:
                block[:, offsets[key]:offsets[key] + d] = a[:, col:col + d]
            col += d
        rows.append(block)
        rhs_rows.append(b)
    if not rows:
        return np.zeros((n, n)), np.zeros(n)
    a_f, b = np.vstack(rows), np.concatenate(rhs_rows)
    return a_f.T @ a_f, a_f.T @ b


def gauss_newton_step(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, free_keys,
                      damping: float = 1e-2, system: tuple | None = None) -> gtsam.Values:
    """One damped Gauss-Newton step over ``free_keys``; every other key of ``values`` is held fixed.

    Solves ``(H_ff + damping I) delta_f = eta_f`` densely (``H``, ``eta``: the graph linearised at
    ``values``; ``f``: the free keys) and retracts the free keys.  This is the first iteration of
    :func:`python_lm` with ``free_keys`` and :func:`local_config` (the same damping) without its error
    evaluations, i.e. the step is not checked.
    ``system``: ``(keys, H, eta)``, the normal equations of further factors at ``values`` over the columns
    of ``keys`` in that order (e.g. factors linearised in a batch elsewhere), added to the graph's.
    Returns the updated ``values`` (a copy).
    """
    in_graph = {int(k) for k in graph.keyVector()}
    seen = in_graph | ({int(k) for k in system[0]} if system is not None else set())
    free = [int(k) for k in free_keys if int(k) in seen]          # a key no factor sees does not move
    free_set = set(free)
    held = [k for k in in_graph if k not in free_set]
    zero = values.zeroVectors()
    step = gtsam.VectorValues()
    for key in values.keys():
        if int(key) not in free_set:
            step.insert(key, np.zeros(int(zero.at(key).shape[0])))
    if not free:
        return values.retract(step)
    dims = [int(zero.at(k).shape[0]) for k in free]
    n = int(sum(dims))
    if graph.size():
        linear = graph.linearize(values)
        h_ff, rhs = _free_normal_equations(linear, free, dims, zero)
        if h_ff is None:               # not all Jacobian factors: gtsam's dense Hessian of every key
            ordering = gtsam.Ordering()
            graph_free = [k for k in free if k in in_graph]
            for key in graph_free + held:
                ordering.push_back(key)
            hessian, eta = linear.hessian(ordering)
            m = int(sum(int(zero.at(k).shape[0]) for k in graph_free))
            cols = _columns(free, dims, graph_free)
            h_ff, rhs = np.zeros((n, n)), np.zeros(n)
            h_ff[np.ix_(cols, cols)] = hessian[:m, :m]
            rhs[cols] = np.asarray(eta, float).reshape(-1)[:m]
    else:
        h_ff, rhs = np.zeros((n, n)), np.zeros(n)
    if system is not None:
        keys, h_sys, eta_sys = system
        keys = [int(k) for k in keys]
        sys_dims = [int(zero.at(k).shape[0]) for k in keys]
        both = [k for k in keys if k in free_set]
        cols, sys_cols = _columns(free, dims, both), _columns(keys, sys_dims, both)
        h_ff[np.ix_(cols, cols)] += h_sys[np.ix_(sys_cols, sys_cols)]
        rhs[cols] += eta_sys[sys_cols]
    h_ff = h_ff + damping * np.eye(n)
    try:
        delta = np.linalg.solve(h_ff, rhs)
    except np.linalg.LinAlgError:
        delta = np.linalg.lstsq(h_ff, rhs, rcond=None)[0]
    offset = 0
    for key, d in zip(free, dims):
        step.insert(key, delta[offset:offset + d])
        offset += d
    return values.retract(step)


def _columns(keys: list[int], dims: list[int], subset: list[int]) -> np.ndarray:
    """The column indices of the keys ``subset`` (in that order) in a system over ``keys`` (dimensions
    ``dims``)."""
    starts = dict(zip(keys, np.concatenate([[0], np.cumsum(dims)[:-1]]).astype(int)))
    width = dict(zip(keys, dims))
    if not subset:
        return np.zeros(0, dtype=np.int64)
    return np.concatenate([np.arange(starts[k], starts[k] + width[k]) for k in subset])
