"""The solver and real-rig sections of docs/results.md, rendered from the benchmarks' JSON (no typed figure).

:func:`solver_section` reads ``benchmarks/results/bench_solvers.json``: the batch LM fit, the iSAM2 stream
(final estimate and causal, i.e. each frame as first estimated) on every track, and the ADMM reference beside
LM and iSAM2 on the subset ADMM runs on.  :func:`realrig_section` reads ``bench_realrig.json``: each variant
of the real-rig scenes, overall and per distance bin (bins without frames left out).  :func:`benchmark_block`
joins them between the markers ``<!-- benchmarks -->`` / ``<!-- /benchmarks -->``; a test checks that the
committed docs/results.md holds exactly this block for the committed JSON.  :func:`detections_block` renders,
the same way, docs/detections.md's table of ``bench_detections.json`` (seed 0) and ``seed*/bench_detections.json``
between ``<!-- detections -->`` / ``<!-- /detections -->``, and :func:`identity_fixes_block` its table of the
``bench_identity_fixes*.json`` runs between ``<!-- identity-fixes -->`` / ``<!-- /identity-fixes -->``.
``python tools/gen_benchmark_docs.py`` rewrites every block.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

BEGIN, END = "<!-- benchmarks -->", "<!-- /benchmarks -->"
DETECTIONS_BEGIN, DETECTIONS_END = "<!-- detections -->", "<!-- /detections -->"
#: Markers of docs/detections.md's block of the same benchmark on the real PedX rig (``--rig pedx``).
DETECTIONS_PEDX_BEGIN, DETECTIONS_PEDX_END = "<!-- detections_pedx_rig -->", "<!-- /detections_pedx_rig -->"
#: Where ``bench_detections.py --rig pedx`` runs are committed (seed 0 there, other seeds in ``seed*/``).
DETECTIONS_PEDX_FOLDER = "benchmarks/results/detections_pedx_rig"


#: Markers of docs/detections.md's table of ``benchmarks/bench_identity_fixes.py``'s runs.
IDENTITY_FIXES_BEGIN, IDENTITY_FIXES_END = "<!-- identity-fixes -->", "<!-- /identity-fixes -->"
#: The identity-fixes runs in the table's order: result name (``benchmarks/results/<name>.json``), how the
#: table names the set.
IDENTITY_FIXES_RUNS = (("bench_identity_fixes", "84 inputs (seeds 0-8, 17-21)"),
                       ("bench_identity_fixes_pedx_rig", "real rig's preset, seeds 0-8"),
                       ("bench_identity_fixes_long", "long (20 people x 80 frames, seeds 10-15)"),
                       ("bench_identity_fixes_heldout", "held out, seeds 30-38"),
                       ("bench_identity_fixes_pedx_rig_heldout", "held out, real rig's preset, seeds 30-38"))


#: Markers of docs/detections.md's table of ``benchmarks/bench_image_frame.py`` (raw or rectified images).
IMAGE_FRAME_BEGIN, IMAGE_FRAME_END = "<!-- image-frame -->", "<!-- /image-frame -->"


#: Markers of docs/detections.md's table of ``benchmarks/bench_pixel_scale.py`` (resized images, normalised
#: coordinates).
PIXEL_SCALE_BEGIN, PIXEL_SCALE_END = "<!-- pixel-scale -->", "<!-- /pixel-scale -->"


#: Markers of docs/detections.md's table of ``bench_association.py --fps`` runs (other frame rates).
FRAME_RATES_BEGIN, FRAME_RATES_END = "<!-- frame-rates -->", "<!-- /frame-rates -->"
#: The frame-rate runs in the table's order (by the scenes' duration): result name, the scenes' rate;
#: ``bench_association`` is the 10 Hz run, of which the seeds the others ran are shown.
FRAME_RATE_RUNS = (("bench_association_20hz_at_10hz", "20 Hz"), ("bench_association_20hz", "20 Hz"),
                   ("bench_association", "10 Hz"),
                   ("bench_association_10hz_4s", "10 Hz"), ("bench_association_5hz_at_10hz", "5 Hz"),
                   ("bench_association_5hz", "5 Hz"), ("bench_association_20hz_4s", "20 Hz"))


#: Suffix of a bench_detections input of a format's detections grouped by the simulator's ids.
TRUE_IDS = "_true_ids"


def _f(value, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def solver_section(data: dict) -> str:
    """Markdown: batch LM, iSAM2 stream (final and causal) and the ADMM reference (bench_solvers.json)."""
    rows = {r["solver"]: r for r in data["all_tracks"]}
    goal = data["goals"]["streamed_final_within_5pct_of_batch"]
    lines = [f"### Solvers (`{data['command'].strip()}`: seed {data['seed']}, {data['pedestrians']} pedestrians x "
             f"{data['frames']} frames, {data['motion']})", "",
             f"All {data['tracks']} tracks; MPJPE in mm over the 13 joints.", "",
             "| solver | tracks | frames | global | root-relative | ms per frame |", "|---|---:|---:|---:|---:|---:|"]
    for name, label in (("lm", "batch fit (LM)"), ("isam2", "iSAM2 stream, final"),
                        ("lm without flip search", "batch fit without the flip search")):
        r = rows.get(name)
        if r:
            lines.append(f"| {label} | {r['tracks']} | {r['frames']} | {_f(r['global_mm'])} | "
                         f"{_f(r['root_relative_mm'])} | {_f(r['ms_per_frame'])} |")
    lines.append(f"| iSAM2 stream, causal (each frame as first estimated) | {data['tracks']} | "
                 f"{rows['isam2']['frames']} | {_f(goal['causal_global_mm'])} | "
                 f"{_f(goal['causal_root_relative_mm'])} | - |")
    lines += ["", f"The ADMM reference on the {data['admm_subset'][0]['tracks']} tracks it runs on:", "",
              "| solver | frames | global | root-relative | ms per frame |", "|---|---:|---:|---:|---:|"]
    for r in data["admm_subset"]:
        lines.append(f"| {r['solver']} | {r['frames']} | {_f(r['global_mm'])} | {_f(r['root_relative_mm'])} | "
                     f"{_f(r['ms_per_frame'])} |")
    return "\n".join(lines) + "\n"


def realrig_section(data: dict) -> str:
    """Markdown: every variant of the real-rig scenes (bench_realrig.json), overall and per distance bin."""
    variants = data["variants"]
    bins = []
    for v in variants.values():
        for key, b in v["eval"]["per_distance"].items():
            if b.get("frames") and key not in bins:
                bins.append(key)
    lines = [f"### Real-rig scenes (`{data['command'].strip()}`: {data['motion']})", "",
             "MPJPE in mm, global / root-relative; keypoint NEES/3 and 95 % coverage of the covariances.", "",
             "| variant | frames | overall | " + " | ".join(f"{b} m" for b in bins) + " | NEES/3 | inside 95 % |",
             "|---|---:|---:|" + "---:|" * len(bins) + "---:|---:|"]
    for name, v in variants.items():
        ev = v["eval"]
        cells = []
        for b in bins:
            d = ev["per_distance"].get(b) or {}
            cells.append(f"{_f(d.get('global_mm'))} / {_f(d.get('root_relative_mm'))}" if d.get("frames") else "-")
        cal = (v.get("calibration") or {}).get("overall") or {}
        coverage = cal.get("coverage95")
        lines.append(f"| {name} | {ev['frames']} | {_f(ev['overall']['global_mm'])} / "
                     f"{_f(ev['overall']['root_relative_mm'])} | " + " | ".join(cells) +
                     f" | {_f(cal.get('mean_nees_over_dof'), 2)} | "
                     f"{_f(None if coverage is None else 100 * coverage)} % |")
    return "\n".join(lines) + "\n"


def benchmark_block(results_dir: str | os.PathLike) -> str:
    """The generated block (markers included) from ``results_dir`` (``benchmarks/results``); sections whose
    JSON is absent are left out."""
    results_dir = Path(results_dir)
    parts = [BEGIN, "## Solvers and real-rig scenes (generated from benchmarks/results/*.json)", ""]
    solvers, realrig = results_dir / "bench_solvers.json", results_dir / "bench_realrig.json"
    if solvers.is_file():
        parts.append(solver_section(json.loads(solvers.read_text())))
    if realrig.is_file():
        parts.append(realrig_section(json.loads(realrig.read_text())))
    parts.append(END)
    return "\n".join(parts) + "\n"


def detection_runs(results_dir: str | os.PathLike) -> list[dict]:
    """The bench_detections results of ``results_dir`` (seed 0) and of its ``seed*/`` folders, by seed."""
    results_dir = Path(results_dir)
    paths = [results_dir / "bench_detections.json"] + sorted(results_dir.glob("seed*/bench_detections.json"))
    runs = [json.loads(p.read_text()) for p in paths if p.is_file()]
    return sorted(runs, key=lambda r: r["seed"])


def detections_section(runs: list[dict], folder: str = "benchmarks/results") -> str:
    """Markdown: per seed and detector format, the issue's goals (MPJPE at 5-25 m against the manual labels,
    identity switches among crossing people, false tracks) with root-relative error, the frames fitted more
    than the match radius from the person whose detections they hold (misplaced: not in the MPJPE; absent
    from older runs), people recovered, the keypoint NEES and the 95 % ellipsoids' coverage (manual / detector:
    the mean NEES follows its tail — a few frames far off with a confident covariance —, the coverage its bulk).
    ``folder``: where the runs are committed (seed 0 in it, seed N in its ``seedN/``), named beside each command
    that did not write to the script's default ``benchmarks/results``."""
    lines = ["| seed | input | manual MPJPE 5-25 m, global / root-rel. (mm) | detector MPJPE 5-25 m (mm) | "
             "ratio (goal <= 1.5) | ratio with the simulator's ids | id switches, crossing people (goal 0) | "
             "false tracks (goal 0) | misplaced frames 5-25 m / scored | recovered / labelled people | "
             "keypoint NEES / dof | keypoints in their 95 % ellipsoid, manual / detector |",
             "|---|---|---|---|---:|---:|---:|---:|---:|---|---:|---:|"]
    for run in runs:
        manual = run["accuracy"]["manual"]["5-25"]
        for fmt, goal in run["goals"].items():
            acc = run["accuracy"][fmt]["5-25"]
            recovered = sum(sc["association"][fmt]["recovered"] for sc in run["scenes"].values())
            labelled = sum(sc["association"][fmt]["labelled_people"] for sc in run["scenes"].values())
            lines.append(f"| {run['seed']} | {fmt} | {_f(manual.get('mpjpe_mm'))} / {_f(manual.get('rel_mpjpe_mm'))} | "
                         f"{_f(acc.get('mpjpe_mm'))} / {_f(acc.get('rel_mpjpe_mm'))} | "
                         f"{_f(goal['mpjpe_ratio_5_25'], 2)} | {_f(goal.get('mpjpe_ratio_5_25_true_ids'), 2)} | "
                         f"{goal['crossing_id_switches']} | "
                         f"{goal['false_tracks']} | {acc.get('misplaced_frames', '-')} / {acc.get('frames', 0)} | "
                         f"{recovered} / {labelled} | "
                         f"{_f(acc.get('keypoint_nees_over_dof'), 2)} | "
                         f"{_f(manual.get('keypoint_coverage95'), 3)} / {_f(acc.get('keypoint_coverage95'), 3)} |")
    met = [(run["seed"], fmt) for run in runs for fmt, g in run["goals"].items()
           if g["within_1.5x"] and g["crossing_id_switches"] == 0 and g["false_tracks"] == 0]
    within = sum(g["within_1.5x"] for run in runs for g in run["goals"].values())
    total = sum(len(run["goals"]) for run in runs)
    lines += ["", f"Within 1.5x of the manual labels: {within} of {total} seed-format runs; all three goals met: "
              f"{len(met)} of {total}.  Commands: " + "; ".join(f"`{run['command']}`" + _written_to(folder, run["seed"])
                                                                for run in runs) + "."]
    lines += ["", "Ratio with the simulator's ids: the same detections grouped into tracks by the simulator's "
              "ids (`use_file_ids`), imported and fitted alike, scored on the frames of the people the "
              "association's tracks were scored on: what a perfect association would give there (`-`: a run "
              "from before it was measured)."]
    pooled = _pooled_ratios(runs)
    if pooled:
        lines += ["", "Over the seeds together (each seed's 5-25 m MPJPE weighted by its frames), ratio to the manual "
                  "labels: " + ", ".join(f"{fmt} {_f(ratio, 2)}" for fmt, ratio in pooled.items()) + "."]
    known = _pooled_ratios(runs, suffix=TRUE_IDS)
    if known:
        lines += ["With the simulator's ids: " + ", ".join(f"{fmt} {_f(ratio, 2)}" for fmt, ratio in known.items())
                  + "."]
    lines += _joint_table(runs)
    lines += _views_table(runs)
    return "\n".join(lines)


