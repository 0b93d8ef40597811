"""Build the keypoint-set data files (``pedx_graph/body/data/keypoint_sets/<set>.json``) from the open body model.

Run from the repository root (needs only the package itself)::

    python tools/build_keypoint_sets.py [--out pedx_graph/body/data/keypoint_sets]

Each detector format's keypoints are defined on the body model by a rule applied to the open model's rest mesh
(mean shape, T-pose; the model's body frame: +y up, +z forward, the subject's left at +x, metres).  The rules:

* joints: shoulders, elbows, wrists, knees, ankles are SMPL joints 16-21, 4/5, 7/8 (SMPLify's choice);
* nose, eyes: the PedX definitions of the model (the open model file's keys; SMPL: smplx's vertex ids);
* ears: the lateral-most head vertex (largest ``+-x``) within ``EAR_BAND_M`` of the eyes' height and behind the
  eyes (``z`` below the eyes' ``z``); SMPL topology: smplx's ear vertices 583 (left) and 4071 (right);
* COCO / OpenPose hips: annotators click the hip on the body's outline, wider than SMPL's hip joint (which sits
  inside the pelvis): half the joint plus half the lateral-most vertex within ``HIP_BAND_M`` of the joint's
  height, among vertices skinned mostly to the pelvis or that thigh;
* OpenPose Neck (BODY_25, COCO-18) = mid-shoulder, ``0.5 (J16 + J17)``; BODY_25's MidHip = the mean of its two
  hips; BODY_25B's Neck is MPII's upper neck: ``0.5 (J12 + J15)`` (neck and head joints);
* BODY_25B's Head (top): the highest rest-mesh vertex (largest ``y``);
* toes and heels, per foot (vertices skinned mostly to that ankle or foot joint, ``s`` = distance outward from
  the ankle joint along ``+-x``): big toe ``argmax(z - TOE_SIDE_WEIGHT s)`` (front, medial), small toe
  ``argmax(z + TOE_SIDE_WEIGHT s)`` (front, lateral), heel ``argmin(z + HEEL_HEIGHT_WEIGHT (y - y_sole))``
  (back, low).  SMPL topology: smplx's foot vertices 3216 / 3226 / 3387 (left big toe, small toe, heel),
  6617 / 6624 / 6787 (right).

For the SMPL topology (V = 6890, used when a real SMPL file is loaded) the points without a known SMPL vertex id
(COCO hips, head top) are written as affine combinations of SMPL joints whose coefficients are fitted by least
squares so that they reproduce the open model's vertex-defined points over ``--samples`` random shapes (rest
pose); the fitting error is stored in each file (``smpl_joint_rule_fit_m``).

A name a format lacks (PedX's ``head`` and ``mouth`` in COCO; ears and toes in PedX) has no definition: it stays
unlabelled.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from pedx_graph.body.keypoint_defs import (SMPL_JOINT_KEYPOINTS, SMPL_MOUTH_RULE,  # noqa: E402
                                          SMPL_VERTEX_KEYPOINTS, faces_digest)
from pedx_graph.body.model import BodyModel  # noqa: E402
from pedx_graph.keypoints import PEDX_KEYPOINTS  # noqa: E402

EAR_BAND_M = 0.015
"""Height band around the eyes in which the ear vertex is searched, metres."""
HIP_BAND_M = 0.02
"""Height band around the hip joint in which the lateral hip surface vertex is searched, metres."""
TOE_SIDE_WEIGHT = 0.6
"""Weight of the sideways distance against the forward distance when picking the big / small toe."""
HEEL_HEIGHT_WEIGHT = 0.5
"""Weight of the height above the sole against the backward distance when picking the heel."""

#: smplx's vertex ids on the SMPL topology (its ``vertex_ids['smplh']`` table).
SMPL_VERTEX_IDS = {"nose": 332, "reye": 6260, "leye": 2800, "rear": 4071, "lear": 583,
                   "lbigtoe": 3216, "lsmalltoe": 3226, "lheel": 3387,
                   "rbigtoe": 6617, "rsmalltoe": 6624, "rheel": 6787}

# Canonical point names (our own) -> the set's names.  Canonical names reuse PedX's where the point is PedX's.
SETS: dict[str, dict] = {
    "pedx18": {"description": "PedX's 18 manual-label keypoints (pedx-format notes), the package's native set.",
               "names": {n: n for n in PEDX_KEYPOINTS}},
    "coco17": {"description": "COCO's 17 person keypoints (annotation and results files; MMPose/ViTPose-style "
                              "detectors).",
               "names": {"nose": "nose", "left_eye": "leye", "right_eye": "reye", "left_ear": "lear",
                         "right_ear": "rear", "left_shoulder": "lsho", "right_shoulder": "rsho",
                         "left_elbow": "lelb", "right_elbow": "relb", "left_wrist": "lwri",
                         "right_wrist": "rwri", "left_hip": "lhip_surf", "right_hip": "rhip_surf",
                         "left_knee": "lknee", "right_knee": "rknee", "left_ankle": "lankl",
                         "right_ankle": "rankl"}},
    "coco18": {"description": "OpenPose's COCO model (18 keypoints; Neck = mid-shoulder).",
               "names": {"Nose": "nose", "Neck": "neck_midsho", "RShoulder": "rsho", "RElbow": "relb",
                         "RWrist": "rwri", "LShoulder": "lsho", "LElbow": "lelb", "LWrist": "lwri",
                         "RHip": "rhip_surf", "RKnee": "rknee", "RAnkle": "rankl", "LHip": "lhip_surf",
                         "LKnee": "lknee", "LAnkle": "lankl", "REye": "reye", "LEye": "leye",
                         "REar": "rear", "LEar": "lear"}},
    "body25": {"description": "OpenPose BODY_25 (Neck = mid-shoulder, MidHip = mean of the hips, feet).",
               "names": {"Nose": "nose", "Neck": "neck_midsho", "RShoulder": "rsho", "RElbow": "relb",
                         "RWrist": "rwri", "LShoulder": "lsho", "LElbow": "lelb", "LWrist": "lwri",
                         "MidHip": "midhip_surf", "RHip": "rhip_surf", "RKnee": "rknee", "RAnkle": "rankl",
                         "LHip": "lhip_surf", "LKnee": "lknee", "LAnkle": "lankl", "REye": "reye",
                         "LEye": "leye", "REar": "rear", "LEar": "lear", "LBigToe": "lbigtoe",
                         "LSmallToe": "lsmalltoe", "LHeel": "lheel", "RBigToe": "rbigtoe",
                         "RSmallToe": "rsmalltoe", "RHeel": "rheel"}},
    "body25b": {"description": "OpenPose BODY_25B (Neck = MPII's upper neck, Head = head top, feet).",
                "names": {"Nose": "nose", "LEye": "leye", "REye": "reye", "LEar": "lear", "REar": "rear",
                          "LShoulder": "lsho", "RShoulder": "rsho", "LElbow": "lelb", "RElbow": "relb",
                          "LWrist": "lwri", "RWrist": "rwri", "LHip": "lhip_surf", "RHip": "rhip_surf",
                          "LKnee": "lknee", "RKnee": "rknee", "LAnkle": "lankl", "RAnkle": "rankl",
                          "Neck": "neck_upper", "Head": "headtop", "LBigToe": "lbigtoe",
                          "LSmallToe": "lsmalltoe", "LHeel": "lheel", "RBigToe": "rbigtoe",
                          "RSmallToe": "rsmalltoe", "RHeel": "rheel"}},
}

#: What each canonical point is, in words (written into the files).
RULE_TEXT = {
    "ear": f"lateral-most head vertex within {EAR_BAND_M} m of the eyes' height, behind the eyes",
    "hip_surf": f"0.5 hip joint + 0.5 lateral-most vertex (pelvis/thigh-skinned) within {HIP_BAND_M} m of the "
                f"joint's height",
    "midhip_surf": "mean of the two surface hips",
    "neck_midsho": "mid-shoulder: 0.5 (J16 + J17)",
    "neck_upper": "upper neck: 0.5 (J12 + J15)",
    "headtop": "highest rest-mesh vertex",
    "bigtoe": f"foot vertex maximising z - {TOE_SIDE_WEIGHT} (outward distance from the ankle)",
    "smalltoe": f"foot vertex maximising z + {TOE_SIDE_WEIGHT} (outward distance from the ankle)",
    "heel": f"foot vertex minimising z + {HEEL_HEIGHT_WEIGHT} (height above the sole)",
}


def _dominant_joint(weights: np.ndarray) -> np.ndarray:
    return np.asarray(weights).argmax(axis=1)


def open_definitions(model: BodyModel) -> dict[str, dict]:
    """Canonical point -> {"vertices": [[id, w]...], "joints": [[id, w]...]} on the open model's rest mesh."""
    verts = np.asarray(model.v_template, dtype=float)
    joints = model.rest_joints(np.zeros(model.num_betas))
    dom = _dominant_joint(model.weights)
    kp = model.keypoint_map
    defs: dict[str, dict] = {}
    for k, name in enumerate(kp.names):                          # PedX points: as the model file defines them
        defs[name] = {"vertices": [[int(v), float(c)] for v, c in zip(kp.vertex_ids, kp.vertex_coeffs[k]) if c],
                      "joints": [[int(j), float(c)] for j, c in enumerate(kp.joint_coeffs[k]) if c]}
    eye_ids = [defs["leye"]["vertices"][0][0], defs["reye"]["vertices"][0][0]]
    eye_y, eye_z = verts[eye_ids, 1].mean(), verts[eye_ids, 2].mean()
    head = (dom == 15) & (np.abs(verts[:, 1] - eye_y) < EAR_BAND_M) & (verts[:, 2] < eye_z)
    for side, sign in (("l", 1.0), ("r", -1.0)):
        cand = np.flatnonzero(head)
        defs[f"{side}ear"] = {"vertices": [[int(cand[np.argmax(sign * verts[cand, 0])]), 1.0]], "joints": []}
        hip_j, thigh_j, knee_j, ankle_j, foot_j = ((1, 1, 4, 7, 10) if side == "l" else (2, 2, 5, 8, 11))
        hip = joints[hip_j]
        band = np.isin(dom, [0, thigh_j]) & (np.abs(verts[:, 1] - hip[1]) < HIP_BAND_M) & (sign * verts[:, 0] > 0)
        cand = np.flatnonzero(band)
        lateral = int(cand[np.argmax(sign * verts[cand, 0])])
        defs[f"{side}hip_surf"] = {"vertices": [[lateral, 0.5]], "joints": [[hip_j, 0.5]]}
        foot = np.flatnonzero(np.isin(dom, [ankle_j, foot_j]) & (sign * verts[:, 0] > 0))
        outward = sign * (verts[foot, 0] - joints[ankle_j, 0])
        sole = verts[foot, 1].min()
        defs[f"{side}bigtoe"] = {"vertices": [[int(foot[np.argmax(verts[foot, 2] - TOE_SIDE_WEIGHT * outward)]),
                                               1.0]], "joints": []}
        defs[f"{side}smalltoe"] = {"vertices": [[int(foot[np.argmax(verts[foot, 2] + TOE_SIDE_WEIGHT * outward)]),
                                                 1.0]], "joints": []}
        defs[f"{side}heel"] = {"vertices": [[int(foot[np.argmin(verts[foot, 2] + HEEL_HEIGHT_WEIGHT
                                                                 * (verts[foot, 1] - sole))]), 1.0]],
                               "joints": []}
    defs["midhip_surf"] = _mean_of(defs["lhip_surf"], defs["rhip_surf"])
    defs["neck_midsho"] = {"vertices": [], "joints": [[16, 0.5], [17, 0.5]]}
    defs["neck_upper"] = {"vertices": [], "joints": [[12, 0.5], [15, 0.5]]}
    defs["headtop"] = {"vertices": [[int(np.argmax(verts[:, 1])), 1.0]], "joints": []}
    return defs


