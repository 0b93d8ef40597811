"""Simulator speed and label statistics: 10 pedestrians x 100 frames with the default configuration.

Method: :func:`pedx_graph.sim.simulate` with ``SimConfig()`` (full HDL-32E-like sweep: 32 x 2000 rays,
both stereo pairs, right images labelled) on the shipped open body model (``--body-model`` to override),
procedural gait (``--motion-dir`` for BVH clips), seed 0, into a temporary folder.  Figures: wall-clock seconds
for the whole run (planning + all frames + writing), per frame, and per phase (cProfile-free: the phases are
timed by wrapping the simulator's entry points) and CPU seconds (this process + workers, less sensitive to
other jobs on a shared machine); label statistics from ``summary.json`` and ``truth/``
(segment precision = share of a segment's points whose ray really hit that person; visible-keypoint rate).
Target: <= 60 s on the 2-core development machine.  Output: benchmarks/results/bench_sim.{json,md}
(``--workers N`` > 1: bench_sim_workersN.{json,md}, without the per-phase times).

    python benchmarks/bench_sim.py [--pedestrians 10] [--frames 100] [--seed 0] [--workers 1] [--body-model FILE]
"""
from __future__ import annotations

import argparse
import importlib
import json
import os
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from pedx_graph.environment import machine_note
from pedx_graph.sim import SimConfig, simulate
from pedx_graph.utils import atomic_write_json, atomic_write_text

OUT_DIR = Path(__file__).resolve().parent / "results"


def _timed(module, name: str, totals: dict) -> None:
    """Wrap ``module.name`` so its cumulative wall time lands in ``totals[name]``."""
    original = getattr(module, name)

    def wrapper(*args, **kwargs):
        t0 = time.perf_counter()
        try:
            return original(*args, **kwargs)
        finally:
            totals[name] += time.perf_counter() - t0

    setattr(module, name, wrapper)