def _written_to(folder: str, seed: int) -> str:
    """`` (written to `<folder>[/seedN]`)`` for a run not in the script's default output folder, else ``""``."""
    path = folder + (f"/seed{seed}" if seed else "")
    return "" if path == "benchmarks/results" else f" (written to `{path}`)"


def _pooled_ratios(runs: list[dict], suffix: str = "") -> dict[str, float]:
    """Detector format -> its 5-25 m MPJPE over all ``runs`` (frame-weighted) over the manual labels' likewise;
    empty with fewer than two runs.  ``suffix``: of the format's input name (:data:`TRUE_IDS`: the format's
    detections grouped by the simulator's ids; empty when a run lacks it)."""
    if len(runs) < 2 or any(fmt + suffix not in run["accuracy"] for run in runs for fmt in run["goals"]):
        return {}

    def pooled(source: str) -> float | None:
        stats = [run["accuracy"][source]["5-25"] for run in runs]
        frames = sum(st.get("frames", 0) for st in stats if st.get("mpjpe_mm") is not None)
        total = sum(st["mpjpe_mm"] * st["frames"] for st in stats if st.get("mpjpe_mm") is not None)
        return total / frames if frames else None

    manual = pooled("manual")
    out = {}
    for fmt in runs[0]["goals"]:
        detector = pooled(fmt + suffix)
        if manual and detector is not None:
            out[fmt] = detector / manual
    return out


