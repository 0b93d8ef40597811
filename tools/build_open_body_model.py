"""Build pedx-graph's open default body model (``pedx_open_neutral.npz``) from the ``anny`` package.

This is a one-off export script. It needs ``torch`` and ``anny``, which are NOT dependencies of
pedx-graph: run it with the python of a separate virtual environment, e.g.::

    python3 -m venv <venv>
    <venv>/bin/pip install torch==2.13.0          # first: the CPU build, so pip does not pull a CUDA one
    <venv>/bin/pip install anny fast-simplification numpy scipy rtree   # rtree: trimesh closest-point queries
    ANNY_CACHE_DIR=<some scratch folder> <venv>/bin/python tools/build_open_body_model.py \
        --out pedx_graph/body/data/pedx_open_neutral.npz

The first run builds anny's model data (two topologies, ~1-2 min each) into ``ANNY_CACHE_DIR``.

What it does (all frames and units are stated; metres throughout):

1. Samples ``n_fit + n_test`` adult phenotypes with ``anny.shape_distribution.SimpleShapeDistribution``
   (heights calibrated to WHO data), its morphological age drawn uniformly in [age_min, age_max] years
   instead of anny's default [0, 90] so that no children are sampled; ``torch.manual_seed(seed)``.
2. Re-poses every sample from anny's A-pose to SMPL's T-pose with anny's ``world-orient`` pose
   parameterisation: every bone keeps its rest world orientation, except the upper arms and the
   forearm/hand chains, which are turned by the smallest rotation that points the shoulder->elbow and
   elbow->wrist directions along +-X (arms horizontal, elbows straight).
3. Converts anny's frame (Z up, facing -Y, subject's left at +X) to SMPL's body frame (Y up, facing +Z,
   left at +X): ``smpl_p = SMPL_R_ANNY @ anny_p`` with ``SMPL_R_ANNY = [[1,0,0],[0,0,1],[0,-1,0]]``,
   and subtracts each sample's pelvis (anny ``root`` bone head), so J_pelvis(beta) ~ 0 for every shape.
4. Decimates the mean T-pose mesh (anny topology ``anny-noeyes-notongue``, watertight, 13348 vertices,
   mirror-symmetric) to 6890 vertices: the body keeps anny's resolution, the head, fingers and toes
   (``DETAIL_GROUPS``, by LBS weight) are decimated with ``fast_simplification`` to fixed shares of the
   rest, on one half with the midline and seams kept, then mirrored (the result is mirror-symmetric).
   Every sample is carried over by barycentric projection of the decimated vertices onto the mean
   full-resolution mesh.
5. Merges anny's 104 bone skinning weights onto SMPL's 24 joints (``BONE_TO_JOINT``), projected the
   same way; rows renormalised to sum to one.
6. PCA over the fitting samples: ``v_template`` = mean, ``shapedirs[:, :, k] = sigma_k * u_k`` (the
   k-th principal direction times its standard deviation), so the samples' betas have unit variance.
7. ``J_regressor`` (24, V): per joint, non-negative least squares over candidate vertices near the joint
   (skinned by the joint, its parent or children), with a heavily weighted sum-to-one row, fitted so
   that ``J_regressor @ v(beta)`` reproduces anny's T-posed joint positions (``JOINT_FROM_BONES``) of the
   fitting samples (PCA-reconstructed vertices, i.e. what the model produces). Rows are then
   renormalised to sum to one exactly. Errors are reported on held-out test samples too.
8. PedX face keypoints as vertex ids: nose and eyes are the vertices nearest to anny's own COCO keypoint
   regressor (evaluated with the full ``anny`` topology that has eyeballs, averaged over the samples);
   the mouth is the vertex nearest to the lip centre (stomion), the mean of the inner lip contour's
   midline vertices (the border of anny's ``mouth_cavity`` texture segment, |x| < 6 mm), averaged over
   the samples. The other 14 keypoints are SMPL joints.

Writes the model with ``np.savez_compressed`` (float32 arrays, loadable as float64) plus a JSON
``provenance`` string, and prints a JSON summary of the checks.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import scipy.optimize
import scipy.spatial

REPO_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO_ROOT))
from pedx_graph.keypoints import PEDX_KEYPOINTS, SMPL_JOINTS, SMPL_PARENTS  # noqa: E402

#: Rotation from anny's frame (Z up, facing -Y, left at +X) to SMPL's (Y up, facing +Z, left at +X).
SMPL_R_ANNY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

ANNY_TOPOLOGY = "anny-noeyes-notongue"
"""Watertight anny topology used for the mesh (no eyeballs, no tongue)."""

LANDMARK_TOPOLOGY = "anny"
"""Full anny topology (with eyeballs) on which anny's COCO keypoint regressor is evaluated."""