def _mean_of(a: dict, b: dict) -> dict:
    out: dict[str, dict[int, float]] = {"vertices": {}, "joints": {}}
    for d in (a, b):
        for kind in ("vertices", "joints"):
            for i, c in d[kind]:
                out[kind][i] = out[kind].get(i, 0.0) + 0.5 * c
    return {kind: [[i, c] for i, c in sorted(out[kind].items())] for kind in out}


def _evaluate(defn: dict, verts: np.ndarray, joints: np.ndarray) -> np.ndarray:
    out = np.zeros(verts.shape[:-2] + (3,))
    for v, c in defn["vertices"]:
        out = out + c * verts[..., v, :]
    for j, c in defn["joints"]:
        out = out + c * joints[..., j, :]
    return out


def fit_joint_rule(model: BodyModel, defn: dict, joint_ids: list[int], samples: int,
                   rng: np.random.Generator) -> tuple[dict, float]:
    """Affine joint combination (coefficients summing to one) reproducing ``defn`` over random shapes (rest pose).

    Returns the definition and the RMS error, metres.  The point is written as
    ``J_a + sum_i c_i (J_i - J_a)`` (``J_a`` = the first joint), so the coefficients sum to one and the point
    moves rigidly with the body.
    """
    betas = rng.standard_normal((samples, model.num_betas))
    targets, diffs = [], []
    for beta in betas:
        verts = model.v_template + np.einsum("vcb,b->vc", model.shapedirs, beta)
        joints = model.rest_joints(beta)
        targets.append(_evaluate(defn, verts, joints) - joints[joint_ids[0]])
        diffs.append(np.stack([joints[j] - joints[joint_ids[0]] for j in joint_ids[1:]], axis=1))  # (3, n)
    A = np.concatenate(diffs, axis=0)
    b = np.concatenate(targets, axis=0)
    coeffs, *_ = np.linalg.lstsq(A, b, rcond=None)
    rms = float(np.sqrt(np.mean((A @ coeffs - b) ** 2) * 3))
    weights = {joint_ids[0]: 1.0 - float(coeffs.sum())}
    for j, c in zip(joint_ids[1:], coeffs):
        weights[j] = weights.get(j, 0.0) + float(c)
    return {"vertices": [], "joints": [[j, round(c, 6)] for j, c in weights.items()]}, rms


