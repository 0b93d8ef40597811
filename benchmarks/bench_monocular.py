"""Body-size depth of one-camera pedestrians (``pedx_graph.graph.monocular``): error vs reported sigma.

Instances: the shipped body model with betas ~ N(0, 1) clipped at 2.5 (the simulator's), a pose drawn from
a motion source (``gait``: the procedural walk / jog / stand; ``cmu``: the CMU hold-out clips when the
motion folder exists, never the clips the pose prior was trained on), a random heading, feet on the ground,
at 5-45 m from a rectified camera of the PedX rig's focal length (3300 px) 1.5 m above the ground; the
left or the right image (alternating), every keypoint labelled and visible with Gaussian click noise of
``click_px`` (the estimator told the same).  Truth: the rectified depth of the true hips' mid-point.

Per distance bin: median / mean / RMS relative error, the mean reported sigma (relative), NEES (mean of
``(error / sigma)^2``, calibrated: 1) and the share inside +-1.96 sigma (calibrated: 95 %).

    python benchmarks/bench_monocular.py [--seed 0] [--instances 1000] [--click-px 2 4]

Writes ``bench_monocular.json`` and ``bench_monocular.md`` into ``--out``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests"))                      # tests/factor_testing.py

from _common import hardware, public_args  # noqa: E402
from factor_testing import make_test_calibration  # noqa: E402
from pedx_graph.body import BodyModel  # noqa: E402
from pedx_graph.data.types import View2D  # noqa: E402
from pedx_graph.graph.monocular import body_size_prior, monocular_depth  # noqa: E402
from pedx_graph.keypoints import PEDX_KEYPOINTS  # noqa: E402
from pedx_graph.utils import atomic_write_json, atomic_write_text  # noqa: E402

_IDX = {n: i for i, n in enumerate(PEDX_KEYPOINTS)}
CLIP_TO_WORLD = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])     # clip Y up -> world z up
BINS = ((5, 15), (15, 25), (25, 35), (35, 45))


def pose_pool(source: str, model) -> np.ndarray | None:
    """(N, 72) poses of a motion source (clip world, Y up), or None when the source is absent."""
    rest = model.rest_joints(np.zeros(model.num_betas))
    if source == "gait":
        from pedx_graph.motion.gait import procedural_gait

        return np.concatenate([procedural_gait(kind, speed, duration=3.0, seed=s, rest_joints=rest).body_pose_aa
                               for kind, speed in (("walk", 0.9), ("walk", 1.2), ("walk", 1.4), ("walk", 1.7),
                                                   ("jog", 2.8), ("stand", 0.0)) for s in range(3)])
    from pedx_graph.motion.bvh import read_bvh
    from pedx_graph.motion.clips import default_motion_dir, list_clips
    from pedx_graph.motion.retarget import retarget_bvh

    if default_motion_dir() is None:
        return None
    return np.concatenate([retarget_bvh(read_bvh(c.path), rest_joints=rest).body_pose_aa[::5]
                           for c in list_clips(split="holdout") if c.category == "walk"])


def run(source: str, poses: np.ndarray, model, prior, calib, instances: int, click_px: float, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    rows = []
    for i in range(instances):
        betas = np.clip(rng.standard_normal(model.num_betas), -2.5, 2.5)
        pose = poses[rng.integers(len(poses))].copy()
        world_R = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)).as_matrix() @ CLIP_TO_WORLD \
            @ Rotation.from_rotvec(pose[:3]).as_matrix()
        pose[:3] = Rotation.from_matrix(world_R).as_rotvec()
        distance = rng.uniform(5.0, 45.0)
        lowest = model.forward(pose, betas).vertices[:, 2].min()
        kp = model.keypoints(pose, betas) + np.array([distance, rng.uniform(-0.25, 0.25) * distance, -lowest])
        side = ("left", "right")[i % 2]
        uv = calib.project(kp)[0 if side == "left" else 1] + rng.normal(scale=click_px, size=(18, 2))
        est = monocular_depth(View2D(uv, np.ones(18, dtype=bool)), calib, side, prior,
                              world_up=np.array([0.0, 0.0, 1.0]), sigma_px=click_px)
        truth = float(calib.world_to_rect(kp[[_IDX["lhip"], _IDX["rhip"]]].mean(axis=0))[2])
        rows.append((truth, np.nan, np.nan) if est is None else (truth, est.depth_m, est.sigma_m))
    data = np.array(rows)
    out = {"source": source, "click_px": click_px, "instances": instances,
           "no_estimate": int(np.isnan(data[:, 1]).sum()), "bins": []}
    data = data[np.isfinite(data[:, 1])]
    for lo, hi in BINS + ((5, 45),):
        sel = (data[:, 0] >= lo) & (data[:, 0] < hi)
        truth, depth, sigma = data[sel].T
        rel = (depth - truth) / truth
        z = (depth - truth) / sigma
        out["bins"].append({"bin": f"{lo}-{hi} m" if (lo, hi) != (5, 45) else "all", "n": int(sel.sum()),
                            "median_error_pct": float(100 * np.median(rel)),
                            "mean_error_pct": float(100 * np.mean(rel)),
                            "rms_error_pct": float(100 * np.sqrt(np.mean(rel ** 2))),
                            "mean_sigma_pct": float(100 * np.mean(sigma / truth)),
                            "nees": float(np.mean(z ** 2)), "coverage_95": float(np.mean(np.abs(z) < 1.96))})
    return out


def to_markdown(result: dict) -> str:
    lines = ["# bench_monocular: body-size depth of one-camera pedestrians", "",
             f"`{result['command']}`", "", "Instances, truth and metrics: see the script's docstring. "
             "NEES and coverage judge the reported sigma (calibrated: 1 and 95 %).", ""]
    for run_ in result["runs"]:
        lines += [f"## poses: {run_['source']}, click noise {run_['click_px']} px ({run_['instances']} instances,"
                  f" {run_['no_estimate']} without an estimate)", "",
                  "| distance | n | median error % | mean error % | RMS error % | mean sigma % | NEES | 95 % coverage |",
                  "|---|---|---|---|---|---|---|---|"]
        for b in run_["bins"]:
            lines.append(f"| {b['bin']} | {b['n']} | {b['median_error_pct']:.2f} | {b['mean_error_pct']:.2f} | "
                         f"{b['rms_error_pct']:.2f} | {b['mean_sigma_pct']:.2f} | {b['nees']:.2f} | "
                         f"{100 * b['coverage_95']:.1f} |")
        lines.append("")
    for source in result.get("skipped_sources", []):
        lines.append(f"Source `{source}` skipped: not available on this machine.")
    lines += ["", f"Hardware: {result['hardware']}", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--instances", type=int, default=1000)
    ap.add_argument("--click-px", type=float, nargs="+", default=[2.0, 4.0])
    ap.add_argument("--sources", nargs="+", default=["gait", "cmu"], choices=["gait", "cmu"])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    model = BodyModel.load()
    prior = body_size_prior(model)
    calib = make_test_calibration(focal_px=3300.0, baseline_m=0.3)
    result = {"command": "python benchmarks/bench_monocular.py " +
              " ".join(public_args(argv if argv is not None else sys.argv[1:])), "seed": args.seed, "runs": [],
              "skipped_sources": []}
    for source in args.sources:
        poses = pose_pool(source, model)
        if poses is None:
            result["skipped_sources"].append(source)
            continue
        for click in args.click_px:
            result["runs"].append(run(source, poses, model, prior, calib, args.instances, click, args.seed))
    result["hardware"] = hardware()
    out = Path(args.out)
    atomic_write_json(out / "bench_monocular.json", result)
    atomic_write_text(out / "bench_monocular.md", to_markdown(result))
    print(to_markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