def _joint_table(runs: list[dict]) -> list[str]:
    """Markdown lines: the global MPJPE of each evaluated joint at 5-25 m per input, over the seeds (each
    seed's mean weighted by its frames); empty when no run reports per-joint errors."""
    sums: dict[str, dict[str, float]] = {}
    frames: dict[str, int] = {}
    joints: list[str] = []
    for run in runs:
        for source, summary in run["accuracy"].items():
            if source.endswith(TRUE_IDS):
                continue
            st = summary.get("5-25") or {}
            per_joint = st.get("joint_mpjpe_mm")
            if not per_joint:
                continue
            joints = joints or list(per_joint)
            acc = sums.setdefault(source, dict.fromkeys(joints, 0.0))
            for joint in joints:
                acc[joint] += per_joint[joint] * st["frames"]
            frames[source] = frames.get(source, 0) + st["frames"]
    if not sums:
        return []
    seeds = ", ".join(str(run["seed"]) for run in runs)
    lines = ["", f"Global MPJPE per joint at 5-25 m (mm; seeds {seeds}, each seed's mean weighted by its frames):",
             "", "| input | frames | " + " | ".join(joints) + " |", "|---|---:|" + "---:|" * len(joints)]
    for source, acc in sums.items():
        lines.append(f"| {source} | {frames[source]} | "
                     + " | ".join(_f(acc[j] / frames[source]) for j in joints) + " |")
    return lines


