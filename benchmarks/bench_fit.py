"""Benchmark of the batch fit: accuracy per distance bin and speed vs track length (seeded).

Accuracy: four simulated scenes, the simulator's pedestrian distances centred on each distance bin (held-out
CMU motion when ../shared/mocap/cmu exists, else the procedural gait), every track fitted with batch LM,
MPJPE global and root-relative pooled over the scenes, overall and per distance bin.
Speed: slow walkers (0.5 m/s, procedural gait) simulated for 200 frames, the longest track cut to
25/50/100/200 frames and fitted on one core (wall and CPU time); at 50 frames every LM variant: the
Python-driven LM with batched linearization or over ``graph.linearize``, with the chain solve or GTSAM's QR,
and gtsam's own optimiser.

    python benchmarks/bench_fit.py [--seed 0] [--pedestrians 10] [--frames 50] [--out benchmarks/results]

Writes ``bench_fit.json`` and ``bench_fit.md`` into ``--out``.
"""
from __future__ import annotations

import argparse
import copy
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import hardware, public_args  # noqa: E402
from pedx_graph.data.reader import read_dataset  # noqa: E402
from pedx_graph.eval.evaluate import evaluate_arrays  # noqa: E402
from pedx_graph.eval.metrics import DISTANCE_BINS, markdown_table, summarise  # noqa: E402
from pedx_graph.graph.config import FitConfig  # noqa: E402
from pedx_graph.sim.config import SimConfig  # noqa: E402
from pedx_graph.sim.simulate import simulate  # noqa: E402
from pedx_graph.solvers.fit import _context, fit_dataset, fit_track  # noqa: E402
from pedx_graph.utils import atomic_write_json, atomic_write_text  # noqa: E402

SHARED_CMU = ROOT.parent / "shared" / "mocap" / "cmu"


def sim_config(pedestrians: int, frames: int) -> SimConfig:
    cfg = SimConfig()
    cfg.scene.n_pedestrians = pedestrians
    cfg.scene.n_frames = frames
    if SHARED_CMU.is_dir():
        cfg.motion.motion_dir = str(SHARED_CMU)
        cfg.motion.split = "holdout"
    return cfg


def accuracy(seed: int, pedestrians: int, frames: int, workers: int, work: Path) -> dict:
    """One scene per distance bin (the simulator's distance weighting centred on the bin), pooled."""
    arrays, scenes = [], []
    t_sim = t_fit = 0.0
    n_tracks = n_failed = n_frames = 0
    per_track = []
    for b, (lo, hi) in enumerate(DISTANCE_BINS):
        scene, results = work / f"scene{b}", work / f"results{b}"
        cfg = sim_config(pedestrians, frames)
        cfg.scene.distance_mean_m = 0.5 * (lo + hi)
        cfg.scene.distance_std_m = 0.35 * (hi - lo)
        t0 = time.perf_counter()
        simulate(scene, cfg, seed=seed + b)
        t1 = time.perf_counter()
        summary = fit_dataset(scene, results, FitConfig(), workers=workers)
        t2 = time.perf_counter()
        t_sim += t1 - t0
        t_fit += t2 - t1
        n_tracks += len(summary["tracks"])
        n_failed += len(summary["failed"])
        n_frames += summary["total_frames"]
        frames_of = {(t["sequence"], t["tracking_id"]): t["frames"] for t in summary["tracks"]}
        per_track += [t["seconds"] / max(frames_of[(t["sequence"], t["tracking_id"])], 1)
                      for t in summary["timings"]["tracks"]]
        arr, _ = evaluate_arrays(results, scene)
        arrays.append(arr)
        scenes.append({"seed": seed + b, "distance_mean_m": cfg.scene.distance_mean_m,
                       "distance_std_m": cfg.scene.distance_std_m, "tracks": len(summary["tracks"]),
                       "frames": summary["total_frames"]})
    pooled = summarise(*(np.concatenate([a[i] for a in arrays]) for i in range(4)))
    return {"simulate_seconds": t_sim, "fit_wall_seconds": t_fit, "workers": workers, "scenes": scenes,
            "tracks": n_tracks, "failed": n_failed, "frames": n_frames,
            "median_ms_per_frame_per_track": 1000 * float(np.median(per_track)) if per_track else None,
            "eval": pooled, "motion": "CMU hold-out clips" if SHARED_CMU.is_dir() else "procedural gait"}


#: The LM variants timed at 50 frames: (label, backend, linearization, linear solver).
VARIANTS = (("python LM, batched linearization, chain solve (default)", "python", "batched", "chain"),
            ("python LM over graph.linearize, chain solve", "python", "graph", "chain"),
            ("python LM over graph.linearize, GTSAM QR solve", "python", "graph", "gtsam"),
            ("gtsam LevenbergMarquardtOptimizer", "gtsam", "graph", "gtsam"))


