"""The evaluation report: the paper's tables for every method, the error floor and covariance calibration.

``build_report(results_dirs, truth, out)`` scores each results folder (``pedx-graph fit`` / ``baseline``
output) against a simulated dataset and writes ``report.json``, ``report.md`` and figures:

* Table II / III: root-relative / global MPJPE per joint (the paper's 13 joints), one column per method;
* Table IV: the energy-term ablation (runs whose ``fit_config.yaml`` switches match a row of
  :data:`pedx_graph.eval.experiments.ABLATION_ROWS`);
* Table V: clean vs detector-like 2D labels (runs whose ``experiment.json`` says ``labels: detector``);
* MPJPE per distance bin, speed (from each run's ``summary.json``), covariance calibration (NEES of the
  keypoints under the marginal covariance at the estimate);
* the error floor: the MPJPE predicted by the graph's marginal covariance evaluated at the ground truth
  (:func:`error_floor`), and each method's ratio to it.

A results folder may carry ``experiment.json`` (``name``, ``label``, ``group``, ``labels``) written by
:mod:`pedx_graph.eval.experiments`; otherwise the name is the folder's, the group ``methods``.
"""
from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pedx_graph.eval.metrics import (DISTANCE_BINS, distance_bin, eval_joints, eval_visibility, joint_errors,
                                     summarise)
from pedx_graph.keypoints import EVAL_JOINTS, PEDX_KEYPOINTS
from pedx_graph.utils import atomic_write_json, atomic_write_text

log = logging.getLogger(__name__)

#: chi-square(3) quantile at 0.95 (the 95 % ellipsoid of a 3D keypoint).
CHI2_3_95 = 7.814727903251178
#: Confidence levels of the calibration curve.
CALIBRATION_LEVELS = tuple(round(0.05 * i, 2) for i in range(1, 20))
_IDX = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}


@dataclass
class ReportConfig:
    """What the report computes besides the accuracy tables."""

    floor: bool = True
    """Compute the error floor (marginal covariance at the ground truth)."""
    floor_samples: int = 64
    """Monte Carlo samples per frame of the floor (root-relative needs the similarity alignment)."""
    calibration: bool = True
    """Covariance calibration of our runs (from ``cov_keypoints_3d`` or recomputed at the estimate)."""
    figures: bool = True
    """Write the PNG figures."""
    seed: int = 0
    """Seed of the floor's Monte Carlo samples."""


# --- runs ------------------------------------------------------------------------------------------------

def describe_run(path: str | os.PathLike) -> dict:
    """Name, label, group, label source and (for our fits) the energy-term switches of a results folder."""
    path = Path(path)
    info = {"path": str(path), "name": path.name, "label": path.name, "group": "methods", "labels": "clean",
            "kind": "unknown", "terms": None}
    summary_path = path / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    if summary.get("baseline"):
        info.update(kind="baseline", label=summary["baseline"])
    if (path / "fit_config.yaml").is_file():
        from pedx_graph.config import load_config
        from pedx_graph.graph.config import FitConfig

        cfg = load_config(FitConfig, path / "fit_config.yaml")
        info.update(kind="fit", terms=dict(vars(cfg.terms)))
    exp = path / "experiment.json"
    if exp.is_file():
        info.update(json.loads(exp.read_text()))
    # times and the executor live in the summary's timings / execution sections (older summaries: top level)
    timings, execution = summary.get("timings") or summary, summary.get("execution") or summary
    info["summary"] = {"wall_seconds": timings.get("wall_seconds"), "total_frames": summary.get("total_frames"),
                       "workers": execution.get("workers") or execution.get("cluster")}
    info["summary"]["tracks"] = len(summary.get("tracks", []))
    info["summary"]["failed"] = len(summary.get("failed", []))
    seconds = [t.get("seconds") for t in timings.get("tracks", []) if t.get("seconds") is not None]
    info["summary"]["track_seconds_sum"] = float(np.sum(seconds)) if seconds else None
    info["summary"]["track_seconds_median"] = float(np.median(seconds)) if seconds else None
    return info


