"""Test helpers for factors: a tiny analytic body model and numerical Jacobian checks.

``ToyBodyModel`` has the same ``point_jacobians`` / ``forward`` interface as ``pedx_graph.body.BodyModel``
but a closed-form, cheap measurement model, so the factors' chain rules can be checked against numerical
derivatives without the SMPL machinery:

    body_v_i(betas, body_pose) = T_i + S_i betas + P_i sin(body_pose)          (body frame, metres)
    world_v_i = world_R_body @ body_v_i + trans

with ``T`` (V, 3) a human-sized point cloud (SMPL body frame: Y up, +Z forward), ``S`` (V, 3, B) and ``P``
(V, 3, 69) small random matrices.  The 18 keypoints are vertices ``keypoint_vertex_ids``; joints are the
first 24 vertices.
"""
from __future__ import annotations

from types import SimpleNamespace

import gtsam
import numpy as np
from gtsam.utils.numerical_derivative import numericalDerivative11

from pedx_graph.body.rotation import exp_so3, hat
from pedx_graph.data.types import StereoCalibration


class ToyBodyModel:
    """Closed-form stand-in for the body model (see the module docstring)."""

    def __init__(self, num_vertices: int = 200, num_betas: int = 10, seed: int = 0) -> None:
        rng = np.random.default_rng(seed)
        half = np.array([0.2, 0.85, 0.12])
        self.template = rng.uniform(-1.0, 1.0, size=(num_vertices, 3)) * half
        self.shapedirs = rng.normal(scale=0.01, size=(num_vertices, 3, num_betas))
        self.posedirs = rng.normal(scale=0.03, size=(num_vertices, 3, 69))
        self.keypoint_vertex_ids = np.arange(18) * (num_vertices // 18)
        self.num_betas = num_betas
        self.num_vertices = num_vertices

    def _body_points(self, body_pose: np.ndarray, betas: np.ndarray, ids: np.ndarray) -> np.ndarray:
        return (self.template[ids] + self.shapedirs[ids] @ betas + self.posedirs[ids] @ np.sin(body_pose))

    def rest_joints(self, betas: np.ndarray) -> np.ndarray:
        """Rest joints (24, 3): the first 24 vertices at zero body pose (linear in betas, like SMPL)."""
        ids = np.arange(24)
        return self.template[ids] + self.shapedirs[ids] @ np.asarray(betas, float)

    def forward(self, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray) -> SimpleNamespace:
        """Vertices (V,3), joints (24,3), keypoints (18,3) in the world frame."""
        pose = np.asarray(pose, dtype=np.float64)
        rot = exp_so3(pose[:3])
        ids = np.arange(self.num_vertices)
        verts = self._body_points(pose[3:], np.asarray(betas, float), ids) @ rot.T + trans
        return SimpleNamespace(vertices=verts, joints=verts[:24].copy(),
                               keypoints=verts[self.keypoint_vertex_ids].copy())

    def point_jacobians(self, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray,
                        vertex_ids: np.ndarray | None = None) -> SimpleNamespace:
        """Points and their derivatives (architecture.md convention) for keypoints or given vertices."""
        pose = np.asarray(pose, dtype=np.float64)
        rot = exp_so3(pose[:3])
        ids = self.keypoint_vertex_ids if vertex_ids is None else np.asarray(vertex_ids, dtype=np.int64)
        body = self._body_points(pose[3:], np.asarray(betas, float), ids)       # (N, 3)
        n = ids.size
        return SimpleNamespace(
            points=body @ rot.T + trans,
            d_root=-rot[None] @ hat(body),                                       # R Exp(d) v ~ R v - R [v]x d
            d_body_pose=(rot[None] @ self.posedirs[ids]) * np.cos(pose[3:])[None, None, :],
            d_trans=np.broadcast_to(np.eye(3), (n, 3, 3)).copy(),
            d_betas=rot[None] @ self.shapedirs[ids],
        )


def random_rot3(rng: np.random.Generator, max_angle: float = np.pi) -> gtsam.Rot3:
    """A random rotation with angle up to ``max_angle``."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return gtsam.Rot3.Expmap(axis * rng.uniform(0.2, max_angle))


def _get(values: gtsam.Values, key: int):
    try:
        return values.atRot3(key)
    except RuntimeError:
        return np.array(values.atVector(key))


def numerical_jacobians(factor: gtsam.NonlinearFactor, values: gtsam.Values,
                        delta: float = 1e-6) -> list[np.ndarray]:
    """Central-difference Jacobians of ``factor.unwhitenedError`` w.r.t. each of its keys (retracting)."""
    out = []
    for key in factor.keys():
        def h(x, key=key):
            v = gtsam.Values(values)
            v.update(key, x)
            return np.asarray(factor.unwhitenedError(v))
        out.append(numericalDerivative11(h, _get(values, key), delta))
    return out


def gtsam_jacobians(factor: gtsam.NoiseModelFactor, values: gtsam.Values) -> list[np.ndarray]:
    """Unwhitened per-key Jacobians as GTSAM sees them: ``linearize`` (whitened) times the sigmas.

    Valid for Gaussian (diagonal) noise models only: a robust model also reweights the rows.
    """
    jf = factor.linearize(values)
    a, _ = jf.jacobian()
    sig = np.asarray(factor.noiseModel().sigmas())
    a = a * sig[:, None]
    out, col = [], 0
    for key in factor.keys():
        x = _get(values, key)
        dim = 3 if isinstance(x, gtsam.Rot3) else x.size
        out.append(a[:, col:col + dim])
        col += dim
    return out


def random_gmm(rng: np.random.Generator, num_components: int, dim: int,
               scale: float = 0.3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random mixture (weights (K,), means (K,D), prec_chol (K,D,D) lower-triangular, precision = L L^T)."""
    weights = rng.uniform(0.5, 1.5, size=num_components)
    weights /= weights.sum()
    means = rng.normal(scale=scale, size=(num_components, dim))
    chol = np.empty((num_components, dim, dim))
    for k in range(num_components):
        a = rng.normal(size=(dim, dim)) / np.sqrt(dim)
        cov = (scale ** 2) * (a @ a.T + 0.5 * np.eye(dim))
        chol[k] = np.linalg.cholesky(np.linalg.inv(cov))
    return weights, means, chol


def assert_factor_jacobians(factor: gtsam.NoiseModelFactor, values: gtsam.Values,
                            rtol: float = 1e-5, atol: float = 1e-6) -> None:
    """Assert GTSAM's linearised Jacobians (unwhitened) match central differences, key by key."""
    num = numerical_jacobians(factor, values)
    ana = gtsam_jacobians(factor, values)
    for i, (a, n) in enumerate(zip(ana, num)):
        assert a.shape == n.shape, f"key {i}: shape {a.shape} vs numerical {n.shape}"
        np.testing.assert_allclose(a, n, rtol=rtol, atol=atol, err_msg=f"Jacobian block of key {i}")


def assert_factor_gradient(factor: gtsam.NoiseModelFactor, values: gtsam.Values,
                           rtol: float = 1e-5, atol: float = 1e-6) -> None:
    """Assert GTSAM's linearisation ``A^T b`` is minus the gradient of ``factor.error`` (central differences,
    key by key): what a factor whose linearisation reweights its rows (IRLS) must keep exact."""
    a, b = factor.linearize(values).jacobian()
    ana = -(a.T @ b)
    col = 0
    for i, key in enumerate(factor.keys()):
        def h(x, key=key):
            v = gtsam.Values(values)
            v.update(key, x)
            return np.array([factor.error(v)])
        num = numericalDerivative11(h, _get(values, key), 1e-5)[0]
        np.testing.assert_allclose(ana[col:col + num.size], num, rtol=rtol, atol=atol,
                                   err_msg=f"gradient of key {i}")
        col += num.size


def make_test_calibration(focal_px: float = 1000.0, baseline_m: float = 0.5,
                          rect_angle: float = 0.02) -> StereoCalibration:
    """A KITTI-style stereo pair 1.5 m above the world origin looking along world +x (camera x = world -y).

    ``rect_angle`` (rad) rotates the rectified frame slightly about the camera y axis (non-identity
    rectification).  Image 1920 x 1200, principal point at the centre.
    """
    k = np.array([[focal_px, 0.0, 960.0], [0.0, focal_px, 600.0], [0.0, 0.0, 1.0]])
    left = np.hstack([k, np.zeros((3, 1))])
    right = left.copy()
    right[0, 3] = -focal_px * baseline_m
    world_T_cam = np.eye(4)
    world_T_cam[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    world_T_cam[:3, 3] = [0.0, 0.0, 1.5]
    return StereoCalibration(name="test-pair", left_P_rect=left, right_P_rect=right,
                             rect_R_cam=gtsam.Rot3.Ry(rect_angle).matrix(), world_T_cam=world_T_cam,
                             image_size=(1920, 1200))


def standing_rotation(yaw: float) -> np.ndarray:
    """``world_R_body`` of an upright SMPL body in the tests' world whose up axis is ``e_z`` (body +Y -> ``e_z``)
    facing yaw ``yaw`` (body +Z); the estimator itself takes up from the data (``Track.ground``)."""
    forward = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    return np.stack([np.cross(up, forward), up, forward], axis=1)


def frame_values(keys, world_R_body: np.ndarray, trans: np.ndarray, body_pose: np.ndarray,
                 betas: np.ndarray) -> gtsam.Values:
    """Values holding one frame's variables under ``keys`` = [root, trans, body_pose, betas]."""
    v = gtsam.Values()
    v.insert(keys[0], gtsam.Rot3(np.asarray(world_R_body, float)))
    v.insert(keys[1], np.asarray(trans, float))
    v.insert(keys[2], np.asarray(body_pose, float))
    v.insert(keys[3], np.asarray(betas, float))
    return v
