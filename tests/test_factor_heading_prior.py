"""Tests of factors/heading_prior.py (E_D, PedX Eq. 3)."""
import gtsam
import numpy as np
import pytest

from factors.heading_prior import (heading_prior_error, heading_sigma, heading_vector,
                                   make_heading_prior_factor, trajectory_headings)
from factor_testing import assert_factor_jacobians, random_rot3

#: The z-up level frame of these tests (world = level); other level frames are tested below.
LEVEL = np.eye(3)


def _standing(yaw):
    """world_R_body of an upright body (body +Y -> world +z) facing world yaw ``yaw``."""
    forward = np.array([np.cos(yaw), np.sin(yaw), 0.0])     # body +Z
    up = np.array([0.0, 0.0, 1.0])                          # body +Y
    x_axis = np.cross(up, forward)                          # body +X = Y x Z
    return np.stack([x_axis, up, forward], axis=1)


def test_noise_free_zero_and_sign():
    rot = _standing(0.7)
    r, _ = heading_prior_error(rot, heading_vector(0.7), LEVEL)
    assert abs(r[0]) < 1e-12
    r, _ = heading_prior_error(rot, heading_vector(0.5), LEVEL)
    assert r[0] == pytest.approx(0.2)                       # body is 0.2 rad counter-clockwise of heading


def test_wrap_near_pi():
    rot = _standing(np.pi - 0.05)
    r, _ = heading_prior_error(rot, heading_vector(-np.pi + 0.05), LEVEL)
    assert r[0] == pytest.approx(-0.1)
    r, _ = heading_prior_error(_standing(-np.pi + 0.02), heading_vector(np.pi - 0.03), LEVEL)
    assert r[0] == pytest.approx(0.05)
    key = gtsam.symbol("r", 0)
    f = make_heading_prior_factor(key, np.pi - 0.01, speed=1.2, world_R_level=LEVEL)
    v = gtsam.Values()
    v.insert(key, gtsam.Rot3(_standing(-np.pi + 0.01)))
    assert_factor_jacobians(f, v)


def test_jacobian_random_rotations():
    rng = np.random.default_rng(0)
    key = gtsam.symbol("r", 4)
    for _ in range(5):
        f = make_heading_prior_factor(key, rng.normal(size=2), speed=1.0, world_R_level=LEVEL)
        v = gtsam.Values()
        v.insert(key, random_rot3(rng))
        assert_factor_jacobians(f, v)


def test_vertical_forward_axis_is_finite():
    rot = np.eye(3)                                         # body +Z -> world +z: lying face up
    r, jac = heading_prior_error(rot, heading_vector(0.3), LEVEL, want_jacobian=True)
    assert r[0] == 0.0 and np.all(jac == 0.0)


def test_speed_handling():
    assert heading_sigma(2.0, 0.3, 0.5) == pytest.approx(0.3)
    assert heading_sigma(0.25, 0.3, 0.5) == pytest.approx(0.6)
    assert np.isfinite(heading_sigma(0.0, 0.3, 0.5))
    assert make_heading_prior_factor(0, 0.0, speed=0.1, min_speed=0.2, world_R_level=LEVEL) is None
    f = make_heading_prior_factor(0, 0.0, speed=0.25, sigma0_rad=0.3, v0=0.5, min_speed=0.2, world_R_level=LEVEL)
    np.testing.assert_allclose(f.noiseModel().sigmas(), [0.6])
    with pytest.raises(ValueError):
        make_heading_prior_factor(0, np.zeros(2), speed=1.0, world_R_level=LEVEL)
    with pytest.raises(ValueError):
        make_heading_prior_factor(0, 0.0, speed=float("nan"), world_R_level=LEVEL)


def test_trajectory_headings_walk_and_stand():
    ts = np.arange(20) * 0.1
    direction = np.array([np.cos(2.0), np.sin(2.0), 0.0])
    walk = np.array([1.0, 2.0, 0.9]) + 1.4 * ts[:, None] * direction
    heading, speed = trajectory_headings(ts, walk)
    np.testing.assert_allclose(heading, np.tile(direction[:2], (20, 1)), atol=1e-12)
    np.testing.assert_allclose(speed, 1.4, rtol=1e-9)
    stand = np.tile([3.0, 1.0, 0.9], (20, 1))
    heading, speed = trajectory_headings(ts, stand)
    assert np.all(speed == 0.0) and np.all(np.isfinite(heading))
    assert all(make_heading_prior_factor(0, h, s, world_R_level=LEVEL) is None for h, s in zip(heading, speed))
    _, speed1 = trajectory_headings(np.array([0.0]), stand[:1])
    assert speed1[0] == 0.0
    with pytest.raises(ValueError, match="increasing"):
        trajectory_headings(np.array([0.0, 0.0]), stand[:2])


def test_level_frame_is_respected_and_rigidly_invariant():
    """The prior reads the heading in the given level frame: turning the whole world (body and level frame)
    by any rotation leaves residual and Jacobian unchanged, and a z-down world works like a z-up one."""
    rng = np.random.default_rng(7)
    key = gtsam.symbol("r", 2)
    for _ in range(5):
        world_R_level = random_rot3(rng).matrix()
        level_R_body = random_rot3(rng).matrix()
        heading = rng.normal(size=2)
        r0, j0 = heading_prior_error(level_R_body, heading_vector(heading), np.eye(3), want_jacobian=True)
        r1, j1 = heading_prior_error(world_R_level @ level_R_body, heading_vector(heading), world_R_level,
                                     want_jacobian=True)
        np.testing.assert_allclose(r1, r0, atol=1e-12)
        np.testing.assert_allclose(j1, j0, atol=1e-12)       # right perturbation: body-frame tangent
        f = make_heading_prior_factor(key, heading, speed=1.0, world_R_level=world_R_level)
        v = gtsam.Values()
        v.insert(key, random_rot3(rng))
        assert_factor_jacobians(f, v)
    z_down = np.diag([1.0, -1.0, -1.0])                       # level x = world x, level up = world -z
    upright = z_down @ _standing(0.4)
    r, _ = heading_prior_error(upright, heading_vector(0.4), z_down)
    assert abs(r[0]) < 1e-12
    with pytest.raises(ValueError, match="rotation"):
        make_heading_prior_factor(key, 0.0, speed=1.0, world_R_level=2 * np.eye(3))
