"""``pedx-graph noise``: print a dataset's label and LiDAR noise measured from the data (one table)."""
from __future__ import annotations

import argparse
import json
import math


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "noise", help="measure a dataset's per-keypoint click noise and LiDAR range noise",
        description="Estimate each keypoint's click noise from the vertical disparity of stereo clicks and the "
                    "LiDAR range noise from the segments of DATASET (pedx_graph.data.noise_estimate), and print "
                    "them with the sigmas a fit with --config would use: a markdown table, or JSON.")
    p.add_argument("dataset", help="dataset root (the folder holding labels/ and calib/, or its parent)")
    p.add_argument("--config", default=None, help="fit YAML preset whose noise settings apply (see configs/)")
    p.add_argument("--sequence", action="append", default=None, help="only these sequences (repeatable)")
    p.add_argument("--json", action="store_true", help="print the summary.json record as JSON instead")
    p.set_defaults(func=_run_noise)


def _run_noise(args: argparse.Namespace) -> int:
    from pedx_graph.config import load_config
    from pedx_graph.data.noise_estimate import estimate_noise, resolve_noise
    from pedx_graph.data.reader import read_dataset
    from pedx_graph.graph.config import FitConfig

    config = load_config(FitConfig, args.config)
    from pedx_graph.preflight import check_dataset
    check_dataset(args.dataset)
    reader_config = getattr(config, "reader_config", None)        # the fit's reader settings (fps, ground)
    tracks = read_dataset(args.dataset, sequences=args.sequence,
                          config=reader_config() if callable(reader_config) else None)
    estimate = estimate_noise(tracks)
    noise = config.noise
    # always measured here; the fit's sigmas as fit_dataset would resolve them with this config
    resolved = resolve_noise(tracks, noise, estimate=estimate)
    record = resolved.record
    if args.json:
        from pedx_graph.utils import to_jsonable

        print(json.dumps(to_jsonable(record), indent=1))
    else:
        print(noise_markdown(record))
    return 0


def _f(value, spec: str) -> str:
    return "-" if value is None or (isinstance(value, float) and not math.isfinite(value)) else format(value, spec)


def noise_markdown(record: dict) -> str:
    """The ``resolve_noise`` record as markdown: one table per keypoint, the pairs, the LiDAR line."""
    est = record.get("estimate") or {}
    kp = record["keypoints"]
    sigma = est.get("keypoint_sigma_px") or {}
    counts = est.get("keypoint_counts") or {}
    pooled = set(est.get("keypoint_pooled") or [])
    clicks = kp.get("click_sigma_px") or {}
    lines = [f"Keypoint click noise (vertical disparity of stereo clicks; {est.get('keypoint_samples', 0)} "
             f"samples, integer clicks: {est.get('integer_clicks')}, outlier fraction "
             f"{_f(est.get('outlier_fraction'), '.3f')}). Fit uses: **{kp['source']}**"
             + (f", model term {kp['model_sigma_px']:.2f} px" if kp.get("model_sigma_px") is not None else "")
             + f"; the fit multiplies the hips' row sigma by {kp.get('hip_sigma_factor', 1.0):g}.",
             "", "| keypoint | samples | estimated px/click | fit click px | fit row sigma px |",
             "|---|---:|---:|---:|---:|"]
    for name, row in kp["row_sigma_px"].items():
        mark = " (pooled)" if name in pooled else ""
        lines.append(f"| {name} | {counts.get(name, 0)} | {_f(sigma.get(name), '.2f')}{mark} | "
                     f"{_f(clicks.get(name), '.2f')} | {row:.2f} |")
    pairs = est.get("pair_offsets") or []
    if pairs:
        lines += ["", "| sequence | pair | samples | offset v_left - v_right px | px/click |",
                  "|---|---|---:|---:|---:|"]
        lines += [f"| {p['sequence']} | {p['pair']} | {p['count']} | {_f(p['offset_px'], '+.2f')} | "
                  f"{_f(p['sigma_px'], '.2f')} |" for p in pairs]
    lidar = record["lidar"]
    lines += ["", f"LiDAR range noise: {_f(est.get('lidar_range_sigma_m'), '.4f')} m from "
              f"{est.get('lidar_count', 0)} local fits in {est.get('lidar_segments', 0)} segments; fit uses: "
              f"**{lidar['source']}**, chamfer sigma {lidar['chamfer_sigma_m']:.4f} m"
              + (f" (range {lidar['range_sigma_m']:.4f}, model {lidar['model_sigma_m']:.4f})"
                 if lidar.get("range_sigma_m") is not None else "")]
    return "\n".join(lines)