def smpl_definitions(model: BodyModel, open_defs: dict[str, dict], samples: int,
                     seed: int) -> tuple[dict[str, dict], dict[str, float]]:
    """Canonical point -> definition on the SMPL topology (see module docstring), and the joint rules' fit RMS."""
    rng = np.random.default_rng(seed)
    defs: dict[str, dict] = {}
    for name, j in SMPL_JOINT_KEYPOINTS.items():
        defs[name] = {"vertices": [], "joints": [[j, 1.0]]}
    for name, v in SMPL_VERTEX_KEYPOINTS.items():
        defs[name] = {"vertices": [[v, 1.0]], "joints": []}
    defs["mouth"] = {"vertices": [list(p) for p in SMPL_MOUTH_RULE["vertices"]],
                     "joints": [list(p) for p in SMPL_MOUTH_RULE["joints"]]}
    for name in ("lear", "rear", "lbigtoe", "lsmalltoe", "lheel", "rbigtoe", "rsmalltoe", "rheel"):
        defs[name] = {"vertices": [[SMPL_VERTEX_IDS[name], 1.0]], "joints": []}
    fits = {}
    defs["lhip_surf"], fits["lhip_surf"] = fit_joint_rule(model, open_defs["lhip_surf"], [1, 0, 2, 4], samples, rng)
    defs["rhip_surf"], fits["rhip_surf"] = fit_joint_rule(model, open_defs["rhip_surf"], [2, 0, 1, 5], samples, rng)
    defs["headtop"], fits["headtop"] = fit_joint_rule(model, open_defs["headtop"], [15, 12, 16, 17], samples,
                                                      rng)
    defs["midhip_surf"] = _mean_of(defs["lhip_surf"], defs["rhip_surf"])
    defs["neck_midsho"] = dict(open_defs["neck_midsho"])
    defs["neck_upper"] = dict(open_defs["neck_upper"])
    return defs, fits


