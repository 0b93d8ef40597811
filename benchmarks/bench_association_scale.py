"""Benchmark: how the association's time grows with people and frames (id-less OpenPose detections, seeded).

Method: the detection benchmark's mixed scene (:func:`bench_detections.scene_configs`: the real rig's two
pairs, walkways with groups, 15 % bystanders, the simulated OpenPose BODY_25 detector with clutter and
fragments) simulated at each size ``people x frames``; then
:func:`pedx_graph.detections.association.associate` on its BODY_25 files with the scene's LiDAR clouds, as
``pedx-graph import`` runs it, timed by wall clock (the fastest of ``--repeats``), with the tracks it finds
and their identity switches (:func:`pedx_graph.detections.evaluate.score_tracks`).  The time of each step is
taken from one profiled run (Python's profiler slows every call alike, so only their shares are reported).
Each further count of ``--workers`` times ``associate(..., workers=N)`` (the stereo pairs' own steps in N local
processes, as ``pedx-graph import --workers N``) the same way, and checks that it finds the same tracks.

    python benchmarks/bench_association_scale.py [--seed 0] [--sizes 10x20,20x40,20x80] [--repeats 1]
                                                 [--workers 1,2] [--out benchmarks/results]

Writes ``bench_association_scale.json`` and ``bench_association_scale.md`` into ``--out``.
"""
from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import hardware, public_args  # noqa: E402
from bench_detections import labelled_instances, read_format, scene_clouds, scene_configs  # noqa: E402
from pedx_graph.data.calib import read_calibrations  # noqa: E402
from pedx_graph.data.ground import ground_from_calibrations  # noqa: E402
from pedx_graph.detections import association  # noqa: E402
from pedx_graph.detections.evaluate import read_detection_truth, score_tracks  # noqa: E402
from pedx_graph.sim.simulate import simulate  # noqa: E402
from pedx_graph.utils import atomic_write_json, atomic_write_text  # noqa: E402

FORMAT = "openpose_body25"
#: Steps of the association whose share of the time is reported (functions of its module).
STEPS = ("camera_tracklets", "pair_tracklets", "stitch_tracks", "repair_swaps", "split_reversals", "_lidar_centre",
         "detection_ranges", "merge_pair_tracks", "move_to_neighbours", "smooth_centres", "separate_people")


def _tracks_key(tracks) -> list:
    """What makes two runs' tracks the same: ids, frames, each frame's detections and centre."""
    return [(t.track_id, [(fr.frame, sorted((cam, d.source) for cam, d in fr.detections.items()),
                           None if fr.world_p is None else fr.world_p.tolist()) for fr in t.frames]) for t in tracks]


def run_size(people: int, frames: int, seed: int, work: Path, repeats: int, workers: tuple[int, ...] = ()) -> dict:
    cfg = scene_configs(people, frames)["mixed"]
    cfg.detections.formats = (FORMAT,)
    scene = work / f"p{people}f{frames}"
    t0 = time.perf_counter()
    simulate(scene, cfg, seed=seed, workers=2)
    simulate_s = time.perf_counter() - t0
    seq = cfg.scene.sequence
    calibs = read_calibrations(scene / "calib")
    clouds = scene_clouds(scene, seq)
    detections = read_format(scene, FORMAT, seq)
    ground = ground_from_calibrations(calibs, seq)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        tracks = association.associate(detections, calibs, clouds=clouds, ground=ground)
        times.append(time.perf_counter() - t0)
    profile = cProfile.Profile()
    profile.enable()
    association.associate(detections, calibs, clouds=clouds, ground=ground)
    profile.disable()
    stats = pstats.Stats(profile).stats
    total = max((v[3] for k, v in stats.items() if k[2] == "associate" and k[0] == association.__file__), default=0.0)
    shares = {}
    for step in STEPS:
        cumulative = sum(v[3] for k, v in stats.items() if k[2] == step and k[0] == association.__file__)
        shares[step] = cumulative / total if total else None
    parallel = {}
    for count in workers:
        times_n = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            found = association.associate(detections, calibs, clouds=clouds, ground=ground, workers=count)
            times_n.append(time.perf_counter() - t0)
        parallel[str(count)] = {"associate_seconds": min(times_n),
                                "same_tracks": _tracks_key(found) == _tracks_key(tracks)}
    score = score_tracks(tracks, read_detection_truth(scene, seq, FORMAT), labelled_instances(scene, seq))
    return {"people": people, "frames": frames, "detections": len(detections), "tracks": len(tracks),
            "id_switches": score["id_switches"], "associate_seconds": min(times), "simulate_seconds": simulate_s,
            "step_shares": shares, "workers": parallel}


def markdown(result: dict) -> str:
    lines = ["# bench_association_scale: association time vs people and frames", "",
             f"Command: `{result['command']}`", "",
             f"Hardware: {result['hardware']}.", "",
             "Method: see the script's docstring (the detection benchmark's mixed scene, simulated OpenPose "
             "BODY_25 files, `associate` with the LiDAR clouds; wall time, the fastest of "
             f"{result['repeats']}; step shares from one profiled run).", "",
             "| people x frames | detections | tracks | id switches | associate (s) | ms per detection | "
             + "".join(f"{n} workers (s) | same tracks | " for n in result.get("workers", []))
             + " | ".join(STEPS) + " |",
             "|---|---:|---:|---:|---:|---:|" + "---:|---|" * len(result.get("workers", [])) + "---:|" * len(STEPS)]
    for row in result["sizes"]:
        shares = " | ".join("" if row["step_shares"][s] is None else f"{100 * row['step_shares'][s]:.0f} %"
                            for s in STEPS)
        parallel = "".join(f"{row['workers'][str(n)]['associate_seconds']:.1f} | "
                           f"{'yes' if row['workers'][str(n)]['same_tracks'] else 'NO'} | "
                           for n in result.get("workers", []))
        lines.append(f"| {row['people']} x {row['frames']} | {row['detections']} | {row['tracks']} | "
                     f"{row['id_switches']} | {row['associate_seconds']:.1f} | "
                     f"{1000 * row['associate_seconds'] / max(row['detections'], 1):.1f} | {parallel}{shares} |")
    lines += ["", "Step shares are of the association's whole time and overlap where one step calls another "
              "(`_lidar_centre` runs inside `pair_tracks`, as do the tracklet steps, `stitch_tracks` and "
              "`repair_swaps`)."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sizes", default="10x20,20x40,20x80", help="people x frames, comma-separated")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--workers", default="1,2",
                        help="worker counts of associate, comma-separated (1: the main column, always run)")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    sizes = [tuple(int(x) for x in item.split("x")) for item in args.sizes.split(",")]
    workers = tuple(sorted({int(x) for x in args.workers.split(",")} - {1}))
    with tempfile.TemporaryDirectory(prefix="bench_association_scale_") as tmp:
        rows = [run_size(p, f, args.seed, Path(tmp), args.repeats, workers) for p, f in sizes]
    result = {"seed": args.seed, "repeats": args.repeats, "workers": list(workers), "sizes": rows,
              "hardware": hardware(),
              "command": " ".join(["python benchmarks/bench_association_scale.py"] + public_args(argv))}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "bench_association_scale.json", result)
    atomic_write_text(out / "bench_association_scale.md", markdown(result))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
