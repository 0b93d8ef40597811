"""``pedx-graph baseline NAME DATASET --out RESULTS``: the paper's baselines over a whole dataset."""
from __future__ import annotations

import argparse

from pedx_graph.baselines.run import BASELINES
from pedx_graph.execution.options import add_run_arguments, run_command


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "baseline", help="run a baseline of the paper (triangulation, left_disp, smplify_disp) on a dataset",
        description="Run baseline NAME on every track of DATASET and write results in the PedX SMPL layout under "
                    "--out as each track completes (keypoints_3d carries the 3D keypoints; the keypoint-only "
                    "baselines fill pose and betas with zeros), with manifest.json, done/, summary.json and the "
                    "resolved config; score them with `pedx-graph eval RESULTS --truth DATASET`.  Tracks run in "
                    "this process, on --workers local processes or on a Dask --cluster (docs/running.md).")
    p.add_argument("name", choices=BASELINES, help="which baseline")
    p.add_argument("dataset", help="dataset root (the folder holding labels/ and calib/, or its parent)")
    p.add_argument("--out", required=True, help="results folder")
    p.add_argument("--config", default=None, help="YAML with BaselineConfig fields (body_model, smplify)")
    p.add_argument("--model", default=None, help="SMPL-format body model file (overrides the config's body_model)")
    p.add_argument("--sequence", action="append", default=None, help="only these sequences (repeatable)")
    add_run_arguments(p)
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from pedx_graph.baselines.run import BaselineConfig, fit_dataset_baseline
    from pedx_graph.config import load_config

    config = load_config(BaselineConfig, args.config)
    if args.model:
        config.body_model = args.model
    from pedx_graph.preflight import check_baseline_setup
    check_baseline_setup(config, args.name, args.dataset, args.config or "<command line>")   # before any output
    return run_command(
        args, lambda **opts: fit_dataset_baseline(args.dataset, args.out, args.name, config=config,
                                                  sequences=args.sequence, **opts),
        lambda s: (f"baseline {args.name}: {s['counts']['done']} of {s['counts']['tracks']} tracks "
                   f"({s['total_frames']} frames) in {s['timings']['wall_seconds']:.1f} s; {s['counts']['failed']} "
                   f"failed; results in {args.out}"))
