"""Analytic Jacobians of posed vertices and joints of an SMPL-format model (no finite differences).

Notation (per frame; see :mod:`pedx_graph.body.lbs`): local rotations ``R_j = Exp(theta_j)``, world joint
rotations ``Rg_j``, posed joint origins ``o_j`` (before ``trans``), skinning transforms ``A_k x = Rg_k x + t_k``
with ``t_k = o_k - Rg_k J_k``, descendant mask ``D[j, k] = 1`` if ``k`` is ``j`` or below it.

Rotation of joint ``j``.  A right perturbation ``R_j <- R_j Exp(w)`` rotates every bone below ``j`` (and ``j``)
about ``o_j`` by ``phi = Rg_j w`` in the world frame, so a vertex ``p = sum_k w_vk A_k x_v`` moves by

    dp = phi x a_j(v),     a_j(v) = sum_k D[j,k] w_vk A_k x_v - W_j(v) o_j,   W_j(v) = sum_k D[j,k] w_vk,

i.e. ``dp/dw = -hat(a_j) Rg_j``.  For the root this is the right-perturbation Jacobian ``d_root``
(``world_R_body <- world_R_body Exp(delta)``; with unit weight sums ``a_0 = p - o_0``); it is built from the
rotation matrix and has no singularity at any heading.  For body joints (additive axis-angle) ``w = J_r(theta_j)
d theta_j`` (right Jacobian), so ``dp/dtheta_j = -hat(a_j) Rg_j J_r(theta_j)``, plus the pose correctives:
``x_v`` contains ``posedirs_v . vec(R_j - I)``, whose derivative is skinned by ``M_v = sum_k w_vk Rg_k``:
``M_v posedirs_v[:, :, j] . dR_j/dtheta_j`` with ``dR_j/dtheta_j[m] = R_j hat(J_r[:, m])``.

A posed joint ``o_i`` is the same formula with one unit weight on bone ``i`` and ``A_i J_i = o_i``:
``a_j = D[j, i] (o_i - o_j)``; joints do not depend on the pose correctives.

Shape.  ``J(beta) = J_template + J_shapedirs beta``; ``t_k = sum_{i in chain(k)} (Rg_parent(i) - Rg_i) J_i``
(``Rg_parent(0) = I``), so ``dt_k/dbeta = sum_{i in chain(k)} (Rg_parent(i) - Rg_i) J_shapedirs_i``.  Then
``dp/dbeta = M_v shapedirs_v + sum_k w_vk dt_k/dbeta`` and ``do_i/dbeta = dt_i/dbeta + Rg_i J_shapedirs_i``.

All arrays are float64 with batch shape ``(N,)`` (callers flatten their leading dims).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pedx_graph.body.lbs import Kinematics
from pedx_graph.body.rotation import hat


@dataclass(frozen=True)
class PointJacobians:
    """World positions of N points and their derivatives (``...`` = batch shape of the inputs).

    Follows the convention of ``docs/architecture.md`` ("Body model Jacobian convention").
    """

    points: np.ndarray
    """(..., N, 3) world positions, metres (``trans`` included)."""
    d_root: np.ndarray
    """(..., N, 3, 3) w.r.t. a right perturbation of the root rotation, ``world_R_body <- world_R_body Exp(delta)``."""
    d_body_pose: np.ndarray
    """(..., N, 3, 69) w.r.t. the 69-d body pose (axis-angle of joints 1..23), additively."""
    d_trans: np.ndarray
    """(..., N, 3, 3) w.r.t. ``trans`` (the identity for vertices, joints and affine keypoints)."""
    d_betas: np.ndarray
    """(..., N, 3, B) w.r.t. the shape coefficients."""


def rotation_bases(kin: Kinematics, jr_body: np.ndarray) -> np.ndarray:
    """Per-joint maps from parameter increments to world rotation increments ``phi``: (N, J, 3, 3).

    ``[Rg_0, Rg_1 J_r(theta_1), ..., Rg_{J-1} J_r(theta_{J-1})]``; jr_body (N, J-1, 3, 3).
    """
    bases = np.empty_like(kin.world_rot)
    bases[:, 0] = kin.world_rot[:, 0]
    bases[:, 1:] = kin.world_rot[:, 1:] @ jr_body
    return bases


def shape_chain_jacobian(kin: Kinematics, joint_shapedirs: np.ndarray, parents: np.ndarray,
                         desc: np.ndarray) -> np.ndarray:
    """``dt_k/dbeta`` of the skinning translations: (N, J, 3, B).

    joint_shapedirs (J, 3, B) = ``J_regressor . shapedirs``; desc (J, J) descendant mask.
    """
    num_n, num_j = kin.world_rot.shape[:2]
    parent_rot = np.empty_like(kin.world_rot)
    parent_rot[:, 0] = np.eye(3)
    parent_rot[:, 1:] = kin.world_rot[:, parents[1:]]
    step = (parent_rot - kin.world_rot) @ joint_shapedirs            # (N, J, 3, B)
    num_b = joint_shapedirs.shape[-1]
    chained = desc.T @ step.reshape(num_n, num_j, 3 * num_b)         # sum over ancestors i of k
    return chained.reshape(num_n, num_j, 3, num_b)


def _cross_columns(levers: np.ndarray, bases: np.ndarray) -> np.ndarray:
    """``-hat(a) @ B`` for a (..., 3) and B (..., 3, 3) (broadcast), i.e. ``B[:, m] x a`` per column m."""
    a0, a1, a2 = levers[..., 0, None], levers[..., 1, None], levers[..., 2, None]
    b0, b1, b2 = bases[..., 0, :], bases[..., 1, :], bases[..., 2, :]
    return np.stack([a2 * b1 - a1 * b2, a0 * b2 - a2 * b0, a1 * b0 - a0 * b1], axis=-2)


def _rotation_blocks(levers: np.ndarray, bases: np.ndarray) -> np.ndarray:
    """Blocks ``-hat(a_pj) B_j`` (N, J, P, 3, 3) from lever arms a (N, P, J, 3) and bases B (N, J, 3, 3).

    Computed as one small matrix product per joint: ``(B[:, m] x a)_c = sum_d hat(B[:, m])[c, d] a_d``, so with
    ``H[j, d, (c, m)] = hat(B_j[:, m])[c, d]`` the block of every point is ``a_j @ H_j``.
    """
    num_n, num_p, num_j = levers.shape[:3]
    hats = hat(np.swapaxes(bases, -1, -2))                           # (N, J, m, c, d)
    hmat = np.ascontiguousarray(hats.transpose(0, 1, 4, 3, 2)).reshape(num_n, num_j, 3, 9)
    blocks = np.swapaxes(levers, 1, 2) @ hmat                        # (N, J, P, (c, m))
    return blocks.reshape(num_n, num_j, num_p, 3, 3)


def _split_blocks(blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, J, P, 3, 3) blocks -> d_root (N, P, 3, 3), d_body (N, P, 3, 3 (J-1)) (column 3 (j-1) + m)."""
    num_n, num_j, num_p = blocks.shape[:3]
    d_body = blocks[:, 1:].transpose(0, 2, 3, 1, 4).reshape(num_n, num_p, 3, 3 * (num_j - 1))
    return blocks[:, 0], d_body


