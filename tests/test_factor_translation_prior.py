"""Tests of factors/translation_prior.py (E_T, PedX Eq. 2)."""
import gtsam
import numpy as np
import pytest

from factor_testing import ToyBodyModel, assert_factor_jacobians
from synthetic_model import synthetic_body_model
from factors.translation_prior import (make_translation_prior_factor, pelvis_shape_basis, sensor_ray_frame,
                                       translation_prior_error)

KT, KB = gtsam.symbol("t", 1), gtsam.symbol("b", 0)
UP, ORIGIN = np.array([0.0, 0.0, 1.0]), np.zeros(3)      # a z-up world with the sensor at its origin


def _values(trans, betas):
    v = gtsam.Values()
    v.insert(KT, np.asarray(trans, float))
    v.insert(KB, np.asarray(betas, float))
    return v


def test_ray_frame():
    q = sensor_ray_frame(np.array([0.0, 5.0, 1.0]), ORIGIN, UP)
    np.testing.assert_allclose(q[:, 0], [0, 1, 0], atol=1e-12)      # ray
    np.testing.assert_allclose(q[:, 1], [-1, 0, 0], atol=1e-12)     # left of the ray
    np.testing.assert_allclose(q.T @ q, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(sensor_ray_frame(np.array([0.0, 0.0, 3.0]), ORIGIN, UP)[:, 0], [1, 0, 0])
    # z-down world, sensor off the origin: the ray is laid on the ground plane, the third column is up
    q = sensor_ray_frame(np.array([-10.0, 1.0, -1.0]), np.array([-2.0, 1.0, -1.5]), np.array([0.0, 0.0, -1.0]))
    np.testing.assert_allclose(q[:, 0], [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(q[:, 2], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(q), 1.0, atol=1e-12)


@pytest.mark.parametrize("model_kind", ["toy", "synthetic_smpl"])
def test_pelvis_basis_matches_model(model_kind):
    model = ToyBodyModel() if model_kind == "toy" else synthetic_body_model()
    rng = np.random.default_rng(0)
    betas = rng.normal(size=10)
    rest, dirs = pelvis_shape_basis(model, 10)
    np.testing.assert_allclose(rest + dirs @ betas, model.rest_joints(betas)[0], atol=1e-12)
    if model_kind == "synthetic_smpl":                 # posed pelvis = J0(betas) + trans, any pose
        pose = rng.normal(scale=0.5, size=72)
        trans = rng.normal(size=3)
        np.testing.assert_allclose(model.forward(pose, betas, trans).joints[0], rest + dirs @ betas + trans,
                                   atol=1e-10)


def test_zero_at_expected_offset_and_jacobians():
    rng = np.random.default_rng(1)
    model = ToyBodyModel()
    betas = rng.normal(size=10)
    rest, dirs = pelvis_shape_basis(model, 10)
    # LiDAR points whose mean lies 0.1 m in front of the pelvis along the ray from the origin
    pelvis = np.array([6.0, 3.0, 1.0])
    ray = np.array([6.0, 3.0, 0.0]) / np.hypot(6.0, 3.0)
    pts = pelvis - 0.1 * ray + rng.normal(scale=0.2, size=(50, 3))
    pts -= pts.mean(axis=0) - (pelvis - 0.1 * ray)
    trans = pelvis - rest - dirs @ betas
    f = make_translation_prior_factor(KT, KB, model, pts, world_up=UP, world_p_sensor=ORIGIN)
    np.testing.assert_allclose(f.unwhitenedError(_values(trans, betas)), 0.0, atol=1e-12)
    v = _values(trans + rng.normal(scale=0.3, size=3), betas + 0.5)
    assert f.error(v) > 0
    assert_factor_jacobians(f, v)


def test_sigmas_per_axis_and_no_points():
    model = ToyBodyModel()
    pts = np.array([[5.0, 0.0, 1.0]])
    f = make_translation_prior_factor(KT, KB, model, pts, world_up=UP, world_p_sensor=ORIGIN, sigma_ray_m=0.2, sigma_lateral_m=0.05,
                                      sigma_vertical_m=0.3)
    np.testing.assert_allclose(f.noiseModel().sigmas(), [0.2, 0.05, 0.3])
    q = sensor_ray_frame(pts[0], ORIGIN, UP)
    r, _ = translation_prior_error(np.array([1.0, 2.0, 3.0]), np.zeros(10), np.zeros(3), np.zeros((3, 10)),
                                   pts[0], q, np.zeros(3))
    np.testing.assert_allclose(r, [1.0 - 5.0, 2.0, 3.0 - 1.0])
    assert make_translation_prior_factor(KT, KB, model, np.zeros((0, 3)), world_up=UP, world_p_sensor=ORIGIN) is None