def _cpu_seconds() -> float:
    """CPU seconds used so far by this process and its finished child processes (user + system)."""
    import resource

    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def label_statistics(out: Path) -> dict:
    """Segment precision per instance, visible-keypoint rate, distance range of labelled instances."""
    precision, distances, n_vis, n_lab = [], [], 0, 0
    for path in sorted((out / "truth").glob("*/*.json")):
        record = json.loads(path.read_text())
        for person in record["people"].values():
            if not person.get("labelled"):
                continue
            distances.append(person["distance_m"])
            if person.get("n_segment_points"):
                precision.append(person["n_segment_points_on_person"] / person["n_segment_points"])
            for view in person["views"].values():
                if view.get("labelled"):
                    n_vis += view["visible"].count("1")
                    n_lab += len(view["visible"])
    return {"segment_precision_median": float(np.median(precision)) if precision else None,
            "segment_precision_mean": float(np.mean(precision)) if precision else None,
            "visible_keypoint_rate": n_vis / n_lab if n_lab else None,
            "labelled_distance_m": [float(np.min(distances)), float(np.median(distances)), float(np.max(distances))]
            if distances else None}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pedestrians", type=int, default=10)
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--body-model", default=None)
    parser.add_argument("--motion-dir", default=None)
    parser.add_argument("--workers", type=int, default=1, help="processes over frames (phase times need 1)")
    args = parser.parse_args(argv)

    from pedx_graph.body import BodyModel
    from pedx_graph.sim import lidar

    sim_mod = importlib.import_module("pedx_graph.sim.simulate")   # the module (the package exports the function)

    body = BodyModel.load(args.body_model)
    config = SimConfig()
    config.scene.n_pedestrians = args.pedestrians
    config.scene.n_frames = args.frames
    config.motion.motion_dir = args.motion_dir
    totals: dict[str, float] = defaultdict(float)
    for module, name in ((sim_mod, "plan_pedestrians"), (sim_mod, "RayScene"), (lidar, "sweep"),
                         (sim_mod, "_label_person_in_view"), (sim_mod, "write_scene_points"),
                         (sim_mod, "write_label2d"), (sim_mod, "npz_bytes")):
        _timed(module, name, totals)
    with tempfile.TemporaryDirectory() as tmp:
        t0, c0 = time.perf_counter(), _cpu_seconds()
        summary = simulate(Path(tmp) / "sim", config, seed=args.seed, body_model=body, workers=args.workers)
        seconds = time.perf_counter() - t0
        cpu_seconds = _cpu_seconds() - c0
        stats = label_statistics(Path(tmp) / "sim")
    phases = {"plan_pedestrians (shapes, motions, placement, LBS for foot contact)": totals["plan_pedestrians"],
              "Embree scene build (all meshes, per frame)": totals["RayScene"],
              "LiDAR sweep (ray cast + noise)": totals["sweep"],
              "labelling (silhouettes, visibility, polygons, noise)": totals["_label_person_in_view"],
              "writing scene PLY": totals["write_scene_points"], "writing 2D label JSON": totals["write_label2d"],
              "truth NPZ encoding": totals["npz_bytes"]}
    result = {
        "method": "simulate(SimConfig()) with n_pedestrians/n_frames from the command line, seed "
                  f"{args.seed}, full 32 x 2000-ray sweeps, both pairs, right images labelled, "
                  f"{args.workers} worker process(es)",
        "workers": args.workers,
        "body_model": Path(body.source).name, "body_vertices": body.num_vertices, "body_faces": int(len(body.faces)),
        "motion": args.motion_dir or "procedural gait",
        "pedestrians": args.pedestrians, "frames": args.frames,
        "seconds_total": seconds, "seconds_per_frame": seconds / args.frames, "target_seconds": 60.0,
        "cpu_seconds_total": cpu_seconds,
        "phase_seconds": phases, "summary": {k: v for k, v in summary.items() if k != "seconds"},
        "label_statistics": stats,
        "hardware": machine_note(),
        "load_average_1min_at_end": os.getloadavg()[0],
    }
    if args.workers > 1:
        result.pop("phase_seconds")          # measured in the parent only: meaningless with workers
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    name = "bench_sim" if args.workers == 1 else f"bench_sim_workers{args.workers}"
    atomic_write_json(OUT_DIR / f"{name}.json", result)
    s = result["summary"]
    lines = [
        "# Simulator benchmark", "",
        f"Method: {result['method']}; body model `{Path(str(body.source)).name}` ({body.num_vertices} vertices, "
        f"{len(body.faces)} faces); motion: {result['motion']}.", "",
        f"Hardware: {result['hardware']}; 1-min load average at the end {result['load_average_1min_at_end']:.1f} "
        "(the machine is shared: wall times scale with the load).", "",
        "| figure | value |", "|---|---|",
        f"| pedestrians x frames | {args.pedestrians} x {args.frames} |",
        f"| total wall time | {seconds:.1f} s (target <= 60 s) |",
        f"| per frame | {seconds / args.frames * 1000:.0f} ms |",
        f"| CPU time (this process + workers) | {cpu_seconds:.1f} s |",
        f"| 2D labels / segments / SMPL labels | {s['labels_2d']} / {s['segments']} / {s['smpl_labels']} |",
        f"| LiDAR points per frame | {s['lidar_points'] / args.frames:.0f} |",
        f"| LiDAR points on people per frame | {s['person_lidar_points'] / args.frames:.1f} |",
        f"| segment precision (all points) | {s['segment_precision']:.3f} |" if s["segment_precision"] else "",
        f"| segment precision per instance, median | {stats['segment_precision_median']:.3f} |"
        if stats["segment_precision_median"] is not None else "",
        f"| visible keypoints among labelled | {stats['visible_keypoint_rate']:.3f} |"
        if stats["visible_keypoint_rate"] is not None else "",
        f"| labelled distance min / median / max | "
        f"{' / '.join(f'{d:.1f}' for d in stats['labelled_distance_m'])} m |" if stats["labelled_distance_m"] else "",
    ]
    if args.workers == 1:
        lines += ["", "Phases (wall time, s):", "", "| phase | seconds |", "|---|---|"]
        lines += [f"| {k} | {v:.2f} |" for k, v in phases.items()]
    lines.append("")
    atomic_write_text(OUT_DIR / f"{name}.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
