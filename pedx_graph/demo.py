"""``pedx-graph demo``: the main job end to end on the embedded defaults.

Simulates a small PedX-like scene (open body model, procedural gait, no data files needed), fits every
track with the factor-graph estimator (shipped priors), evaluates against the simulator's ground truth and
prints the accuracy table.  Everything is written under ``--out``: ``scene/`` (PedX layout + truth),
``results/`` (PedX SMPL layout, summary.json, fit_config.yaml, eval.json, eval.md).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser("demo", help="simulate a small scene, fit it, print the accuracy table",
                              description=__doc__.splitlines()[0])
    p.add_argument("--out", default="pedx_demo", help="output folder (default: ./pedx_demo)")
    p.add_argument("--seed", type=int, default=0, help="seed of the scene")
    p.add_argument("--pedestrians", type=int, default=4, help="pedestrians in the scene")
    p.add_argument("--frames", type=int, default=20, help="frames (10 Hz)")
    p.add_argument("--workers", type=int, default=2, help="processes over tracks")
    p.add_argument("--config", default=None, help="fit config preset (YAML)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pedx_graph.config import load_config
    from pedx_graph.eval.evaluate import evaluate, write_report
    from pedx_graph.eval.metrics import markdown_table
    from pedx_graph.graph.config import FitConfig
    from pedx_graph.sim.config import SimConfig
    from pedx_graph.sim.simulate import simulate
    from pedx_graph.solvers.fit import fit_dataset

    config = load_config(FitConfig, args.config)            # a bad preset stops the demo before it simulates
    out = Path(args.out)
    scene, results = out / "scene", out / "results"
    t0 = time.perf_counter()
    sim_config = SimConfig()
    sim_config.scene.n_pedestrians = args.pedestrians
    sim_config.scene.n_frames = args.frames
    simulate(scene, sim_config, seed=args.seed, overwrite=True)   # the demo owns its folder: a re-run replaces it
    t1 = time.perf_counter()
    print(f"simulated {args.pedestrians} pedestrians x {args.frames} frames in {t1 - t0:.1f} s -> {scene}")
    summary = fit_dataset(scene, results, config, workers=args.workers, overwrite=True,   # a re-run replaces them
                          progress=True)                    # a bar per track when stderr is a terminal
    t2 = time.perf_counter()
    print(f"fitted {len(summary['tracks'])} tracks ({summary['total_frames']} frames) in {t2 - t1:.1f} s "
          f"({1000 * (t2 - t1) / max(summary['total_frames'], 1):.0f} ms per frame, {args.workers} workers); "
          f"{len(summary['failed'])} failed")
    report = evaluate(results, scene)
    write_report(report, results, title="Demo accuracy")
    print(markdown_table(report, title="Demo accuracy (simulated ground truth)"))
    print(f"results: {results} (PedX SMPL layout, summary.json, eval.md)")
    if summary["tracks"]:                                   # a picture of one track (pedx-graph export)
        from pedx_graph.export.run import ExportConfig, export_results

        first = summary["tracks"][0]["tracking_id"]
        export_results(results, out / "export", scene, ExportConfig(tracks=(first,), overlay_every=10 ** 6))
        seq = summary["tracks"][0]["sequence"]
        print(f"picture: {out / 'export' / 'animation' / seq / f'{seq}_{first}.gif'} "
              f"(top view: {out / 'export' / 'topview' / seq / f'{seq}_{first}.png'}; all tracks: "
              f"pedx-graph export {results})")
    print("next: fit your own data (README, 'Use your own data') or from Python (README, 'Python API'; "
          "examples/fit_simulated_scene.py)")
    return 0 if summary["tracks"] else 1
