"""``pedx-graph baseline NAME DATASET --out RESULTS``: the paper's baselines over a whole dataset."""
from __future__ import annotations

import argparse

from pedx_graph.baselines.run import BASELINES


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "baseline", help="run a baseline of the paper (triangulation, left_disp, smplify_disp) on a dataset",
        description="Run baseline NAME on every track of DATASET and write results in the PedX SMPL layout under "
                    "--out (keypoints_3d carries the 3D keypoints; the keypoint-only baselines fill pose and "
                    "betas with zeros), with summary.json and the resolved config; score them with "
                    "`pedx-graph eval RESULTS --truth DATASET`.")
    p.add_argument("name", choices=BASELINES, help="which baseline")
    p.add_argument("dataset", help="dataset root (the folder holding labels/ and calib/, or its parent)")
    p.add_argument("--out", required=True, help="results folder")
    p.add_argument("--config", default=None, help="YAML with BaselineConfig fields (body_model, smplify)")
    p.add_argument("--model", default=None, help="SMPL-format body model file (overrides the config's body_model)")
    p.add_argument("--workers", type=int, default=1, help="processes over tracks")
    p.add_argument("--sequence", action="append", default=None, help="only these sequences (repeatable)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from pedx_graph.baselines.run import BaselineConfig, fit_dataset_baseline
    from pedx_graph.config import load_config

    config = load_config(BaselineConfig, args.config)
    if args.model:
        config.body_model = args.model
    from pedx_graph.preflight import check_baseline_setup
    check_baseline_setup(config, args.name, args.dataset, args.config or "<command line>")   # before any output
    summary = fit_dataset_baseline(args.dataset, args.out, args.name, workers=args.workers, config=config,
                                   sequences=args.sequence)
    n_ok, n_bad = len(summary["tracks"]), len(summary["failed"])
    print(f"baseline {args.name}: {n_ok} tracks ({summary['total_frames']} frames) in "
          f"{summary['wall_seconds']:.1f} s; {n_bad} failed; results in {args.out}")
    for bad in summary["failed"]:
        print(f"  failed {bad['sequence']}/{bad['tracking_id']}: {bad['error']}")
    return 0 if n_ok or not n_bad else 1
