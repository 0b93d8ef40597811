"""ADMM reference solver (pedx_graph.solvers.admm) against the joint graph's optimum on tiny tracks."""
import numpy as np
import pytest

from solver_fixtures import synthetic_config, synthetic_context, synthetic_track
from pedx_graph.graph.build import build_track_graph, extract_estimate
from pedx_graph.graph.config import SolverConfig
from pedx_graph.solvers.admm import AdmmConfig, _frame_factor_indices, admm_solve, fit_track_admm
from pedx_graph.solvers.lm import python_lm

TIGHT = SolverConfig(max_iterations=100, relative_error_tol=1e-8)


@pytest.fixture(scope="module")
def ctx():
    return synthetic_context()


def test_frame_subproblems_cover_every_factor_once_or_twice(ctx):
    track, _ = synthetic_track(ctx, 3, seed=0)
    problem = build_track_graph(track, ctx, synthetic_config())
    groups = _frame_factor_indices(problem)
    counts = np.zeros(problem.graph.size(), int)
    for g in groups:
        counts[g] += 1
    kinds = np.array(problem.factor_kinds)
    assert np.all(counts[kinds == "temporal_prior"] == 2)          # in both frames' subproblems
    assert np.all(counts[kinds == "shape_prior"] == 0)             # on the consensus
    assert np.all(counts[(kinds != "temporal_prior") & (kinds != "shape_prior")] == 1)


def test_admm_reaches_the_joint_optimum(ctx):
    """Chamfer off (single optimum): ADMM with the paper's settings ends at batch LM's objective and shape."""
    config = synthetic_config(lidar_chamfer=False)
    track, _ = synthetic_track(ctx, 4, seed=1)
    problem = build_track_graph(track, ctx, config)
    batch, report = python_lm(problem.graph, problem.initial, TIGHT)
    values, admm = admm_solve(problem, config, AdmmConfig())
    assert admm.converged and admm.iterations < AdmmConfig().max_iterations
    assert admm.primal_residuals[-1] < 0.05 and admm.dual_residuals[-1] < 0.05
    assert admm.final_error == pytest.approx(report.final_error, rel=0.01)
    a, b = extract_estimate(problem, batch, ctx), extract_estimate(problem, values, ctx)
    assert np.linalg.norm(a.betas - b.betas) < 0.18                                     # measured 0.121
    assert np.max(np.linalg.norm(a.world_keypoints - b.world_keypoints, axis=-1)) < 0.027   # measured 0.018 m
    # tighter tolerances bring the shape closer
    values_t, admm_t = admm_solve(problem, config, AdmmConfig(primal_tol=0.005, dual_tol=0.005, max_iterations=80))
    assert np.linalg.norm(extract_estimate(problem, values_t, ctx).betas - a.betas) < np.linalg.norm(a.betas - b.betas)


def test_admm_full_graph_is_a_stationary_point(ctx):
    """With every term on (chamfer correspondences: several local optima), ADMM ends at a point LM can
    barely improve, with an objective no worse than batch LM's."""
    config = synthetic_config()
    track, _ = synthetic_track(ctx, 3, seed=0)
    problem = build_track_graph(track, ctx, config)
    _, report = python_lm(problem.graph, problem.initial, TIGHT)
    values, admm = admm_solve(problem, config, AdmmConfig())
    assert admm.final_error <= report.final_error * 1.03
    polished, polish = python_lm(problem.graph, values, TIGHT)
    assert polish.final_error >= admm.final_error * 0.99
    shift = extract_estimate(problem, polished, ctx).betas - extract_estimate(problem, values, ctx).betas
    assert np.linalg.norm(shift) < 0.17                                 # measured 0.114


def test_admm_process_pool_matches_serial(ctx):
    config = synthetic_config(lidar_chamfer=False)
    track, _ = synthetic_track(ctx, 3, seed=2)
    problem = build_track_graph(track, ctx, config)
    serial, _ = admm_solve(problem, config, AdmmConfig(max_iterations=2))
    parallel, _ = admm_solve(problem, config, AdmmConfig(max_iterations=2, workers=2), track=track, ctx=ctx)
    a, b = extract_estimate(problem, serial, ctx), extract_estimate(problem, parallel, ctx)
    np.testing.assert_allclose(a.world_keypoints, b.world_keypoints, atol=1e-9)
    np.testing.assert_allclose(a.betas, b.betas, atol=1e-9)


def test_fit_track_admm_result(ctx):
    config = synthetic_config(lidar_chamfer=False)
    track, truth = synthetic_track(ctx, 3, seed=3)
    result = fit_track_admm(track, config, ctx, AdmmConfig(max_iterations=30), marginals=True, diagnostics=True)
    assert result.solver == "admm" and result.pose.shape == (3, 72) and result.betas.shape == (10,)
    problem = build_track_graph(track, ctx, config)
    batch = extract_estimate(problem, python_lm(problem.graph, problem.initial, TIGHT)[0], ctx)
    mpjpe = np.linalg.norm(result.world_keypoints - truth["keypoints"], axis=-1).mean()
    assert mpjpe < np.linalg.norm(batch.world_keypoints - truth["keypoints"], axis=-1).mean() + 0.01
    assert result.extra_track["admm_iterations"] == result.iterations
    assert result.extra_per_frame[0]["covariance_status"] == "ok"
    assert len(result.to_labels()) == 3