def _bone_to_joint_table() -> dict[str, str]:
    """Anny bone label -> SMPL joint name (whose LBS weight the bone's weight is added to)."""
    table = {b: "pelvis" for b in ("root", "pelvis.L", "pelvis.R", "spine05", "spine04")}
    table.update({"spine03": "spine1", "spine02": "spine2", "spine01": "spine3"})
    table.update({b: "neck" for b in ("neck01", "neck02", "neck03")})
    table.update({b: "head" for b in ("head", "eye.L", "eye.R")})
    for side, smpl in (("L", "left"), ("R", "right")):
        table.update({f"upperleg01.{side}": f"{smpl}_hip", f"upperleg02.{side}": f"{smpl}_hip"})
        table.update({f"lowerleg01.{side}": f"{smpl}_knee", f"lowerleg02.{side}": f"{smpl}_knee"})
        table[f"foot.{side}"] = f"{smpl}_ankle"
        for toe in range(1, 6):
            for seg in range(1, 4):
                table[f"toe{toe}-{seg}.{side}"] = f"{smpl}_foot"
        table.update({f"clavicle.{side}": f"{smpl}_collar", f"shoulder01.{side}": f"{smpl}_collar"})
        table.update({f"upperarm01.{side}": f"{smpl}_shoulder", f"upperarm02.{side}": f"{smpl}_shoulder"})
        table.update({f"lowerarm01.{side}": f"{smpl}_elbow", f"lowerarm02.{side}": f"{smpl}_elbow"})
        table[f"wrist.{side}"] = f"{smpl}_wrist"
        for k in range(1, 5):
            table[f"metacarpal{k}.{side}"] = f"{smpl}_wrist"
        for finger in range(1, 6):
            for seg in range(1, 4):
                table[f"finger{finger}-{seg}.{side}"] = f"{smpl}_hand"
    return table


#: Anny bone label -> SMPL joint whose weight it joins.
BONE_TO_JOINT: dict[str, str] = _bone_to_joint_table()


def _joint_from_bones() -> dict[str, tuple[str, ...]]:
    """SMPL joint name -> anny bones whose (posed) heads are averaged to give the joint position."""
    table: dict[str, tuple[str, ...]] = {
        "pelvis": ("root",), "spine1": ("spine03",), "spine2": ("spine02",), "spine3": ("spine01",),
        "neck": ("neck01",), "head": ("head",),
    }
    for side, smpl in (("L", "left"), ("R", "right")):
        table[f"{smpl}_hip"] = (f"upperleg01.{side}",)
        table[f"{smpl}_knee"] = (f"lowerleg01.{side}",)
        table[f"{smpl}_ankle"] = (f"foot.{side}",)
        table[f"{smpl}_foot"] = tuple(f"toe{k}-1.{side}" for k in range(1, 6))
        table[f"{smpl}_collar"] = (f"clavicle.{side}",)
        table[f"{smpl}_shoulder"] = (f"upperarm01.{side}",)
        table[f"{smpl}_elbow"] = (f"lowerarm01.{side}",)
        table[f"{smpl}_wrist"] = (f"wrist.{side}",)
        table[f"{smpl}_hand"] = tuple(f"finger{k}-1.{side}" for k in range(2, 6))
    return table


#: SMPL joint name -> anny bone heads averaged for its position.
JOINT_FROM_BONES: dict[str, tuple[str, ...]] = _joint_from_bones()

#: Decimation groups: name -> (SMPL joints whose LBS weight defines the region, share of the vertex budget
#: left after the body keeps anny's full resolution). Anny's mesh spends most vertices on the head
#: (including the mouth cavity), the fingers and the toes; plain QEM decimation kept that imbalance.
DETAIL_GROUPS: dict[str, tuple[tuple[str, ...], float]] = {
    "head": (("head",), 0.55),
    "hands": (("left_hand", "right_hand"), 0.30),
    "feet": (("left_foot", "right_foot"), 0.15),
}

#: PedX keypoint -> SMPL joint index (the keypoints not listed are mesh vertices).
PEDX_JOINT_IDS: dict[str, int] = {
    "head": 15, "neck": 12, "lsho": 16, "rsho": 17, "lelb": 18, "relb": 19, "lwri": 20, "rwri": 21,
    "lhip": 1, "rhip": 2, "lknee": 4, "rknee": 5, "lankl": 7, "rankl": 8,
}


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=str(REPO_ROOT / "pedx_graph/body/data/pedx_open_neutral.npz"),
                   help="output .npz (SMPL-format keys + pedx keys + provenance)")
    p.add_argument("--seed", type=int, default=20250611, help="torch seed for the phenotype sampler")
    p.add_argument("--n-fit", type=int, default=500, help="samples for PCA and the joint regressor")
    p.add_argument("--n-test", type=int, default=100, help="held-out samples for the error report")
    p.add_argument("--age-min", type=float, default=18.0, help="youngest morphological age (years)")
    p.add_argument("--age-max", type=float, default=90.0, help="oldest morphological age (years)")
    p.add_argument("--n-vertices", type=int, default=6890, help="target vertex count of the mesh")
    p.add_argument("--n-betas", type=int, default=10, help="number of shape directions")
    p.add_argument("--batch", type=int, default=50, help="anny forward batch size")
    p.add_argument("--summary", default=None, help="optional path for the JSON check summary")
    return p.parse_args(argv)


