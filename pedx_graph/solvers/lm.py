"""Levenberg-Marquardt over a GTSAM nonlinear factor graph.

Two back-ends with the same stopping rules:

* :func:`python_lm` drives LM from Python: ``graph.linearize(values)`` once per iteration, the damped
  system ``(A^T A + lambda I) delta = A^T b`` solved either by GTSAM (damping added as unit-noise
  ``sqrt(lambda) * I`` Jacobian factors per variable, ``GaussianFactorGraph.optimize()``, sparse QR) or,
  for a track's chain + arrow graph (``layout``), by the block Cholesky sweep of
  :mod:`pedx_graph.solvers.chain`; then ``Values.retract``.  Every CustomFactor callback then runs from Python at ~10 us overhead, instead of the
  ~200 us (growing with the graph) it costs inside gtsam's optimisers (see docs/solver.md for the measured
  comparison).
* :func:`gtsam_lm` runs ``gtsam.LevenbergMarquardtOptimizer`` with matching parameters.
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
from pedx_graph.solvers.chain import ChainLayout, NotAChainError, solve_chain


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


def _tangent_dims(values: gtsam.Values) -> dict[int, int]:
    zero = values.zeroVectors()
    return {int(k): int(zero.at(k).shape[0]) for k in values.keys()}


Prefetch = Callable[[gtsam.Values, bool], None]
"""``prefetch(values, jacobians)``: called before every ``graph.linearize`` (True) / ``graph.error`` (False)."""


def python_lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
              config: SolverConfig | None = None,
              prefetch: Prefetch | None = None,
              layout: ChainLayout | None = None,
              linearizer=None) -> tuple[gtsam.Values, SolveReport]:
    """Minimise ``graph.error`` from ``values`` with LM driven from Python; returns (estimate, report).

    ``prefetch`` lets the caller batch-evaluate what the factors will ask for (see
    :mod:`pedx_graph.graph.batch`); it never changes the result.  ``layout``: the track's
    :class:`~pedx_graph.solvers.chain.ChainLayout` to solve each damped system by the block sweep (same
    step as GTSAM's QR up to round-off; falls back to GTSAM when the graph is not a chain).
    ``linearizer`` (with ``layout``): a :class:`~pedx_graph.solvers.batched.BatchedLinearizer` of this graph,
    which gives ``graph.error`` and the chain system of ``graph.linearize`` from batched evaluations.
    """
    config = config or SolverConfig()
    prefetch = prefetch or (lambda values, jacobians: None)
    t0 = time.perf_counter()
    dims = _tangent_dims(values)
    damping_models = {d: gtsam.noiseModel.Unit.Create(d) for d in set(dims.values())}
    eyes = {d: np.eye(d) for d in set(dims.values())}
    zeros = {d: np.zeros(d) for d in set(dims.values())}
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
                    damped.add(gtsam.JacobianFactor(key, sqrt_lam * eyes[d], zeros[d], damping_models[d]))
                try:
                    delta = damped.optimize()
                except RuntimeError:
                    lam *= 10.0
                    continue
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
