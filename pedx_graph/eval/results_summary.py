"""What a results folder says about itself, without ground truth: residuals, covariances, diagnostics.

:func:`summarise_results` reads a fit's ``summary.json`` and ``labels/3d/smpl`` and returns: per residual term
the chi-square per row summed over tracks; the median keypoint and translation standard deviation (from the
marginal covariances ``cov_keypoints_3d`` / ``cov_trans``: ``sqrt(trace / 3)``, mm) per distance bin (distance
of ``trans`` from the sensor in the level frame of the sequence's derived ground; bins without frames left
out); per track the final error, iterations, mesh checks, depth sources, consistency, plausibility and the
stretches the import listed to check who is who (``identity_review``, detector input only).
:func:`results_tables` renders it as markdown.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from pedx_graph.data.ground import GroundFrame
from pedx_graph.eval.metrics import DISTANCE_BINS, distance_bin


def _sd_mm(cov) -> float | None:
    """``sqrt(trace(cov) / 3)`` of a 3x3 covariance (m^2) in mm, or None."""
    try:
        c = np.asarray(cov, dtype=float)
    except (TypeError, ValueError):
        return None
    if c.shape != (3, 3) or not np.all(np.isfinite(c)):
        return None
    return 1000.0 * float(np.sqrt(max(np.trace(c), 0.0) / 3.0))


def summarise_results(results: str | os.PathLike) -> dict:
    """The no-truth summary of one results folder (module docstring)."""
    from pedx_graph.data.reader import read_smpl_labels

    results = Path(results)
    summary_path = results / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    grounds = {seq: GroundFrame.from_dict(g) for seq, g in (summary.get("ground") or {}).items()}
    labels = read_smpl_labels(results)
    bins = {f"{lo:g}-{hi:g}": {"frames": 0, "keypoint_sd_mm": [], "trans_sd_mm": []} for lo, hi in DISTANCE_BINS}
    status: dict[str, int] = {}
    consistent = frames = 0
    for (seq, _), labs in labels.items():
        ground = grounds.get(seq)
        for lab in labs:
            frames += 1
            status[str(lab.extra.get("covariance_status", "none"))] = \
                status.get(str(lab.extra.get("covariance_status", "none")), 0) + 1
            consistent += bool(lab.extra.get("fit_consistent", False))
            if ground is None:
                continue
            key = distance_bin(float(ground.horizontal_distance(np.asarray(lab.trans, float))), DISTANCE_BINS)
            if key not in bins:
                continue
            bins[key]["frames"] += 1
            kp = lab.extra.get("cov_keypoints_3d")
            if kp is not None:
                sds = [_sd_mm(c) for c in kp]
                bins[key]["keypoint_sd_mm"].extend(v for v in sds if v is not None)
            sd = _sd_mm(lab.extra.get("cov_trans"))
            if sd is not None:
                bins[key]["trans_sd_mm"].append(sd)
    per_distance = {k: {"frames": b["frames"],
                        "keypoint_sd_median_mm": float(np.median(b["keypoint_sd_mm"])) if b["keypoint_sd_mm"] else None,
                        "trans_sd_median_mm": float(np.median(b["trans_sd_mm"])) if b["trans_sd_mm"] else None}
                    for k, b in bins.items() if b["frames"]}
    residuals: dict[str, dict] = {}
    tracks = []
    for t in summary.get("tracks", []):
        diag = t.get("diagnostics") or {}
        for term, r in (diag.get("residuals") or {}).items():
            acc = residuals.setdefault(term, {"chi2": 0.0, "rows": 0, "outlier_rows": 0})
            acc["chi2"] += float(r.get("chi2") or 0.0)
            acc["rows"] += int(r.get("rows") or 0)
            acc["outlier_rows"] += int(r.get("outlier_rows") or 0)
        plaus = t.get("plausibility") or {}
        tracks.append({"sequence": t.get("sequence"), "tracking_id": t.get("tracking_id"),
                       "frames": t.get("frames"), "final_error": t.get("final_error"),
                       "iterations": t.get("iterations"), "mesh_closed": t.get("mesh_closed"),
                       "inside_out_frames": t.get("inside_out_frames"),
                       "inconsistent_frames": diag.get("inconsistent_frames"),
                       "depth_sources": t.get("depth_sources"), "monocular": t.get("monocular"),
                       "max_distance_m": plaus.get("max_distance_m"), "max_abs_beta": plaus.get("max_abs_beta"),
                       "outlier_fraction": plaus.get("outlier_fraction"),
                       "identity_review": t.get("identity_review") or []})
    for acc in residuals.values():
        acc["chi2_per_row"] = acc["chi2"] / acc["rows"] if acc["rows"] else None
    return {"path": str(results), "name": results.name, "tracks": tracks, "frames": frames,
            "failed": len(summary.get("failed", [])), "covariance_status": status,
            "consistent_fraction": consistent / frames if frames else None, "residuals": residuals,
            "per_distance": per_distance}


def _f(value, digits: int = 1) -> str:
    return "-" if value is None or (isinstance(value, float) and not np.isfinite(value)) else f"{value:.{digits}f}"


def results_tables(stats: dict) -> dict[str, str]:
    """Markdown tables of :func:`summarise_results`: ``residuals``, ``uncertainty`` and ``tracks``."""
    res = ["| term | rows | chi2 / row | robust-loss outlier rows |", "|---|---:|---:|---:|"]
    for term, r in stats["residuals"].items():
        res.append(f"| {term} | {r['rows']} | {_f(r['chi2_per_row'], 2)} | {r['outlier_rows']} |")
    unc = ["| distance | frames | median keypoint SD (mm) | median translation SD (mm) |", "|---|---:|---:|---:|"]
    for key, b in stats["per_distance"].items():
        unc.append(f"| {key} m | {b['frames']} | {_f(b['keypoint_sd_median_mm'])} | {_f(b['trans_sd_median_mm'])} |")
    trk = ["| track | frames | final error | iterations | mesh closed | inside-out frames | inconsistent frames | "
           "depth sources | max distance (m) | max abs beta | check who is who (frames, other track) |",
           "|---|---:|---:|---:|:---:|---:|---:|---|---:|---:|---|"]
    for t in stats["tracks"]:
        depth = ", ".join(f"{k} {v}" for k, v in (t["depth_sources"] or {}).items()) or "-"
        tid = str(t["tracking_id"])                     # a release's 32-hex id shortened, an import's kept
        trk.append(f"| {t['sequence']} {tid if len(tid) <= 12 else tid[:8]} | {t['frames']} | {_f(t['final_error'])} | "
                   f"{t['iterations'] if t['iterations'] is not None else '-'} | "
                   f"{'yes' if t['mesh_closed'] else 'no'} | {t['inside_out_frames'] if t['inside_out_frames'] is not None else '-'} | "
                   f"{t['inconsistent_frames'] if t['inconsistent_frames'] is not None else '-'} | {depth} | "
                   f"{_f(t['max_distance_m'])} | {_f(t['max_abs_beta'], 2)} | "
                   + ("; ".join(f"{r['first_frame']}-{r['last_frame']} ({r['other']})" for r in t["identity_review"])
                      or "-") + " |")
    return {"residuals": "\n".join(res) + "\n", "uncertainty": "\n".join(unc) + "\n", "tracks": "\n".join(trk) + "\n"}
