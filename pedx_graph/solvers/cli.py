"""``pedx-graph fit`` (batch LM over whole tracks)."""
from __future__ import annotations

import argparse
import logging

from pedx_graph.config import load_config
from pedx_graph.execution.options import add_run_arguments, run_command
from pedx_graph.graph.config import FitConfig
from pedx_graph.preflight import check_fit_setup

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser("fit", help="fit every track of a PedX-layout dataset (batch LM)",
                              description="Fit every track of every sequence of DATASET and write results in "
                                          "the PedX SMPL layout under --out as each track completes, with "
                                          "manifest.json, a completion marker per track (done/), summary.json "
                                          "and the config; tracks run in this process, on --workers local "
                                          "processes or on a Dask --cluster (docs/running.md).")
    p.add_argument("dataset", help="dataset root (the folder holding labels/ and calib/, or its parent)")
    p.add_argument("--out", required=True, help="results folder")
    p.add_argument("--solver", default="lm", choices=["lm", "admm"],
                   help="lm: batch Levenberg-Marquardt over the joint graph; admm: the paper's ADMM (reference)")
    p.add_argument("--config", default=None, help="YAML preset (see configs/)")
    p.add_argument("--sequence", action="append", default=None, help="only these sequences (repeatable)")
    add_run_arguments(p)
    p.set_defaults(func=_run_fit)


def _run_fit(args: argparse.Namespace) -> int:
    from pedx_graph.solvers.fit import fit_dataset

    config = load_config(FitConfig, args.config)
    check_fit_setup(config, args.dataset, args.config or "<defaults>")    # one line before any output
    return run_command(
        args, lambda **opts: fit_dataset(args.dataset, args.out, config, sequences=args.sequence, solver=args.solver,
                                         **opts),
        lambda s: (f"fitted {s['counts']['done']} of {s['counts']['tracks']} tracks ({s['total_frames']} frames) in "
                   f"{s['timings']['wall_seconds']:.1f} s; {s['counts']['failed']} failed; results in {args.out}"))
