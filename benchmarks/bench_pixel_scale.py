"""Benchmark: detections made on resized images, or written in normalised coordinates, told from the files and
checked against the LiDAR (seeded; ``pedx_graph.detections.pixel_scale``).

Per rig (the default one and the ``pedx`` preset) and seed, small scenes are simulated (``--pedestrians`` x
``--frames``, OpenPose BODY_25 and COCO files) with the simulated detector run on the images resized by
``detections.image_scale`` (1, 0.75, 0.5) and, at 1, writing normalised coordinates
(``detections.pixel_units``: ``unit``, ``signed_unit``).  Each input is read as the import reads it and passed
to :func:`~pedx_graph.detections.pixel_scale.detector_pixels` (default config, the scene's point clouds, the
up axis from the calibration) in the cases a user meets:

* ``as written``: the files alone (OpenPose has no image size; the COCO image list gives the resized one);
* ``no sizes`` (COCO): the image list's ``width`` / ``height`` left out;
* ``told``: OpenPose with the resize given (``pixel_scale.scale``);
* ``told twice`` (OpenPose, written at 0.5): the resize given for pixels that are the calibration's (the
  scene written at 1 told 0.5).

Each case is right when the import accepts pixels it reads correctly (every camera's scale within 0.5 % of
the truth and the units right) or refuses pixels it would read wrongly; a refusal's ``best_scale`` (from the
LiDAR) is compared with the true factor between the pixels as read and the calibration's.

    python benchmarks/bench_pixel_scale.py [--seeds 0-4] [--workers 2] [--out benchmarks/results]

Writes ``bench_pixel_scale.json`` and ``.md``.
"""
from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import hardware, parse_seeds, public_args, rows_per_seed, write_outputs  # noqa: E402

RIGS = ("default", "pedx")
#: (image_scale, pixel_units) the simulated detector writes.
WRITTEN = ((1.0, "pixels"), (0.75, "pixels"), (0.5, "pixels"), (1.0, "unit"), (1.0, "signed_unit"))
FORMATS = ("openpose_body25", "coco")


def _scene(out: Path, rig: str, scale: float, units: str, seed: int, pedestrians: int, frames: int) -> Path:
    from pedx_graph.sim.config import SimConfig, pedx_rig_config
    from pedx_graph.sim.simulate import simulate

    config = SimConfig() if rig == "default" else pedx_rig_config()
    config.scene.n_pedestrians, config.scene.n_frames = pedestrians, frames
    config.detections.formats = FORMATS
    config.detections.image_scale = scale
    config.detections.pixel_units = units
    simulate(out, config, seed=seed, workers=1)
    return out


def _cases(fmt: str, scale: float, units: str):
    """(case name, detections transform, config.scale, the factor the pixels as read are off by)."""
    from pedx_graph.detections.pixel_scale import PixelScaleConfig

    yield "as written", None, PixelScaleConfig(), (1.0 if fmt == "coco" or units != "pixels" else scale)
    if fmt == "coco":
        yield "no sizes", "strip", PixelScaleConfig(), (1.0 if units != "pixels" else scale)
    elif units == "pixels":
        yield "told", None, PixelScaleConfig(scale=scale), 1.0
        if scale == 1.0:
            yield "told twice", None, PixelScaleConfig(scale=0.5), 2.0


def run_seed(seed: int, pedestrians: int, frames: int) -> list[dict]:
    """Every rig and written scale of one seed (module docstring): one row per format and case."""
    from bench_association import read_format
    from pedx_graph.data.calib import read_calibrations
    from pedx_graph.data.ground import ground_from_calibrations
    from pedx_graph.data.types import DataFormatError
    from pedx_graph.detections.importer import _Clouds
    from pedx_graph.detections.pixel_scale import detector_pixels

    logging.disable(logging.WARNING)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for rig in RIGS:
            for scale, units in WRITTEN:
                root = _scene(Path(tmp) / f"{rig}_{scale:g}_{units}", rig, scale, units, seed, pedestrians, frames)
                seq = next((root / "truth" / "detections").iterdir()).name
                calibrations = read_calibrations(root / "calib")
                up = ground_from_calibrations(calibrations, seq).world_up
                clouds = _Clouds(root, seq, cache_mb=2000)
                for fmt in FORMATS:
                    read = read_format(root, fmt, seq)
                    for case, transform, config, off_by in _cases(fmt, scale, units):
                        dets = read if transform is None else [dataclasses.replace(d, image_size=None) for d in read]
                        t0 = time.perf_counter()
                        try:
                            _, record = detector_pixels(dets, calibrations, config, clouds, seq, up)
                            refused, message = False, ""
                        except DataFormatError as exc:
                            record, refused, message = None, True, str(exc)
                        seconds = time.perf_counter() - t0
                        row = {"seed": seed, "rig": rig, "written_scale": scale, "written_units": units,
                               "format": fmt, "case": case, "told_scale": config.scale, "refused": refused,
                               "reads_right": off_by == 1.0, "seconds": seconds}
                        if refused:
                            row["message"] = message.replace(str(root), "<scene>")     # no machine paths
                            # the LiDAR's preferred factor, as the error states it
                            best = message.split("pixels are ")[1].split(" x")[0] if "pixels are " in message else None
                            row["best_scale"] = float(best) if best else None
                        else:
                            cams = record["cameras"].values()
                            truth = (scale, scale) if units == "pixels" else (1.0, 1.0)
                            row["scale_error"] = max(abs(s / t - 1.0) for c in cams for s, t in zip(c["scale"], truth))
                            row["units_read"] = sorted({c["units"] for c in cams})
                            every = record["lidar_check"].get("all pairs", {})
                            row.update({k: every.get(k) for k in ("people", "people_on_lidar", "best_scale",
                                                                  "people_on_lidar_at_best",
                                                                  "people_on_lidar_elsewhere")})
                        if off_by == 1.0:
                            row["right"] = (not refused and row["scale_error"] <= 0.005
                                            and row["units_read"] == [units])
                        else:
                            row["right"] = refused
                            row["best_scale_error"] = (abs(row["best_scale"] / off_by - 1.0)
                                                       if row.get("best_scale") else None)
                        rows.append(row)
    return rows


