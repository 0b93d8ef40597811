"""SO(3) helpers: Rodrigues, log, right Jacobian, at random angles, 0, 1e-7 and near pi."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pedx_graph.body.rotation import (exp_so3, exp_so3_derivative, hat, left_jacobian, log_so3,
                                      quaternion_to_matrix, right_jacobian, right_jacobian_inverse, vee)


def _unit(rng, n):
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def _test_vectors(seed=0):
    """Rotation vectors: random, zero, tiny (1e-7, 1e-12), near the small-angle switch, near pi."""
    rng = np.random.default_rng(seed)
    axes = _unit(rng, 8)
    angles = np.array([0.3, 1.7, 2.9, 1e-7, 1e-12, 9.99e-4, 1.001e-3, np.pi - 1e-4])
    return np.concatenate([axes * angles[:, None], np.zeros((1, 3)), rng.normal(size=(4, 3))])


def test_hat_is_cross_product_and_vee_inverts_it():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(2, 5, 3))
    np.testing.assert_allclose(hat(a) @ b[..., None], np.cross(a, b)[..., None], atol=1e-15)
    np.testing.assert_allclose(vee(hat(a)), a, atol=1e-15)


def test_exp_matches_scipy_and_is_a_rotation():
    w = _test_vectors()
    rot = exp_so3(w)
    np.testing.assert_allclose(rot, Rotation.from_rotvec(w).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(rot @ np.swapaxes(rot, -1, -2), np.broadcast_to(np.eye(3), rot.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-14)


def test_exp_is_batched_over_leading_dims():
    w = np.random.default_rng(2).normal(size=(2, 3, 4, 3))
    assert exp_so3(w).shape == (2, 3, 4, 3, 3)
    np.testing.assert_allclose(exp_so3(w)[1, 2, 3], exp_so3(w[1, 2, 3]), atol=0)


def test_log_inverts_exp_including_tiny_and_near_pi_angles():
    w = _test_vectors()
    back = log_so3(exp_so3(w))
    np.testing.assert_allclose(back, w, atol=1e-11, rtol=1e-9)
    # tiny angles keep their relative precision
    tiny = np.array([[1e-7, -2e-7, 3e-8]])
    np.testing.assert_allclose(log_so3(exp_so3(tiny)), tiny, rtol=1e-9, atol=0)


@pytest.mark.parametrize("eps", [1e-4, 1e-7, 1e-10, 0.0])
def test_log_near_pi_returns_a_vector_that_maps_back(eps):
    rng = np.random.default_rng(3)
    axes = _unit(rng, 6)
    rot = exp_so3(axes * (np.pi - eps))
    w = log_so3(rot)
    np.testing.assert_allclose(np.linalg.norm(w, axis=1), np.pi - eps, atol=1e-9)
    np.testing.assert_allclose(exp_so3(w), rot, atol=1e-12)


def _numeric_right_jacobian(w, h=1e-6):
    """Column m: Log(Exp(w)^T Exp(w + h e_m)) central difference."""
    base_t = np.swapaxes(exp_so3(w), -1, -2)
    cols = []
    for e in np.eye(3):
        plus = log_so3(base_t @ exp_so3(w + h * e))
        minus = log_so3(base_t @ exp_so3(w - h * e))
        cols.append((plus - minus) / (2 * h))
    return np.stack(cols, axis=-1)


def test_right_jacobian_matches_numerical_derivative():
    w = _test_vectors()
    np.testing.assert_allclose(right_jacobian(w), _numeric_right_jacobian(w), atol=1e-8)
    np.testing.assert_allclose(right_jacobian(np.zeros(3)), np.eye(3), atol=0)


def test_left_jacobian_and_inverse():
    w = _test_vectors()
    # Exp(J_l d) Exp(w) = Exp(w) Exp(J_r d)  =>  J_l = Exp(w) J_r
    np.testing.assert_allclose(left_jacobian(w), exp_so3(w) @ right_jacobian(w), atol=1e-12)
    eye = np.broadcast_to(np.eye(3), (len(w), 3, 3))
    np.testing.assert_allclose(right_jacobian_inverse(w) @ right_jacobian(w), eye, atol=1e-9)


def test_exp_derivative_matches_finite_differences():
    w = _test_vectors()
    h = 1e-6
    num = np.stack([(exp_so3(w + h * e) - exp_so3(w - h * e)) / (2 * h) for e in np.eye(3)], axis=-1)
    np.testing.assert_allclose(exp_so3_derivative(w), num, atol=1e-9)


def test_quaternion_to_matrix_matches_scipy():
    q = np.random.default_rng(4).normal(size=(6, 4))
    xyzw = np.concatenate([q[:, 1:], q[:, :1]], axis=1)
    np.testing.assert_allclose(quaternion_to_matrix(q), Rotation.from_quat(xyzw).as_matrix(), atol=1e-14)
