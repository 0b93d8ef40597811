"""Compare fitted results with ground truth (both in the PedX SMPL layout): MPJPE tables.

Ground-truth keypoints come from the ground-truth SMPL parameters through the body model (the simulator's
model); predictions use the ``keypoints_3d`` field our results carry, or the body model when absent.
Visibility weights come from the truth dataset's 2D labels (a joint counts when it is labelled visible in
the left or the right image); the distance of a frame is the horizontal distance of the true pelvis from the
LiDAR.

Results and truth must be of one scene (:func:`check_results_match_truth`), else :class:`EvalMismatchError`
names what does not match instead of reporting metres of error: every sequence of the results has ground
truth; at least ``min_matched_fraction`` (half) of the result frames have a ground-truth label of the same
sequence, track and frame; and the results' keypoints, projected with the truth's calibration, land on the
truth's 2D labels (median offset at most ``max_label_offset`` = half the size of the labelled keypoints' box,
while a fit is off by a few percent of it).  The last catches results of another scene that happens to share
sequence, track and frame names (the simulator's for the same seed on another rig).
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


#: At least this fraction of the result frames must have a ground-truth label (same sequence, track, frame).
MIN_MATCHED_FRACTION = 0.5

#: Largest median offset of the results' projected keypoints from the truth's 2D labels, in sizes (diagonal of
#: the labelled keypoints' box) of the labelled person.
MAX_LABEL_OFFSET = 0.5


class EvalMismatchError(ValueError):
    """Results and ground truth are not of the same scene; the message says what does not match."""


def _visibility(truth_root, grounds: dict | None = None, views: dict | None = None) -> dict:
    """(sequence, tracking id, frame) -> (18,) labelled-and-visible flags of the truth's 2D labels; fills
    ``grounds`` (sequence -> :class:`~pedx_graph.data.ground.GroundFrame`) and ``views`` (same key -> (the
    calibration, side, (18, 2) pixels) of the frame's first labelled image) when given."""
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
            labelled = fr.labelled_views()
            if views is not None and labelled:
                pair, side, view = labelled[0]
                views[(track.sequence, track.tracking_id, fr.frame)] = (track.calibrations[pair], side,
                                                                        view.keypoints)
    return vis


def _label_offset(world_keypoints: np.ndarray, calib, side: str, pixels: np.ndarray) -> float:
    """Median pixel distance of the projected (18, 3) keypoints from the labelled (18, 2) pixels, in sizes of
    the labelled keypoints' box; NaN with fewer than three labelled keypoints or a point behind the camera."""
    labelled = np.all(np.isfinite(pixels), axis=1)
    if labelled.sum() < 3:
        return float("nan")
    depth = calib.world_to_rect(world_keypoints)[:, 2]
    if np.any(depth[labelled] <= 0):
        return float("inf")
    left, right = calib.project(world_keypoints)
    uv = left if side == "left" else right
    size = float(np.linalg.norm(pixels[labelled].max(axis=0) - pixels[labelled].min(axis=0)))
    offset = float(np.median(np.linalg.norm(uv[labelled] - pixels[labelled], axis=1)))
    return offset / max(size, 1.0)


def check_results_match_truth(pred: dict, gt: dict, views: dict, results, truth, model: BodyModel,
                              min_matched_fraction: float = MIN_MATCHED_FRACTION,
                              max_label_offset: float = MAX_LABEL_OFFSET) -> None:
    """:class:`EvalMismatchError` when the results (``pred``) and the ground truth (``gt``, ``views`` of its 2D
    labels) are not of one scene (module docstring); names the sequences, tracks or frames that do not match."""
    def some(items) -> str:
        items = sorted(items)
        return ", ".join(map(str, items[:3])) + (f" and {len(items) - 3} more" if len(items) > 3 else "")

    pred_sequences = {seq for seq, _ in pred}
    gt_sequences = {seq for seq, _ in gt}
    if not pred_sequences & gt_sequences:
        raise EvalMismatchError(f"{results}: sequences {some(pred_sequences)} of the results have no ground truth "
                                f"in {truth} (it has {some(gt_sequences)}): not the same dataset")
    n_frames = sum(len(labels) for labels in pred.values())
    gt_frames = {(key, lab.frame) for key, labels in gt.items() for lab in labels}
    matched = [(key, lab) for key, labels in pred.items() for lab in labels if (key, lab.frame) in gt_frames]
    if len(matched) < min_matched_fraction * n_frames:
        foreign = [f"{seq}/{tid}" for seq, tid in pred if (seq, tid) not in gt]
        detail = (f"tracks without ground truth: {some(foreign)}" if foreign else
                  "the tracks exist but their frames do not")
        raise EvalMismatchError(f"{results}: only {len(matched)} of {n_frames} result frames "
                                f"({100 * len(matched) / max(n_frames, 1):.0f} %) have a ground-truth label in "
                                f"{truth} (at least {100 * min_matched_fraction:g} %); {detail}")
    offsets = []
    for key, lab in matched:
        view = views.get((key[0], key[1], lab.frame))
        if view is not None:
            keypoints = _keypoints_of([lab], model, use_extra=True)[0]
            offsets.append(_label_offset(keypoints, *view))
    offsets = np.asarray([o for o in offsets if not np.isnan(o)])
    if offsets.size and np.median(offsets) > max_label_offset:
        raise EvalMismatchError(f"{results}: the results' keypoints land a median {np.median(offsets):.3g} person "
                                f"sizes away from the 2D labels of {truth} when projected with its calibration "
                                f"(at most {max_label_offset:g}): results of another scene, rig or world frame")


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
    views: dict = {}
    vis = _visibility(truth, grounds, views)
    check_results_match_truth(pred, gt, views, results, truth, model)
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