def _views_table(runs: list[dict]) -> list[str]:
    """Markdown lines: the limb joints' global error at 5-25 m per input by how many images held the joint
    (``limbs_by_views``), pooled over the seeds (joint-frames summed): share, mean error and part of the summed
    error per bin; empty when no run reports it."""
    pooled: dict[str, dict[str, list[float]]] = {}
    for run in runs:
        for source, summary in run["accuracy"].items():
            if source.endswith(TRUE_IDS):
                continue
            for label, b in ((summary.get("5-25") or {}).get("limbs_by_views") or {}).items():
                acc = pooled.setdefault(source, {}).setdefault(label, [0.0, 0.0])
                acc[0] += b["joint_frames"]
                acc[1] += (b["mpjpe_mm"] or 0.0) * b["joint_frames"]
    if not pooled:
        return []
    bins = list(next(iter(pooled.values())))
    seeds = ", ".join(str(run["seed"]) for run in runs)
    lines = ["", f"Limb joints (knees, ankles, shoulders, elbows, wrists) at 5-25 m by how many images' keypoints "
             f"held them (seeds {seeds} pooled): share of the joint-frames, mean global error (mm) and that "
             "bin's part of the summed error.  None: placed by the priors; one: depth from the rest of the body.",
             "", "| input | " + " | ".join(f"{b} image" + ("" if b == "1" else "s") for b in bins) + " |",
             "|---|" + "---:|" * len(bins)]
    for source, by_bin in pooled.items():
        count = sum(v[0] for v in by_bin.values())
        error = sum(v[1] for v in by_bin.values())
        lines.append(f"| {source} | " + " | ".join(
            f"{_f(by_bin[b][0] / count, 2)}, {_f(by_bin[b][1] / by_bin[b][0]) if by_bin[b][0] else '-'} "
            f"({_f(by_bin[b][1] / error, 2)})" for b in bins) + " |")
    return lines