def summarise(rows: list[dict]) -> list[dict]:
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for row in rows:
        groups[(row["rig"], row["format"], row["written_scale"], row["written_units"], row["case"])].append(row)
    out = []
    for (rig, fmt, scale, units, case), group in sorted(groups.items()):
        best_errors = [r["best_scale_error"] for r in group if r.get("best_scale_error") is not None]
        margins = [r["people_on_lidar_elsewhere"] / r["people_on_lidar"] for r in group
                   if not r["refused"] and r.get("people_on_lidar")]
        out.append({"rig": rig, "format": fmt, "written_scale": scale, "written_units": units, "case": case,
                    "max_elsewhere_ratio": max(margins) if margins else None,
                    "inputs": len(group), "reads_right": group[0]["reads_right"],
                    "right": sum(r["right"] for r in group), "refused": sum(r["refused"] for r in group),
                    "median_best_scale_error": float(np.median(best_errors)) if best_errors else None,
                    "median_seconds": float(np.median([r["seconds"] for r in group]))})
    return out


def markdown(result: dict) -> str:
    lines = ["# bench_pixel_scale: resized images and normalised coordinates, told from the files and the LiDAR", "",
             f"Command: `{result['command']}`", "",
             f"Method: see the script's docstring.  Seeds {', '.join(map(str, result['seeds']))}; "
             f"{result['pedestrians']} pedestrians x {result['frames']} frames per scene.  'Written': the factor the "
             "simulated detector's images were resized by and its coordinates' units; 'read right': whether the "
             "pixels as the import would read them are the calibration's (then they must be accepted, else "
             "refused); 'LiDAR's factor off': a refusal's factor against the true one (median); 'elsewhere': for "
             "accepted inputs, the most people any scale beyond 10 % of the one used puts on the LiDAR's returns, "
             "over those the scale used puts there (the largest over the seeds; the check refuses at 2).", "",
             "| rig | format | written | case | read right | right / inputs | refused | LiDAR's factor off | "
             "elsewhere | median time (ms) |", "|---|---|---|---|---|---:|---:|---:|---:|---:|"]
    for s in result["summary"]:
        written = f"{s['written_scale']:g} x, {s['written_units'].replace('_', ' ')}"
        off = f"{100 * s['median_best_scale_error']:.1f} %" if s["median_best_scale_error"] is not None else "-"
        elsewhere = f"{s['max_elsewhere_ratio']:.2f}" if s["max_elsewhere_ratio"] is not None else "-"
        lines.append(f"| {s['rig']} | {s['format']} | {written} | {s['case']} | {'yes' if s['reads_right'] else 'no'} "
                     f"| {s['right']} / {s['inputs']} | {s['refused']} | {off} | {elsewhere} "
                     f"| {1000 * s['median_seconds']:.0f} |")
    total = sum(s["right"] for s in result["summary"])
    inputs = sum(s["inputs"] for s in result["summary"])
    lines += ["", f"Right: {total} of {inputs} inputs.", "",
              f"Hardware: {result['hardware']}; {result['total_seconds']:.0f} s with {result['workers']} "
              "worker(s).", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="0-4", help="seeds and inclusive ranges, comma-separated")
    parser.add_argument("--pedestrians", type=int, default=8)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2, help="processes, one seed each")
    parser.add_argument("--name", default="bench_pixel_scale")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    seeds = parse_seeds(args.seeds)
    t0 = time.perf_counter()
    rows = rows_per_seed(run_seed, seeds, args.workers, args.pedestrians, args.frames)
    result = {"seeds": seeds, "pedestrians": args.pedestrians, "frames": args.frames, "workers": args.workers,
              "summary": summarise(rows), "rows": rows,
              "command": " ".join(["python benchmarks/bench_pixel_scale.py"] + public_args(argv)),
              "hardware": hardware(), "total_seconds": time.perf_counter() - t0}
    write_outputs(args.out, args.name, result, markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
