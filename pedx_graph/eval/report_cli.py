"""``pedx-graph report`` and ``pedx-graph experiments``: the evaluation report and the whole experiment."""
from __future__ import annotations

import argparse
import shutil
from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "report", help="residuals, covariances, diagnostics and pictures of results folders; accuracy tables with --truth",
        description="Write report.md and report.json into --out for RESULTS_DIRS (fit / baseline output): "
                    "residuals, marginal covariances per distance, per-track diagnostics and plausibility, and "
                    "pictures (pedx-graph export); with --truth (a simulated dataset) also per-joint tables "
                    "(paper Tables II/III), the ablation (IV), detector labels (V), distance bins, speed, "
                    "covariance calibration and the error floor.")
    p.add_argument("results", nargs="+", metavar="RESULTS_DIRS", help="results folders (distinct names)")
    p.add_argument("--truth", default=None,
                   help="dataset with ground truth (simulated): adds the accuracy tables, error floor and "
                        "calibration (default: none, the report of what the results say about themselves)")
    p.add_argument("--out", required=True, help="report folder")
    p.add_argument("--model", default=None, help="body model of the ground truth (default: the open model)")
    p.add_argument("--no-floor", action="store_true", help="skip the error floor")
    p.add_argument("--no-calibration", action="store_true", help="skip the covariance calibration")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--floor-samples", type=int, default=64, help="Monte Carlo samples per frame of the floor")
    p.add_argument("--seed", type=int, default=0, help="seed of the floor's Monte Carlo samples")
    p.set_defaults(func=_run_report)

    e = subparsers.add_parser(
        "experiments", help="simulate, fit, run baselines, ablation and detector labels, then report",
        description="The whole evaluation from one seed into OUT (scenes/, dataset/, runs/, report/); with "
                    "--docs also writes DOCS/results.md and DOCS/figures/*.png.")
    e.add_argument("out", metavar="OUT", help="experiment folder (new)")
    e.add_argument("--seed", type=int, default=0, help="seed of the scenes, labels and Monte Carlo samples")
    e.add_argument("--config", default=None, help="YAML with ExperimentConfig fields")
    e.add_argument("--workers", type=int, default=2, help="processes (simulation frames, tracks)")
    e.add_argument("--docs", default=None, help="also write results.md and figures/ into this folder")
    e.add_argument("-q", "--quiet", action="store_true",
                   help="no progress bars (one per phase on stderr, shown only when stderr is a terminal)")
    e.set_defaults(func=_run_experiments)


def _run_report(args: argparse.Namespace) -> int:
    from pedx_graph.body import BodyModel
    from pedx_graph.eval.report import ReportConfig, build_report

    config = ReportConfig(floor=not args.no_floor, calibration=not args.no_calibration,
                          figures=not args.no_figures, floor_samples=args.floor_samples, seed=args.seed)
    build_report(args.results, args.truth, args.out, config, BodyModel.load(args.model))
    print(f"report written to {Path(args.out) / 'report.md'}")
    return 0


def docs_preamble(record: dict, command: str) -> str:
    """The header of docs/results.md: command, seed, scene sizes, hardware, phase times."""
    cfg = record["config"]
    code = record.get("code", {})
    scenes = ", ".join(f"{s['name']} (intersection at {s['intersection_x_m']:g} m, distance target "
                       f"{s['distance_mean_m']:g} +- {s['distance_std_m']:g} m)" for s in cfg["scenes"])
    phases = "\n".join(f"| {name} | {sec:.1f} |" for name, sec in record["phases_seconds"].items())
    return (f"Reproduce (from the project root, {record['workers']} worker processes):\n\n"
            f"```bash\n{command}\n```\n\n"
            f"Seed {record['seed']}; {len(cfg['scenes'])} simulated scenes of {cfg['pedestrians']} pedestrians x "
            f"{cfg['frames']} frames: {scenes}; motion: {record['motion']}. Hardware: {record['hardware']}; "
            f"total {record['total_seconds'] / 60:.1f} min. Code: commit {code.get('commit')}"
            f"{' with uncommitted changes' if code.get('dirty') else ''}.\n\n"
            "MPJPE in millimetres over the paper's 13 joints, weighted by the annotator's visibility (a joint "
            "counts when labelled visible in the left or right image). Global: world frame, no alignment; "
            "root-relative: after a similarity alignment per frame.\n\n"
            f"| phase | wall s |\n|---|---:|\n{phases}\n")


NOTES_BEGIN, NOTES_END = "<!-- notes -->", "<!-- /notes -->"


def kept_notes(path: Path) -> str:
    """The hand-written block between ``<!-- notes -->`` and ``<!-- /notes -->`` of an existing results file
    (kept when the file is regenerated), or an empty block."""
    text = path.read_text() if path.is_file() else ""
    if NOTES_BEGIN in text and NOTES_END in text:
        body = text[text.index(NOTES_BEGIN):text.index(NOTES_END) + len(NOTES_END)]
        return "\n" + body + "\n"
    return f"\n{NOTES_BEGIN}\n{NOTES_END}\n"


def _run_experiments(args: argparse.Namespace) -> int:
    import json

    from pedx_graph.config import load_config
    from pedx_graph.eval.experiments import ExperimentConfig
    from pedx_graph.eval.tables import render_markdown
    from pedx_graph.experiment_runner import run_experiments

    config = load_config(ExperimentConfig, args.config)
    if config.fit_config:                                   # the presets it names, checked before anything runs
        from pedx_graph.graph.config import FitConfig
        load_config(FitConfig, config.fit_config)
    if config.detector_config:
        from pedx_graph.eval.detector_noise import DetectorNoiseConfig
        load_config(DetectorNoiseConfig, config.detector_config)
    from tqdm.contrib.logging import logging_redirect_tqdm

    with logging_redirect_tqdm():                           # phase names above the bars, not through them
        record = run_experiments(args.out, config, seed=args.seed, workers=args.workers, progress=not args.quiet)
    report_dir = Path(args.out) / "report"
    print(f"experiment written to {args.out} in {record['total_seconds'] / 60:.1f} min; "
          f"report {report_dir / 'report.md'}")
    if args.docs:
        docs = Path(args.docs)
        (docs / "figures").mkdir(parents=True, exist_ok=True)
        report = json.loads((report_dir / "report.json").read_text())
        for fig in report.get("figures", []):
            shutil.copy2(report_dir / fig, docs / "figures" / Path(fig).name)
        command = (f"pedx-graph experiments OUT --seed {args.seed} --workers {args.workers}"
                   + (f" --config {args.config}" if args.config else "") + f" --docs {args.docs}")
        from pedx_graph.utils import atomic_write_text

        from pedx_graph.eval.benchmark_tables import benchmark_block

        text = render_markdown(report, title="Results", preamble=docs_preamble(record, command))
        bench = Path(__file__).resolve().parents[2] / "benchmarks" / "results"   # solvers, real rig (JSON)
        if bench.is_dir():
            text = text.rstrip("\n") + "\n\n" + benchmark_block(bench)
        atomic_write_text(docs / "results.md", text + kept_notes(docs / "results.md"))
        print(f"wrote {docs / 'results.md'}")
    return 0