def detections_block(results_dir: str | os.PathLike, folder: str = "benchmarks/results",
                     begin: str = DETECTIONS_BEGIN, end: str = DETECTIONS_END) -> str:
    """The generated bench_detections block of docs/detections.md (markers included): the runs in
    ``results_dir``, committed as ``folder`` (the project-relative path the text names)."""
    return "\n".join([begin, detections_section(detection_runs(results_dir), folder), end]) + "\n"


def identity_fixes_block(results_dir: str | os.PathLike) -> str:
    """docs/detections.md's table of the committed ``bench_identity_fixes*.json`` runs (markers included; a run
    not in ``results_dir`` is left out): per set the track frames the review flags, the fix operations a
    reviewer writes looking inside the review's stretches / everywhere, and switches (crossing), people's
    detections on another's track and centres off by more than 0.5 m as associated -> after the review's
    fixes -> after fixes everywhere; then each run's command."""
    results_dir = Path(results_dir)
    lines = [IDENTITY_FIXES_BEGIN,
             "| set | flagged / track frames | fix operations, review / everywhere | id switches (crossing) | "
             "others' detections | centres off > 0.5 m |",
             "|---|---:|---:|---|---|---|"]
    commands = []
    for name, label in IDENTITY_FIXES_RUNS:
        path = results_dir / f"{name}.json"
        if not path.is_file():
            continue
        run = json.loads(path.read_text())
        t = run["totals"]
        stages = ("associated", "review_fixed", "all_fixed")
        switches = " -> ".join(f"{t[s + '_id_switches']} ({t[s + '_crossing_id_switches']})" for s in stages)
        lines.append(f"| {label} | {t['review_flagged_frames']} / {t['track_frames']} "
                     f"({100 * t['review_flagged_frames'] / max(t['track_frames'], 1):.0f} %) | "
                     f"{t['review_operations']} / {t['all_operations']} | {switches} | "
                     + " -> ".join(str(t[s + "_others_detections"]) for s in stages) + " | "
                     + " -> ".join(str(t[s + "_misplaced_centres"]) for s in stages) + " |")
        commands.append(f"`{run['command']}`")
    lines += ["", "Commands: " + "; ".join(commands) + ".", IDENTITY_FIXES_END]
    return "\n".join(lines) + "\n"


