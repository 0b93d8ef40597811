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