def ablation_row(terms: dict | None) -> int | None:
    """Index (1-based) of the ablation row whose switches equal ``terms``, else None."""
    from pedx_graph.eval.experiments import ABLATION_ROWS

    if not terms:
        return None
    for i, row in enumerate(ABLATION_ROWS, start=1):
        if all(bool(terms.get(k)) == v for k, v in row.terms.items()):
            return i
    return None


# --- per-frame errors ----------------------------------------------------------------------------------

def frame_visibility(track_frame) -> np.ndarray:
    """(18,) bool: labelled visible in the left or the right image (as :mod:`pedx_graph.eval.evaluate`)."""
    vis = np.zeros(len(PEDX_KEYPOINTS), dtype=bool)
    for view in (track_frame.left, track_frame.right):
        if view is not None:
            vis |= np.asarray(view.visible, dtype=bool) & view.labelled
    return vis


def eval_jacobian(full: np.ndarray) -> np.ndarray:
    """(..., 18, 3, D) keypoint Jacobians -> (..., 13, 3, D) of the evaluated joints (hip = mid-hips)."""
    out = []
    for name in EVAL_JOINTS:
        if name == "hip":
            out.append(0.5 * (full[..., _IDX["lhip"], :, :] + full[..., _IDX["rhip"], :, :]))
        else:
            out.append(full[..., _IDX[name], :, :])
    return np.stack(out, axis=-3)


