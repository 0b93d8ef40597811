"""A small stand-in body model for the simulator tests (capsule limbs on an SMPL-like skeleton).

Closed-ish mesh (one cylinder per bone, a head sphere), rigidly skinned to the bone's parent joint, joints
regressed exactly from 24 extra vertices, height as shape component 0.  ~1.5k vertices: fast to ray cast.
Used when the package's default body model file is not installed.
"""
from __future__ import annotations

import numpy as np
import trimesh

from synthetic_model import SYNTHETIC_REST_JOINTS
from pedx_graph.keypoints import PEDX_KEYPOINTS, SMPL_PARENTS

_JOINTS = SYNTHETIC_REST_JOINTS
_RADIUS = {1: 0.09, 2: 0.09, 3: 0.14, 4: 0.075, 5: 0.075, 6: 0.15, 7: 0.055, 8: 0.055, 9: 0.15,
           10: 0.045, 11: 0.045, 12: 0.06, 13: 0.06, 14: 0.06, 15: 0.05, 16: 0.06, 17: 0.06,
           18: 0.05, 19: 0.05, 20: 0.04, 21: 0.04, 22: 0.03, 23: 0.03}


def standin_model_arrays() -> dict:
    parents = np.array(SMPL_PARENTS)
    verts, faces, weights = [], [], []
    offset = 0

    def add(v, f, joint):
        nonlocal offset
        verts.append(v)
        faces.append(f + offset)
        w = np.zeros((len(v), 24))
        w[:, joint] = 1.0
        weights.append(w)
        offset += len(v)

    for j in range(1, 24):
        p = parents[j]
        seg = np.stack([_JOINTS[p], _JOINTS[j]])
        if np.linalg.norm(seg[1] - seg[0]) < 1e-3:
            continue
        cyl = trimesh.creation.capsule(radius=_RADIUS[j], height=float(np.linalg.norm(seg[1] - seg[0])),
                                       count=[8, 8])
        # capsule along +z centred at origin -> align with the bone
        direction = (seg[1] - seg[0]) / np.linalg.norm(seg[1] - seg[0])
        rot = trimesh.geometry.align_vectors([0, 0, 1], direction)
        cyl.apply_transform(rot)
        cyl.apply_translation(seg.mean(axis=0))
        add(np.asarray(cyl.vertices), np.asarray(cyl.faces), p)
    head = trimesh.creation.icosphere(subdivisions=2, radius=0.11)
    head.apply_translation(_JOINTS[15] + [0.0, 0.08, 0.0])
    head_start = offset
    add(np.asarray(head.vertices), np.asarray(head.faces), 15)
    joint_start = offset
    add(_JOINTS.copy(), np.zeros((0, 3), dtype=np.int64), 0)
    weights[-1][:] = np.eye(24)
    v = np.concatenate(verts)
    w = np.concatenate(weights)
    f = np.concatenate(faces).astype(np.int64)
    shapedirs = np.zeros((len(v), 3, 10))
    shapedirs[:, :, 0] = 0.05 * v            # beta_0: overall scale about the pelvis
    shapedirs[:, 0, 1] = 0.04 * v[:, 0]       # beta_1: width
    jreg = np.zeros((24, len(v)))
    jreg[np.arange(24), joint_start + np.arange(24)] = 1.0
    kintree = np.zeros((2, 24), dtype=np.uint32)
    kintree[0] = np.where(parents < 0, 4294967295, parents).astype(np.uint32)
    kintree[1] = np.arange(24)
    vertex_ids = np.full(18, -1, dtype=np.int64)
    joint_ids = np.full(18, -1, dtype=np.int64)
    joint_of = {"head": 15, "neck": 12, "lsho": 16, "rsho": 17, "lelb": 18, "relb": 19, "lwri": 20,
                "rwri": 21, "lhip": 1, "rhip": 2, "lknee": 4, "rknee": 5, "lankl": 7, "rankl": 8}
    targets = {"nose": [0.0, 0.68, 0.14], "leye": [0.035, 0.72, 0.12], "reye": [-0.035, 0.72, 0.12],
               "mouth": [0.0, 0.63, 0.12]}
    head_ids = np.arange(head_start, joint_start)
    for i, name in enumerate(PEDX_KEYPOINTS):
        if name in targets:
            vertex_ids[i] = head_ids[np.argmin(np.linalg.norm(v[head_ids] - targets[name], axis=1))]
        else:
            joint_ids[i] = joint_of[name]
    return {"v_template": v, "shapedirs": shapedirs, "J_regressor": jreg, "weights": w, "kintree_table": kintree,
            "f": f, "pedx_keypoint_names": np.array(PEDX_KEYPOINTS), "pedx_keypoint_vertex_ids": vertex_ids,
            "pedx_keypoint_joint_ids": joint_ids}


def standin_body_model():
    from pedx_graph.body import BodyModel, validate_model_arrays

    return BodyModel.from_data(validate_model_arrays(standin_model_arrays(), source="<stand-in>"))


def test_standin_model_stands_upright():
    m = standin_body_model()
    out = m.forward(np.zeros(72), np.zeros(10))
    height = out.vertices[:, 1].max() - out.vertices[:, 1].min()
    assert 1.5 < height < 1.9
    assert out.keypoints.shape == (18, 3)
