"""The Python-driven LM and gtsam's LM reach the same optimum on a nonlinear graph with Rot3 and vectors."""
import gtsam
import numpy as np
import pytest

from pedx_graph.graph.config import SolverConfig
from pedx_graph.solvers.lm import gtsam_lm, python_lm, solve


def _problem(seed=0, n=8):
    rng = np.random.default_rng(seed)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i in range(n):
        kr, kt = gtsam.symbol("r", i), gtsam.symbol("t", i)
        graph.add(gtsam.PriorFactorRot3(kr, gtsam.Rot3.Expmap(rng.normal(size=3)),
                                        gtsam.noiseModel.Isotropic.Sigma(3, 0.1)))
        target = rng.normal(size=3)

        def err(this, v, H, target=target):
            x = v.atVector(this.keys()[0])
            if H is not None:
                H[0] = np.diag(np.cos(x))
            return np.sin(x) - np.sin(target)

        graph.add(gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(3, 0.1), [kt], err))
        if i:
            graph.add(gtsam.BetweenFactorRot3(gtsam.symbol("r", i - 1), kr, gtsam.Rot3(),
                                              gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
        values.insert(kr, gtsam.Rot3())
        values.insert(kt, np.zeros(3))
    return graph, values


def test_python_lm_matches_gtsam_lm():
    graph, values = _problem()
    a, ra = python_lm(graph, values, SolverConfig(max_iterations=50, relative_error_tol=1e-10))
    b, rb = gtsam_lm(graph, values, SolverConfig(max_iterations=50, relative_error_tol=1e-10))
    assert ra.final_error < ra.initial_error
    assert ra.final_error == pytest.approx(rb.final_error, rel=1e-6, abs=1e-9)
    for i in range(8):
        k = gtsam.symbol("r", i)
        assert a.atRot3(k).equals(b.atRot3(k), 1e-5)
    assert ra.errors == sorted(ra.errors, reverse=True)      # monotone decrease


def test_solve_rejects_unknown_backend():
    graph, values = _problem(n=1)
    with pytest.raises(ValueError, match="backend"):
        solve(graph, values, SolverConfig(backend="magic"))
