"""The evaluation report: the paper's tables for every method, the error floor and covariance calibration.

``build_report(results_dirs, truth, out)`` scores each results folder (``pedx-graph fit`` / ``baseline``
output) against a simulated dataset and writes ``report.json``, ``report.md`` and figures:

* Table II / III: root-relative / global MPJPE per joint (the paper's 13 joints), one column per method;
* Table IV: the energy-term ablation (runs whose ``fit_config.yaml`` switches match a row of
  :data:`pedx_graph.eval.runs.ABLATION_ROWS`);
* Table V: clean vs detector-like 2D labels (runs whose ``experiment.json`` says ``labels: detector``);
* MPJPE per distance bin, speed (from each run's ``summary.json``), covariance calibration (NEES of the
  keypoints under the marginal covariance at the estimate);
* the error floor: the MPJPE predicted by the graph's marginal covariance evaluated at the ground truth
  (:func:`error_floor`), and each method's ratio to it.

A results folder may carry ``experiment.json`` (``name``, ``label``, ``group``, ``labels``) written by
:mod:`pedx_graph.experiment_runner`; otherwise the name is the folder's, the group ``methods``.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pedx_graph.eval.calibration import calibration
from pedx_graph.eval.floor import error_floor, frame_visibility
from pedx_graph.eval.metrics import eval_joints, eval_visibility, joint_errors
from pedx_graph.eval.runs import ABLATION_ROWS, ablation_row, describe_run
from pedx_graph.eval.tables import (ablation_ordering, ablation_table, calibration_table, distance_table,
                                    floor_ratio_table, ordering_text, pair_table, per_joint_table,
                                    render_markdown, robust_table, speed_table)
from pedx_graph.utils import atomic_write_json, atomic_write_text

log = logging.getLogger(__name__)



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
    matched = []
    for r in runs:
        if r["labels"] != "clean" or r["kind"] != "fit":
            continue
        # experiment.json names the row (or None: not an ablation run); other folders match by their switches
        row = r["ablation_row"] if "ablation_row" in r else ablation_row(r.get("terms"))
        if row is not None:
            matched.append((int(row), r))
    shared = {n for n, _ in matched if sum(m == n for m, _ in matched) > 1}
    ablation = [(n, ABLATION_ROWS[n - 1].label + (f" ({r['name']})" if n in shared else ""), r["terms"], r["eval"])
                for n, r in matched]                     # runs sharing a row keep their own names
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


def no_truth_sections(results_dirs, out: Path, config: "ReportConfig", model,
                      pictures_wanted: bool = True) -> tuple[dict, dict, list[str]]:
    """Per results folder: the :func:`~pedx_graph.eval.results_summary.summarise_results` record, its markdown
    tables (keys ``results_<name>_<table>``) and, with ``config.figures``, the top views of each track and one
    overlay per camera written by the export (``out/export/<name>/``; links relative to ``out``)."""
    from pedx_graph.eval.results_summary import results_tables, summarise_results

    stats, tables, pictures = {}, {}, []
    for path in results_dirs:
        path = Path(path)
        if not (path / "summary.json").is_file():
            continue
        record = summarise_results(path)
        stats[path.name] = record
        for key, text in results_tables(record).items():
            tables[f"results_{path.name}_{key}"] = text
        if config.figures and pictures_wanted and (path / "fit_config.yaml").is_file():
            from pedx_graph.export.run import ExportConfig, export_results

            target = out / "export" / path.name
            try:
                export_results(path, target, None, ExportConfig(meshes=False, animations=False,
                                                                overlay_every=10 ** 6, overlay_scale=0.5), model)
            except (OSError, ValueError) as exc:       # pictures are optional: say why they are missing
                log.warning("%s: no pictures: %s", path, exc)
                continue
            pictures += sorted(str(p.relative_to(out)) for p in target.rglob("*.png"))
            pictures += sorted(str(p.relative_to(out)) for p in target.rglob("*.jpg"))
    return stats, tables, pictures


def build_report(results_dirs, truth: str | os.PathLike | None, out: str | os.PathLike,
                 config: ReportConfig | None = None, model=None, preamble: str = "",
                 figure_prefix: str = "figures") -> dict:
    """Write ``report.json``, ``report.md`` and figures (``out/figures/*.png``) into ``out`` for
    ``results_dirs``: always what the results say about themselves (:func:`no_truth_sections`: residuals,
    covariances per distance, per-track diagnostics, pictures); with ``truth`` (a simulated dataset) also the
    accuracy tables, the error floor and the covariance calibration.  Returns the report dict."""
    from pedx_graph.body import BodyModel

    config = config or ReportConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model = model or BodyModel.load()
    if truth is None:                        # every run reports on itself, with pictures
        stats, result_tables, pictures = no_truth_sections(results_dirs, out, config, model)
    else:                                    # the first fit run only (the accuracy tables cover the rest)
        first_fit = [p for p in results_dirs if (Path(p) / "fit_config.yaml").is_file()][:1]
        stats, result_tables, pictures = no_truth_sections(first_fit, out, config, model, pictures_wanted=False)
    if truth is None:
        report = {"tables": result_tables, "results": stats, "truth": None, "pictures": pictures,
                  "runs": [describe_run(p) for p in results_dirs], "figures": []}
        atomic_write_json(out / "report.json", report)
        atomic_write_text(out / "report.md", render_markdown(report, preamble=preamble))
        return report
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
    report["tables"].update(result_tables)
    report["results"] = stats
    report["pictures"] = pictures
    atomic_write_json(out / "report.json", report)
    atomic_write_text(out / "report.md", render_markdown(report, preamble=preamble))
    return report
