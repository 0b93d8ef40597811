"""Speed of the numpy body model: PedX keypoints + analytic Jacobians, and full-mesh LBS.

Method: seeded random poses (axis-angle ~ N(0, 0.3^2) per joint), betas ~ N(0, 1), trans ~ N(0, 1) for
``--frames`` frames.  Each operation is run once to warm up, then ``--repeats`` times; the minimum and the
median wall time (``time.perf_counter``) and calling-thread CPU time (``time.thread_time``) are divided by
the number of frames.  BLAS is limited to one thread (threadpoolctl) so CPU time measures this process's own
work even on a shared machine.  Operations:

* ``keypoints + Jacobians, batched``: ``BodyModel.point_jacobians(pose, betas, trans)`` over all frames at once
  (18 keypoints; d_root, d_body_pose, d_trans, d_betas);
* ``keypoints + Jacobians, one frame per call``: the same, frame by frame (what a per-frame factor does);
* ``keypoints only, batched``: ``BodyModel.keypoints``;
* ``full-mesh LBS, batched``: ``BodyModel.forward`` (all vertices, joints, keypoints);
* ``300-vertex Jacobians, one frame per call``: ``point_jacobians(..., vertex_ids=300 ids)``.

Body models: the open default model when installed (pedx_graph/body/data/pedx_open_neutral.npz, no pose
correctives), and always a synthetic SMPL-format model with SMPL's 6890 vertices and non-zero pose correctives
(the more expensive case, like a real SMPL file).
Output: benchmarks/results/bench_body.{json,md}.  Targets: keypoints + Jacobians <= 0.3 ms/frame batched;
full-mesh LBS <= 3 ms/frame batched.

    python benchmarks/bench_body.py [--frames 100] [--repeats 7] [--seed 0] [--synthetic]
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from pedx_graph.body import BodyModel
from pedx_graph.body.io import validate_model_arrays
from pedx_graph.body.model import default_model_path
from pedx_graph.environment import cpu_name, library_versions, machine_note
from pedx_graph.utils import atomic_write_json, atomic_write_text, make_rng

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))     # tests/synthetic_model.py
from synthetic_model import synthetic_model_arrays  # noqa: E402

OUT_DIR = Path(__file__).resolve().parent / "results"
TARGETS_MS = {"keypoints + Jacobians, batched": 0.3, "full-mesh LBS, batched": 3.0}


def load_models(force_synthetic: bool, seed: int) -> list[tuple[BodyModel, str]]:
    """The open default model (if installed and not ``force_synthetic``) and the synthetic worst case."""
    models = []
    if not force_synthetic and default_model_path().is_file():
        models.append((BodyModel.load(), "open default model (pedx_open_neutral.npz)"))
    arrays = synthetic_model_arrays(num_vertices=6890, seed=seed, with_keypoint_keys=False)
    models.append((BodyModel.from_data(validate_model_arrays(arrays, source="synthetic-6890")),
                   "synthetic SMPL-format model, 6890 vertices, non-zero posedirs, SMPL keypoint ids"))
    return models


def time_op(fn, repeats: int, frames: int) -> dict:
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.thread_time()
        fn()
        cpu.append(time.thread_time() - c0)
        wall.append(time.perf_counter() - t0)
    per = 1e3 / frames
    return {"wall_ms_per_frame_min": min(wall) * per, "wall_ms_per_frame_median": float(np.median(wall)) * per,
            "cpu_ms_per_frame_min": min(cpu) * per, "cpu_ms_per_frame_median": float(np.median(cpu)) * per}


def run_model(model: BodyModel, frames: int, repeats: int, seed: int) -> dict:
    rng = make_rng(seed)
    pose = rng.normal(scale=0.3, size=(frames, 72))
    betas = rng.normal(size=(frames, model.num_betas))
    trans = rng.normal(size=(frames, 3))
    vertex_ids = rng.choice(model.num_vertices, size=min(300, model.num_vertices), replace=False)
    single = min(frames, 20)

    def per_frame_jac():
        for i in range(single):
            model.point_jacobians(pose[i], betas[i], trans[i])

    def per_frame_vertices():
        for i in range(single):
            model.point_jacobians(pose[i], betas[i], trans[i], vertex_ids=vertex_ids)

    ops = {
        "keypoints + Jacobians, batched": (lambda: model.point_jacobians(pose, betas, trans), frames),
        "keypoints + Jacobians, one frame per call": (per_frame_jac, single),
        "keypoints only, batched": (lambda: model.keypoints(pose, betas, trans), frames),
        "full-mesh LBS, batched": (lambda: model.forward(pose, betas, trans), frames),
        "300-vertex Jacobians, one frame per call": (per_frame_vertices, single),
    }
    results = {}
    with threadpool_limits(limits=1):
        for name, (fn, n) in ops.items():
            results[name] = dict(time_op(fn, repeats, n), frames=n)
            if name in TARGETS_MS:
                results[name]["target_ms_per_frame"] = TARGETS_MS[name]
                results[name]["meets_target_cpu"] = results[name]["cpu_ms_per_frame_min"] <= TARGETS_MS[name]
                results[name]["meets_target_wall"] = results[name]["wall_ms_per_frame_min"] <= TARGETS_MS[name]
    return results


def run(frames: int, repeats: int, seed: int, force_synthetic: bool) -> dict:
    runs = []
    for model, desc in load_models(force_synthetic, seed):
        runs.append({"model": {"description": desc, "num_vertices": model.num_vertices,
                               "posedirs": model.posedirs is not None,
                               "keypoint_source": model.keypoint_map.source},
                     "results": run_model(model, frames, repeats, seed)})
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    return {
        "benchmark": "bench_body",
        "method": ("min / median over repeats of wall and thread CPU time divided by frames; BLAS limited to one "
                   "thread; seeded random poses"),
        "seed": seed, "frames": frames, "repeats": repeats,
        "hardware": {"machine": platform.machine(), "processor": cpu_name(),
                     "cpu_count": os.cpu_count(), "python": platform.python_version(),
                     "numpy": np.__version__, "libraries": library_versions(), "note": machine_note(),
                     "load_average_at_end": list(load) if load else None},
        "runs": runs,
    }


def to_markdown(report: dict) -> str:
    hw = report["hardware"]
    load = [round(x, 2) for x in hw["load_average_at_end"]] if hw["load_average_at_end"] else None
    # results written before the note existed name the cores, Python and numpy only
    machine = hw.get("note") or f"{hw['cpu_count']} CPUs ({hw['machine']}), Python {hw['python']}, numpy {hw['numpy']}"
    lines = [
        "# Body model speed (numpy)",
        "",
        f"Method: {report['method']}; {report['frames']} frames, {report['repeats']} repeats, seed {report['seed']}.",
        f"Hardware: {machine}; load average at the end {load} (a shared machine: wall times are noisy, CPU times less so).",
    ]
    for run in report["runs"]:
        lines += [
            "",
            f"## {run['model']['description']}",
            "",
            "| operation | frames | CPU ms/frame (min) | wall ms/frame (min) | wall ms/frame (median) | target |",
            "|---|---|---|---|---|---|",
        ]
        for name, r in run["results"].items():
            target = "-"
            if "target_ms_per_frame" in r:
                verdict = "met" if r["meets_target_wall"] else ("met in CPU time" if r["meets_target_cpu"]
                                                                else "NOT met")
                target = f"<= {r['target_ms_per_frame']} ({verdict})"
            lines.append(f"| {name} | {r['frames']} | {r['cpu_ms_per_frame_min']:.3f} | "
                         f"{r['wall_ms_per_frame_min']:.3f} | {r['wall_ms_per_frame_median']:.3f} | {target} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--synthetic", action="store_true", help="only the synthetic 6890-vertex model")
    args = parser.parse_args(argv)
    report = run(args.frames, args.repeats, args.seed, args.synthetic)
    atomic_write_json(OUT_DIR / "bench_body.json", report)
    text = to_markdown(report)
    atomic_write_text(OUT_DIR / "bench_body.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
