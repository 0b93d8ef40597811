"""Linear blend skinning of SMPL-format models in pure numpy (same meaning as smplx's ``lbs.py``).

Shapes: ``V`` vertices, ``J`` joints (24 for SMPL), ``B`` shape coefficients, ``P = 9 (J - 1)`` pose-corrective
features.  Every function is batched over arbitrary leading dimensions ``...`` and works in float64.

The model (Loper et al. 2015, SMPL eqs. 2-10), in the body frame (metres; SMPL's frame: Y up, +Z forward):

1. ``v_shaped = v_template + shapedirs . betas``                          (shape blend shapes)
2. ``J = J_regressor @ v_shaped``                                        (rest joint locations)
3. ``R_j = Exp(theta_j)``                                                (axis-angle per joint)
4. ``v_posed = v_shaped + posedirs . vec(R_1..J-1 - I)``                 (pose correctives, row-major vec)
5. ``G_j = G_parent(j) [R_j | J_j - J_parent(j)]``, ``G_0 = [R_0 | J_0]``;  ``A_j = G_j - [0 | G_j^R J_j]``
6. ``vertex = sum_j w_vj A_j [v_posed; 1]``                              (skinning)
7. ``trans`` is added to vertices and posed joints at the very end.

The world rotation of joint ``j`` is ``Rg_j = G_j^R`` and its world origin (posed joint, before ``trans``) is
``o_j = G_j^t``; ``A_j x = Rg_j x + (o_j - Rg_j J_j)``.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from pedx_graph.body.rotation import exp_so3


def blend_shapes(betas: np.ndarray, shapedirs: np.ndarray) -> np.ndarray:
    """Shape offsets ``sum_b betas[..., b] shapedirs[:, :, b]``: betas (..., B), shapedirs (V, 3, B) -> (..., V, 3)."""
    betas = np.asarray(betas, dtype=np.float64)
    num_v = shapedirs.shape[0]
    flat = shapedirs.reshape(num_v * 3, -1)                     # (3V, B)
    out = betas @ flat.T                                        # (..., 3V)
    return out.reshape(betas.shape[:-1] + (num_v, 3))


def vertices2joints(j_regressor, vertices: np.ndarray) -> np.ndarray:
    """Joint locations ``J_regressor @ vertices``.

    j_regressor (J, V) dense or scipy-sparse, vertices (..., V, 3) -> (..., J, 3).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    lead = vertices.shape[:-2]
    num_v = vertices.shape[-2]
    if sp.issparse(j_regressor):
        flat = np.moveaxis(vertices.reshape((-1, num_v, 3)), 1, 0).reshape(num_v, -1)   # (V, n*3)
        joints = np.asarray(j_regressor @ flat)                                        # (J, n*3)
        joints = np.moveaxis(joints.reshape(joints.shape[0], -1, 3), 0, 1)
        return joints.reshape(lead + (j_regressor.shape[0], 3))
    return np.einsum("jv,...vc->...jc", np.asarray(j_regressor, dtype=np.float64), vertices)


def pose_features(rot_mats: np.ndarray) -> np.ndarray:
    """Pose-corrective features ``vec(R_j - I)`` for j >= 1, row-major: rot_mats (..., J, 3, 3) -> (..., 9 (J-1))."""
    feats = rot_mats[..., 1:, :, :] - np.eye(3)
    return feats.reshape(rot_mats.shape[:-3] + (-1,))


def pose_offsets(rot_mats: np.ndarray, posedirs: np.ndarray) -> np.ndarray:
    """Pose-corrective offsets ``posedirs . pose_features(R)``: posedirs (V, 3, P) -> (..., V, 3)."""
    feats = pose_features(rot_mats)
    num_v = posedirs.shape[0]
    out = feats @ posedirs.reshape(num_v * 3, -1).T
    return out.reshape(feats.shape[:-1] + (num_v, 3))


def depth_levels(parents: np.ndarray) -> list[np.ndarray]:
    """Joint indices grouped by depth in the tree (root first); each level depends only on earlier ones."""
    parents = np.asarray(parents)
    depth = np.zeros(len(parents), dtype=np.int64)
    for j in range(1, len(parents)):
        depth[j] = depth[parents[j]] + 1
    return [np.flatnonzero(depth == d) for d in range(int(depth.max()) + 1)]


