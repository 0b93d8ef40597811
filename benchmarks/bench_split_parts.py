"""Benchmark: a person split in two by a bottom-up detector — how well the association's joining test tells its
own two parts from other people's (seeded; the measurement behind ``AssociationConfig.join_row_sigma`` and
``join_column_sigma``).

Method: the detection benchmark's two scenes (:func:`bench_detections.scene_configs`, CMU hold-out motion when
../shared is there) simulated with OpenPose BODY_25 and BODY_25B output and ``split_prob`` (every split
person's upper body and hips-and-legs written as two people, truth kind ``part``), for ``--seeds`` seeds.  In
every image, every detection with upper-body keypoints only and every one with hip and leg keypoints only (as
the association reads them: rectified, below ``min_confidence`` left out) are paired, and
:func:`pedx_graph.detections.association.join_misfit` gives each pair's row RMS and column offset (fractions
of the fitted height).  Reported: their quantiles over the pairs that are one person's two parts and over
the others, and what :func:`~pedx_graph.detections.association.join_split_parts` makes of each image: one
person's parts joined, two people's parts joined, one person's parts left apart.

    python benchmarks/bench_split_parts.py [--seeds 0,1,2] [--split-prob 0.15] [--out benchmarks/results]

Writes ``bench_split_parts.json`` and ``bench_split_parts.md`` into ``--out``.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import hardware, public_args  # noqa: E402
from bench_detections import read_format, scene_configs  # noqa: E402
from pedx_graph.data.calib import read_calibrations  # noqa: E402
from pedx_graph.detections.association import (AssociationConfig, _usable, join_misfit,  # noqa: E402
                                               join_split_parts)
from pedx_graph.detections.evaluate import detection_records, read_detection_truth  # noqa: E402
from pedx_graph.detections.undistort import rectified  # noqa: E402
from pedx_graph.keypoints import lower_body_mask  # noqa: E402
from pedx_graph.sim.config import DETECTOR_FORMATS  # noqa: E402
from pedx_graph.sim.simulate import simulate  # noqa: E402
from pedx_graph.utils import atomic_write_json, atomic_write_text  # noqa: E402

FORMATS = ("openpose_body25", "openpose_body25b")
QUANTILES = (50, 90, 99, 100)


def _person(records: list[dict]) -> str | None:
    """The one person all records are parts of, else None."""
    people = {r.get("tracking_id") if r["kind"] == "part" else None for r in records}
    return people.pop() if len(people) == 1 else None


def measure(scene: Path, sequence: str, config: AssociationConfig) -> dict:
    calibs = read_calibrations(scene / "calib")
    own, other = [], []
    joins = {"own_parts_joined": 0, "two_people_joined": 0, "own_parts_left_apart": 0}
    for fmt in FORMATS:
        keypoint_set = DETECTOR_FORMATS[fmt]
        lower = lower_body_mask(keypoint_set)
        records = read_detection_truth(scene, sequence, fmt)
        index = {(r["camera"], r["frame"], r["index"]): r for r in records}
        images = defaultdict(list)
        for det in read_format(scene, fmt, sequence):
            uv = _usable(rectified(det, calibs), det.confidence, config.min_confidence)
            images[(det.camera, det.frame)].append((det, uv))
        for items in images.values():
            truth = {id(det): detection_records(det, records, index)[0] for det, _ in items}
            present = [np.all(np.isfinite(uv), axis=1) for _, uv in items]
            uppers = [k for k, p in enumerate(present) if p[~lower].sum() >= 2 and not p[lower].any()]
            lowers = [k for k, p in enumerate(present) if p[lower].sum() >= 2 and not p[~lower].any()]
            for i in uppers:
                for j in lowers:
                    misfit = join_misfit(items[i][1], items[j][1], keypoint_set)
                    if misfit is not None:
                        same = _person([truth[id(items[i][0])], truth[id(items[j][0])]]) is not None
                        (own if same else other).append(misfit)
            split_people = {truth[id(items[k][0])]["tracking_id"] for k in uppers
                            if truth[id(items[k][0])]["kind"] == "part"} & \
                {truth[id(items[k][0])]["tracking_id"] for k in lowers if truth[id(items[k][0])]["kind"] == "part"}
            joined_people = set()
            for det, _ in join_split_parts(items, config):
                if " + " not in det.source:
                    continue
                person = _person(detection_records(det, records, index))
                if person is None:
                    joins["two_people_joined"] += 1
                else:
                    joins["own_parts_joined"] += 1
                    joined_people.add(person)
            joins["own_parts_left_apart"] += len(split_people - joined_people)
    return {"own": own, "other": other, "joins": joins}


def _quantiles(values: list) -> dict:
    if not values:
        return {}
    arr = np.asarray(values, dtype=float)
    return {name: {str(q): float(np.percentile(arr[:, k], q)) for q in QUANTILES}
            for k, name in enumerate(("row_rms", "column_offset"))}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--split-prob", type=float, default=0.15)
    parser.add_argument("--pedestrians", type=int, default=10)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    config = AssociationConfig()
    t0 = time.perf_counter()
    own, other = [], []
    joins: dict[str, int] = defaultdict(int)
    with tempfile.TemporaryDirectory(prefix="bench_split_parts_") as tmp:
        for seed in (int(s) for s in args.seeds.split(",")):
            for offset, (name, cfg) in enumerate(scene_configs(args.pedestrians, args.frames,
                                                               detector_split_prob=args.split_prob).items()):
                cfg.detections.formats = FORMATS
                scene = Path(tmp) / f"s{seed}_{name}"
                simulate(scene, cfg, seed=seed + offset, workers=2)
                part = measure(scene, cfg.scene.sequence, config)
                own += part["own"]
                other += part["other"]
                for key, value in part["joins"].items():
                    joins[key] += value
    result = {"seeds": args.seeds, "split_prob": args.split_prob, "pedestrians": args.pedestrians,
              "frames": args.frames, "pairs_own": len(own), "pairs_other": len(other),
              "own": _quantiles(own), "other": _quantiles(other),
              "other_within_gates": int(sum(1 for r, c in other if r <= config.gate_sigmas * config.join_row_sigma
                                            and c <= config.gate_sigmas * config.join_column_sigma)),
              "joins": dict(joins), "join_row_sigma": config.join_row_sigma,
              "join_column_sigma": config.join_column_sigma, "gate_sigmas": config.gate_sigmas,
              "seconds": time.perf_counter() - t0, "hardware": hardware(),
              "command": " ".join(["python benchmarks/bench_split_parts.py"] + public_args(argv))}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "bench_split_parts.json", result)
    atomic_write_text(out / "bench_split_parts.md", markdown(result))
    print(markdown(result))
    return 0


def markdown(result: dict) -> str:
    lines = ["# bench_split_parts: joining a person a bottom-up detector split in two", "",
             f"Command: `{result['command']}`", "", f"Hardware: {result['hardware']}; {result['seconds']:.0f} s.", "",
             f"Method: see the script's docstring (seeds {result['seeds']}, both scenes of the detection "
             f"benchmark, OpenPose BODY_25 and BODY_25B, split probability {result['split_prob']:g}).", "",
             "| pairs (upper part, legs) in one image | count | row RMS q50 / q90 / q99 / max | "
             "column offset q50 / q90 / q99 / max |", "|---|---:|---|---|"]
    for key, label in (("own", "one person's two parts"), ("other", "parts of two people")):
        q = result[key]
        cells = [" / ".join(f"{q[name][str(p)]:.3f}" for p in QUANTILES) if q else "" for name in
                 ("row_rms", "column_offset")]
        lines.append(f"| {label} | {result['pairs_' + key]} | {cells[0]} | {cells[1]} |")
    joins = result["joins"]
    lines += ["", f"Gates (`gate_sigmas` x sigma): row RMS {result['gate_sigmas'] * result['join_row_sigma']:.3f}, "
              f"column offset {result['gate_sigmas'] * result['join_column_sigma']:.3f}; pairs of two people "
              f"within both: {result['other_within_gates']} of {result['pairs_other']} (the best-fitting pairs "
              "are joined first, so most of these lose to the person's own part).", "",
              f"`join_split_parts` on every image: {joins.get('own_parts_joined', 0)} people joined from their own "
              f"two parts, {joins.get('two_people_joined', 0)} joins of two people's parts, "
              f"{joins.get('own_parts_left_apart', 0)} people whose two parts were both there and left apart."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    sys.exit(main())
