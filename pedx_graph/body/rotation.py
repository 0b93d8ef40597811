"""SO(3) helpers in pure numpy, batched over leading dimensions.

Conventions
-----------
* A rotation vector ``omega`` (..., 3) is an axis-angle vector: angle ``theta = |omega|`` in radians about
  the unit axis ``omega / theta``.
* ``hat(omega)`` is the skew matrix with ``hat(a) @ b == cross(a, b)``.
* ``exp_so3(omega) = I + sin(theta)/theta K + (1 - cos(theta))/theta^2 K^2`` with ``K = hat(omega)``
  (Rodrigues).  Near ``theta = 0`` the coefficients are evaluated by their Taylor series, so the result
  and its derivatives stay finite and accurate at 0 and at 1e-7.
* Right Jacobian: ``exp_so3(omega + d) ~= exp_so3(omega) @ exp_so3(right_jacobian(omega) @ d)``, i.e.
  ``J_r(omega) = I - (1 - cos theta)/theta^2 K + (theta - sin theta)/theta^3 K^2``.  This is the GTSAM
  ``Rot3::ExpmapDerivative`` convention.
* ``log_so3`` returns the rotation vector with angle in [0, pi]; near pi it recovers the axis from the
  symmetric part of the matrix.

All functions accept float arrays of any leading shape and return float64.
"""
from __future__ import annotations

import numpy as np

#: Below this angle (rad) the Rodrigues / Jacobian coefficients use their Taylor series.  With terms up to
#: theta^4 the truncation error at the switch is ~theta^6/5040 ~ 1e-22, far below float64 resolution.
SMALL_ANGLE = 1e-3

#: Above ``pi - NEAR_PI`` the logarithm takes the axis from the symmetric part of the matrix.
NEAR_PI = 1e-3


