"""The command-line flags shared by ``fit``, ``stream`` and ``baseline`` (where tasks run, resume or
overwrite, progress) and how a run's end maps to one line on stderr and the exit code.

Exit codes: 0 done (some tracks may have failed: the summary lists them; 1 when every track failed),
1 an unusable ``--out`` or cluster (their ``ValueError`` subclasses end in one line through
:func:`pedx_graph.cli.main`), 2 bad flags, 128 + signal number after SIGINT (130) or SIGTERM (143), the
finished tracks kept and the summary written.
"""
from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Callable


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--workers``, ``--cluster``, ``--resume`` / ``--overwrite`` and ``--quiet`` (``--no-progress``)."""
    group = parser.add_argument_group("where tracks run, and the results folder")
    group.add_argument("--workers", type=positive_int, default=1,
                       help="local processes over tracks (default 1: this process)")
    group.add_argument("--cluster", default=None, metavar="ADDRESS",
                       help="run the tracks on a Dask cluster: a scheduler address (tcp://host:8786), a scheduler "
                            "file (JSON), or local:N for a LocalCluster of N worker processes on this machine "
                            "(needs the 'dask' extra)")
    again = group.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true",
                       help="finish the run in --out: skip the tracks it completed (same dataset, config and "
                            "version, checked against its manifest.json)")
    again.add_argument("--overwrite", action="store_true",
                       help="replace the results of a previous run in --out (only its own files are removed)")
    group.add_argument("-q", "--quiet", "--no-progress", dest="no_progress", action="store_true",
                       help="no progress bar (one per track on stderr, shown only when stderr is a terminal)")
    parser.set_defaults(run_parser=parser)


def run_options(args: argparse.Namespace) -> dict:
    """Keyword arguments of ``fit_dataset`` / ``stream_dataset`` / ``fit_dataset_baseline`` from the flags;
    a contradiction is a usage error (exit 2)."""
    from pedx_graph.execution.executors import ExecutorError, parse_local_cluster

    parser = args.run_parser
    if args.cluster is not None:
        if args.workers != 1:
            parser.error("--workers and --cluster exclude each other (use --cluster local:N for N local workers)")
        try:
            parse_local_cluster(args.cluster)
        except ExecutorError as exc:
            parser.error(str(exc))
    return {"workers": args.workers, "cluster": args.cluster, "resume": args.resume, "overwrite": args.overwrite,
            "progress": not args.no_progress, "keep_records": False}


def run_command(args: argparse.Namespace, run: Callable[..., dict], describe: Callable[[dict], str]) -> int:
    """Run ``run(**run_options(args))``; print ``describe(summary)`` (and each failed track) on success.
    An interrupt ends in one line on stderr and its exit code; other errors propagate (one line from
    :func:`pedx_graph.cli.main`)."""
    from pedx_graph.execution.runner import RunInterrupted

    options = run_options(args)
    name = args.run_parser.prog
    redirect = contextlib.nullcontext()
    if options["progress"]:
        from tqdm.contrib.logging import logging_redirect_tqdm
        redirect = logging_redirect_tqdm()
    try:
        with redirect:
            summary = run(**options)
    except RunInterrupted as exc:
        if exc.summary is None:
            print(f"{name}: interrupted before any track ran; nothing written", file=sys.stderr)
        else:
            counts = exc.summary["counts"]
            print(f"{name}: interrupted: {counts['done']} of {counts['tracks']} tracks done ({counts['failed']} "
                  f"failed) in {args.out}; finish with --resume", file=sys.stderr)
        return exc.exit_code
    print(describe(summary))
    for bad in summary["failed"]:
        where = f" frame {bad['frame']}" if "frame" in bad else ""
        print(f"  failed {bad['sequence']}/{bad['tracking_id']}{where} ({bad.get('stage', 'task')}): {bad['error']}")
    counts = summary["counts"]
    return 0 if counts["done"] or not counts["failed"] else 1
