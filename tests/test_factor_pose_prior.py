"""Tests of factors/pose_prior.py (E_P max-mixture GMM pose prior)."""
import gtsam
import numpy as np
import pytest
from scipy.stats import multivariate_normal

from factors.common import MaxMixture
from factors.pose_prior import make_pose_prior_factor, pose_prior_error
from factor_testing import assert_factor_jacobians, random_gmm

D = 69


def _nll_max(x, weights, means, chol):
    best = -np.inf
    for w, mu, L in zip(weights, means, chol):
        cov = np.linalg.inv(L @ L.T)
        best = max(best, np.log(w) + multivariate_normal(mu, cov).logpdf(x))
    return -best


def test_max_mixture_cost_equals_negative_log_of_best_component():
    rng = np.random.default_rng(1)
    weights, means, chol = random_gmm(rng, 4, D)
    mix = MaxMixture(weights, means, chol)
    xs = [means[k] + rng.normal(scale=0.1, size=D) for k in range(4)]
    costs = [mix.negative_log_likelihood(x) for x in xs]
    nlls = [_nll_max(x, weights, means, chol) for x in xs]
    # equal up to one additive constant
    np.testing.assert_allclose(np.diff(costs), np.diff(nlls), rtol=1e-9, atol=1e-8)
    for x in xs:
        r, _, _ = mix.residual(x)
        assert r.shape == (D + 1,) and r[-1] >= 0.0


def test_zero_residual_at_mean_of_dominant_component():
    rng = np.random.default_rng(2)
    _, means, chol = random_gmm(rng, 3, D)
    chol[:] = chol[0]                        # equal covariances -> the heaviest weight has c_k = c_min
    weights = np.array([0.6, 0.3, 0.1])
    r, _ = pose_prior_error(means[0], MaxMixture(weights, means, chol))
    np.testing.assert_allclose(r, 0.0, atol=1e-12)


def test_jacobian_matches_numerical_derivative():
    rng = np.random.default_rng(3)
    weights, means, chol = random_gmm(rng, 3, D)
    key = gtsam.symbol("p", 7)
    factor = make_pose_prior_factor(key, weights, means, chol)
    values = gtsam.Values()
    values.insert(key, means[1] + rng.normal(scale=0.05, size=D))
    assert_factor_jacobians(factor, values)
    r = factor.unwhitenedError(values)
    assert r.shape == (D + 1,)
    np.testing.assert_allclose(factor.error(values), 0.5 * r @ r)


def test_covariance_scale_weakens_prior_and_shared_mixture():
    rng = np.random.default_rng(4)
    weights, means, chol = random_gmm(rng, 2, D)
    x = means[0] + rng.normal(scale=0.2, size=D)
    r1, _ = pose_prior_error(x, MaxMixture(weights, means, chol))
    r4, _ = pose_prior_error(x, MaxMixture(weights, means, chol, covariance_scale=4.0))
    assert np.linalg.norm(r4[:-1]) < np.linalg.norm(r1[:-1])
    mix = MaxMixture(weights, means, chol)
    key = gtsam.symbol("p", 0)
    f = make_pose_prior_factor(key, mixture=mix)
    v = gtsam.Values()
    v.insert(key, x)
    np.testing.assert_allclose(f.unwhitenedError(v), r1)


def test_bad_inputs_raise():
    rng = np.random.default_rng(5)
    weights, means, chol = random_gmm(rng, 2, 5)
    with pytest.raises(ValueError, match="69"):
        make_pose_prior_factor(0, weights, means, chol)
    with pytest.raises(ValueError, match="prec_chol"):
        MaxMixture(weights, means, chol[:, :4])
    with pytest.raises(ValueError, match="needs"):
        make_pose_prior_factor(0)


def test_factor_error_is_the_best_components_negative_log_density():
    """The factor built from a GaussianMixturePrior: error = -log max_k w_k N_k(x) - C (the prior's density)."""
    import pedx_graph.priors.gmm as gmm_mod
    rng = np.random.default_rng(6)
    weights, means, chol = random_gmm(rng, 3, D)
    cov = np.linalg.inv(chol @ np.swapaxes(chol, 1, 2))
    prior = gmm_mod.GaussianMixturePrior(name="pose", weights=weights, means=means, covariances=cov,
                                         precisions_cholesky=chol, dims=tuple(f"d{i}" for i in range(D)))
    factor = make_pose_prior_factor(0, mixture=MaxMixture.from_gmm(prior))
    for _ in range(3):
        x = means[rng.integers(3)] + rng.normal(scale=0.1, size=D)
        values = gtsam.Values()
        values.insert(0, x)
        expected = -prior.component_log_densities(x).max() - prior.residual_constant()
        assert factor.error(values) == pytest.approx(expected, rel=1e-9, abs=1e-9)
