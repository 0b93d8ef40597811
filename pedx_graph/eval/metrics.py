"""Accuracy metrics of the paper (Sec. V): MPJPE in the global frame and root-relative.

* **global**: Euclidean distance per joint in the world (LiDAR) frame, no alignment: metric position matters.
* **root-relative**: after a similarity (rotation, translation, scale) alignment of the 13 evaluated joints
  of one frame onto the ground truth (Umeyama), so only the articulated pose counts.

Joints are the paper's 13 (``EVAL_JOINTS``); ``hip`` is the mid-point of ``lhip`` and ``rhip``.  Errors are
averaged with per-joint weights; the headline weights are the annotator's visibility (a joint counts when
it is labelled visible in the left or the right image), as the paper evaluates labelled joints.
"""
from __future__ import annotations

import numpy as np

from pedx_graph.keypoints import EVAL_JOINTS, PEDX_KEYPOINTS

_IDX = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}

#: Distance bins of the reports, metres (horizontal distance of the pelvis from the LiDAR).
DISTANCE_BINS: tuple[tuple[float, float], ...] = ((5.0, 15.0), (15.0, 25.0), (25.0, 35.0), (35.0, 45.0))


def eval_joints(keypoints18: np.ndarray) -> np.ndarray:
    """(..., 18, 3) PedX keypoints -> (..., 13, 3) evaluated joints in ``EVAL_JOINTS`` order."""
    kp = np.asarray(keypoints18, dtype=float)
    out = []
    for name in EVAL_JOINTS:
        if name == "hip":
            out.append(0.5 * (kp[..., _IDX["lhip"], :] + kp[..., _IDX["rhip"], :]))
        else:
            out.append(kp[..., _IDX[name], :])
    return np.stack(out, axis=-2)


def eval_visibility(visible18: np.ndarray) -> np.ndarray:
    """(..., 18) bool visibility -> (..., 13): ``hip`` counts when either hip is visible."""
    vis = np.asarray(visible18, dtype=bool)
    out = []
    for name in EVAL_JOINTS:
        if name == "hip":
            out.append(vis[..., _IDX["lhip"]] | vis[..., _IDX["rhip"]])
        else:
            out.append(vis[..., _IDX[name]])
    return np.stack(out, axis=-1)


def similarity_align(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Umeyama: the similarity transform of ``source`` (N, 3) that best fits ``target`` (N, 3).

    Returns the aligned source points (N, 3).  Needs N >= 3 non-collinear points.
    """
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    s0, t0 = source - mu_s, target - mu_t
    cov = t0.T @ s0 / len(source)
    u, sig, vt = np.linalg.svd(cov)
    d = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        d[-1] = -1.0
    rot = u @ np.diag(d) @ vt
    var_s = (s0 ** 2).sum() / len(source)
    scale = float((sig * d).sum() / var_s) if var_s > 0 else 1.0
    return scale * s0 @ rot.T + mu_t


def joint_errors(pred13: np.ndarray, truth13: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint errors (..., 13) in metres: (global, root-relative after similarity alignment)."""
    pred13 = np.asarray(pred13, dtype=float)
    truth13 = np.asarray(truth13, dtype=float)
    glob = np.linalg.norm(pred13 - truth13, axis=-1)
    flat_p = pred13.reshape(-1, len(EVAL_JOINTS), 3)
    flat_t = truth13.reshape(-1, len(EVAL_JOINTS), 3)
    rel = np.stack([np.linalg.norm(similarity_align(p, t) - t, axis=-1) for p, t in zip(flat_p, flat_t)])
    return glob, rel.reshape(glob.shape)


def weighted_mean(errors: np.ndarray, weights: np.ndarray) -> float:
    """Weighted mean of errors; NaN when all weights are zero."""
    w = np.asarray(weights, dtype=float)
    total = w.sum()
    return float((np.asarray(errors) * w).sum() / total) if total > 0 else float("nan")


def distance_bin(distance_m: float, bins: tuple[tuple[float, float], ...] = DISTANCE_BINS) -> str | None:
    """Label of the distance bin of a distance, e.g. ``"5-15"``; None outside every bin."""
    for lo, hi in bins:
        if lo <= distance_m < hi:
            return f"{lo:g}-{hi:g}"
    return None


def summarise(glob: np.ndarray, rel: np.ndarray, weights: np.ndarray, distances: np.ndarray,
              bins: tuple[tuple[float, float], ...] = DISTANCE_BINS) -> dict:
    """Tables of MPJPE (millimetres) from per-frame per-joint errors.

    ``glob``, ``rel``, ``weights``: (N, 13); ``distances``: (N,) metres; ``bins``: the distance bins, metres.
    Returns a dict with ``overall``
    (global/root-relative, visibility-weighted and all joints), ``per_joint`` and ``per_distance``.
    """
    glob = np.asarray(glob) * 1000.0
    rel = np.asarray(rel) * 1000.0
    weights = np.asarray(weights, dtype=float)
    ones = np.ones_like(weights)
    out = {
        "frames": int(len(glob)),
        "overall": {
            "global_mm": weighted_mean(glob, weights),
            "root_relative_mm": weighted_mean(rel, weights),
            "global_all_joints_mm": weighted_mean(glob, ones),
            "root_relative_all_joints_mm": weighted_mean(rel, ones),
        },
        "per_joint": {
            name: {"global_mm": weighted_mean(glob[:, j], weights[:, j]),
                   "root_relative_mm": weighted_mean(rel[:, j], weights[:, j])}
            for j, name in enumerate(EVAL_JOINTS)
        },
        "per_distance": {},
    }
    labels = np.array([distance_bin(float(d), bins) for d in distances], dtype=object)
    for lo, hi in bins:
        key = f"{lo:g}-{hi:g}"
        sel = labels == key
        out["per_distance"][key] = {
            "frames": int(sel.sum()),
            "global_mm": weighted_mean(glob[sel], weights[sel]) if sel.any() else float("nan"),
            "root_relative_mm": weighted_mean(rel[sel], weights[sel]) if sel.any() else float("nan"),
        }
    return out


def markdown_table(summary: dict, title: str = "Accuracy") -> str:
    """Markdown tables (overall, per distance, per joint) of :func:`summarise`'s output."""
    o = summary["overall"]
    lines = [f"## {title}", "",
             f"Frames: {summary['frames']}. MPJPE in millimetres; visibility-weighted unless stated.", "",
             "| metric | global | root-relative |", "|---|---:|---:|",
             f"| visible joints | {o['global_mm']:.1f} | {o['root_relative_mm']:.1f} |",
             f"| all joints | {o['global_all_joints_mm']:.1f} | {o['root_relative_all_joints_mm']:.1f} |",
             "", "| distance (m) | frames | global | root-relative |", "|---|---:|---:|---:|"]
    for key, row in summary["per_distance"].items():
        lines.append(f"| {key} | {row['frames']} | {row['global_mm']:.1f} | {row['root_relative_mm']:.1f} |")
    lines += ["", "| joint | global | root-relative |", "|---|---:|---:|"]
    for name, row in summary["per_joint"].items():
        lines.append(f"| {name} | {row['global_mm']:.1f} | {row['root_relative_mm']:.1f} |")
    return "\n".join(lines) + "\n"
