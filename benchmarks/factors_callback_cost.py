"""Cost of the pedx-graph factors' Python callbacks: graph.linearize / graph.error over 100 factors.

Method: 100 frames of a standing, walking-like pedestrian (seeded random pose near zero), one factor of the
measured kind per frame (per consecutive pair for the temporal prior), all on one ``NonlinearFactorGraph``;
``graph.error`` (residual only) at a new estimate, ``graph.linearize`` at that same estimate (LM's pattern:
the chamfer factor then reuses its matches) and ``graph.linearize`` at another new estimate are timed
``--repeats`` times in process CPU time (single-threaded BLAS; CPU time is robust to other jobs on a shared
machine, wall time is not); the median divided by the number of factors is reported in microseconds per
factor (the callbacks dominate; GTSAM's own overhead is included).  Body model: a synthetic SMPL-format model
(``tests/synthetic_model.py``) with SMPL's vertex count (6890) unless ``--vertices`` says
otherwise.  Output: benchmarks/results/factors_callback_cost.{json,md}.

    python benchmarks/factors_callback_cost.py [--frames 100] [--repeats 3] [--vertices 6890]
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")           # one thread: CPU time then equals the callbacks' own work
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))     # tests/synthetic_model.py

import gtsam  # noqa: E402
import numpy as np  # noqa: E402

from factors import (FrameKeys, FrameState, StereoKeypoints, make_heading_prior_factor, make_joint_limit_factor,
                     make_lidar_chamfer_factor, make_pose_prior_factor, make_shape_prior_factor,
                     make_stereo_reprojection_factor, make_temporal_prior_factor, make_translation_prior_factor)
from factors.common import MaxMixture
from factors.temporal_prior import TEMPORAL_DIM
from factor_testing import frame_values, make_test_calibration, random_gmm, standing_rotation
from pedx_graph.environment import cpu_name, library_versions, machine_note
from pedx_graph.utils import atomic_write_json, atomic_write_text, make_rng
from synthetic_model import synthetic_body_model  # noqa: E402

OUT_DIR = Path(__file__).resolve().parent / "results"


def build(num_frames: int, num_vertices: int, seed: int):
    rng = make_rng(seed)
    model = synthetic_body_model(num_vertices=num_vertices, seed=seed)
    calib = make_test_calibration()
    states, values, keys = [], gtsam.Values(), []
    betas = rng.normal(scale=0.5, size=10)
    values.insert(gtsam.symbol("b", 0), betas)
    for i in range(num_frames):
        k = FrameKeys.for_frame(i)
        s = FrameState.from_arrays(standing_rotation(2.8 + 0.01 * i), np.array([8.0, 0.4 + 0.05 * i, 0.9]),
                                   rng.normal(scale=0.15, size=69), betas)
        v = frame_values(k.as_list(), s.world_R_body, s.trans, s.body_pose, s.betas)
        values.insert(k.root, v.atRot3(k.root))
        values.insert(k.trans, v.atVector(k.trans))
        values.insert(k.body_pose, v.atVector(k.body_pose))
        states.append(s)
        keys.append(k)
    return rng, model, calib, states, values, keys


def factor_sets(rng, model, calib, states, keys):
    pose_mix = MaxMixture(*random_gmm(rng, 8, 69))
    temp_mix = MaxMixture(*random_gmm(rng, 10, TEMPORAL_DIM))
    sets = {}
    lidar = []
    stereo = []
    for s in states:
        out = model.forward(s.full_pose, s.betas, s.trans)
        left, right = calib.project(out.keypoints)
        stereo.append(StereoKeypoints(left + rng.normal(size=left.shape), right + rng.normal(size=right.shape),
                                      np.ones(18, bool), np.ones(18, bool)))
        ids = rng.choice(out.vertices.shape[0], 300, replace=False)
        lidar.append(out.vertices[ids] + rng.normal(scale=0.01, size=(300, 3)))
    sets["stereo_reprojection (36 rows)"] = [make_stereo_reprojection_factor(k, model, m, calib)
                                             for k, m in zip(keys, stereo)]
    sets["lidar_chamfer (300 points, all vertices)"] = [make_lidar_chamfer_factor(k, model, p)
                                                       for k, p in zip(keys, lidar)]
    cand = np.arange(0, model.num_vertices, 4)
    sets["lidar_chamfer (300 points, 1/4 of vertices)"] = [
        make_lidar_chamfer_factor(k, model, p, candidate_vertex_ids=cand) for k, p in zip(keys, lidar)]
    up, sensor = np.array([0.0, 0.0, 1.0]), np.zeros(3)          # the synthetic frames' z-up world
    sets["translation_prior"] = [make_translation_prior_factor(k.trans, k.betas, model, p, world_up=up,
                                                               world_p_sensor=sensor)
                                 for k, p in zip(keys, lidar)]
    sets["heading_prior"] = [make_heading_prior_factor(k.root, 2.8, speed=1.2, world_R_level=np.eye(3))
                             for k in keys]
    sets["pose_prior (K=8)"] = [make_pose_prior_factor(k.body_pose, mixture=pose_mix) for k in keys]
    sets["joint_limits"] = [make_joint_limit_factor(k.body_pose) for k in keys]
    sets["shape_prior (native)"] = [make_shape_prior_factor(k.betas) for k in keys]
    sets["temporal_prior (K=10)"] = [
        make_temporal_prior_factor(a.root, a.trans, a.body_pose, b.root, b.trans, b.body_pose, mixture=temp_mix)
        for a, b in zip(keys[:-1], keys[1:])]
    return sets


def _shifted(values, keys, offset):
    """A copy of ``values`` with every frame's trans moved by ``offset`` m (defeats the chamfer match memo)."""
    out = gtsam.Values(values)
    for k in keys:
        out.update(k.trans, values.atVector(k.trans) + offset)
    return out


