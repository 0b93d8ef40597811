"""Levenberg-Marquardt over a GTSAM nonlinear factor graph.

Two back-ends with the same stopping rules:

* :func:`python_lm` drives LM from Python: ``graph.linearize(values)`` once per iteration, damping added
  as unit-noise ``sqrt(lambda) * I`` Jacobian factors per variable, ``GaussianFactorGraph.optimize()`` and
  ``Values.retract``.  Every CustomFactor callback then runs from Python at ~10 us overhead, instead of the
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

from pedx_graph.graph.config import SolverConfig


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


def _tangent_dims(values: gtsam.Values) -> dict[int, int]:
    zero = values.zeroVectors()
    return {int(k): int(zero.at(k).shape[0]) for k in values.keys()}


Prefetch = Callable[[gtsam.Values, bool], None]
"""``prefetch(values, jacobians)``: called before every ``graph.linearize`` (True) / ``graph.error`` (False)."""


def python_lm(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
              config: SolverConfig | None = None,
              prefetch: Prefetch | None = None) -> tuple[gtsam.Values, SolveReport]:
    """Minimise ``graph.error`` from ``values`` with LM driven from Python; returns (estimate, report).

    ``prefetch`` lets the caller batch-evaluate what the factors will ask for (see
    :mod:`pedx_graph.graph.batch`); it never changes the result.
    """
    config = config or SolverConfig()
    prefetch = prefetch or (lambda values, jacobians: None)
    t0 = time.perf_counter()
    dims = _tangent_dims(values)
    damping_models = {d: gtsam.noiseModel.Unit.Create(d) for d in set(dims.values())}
    eyes = {d: np.eye(d) for d in set(dims.values())}
    zeros = {d: np.zeros(d) for d in set(dims.values())}
    prefetch(values, False)
    err = graph.error(values)
    initial = err
    lam = config.lambda_initial
    errors: list[float] = []
    converged = False
    iterations = 0
    for iterations in range(1, config.max_iterations + 1):
        prefetch(values, True)
        linear = graph.linearize(values)
        accepted = False
        while lam <= config.lambda_max:
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
            prefetch(candidate, False)
            new_err = graph.error(candidate)
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
          prefetch: Prefetch | None = None) -> tuple[gtsam.Values, SolveReport]:
    """Dispatch on ``config.backend`` (``prefetch`` serves the Python-driven LM only)."""
    config = config or SolverConfig()
    if config.backend == "python":
        return python_lm(graph, values, config, prefetch)
    if config.backend == "gtsam":
        return gtsam_lm(graph, values, config)
    raise ValueError(f"solver.backend must be 'python' or 'gtsam', got {config.backend!r}")
