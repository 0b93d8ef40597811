"""What a results folder is: its name, label, group and energy-term switches, and the ablation rows.

A results folder may carry ``experiment.json`` (``name``, ``label``, ``group``, ``labels``, ``ablation_row``)
written by :mod:`pedx_graph.experiment_runner`; otherwise the name is the folder's, the group ``methods``.
Table IV rows (:data:`ABLATION_ROWS`): the pose and shape priors and the joint limits stay on in every row;
the heading prior E_D comes from the LiDAR trajectory, so it is switched with E_T.  Both the experiment (which
runs the rows) and the report (which tabulates them) read them here.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np


#: Symbols of the switches shown in Table IV, in column order (TermsConfig field -> paper symbol).
ABLATION_TERM_SYMBOLS = {"left_reprojection": "E_J,l", "right_reprojection": "E_J,r",
                         "translation_prior": "E_T (+E_D)", "lidar_chamfer": "E_3d", "temporal_prior": "E_tp"}


@dataclass(frozen=True)
class AblationRow:
    """One row of Table IV: a label and the energy-term switches (``TermsConfig`` fields)."""

    label: str
    terms: dict

    def fit_terms(self) -> dict:
        """All ``TermsConfig`` switches of the row (heading follows the translation prior; priors on; a row
        without the right image uses the primary pair's left camera only, not another pair's too)."""
        return {**self.terms, "heading_prior": self.terms["translation_prior"], "pose_prior": True,
                "all_views": self.terms["right_reprojection"]}


def _row(label: str, left: bool, right: bool, trans: bool, chamfer: bool, temporal: bool) -> AblationRow:
    return AblationRow(label, {"left_reprojection": left, "right_reprojection": right, "translation_prior": trans,
                               "lidar_chamfer": chamfer, "temporal_prior": temporal})


#: Table IV rows, cumulative as the paper's ordering claim (stereo, LiDAR translation, 3D distance, temporal
#: each help), plus the full estimator without the right image.
ABLATION_ROWS: tuple[AblationRow, ...] = (
    _row("left image", True, False, False, False, False),
    _row("stereo", True, True, False, False, False),
    _row("stereo + LiDAR translation", True, True, True, False, False),
    _row("stereo + LiDAR translation + 3D distance", True, True, True, True, False),
    _row("full (+ temporal)", True, True, True, True, True),
    _row("full without the right image", True, False, True, True, True),
)



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
    if not terms:
        return None
    for i, row in enumerate(ABLATION_ROWS, start=1):
        if all(bool(terms.get(k)) == v for k, v in row.terms.items()):
            return i
    return None