def descendant_mask(parents: np.ndarray) -> np.ndarray:
    """``D[j, k] = 1.0`` if joint ``k`` is ``j`` or a descendant of ``j`` (requires parents[k] < k): (J, J)."""
    parents = np.asarray(parents)
    num_j = len(parents)
    mask = np.eye(num_j)
    for k in range(num_j - 1, 0, -1):
        mask[parents[k]] += mask[k]
    return np.minimum(mask, 1.0)


@dataclass(frozen=True)
class Kinematics:
    """Forward kinematics of a batch of poses (all arrays float64, ``...`` = batch shape).

    ``world`` below is the model's output frame before ``trans`` is added.
    """

    rot_mats: np.ndarray
    """(..., J, 3, 3) local rotations ``R_j = Exp(theta_j)`` (joint 0: ``world_R_body``)."""
    rest_joints: np.ndarray
    """(..., J, 3) rest joint locations ``J(betas)``."""
    world_rot: np.ndarray
    """(..., J, 3, 3) world rotation of each joint's frame, ``Rg_j = Rg_parent R_j``."""
    world_origin: np.ndarray
    """(..., J, 3) posed joint locations ``o_j`` (before ``trans``)."""
    bone_trans: np.ndarray
    """(..., J, 3) translation of the skinning transform, ``o_j - Rg_j J_j``."""


@functools.lru_cache(maxsize=16)
def _tree(parents_bytes: bytes) -> tuple[list[tuple[int, int]], np.ndarray, np.ndarray, np.ndarray]:
    """Cached (child/parent pairs, ancestor mask (J, J), parent index with root -> 0, non-root indices)."""
    par = np.frombuffer(parents_bytes, dtype=np.int64)
    ancestors = descendant_mask(par).T.copy()           # ancestors[k, i] = 1 if i is k or above it
    parent_or_root = np.where(par < 0, 0, par)
    pairs = [(int(j), int(par[j])) for j in range(1, len(par))]
    return pairs, ancestors, parent_or_root, np.flatnonzero(par >= 0)


def batch_rigid_transform(rot_mats: np.ndarray, rest_joints: np.ndarray, parents: np.ndarray) -> Kinematics:
    """Chain local rotations along the kinematic tree (smplx ``batch_rigid_transform``).

    rot_mats (..., J, 3, 3), rest_joints (..., J, 3), parents (J,) with parents[0] = -1 and parents[j] < j.
    World rotations are chained joint by joint (``Rg_j = Rg_parent R_j``, views and in-place products); the
    posed origins are then one sum over ancestors, ``o_k = sum_{i in chain(k)} Rg_parent(i) (J_i - J_parent(i))``
    (root term: ``J_0``).
    """
    rot_mats = np.asarray(rot_mats, dtype=np.float64)
    rest_joints = np.asarray(rest_joints, dtype=np.float64)
    pairs, ancestors, parent_or_root, non_root = _tree(np.asarray(parents, dtype=np.int64).tobytes())
    lead = np.broadcast_shapes(rot_mats.shape[:-3], rest_joints.shape[:-2])
    num_j = rot_mats.shape[-3]
    if rot_mats.shape[:-3] != lead:
        rot_mats = np.broadcast_to(rot_mats, lead + rot_mats.shape[-3:])
    if rest_joints.shape[:-2] != lead:
        rest_joints = np.broadcast_to(rest_joints, lead + rest_joints.shape[-2:])
    flat_rot = rot_mats.reshape((-1, num_j, 3, 3))
    flat_joints = rest_joints.reshape((-1, num_j, 3))
    world_rot = flat_rot.copy()
    for j, par in pairs:
        np.matmul(world_rot[:, par], flat_rot[:, j], out=world_rot[:, j])
    bones = flat_joints.copy()                                            # J_i - J_parent(i); root: J_0
    bones[:, non_root] -= flat_joints[:, parent_or_root[non_root]]
    rotated = bones.copy()
    rotated[:, non_root] = (world_rot[:, parent_or_root[non_root]] @ bones[:, non_root, :, None])[..., 0]
    world_origin = ancestors @ rotated
    bone_trans = world_origin - (world_rot @ flat_joints[..., None])[..., 0]
    shape_r, shape_j = lead + (num_j, 3, 3), lead + (num_j, 3)
    return Kinematics(rot_mats=flat_rot.reshape(shape_r), rest_joints=flat_joints.reshape(shape_j),
                      world_rot=world_rot.reshape(shape_r), world_origin=world_origin.reshape(shape_j),
                      bone_trans=bone_trans.reshape(shape_j))


