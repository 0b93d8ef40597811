"""Benchmark of the stance-foot ground-contact term (factors/ground_contact.py): accuracy with and without it.

The scenes of benchmarks/bench_fit.py (one simulated scene centred on each distance bin, seeds
seed..seed+3, held-out CMU motion when ../shared/mocap/cmu exists, else the procedural gait) are fitted with
the default configuration and with ``NoiseConfig.ground_contact_sigma_m`` set to each ``--sigmas`` value;
MPJPE global and root-relative pooled over the scenes, overall and per distance bin, and the ankles'
errors.  The ground plane is the one the reader derives per sequence (``Track.ground``); frames of a
sequence without a fitted plane get no ground-contact factor (counted).

    python benchmarks/bench_ground_contact.py [--seed 0] [--pedestrians 8] [--frames 40] [--sigmas 0.03 0.06]
                                              [--kerb-m 0.15]

``--kerb-m``: the same fits with the ground plane given ``kerb_m`` below the one derived from the scene — the
pedestrians on a kerb above the road plane a LiDAR fit finds (the simulator's ground is flat and its
pedestrians always have a foot on it, the very assumption of the term; this row shows what a wrong plane
costs).

Writes ``bench_ground_contact.json`` and ``.md`` into ``--out``.
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

from _common import cell, hardware, public_args  # noqa: E402
from bench_fit import sim_config  # noqa: E402
from pedx_graph.data.reader import read_dataset  # noqa: E402
from pedx_graph.eval.evaluate import evaluate_arrays  # noqa: E402
from pedx_graph.eval.metrics import DISTANCE_BINS, summarise  # noqa: E402
from pedx_graph.graph.config import FitConfig  # noqa: E402
from pedx_graph.sim.simulate import simulate  # noqa: E402
from pedx_graph.solvers.fit import fit_dataset  # noqa: E402
from pedx_graph.utils import atomic_write_json, atomic_write_text  # noqa: E402


def scenes(seed: int, pedestrians: int, frames: int, work: Path) -> list[dict]:
    """Simulate the four distance-bin scenes; the ground planes the reader derives for them."""
    out = []
    for b, (lo, hi) in enumerate(DISTANCE_BINS):
        path = work / f"scene{b}"
        cfg = sim_config(pedestrians, frames)
        cfg.scene.distance_mean_m = 0.5 * (lo + hi)
        cfg.scene.distance_std_m = 0.35 * (hi - lo)
        simulate(path, cfg, seed=seed + b)
        grounds = {t.sequence: t.ground for t in read_dataset(path)}
        first = next(iter(grounds.values()))
        out.append({"path": path, "seed": seed + b, "sequences": len(grounds),
                    "world_up": [float(x) for x in first.world_up], "ground_offset_m": first.ground_offset_m,
                    "with_plane": sum(g is not None and g.ground_offset_m is not None for g in grounds.values()),
                    "sources": sorted({g.source for g in grounds.values() if g is not None})})
    return out


def variant(label: str, sigma_m: float, scene_list: list[dict], workers: int, work: Path,
            plane_below_feet_m: float = 0.0) -> dict:
    """Fit every scene with ``ground_contact_sigma_m = sigma_m``; ``plane_below_feet_m`` > 0: the ground plane
    given to the fit lies that far below the one derived from the scene (pedestrians on a kerb above the
    road plane the LiDAR fit finds)."""
    config = FitConfig()
    config.noise.ground_contact_sigma_m = float(sigma_m)
    arrays, n_tracks, t0 = [], 0, time.perf_counter()
    for b, sc in enumerate(scene_list):
        results = work / f"{label}-results{b}"
        cfg = copy.deepcopy(config)
        if plane_below_feet_m:
            cfg.ground.world_up = tuple(sc["world_up"])
            cfg.ground.ground_offset_m = sc["ground_offset_m"] - plane_below_feet_m
        summary = fit_dataset(sc["path"], results, cfg, workers=workers)
        n_tracks += len(summary["tracks"])
        arrays.append(evaluate_arrays(results, sc["path"])[0])
    pooled = summarise(*(np.concatenate([a[i] for a in arrays]) for i in range(4)))
    return {"label": label, "ground_contact_sigma_m": float(sigma_m), "plane_below_feet_m": plane_below_feet_m,
            "tracks": n_tracks,
            "fit_wall_seconds": time.perf_counter() - t0, "eval": pooled}


def _row(v: dict) -> str:
    ev = v["eval"]
    ankles = [ev["per_joint"][j] for j in ("lankl", "rankl")]
    bins = " | ".join(cell(ev["per_distance"][k]["global_mm"]) for k in ev["per_distance"])
    return (f"| {v['label']} | {cell(ev['overall']['global_mm'])} | {cell(ev['overall']['root_relative_mm'])} | "
            f"{cell(np.mean([a['global_mm'] for a in ankles]))} | "
            f"{cell(np.mean([a['root_relative_mm'] for a in ankles]))} | {bins} |")


def to_markdown(result: dict) -> str:
    first = result["variants"][0]["eval"]["per_distance"]
    lines = ["# Ground-contact term benchmark", "",
             f"Command: `{result['command']}`  ",
             f"Hardware: {result['hardware']}  ",
             f"Seed {result['seed']}; the four scenes of bench_fit (one centred on each distance bin), each "
             f"{result['pedestrians']} pedestrians x {result['frames']} frames; sequences with a fitted ground plane: "
             f"{sum(s['with_plane'] for s in result['scenes'])} of {sum(s['sequences'] for s in result['scenes'])} "
             f"(sources: {', '.join(sorted({x for s in result['scenes'] for x in s['sources']}))}).", "",
             "MPJPE in millimetres, visibility-weighted; ankles: mean of the two ankle joints; bins: global MPJPE "
             "per distance bin.", "",
             "| variant | global | root-relative | ankles global | ankles root-rel. | "
             + " | ".join(f"{k} m" for k in first) + " |",
             "|---|" + "---:|" * (4 + len(first))]
    lines += [_row(v) for v in result["variants"]]
    lines += ["", f"Verdict: {result['verdict']}", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pedestrians", type=int, default=8)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--sigmas", type=float, nargs="+", default=[0.03, 0.06],
                    help="ground_contact_sigma_m values to compare with the default (off), metres")
    ap.add_argument("--kerb-m", type=float, default=0.15,
                    help="also fit with the ground plane this far below the feet (a kerb), metres; 0: not")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        scene_list = scenes(args.seed, args.pedestrians, args.frames, work)
        variants = [variant("off (sigma 0)", 0.0, scene_list, args.workers, work)]
        variants += [variant(f"on, sigma {s:g} m", s, scene_list, args.workers, work) for s in args.sigmas]
        if args.kerb_m > 0:
            variants += [variant(f"on, sigma {s:g} m, plane {args.kerb_m:g} m below the feet", s, scene_list,
                                 args.workers, work, args.kerb_m) for s in args.sigmas]
    base = variants[0]["eval"]["overall"]
    best = min((v for v in variants[1:] if not v["plane_below_feet_m"]), key=lambda v: v["eval"]["overall"]["global_mm"])
    gain = base["global_mm"] - best["eval"]["overall"]["global_mm"]
    gain_rel = base["root_relative_mm"] - best["eval"]["overall"]["root_relative_mm"]
    helps = gain > 0.02 * base["global_mm"] and gain_rel >= 0.0
    verdict = (f"best '{best['label']}' changes visible MPJPE by {-gain:+.1f} mm global, {-gain_rel:+.1f} mm "
               f"root-relative against off: " + ("it helps (> 2 % global, root-relative not worse)." if helps
                                                 else "it does not help enough (needs > 2 % global and a "
                                                      "root-relative error not worse); the term stays off."))
    kerb = [v for v in variants if v["plane_below_feet_m"]]
    if kerb:
        worst = max(kerb, key=lambda v: v["eval"]["overall"]["global_mm"])
        verdict += (f" With the plane {args.kerb_m:g} m below the feet, '{worst['label']}' gives "
                    f"{worst['eval']['overall']['global_mm']:.1f} mm global, "
                    f"{worst['eval']['overall']['root_relative_mm']:.1f} mm root-relative (off: "
                    f"{base['global_mm']:.1f}, {base['root_relative_mm']:.1f}).")
    result = {"command": "python benchmarks/bench_ground_contact.py "
                         + " ".join(public_args(argv if argv is not None else sys.argv[1:])),
              "seed": args.seed, "pedestrians": args.pedestrians, "frames": args.frames,
              "scenes": [{k: v for k, v in s.items() if k != "path"} for s in scene_list],
              "variants": variants, "helps": bool(helps), "verdict": verdict, "hardware": hardware()}
    out = Path(args.out)
    atomic_write_json(out / "bench_ground_contact.json", result)
    atomic_write_text(out / "bench_ground_contact.md", to_markdown(result))
    print(to_markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
