"""Command-line interface: ``pedx-graph <command> ...``.

Each sub-package that offers a command has a ``cli`` module with ``register(subparsers)``; this module
only collects them, so importing the CLI stays cheap and one broken command does not hide the others.
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys

#: Modules providing ``register(subparsers)``, in help order.
COMMAND_MODULES = (
    "pedx_graph.body.cli",       # info
    "pedx_graph.sim.cli",        # simulate
    "pedx_graph.data.noise_cli",  # noise
    "pedx_graph.priors.cli",     # train-prior
    "pedx_graph.solvers.cli",    # fit
    "pedx_graph.solvers.stream_cli",  # stream
    "pedx_graph.baselines.cli",  # baseline
    "pedx_graph.eval.cli",       # eval
    "pedx_graph.eval.report_cli",  # report, experiments
    "pedx_graph.demo",           # demo
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pedx-graph", description="pedx-graph: metric 3D pedestrian body models from stereo 2D labels and LiDAR (factor graphs).")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name == name:      # command not written yet
                continue
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