# ----------------------------------------------------------------------------------------------
# anny side (torch)
# ----------------------------------------------------------------------------------------------

def _min_rotation(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(B, 3, 3) smallest rotations taking unit vectors ``src`` (B, 3) onto unit vectors ``dst`` (B, 3).

    Rodrigues: axis = src x dst / |src x dst|, angle = atan2(|src x dst|, src . dst).
    """
    axis = np.cross(src, dst)
    s = np.linalg.norm(axis, axis=1)
    c = np.einsum("bi,bi->b", src, dst)
    if np.any(s < 1e-9):
        raise ValueError("degenerate arm direction (already on the target axis or opposite)")
    k = axis / s[:, None]
    kx = np.zeros((len(src), 3, 3))
    kx[:, 0, 1], kx[:, 0, 2], kx[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    kx -= np.transpose(kx, (0, 2, 1))
    eye = np.eye(3)[None]
    return eye + s[:, None, None] * kx + (1.0 - c)[:, None, None] * (kx @ kx)


def tpose_deltas(bone_labels, bone_parents, rest_bone_poses: np.ndarray) -> np.ndarray:
    """World-orient deltas (B, nb, 4, 4) that put anny's arms horizontal with straight elbows.

    ``rest_bone_poses`` (B, nb, 4, 4): anny rest poses ``[R_c | h_c]`` in anny's frame. Every bone's
    delta is its rest world orientation ``R_c`` (root: its full rest pose), except: upper-arm bones get
    ``Q_up R_c`` and every bone from the forearm down gets ``Q_fore R_c``, with ``Q`` the smallest
    rotation taking the rest shoulder->elbow (resp. elbow->wrist) direction to +X (left) or -X (right).
    """
    labels = list(bone_labels)
    idx = {b: i for i, b in enumerate(labels)}
    children: dict[int, list[int]] = {i: [] for i in range(len(labels))}
    for i, p in enumerate(bone_parents):
        if i > 0:
            children[int(p)].append(i)

    def subtree(i):
        out, stack = [], [i]
        while stack:
            j = stack.pop()
            out.append(j)
            stack.extend(children[j])
        return out

    deltas = rest_bone_poses.copy()
    deltas[:, 1:, :3, 3] = 0.0
    heads = rest_bone_poses[:, :, :3, 3]
    rot = rest_bone_poses[:, :, :3, :3]
    for side, sign in (("L", 1.0), ("R", -1.0)):
        target = np.tile([sign, 0.0, 0.0], (len(heads), 1))
        shoulder, elbow, wrist = idx[f"upperarm01.{side}"], idx[f"lowerarm01.{side}"], idx[f"wrist.{side}"]
        up = heads[:, elbow] - heads[:, shoulder]
        fore = heads[:, wrist] - heads[:, elbow]
        q_up = _min_rotation(up / np.linalg.norm(up, axis=1, keepdims=True), target)
        q_fore = _min_rotation(fore / np.linalg.norm(fore, axis=1, keepdims=True), target)
        fore_bones = subtree(elbow)
        up_bones = [b for b in subtree(shoulder) if b not in fore_bones]
        for b in up_bones:
            deltas[:, b, :3, :3] = q_up @ rot[:, b]
        for b in fore_bones:
            deltas[:, b, :3, :3] = q_fore @ rot[:, b]
    return deltas


def run_anny(args) -> dict:
    """Sample phenotypes and evaluate anny; returns numpy arrays in anny's frame (metres)."""
    import torch
    import anny
    from anny.shape_distribution import SimpleShapeDistribution

    torch.manual_seed(args.seed)
    t0 = time.time()
    model = anny.Anny(topology=ANNY_TOPOLOGY, skinning_method="lbs").to(torch.float64)
    lm_model = anny.Anny(topology=LANDMARK_TOPOLOGY, skinning_method="lbs").to(torch.float64)
    print(f"[anny] models ready in {time.time() - t0:.1f} s", flush=True)
    age = torch.distributions.Uniform(torch.tensor(args.age_min, dtype=torch.float64),
                                      torch.tensor(args.age_max, dtype=torch.float64))
    sampler = SimpleShapeDistribution(model, morphological_age_distribution=age)
    n = args.n_fit + args.n_test
    morph_age, phen = sampler.sample(n)
    from anny.face_segmentation import get_face_segmentation_mask
    cavity = get_face_segmentation_mask(model, ["mouth_cavity"]).numpy()
    lips = mouth_contour_midline(model.faces.numpy(), cavity, model.template_vertices.numpy())
    coco = anny.KeypointsRegressor.coco(lm_model)
    coco_ids = [coco.labels.index(k) for k in ("nose", "left_eye", "right_eye")]

    posed_v, posed_heads, landmarks = [], [], []
    with torch.no_grad():
        for start in range(0, n, args.batch):
            sl = slice(start, min(n, start + args.batch))
            kw = {k: v[sl] for k, v in phen.items()}
            rest = model(phenotype_kwargs=kw)
            rest_poses = rest["rest_bone_poses"].numpy()
            deltas = tpose_deltas(model.bone_labels, model.bone_parents, rest_poses)
            out = model(pose_parameters=torch.from_numpy(deltas), phenotype_kwargs=kw,
                        pose_parameterization="world-orient")
            lm_out = lm_model(phenotype_kwargs=kw)
            posed_v.append(out["vertices"].numpy())
            posed_heads.append(out["bone_poses"][:, :, :3, 3].numpy())
            face = coco({"vertices": lm_out["rest_vertices"]})[:, coco_ids].numpy()
            mouth = out["vertices"][:, lips].numpy().mean(axis=1, keepdims=True)
            landmarks.append(np.concatenate([face, mouth], axis=1))
    print(f"[anny] {n} samples evaluated in {time.time() - t0:.1f} s", flush=True)

    dense_w = np.zeros((model.template_vertices.shape[0], len(model.bone_labels)))
    np.add.at(dense_w, (np.arange(dense_w.shape[0])[:, None], model.vertex_bone_indices.numpy()),
              model.vertex_bone_weights.numpy().astype(np.float64))
    return {
        "anny_version": anny.__version__, "torch_version": torch.__version__,
        "bone_labels": list(model.bone_labels), "bone_parents": [int(p) for p in model.bone_parents],
        "faces": model.faces.numpy().astype(np.int64),
        "bone_weights": dense_w,
        "posed_vertices": np.concatenate(posed_v), "posed_heads": np.concatenate(posed_heads),
        "face_landmarks": np.concatenate(landmarks),
        "morphological_age": morph_age.numpy(),
        "phenotypes": {k: v.numpy() for k, v in phen.items()},
    }


# ----------------------------------------------------------------------------------------------
# numpy side
# ----------------------------------------------------------------------------------------------

def to_smpl_frame(anny_p: np.ndarray) -> np.ndarray:
    """``smpl_p = SMPL_R_ANNY @ anny_p`` on the last axis (..., 3)."""
    return anny_p @ SMPL_R_ANNY.T


def face_groups(faces: np.ndarray, joint_weights: np.ndarray) -> np.ndarray:
    """(F,) decimation group of each face: 0 = body, k >= 1 = the k-th entry of ``DETAIL_GROUPS``.

    A face joins the group with the largest LBS weight summed over its three corners
    (``joint_weights`` (V, 24), SMPL joint order)."""
    score = np.zeros((len(joint_weights), len(DETAIL_GROUPS) + 1))
    for k, (joints, _) in enumerate(DETAIL_GROUPS.values(), start=1):
        score[:, k] = joint_weights[:, [SMPL_JOINTS.index(j) for j in joints]].sum(axis=1)
    score[:, 0] = 1.0 - score[:, 1:].sum(axis=1)
    return np.argmax(score[faces].sum(axis=1), axis=1)


def _decimate_patch(vertices: np.ndarray, faces: np.ndarray, n_target: int):
    """Decimate an open patch to ``n_target`` vertices keeping its border vertices fixed.

    Edge collapses keep the Euler characteristic chi = V - E + F; with b border vertices (= border edges)
    and 3F = 2E - b, a patch of V vertices has F = 2V - b - 2 chi triangles: the decimation target.
    Returns (vertices, faces) of the patch (unused vertices dropped).
    """
    import fast_simplification
    used = np.unique(faces)
    v, f = vertices[used], np.searchsorted(used, faces)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    n_border = len(np.unique(uniq[count == 1]))
    chi = len(v) - len(uniq) + len(f)
    if n_target >= len(v):
        return v, f
    for extra in (0, 1, -1, 2, -2):
        dec_v, dec_f = fast_simplification.simplify(v, f.astype(np.int32), preserve_border=True,
                                                    target_count=2 * n_target - n_border - 2 * chi + extra)
        kept = np.unique(dec_f)
        if len(kept) == n_target:
            break
    return dec_v[kept], np.searchsorted(kept, dec_f)


def decimate_symmetric(vertices: np.ndarray, faces: np.ndarray, groups: np.ndarray, n_vertices: int,
                       tol: float = 1e-6):
    """Mirror-symmetric, region-budgeted decimation of a closed, mirror-symmetric mesh (mirror plane x = 0).

    The left half (faces with a vertex at x > tol; no face may cross x = 0) is split into the face
    ``groups`` (0 = body, k = ``DETAIL_GROUPS`` entry k). The body keeps anny's resolution; each detail
    group is decimated with ``fast_simplification`` to its share of the remaining vertex budget, keeping
    its border (the midline and the seams between groups) fixed, so the patches stitch back exactly
    (shared vertices are bit-identical). The half is then mirrored (x -> -x, reversed winding) and joined
    along the midline. ``n_vertices`` counts the whole mesh: half = (n_vertices + midline) / 2.
    Returns (vertices (V, 3), faces (F, 3) int64); the left half's vertices come first.
    """
    x = vertices[:, 0]
    fx = x[faces]
    if np.any((fx > tol).any(axis=1) & (fx < -tol).any(axis=1)):
        raise ValueError("a face crosses the mirror plane; symmetric decimation needs a midline edge loop")
    left = (fx > tol).any(axis=1)
    half_faces, half_groups = faces[left], groups[left]
    snapped = vertices.copy()
    snapped[np.abs(x) <= tol, 0] = 0.0
    n_groups = len(DETAIL_GROUPS) + 1
    member = np.zeros((len(vertices), n_groups), dtype=bool)
    for g in range(n_groups):
        member[np.unique(half_faces[half_groups == g]), g] = True
    in_half = member.any(axis=1)
    n_mid = int((in_half & (np.abs(x) <= tol)).sum())
    shared = int((member.sum(axis=1) - 1).clip(0).sum())          # seam vertices counted twice or more
    target_half = (n_vertices + n_mid + 1) // 2
    n_body = int(member[:, 0].sum())
    spare = target_half + shared - n_body
    shares = np.array([share for _, share in DETAIL_GROUPS.values()], dtype=float)
    targets = np.floor(spare * shares / shares.sum()).astype(int)
    targets[0] += spare - targets.sum()
    if spare <= 0 or np.any(targets < member[:, 1:].sum(axis=0) // 20):
        raise ValueError(f"vertex budget {n_vertices} too small for the body at full resolution ({n_body})")
    parts = [_decimate_patch(snapped, half_faces[half_groups == 0], n_body)]
    parts += [_decimate_patch(snapped, half_faces[half_groups == g], int(targets[g - 1]))
              for g in range(1, n_groups)]
    all_v = np.vstack([p[0] for p in parts])
    offsets = np.cumsum([0] + [len(p[0]) for p in parts])
    all_f = np.vstack([p[1] + o for p, o in zip(parts, offsets[:-1])])
    half_v, inverse = np.unique(all_v, axis=0, return_inverse=True)
    half_f = inverse.reshape(-1)[all_f]
    mid = np.abs(half_v[:, 0]) <= tol
    if int(mid.sum()) != n_mid:
        raise RuntimeError(f"decimation moved midline vertices ({int(mid.sum())} of {n_mid} left)")
    mirror_id = np.arange(len(half_v))
    mirror_id[~mid] = len(half_v) + np.arange(int((~mid).sum()))
    out_v = np.vstack([half_v, half_v[~mid] * np.array([-1.0, 1.0, 1.0])])
    out_f = np.vstack([half_f, mirror_id[half_f][:, ::-1]])
    return out_v, out_f.astype(np.int64)


def barycentric_projection(src_vertices: np.ndarray, src_faces: np.ndarray, points: np.ndarray):
    """Closest point on the source mesh for each point: (face ids (P,), barycentric weights (P, 3), dist (P,))."""
    import trimesh
    mesh = trimesh.Trimesh(src_vertices, src_faces, process=False)
    closest, dist, tri = trimesh.proximity.closest_point(mesh, points)
    bary = trimesh.triangles.points_to_barycentric(src_vertices[src_faces[tri]], closest)
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    return tri, bary, dist


def merge_weights(bone_weights: np.ndarray, bone_labels) -> np.ndarray:
    """(V, nb) anny bone weights -> (V, 24) SMPL joint weights by ``BONE_TO_JOINT``; rows sum to one."""
    merge = np.zeros((len(bone_labels), len(SMPL_JOINTS)))
    for b, label in enumerate(bone_labels):
        if label not in BONE_TO_JOINT:
            raise KeyError(f"anny bone {label!r} has no SMPL joint in BONE_TO_JOINT")
        merge[b, SMPL_JOINTS.index(BONE_TO_JOINT[label])] = 1.0
    w = bone_weights @ merge
    return w / w.sum(axis=1, keepdims=True)


def joint_positions(heads: np.ndarray, bone_labels) -> np.ndarray:
    """(..., nb, 3) bone heads -> (..., 24, 3) SMPL joints by ``JOINT_FROM_BONES``."""
    labels = list(bone_labels)
    return np.stack([heads[..., [labels.index(b) for b in JOINT_FROM_BONES[j]], :].mean(axis=-2)
                     for j in SMPL_JOINTS], axis=-2)


def pca_shape_space(samples: np.ndarray, n_betas: int):
    """PCA of (N, V, 3) samples: mean (V, 3), dirs (V, 3, K) scaled by the std, betas (N, K), variance ratio.

    ``samples[i] ~ mean + dirs @ betas[i]``, betas of the samples with unit sample variance. Signs:
    direction 0 makes the body taller (+Y extent), the others have a positive largest-magnitude entry.
    """
    n, nv, _ = samples.shape
    mean = samples.mean(axis=0)
    x = (samples - mean).reshape(n, -1)
    u, s, vt = np.linalg.svd(x, full_matrices=False)
    var = s ** 2 / (n - 1)
    ratio = var / var.sum()
    std = np.sqrt(var[:n_betas])
    dirs = vt[:n_betas] * std[:, None]
    betas = u[:, :n_betas] * np.sqrt(n - 1)
    top, bottom = np.argmax(mean[:, 1]), np.argmin(mean[:, 1])
    for k in range(n_betas):
        d = dirs[k].reshape(nv, 3)
        flip = (d[top, 1] - d[bottom, 1] < 0) if k == 0 else (dirs[k][np.argmax(np.abs(dirs[k]))] < 0)
        if flip:
            dirs[k] *= -1.0
            betas[:, k] *= -1.0
    return mean, dirs.reshape(n_betas, nv, 3).transpose(1, 2, 0), betas, ratio


def fit_joint_regressor(verts: np.ndarray, joints: np.ndarray, weights: np.ndarray, template: np.ndarray,
                        n_candidates: int = 1500, sum_weight: float = 100.0) -> np.ndarray:
    """Non-negative J_regressor (24, V) with rows summing to one.

    For joint j: minimise ``sum_i |sum_v w_v verts[i, v] - joints[i, j]|^2 + sum_weight^2 (sum_v w_v - 1)^2``
    over ``w >= 0`` (scipy NNLS), restricted to the ``n_candidates`` template vertices nearest to the mean
    joint among those skinned (weight > 0.05) by the joint, its parent or its children; then ``w /= sum(w)``.
    ``verts`` (N, V, 3), ``joints`` (N, 24, 3), ``weights`` (V, 24), ``template`` (V, 3).
    """
    nv = verts.shape[1]
    reg = np.zeros((len(SMPL_JOINTS), nv))
    mean_joints = joints.mean(axis=0)
    for j in range(len(SMPL_JOINTS)):
        family = [j] + ([SMPL_PARENTS[j]] if SMPL_PARENTS[j] >= 0 else []) + \
            [c for c, p in enumerate(SMPL_PARENTS) if p == j]
        skinned = np.nonzero(weights[:, family].sum(axis=1) > 0.05)[0]
        d = np.linalg.norm(template[skinned] - mean_joints[j], axis=1)
        cand = skinned[np.argsort(d)[:n_candidates]]
        a = verts[:, cand, :].transpose(0, 2, 1).reshape(-1, len(cand))
        b = joints[:, j, :].reshape(-1)
        a = np.vstack([a, np.full((1, len(cand)), sum_weight)])
        b = np.append(b, sum_weight)
        w, _ = scipy.optimize.nnls(a, b, maxiter=50 * len(cand))
        reg[j, cand] = w / w.sum()
    return reg


def mouth_contour_midline(faces: np.ndarray, cavity_faces: np.ndarray, rest_vertices: np.ndarray,
                          half_width: float = 0.006) -> np.ndarray:
    """Vertex ids of the inner lip contour near the midline (anny frame, x = left-right).

    The inner lip contour is the set of vertices shared by faces of anny's ``mouth_cavity`` texture segment
    and faces outside it; those within ``half_width`` of the midline (|x| < half_width on ``rest_vertices``)
    are the centres of the upper and lower inner lips. Their mean is the lip-centre point (stomion).
    """
    cavity = np.unique(faces[cavity_faces])
    outside = np.unique(faces[~cavity_faces])
    contour = np.intersect1d(cavity, outside)
    mid = contour[np.abs(rest_vertices[contour, 0]) < half_width]
    if len(mid) < 2:
        raise RuntimeError("could not find the inner lip contour near the midline")
    return mid


def body_height(v: np.ndarray) -> np.ndarray:
    """Standing height (max y - min y) of (..., V, 3) T-pose vertices, metres."""
    return v[..., 1].max(axis=-1) - v[..., 1].min(axis=-1)


def mirror_asymmetry(v: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mirror (x -> -x) asymmetry of a mesh: per vertex, the distance (V,) from its mirror image to the
    nearest vertex (connectivity symmetry) and to the nearest surface point (shape symmetry)."""
    import trimesh
    mirrored = v * np.array([-1.0, 1.0, 1.0])
    d_vertex, _ = scipy.spatial.cKDTree(v).query(mirrored)
    _, d_surface, _ = trimesh.proximity.closest_point(trimesh.Trimesh(v, faces, process=False), mirrored)
    return d_vertex, d_surface


def build(args) -> tuple[dict, dict]:
    data = run_anny(args)
    labels = data["bone_labels"]
    n_fit = args.n_fit
    root = labels.index("root")

    # SMPL frame, each sample centred on its own pelvis (anny root bone head).
    pelvis = to_smpl_frame(data["posed_heads"][:, root])
    verts_full = to_smpl_frame(data["posed_vertices"]) - pelvis[:, None]
    joints = joint_positions(to_smpl_frame(data["posed_heads"]), labels) - pelvis[:, None]
    face_lm = to_smpl_frame(data["face_landmarks"]) - pelvis[:, None]
    faces_full = data["faces"]

    # Decimate the mean mesh, carry everything over by barycentric projection.
    mean_full = verts_full[:n_fit].mean(axis=0)
    weights_full = merge_weights(data["bone_weights"], labels)
    dec_v, dec_f = decimate_symmetric(mean_full, faces_full, face_groups(faces_full, weights_full), args.n_vertices)
    tri, bary, proj_dist = barycentric_projection(mean_full, faces_full, dec_v)
    corners = faces_full[tri]                                       # (V, 3) full-mesh vertex ids
    verts = np.einsum("vk,nvkd->nvd", bary, verts_full[:, corners])   # (N, V, 3)
    weights = np.einsum("vk,vkj->vj", bary, weights_full[corners])
    weights /= weights.sum(axis=1, keepdims=True)

    # PCA shape space on the fitting samples.
    template, shapedirs, betas_fit, ratio = pca_shape_space(verts[:n_fit], args.n_betas)
    basis = shapedirs.reshape(-1, args.n_betas)
    betas_test = np.linalg.lstsq(basis, (verts[n_fit:] - template).reshape(len(verts) - n_fit, -1).T,
                                 rcond=None)[0].T
    betas_all = np.vstack([betas_fit, betas_test])
    recon = template + np.einsum("vdk,nk->nvd", shapedirs, betas_all)

    # Joint regressor on the model's own (reconstructed) vertices.
    j_reg = fit_joint_regressor(recon[:n_fit], joints[:n_fit], weights, template)
    j_pred = np.einsum("jv,nvd->njd", j_reg, recon)
    err = np.linalg.norm(j_pred - joints, axis=-1) * 1000.0        # (N, 24) mm

    # Keypoints: face vertices from anny's own landmarks, the rest SMPL joints.
    tree = scipy.spatial.cKDTree(template)
    lm_mean = face_lm[:n_fit].mean(axis=0)                         # nose, left_eye, right_eye, mouth
    lm_dist, lm_vid = tree.query(lm_mean)
    vertex_ids = {"nose": int(lm_vid[0]), "leye": int(lm_vid[1]), "reye": int(lm_vid[2]), "mouth": int(lm_vid[3])}
    kp_vertex = np.array([vertex_ids.get(k, -1) for k in PEDX_KEYPOINTS], dtype=np.int64)
    kp_joint = np.array([PEDX_JOINT_IDS.get(k, -1) for k in PEDX_KEYPOINTS], dtype=np.int64)
    assert np.all((kp_vertex >= 0) != (kp_joint >= 0))

    # Checks.
    tmpl_joints = j_reg @ template
    heights_samples = body_height(verts)
    beta1_grid = np.array([-3.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0])
    heights_beta1 = body_height(template[None] + shapedirs[None, :, :, 0] * beta1_grid[:, None, None])
    asym_vertex, asym_surface = mirror_asymmetry(template, dec_f)
    left = [i for i, nme in enumerate(SMPL_JOINTS) if nme.startswith("left_")]
    right = [SMPL_JOINTS.index(SMPL_JOINTS[i].replace("left_", "right_")) for i in left]
    joint_asym = np.linalg.norm(tmpl_joints[left] * np.array([-1.0, 1.0, 1.0]) - tmpl_joints[right], axis=1)
    try:
        import trimesh
        tm = trimesh.Trimesh(template, dec_f, process=False)
        watertight, euler = bool(tm.is_watertight), int(tm.euler_number)
        volume = float(tm.volume)
    except Exception:  # pragma: no cover - trimesh comes with anny
        watertight, euler, volume = None, None, None
    recon_err = np.linalg.norm(recon - verts, axis=-1) * 1000.0
    dominant = np.argmax(weights, axis=1)
    ages = data["morphological_age"]

    def stats(a):
        return {"mean": float(np.mean(a)), "max": float(np.max(a))}

    summary = {
        "vertices": int(len(template)), "faces": int(len(dec_f)), "watertight": watertight, "euler_number": euler,
        "template_volume_m3": volume,
        "projection_distance_mm": stats(proj_dist * 1000.0),
        "pca_explained_variance_ratio": [float(r) for r in ratio[:args.n_betas]],
        "pca_explained_total": float(ratio[:args.n_betas].sum()),
        "pca_vertex_error_mm": {"fit": stats(recon_err[:n_fit]), "test": stats(recon_err[n_fit:])},
        "regressor_error_mm": {
            "fit": stats(err[:n_fit]), "test": stats(err[n_fit:]),
            "per_joint_mean_fit": {nme: float(err[:n_fit, j].mean()) for j, nme in enumerate(SMPL_JOINTS)},
        },
        "regressor_nonzeros_per_joint": [int(np.count_nonzero(r)) for r in j_reg],
        "template_pelvis_m": [float(c) for c in tmpl_joints[0]],
        "template_height_m": float(body_height(template)),
        "sample_height_m": {"min": float(heights_samples.min()), "max": float(heights_samples.max()),
                            "mean": float(heights_samples.mean())},
        "beta1_height_m": {str(b): float(h) for b, h in zip(beta1_grid, heights_beta1)},
        "betas_fit_std": [float(s) for s in betas_fit.std(axis=0, ddof=1)],
        "betas_test_std": [float(s) for s in betas_test.std(axis=0, ddof=1)],
        "mirror_asymmetry_to_vertex_mm": stats(asym_vertex * 1000.0),
        "mirror_asymmetry_to_surface_mm": stats(asym_surface * 1000.0),
        "joint_mirror_asymmetry_mm": stats(joint_asym * 1000.0),
        "weights": {
            "row_sum_max_dev": float(np.abs(weights.sum(axis=1) - 1.0).max()), "min": float(weights.min()),
            "max_per_joint": {nme: float(weights[:, j].max()) for j, nme in enumerate(SMPL_JOINTS)},
            "dominant_vertices_per_joint": {nme: int((dominant == j).sum()) for j, nme in enumerate(SMPL_JOINTS)},
        },
        "face_landmark_to_vertex_mm": {k: float(d * 1000.0) for k, d in zip(("nose", "leye", "reye", "mouth"),
                                                                             lm_dist)},
        "keypoint_vertex_ids": vertex_ids,
        "morphological_age_years": {"min": float(ages.min()), "max": float(ages.max())},
    }

    provenance = {
        "builder": "tools/build_open_body_model.py",
        "source": "anny (NAVER, Apache-2.0 code; MakeHuman/MPFB2 CC0 mesh, weights and targets)",
        "anny_version": data["anny_version"], "torch_version": data["torch_version"],
        "anny_topology": ANNY_TOPOLOGY, "landmark_topology": LANDMARK_TOPOLOGY,
        "sampler": "anny.shape_distribution.SimpleShapeDistribution (WHO-calibrated), morphological age "
                   f"~ Uniform({args.age_min:g}, {args.age_max:g}) years",
        "seed": args.seed, "n_fit_samples": n_fit, "n_test_samples": args.n_test,
        "pose": "T-pose via anny world-orient (arms horizontal, elbows straight); SMPL axes (Y up, +Z forward), "
                "metres; each sample centred on its pelvis",
        "vertices": int(len(template)), "faces": int(len(dec_f)), "watertight": watertight,
        "n_betas": args.n_betas,
        "pca_explained_variance_ratio": summary["pca_explained_variance_ratio"],
        "pca_explained_total": summary["pca_explained_total"],
        "regressor_error_mm": {"fit_mean": summary["regressor_error_mm"]["fit"]["mean"],
                               "fit_max": summary["regressor_error_mm"]["fit"]["max"],
                               "test_mean": summary["regressor_error_mm"]["test"]["mean"],
                               "test_max": summary["regressor_error_mm"]["test"]["max"]},
        "posedirs": "zeros (no pose correctives)",
        "face_keypoints": "nose/eyes: nearest vertex to anny's COCO regressor; mouth: nearest vertex to the "
                          "midline of the inner lip contour (anny mouth_cavity segment)",
        "build_date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d"),
    }

    nv = len(template)
    kintree = np.vstack([np.array(SMPL_PARENTS, dtype=np.int64), np.arange(len(SMPL_JOINTS))])
    kintree = np.where(kintree < 0, 4294967295, kintree).astype(np.uint32)
    arrays = {
        "v_template": template.astype(np.float32),
        "shapedirs": shapedirs.astype(np.float32),
        "posedirs": np.zeros((nv, 3, 207), dtype=np.float32),
        "J_regressor": j_reg.astype(np.float32),
        "weights": weights.astype(np.float32),
        "kintree_table": kintree,
        "f": dec_f.astype(np.int32),
        "pedx_keypoint_names": np.array(PEDX_KEYPOINTS),
        "pedx_keypoint_vertex_ids": kp_vertex,
        "pedx_keypoint_joint_ids": kp_joint,
        "provenance": np.array(json.dumps(provenance, sort_keys=True)),
    }
    # float32 storage: renormalise the stored rows so they still sum to one in float64.
    for key in ("J_regressor", "weights"):
        a = arrays[key].astype(np.float64)
        arrays[key] = (a / a.sum(axis=1, keepdims=True)).astype(np.float32)
    return arrays, summary


def main(argv=None) -> int:
    args = parse_args(argv)
    if "ANNY_CACHE_DIR" not in os.environ:
        print("note: ANNY_CACHE_DIR is not set; anny caches ~1 GB under its default folder", file=sys.stderr)
    arrays, summary = build(args)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp.npz")
    np.savez_compressed(tmp, **arrays)
    os.replace(tmp, out)
    summary["file_bytes"] = out.stat().st_size
    text = json.dumps(summary, indent=1)
    print(text)
    if args.summary:
        Path(args.summary).write_text(text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