def _timed_fit(track, config, ctx, repeats: int) -> dict:
    """Best of ``repeats`` fits (wall and CPU seconds of this process; covariances/diagnostics off)."""
    best = None
    for _ in range(repeats):
        cpu0, wall0 = time.process_time(), time.perf_counter()
        res = fit_track(track, config, ctx)
        cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
        if best is None or cpu < best["cpu_seconds"]:
            flips = res.extra_track.get("flips", {})
            best = {"seconds": wall, "cpu_seconds": cpu, "iterations": res.iterations,
                    "final_error": res.final_error, "flip_segments_tried": len(flips.get("tried", [])),
                    "flip_segments_accepted": len(flips.get("accepted", []))}
    n = len(track.frames)
    best.update(frames=n, ms_per_frame=1000 * best["seconds"] / n, cpu_ms_per_frame=1000 * best["cpu_seconds"] / n)
    return best


def speed(seed: int, work: Path, repeats: int = 3) -> dict:
    scene = work / "speed_scene"
    cfg = sim_config(3, 200)
    cfg.scene.speed_mean_mps = 0.5        # slow walkers stay in view for the 200-frame track
    cfg.scene.speed_std_mps = 0.05
    cfg.motion.motion_dir = None          # procedural gait: speed as configured
    simulate(scene, cfg, seed=seed + 1)
    tracks = sorted(read_dataset(scene), key=len, reverse=True)
    track = tracks[0]
    rows = []
    config = FitConfig()
    config.covariances = config.diagnostics = False        # the solve only (marginals: bench_solvers)
    ctx = _context(config)
    lengths = [n for n in (25, 50, 100, 200) if n <= len(track)]
    if len(track) < 200 and len(track) > lengths[-1]:
        lengths.append(len(track))            # the longest the scene gave
    for length in lengths:
        sub = copy.copy(track)
        sub.frames = track.frames[:length]
        fit_track(sub, config, ctx)           # warm-up (imports, caches)
        for label, backend, linearization, solver in (VARIANTS if length == 50 else VARIANTS[:1]):
            cfg_v = copy.deepcopy(config)
            cfg_v.solver.backend, cfg_v.solver.linearization, cfg_v.solver.linear_solver = \
                backend, linearization, solver
            row = _timed_fit(sub, cfg_v, ctx, repeats if length <= 100 else 2)
            row["variant"] = label
            rows.append(row)
    return {"track_frames_available": len(track), "repeats": repeats, "rows": rows}


def to_markdown(result: dict) -> str:
    acc = result["accuracy"]
    lines = ["# Batch fit benchmark", "",
             f"Command: `{result['command']}`  ", f"Hardware: {result['hardware']}  ",
             f"Seed {result['seed']}; four scenes (one centred on each distance bin, seeds seed..seed+3), each "
             f"{result['pedestrians']} pedestrians x {result['frames']} frames, "
             f"motion: {acc['motion']}; {acc['tracks']} tracks fitted ({acc['failed']} failed), "
             f"{acc['frames']} frames; fit wall time {acc['fit_wall_seconds']:.1f} s with {acc['workers']} workers.",
             "", markdown_table(acc["eval"], title="Accuracy (MPJPE, mm)"), "## Speed (one core, one track)", "",
             "The longest track of a slow-walker scene (procedural gait) cut to each length; staged LM as "
             "`pedx-graph fit` runs it, covariances and diagnostics off; BLAS one thread; best of "
             f"{result['speed'].get('repeats', 1)} runs by CPU time (longest track: best of 2).  CPU = this "
             "process's CPU time (robust to other jobs on a shared machine); wall = elapsed; flips = limb depth-flip "
             "candidates tried / kept after the staged fit (0 / 0: the track was not gated in).", "",
             "| frames | LM variant | wall s | wall ms/frame | CPU ms/frame | iterations | flips | final error |",
             "|---:|---|---:|---:|---:|---:|---:|---:|"]
    for row in result["speed"]["rows"]:
        lines.append(f"| {row['frames']} | {row['variant']} | {row['seconds']:.2f} | {row['ms_per_frame']:.1f} | "
                     f"{row['cpu_ms_per_frame']:.1f} | {row['iterations']} | "
                     f"{row.get('flip_segments_tried', 0)} / {row.get('flip_segments_accepted', 0)} | "
                     f"{row['final_error']:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pedestrians", type=int, default=10)
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--repeats", type=int, default=5, help="speed: best of this many fits per length (<= 100 frames)")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        result = {"command": "python benchmarks/bench_fit.py " + " ".join(public_args(argv if argv is not None else sys.argv[1:])),
                  "seed": args.seed, "pedestrians": args.pedestrians,
                  "frames": args.frames,
                  "accuracy": accuracy(args.seed, args.pedestrians, args.frames, args.workers, work),
                  "speed": {"rows": []} if args.skip_speed else speed(args.seed, work, args.repeats)}
        result["hardware"] = hardware()
    out = Path(args.out)
    atomic_write_json(out / "bench_fit.json", result)
    atomic_write_text(out / "bench_fit.md", to_markdown(result))
    print(to_markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