def expected_errors(cov13: np.ndarray, truth13: np.ndarray, samples: int,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Expected per-joint errors (13,) in metres, (global, root-relative), of an estimate distributed as
    ``truth13 + N(0, cov13)``: ``E ||delta_j||`` and the root-relative error after the similarity alignment,
    by Monte Carlo with ``samples`` draws.  ``cov13`` (39, 39), ``truth13`` (13, 3)."""
    n = truth13.size
    cov = 0.5 * (cov13 + cov13.T)
    w, v = np.linalg.eigh(cov)
    root = v * np.sqrt(np.clip(w, 0.0, None))
    delta = (rng.normal(size=(samples, n)) @ root.T).reshape(samples, *truth13.shape)
    glob, rel = joint_errors(truth13[None] + delta, np.broadcast_to(truth13, delta.shape))
    return glob.mean(axis=0), rel.mean(axis=0)


# --- error floor ---------------------------------------------------------------------------------------

def floor_fit_config(truth: str | os.PathLike, base=None):
    """The fit config of the floor: the estimator's terms with the simulator's noise (read from
    ``sim_config.yaml`` when present: 2D click noise, LiDAR range noise), Gaussian losses, no hip inflation."""
    import copy

    import yaml

    from pedx_graph.graph.config import FitConfig

    config = copy.deepcopy(base) if base is not None else FitConfig()
    sim_path = Path(truth) / "sim_config.yaml"
    labels, lidar = {}, {}
    if sim_path.is_file():
        data = yaml.safe_load(sim_path.read_text()) or {}
        labels, lidar = data.get("labels", {}), data.get("lidar", {})
    config.noise.keypoint_sigma_px = float(labels.get("visible_noise_px", 2.0))
    config.noise.occluded_keypoint_sigma_px = float(labels.get("occluded_noise_px", 8.0))
    config.noise.lidar_sigma_m = max(float(lidar.get("range_noise_m", 0.02)), 1e-3)
    config.noise.hip_sigma_factor = 1.0
    config.noise.reprojection_loss = "none"
    config.noise.lidar_loss = "none"
    return config


def _true_person_points(truth_root: Path, track, frame_index: int) -> np.ndarray:
    """The frame's segment points restricted to those really on the person (simulator truth), if known."""
    fr = track.frames[frame_index]
    path = truth_root / "truth" / track.sequence / f"{track.sequence}_{fr.frame:07d}.npz"
    if not path.is_file():
        return fr.world_lidar_points
    with np.load(path) as npz:
        key = f"segment_is_person__{track.tracking_id}"
        if key not in npz.files:
            return fr.world_lidar_points
        mask = np.asarray(npz[key], dtype=bool)
    if len(mask) != len(fr.world_lidar_points):
        return fr.world_lidar_points
    return fr.world_lidar_points[mask]


def smpl_values(keys, labels):
    """gtsam Values holding the SMPL parameters of ``labels`` (one per frame, same order as ``keys``):
    ``world_R_body = Exp(pose[:3])``, ``trans``, ``body_pose = pose[3:]``, the first label's ``betas``."""
    import gtsam

    values = gtsam.Values()
    values.insert(keys[0].betas, np.asarray(labels[0].betas, dtype=float))
    for k, lab in zip(keys, labels):
        values.insert(k.root, gtsam.Rot3.Expmap(np.asarray(lab.pose[:3], dtype=float)))
        values.insert(k.trans, np.asarray(lab.trans, dtype=float))
        values.insert(k.body_pose, np.asarray(lab.pose[3:], dtype=float))
    return values


def error_floor(truth: str | os.PathLike, fit_config=None, samples: int = 64, seed: int = 0,
                exact_segments: bool = True) -> dict:
    """Predicted MPJPE of an estimator with the graph's information at the ground truth.

    For every track of ``truth`` (a simulated dataset): the track's graph (:func:`floor_fit_config`:
    simulator noise, Gaussian losses; the LiDAR points restricted to the person's own points when
    ``exact_segments``) is linearised at the ground-truth values; the chain marginals give each frame's
    joint covariance ``Sigma_i`` (75 + B); the evaluated joints' covariance is ``J Sigma_i J^T`` (39, 39)
    with ``J`` the joints' Jacobian; the expected global and root-relative errors per joint follow by
    Monte Carlo (:func:`expected_errors`).  Frames whose information needed the diffuse regulariser
    (not observable) are left out and counted.  Returns the :func:`summarise` dict plus ``excluded_frames``.
    """
    import dataclasses

    from pedx_graph.data.reader import read_dataset, read_smpl_labels
    from pedx_graph.graph.build import EstimatorContext, build_track_graph
    from pedx_graph.solvers.marginals import compute_marginals

    truth_root = Path(truth)
    config = fit_config or floor_fit_config(truth_root)
    ctx = EstimatorContext.create(config)
    gt = read_smpl_labels(truth_root)
    rng = np.random.default_rng(seed)
    glob_all, rel_all, w_all, dist_all = [], [], [], []
    excluded = 0
    for track in read_dataset(truth_root):
        by_frame = {lab.frame: lab for lab in gt.get((track.sequence, track.tracking_id), [])}
        keep = [i for i, fr in enumerate(track.frames) if fr.frame in by_frame]
        if not keep:
            continue
        frames = [track.frames[i] for i in keep]
        if exact_segments:
            frames = [dataclasses.replace(fr, world_lidar_points=_true_person_points(truth_root, track, i))
                      for i, fr in zip(keep, frames)]
        sub = dataclasses.replace(track, frames=frames)
        labels = [by_frame[fr.frame] for fr in frames]
        problem = build_track_graph(sub, ctx, config)
        values = smpl_values(problem.keys, labels)
        problem.prefetch(values, True)
        marg = compute_marginals(problem.graph, values, problem.keys)
        pose = np.stack([lab.pose for lab in labels])
        trans = np.stack([lab.trans for lab in labels])
        betas = np.broadcast_to(np.asarray(labels[0].betas, float), (len(labels), len(labels[0].betas)))
        jac = ctx.model.point_jacobians(pose, betas, trans)
        full = np.concatenate([np.asarray(jac.d_root), np.asarray(jac.d_trans), np.asarray(jac.d_body_pose),
                               np.asarray(jac.d_betas)], axis=-1)                  # (T, 18, 3, 75 + B)
        j13 = eval_jacobian(full).reshape(len(labels), 39, -1)
        truth13 = eval_joints(np.asarray(jac.points))
        for i, fr in enumerate(frames):
            if marg.regularised[i]:
                excluded += 1
                continue
            cov13 = j13[i] @ marg.frame_covariances[i] @ j13[i].T
            g, r = expected_errors(cov13, truth13[i], samples, rng)
            glob_all.append(g)
            rel_all.append(r)
            w_all.append(eval_visibility(frame_visibility(fr)))
            pelvis = truth13[i][EVAL_JOINTS.index("hip")]
            dist_all.append(float(track.ground.horizontal_distance(pelvis)))
    if not glob_all:
        raise ValueError(f"{truth}: no frame with ground truth for the error floor")
    out = summarise(np.array(glob_all), np.array(rel_all), np.array(w_all), np.array(dist_all))
    out["excluded_frames"] = excluded
    out["samples_per_frame"] = samples
    out["noise"] = {"keypoint_sigma_px": config.noise.keypoint_sigma_px,
                    "occluded_keypoint_sigma_px": config.noise.occluded_keypoint_sigma_px,
                    "lidar_sigma_m": config.noise.lidar_sigma_m, "exact_segments": exact_segments}
    return out


# --- calibration ---------------------------------------------------------------------------------------

def _nees(err: np.ndarray, cov: np.ndarray) -> np.ndarray:
    return np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[..., None])[..., 0])


