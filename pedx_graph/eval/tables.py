"""Markdown tables of the evaluation report (pure functions of summaries: no file access).

Per-joint (paper Tables II / III), distance bins (bins without frames left out), ratio to the error floor,
the ablation (IV) and its ordering, detector labels (V), mean vs median, speed, covariance calibration, and
:func:`render_markdown` putting them under headings.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from pedx_graph.eval.metrics import DISTANCE_BINS
from pedx_graph.eval.runs import ABLATION_TERM_SYMBOLS
from pedx_graph.keypoints import EVAL_JOINTS



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


def filled_bins(summaries: dict[str, dict]) -> list[str]:
    """The distance bins (``"lo-hi"`` keys of :data:`DISTANCE_BINS`) in which some summary has frames (the
    tables leave empty bins out)."""
    keys = [f"{lo:g}-{hi:g}" for lo, hi in DISTANCE_BINS]
    return [b for b in keys if any(s["per_distance"].get(b, {}).get("frames") for s in summaries.values())]


def distance_table(summaries: dict[str, dict], floor: dict | None = None) -> str:
    """Markdown: methods as rows, distance bins with frames as columns, ``global / root-relative`` MPJPE (mm)
    per cell (``-`` where a method has no frame in a bin)."""
    bins = filled_bins(summaries)
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
    """Markdown: each method's MPJPE divided by the floor's, overall and per distance bin with frames
    (global / rel)."""
    bins = filled_bins(summaries)
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
        if not s["tracks"] and s.get("wall_seconds") is None:      # no summary.json (e.g. causal estimates)
            continue
        per_frame = (s["track_seconds_sum"] / s["total_frames"]
                     if s.get("track_seconds_sum") and s.get("total_frames") else None)
        lines.append(f"| {r['name']} | {s['tracks']} ({s['failed']}) | {s.get('total_frames') or '-'} | "
                     f"{s.get('workers') or '-'} | {_fmt(s.get('wall_seconds'))} | {_fmt(per_frame, 3)} | "
                     f"{_fmt(s.get('track_seconds_median'), 2)} |")
    return "\n".join(lines) + "\n"


def calibration_table(cal: dict) -> str:
    """Markdown: NEES / dof and 95 % coverage overall, visible/occluded and per distance bin (rows without
    keypoints left out)."""
    lines = ["| keypoints | n | mean NEES/3 | median NEES/3 | inside 95 % ellipsoid |", "|---|---:|---:|---:|---:|"]
    rows = [("all", cal["overall"]), ("visible", cal["visible"]), ("occluded", cal["occluded"])]
    rows += [(f"{k} m", v) for k, v in cal["per_distance"].items()]
    for name, s in rows:
        if not s["n"]:
            continue
        lines.append(f"| {name} | {s['n']} | {_fmt(s['mean_nees_over_dof'], 2)} | "
                     f"{_fmt(s['median_nees_over_dof'], 2)} | {_fmt(100 * s['coverage95'] if s['n'] else None)} % |")
    return "\n".join(lines) + "\n"


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
    for name in report.get("results") or {}:
        lines += [f"## Results without ground truth: {name}", ""]
        for part, heading in _RESULT_SECTIONS:
            text = tables.get(f"results_{name}_{part}")
            if text:
                lines += [f"### {heading}", "", text]
    pictures = report.get("pictures") or []
    if pictures:
        lines += ["## Pictures (pedx-graph export)", ""]
        lines += [f"![{Path(p).stem}]({p})" + "\n" for p in pictures]
    return "\n".join(lines).rstrip() + "\n"


_RESULT_SECTIONS = (("residuals", "Residuals (chi-square per row at the fit, summed over tracks)"),
                    ("uncertainty", "Marginal covariances per distance (SD = sqrt(trace / 3))"),
                    ("tracks", "Per-track diagnostics and plausibility"))