def image_frame_table(result: dict) -> list[str]:
    """The table of a ``bench_image_frame`` run (its JSON as a dict): per rig, images the detector ran on and turn
    of the raw right camera, the pairs, how they were read and what each reading does to the keypoints."""
    lines = ["| rig | detector ran on | right camera turned (deg) | pairs | right (by its rows) | wrong by its rows "
             "| wrong, undecided | median people matched | median abs. log evidence | keypoint error as read (px) "
             "| right reading (px) | wrong reading (px) | decision (ms) |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for s in result["summary"]:
        lines.append(f"| {s['rig']} | {s['images']} | {s['rotation_deg']:g} | {s['pairs']} | {s['right']} "
                     f"({s['right_by_own_rows']}) | {s['wrong_by_own_rows']} | {s['wrong_undecided']} | "
                     f"{_f(s['median_matches'], 0)} | {_f(s['median_abs_log_evidence'])} | "
                     f"{_f(s['keypoint_error_px_as_read'])} | {_f(s['keypoint_error_px_right_reading'])} | "
                     f"{_f(s['keypoint_error_px_wrong_reading'])} | {_f(s['median_decide_ms'], 0)} |")
    return lines


def _small_scenes_block(results_dir: str | os.PathLike, name: str, table, begin: str, end: str,
                        formats: bool = False) -> str:
    """A docs table (markers included) of a committed benchmark run on small seeded scenes (``<name>.json``,
    rendered by ``table``) and its command, seeds and scene size (and formats)."""
    run = json.loads((Path(results_dir) / f"{name}.json").read_text())
    listed = f"; {', '.join(run['formats'])}" if formats else ""
    return "\n".join([begin, *table(run), "", f"Command: `{run['command']}` (seeds "
                      f"{', '.join(map(str, run['seeds']))}; {run['pedestrians']} pedestrians x {run['frames']} "
                      f"frames per scene{listed}).", end]) + "\n"


def image_frame_block(results_dir: str | os.PathLike) -> str:
    """docs/detections.md's table of the committed ``bench_image_frame.json`` (markers included) and its
    command."""
    return _small_scenes_block(results_dir, "bench_image_frame", image_frame_table, IMAGE_FRAME_BEGIN,
                               IMAGE_FRAME_END, formats=True)


def _pixel_case(s: dict) -> tuple[int, str]:
    """A ``bench_pixel_scale`` summary row's place and name in the docs' table."""
    written = (f"pixels of images resized by {s['written_scale']:g}" if s["written_units"] == "pixels"
               and s["written_scale"] != 1 else "pixels of the calibrated images" if s["written_units"] == "pixels"
               else "[0, 1] of the image" if s["written_units"] == "unit" else "[-1, 1] of the image")
    case = {("coco", "as written"): "COCO, with its image list's sizes", ("coco", "no sizes"): "COCO, no sizes",
            ("openpose_body25", "as written"): "OpenPose",
            ("openpose_body25", "told"): "OpenPose, told the resize",
            ("openpose_body25", "told twice"): "OpenPose, told 0.5 (no resize was made)"}[(s["format"], s["case"])]
    order = (s["written_units"] != "pixels", -s["written_scale"], s["case"] == "told twice")
    return order, f"{written}; {case}"


def pixel_scale_table(result: dict) -> list[str]:
    """The table of a ``bench_pixel_scale`` run (its JSON as a dict): per way the coordinates were written and
    read, the inputs the import handled right (accepted when it reads them right, else refused) on each rig,
    how far a refusal's factor from the LiDAR is from the truth (median), and the accepted inputs' margin
    (the most people any scale beyond the tolerance puts on the LiDAR's returns over those the scale used
    puts there; the largest)."""
    import statistics

    groups: dict[tuple, dict] = {}
    for row in result["rows"]:
        order, name = _pixel_case(row)
        g = groups.setdefault((order, name), {"reads_right": row["reads_right"], "rigs": {}, "off": [],
                                              "margin": [], "ms": []})
        right, inputs = g["rigs"].get(row["rig"], (0, 0))
        g["rigs"][row["rig"]] = (right + bool(row["right"]), inputs + 1)
        if row.get("best_scale_error") is not None:
            g["off"].append(row["best_scale_error"])
        if not row["refused"] and row.get("people_on_lidar"):
            g["margin"].append(row["people_on_lidar_elsewhere"] / row["people_on_lidar"])
        g["ms"].append(1000 * row["seconds"])
    lines = ["| coordinates written; read from | read right as they are | right / inputs, default rig | "
             "right / inputs, real rig's preset | refusal: LiDAR's factor off (median) | accepted: people on the "
             "LiDAR at another scale / at the one used (largest) | time (ms, median) |",
             "|---|---|---:|---:|---:|---:|---:|"]
    for (_, name), g in sorted(groups.items()):
        rigs = [f"{g['rigs'][r][0]} / {g['rigs'][r][1]}" if r in g["rigs"] else "-" for r in ("default", "pedx")]
        off = f"{100 * statistics.median(g['off']):.1f} %" if g["off"] else "-"
        margin = f"{max(g['margin']):.2f}" if g["margin"] else "-"
        lines.append(f"| {name} | {'yes' if g['reads_right'] else 'no'} | {rigs[0]} | {rigs[1]} | {off} | {margin} "
                     f"| {statistics.median(g['ms']):.0f} |")
    return lines


def pixel_scale_block(results_dir: str | os.PathLike) -> str:
    """docs/detections.md's table of the committed ``bench_pixel_scale.json`` (markers included) and its
    command."""
    return _small_scenes_block(results_dir, "bench_pixel_scale", pixel_scale_table, PIXEL_SCALE_BEGIN,
                               PIXEL_SCALE_END)


def frame_rates_block(results_dir: str | os.PathLike) -> str:
    """docs/detections.md's table of the association at other frame rates (markers included): per run of
    :data:`FRAME_RATE_RUNS` (the 10 Hz run restricted to the seeds of the others) its totals, the walks'
    implied interval over the one used (range) and the inputs the check flagged; then the commands."""
    results_dir = Path(results_dir)
    runs = {name: json.loads((results_dir / f"{name}.json").read_text()) for name, _ in FRAME_RATE_RUNS}
    seeds = sorted({r["seed"] for name, _ in FRAME_RATE_RUNS if name != "bench_association"
                    for r in runs[name]["rows"]})
    lines = [FRAME_RATES_BEGIN,
             "| scenes | frames (duration) | association told | tracks (false) | recovered / labelled | id switches "
             "(crossing) | centres off > 0.5 m / placed | walks imply / interval used | flagged |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    commands = []
    for name, rate in FRAME_RATE_RUNS:
        run = runs[name]
        rows = [r for r in run["rows"] if r["seed"] in seeds]
        total = {k: sum(r[k] for r in rows) for k in ("tracks", "false_tracks", "recovered", "labelled_people",
                                                       "id_switches", "crossing_id_switches",
                                                       "misplaced_centres", "placed_frames")}
        ratios = [r["walk_ratio"] for r in rows if r.get("walk_ratio") is not None]
        flagged = sum(1 for r in rows if r.get("walk_ratio") is not None and not r["walk_agrees"])
        interval = run.get("frame_interval_s", 0.1)
        fps = run.get("scene_fps") or 10.0
        lines.append(f"| {rate} | {run['frames']} ({run['frames'] / fps:g} s) | {interval:g} s | "
                     f"{total['tracks']} ({total['false_tracks']}) | "
                     f"{total['recovered']} / {total['labelled_people']} | {total['id_switches']} "
                     f"({total['crossing_id_switches']}) | {total['misplaced_centres']} / {total['placed_frames']} | "
                     f"{min(ratios):.2f}-{max(ratios):.2f} | {flagged} of {len(ratios)} |")
        commands.append(f"`{run['command']}`" + (f" (seeds {seeds[0]}-{seeds[-1]} of it)"
                                                  if name == "bench_association" else ""))
    lines += ["", "Commands: " + "; ".join(commands) + ".", FRAME_RATES_END]
    return "\n".join(lines) + "\n"


KEYPOINT_CALIBRATION_BEGIN, KEYPOINT_CALIBRATION_END = "<!-- keypoint-calibration -->", "<!-- /keypoint-calibration -->"
#: The keypoint-calibration runs in docs/detections.md's table: folder under benchmarks/results, row label.
KEYPOINT_CALIBRATION_RUNS = (("keypoint_calibration", "simulator's ids"),
                             ("keypoint_calibration_definition_sigma_2cm",
                              "simulator's ids, `definition_sigma_m` 2 cm"),
                             ("keypoint_calibration_associated", "the association (no ids)"),
                             ("keypoint_calibration_associated/seed1", "the association (no ids), seed 1"),
                             ("keypoint_calibration_pedx_rig", "simulator's ids, real PedX rig"))


def keypoint_calibration_block(results_dir: str | os.PathLike) -> str:
    """docs/detections.md's table of ``bench_keypoint_calibration`` (markers included): per run of
    :data:`KEYPOINT_CALIBRATION_RUNS` and detector offset, each format's MPJPE at 5-25 m with the shipped
    definitions, after one round and after the last, and the coverage of the 95 % ellipsoids before and
    after; then the commands."""
    results_dir = Path(results_dir)
    lines = [KEYPOINT_CALIBRATION_BEGIN,
             "| detections grouped by | detector's points off the definitions | MPJPE, shipped definitions (round 0) | "
             "after 1 round | after the last round | 95 % coverage, round 0 -> last |",
             "|---|---|---|---|---|---|"]
    commands = []
    for folder, label in KEYPOINT_CALIBRATION_RUNS:
        run = json.loads((results_dir / folder / "bench_keypoint_calibration.json").read_text())
        for shift, formats in run["shifts"].items():
            def row(r, key, digits):
                return " / ".join(_f(formats[fmt]["rounds"][r][key], digits) for fmt in formats)
            last = run["rounds"]
            lines.append(f"| {label} | {float(shift) * 100:g} cm | {row(0, 'mpjpe_mm', 1)} | {row(1, 'mpjpe_mm', 1)} | "
                         f"{row(last, 'mpjpe_mm', 1)} (round {last}) | {row(0, 'coverage_95', 3)} -> "
                         f"{row(last, 'coverage_95', 3)} |")
        commands.append(f"`{run['command']}` (`benchmarks/results/{folder}`)")
    names = " / ".join(json.loads((results_dir / KEYPOINT_CALIBRATION_RUNS[0][0] / "bench_keypoint_calibration.json")
                                  .read_text())["shifts"]["0"].keys())
    lines += ["", f"Formats in each cell: {names}.  Commands: " + "; ".join(commands) + ".",
              KEYPOINT_CALIBRATION_END]
    return "\n".join(lines) + "\n"


def replace_block(text: str, block: str, begin: str = BEGIN, end: str = END) -> str:
    """``text`` with its block between ``begin`` / ``end`` replaced by ``block`` (the benchmark block: inserted
    before the notes, else appended)."""
    if begin in text and end in text:
        return text[:text.index(begin)] + block.rstrip("\n") + text[text.index(end) + len(end):]
    marker = "<!-- notes -->"
    if marker in text:
        return text[:text.index(marker)] + block + "\n" + text[text.index(marker):]
    return text.rstrip("\n") + "\n\n" + block
