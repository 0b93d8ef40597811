"""Tests of factors/temporal_prior.py (E_tp, PedX Eq. 10)."""
import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from factors.common import MaxMixture
from factors.temporal_prior import (TEMPORAL_DIM, make_temporal_prior_factor, sequence_differences,
                                    temporal_difference,
                                    temporal_difference_jacobians, temporal_prior_error)
from factor_testing import assert_factor_jacobians, random_gmm, random_rot3


def _frame(rng):
    return random_rot3(rng), rng.normal(size=3), rng.normal(scale=0.3, size=69)


def test_difference_definition_and_invariance():
    rng = np.random.default_rng(0)
    ri, ti, pi = _frame(rng)
    rj, tj, pj = _frame(rng)
    d = temporal_difference(ri.matrix(), ti, pi, rj.matrix(), tj, pj)
    assert d.shape == (TEMPORAL_DIM,)
    np.testing.assert_allclose(d[:3], ri.matrix().T @ (tj - ti))
    np.testing.assert_allclose(d[3:6], gtsam.Rot3.Logmap(ri.between(rj)), atol=1e-12)
    np.testing.assert_allclose(d[6:], pj - pi)
    # invariant to a rigid motion of the world (any up axis)
    g = random_rot3(rng).matrix()
    shift = rng.normal(size=3)
    d2 = temporal_difference(g @ ri.matrix(), g @ ti + shift, pi, g @ rj.matrix(), g @ tj + shift, pj)
    np.testing.assert_allclose(d2, d, atol=1e-12)
    # batched
    batch = temporal_difference(np.stack([ri.matrix()] * 2), np.stack([ti] * 2), np.stack([pi] * 2),
                                np.stack([rj.matrix()] * 2), np.stack([tj] * 2), np.stack([pj] * 2))
    np.testing.assert_allclose(batch, np.stack([d, d]), atol=1e-12)
    d1, _ = temporal_difference_jacobians(ri.matrix(), ti, pi, rj.matrix(), tj, pj)
    np.testing.assert_allclose(d1, d, atol=1e-12)
    seq = sequence_differences(np.stack([ri.matrix(), rj.matrix(), ri.matrix()]), np.stack([ti, tj, ti]),
                               np.stack([pi, pj, pi]))
    assert seq.shape == (2, TEMPORAL_DIM)
    np.testing.assert_allclose(seq[0], d, atol=1e-12)


def _values_and_keys(rng):
    keys = [gtsam.symbol(c, i) for i in (3, 4) for c in "rtp"]
    v = gtsam.Values()
    for i in range(2):
        rot, trans, pose = _frame(rng)
        v.insert(keys[3 * i], rot)
        v.insert(keys[3 * i + 1], trans)
        v.insert(keys[3 * i + 2], pose)
    return v, keys


@pytest.mark.parametrize("gap", [1, 3])
def test_jacobians_match_numerical(gap):
    rng = np.random.default_rng(10 + gap)
    weights, means, chol = random_gmm(rng, 3, TEMPORAL_DIM)
    v, keys = _values_and_keys(rng)
    f = make_temporal_prior_factor(*keys, weights, means, chol, frame_gap=gap)
    assert_factor_jacobians(f, v, rtol=1e-5, atol=1e-5)
    assert f.unwhitenedError(v).shape == (TEMPORAL_DIM + 1,)


def test_zero_residual_and_gap_scaling():
    rng = np.random.default_rng(20)
    _, means, chol = random_gmm(rng, 2, TEMPORAL_DIM)
    chol[:] = chol[0]
    mix = MaxMixture(np.array([0.7, 0.3]), means, chol)
    # build frame j so that d(i, j) equals the dominant mean exactly
    ri, ti, pi = _frame(rng)
    mu = means[0]
    rj = ri.matrix() @ gtsam.Rot3.Expmap(mu[3:6]).matrix()
    tj = ti + ri.matrix() @ mu[:3]
    pj = pi + mu[6:]
    r, _ = temporal_prior_error(ri.matrix(), ti, pi, rj, tj, pj, mix)
    np.testing.assert_allclose(r, 0.0, atol=1e-9)
    # a two-frame gap with twice the step is also zero (evaluated at d / k)
    rj2 = rj @ gtsam.Rot3.Expmap(mu[3:6]).matrix()
    tj2 = ti + ri.matrix() @ (2 * mu[:3])
    pj2 = pi + 2 * mu[6:]
    d2 = temporal_difference(ri.matrix(), ti, pi, rj2, tj2, pj2)
    r2, _ = temporal_prior_error(ri.matrix(), ti, pi, rj2, tj2, pj2, mix, frame_gap=2)
    np.testing.assert_allclose(d2[:3], 2 * mu[:3], atol=1e-9)
    np.testing.assert_allclose(r2, 0.0, atol=1e-9)


def test_bad_inputs():
    rng = np.random.default_rng(30)
    weights, means, chol = random_gmm(rng, 2, TEMPORAL_DIM)
    with pytest.raises(ValueError, match="frame_gap"):
        make_temporal_prior_factor(*range(6), weights, means, chol, frame_gap=0)
    w5, m5, c5 = random_gmm(rng, 2, 5)
    with pytest.raises(ValueError, match="75"):
        make_temporal_prior_factor(*range(6), w5, m5, c5)


def test_factor_and_training_share_one_definition_of_the_difference():
    """The factor and the prior's training use the one function of pedx_graph.priors.difference; a sequence's
    differences are the pairwise ones of consecutive frames."""
    import factors.temporal_prior as tp
    import pedx_graph.priors.train as train
    from pedx_graph.priors.difference import temporal_difference

    assert tp.temporal_difference is temporal_difference and train.temporal_difference is temporal_difference
    rng = np.random.default_rng(40)
    rot = np.stack([random_rot3(rng).matrix() for _ in range(6)])
    trans = rng.normal(size=(6, 3))
    pose = rng.normal(scale=0.3, size=(6, 69))
    seq = sequence_differences(rot, trans, pose)
    for t in range(5):
        d = temporal_difference(rot[t], trans[t], pose[t], rot[t + 1], trans[t + 1], pose[t + 1])
        np.testing.assert_allclose(seq[t], d, atol=1e-12)
        np.testing.assert_allclose(d[:3], rot[t].T @ (trans[t + 1] - trans[t]), atol=1e-12)
        np.testing.assert_allclose(Rotation.from_rotvec(d[3:6]).as_matrix(), rot[t].T @ rot[t + 1], atol=1e-9)


def test_mixture_from_sklearn_like_object():
    from types import SimpleNamespace
    rng = np.random.default_rng(41)
    weights, means, chol = random_gmm(rng, 2, TEMPORAL_DIM)
    a = MaxMixture.from_gmm(SimpleNamespace(weights_=weights, means_=means, precisions_cholesky_=chol))
    b = MaxMixture.from_gmm(SimpleNamespace(weights=weights, means=means, precisions_cholesky=chol))
    x = rng.normal(size=TEMPORAL_DIM)
    np.testing.assert_allclose(a.residual(x)[0], b.residual(x)[0])
