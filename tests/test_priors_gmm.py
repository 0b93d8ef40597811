"""GaussianMixturePrior: max-mixture residual = -log best component density + const, Jacobian, files."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from pedx_graph.priors.gmm import (GaussianMixturePrior, PriorFormatError, from_sklearn,
                                   precision_cholesky_from_covariance)


def _random_prior(seed=0, k=4, d=6):
    rng = np.random.default_rng(seed)
    means = rng.normal(size=(k, d))
    a = rng.normal(size=(k, d, d))
    cov = a @ np.swapaxes(a, 1, 2) / d + 0.1 * np.eye(d)
    w = rng.uniform(0.2, 1.0, size=k)
    return GaussianMixturePrior("test", w / w.sum(), means, cov, precision_cholesky_from_covariance(cov),
                                dims=tuple(f"x{i}" for i in range(d)))


def test_precision_cholesky():
    prior = _random_prior()
    for sigma, chol in zip(prior.covariances, prior.precisions_cholesky):
        np.testing.assert_allclose(chol @ chol.T, np.linalg.inv(sigma), rtol=1e-9, atol=1e-9)


def test_half_squared_residual_is_best_component_neg_log_density():
    prior = _random_prior()
    rng = np.random.default_rng(1)
    for x in rng.normal(size=(20, prior.dim)) * 1.5:
        r, _, k = prior.residual(x)
        dens = np.array([w * multivariate_normal(m, c).pdf(x)
                         for w, m, c in zip(prior.weights, prior.means, prior.covariances)])
        assert k == int(np.argmax(dens))
        assert 0.5 * r @ r == pytest.approx(-np.log(dens.max()) - prior.residual_constant(), rel=1e-9, abs=1e-9)
    assert np.all(prior.normalised_constants >= 0) and prior.normalised_constants.min() == 0.0


def test_jacobian_matches_numerical_derivative():
    prior = _random_prior(seed=2)
    x = np.random.default_rng(3).normal(size=prior.dim)
    r0, jac, k = prior.residual(x, want_jacobian=True)
    eps = 1e-6
    num = np.empty_like(jac)
    for i in range(prior.dim):
        dx = np.zeros(prior.dim)
        dx[i] = eps
        rp, _, kp = prior.residual(x + dx)
        rm, _, km = prior.residual(x - dx)
        assert kp == km == k
        num[:, i] = (rp - rm) / (2 * eps)
    np.testing.assert_allclose(jac, num, atol=1e-6)
    assert np.all(jac[-1] == 0)


def test_batch_residuals_equal_single():
    prior = _random_prior(seed=4)
    xs = np.random.default_rng(5).normal(size=(7, prior.dim))
    rs, ks = prior.residuals(xs)
    for x, r, k in zip(xs, rs, ks):
        r1, _, k1 = prior.residual(x)
        assert k == k1
        np.testing.assert_allclose(r, r1)


def test_sklearn_wrapper_density_matches_score_samples():
    from sklearn.mixture import GaussianMixture
    data = np.random.default_rng(6).normal(size=(300, 3)) @ np.diag([1.0, 0.3, 2.0])
    gmm = GaussianMixture(3, covariance_type="full", random_state=0).fit(data)
    prior = from_sklearn("s", gmm, dims=("a", "b", "c"))
    np.testing.assert_allclose(prior.log_density(data[:20]), gmm.score_samples(data[:20]), rtol=1e-9)


def test_factors_use_this_max_mixture_and_batch_equals_single():
    import factors.common as common
    from pedx_graph.priors.gmm import MaxMixture
    assert common.MaxMixture is MaxMixture                     # one definition of the residual
    prior = _random_prior(seed=7)
    xs = np.random.default_rng(8).normal(size=(5, prior.dim))
    r_batch, k_batch = prior.residuals(xs)
    for x, r_b, k_b in zip(xs, r_batch, k_batch):
        r_a, jac, k_a = prior.residual(x, want_jacobian=True)
        assert k_a == k_b
        np.testing.assert_allclose(r_a, r_b, atol=1e-12)
        np.testing.assert_allclose(jac[:-1], prior.precisions_cholesky[k_a].T, atol=1e-12)
        assert not jac[-1].any()


def test_npz_round_trip_and_errors(tmp_path):
    prior = _random_prior()
    prior = GaussianMixturePrior(**{**prior.__dict__, "dt": 0.1, "meta": {"a": 1}})
    path = prior.save_npz(tmp_path / "p.npz")
    back = GaussianMixturePrior.load_npz(path)
    np.testing.assert_array_equal(back.means, prior.means)
    np.testing.assert_array_equal(back.precisions_cholesky, prior.precisions_cholesky)
    assert back.dt == 0.1 and back.meta == {"a": 1} and back.dims == prior.dims
    with pytest.raises(PriorFormatError, match="not found"):
        GaussianMixturePrior.load_npz(tmp_path / "none.npz")
    np.savez(tmp_path / "bad.npz", weights=prior.weights)
    with pytest.raises(PriorFormatError, match="missing key 'means'"):
        GaussianMixturePrior.load_npz(tmp_path / "bad.npz")
