"""``pedx-graph stream`` (causal per-frame estimates with iSAM2, smoothed tracks at their end)."""
from __future__ import annotations

import argparse

from pedx_graph.execution.options import add_run_arguments, run_command


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "stream", help="stream a dataset frame by frame (iSAM2 per track, causal estimates + smoothed tracks)",
        description="Feed the frames of every pedestrian track of DATASET in timestamp order to its own "
                    "iSAM2 (one task per track).  Writes the causal estimate after each frame under "
                    "RESULTS/causal (PedX SMPL layout), the smoothed estimate of every track when it ends "
                    "under RESULTS (with covariances), as each track completes, and RESULTS/summary.json "
                    "with the per-update latencies in its timings section; tracks run in this process, on "
                    "--workers local processes or on a Dask --cluster (docs/running.md).")
    p.add_argument("dataset", help="dataset root (the folder holding labels/ and calib/, or its parent)")
    p.add_argument("--out", required=True, help="results folder")
    p.add_argument("--config", default=None, help="YAML preset of the estimator (FitConfig, see configs/)")
    p.add_argument("--stream-config", default=None, help="YAML of the streaming settings (StreamConfig)")
    p.add_argument("--sequence", action="append", default=None, help="only these sequences (repeatable)")
    p.add_argument("--causal-covariance", action="store_true",
                   help="also write covariances with every causal estimate (iSAM2 joint marginals)")
    p.add_argument("--no-marginals", action="store_true", help="skip covariances of the smoothed tracks")
    p.add_argument("--track-timeout", type=float, default=None,
                   help="seconds without observations after which a track ends (default from the config)")
    add_run_arguments(p)
    p.set_defaults(func=_run_stream)


def _run_stream(args: argparse.Namespace) -> int:
    from pedx_graph.config import load_config
    from pedx_graph.config_ranges import check_config
    from pedx_graph.graph.config import FitConfig
    from pedx_graph.solvers.stream import StreamConfig, stream_dataset

    config = load_config(FitConfig, args.config)
    stream_config = load_config(StreamConfig, args.stream_config)
    if args.causal_covariance:
        stream_config.causal_covariance = True
    if args.no_marginals:
        stream_config.marginals = False
    if args.track_timeout is not None:
        stream_config.track_timeout_s = args.track_timeout
    from pedx_graph.preflight import check_fit_setup
    check_config(stream_config, args.stream_config or "<command line>")       # before any output
    check_fit_setup(config, args.dataset, args.config or "<defaults>")

    def describe(summary: dict) -> str:
        lat = summary["timings"].get("update_ms", {})
        return (f"streamed {summary['counts']['done']} of {summary['counts']['tracks']} tracks "
                f"({summary['total_frames']} frames) in {summary['timings']['wall_seconds']:.1f} s; update median "
                f"{lat.get('median', float('nan')):.1f} ms, p90 {lat.get('p90', float('nan')):.1f} ms; "
                f"{len(summary['failed'])} failures; results in {args.out}")

    return run_command(args, lambda **opts: stream_dataset(args.dataset, args.out, config, stream_config,
                                                           sequences=args.sequence, **opts), describe)
