"""Tests of factors/shape_prior.py (betas ~ N(0, sigma^2 I))."""
import gtsam
import numpy as np
import pytest

from factors.shape_prior import make_shape_prior_factor, shape_prior_error


def test_shape_prior_error_and_residual():
    rng = np.random.default_rng(0)
    betas = rng.normal(size=10)
    key = gtsam.symbol("b", 0)
    f = make_shape_prior_factor(key, sigma=2.0)
    v = gtsam.Values()
    v.insert(key, betas)
    r, jac = shape_prior_error(betas)
    np.testing.assert_allclose(f.unwhitenedError(v), r)
    np.testing.assert_allclose(f.error(v), 0.5 * np.sum((betas / 2.0) ** 2))
    np.testing.assert_allclose(jac, np.eye(10))
    v0 = gtsam.Values()
    v0.insert(key, np.zeros(10))
    assert f.error(v0) == pytest.approx(0.0, abs=1e-15)


def test_shape_prior_bad_inputs():
    with pytest.raises(ValueError):
        make_shape_prior_factor(0, sigma=0.0)
    with pytest.raises(ValueError):
        make_shape_prior_factor(0, num_betas=10, mean=np.zeros(3))


# --- the support hinge ------------------------------------------------------------------------------------
from factors.shape_prior import (consensus_shape, make_shape_support_factor, shape_factors,  # noqa: E402
                                 shape_support_error)
from factor_testing import assert_factor_jacobians  # noqa: E402


def test_shape_support_residual_zero_inside_and_linear_outside():
    betas = np.array([0.0, 3.4, -3.4, 3.6, -5.0, 10.0, -0.2, 2.0, -3.5, 3.5])
    r, jac = shape_support_error(betas, 3.5, want_jacobian=True)
    np.testing.assert_allclose(r, [0, 0, 0, 0.1, -1.5, 6.5, 0, 0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(np.diag(jac), (np.abs(betas) > 3.5).astype(float))
    key = gtsam.symbol("b", 0)
    f = make_shape_support_factor(key, bound=3.5, sigma_hinge=0.05)
    v = gtsam.Values()
    v.insert(key, betas)
    np.testing.assert_allclose(f.unwhitenedError(v), r, atol=1e-12)
    assert f.error(v) == pytest.approx(0.5 * np.sum((r / 0.05) ** 2))
    # around a non-zero mean the support is |betas - mean| <= bound
    mean = np.full(10, 1.0)
    r_mean, _ = shape_support_error(betas, 3.5, mean)
    np.testing.assert_allclose(r_mean, shape_support_error(betas - mean, 3.5)[0])


def test_shape_support_jacobian_matches_numerical_at_random_points():
    rng = np.random.default_rng(3)
    key = gtsam.symbol("b", 0)
    mean = rng.normal(scale=0.5, size=10)
    f = make_shape_support_factor(key, bound=2.0, sigma_hinge=0.1, mean=mean)
    active_seen = 0
    for _ in range(6):
        betas = rng.normal(scale=3.0, size=10)
        d = np.abs(betas - mean)
        betas[np.abs(d - 2.0) < 1e-3] += 0.01          # keep off the kink (central differences straddle it)
        v = gtsam.Values()
        v.insert(key, betas)
        assert_factor_jacobians(f, v)
        active_seen += int(np.sum(np.abs(betas - mean) > 2.0))
    assert active_seen > 5                              # the wall was exercised, not only the flat inside


def test_shape_factors_and_bad_inputs():
    key = gtsam.symbol("b", 0)
    assert len(shape_factors(key, 10, 1.0, 3.5, 0.05)) == 2
    assert len(shape_factors(key, 10, 1.0, 0.0, 0.05)) == 1
    assert len(shape_factors(key, 10, 1.0, float("inf"), 0.05)) == 1
    # the bound is in prior standard deviations: sigma 2 and 3.5 SD -> |beta| <= 7
    support = shape_factors(key, 10, 2.0, 3.5, 0.05)[1]
    v = gtsam.Values()
    v.insert(key, np.r_[6.9, 7.2, np.zeros(8)])
    np.testing.assert_allclose(support.unwhitenedError(v)[:2], [0.0, 0.2], atol=1e-12)
    for kwargs in ({"bound": 0.0}, {"bound": float("inf")}, {"sigma_hinge": 0.0}, {"mean": np.zeros(3)}):
        with pytest.raises(ValueError):
            make_shape_support_factor(key, **kwargs)


def test_lm_keeps_the_shape_inside_its_support_against_many_frames_of_pull():
    """50 weak measurements each pulling beta_0 to -30 (as the T frames of a track do through the shared
    shape; together twice the prior's precision) beat the Gaussian prior alone (beta_0 = -20) but not the
    support hinge."""
    key = gtsam.symbol("b", 0)
    graph = gtsam.NonlinearFactorGraph()
    target = np.zeros(10)
    target[0] = -30.0
    for _ in range(50):
        graph.add(gtsam.PriorFactorVector(key, target, gtsam.noiseModel.Isotropic.Sigma(10, 5.0)))
    prior_only = gtsam.NonlinearFactorGraph(graph)
    for factor in shape_factors(key, 10, 1.0, 3.5, 0.05):
        graph.add(factor)
    prior_only.add(make_shape_prior_factor(key))
    v = gtsam.Values()
    v.insert(key, np.zeros(10))
    free = gtsam.LevenbergMarquardtOptimizer(prior_only, v).optimize().atVector(key)
    held = gtsam.LevenbergMarquardtOptimizer(graph, v).optimize().atVector(key)
    assert free[0] == pytest.approx(-20.0, abs=1e-6)
    # equilibrium of the pulls (2 (b + 30)), the prior (b) and the wall ((b + 3.5) / 0.05^2)
    expected = (-2 * 30.0 - 3.5 / 0.05 ** 2) / (2 + 1 + 1 / 0.05 ** 2)
    assert held[0] == pytest.approx(expected, abs=1e-4)           # LM stopping tolerance
    assert -3.5 - 0.15 < held[0] < -3.5
    np.testing.assert_allclose(held[1:], 0.0, atol=1e-9)


def test_consensus_shape_is_the_minimiser():
    """The ADMM consensus step's closed form against a dense 1-D search of the same objective."""
    grid = np.linspace(-12, 12, 240001)
    for m, precision in ((0.5, 3.0), (6.0, 8.0), (-9.0, 20.0), (3.6, 1.0), (-30.0, 100.0)):
        m_arr = np.array([m])
        got = consensus_shape(m_arr, precision, 1.0, 3.5, 0.05)[0]
        energy = (0.5 * grid ** 2 + 0.5 * ((grid - np.clip(grid, -3.5, 3.5)) / 0.05) ** 2
                  + 0.5 * precision * (grid - m) ** 2)
        assert got == pytest.approx(grid[np.argmin(energy)], abs=2e-4)
    # without a support: the Gaussian consensus of before
    assert consensus_shape(np.array([6.0]), 8.0, 1.0, None, 0.05)[0] == pytest.approx(8.0 * 6.0 / 9.0)