def hat(omega: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix of ``omega`` (..., 3) -> (..., 3, 3), ``hat(a) @ b = a x b``."""
    omega = np.asarray(omega, dtype=np.float64)
    out = np.zeros(omega.shape[:-1] + (3, 3))
    x, y, z = omega[..., 0], omega[..., 1], omega[..., 2]
    out[..., 0, 1] = -z
    out[..., 0, 2] = y
    out[..., 1, 0] = z
    out[..., 1, 2] = -x
    out[..., 2, 0] = -y
    out[..., 2, 1] = x
    return out


def vee(mat: np.ndarray) -> np.ndarray:
    """Inverse of :func:`hat` on the skew part: (..., 3, 3) -> (..., 3), ``vee(M) = (M - M^T)^v / 2``."""
    mat = np.asarray(mat, dtype=np.float64)
    return 0.5 * np.stack(
        [mat[..., 2, 1] - mat[..., 1, 2],
         mat[..., 0, 2] - mat[..., 2, 0],
         mat[..., 1, 0] - mat[..., 0, 1]],
        axis=-1,
    )


def _angle(omega: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """theta, theta^2 and a mask of small angles for ``omega`` (..., 3)."""
    theta2 = np.einsum("...i,...i->...", omega, omega)
    theta = np.sqrt(theta2)
    return theta, theta2, theta < SMALL_ANGLE


def _safe(theta: np.ndarray, small: np.ndarray) -> np.ndarray:
    """theta with small entries replaced by 1 (their value is taken from a Taylor series instead)."""
    return np.where(small, 1.0, theta)


def rodrigues_coefficients(omega: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coefficients ``a = sin(t)/t``, ``b = (1 - cos t)/t^2``, ``c = (t - sin t)/t^3`` of ``omega`` (..., 3).

    Each has shape (...,); Taylor series are used for ``t < SMALL_ANGLE``.
    """
    omega = np.asarray(omega, dtype=np.float64)
    theta, theta2, small = _angle(omega)
    if not small.any():                     # common case: no Taylor branch needed
        s, co = np.sin(theta), np.cos(theta)
        return s / theta, (1.0 - co) / theta2, (theta - s) / (theta2 * theta)
    ts = _safe(theta, small)
    s, co = np.sin(ts), np.cos(ts)
    a = np.where(small, 1.0 - theta2 / 6.0 + theta2 * theta2 / 120.0, s / ts)
    b = np.where(small, 0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0, (1.0 - co) / (ts * ts))
    c = np.where(small, 1.0 / 6.0 - theta2 / 120.0 + theta2 * theta2 / 5040.0, (ts - s) / (ts * ts * ts))
    return a, b, c


def exp_so3(omega: np.ndarray) -> np.ndarray:
    """Rotation matrix ``Exp(omega)`` for rotation vectors (..., 3) -> (..., 3, 3) (Rodrigues formula)."""
    omega = np.asarray(omega, dtype=np.float64)
    a, b, _ = rodrigues_coefficients(omega)
    k = hat(omega)
    return np.eye(3) + a[..., None, None] * k + b[..., None, None] * (k @ k)


def right_jacobian(omega: np.ndarray) -> np.ndarray:
    """Right Jacobian ``J_r(omega)`` (..., 3) -> (..., 3, 3).

    ``J_r = I - (1 - cos t)/t^2 K + (t - sin t)/t^3 K^2`` with ``K = hat(omega)``; so that
    ``Exp(omega + d) ~= Exp(omega) Exp(J_r d)`` to first order in ``d``.  ``J_r(0) = I``.
    """
    return exp_and_right_jacobian(omega)[1]


def exp_and_right_jacobian(omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(exp_so3(omega), right_jacobian(omega))`` sharing ``K``, ``K^2`` and the coefficients."""
    omega = np.asarray(omega, dtype=np.float64)
    a, b, c = rodrigues_coefficients(omega)
    k = hat(omega)
    k2 = k @ k
    b = b[..., None, None]
    eye = np.eye(3)
    return eye + a[..., None, None] * k + b * k2, eye - b * k + c[..., None, None] * k2


def left_jacobian(omega: np.ndarray) -> np.ndarray:
    """Left Jacobian ``J_l(omega) = J_r(-omega)``: ``Exp(omega + d) ~= Exp(J_l d) Exp(omega)``."""
    return right_jacobian(-np.asarray(omega, dtype=np.float64))


def right_jacobian_inverse(omega: np.ndarray) -> np.ndarray:
    """Inverse right Jacobian ``J_r(omega)^-1`` (..., 3) -> (..., 3, 3).

    ``J_r^-1 = I + K/2 + (1/t^2 - (1 + cos t)/(2 t sin t)) K^2``; the coefficient's Taylor series
    ``1/12 + t^2/720 + t^4/30240`` is used for small ``t``.  It is singular at ``t = 2 pi`` (not at pi),
    so it is finite for every rotation vector returned by :func:`log_so3`.
    """
    omega = np.asarray(omega, dtype=np.float64)
    theta, theta2, small = _angle(omega)
    ts = _safe(theta, small)
    d = np.where(small, 1.0 / 12.0 + theta2 / 720.0 + theta2 * theta2 / 30240.0,
                 1.0 / (ts * ts) - (1.0 + np.cos(ts)) / (2.0 * ts * np.sin(ts)))
    k = hat(omega)
    eye = np.broadcast_to(np.eye(3), k.shape)
    return eye + 0.5 * k + d[..., None, None] * (k @ k)


def exp_so3_derivative(omega: np.ndarray, rot: np.ndarray | None = None,
                       jr: np.ndarray | None = None) -> np.ndarray:
    """Derivative of the matrix ``Exp(omega)`` (..., 3) with respect to ``omega``: (..., 3, 3, 3).

    ``out[..., r, s, m] = d Exp(omega)[r, s] / d omega[m] = (Exp(omega) @ hat(J_r(omega)[:, m]))[r, s]``.
    Used for the pose-corrective blend shapes, which are linear in the matrix entries.  ``rot`` and ``jr``
    (``exp_so3(omega)``, ``right_jacobian(omega)``) may be passed when already computed.
    """
    omega = np.asarray(omega, dtype=np.float64)
    rot = exp_so3(omega) if rot is None else rot
    jr = right_jacobian(omega) if jr is None else jr
    # hat of each column m of J_r: (..., m, 3, 3)
    hats = hat(np.swapaxes(jr, -1, -2))
    out = rot[..., None, :, :] @ hats          # (..., m, r, s)
    return np.moveaxis(out, -3, -1)


def log_so3(rot: np.ndarray) -> np.ndarray:
    """Rotation vector ``Log(R)`` of rotation matrices (..., 3, 3) -> (..., 3), angle in [0, pi].

    The angle is ``atan2(|vee(R)|, (tr R - 1)/2)`` (well conditioned everywhere).  Away from pi,
    ``omega = theta / sin(theta) * vee(R)`` (Taylor series for small angles).  Within ``NEAR_PI`` of pi the
    axis is taken from the largest column of ``(R + R^T)/2 - cos(theta) I = (1 - cos theta) u u^T``, with the
    sign chosen to agree with ``vee(R)``.
    """
    rot = np.asarray(rot, dtype=np.float64)
    v = vee(rot)
    sin_t = np.linalg.norm(v, axis=-1)
    cos_t = 0.5 * (np.trace(rot, axis1=-2, axis2=-1) - 1.0)
    theta = np.arctan2(sin_t, cos_t)
    small = theta < SMALL_ANGLE
    near_pi = theta > np.pi - NEAR_PI
    regular = ~(small | near_pi)
    theta2 = theta * theta
    scale = np.where(small, 1.0 + theta2 / 6.0 + 7.0 * theta2 * theta2 / 360.0,
                     theta / np.where(regular, sin_t, 1.0))
    out = scale[..., None] * v
    if np.any(near_pi):
        sym = 0.5 * (rot + np.swapaxes(rot, -1, -2)) - cos_t[..., None, None] * np.eye(3)
        sym = sym[near_pi]                                  # (n, 3, 3) = (1 - cos t) u u^T
        idx = np.argmax(np.diagonal(sym, axis1=-2, axis2=-1), axis=-1)
        col = np.take_along_axis(sym, idx[:, None, None], axis=-1)[..., 0]   # (1 - cos t) u u_i
        axis = col / np.linalg.norm(col, axis=-1, keepdims=True)
        sign = np.where(np.einsum("ni,ni->n", axis, v[near_pi]) < 0.0, -1.0, 1.0)
        out[near_pi] = (sign * theta[near_pi])[:, None] * axis
    return out


def quaternion_to_matrix(quat_wxyz: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) stored as (w, x, y, z) (normalised first)."""
    q = np.asarray(quat_wxyz, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack(
        [np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
         np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
         np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1)],
        axis=-2,
    )