def run_covariances(results: str | os.PathLike, truth: str | os.PathLike) -> dict:
    """Per-frame keypoint covariances (18, 3, 3) of a fit run: ``cov_keypoints_3d`` from the results when
    present, else recomputed at the estimate (the run's ``fit_config.yaml``; chain marginals).  Returns
    ``{(sequence, tracking_id, frame): (18, 3, 3) or None}``."""
    from pedx_graph.config import load_config
    from pedx_graph.data.reader import read_dataset, read_smpl_labels
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
        problem = build_track_graph(track, ctx, config)
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


# --- tables --------------------------------------------------------------------------------------------

def _fmt(value, digits: int = 1) -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}"


def per_joint_table(summaries: dict[str, dict], metric: str, floor: dict | None = None) -> str:
    """Markdown: joints as rows, methods as columns (MPJPE mm of ``metric``: ``global_mm`` or
    ``root_relative_mm``), the visibility-weighted mean last; a floor column when given."""
    names = list(summaries)
    head = "| joint | " + " | ".join(names) + (" | floor |" if floor else " |")
    lines = [head, "|---|" + "---:|" * (len(names) + (1 if floor else 0))]
    for joint in EVAL_JOINTS:
        cells = [_fmt(summaries[n]["per_joint"][joint][metric]) for n in names]
        if floor:
            cells.append(_fmt(floor["per_joint"][joint][metric]))
        lines.append(f"| {joint} | " + " | ".join(cells) + " |")
    cells = [_fmt(summaries[n]["overall"][metric]) for n in names]
    if floor:
        cells.append(_fmt(floor["overall"][metric]))
    lines.append("| **mean** | " + " | ".join(f"**{c}**" for c in cells) + " |")
    return "\n".join(lines) + "\n"


