"""``pedx-graph fit`` (batch LM over whole tracks)."""
from __future__ import annotations

import argparse
import json
import logging

from pedx_graph.config import load_config
from pedx_graph.graph.config import FitConfig
from pedx_graph.preflight import check_fit_setup

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser("fit", help="fit every track of a PedX-layout dataset (batch LM)",
                              description="Fit every track of every sequence of DATASET and write results in "
                                          "the PedX SMPL layout under --out, with summary.json and the config.")
    p.add_argument("dataset", help="dataset root (the folder holding labels/ and calib/, or its parent)")
    p.add_argument("--out", required=True, help="results folder")
    p.add_argument("--solver", default="lm", choices=["lm", "admm"],
                   help="lm: batch Levenberg-Marquardt over the joint graph; admm: the paper's ADMM (reference)")
    p.add_argument("--config", default=None, help="YAML preset (see configs/)")
    p.add_argument("--workers", type=int, default=1, help="processes over tracks")
    p.add_argument("--sequence", action="append", default=None, help="only these sequences (repeatable)")
    p.set_defaults(func=_run_fit)


def _run_fit(args: argparse.Namespace) -> int:
    from pedx_graph.solvers.fit import fit_dataset

    config = load_config(FitConfig, args.config)
    check_fit_setup(config, args.dataset, args.config or "<defaults>")    # one line before any output
    summary = fit_dataset(args.dataset, args.out, config, workers=args.workers, sequences=args.sequence,
                          solver=args.solver)
    n_ok, n_bad = len(summary["tracks"]), len(summary["failed"])
    print(f"fitted {n_ok} tracks ({summary['total_frames']} frames) in {summary['wall_seconds']:.1f} s; "
          f"{n_bad} failed; results in {args.out}")
    for bad in summary["failed"]:
        print(f"  failed {bad['sequence']}/{bad['tracking_id']}: {bad['error']}")
    return 0 if n_ok or not n_bad else 1
