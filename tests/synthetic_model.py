"""A synthetic SMPL-format body model for tests and benchmarks: random, body-like, never a usable human
model (no licensed model is ever needed to run the tests)."""
from __future__ import annotations

import json

import numpy as np
import scipy.sparse as sp

from pedx_graph.body import BodyModel
from pedx_graph.body.io import NUM_POSE_FEATURES, ROOT_PARENT_UINT32, validate_model_arrays
from pedx_graph.keypoints import PEDX_KEYPOINTS, SMPL_PARENTS
from pedx_graph.utils import make_rng

#: Rough SMPL-like T-pose joint locations (metres, Y up, +Z forward, left = +X) for synthetic models.
SYNTHETIC_REST_JOINTS = np.array([
    [0.0, 0.0, 0.0], [0.06, -0.09, 0.0], [-0.06, -0.09, 0.0], [0.0, 0.11, -0.02],
    [0.10, -0.47, 0.0], [-0.10, -0.47, 0.0], [0.0, 0.24, 0.0], [0.09, -0.87, -0.04],
    [-0.09, -0.87, -0.04], [0.0, 0.29, 0.02], [0.11, -0.93, 0.08], [-0.11, -0.93, 0.08],
    [0.0, 0.50, -0.02], [0.07, 0.41, -0.01], [-0.07, 0.41, -0.01], [0.0, 0.60, 0.03],
    [0.17, 0.44, -0.02], [-0.17, 0.44, -0.02], [0.43, 0.43, -0.04], [-0.43, 0.43, -0.04],
    [0.68, 0.43, -0.03], [-0.68, 0.43, -0.03], [0.77, 0.43, -0.04], [-0.77, 0.43, -0.04],
])


