"""Covariance calibration of a fit against ground truth: NEES of the keypoints under their marginals.

:func:`calibration` compares each fitted keypoint's error with its 3x3 marginal covariance
(``cov_keypoints_3d``, or recomputed at the estimate by :func:`run_covariances`): mean NEES / 3 and the fraction
inside the 95 % ellipsoid, overall, visible / occluded and per distance bin (calibrated: 1 and 0.95).
"""
from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np

from pedx_graph.eval.floor import frame_visibility, smpl_values
from pedx_graph.eval.metrics import DISTANCE_BINS, distance_bin
from pedx_graph.keypoints import PEDX_KEYPOINTS

log = logging.getLogger(__name__)

#: chi-square(3) quantile at 0.95 (the 95 % ellipsoid of a 3D keypoint).
CHI2_3_95 = 7.814727903251178
#: Confidence levels of the calibration curve.
CALIBRATION_LEVELS = tuple(round(0.05 * i, 2) for i in range(1, 20))
_IDX = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}



def _nees(err: np.ndarray, cov: np.ndarray) -> np.ndarray:
    return np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[..., None])[..., 0])


def run_covariances(results: str | os.PathLike, truth: str | os.PathLike) -> dict:
    """Per-frame keypoint covariances (18, 3, 3) of a fit run: ``cov_keypoints_3d`` from the results when
    present, else recomputed at the estimate (the run's ``fit_config.yaml``; chain marginals).  Returns
    ``{(sequence, tracking_id, frame): (18, 3, 3) or None}``."""
    from pedx_graph.config import load_config
    from pedx_graph.data.reader import read_dataset, read_smpl_labels
    from pedx_graph.detections.fit_layout import fit_layout
    from pedx_graph.graph.build import EstimatorContext, build_track_graph
    from pedx_graph.graph.config import FitConfig
    from pedx_graph.solvers.marginals import compute_marginals, keypoint_covariances_batch

    results = Path(results)
    pred = read_smpl_labels(results)
    out: dict = {}
    missing = []
    for key, labels in pred.items():
        for lab in labels:
            cov = lab.extra.get("cov_keypoints_3d")
            if cov is None:
                if "covariance_status" not in lab.extra:
                    missing.append(key)
                out[(key[0], key[1], lab.frame)] = None
            else:
                out[(key[0], key[1], lab.frame)] = np.asarray(cov, dtype=float)
    if not missing:
        return out
    config = load_config(FitConfig, results / "fit_config.yaml") if (results / "fit_config.yaml").is_file() \
        else FitConfig()
    ctx = EstimatorContext.create(config)
    wanted = set(missing)
    summary_path = results / "summary.json"
    dataset = json.loads(summary_path.read_text()).get("dataset") if summary_path.is_file() else None
    for track in read_dataset(dataset if dataset and Path(dataset).is_dir() else truth):
        key = (track.sequence, track.tracking_id)
        if key not in wanted:
            continue
        by_frame = {lab.frame: lab for lab in pred[key]}
        if any(fr.frame not in by_frame for fr in track.frames):
            continue
        labels = [by_frame[fr.frame] for fr in track.frames]
        laid, laid_ctx, laid_config = fit_layout(track, ctx, config)   # a detector track: its own points
        problem = build_track_graph(laid, laid_ctx, laid_config)
        values = smpl_values(problem.keys, labels)
        problem.prefetch(values, True)
        try:
            marg = compute_marginals(problem.graph, values, problem.keys)
        except Exception as exc:  # reported as missing covariances
            log.warning("%s/%s: marginals failed: %s", *key, exc)
            continue
        pose = np.stack([lab.pose for lab in labels])
        trans = np.stack([lab.trans for lab in labels])
        covs = keypoint_covariances_batch(ctx.model, pose, labels[0].betas, trans, marg.frame_covariances)
        for i, fr in enumerate(track.frames):
            out[(key[0], key[1], fr.frame)] = None if marg.regularised[i] else covs[i]
    return out


def calibration(results: str | os.PathLike, truth: str | os.PathLike, model=None,
                bins: tuple[tuple[float, float], ...] = DISTANCE_BINS) -> dict:
    """NEES of the fitted keypoints under their covariances: per distance bin mean NEES / 3 and the fraction
    inside the 95 % ellipsoid (calibrated: 1 and 0.95), plus the coverage curve over
    :data:`CALIBRATION_LEVELS` (fraction with ``NEES <= chi2_3^-1(p)``) for all and for visible joints."""
    from scipy.stats import chi2

    from pedx_graph.body import BodyModel
    from pedx_graph.data.reader import read_dataset, read_smpl_labels

    model = model or BodyModel.load()
    covs = run_covariances(results, truth)
    pred = read_smpl_labels(results)
    gt = read_smpl_labels(truth)
    vis, grounds = {}, {}
    for track in read_dataset(truth):
        grounds[track.sequence] = track.ground
        for fr in track.frames:
            vis[(track.sequence, track.tracking_id, fr.frame)] = frame_visibility(fr)
    nees_all, vis_all, dist_all = [], [], []
    skipped = 0
    for key, gt_labels in gt.items():
        pred_by = {lab.frame: lab for lab in pred.get(key, [])}
        for g in gt_labels:
            p = pred_by.get(g.frame)
            cov = covs.get((key[0], key[1], g.frame))
            if p is None or (key[0], key[1], g.frame) not in vis:
                continue
            if cov is None:
                skipped += 1
                continue
            true_kp = np.asarray(model.keypoints(g.pose, g.betas, g.trans))
            est = np.asarray(p.extra["keypoints_3d"], float) if "keypoints_3d" in p.extra else \
                np.asarray(model.keypoints(p.pose, p.betas, p.trans))
            nees_all.append(_nees(est - true_kp, cov))
            vis_all.append(vis[(key[0], key[1], g.frame)])
            pelvis = 0.5 * (true_kp[_IDX["lhip"]] + true_kp[_IDX["rhip"]])
            dist_all.append(float(grounds[key[0]].horizontal_distance(pelvis)))
    if not nees_all:
        return {"frames": 0, "skipped_frames": skipped}
    nees_arr, vis_arr, dist = np.array(nees_all), np.array(vis_all), np.array(dist_all)
    thresholds = chi2.ppf(np.array(CALIBRATION_LEVELS), 3)

    def stats(values: np.ndarray) -> dict:
        values = values.reshape(-1)
        if values.size == 0:
            return {"n": 0, "mean_nees_over_dof": float("nan"), "median_nees_over_dof": float("nan"),
                    "coverage95": float("nan")}
        return {"n": int(values.size), "mean_nees_over_dof": float(values.mean() / 3),
                "median_nees_over_dof": float(np.median(values) / 3),
                "coverage95": float(np.mean(values <= CHI2_3_95))}

    labels = np.array([distance_bin(d, bins) for d in dist], dtype=object)
    out = {"frames": int(len(dist)), "skipped_frames": skipped, "overall": stats(nees_arr),
           "visible": stats(nees_arr[vis_arr]), "occluded": stats(nees_arr[~vis_arr]), "per_distance": {},
           "curve": {"levels": list(CALIBRATION_LEVELS),
                     "all": [float(np.mean(nees_arr <= t)) for t in thresholds],
                     "visible": [float(np.mean(nees_arr[vis_arr] <= t)) for t in thresholds]}}
    for lo, hi in bins:
        key = f"{lo:g}-{hi:g}"
        out["per_distance"][key] = stats(nees_arr[labels == key])
    return out