def build(out_dir: Path, samples: int = 200, seed: int = 0) -> list[Path]:
    """Write one JSON file per keypoint set into ``out_dir``; returns the paths."""
    model = BodyModel.load()
    open_defs = open_definitions(model)
    smpl_defs, fits = smpl_definitions(model, open_defs, samples, seed)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for set_name, spec in SETS.items():
        names = list(spec["names"])
        canon = [spec["names"][n] for n in names]
        rules = {}
        for n, c in zip(names, canon):
            key = c[1:] if c[:1] in "lr" and c[1:] in RULE_TEXT else c
            if key in RULE_TEXT:
                rules[n] = RULE_TEXT[key]
        doc = {
            "name": set_name,
            "description": spec["description"],
            "generated_by": "tools/build_keypoint_sets.py",
            "keypoints": names,
            "pedx_equivalent": {n: c for n, c in zip(names, canon) if c in PEDX_KEYPOINTS},
            "rules": rules,
            "definitions": {
                "open": {"faces_sha256_16": faces_digest(model.faces), "num_vertices": int(model.num_vertices),
                         "points": {n: open_defs[c] for n, c in zip(names, canon)}},
                "smpl": {"num_vertices": 6890,
                         "points": {n: smpl_defs[c] for n, c in zip(names, canon)}},
            },
            "smpl_joint_rule_fit_m": {n: round(fits[c], 5) for n, c in zip(names, canon) if c in fits},
        }
        path = out_dir / f"{set_name}.json"
        path.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=str(REPO / "pedx_graph/body/data/keypoint_sets"),
                        help="output folder (default: the package's keypoint_sets folder)")
    parser.add_argument("--samples", type=int, default=200, help="random shapes for the SMPL joint rules")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random shapes")
    args = parser.parse_args(argv)
    for path in build(Path(args.out), args.samples, args.seed):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
