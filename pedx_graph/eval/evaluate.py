"""Compare fitted results with ground truth (both in the PedX SMPL layout): MPJPE tables.

Ground-truth keypoints come from the ground-truth SMPL parameters through the body model (the simulator's
model); predictions use the ``keypoints_3d`` field our results carry, or the body model when absent.
Visibility weights come from the truth dataset's 2D labels (a joint counts when it is labelled visible in
the left or the right image); the distance of a frame is the horizontal distance of the true pelvis from the
LiDAR.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from pedx_graph.body import BodyModel
from pedx_graph.eval.metrics import eval_joints, eval_visibility, joint_errors, markdown_table, summarise
from pedx_graph.utils import atomic_write_json, atomic_write_text

log = logging.getLogger(__name__)


def _keypoints_of(labels, model: BodyModel, use_extra: bool) -> np.ndarray:
    if use_extra and all("keypoints_3d" in lab.extra for lab in labels):
        return np.stack([np.asarray(lab.extra["keypoints_3d"], dtype=float) for lab in labels])
    pose = np.stack([lab.pose for lab in labels])
    betas = np.stack([lab.betas for lab in labels])
    trans = np.stack([lab.trans for lab in labels])
    return np.asarray(model.keypoints(pose, betas, trans))


def _visibility(truth_root, grounds: dict | None = None) -> dict:
    """(sequence, tracking id, frame) -> (18,) labelled-and-visible flags of the truth's 2D labels; fills
    ``grounds`` (sequence -> :class:`~pedx_graph.data.ground.GroundFrame`) when given."""
    from pedx_graph.data.reader import read_dataset

    vis = {}
    for track in read_dataset(truth_root):
        if grounds is not None:
            grounds[track.sequence] = track.ground
        for fr in track.frames:
            v = np.zeros(18, dtype=bool)
            for view in (fr.left, fr.right):
                if view is not None:
                    v |= np.asarray(view.visible, dtype=bool) & view.labelled
            vis[(track.sequence, track.tracking_id, fr.frame)] = v
    return vis


def evaluate(results: str | os.PathLike, truth: str | os.PathLike, model: BodyModel | None = None) -> dict:
    """MPJPE of ``results`` against ``truth``: the :func:`summarise` dict plus coverage counts."""
    arrays, missing = evaluate_arrays(results, truth, model)
    summary = summarise(*arrays)
    summary["missing_frames"] = missing
    summary["results"] = str(results)
    summary["truth"] = str(truth)
    return summary


def evaluate_arrays(results: str | os.PathLike, truth: str | os.PathLike, model: BodyModel | None = None
                    ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], int]:
    """Per-frame errors of ``results`` against ``truth``: ((global (N,13), root-relative (N,13),
    visibility weights (N,13), distance (N,): the pelvis' distance from the rig in the ground plane of the
    sequence's :class:`~pedx_graph.data.ground.GroundFrame`), number of labelled truth frames without a
    result)."""
    from pedx_graph.data.reader import read_smpl_labels

    model = model or BodyModel.load()
    pred = read_smpl_labels(results)
    gt = read_smpl_labels(truth)
    grounds: dict = {}
    vis = _visibility(truth, grounds)
    glob_all, rel_all, w_all, dist_all = [], [], [], []
    missing = 0
    for key, gt_labels in gt.items():
        pred_by_frame = {lab.frame: lab for lab in pred.get(key, [])}
        pairs = [(g, pred_by_frame[g.frame]) for g in gt_labels if g.frame in pred_by_frame
                 and (key[0], key[1], g.frame) in vis]
        missing += sum(1 for g in gt_labels if g.frame not in pred_by_frame and (key[0], key[1], g.frame) in vis)
        if not pairs:
            continue
        gt_kp = _keypoints_of([g for g, _ in pairs], model, use_extra=False)
        pr_kp = _keypoints_of([p for _, p in pairs], model, use_extra=True)
        glob, rel = joint_errors(eval_joints(pr_kp), eval_joints(gt_kp))
        weights = np.stack([eval_visibility(vis[(key[0], key[1], g.frame)]) for g, _ in pairs])
        pelvis = 0.5 * (gt_kp[:, 12] + gt_kp[:, 13])
        glob_all.append(glob); rel_all.append(rel); w_all.append(weights)
        dist_all.append(grounds[key[0]].horizontal_distance(pelvis))
    if not glob_all:
        raise ValueError(f"no frame of {results} matches a labelled frame of {truth}")
    arrays = (np.concatenate(glob_all), np.concatenate(rel_all), np.concatenate(w_all), np.concatenate(dist_all))
    return arrays, missing


def write_report(summary: dict, out_dir: str | os.PathLike, title: str = "Accuracy") -> tuple[Path, Path]:
    """Write ``eval.json`` and ``eval.md`` into ``out_dir`` (atomically)."""
    out_dir = Path(out_dir)
    j = atomic_write_json(out_dir / "eval.json", summary)
    m = atomic_write_text(out_dir / "eval.md", markdown_table(summary, title))
    return j, m
