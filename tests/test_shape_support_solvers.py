"""The shape support hinge (``factors.shape_prior``) in every solver path: the batched linearizer (where it
stays in the GTSAM subgraph), batch LM, ADMM (its consensus step) and iSAM2.

A track whose frames all pull the shared shape's first coefficient towards -30 (as systematic reprojection
residuals of a one-camera track can) ends inside the support with the hinge, far outside without it.
"""
from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from pedx_graph.graph.build import build_track_graph
from pedx_graph.solvers.admm import AdmmConfig, admm_solve
from pedx_graph.solvers.batched import BatchedLinearizer
from pedx_graph.solvers.isam import IsamConfig
from pedx_graph.solvers.isam_batch import isam_solve
from pedx_graph.solvers.lm import python_lm
from solver_fixtures import synthetic_config, synthetic_context, synthetic_track

BOUND = 3.5
PULL_SIGMA = 0.75


@pytest.fixture(scope="module")
def ctx():
    return synthetic_context()


def _config(support: bool):
    config = synthetic_config(lidar_chamfer=False)
    return dataclasses.replace(config, noise=dataclasses.replace(
        config.noise, shape_support_sd=BOUND if support else 0.0))


def _pulled_problem(ctx, support: bool, num_frames: int = 4):
    """The track's graph plus, per frame, a prior pulling beta_0 towards -30 (``PULL_SIGMA`` per frame)."""
    track, _ = synthetic_track(ctx, num_frames, seed=2)
    config = _config(support)
    problem = build_track_graph(track, ctx, config)
    nb = ctx.model.num_betas
    target = np.zeros(nb)
    target[0] = -30.0
    for i, k in enumerate(problem.keys):
        problem.graph.add(gtsam.PriorFactorVector(k.betas, target, gtsam.noiseModel.Isotropic.Sigma(nb, PULL_SIGMA)))
        problem.factor_kinds.append("pull")
        problem.factor_frames.append(i)
    return problem, config


def test_graph_holds_the_support_factor(ctx):
    track, _ = synthetic_track(ctx, 3, seed=0)
    on = build_track_graph(track, ctx, _config(True))
    off = build_track_graph(track, ctx, _config(False))
    assert on.factor_kinds.count("shape_prior") == 2 and off.factor_kinds.count("shape_prior") == 1
    assert all(f == -1 for kind, f in zip(on.factor_kinds, on.factor_frames) if kind == "shape_prior")


def test_batched_linearizer_with_an_active_support(ctx):
    from test_solver_batched import _assert_systems_equal

    track, _ = synthetic_track(ctx, 4, seed=3)
    problem = build_track_graph(track, ctx, _config(True))
    values = gtsam.Values(problem.initial)
    betas = np.zeros(ctx.model.num_betas)
    betas[[0, 3]] = [-6.0, 4.2]                       # two coefficients past the bound
    values.update(problem.keys[0].betas, betas)
    lin = BatchedLinearizer(problem)
    assert lin.rest.size() == 2                       # the shape prior and its support, linearised by GTSAM
    assert lin.error(values) == pytest.approx(problem.graph.error(values), rel=1e-10)
    _assert_systems_equal(lin.system(values), problem.layout.assemble(problem.graph.linearize(values)))


def _beta0_lm(problem, config):
    values, _ = python_lm(problem.graph, problem.initial, config.solver, problem.prefetch, problem.layout,
                          BatchedLinearizer(problem))
    return float(values.atVector(problem.keys[0].betas)[0])


def _beta0_admm(problem, config):
    values, _ = admm_solve(problem, config, AdmmConfig(max_iterations=30))
    return float(values.atVector(problem.keys[0].betas)[0])


def _beta0_isam(problem, config):
    values, _, _ = isam_solve(problem, IsamConfig(), config.solver)
    return float(values.atVector(problem.keys[0].betas)[0])


@pytest.mark.parametrize("solve", [_beta0_lm, _beta0_admm, _beta0_isam], ids=["lm", "admm", "isam"])
def test_every_solver_keeps_the_shape_inside_its_support(ctx, solve):
    held = solve(*_pulled_problem(ctx, support=True))
    free = solve(*_pulled_problem(ctx, support=False))
    assert free < -20.0                               # the pulls beat the Gaussian prior alone (-26 measured)
    assert -BOUND - 0.09 < held < -BOUND              # against the wall, a little past it (0.055 measured)