def distance_table(summaries: dict[str, dict], floor: dict | None = None) -> str:
    """Markdown: methods as rows, distance bins as columns, ``global / root-relative`` MPJPE (mm) per cell."""
    bins = [f"{lo:g}-{hi:g}" for lo, hi in DISTANCE_BINS]
    rows = dict(summaries)
    if floor:
        rows["floor"] = floor
    lines = ["| method | " + " | ".join(f"{b} m" for b in bins) + " |", "|---|" + "---:|" * len(bins)]
    first = next(iter(summaries.values()))
    lines.append("| frames | " + " | ".join(str(first["per_distance"][b]["frames"]) for b in bins) + " |")
    for name, s in rows.items():
        cells = [f"{_fmt(s['per_distance'][b]['global_mm'])} / {_fmt(s['per_distance'][b]['root_relative_mm'])}"
                 for b in bins]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def floor_ratio_table(summaries: dict[str, dict], floor: dict) -> str:
    """Markdown: each method's MPJPE divided by the floor's, overall and per distance bin (global / rel)."""
    bins = [f"{lo:g}-{hi:g}" for lo, hi in DISTANCE_BINS]
    lines = ["| method | overall | " + " | ".join(f"{b} m" for b in bins) + " |",
             "|---|---:|" + "---:|" * len(bins)]

    def ratio(a, b):
        return a / b if (a is not None and b and np.isfinite(a) and np.isfinite(b)) else float("nan")

    for name, s in summaries.items():
        cells = [f"{_fmt(ratio(s['overall']['global_mm'], floor['overall']['global_mm']))} / "
                 f"{_fmt(ratio(s['overall']['root_relative_mm'], floor['overall']['root_relative_mm']))}"]
        for b in bins:
            mine, low = s["per_distance"][b], floor["per_distance"][b]
            cells.append(f"{_fmt(ratio(mine['global_mm'], low['global_mm']))} / "
                         f"{_fmt(ratio(mine['root_relative_mm'], low['root_relative_mm']))}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def ablation_table(rows: list[tuple[int, str, dict, dict]]) -> str:
    """Markdown of Table IV: ``rows`` = (row number, label, terms, summary) in row order."""
    from pedx_graph.eval.experiments import ABLATION_TERM_SYMBOLS

    symbols = list(ABLATION_TERM_SYMBOLS.items())
    lines = ["| row | " + " | ".join(sym for _, sym in symbols) + " | global | root-relative | " + _ROBUST_HEAD,
             "|---|" + ":---:|" * len(symbols) + "---:|---:|---:|---:|---:|"]
    for number, label, terms, s in rows:
        marks = " | ".join("x" if terms.get(field) else "" for field, _ in symbols)
        lines.append(f"| {number}: {label} | {marks} | {_fmt(s['overall']['global_mm'])} | "
                     f"{_fmt(s['overall']['root_relative_mm'])} | {_robust_cells(s)} |")
    return "\n".join(lines) + "\n"


_ROBUST_HEAD = "median frame, global | median frame, root-rel. | frames > 0.5 m |"


def _robust_cells(summary: dict) -> str:
    rb = summary.get("robust") or {}
    rate = rb.get("gross_failure_rate")
    return (f"{_fmt(rb.get('global_median_mm'))} | {_fmt(rb.get('root_relative_median_mm'))} | "
            f"{_fmt(None if rate is None else 100 * rate)} %")


def robust_table(summaries: dict[str, dict]) -> str:
    """Markdown: mean vs per-frame median MPJPE and the gross-failure rate of each method."""
    lines = ["| method | global mean | root-rel. mean | " + _ROBUST_HEAD, "|---|---:|---:|---:|---:|---:|"]
    for name, s in summaries.items():
        lines.append(f"| {name} | {_fmt(s['overall']['global_mm'])} | {_fmt(s['overall']['root_relative_mm'])} | "
                     f"{_robust_cells(s)} |")
    return "\n".join(lines) + "\n"


#: The paper's ordering claim as (without, with, what is added) ablation rows.
ORDERING_STEPS = ((1, 2, "stereo (right image)"), (2, 3, "LiDAR translation"), (3, 4, "3D distance (chamfer)"),
                  (4, 5, "temporal prior"), (6, 5, "right image, given LiDAR and temporal terms"))


def ablation_ordering(rows: list[tuple[int, str, dict, dict]]) -> list[dict]:
    """For each step of :data:`ORDERING_STEPS` present in ``rows``: the MPJPE change (mm, with - without;
    negative = the term helps), global and root-relative."""
    by_row = {n: s for n, _, _, s in rows}
    out = []
    for without, with_, what in ORDERING_STEPS:
        if without in by_row and with_ in by_row:
            a, b = by_row[without]["overall"], by_row[with_]["overall"]
            step = {"from_row": without, "to_row": with_, "adds": what,
                    "global_change_mm": b["global_mm"] - a["global_mm"],
                    "root_relative_change_mm": b["root_relative_mm"] - a["root_relative_mm"]}
            ra, rb = by_row[without].get("robust") or {}, by_row[with_].get("robust") or {}
            if "global_median_mm" in ra and "global_median_mm" in rb:
                step["global_median_change_mm"] = rb["global_median_mm"] - ra["global_median_mm"]
                step["root_relative_median_change_mm"] = rb["root_relative_median_mm"] - ra["root_relative_median_mm"]
            out.append(step)
    return out


def ordering_text(steps: list[dict]) -> str:
    """Markdown list: whether each added term lowered the global / root-relative MPJPE."""
    lines = []
    for st in steps:
        verdict = lambda d: "helps" if d < 0 else "does not help"  # noqa: E731
        text = (f"- row {st['from_row']} -> {st['to_row']}, adding {st['adds']}: mean global "
                f"{st['global_change_mm']:+.1f} mm ({verdict(st['global_change_mm'])}), root-relative "
                f"{st['root_relative_change_mm']:+.1f} mm ({verdict(st['root_relative_change_mm'])})")
        if "global_median_change_mm" in st:
            text += (f"; per-frame median global {st['global_median_change_mm']:+.1f} mm "
                     f"({verdict(st['global_median_change_mm'])}), root-relative "
                     f"{st['root_relative_median_change_mm']:+.1f} mm "
                     f"({verdict(st['root_relative_median_change_mm'])})")
        lines.append(text)
    return "\n".join(lines) + ("\n" if lines else "")


def pair_table(pairs: list[tuple[str, dict, dict]]) -> str:
    """Markdown of Table V: (method, clean summary, noisy summary) -> global and root-relative, both label sets."""
    lines = ["| method | labels | global mean | root-rel. mean | " + _ROBUST_HEAD, "|---|---|---:|---:|---:|---:|---:|"]
    for name, clean, noisy in pairs:
        for which, s in (("annotator", clean), ("detector", noisy)):
            lines.append(f"| {name} | {which} | {_fmt(s['overall']['global_mm'])} | "
                         f"{_fmt(s['overall']['root_relative_mm'])} | {_robust_cells(s)} |")
    return "\n".join(lines) + "\n"


def speed_table(runs: list[dict]) -> str:
    """Markdown: wall time, frames, workers and per-frame single-process time of each run."""
    lines = ["| run | tracks (failed) | frames | workers | wall s | process s per frame | median s per track |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for r in runs:
        s = r["summary"]
        per_frame = (s["track_seconds_sum"] / s["total_frames"]
                     if s.get("track_seconds_sum") and s.get("total_frames") else None)
        lines.append(f"| {r['name']} | {s['tracks']} ({s['failed']}) | {s.get('total_frames') or '-'} | "
                     f"{s.get('workers') or '-'} | {_fmt(s.get('wall_seconds'))} | {_fmt(per_frame, 3)} | "
                     f"{_fmt(s.get('track_seconds_median'), 2)} |")
    return "\n".join(lines) + "\n"


def calibration_table(cal: dict) -> str:
    """Markdown: NEES / dof and 95 % coverage overall, visible/occluded and per distance bin."""
    lines = ["| keypoints | n | mean NEES/3 | median NEES/3 | inside 95 % ellipsoid |", "|---|---:|---:|---:|---:|"]
    rows = [("all", cal["overall"]), ("visible", cal["visible"]), ("occluded", cal["occluded"])]
    rows += [(f"{k} m", v) for k, v in cal["per_distance"].items()]
    for name, s in rows:
        lines.append(f"| {name} | {s['n']} | {_fmt(s['mean_nees_over_dof'], 2)} | "
                     f"{_fmt(s['median_nees_over_dof'], 2)} | {_fmt(100 * s['coverage95'] if s['n'] else None)} % |")
    return "\n".join(lines) + "\n"


# --- the report ----------------------------------------------------------------------------------------

#: A frame whose global MPJPE exceeds this (metres) counts as a gross failure.
GROSS_FAILURE_M = 0.5


def truth_index(truth: str | os.PathLike, model) -> dict:
    """``{(sequence, tracking_id, frame): ((13, 3) true joints, (13,) visibility weights)}`` of a dataset."""
    from pedx_graph.data.reader import read_dataset, read_smpl_labels

    gt = read_smpl_labels(truth)
    vis = {(t.sequence, t.tracking_id, fr.frame): frame_visibility(fr) for t in read_dataset(truth)
           for fr in t.frames}
    out = {}
    for key, labels in gt.items():
        labels = [lab for lab in labels if (key[0], key[1], lab.frame) in vis]
        if not labels:
            continue
        kp = np.asarray(model.keypoints(np.stack([lab.pose for lab in labels]),
                                        np.stack([lab.betas for lab in labels]),
                                        np.stack([lab.trans for lab in labels])))
        for lab, joints in zip(labels, eval_joints(kp)):
            out[(key[0], key[1], lab.frame)] = (joints, eval_visibility(vis[(key[0], key[1], lab.frame)]))
    return out


def robust_stats(results: str | os.PathLike, index: dict) -> dict:
    """Per-frame MPJPE (visibility-weighted over the frame's joints) of a results folder: the median over
    frames (global, root-relative, mm), the fraction of frames whose global MPJPE exceeds
    :data:`GROSS_FAILURE_M` and the median over tracks of the track's mean global MPJPE."""
    from pedx_graph.data.reader import read_smpl_labels

    per_frame_g, per_frame_r, per_track = [], [], []
    for key, labels in read_smpl_labels(results).items():
        track_g = []
        for lab in labels:
            entry = index.get((key[0], key[1], lab.frame))
            if entry is None or "keypoints_3d" not in lab.extra:
                continue
            truth13, weights = entry
            if weights.sum() <= 0:
                continue
            pred13 = eval_joints(np.asarray(lab.extra["keypoints_3d"], dtype=float))
            glob, rel = joint_errors(pred13[None], truth13[None])
            g = float((glob[0] * weights).sum() / weights.sum())
            per_frame_g.append(g)
            per_frame_r.append(float((rel[0] * weights).sum() / weights.sum()))
            track_g.append(g)
        if track_g:
            per_track.append(float(np.mean(track_g)))
    if not per_frame_g:
        return {"frames": 0}
    g, r = np.array(per_frame_g), np.array(per_frame_r)
    return {"frames": int(len(g)), "global_median_mm": 1000 * float(np.median(g)),
            "root_relative_median_mm": 1000 * float(np.median(r)),
            "gross_failure_rate": float(np.mean(g > GROSS_FAILURE_M)),
            "track_median_global_mm": 1000 * float(np.median(per_track))}


def collect_runs(results_dirs, truth, model=None) -> list[dict]:
    """:func:`describe_run` + the :func:`pedx_graph.eval.evaluate.evaluate` summary of every folder, with
    :func:`robust_stats` under ``eval["robust"]``."""
    from pedx_graph.body import BodyModel
    from pedx_graph.eval.evaluate import evaluate

    model = model or BodyModel.load()
    index = truth_index(truth, model)
    runs = []
    for path in results_dirs:
        info = describe_run(path)
        info["eval"] = evaluate(path, truth, model)
        info["eval"]["robust"] = robust_stats(path, index)
        runs.append(info)
    names = [r["name"] for r in runs]
    if len(set(names)) != len(names):
        raise ValueError(f"results folders must have distinct names, got {names}")
    return runs


def assemble(runs: list[dict], floor: dict | None = None, calibrations: dict | None = None) -> dict:
    """All tables as data + markdown from evaluated runs (pure; no file access)."""
    methods = {r["label"]: r["eval"] for r in runs if r["group"] == "methods" and r["labels"] == "clean"}
    ablation = []
    for r in runs:
        if r["labels"] != "clean" or r["kind"] != "fit":
            continue
        row = r.get("ablation_row") or ablation_row(r.get("terms"))
        if row is not None:
            from pedx_graph.eval.experiments import ABLATION_ROWS
            ablation.append((int(row), ABLATION_ROWS[int(row) - 1].label, r["terms"], r["eval"]))
    ablation.sort(key=lambda t: t[0])
    noisy = []
    clean_by_label = {r["label"]: r["eval"] for r in runs if r["labels"] == "clean"}
    for r in runs:
        if r["labels"] == "detector" and r["label"] in clean_by_label:
            noisy.append((r["label"], clean_by_label[r["label"]], r["eval"]))
    tables = {}
    if methods:
        tables["table2_root_relative_per_joint"] = per_joint_table(methods, "root_relative_mm", floor)
        tables["table3_global_per_joint"] = per_joint_table(methods, "global_mm", floor)
        tables["per_distance"] = distance_table(methods, floor)
        if all("robust" in m for m in methods.values()):
            tables["robust"] = robust_table(methods)
        if floor:
            tables["floor_ratio"] = floor_ratio_table(methods, floor)
    ordering = ablation_ordering(ablation)
    if ablation:
        tables["table4_ablation"] = ablation_table(ablation) + ("\n" + ordering_text(ordering) if ordering else "")
    if noisy:
        tables["table5_noisy_labels"] = pair_table(noisy)
    tables["speed"] = speed_table(runs)
    for name, cal in (calibrations or {}).items():
        if cal.get("frames"):
            tables[f"calibration_{name}"] = calibration_table(cal)
    return {"methods": list(methods), "ablation": [{"row": n, "label": lab, "terms": t,
                                                    "global_mm": s["overall"]["global_mm"],
                                                    "root_relative_mm": s["overall"]["root_relative_mm"]}
                                                   for n, lab, t, s in ablation],
            "ablation_ordering": ordering,
            "noisy": [{"method": n, "clean": c["overall"], "detector": d["overall"]} for n, c, d in noisy],
            "tables": tables}


_SECTIONS = (
    ("table2_root_relative_per_joint", "Table II: root-relative MPJPE per joint (mm, after similarity alignment)"),
    ("table3_global_per_joint", "Table III: global MPJPE per joint (mm, world frame, no alignment)"),
    ("table4_ablation", "Table IV: energy-term ablation (our fit; MPJPE mm)"),
    ("table5_noisy_labels", "Table V: annotator vs simulated-detector 2D labels (MPJPE mm)"),
    ("robust", "Mean vs median: gross failures dominate the global mean (mm)"),
    ("per_distance", "MPJPE per distance bin (mm, global / root-relative)"),
    ("floor_ratio", "Ratio to the error floor (global / root-relative)"),
    ("speed", "Speed"),
)


def render_markdown(report: dict, title: str = "pedx-graph evaluation report", preamble: str = "") -> str:
    """The report's markdown: every table with a heading, calibration tables and figure links."""
    lines = [f"# {title}", ""]
    if preamble:
        lines += [preamble.rstrip(), ""]
    tables = report["tables"]
    for key, heading in _SECTIONS:
        if key in tables:
            lines += [f"## {heading}", "", tables[key]]
    for key, text in tables.items():
        if key.startswith("calibration_"):
            lines += [f"## Covariance calibration: {key[len('calibration_'):]}", "",
                      "NEES of the 18 fitted keypoints under their marginal covariances (calibrated: "
                      "mean NEES/3 = 1, 95 % inside the 95 % ellipsoid).", "", text]
    for fig in report.get("figures", []):
        lines += [f"![{Path(fig).stem}]({fig})", ""]
    return "\n".join(lines).rstrip() + "\n"


def build_report(results_dirs, truth: str | os.PathLike, out: str | os.PathLike,
                 config: ReportConfig | None = None, model=None, preamble: str = "",
                 figure_prefix: str = "figures") -> dict:
    """Evaluate ``results_dirs`` against ``truth`` and write ``report.json``, ``report.md`` and figures
    (``out/figures/*.png``) into ``out``.  Returns the report dict."""
    from pedx_graph.body import BodyModel

    config = config or ReportConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model = model or BodyModel.load()
    runs = collect_runs(results_dirs, truth, model)
    floor = None
    if config.floor:
        try:
            floor = error_floor(truth, samples=config.floor_samples, seed=config.seed)
        except Exception as exc:  # a dataset without simulator truth: no floor, say so
            log.warning("error floor not computed: %s", exc)
    calibrations = {}
    if config.calibration:
        for r in runs:
            if r["kind"] == "fit" and r["labels"] == "clean" and r["group"] == "methods":
                calibrations[r["label"]] = calibration(r["path"], truth, model)
    report = assemble(runs, floor, calibrations)
    report["runs"] = [{k: v for k, v in r.items()} for r in runs]
    report["floor"] = floor
    report["calibration"] = calibrations
    report["truth"] = str(truth)
    figures = []
    if config.figures:
        from pedx_graph.eval import plots

        figures = plots.write_figures(report, runs, truth, out / figure_prefix, model)
        figures = [str(Path(figure_prefix) / Path(f).name) for f in figures]
    report["figures"] = figures
    atomic_write_json(out / "report.json", report)
    atomic_write_text(out / "report.md", render_markdown(report, preamble=preamble))
    return report