def time_set(factors, values, keys, repeats):
    graph = gtsam.NonlinearFactorGraph()
    for f in factors:
        graph.add(f)
    graph.linearize(values)                          # warm-up
    err, lin_cold, lin_after = [], [], []
    for rep in range(repeats):
        fresh = _shifted(values, keys, 1e-4 * (rep + 1))
        t0 = time.process_time()
        graph.error(fresh)                           # residual only, at a new estimate
        err.append(time.process_time() - t0)
        t0 = time.process_time()
        graph.linearize(fresh)                       # Jacobians at the estimate just evaluated (LM's pattern)
        lin_after.append(time.process_time() - t0)
        other = _shifted(values, keys, -1e-4 * (rep + 1))
        t0 = time.process_time()
        graph.linearize(other)                       # Jacobians at a new estimate
        lin_cold.append(time.process_time() - t0)
    n = len(factors)
    per = lambda xs: 1e6 * float(np.median(xs)) / n
    return {"factors": n, "error_us_per_factor": per(err), "linearize_us_per_factor": per(lin_cold),
            "linearize_after_error_us_per_factor": per(lin_after)}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--vertices", type=int, default=6890)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng, model, calib, states, values, keys = build(args.frames, args.vertices, args.seed)
    results = {name: time_set(fs, values, keys, args.repeats)
               for name, fs in factor_sets(rng, model, calib, states, keys).items()}
    report = {
        "method": "median process CPU time over repeats of graph.error / graph.linearize over one factor per "
                  "frame at fresh estimates, divided by the number of factors (Python callbacks included), "
                  "single-threaded BLAS",
        "frames": args.frames, "repeats": args.repeats, "vertices": args.vertices, "seed": args.seed,
        "hardware": {"machine": platform.machine(), "processor": cpu_name(), "cpus": os.cpu_count(),
                     "python": platform.python_version(), "gtsam": getattr(gtsam, "__version__", "?"),
                     "libraries": library_versions(), "note": machine_note()},
        "results": results,
    }
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    atomic_write_json(OUT_DIR / "factors_callback_cost.json", report)
    lines = ["# Factor callback cost", "", report["method"] + ".", "",
             f"{args.frames} frames, synthetic SMPL-format body model with {args.vertices} vertices, "
             f"seed {args.seed}. Hardware: {report['hardware']['note']}. Shared machine: expect noise.", "",
             "| factor | n | error µs/factor | linearize µs/factor | linearize after error at the same estimate |",
             "|---|---|---|---|---|"]
    for name, r in results.items():
        lines.append(f"| {name} | {r['factors']} | {r['error_us_per_factor']:.0f} | {r['linearize_us_per_factor']:.0f} "
                     f"| {r['linearize_after_error_us_per_factor']:.0f} |")
    atomic_write_text(OUT_DIR / "factors_callback_cost.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return report


if __name__ == "__main__":
    main()