def synthetic_model_arrays(num_vertices: int = 300, seed: int = 0, num_betas: int = 10,
                           with_posedirs: bool = True, with_keypoint_keys: bool = True) -> dict:
    """A random SMPL-format key -> array dict with a body-like layout, for tests and benchmarks.

    Vertices are scattered around the bones of an SMPL-like T-pose skeleton (and a head sphere); each vertex
    is skinned to its 4 nearest joints; ``shapedirs`` scale the body (component 0 = height) plus random
    smooth offsets; ``posedirs`` are small random values; ``J_regressor`` is a sparse convex combination of
    8 vertices near each joint (scipy CSC, as in the SMPL pickles); ``kintree_table`` is uint32 with the
    root parent 4294967295; faces are random valid triangles.  Not a usable human model.
    """
    rng = make_rng(seed)
    parents = np.array(SMPL_PARENTS)
    joints = SYNTHETIC_REST_JOINTS
    # Vertices along bones (parent -> child), radius ~5 cm, plus a head sphere of radius 10 cm.
    num_head = max(num_vertices // 10, 8)
    num_body = num_vertices - num_head
    bone = rng.integers(1, len(parents), size=num_body)
    frac = rng.uniform(0.0, 1.0, size=num_body)[:, None]
    centre = joints[parents[bone]] * (1 - frac) + joints[bone] * frac
    body = centre + rng.normal(scale=0.05, size=(num_body, 3))
    head_dir = rng.normal(size=(num_head, 3))
    head = joints[15] + 0.1 * head_dir / np.linalg.norm(head_dir, axis=1, keepdims=True)
    v_template = np.concatenate([body, head])
    # Skinning: 4 nearest joints, weights ~ exp(-d^2 / (2 * 0.08^2)), normalised.
    d2 = ((v_template[:, None, :] - joints[None]) ** 2).sum(-1)
    nearest = np.argsort(d2, axis=1)[:, :4]
    weights = np.zeros((num_vertices, len(parents)))
    w = np.exp(-np.take_along_axis(d2, nearest, axis=1) / (2 * 0.08 ** 2)) + 1e-3
    np.put_along_axis(weights, nearest, w / w.sum(axis=1, keepdims=True), axis=1)
    # Shape directions: height scaling, width scaling, then smooth random fields.
    shapedirs = np.zeros((num_vertices, 3, num_betas))
    shapedirs[:, 1, 0] = 0.05 * v_template[:, 1]
    if num_betas > 1:
        shapedirs[:, 0, 1] = 0.04 * v_template[:, 0]
        shapedirs[:, 2, 1] = 0.04 * v_template[:, 2]
    for b in range(2, num_betas):
        freq = rng.normal(scale=3.0, size=(3, 3))
        shapedirs[:, :, b] = 0.005 * np.sin(v_template @ freq + rng.uniform(0, 2 * np.pi, size=3))
    posedirs = (rng.normal(scale=2e-3, size=(num_vertices, 3, NUM_POSE_FEATURES)) if with_posedirs
                else np.zeros((num_vertices, 3, NUM_POSE_FEATURES)))
    # Sparse regressor: 8 nearest vertices of each joint, positive weights summing to one.
    rows, cols, vals = [], [], []
    for j in range(len(parents)):
        near = np.argsort(d2[:, j])[:8]
        wj = rng.uniform(0.5, 1.5, size=8)
        rows += [j] * 8
        cols += near.tolist()
        vals += (wj / wj.sum()).tolist()
    j_regressor = sp.csc_matrix((vals, (rows, cols)), shape=(len(parents), num_vertices))
    kintree = np.zeros((2, len(parents)), dtype=np.uint32)
    kintree[0] = np.where(parents < 0, ROOT_PARENT_UINT32, parents).astype(np.uint32)
    kintree[1] = np.arange(len(parents), dtype=np.uint32)
    first = rng.integers(0, num_vertices, size=2 * num_vertices)
    steps = rng.integers(1, max(num_vertices // 2, 2), size=(2 * num_vertices, 2))
    faces = np.stack([first, first + steps[:, 0], first + steps[:, 0] + steps[:, 1]], axis=1) % num_vertices
    out = {
        "v_template": v_template, "shapedirs": shapedirs, "posedirs": posedirs, "J_regressor": j_regressor,
        "weights": weights, "kintree_table": kintree, "f": faces.astype(np.uint32),
    }
    if with_keypoint_keys:
        vertex_ids = np.full(len(PEDX_KEYPOINTS), -1, dtype=np.int64)
        joint_ids = np.full(len(PEDX_KEYPOINTS), -1, dtype=np.int64)
        head_ids = np.arange(num_body, num_vertices)
        face_targets = {"nose": [0.0, 0.58, 0.13], "leye": [0.03, 0.63, 0.11], "reye": [-0.03, 0.63, 0.11],
                        "mouth": [0.0, 0.54, 0.11]}
        joint_of = {"head": 15, "neck": 12, "lsho": 16, "rsho": 17, "lelb": 18, "relb": 19, "lwri": 20,
                    "rwri": 21, "lhip": 1, "rhip": 2, "lknee": 4, "rknee": 5, "lankl": 7, "rankl": 8}
        for i, name in enumerate(PEDX_KEYPOINTS):
            if name in face_targets:
                dist = np.linalg.norm(v_template[head_ids] - np.array(face_targets[name]), axis=1)
                vertex_ids[i] = head_ids[np.argmin(dist)]
            else:
                joint_ids[i] = joint_of[name]
        out["pedx_keypoint_names"] = np.array(PEDX_KEYPOINTS)
        out["pedx_keypoint_vertex_ids"] = vertex_ids
        out["pedx_keypoint_joint_ids"] = joint_ids
        out["provenance"] = np.array(json.dumps({"builder": "tests/synthetic_model.synthetic_model_arrays",
                                                 "seed": int(seed), "num_vertices": int(num_vertices)}))
    return out


def synthetic_body_model(num_vertices: int = 300, seed: int = 0) -> BodyModel:
    """A real :class:`pedx_graph.body.BodyModel` on the synthetic SMPL-format arrays."""
    return BodyModel.from_data(validate_model_arrays(synthetic_model_arrays(num_vertices=num_vertices, seed=seed)))