def vertex_jacobians(kin: Kinematics, bases: np.ndarray, rest_points: np.ndarray, weights: np.ndarray,
                     desc: np.ndarray, shapedirs_flat: np.ndarray, dt_dbeta: np.ndarray,
                     posedirs_flat: np.ndarray | None = None, drot_body: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Posed positions (before ``trans``) and Jacobians of P vertices.

    rest_points (N, P, 3) = shaped + pose-corrected rest positions ``x_v``; weights (P, J); shapedirs_flat
    (3P, B) and posedirs_flat (3P, 9 (J-1)) or None: the blend shapes of those vertices, rows ordered (vertex,
    coordinate); drot_body (N, J-1, 3, 3, 3) = ``dR_j/dtheta_j`` (needed with posedirs).  ``weights``,
    ``shapedirs_flat`` and ``posedirs_flat`` may also carry a leading N (a different vertex set per batch
    element: (N, P, J), (N, 3P, B), (N, 3P, 9 (J-1))).
    Returns points (N, P, 3), d_root (N, P, 3, 3), d_body (N, P, 3, 3 (J-1)), d_betas (N, P, 3, B).
    """
    world_rot, origin = kin.world_rot, kin.world_origin
    num_n, num_j = world_rot.shape[:2]
    num_p = rest_points.shape[1]
    weights_n = weights if weights.ndim == 3 else weights[None]                      # (N or 1, P, J)
    # Position of each vertex under each bone: y_vk = Rg_k x_v + t_k, (N, P, J, 3), as one product.
    rot_cols = world_rot.transpose(0, 3, 1, 2).reshape(num_n, 3, 3 * num_j)           # [n, b, (k, a)]
    under_bone = (rest_points @ rot_cols).reshape(num_n, num_p, num_j, 3) + kin.bone_trans[:, None]
    weighted = weights_n[..., None] * under_bone
    subtree_w = weights_n @ desc.T                                   # W_j(v), (N or 1, P, J)
    levers = desc @ weighted - subtree_w[..., None] * origin[:, None]
    # The root's subtree is every joint, so its lever is p - W_0 o_0: the points come for free.
    points = levers[:, :, 0] + subtree_w[..., 0, None] * origin[:, None, 0]
    blocks = _rotation_blocks(levers, bases)                         # (N, J, P, 3, 3)
    blended_rot = (weights_n @ world_rot.reshape(num_n, num_j, 9)).reshape(num_n, num_p, 3, 3)   # M_v
    if posedirs_flat is not None:
        per_joint = posedirs_flat.reshape(-1, 3 * num_p, num_j - 1, 9).transpose(0, 2, 1, 3)  # (., J-1, 3P, 9)
        dq = per_joint @ drot_body.reshape(num_n, num_j - 1, 9, 3)                          # (N, J-1, 3P, 3)
        blocks[:, 1:] += blended_rot[:, None] @ dq.reshape(num_n, num_j - 1, num_p, 3, 3)
    d_root, d_body = _split_blocks(blocks)
    num_b = shapedirs_flat.shape[-1]
    d_betas = (blended_rot @ shapedirs_flat.reshape(-1, num_p, 3, num_b)
               + (weights_n @ dt_dbeta.reshape(num_n, num_j, 3 * num_b)).reshape(num_n, num_p, 3, num_b))
    return points, d_root, d_body, d_betas


def ancestor_pairs(desc: np.ndarray, joint_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (q, j) with joint ``j`` a strict ancestor of joint ``joint_ids[q]``."""
    num_j = desc.shape[0]
    return np.nonzero(desc.T[joint_ids] * (1.0 - np.eye(num_j)[joint_ids]))


def joint_jacobians(kin: Kinematics, bases: np.ndarray, joint_ids: np.ndarray, desc: np.ndarray,
                    joint_shapedirs: np.ndarray, dt_dbeta: np.ndarray,
                    pairs: tuple[np.ndarray, np.ndarray] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Posed positions (before ``trans``) and Jacobians of the joints ``joint_ids`` (Q,).

    ``pairs``: :func:`ancestor_pairs` of ``joint_ids`` (computed when not given).

    Returns points (N, Q, 3), d_root (N, Q, 3, 3), d_body (N, Q, 3, 3 (J-1)), d_betas (N, Q, 3, B).
    """
    origin = kin.world_origin
    num_n, num_j = origin.shape[:2]
    points = origin[:, joint_ids]                                    # (N, Q, 3)
    # Only strict ancestors j of joint i have a non-zero lever o_i - o_j: compute those pairs only.
    q_idx, j_idx = ancestor_pairs(desc, joint_ids) if pairs is None else pairs
    levers = points[:, q_idx] - origin[:, j_idx]                     # (N, pairs, 3)
    blocks = _cross_columns(levers, bases[:, j_idx])                 # (N, pairs, 3, 3)
    num_q = len(joint_ids)
    at_root = j_idx == 0
    d_root = np.zeros((num_n, num_q, 3, 3))
    d_root[:, q_idx[at_root]] = blocks[:, at_root]
    d_body = np.zeros((num_n, num_q, 3, num_j - 1, 3))
    # advanced indices separated by a slice put the pair axis first: (pairs, N, 3, 3)
    d_body[:, q_idx[~at_root], :, j_idx[~at_root] - 1] = np.moveaxis(blocks[:, ~at_root], 1, 0)
    d_body = d_body.reshape(num_n, num_q, 3, 3 * (num_j - 1))
    d_betas = dt_dbeta[:, joint_ids] + kin.world_rot[:, joint_ids] @ joint_shapedirs[joint_ids][None]
    return points, d_root, d_body, d_betas
