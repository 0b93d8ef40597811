"""Tests of factors/joint_limits.py (hinge limits on knees and elbows)."""
import gtsam
import numpy as np
import pytest

from factors.joint_limits import DEFAULT_JOINT_LIMITS, JointLimit, joint_limit_error, make_joint_limit_factor
from factor_testing import assert_factor_jacobians


def test_zero_inside_limits_and_hinge_outside():
    pose = np.zeros(69)
    r, _ = joint_limit_error(pose)
    np.testing.assert_allclose(r, 0.0)
    pose[9] = -0.5                    # left knee bent backwards by 0.5 rad, limit -0.1
    pose[52] = 0.3                    # left elbow backwards, limit 0.1
    r, jac = joint_limit_error(pose, want_jacobian=True)
    np.testing.assert_allclose(r, [-0.4, 0.0, 0.2, 0.0], atol=1e-12)
    assert jac[0, 9] == 1.0 and jac[2, 52] == 1.0 and jac[1].sum() == 0.0


def test_jacobian_matches_numerical_derivative():
    rng = np.random.default_rng(1)
    key = gtsam.symbol("p", 3)
    f = make_joint_limit_factor(key, sigma_rad=0.1)
    pose = rng.normal(scale=0.3, size=69)
    pose[[9, 12, 52, 55]] = [-0.7, 1.0, 0.6, 3.0]      # outside, inside, outside, outside
    v = gtsam.Values()
    v.insert(key, pose)
    assert_factor_jacobians(f, v)
    assert f.error(v) > 0


def test_bad_limits_raise():
    with pytest.raises(ValueError):
        make_joint_limit_factor(0, limits=(JointLimit("x", 70, 0.0, 1.0),))
    with pytest.raises(ValueError):
        make_joint_limit_factor(0, limits=())
    assert len(DEFAULT_JOINT_LIMITS) == 4
