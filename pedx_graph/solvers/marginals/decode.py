"""Match decoding: the chamfer points' matched vertices read back from a GTSAM-linearised chamfer factor.

For a graph linearised by GTSAM (no term cache at hand) the point-to-plane rows of
:mod:`pedx_graph.solvers.marginals.plane` need each point's matched vertex.  It is decoded from the factor's
whitened Jacobian itself, so no factor internals are needed: per point (3 rows ``A_i = M_i J_v``) ``M_i``
is the translation block (``d v / d trans = I``), ``J_v = M_i^-1 A_i``, and the root block of ``J_v`` is
``-R [y]_x`` with ``y`` the matched vertex relative to the pelvis (the root's centre of rotation) in the
body frame, so the vertex is at ``R y + pelvis``.  A factor whose rows do not decode to a mesh vertex
(within ``MarginalsConfig.vertex_match_tol_m``) keeps its point-to-point information.
"""
from __future__ import annotations

import logging

import gtsam
import numpy as np
from scipy.spatial import cKDTree

from pedx_graph.solvers.marginals.chain import POSE_SLICE, ROOT_SLICE, TRANS_SLICE
from pedx_graph.solvers.marginals.normals import face_incidence, vertex_normals
from pedx_graph.solvers.marginals.plane import plane_rows

log = logging.getLogger(__name__)


def _key_layout(keys) -> tuple[dict[int, tuple[int, slice]], int]:
    """Map every frame key to (frame index, slice in the 75-d frame block); and the shape key."""
    layout = {}
    for i, k in enumerate(keys):
        layout[int(k.root)] = (i, ROOT_SLICE)
        layout[int(k.trans)] = (i, TRANS_SLICE)
        layout[int(k.body_pose)] = (i, POSE_SLICE)
    return layout, int(keys[0].betas)


def point_to_plane_rows(a_mat: np.ndarray, root_cols: slice, trans_cols: slice, world_R_body: np.ndarray,
                        centre: np.ndarray, vertices: np.ndarray, normals: np.ndarray,
                        tol_m: float = 1e-6, tree=None) -> np.ndarray | None:
    """Point-to-plane rows (M, n) from a chamfer factor's whitened point-to-point Jacobian ``a_mat`` (3M, n):
    each point's matched vertex decoded (see the module docstring; ``centre`` the pelvis), its normal looked
    up among ``vertices`` (posed, world) with ``normals``, then :func:`~pedx_graph.solvers.marginals.plane.plane_rows`.
    ``None`` when a point does not decode to a mesh vertex within ``tol_m`` (not a chamfer factor of this
    layout)."""
    a_mat = np.asarray(a_mat, float)
    if a_mat.shape[0] % 3:
        return None
    blocks = a_mat.reshape(a_mat.shape[0] // 3, 3, -1)
    weight = blocks[:, :, trans_cols]
    try:
        root_v = np.linalg.solve(weight, blocks[:, :, root_cols])                  # (M, 3, 3) of J_v
    except np.linalg.LinAlgError:
        return None
    skew = -np.einsum("ji,mjk->mik", world_R_body, root_v)                          # [y]_x
    y = np.stack([skew[:, 2, 1], skew[:, 0, 2], skew[:, 1, 0]], axis=1)
    dist, idx = (tree or cKDTree(vertices)).query(y @ world_R_body.T + centre)
    if not np.all(np.isfinite(dist)) or np.max(dist) > tol_m:
        return None
    return plane_rows(blocks, weight, normals[idx])


def chamfer_plane_rows(linear: gtsam.GaussianFactorGraph, values: gtsam.Values, keys, factor_kinds,
                       model, tol_m: float = 1e-6) -> dict:
    """Factor index -> point-to-plane rows for every LiDAR chamfer factor of ``linear`` (kind
    ``lidar_chamfer`` in ``factor_kinds``) that decodes (:func:`point_to_plane_rows`)."""
    layout, shape_key = _key_layout(keys)
    chamfer = [j for j, kind in enumerate(factor_kinds) if kind == "lidar_chamfer" and j < linear.size()]
    if not chamfer:
        return {}
    betas = np.asarray(values.atVector(int(keys[0].betas)), float)
    pelvis_rest = np.asarray(model.rest_joints(betas))[0]
    faces = np.asarray(model.faces, dtype=np.int64)
    out, meshes, incidence = {}, {}, None
    for j in chamfer:
        factor = linear.at(j)
        if factor is None:
            continue
        fkeys = [int(k) for k in factor.keys()]
        frames = {layout[k][0] for k in fkeys if k != shape_key}
        if len(frames) != 1:
            continue
        i = frames.pop()
        cols, col = {}, 0
        for k in fkeys:
            dim = len(betas) if k == shape_key else layout[k][1].stop - layout[k][1].start
            cols[k] = slice(col, col + dim)
            col += dim
        k = keys[i]
        if int(k.root) not in cols or int(k.trans) not in cols:
            continue
        rot = values.atRot3(k.root).matrix()
        trans = np.asarray(values.atVector(k.trans), float)
        if i not in meshes:
            pose = np.concatenate([gtsam.Rot3.Logmap(values.atRot3(k.root)), values.atVector(k.body_pose)])
            verts = np.asarray(model.forward(pose, betas, trans).vertices, float)
            if incidence is None:
                incidence = face_incidence(faces, len(verts))
            meshes[i] = (verts, vertex_normals(verts, faces, incidence), cKDTree(verts))
        verts, normals, tree = meshes[i]
        rows = point_to_plane_rows(factor.jacobian()[0], cols[int(k.root)], cols[int(k.trans)], rot,
                                   pelvis_rest + trans, verts, normals, tol_m, tree)
        if rows is None:
            log.info("marginals: chamfer factor %d does not decode to mesh vertices; kept point-to-point", j)
            continue
        out[j] = rows
    return out
