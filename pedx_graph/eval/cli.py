"""``pedx-graph eval``: MPJPE of results against ground truth."""
from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser("eval", help="MPJPE (global and root-relative) of results against ground truth",
                              description="Compare RESULTS (PedX SMPL layout) with the ground truth of a "
                                          "simulated dataset; writes eval.json and eval.md into RESULTS.")
    p.add_argument("results", help="results folder written by `pedx-graph fit`")
    p.add_argument("--truth", required=True, help="dataset with ground-truth labels/3d/smpl")
    p.add_argument("--model", default=None, help="body model of the ground truth (default: the open model)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from pedx_graph.body import BodyModel
    from pedx_graph.eval.evaluate import evaluate, write_report
    from pedx_graph.eval.metrics import markdown_table

    summary = evaluate(args.results, args.truth, BodyModel.load(args.model))
    write_report(summary, args.results)
    print(markdown_table(summary))
    return 0