def skin(points: np.ndarray, weights: np.ndarray, world_rot: np.ndarray, bone_trans: np.ndarray) -> np.ndarray:
    """Blend ``sum_j w_vj (Rg_j x_v + bone_trans_j)``: points (..., V, 3) or (V, 3), weights (V, J), world_rot
    (..., J, 3, 3), bone_trans (..., J, 3) -> (..., V, 3).

    The 12 transform entries per joint are blended for every batch element in one matrix product, laid out
    coordinate-major (12, N, V) so that applying them to the points is a few contiguous elementwise passes
    (no per-vertex 3x3 matmul; ~2x faster than the vertex-major layout for a thousand vertices).
    """
    lead = world_rot.shape[:-3]
    num_j = world_rot.shape[-3]
    num_v = weights.shape[0]
    num_n = int(np.prod(lead, dtype=np.int64))
    mats = np.concatenate([world_rot, bone_trans[..., None]], axis=-1).reshape(num_n, num_j, 12)
    planes = (np.ascontiguousarray(mats.transpose(2, 0, 1)).reshape(12 * num_n, num_j)
              @ np.asarray(weights, dtype=np.float64).T).reshape(3, 4, num_n, num_v)
    coords = np.moveaxis(np.broadcast_to(points, lead + (num_v, 3)).reshape(num_n, num_v, 3), -1, 0)
    out = planes[:, 3] + planes[:, 0] * coords[0] + planes[:, 1] * coords[1] + planes[:, 2] * coords[2]
    return np.moveaxis(out, 0, -1).reshape(lead + (num_v, 3))


def skin_frames_last(rest_points: np.ndarray, weights, world_rot: np.ndarray, bone_trans: np.ndarray) -> np.ndarray:
    """Same as :func:`skin` for N frames stored frame-last (fast path for whole meshes).

    rest_points (V, 3, N), weights (V, J) dense or scipy-sparse (sparse is faster: SMPL has <= 4 non-zeros
    per row), world_rot (N, J, 3, 3), bone_trans (N, J, 3) -> (V, 3, N).  The blended transforms are one
    (V, J) x (J, 12 N) product; the frame-last layout keeps every later operation contiguous.
    """
    num_n, num_j = world_rot.shape[:2]
    num_v = rest_points.shape[0]
    mats = np.concatenate([world_rot, bone_trans[..., None]], axis=-1)           # (N, J, 3, 4)
    mats = np.ascontiguousarray(mats.transpose(1, 2, 3, 0)).reshape(num_j, 12 * num_n)
    blended = np.asarray(weights @ mats).reshape(num_v, 3, 4, num_n)
    return np.einsum("vijn,vjn->vin", blended[:, :, :3], rest_points) + blended[:, :, 3]


def lbs(betas: np.ndarray, full_pose: np.ndarray, v_template: np.ndarray, shapedirs: np.ndarray,
        posedirs: np.ndarray | None, j_regressor, parents: np.ndarray, weights: np.ndarray,
        trans: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and posed joints of an SMPL-format model (steps 1-7 above).

    betas (..., B), full_pose (..., 3 J) axis-angle, v_template (V, 3), shapedirs (V, 3, B), posedirs (V, 3, P)
    or None, j_regressor (J, V) dense or sparse, parents (J,), weights (V, J), trans (..., 3) or None.
    Returns vertices (..., V, 3) and joints (..., J, 3), in metres.
    """
    betas = np.asarray(betas, dtype=np.float64)
    full_pose = np.asarray(full_pose, dtype=np.float64)
    num_j = len(parents)
    lead = np.broadcast_shapes(betas.shape[:-1], full_pose.shape[:-1])
    v_shaped = v_template + blend_shapes(betas, shapedirs)
    rest_joints = vertices2joints(j_regressor, v_shaped)
    rot_mats = exp_so3(full_pose.reshape(full_pose.shape[:-1] + (num_j, 3)))
    v_posed = v_shaped if posedirs is None else v_shaped + pose_offsets(rot_mats, posedirs)
    kin = batch_rigid_transform(rot_mats, rest_joints, parents)
    v_posed = np.broadcast_to(v_posed, lead + v_posed.shape[-2:])
    vertices = skin(v_posed, weights, kin.world_rot, kin.bone_trans)
    joints = kin.world_origin
    if trans is not None:
        trans = np.asarray(trans, dtype=np.float64)
        vertices = vertices + trans[..., None, :]
        joints = joints + trans[..., None, :]
    return vertices, joints
