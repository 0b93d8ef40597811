"""Benchmark: how near the simulator's moving cars come to its pedestrians, and how often keeping them clear
retimes a car (seeded; nothing is rendered).

The intersection's two moving cars drive straight across the cross road at constant speed, and about two in five
groups of pedestrians walk on crosswalks over that road.  Per rig (the default one and the ``pedx`` preset) and
seed, the scene and its pedestrians are drawn exactly as ``simulate`` draws them
(:func:`pedx_graph.sim.simulate.plan_scene`: the same random streams; the default motion source), and then:

* with the cars as drawn (``scene.car_clearance_m`` 0, the default): the nearest approach over the frames of
  any present pedestrian's pelvis to any moving car's footprint (:func:`pedx_graph.sim.scene.car_gaps`, 0 =
  the pelvis inside the footprint).  Below 0.3 m the car's body overlaps the walker's (a body reaches ~0.15-0.3 m
  from its pelvis): a car driving through a person;
* per clearance of ``--clearances``: the share of scenes in which
  :func:`~pedx_graph.sim.scene.retime_moving_cars` shifts a car (every simulated file of such a scene
  changes; the other scenes' files stay byte-identical but for ``sim_config.yaml``), and the shifts' sizes.

    python benchmarks/bench_car_clearance.py [--seeds 0-39] [--clearances 0.3,1.0] [--out benchmarks/results]

Writes ``bench_car_clearance.json`` and ``.md``.
"""
from __future__ import annotations

import argparse
import copy
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import cell, hardware, parse_seeds, public_args  # noqa: E402
from pedx_graph.body import BodyModel  # noqa: E402
from pedx_graph.sim.config import SimConfig, pedx_rig_config  # noqa: E402
from pedx_graph.sim.scene import car_gaps, retime_moving_cars  # noqa: E402
from pedx_graph.sim.simulate import plan_scene  # noqa: E402
from pedx_graph.utils import atomic_write_json, atomic_write_text  # noqa: E402

#: A pelvis nearer a car's footprint than this has the car's body overlapping the walker's, metres.
THROUGH_M = 0.3
RIGS = {"default": SimConfig, "pedx": pedx_rig_config}


def scene_row(config: SimConfig, seed: int, body_model, clearances: list[float]) -> dict:
    """One scene's nearest car approach (cars as drawn) and, per clearance, the retiming's shifts (s)."""
    config = copy.deepcopy(config)
    config.scene.car_clearance_m = 0.0
    scene, people = plan_scene(config, seed, body_model)
    fps = config.scene.fps
    pelvis_xy = np.stack([person.world_pelvis_xy for person in people])
    present = np.stack([person.present for person in people])
    nearest = min((float(np.min(np.where(present, car_gaps(car, pelvis_xy, fps), np.inf)))
                   for car in scene.moving_cars), default=float("inf"))
    shifts = {}
    for clearance in clearances:
        trial = copy.deepcopy(scene)
        shifts[f"{clearance:g}"] = retime_moving_cars(trial, pelvis_xy, present, fps, clearance)
    return {"seed": seed, "nearest_m": nearest if np.isfinite(nearest) else None, "shifts_s": shifts}


def summarise(rows: list[dict], clearances: list[float]) -> dict:
    nearest = np.array([r["nearest_m"] for r in rows if r["nearest_m"] is not None])
    out = {"scenes": len(rows), "through_scenes": int(np.sum(nearest < THROUGH_M)),
           "median_nearest_m": float(np.median(nearest)) if len(nearest) else None, "retimed": {}}
    for clearance in clearances:
        key = f"{clearance:g}"
        moved = [abs(s) for r in rows for s in r["shifts_s"][key] if s]
        out["retimed"][key] = {"scenes": sum(1 for r in rows if any(r["shifts_s"][key])), "cars": len(moved),
                               "median_shift_s": float(np.median(moved)) if moved else None,
                               "max_shift_s": float(np.max(moved)) if moved else None}
    return out


def markdown(result: dict) -> str:
    clearances = result["clearances"]
    lines = ["# bench_car_clearance: moving cars and pedestrians in the simulated scenes", "",
             f"Command: `{result['command']}`", "",
             "Method: see the script's docstring.  Per rig, seeds "
             f"{result['seeds'][0]}-{result['seeds'][-1]} drawn as `simulate` draws them (default motion source; "
             "nothing rendered).  'Through': the nearest approach of a present pedestrian's pelvis to a moving "
             f"car's footprint is below {THROUGH_M:g} m with the cars as drawn (scene.car_clearance_m 0, the "
             "default): the car's body overlaps the walker's.  Retimed: scenes in which keeping each car that "
             "far from every pedestrian shifts one (its crossing moved by whole frame periods).", "",
             "| rig | scenes | through (< 0.3 m) | median nearest approach (m) | "
             + " | ".join(f"retimed at {c:g} m: scenes, cars, median / max shift (s)" for c in clearances) + " |",
             "|---|---:|---:|---:|" + "---|" * len(clearances)]
    for rig, s in result["rigs"].items():
        cells = []
        for c in clearances:
            r = s["retimed"][f"{c:g}"]
            cells.append(f"{r['scenes']}, {r['cars']}, {cell(r['median_shift_s'])} / {cell(r['max_shift_s'])}")
        lines.append(f"| {rig} | {s['scenes']} | {s['through_scenes']} | {cell(s['median_nearest_m'], '.2f')} | "
                     + " | ".join(cells) + " |")
    lines += ["", f"Hardware: {result['hardware']}; {result['total_seconds']:.0f} s.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="0-39", help="seeds and inclusive ranges, comma-separated")
    parser.add_argument("--clearances", default="0.3,1.0", help="comma list of car clearances, metres")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    seeds = parse_seeds(args.seeds)
    clearances = [float(x) for x in args.clearances.split(",")]
    t0 = time.perf_counter()
    body_model = BodyModel.load(SimConfig().body_model)
    result = {"seeds": seeds, "clearances": clearances, "through_m": THROUGH_M, "rigs": {}, "scenes": {}}
    for rig, make in RIGS.items():
        rows = [scene_row(make(), seed, body_model, clearances) for seed in seeds]
        result["scenes"][rig] = rows
        result["rigs"][rig] = summarise(rows, clearances)
    result.update(command=" ".join(["python benchmarks/bench_car_clearance.py"] + public_args(argv)),
                  hardware=hardware(), total_seconds=time.perf_counter() - t0)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "bench_car_clearance.json", result)
    text = markdown(result)
    atomic_write_text(out / "bench_car_clearance.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
