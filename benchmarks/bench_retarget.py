"""Retargeting of the CMU pedestrian clips onto SMPL's tree: joint error per clip and time per clip.

Method: every clip of the CMU folder (default ``../shared/mocap/cmu``; ``--motion-dir``) is read, retargeted
(:func:`pedx_graph.motion.retarget_bvh`) and compared joint by joint with the BVH's own joints
(:func:`pedx_graph.motion.retarget.retarget_joint_error`, 14 joints: neck, head, hips, knees, ankles,
shoulders, elbows, wrists; pelvis excluded), as absolute positions and bone by bone (each joint's offset
from its nearest compared ancestor). Two rest skeletons are used:

* ``bvh``: the BVH's own rest geometry on SMPL's tree -- a consistency check of the transfer (should be 0);
* ``body``: the body model's rest joints ``J(0)`` (the shipped open model if present, else the generic
  hand-made skeleton :func:`pedx_graph.motion.generic_rest_joints`) with bone lengths set to the BVH's;
  this error is the rest-pose mismatch between the two skeletons.

Time: wall-clock of read + retarget per clip (median of ``--repeats``). Output:
benchmarks/results/bench_retarget.{json,md}.

    python benchmarks/bench_retarget.py [--motion-dir DIR] [--repeats 3]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from pedx_graph.environment import machine_note
from pedx_graph.motion import default_motion_dir, generic_rest_joints, list_clips, read_bvh, retarget_bvh
from pedx_graph.motion.retarget import bvh_rest_joints, retarget_joint_error
from pedx_graph.utils import atomic_write_json, atomic_write_text

OUT_DIR = Path(__file__).resolve().parent / "results"


def body_rest_joints() -> tuple[np.ndarray, str]:
    """Rest joints of the shipped body model at betas = 0, else the generic skeleton."""
    try:
        from pedx_graph.body.model import BodyModel, default_model_path
        if default_model_path().is_file():
            model = BodyModel.load()
            return model.rest_joints(np.zeros(model.num_betas)), f"body model {default_model_path().name}"
    except Exception:          # body model missing or not importable: fall back
        pass
    return generic_rest_joints(), "generic_rest_joints() (no body model file)"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--motion-dir", type=Path, default=None)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    motion_dir = args.motion_dir or default_motion_dir()
    if motion_dir is None:
        print("no CMU motion folder found; pass --motion-dir")
        return 1
    rest, rest_name = body_rest_joints()
    rows = []
    for info in list_clips(motion_dir, "all"):
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            motion = read_bvh(info.path)
            retarget_bvh(motion)
            times.append(time.perf_counter() - t0)
        exact = retarget_joint_error(motion, bvh_rest_joints(motion), scale_bones=False)
        body = retarget_joint_error(motion, rest)
        rows.append({"clip": info.name, "category": info.category, "frames": motion.num_frames,
                     "holdout": info.holdout, "consistency_mean_mm": exact.mean_mm,
                     "body_mean_mm": body.mean_mm, "body_max_mm": body.max_mm,
                     "body_local_mean_mm": body.local_mean_mm,
                     "body_per_joint_mm": body.per_joint_mm, "seconds": float(np.median(times))})
    means = np.array([r["body_mean_mm"] for r in rows])
    summary = {"clips": len(rows), "rest_skeleton": rest_name,
               "body_mean_mm_over_clips": float(means.mean()), "body_mean_mm_min": float(means.min()),
               "body_mean_mm_max": float(means.max()),
               "consistency_max_mm": float(max(r["consistency_mean_mm"] for r in rows)),
               "body_local_mean_mm_over_clips": float(np.mean([r["body_local_mean_mm"] for r in rows])),
               "seconds_per_clip_median": float(np.median([r["seconds"] for r in rows])),
               "hardware": machine_note()}
    OUT_DIR.mkdir(parents=True, exist_ok=True)
    atomic_write_json(OUT_DIR / "bench_retarget.json", {"summary": summary, "clips": rows})
    joints = list(rows[0]["body_per_joint_mm"])
    per_joint = {j: float(np.mean([r["body_per_joint_mm"][j] for r in rows])) for j in joints}
    lines = ["# CMU -> SMPL retargeting error", "",
             f"Rest skeleton: {rest_name}. Hardware: {summary['hardware']}.", "",
             f"Mean per-joint error over {len(rows)} clips: {summary['body_mean_mm_over_clips']:.1f} mm "
             f"(clip means {summary['body_mean_mm_min']:.1f}-{summary['body_mean_mm_max']:.1f} mm); "
             f"bone by bone (offset from the nearest compared ancestor): "
             f"{summary['body_local_mean_mm_over_clips']:.1f} mm; "
             f"transfer consistency (BVH rest geometry): max {summary['consistency_max_mm']:.2e} mm; "
             f"read + retarget {1000 * summary['seconds_per_clip_median']:.0f} ms per clip (median).", "",
             "| clip | category | frames | mean mm | max mm | bone-by-bone mm | consistency mm |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['clip']}{' (hold-out)' if r['holdout'] else ''} | {r['category']} | {r['frames']} | "
                     f"{r['body_mean_mm']:.1f} | {r['body_max_mm']:.0f} | {r['body_local_mean_mm']:.1f} | "
                     f"{r['consistency_mean_mm']:.1e} |")
    lines += ["", "Mean error per joint over all clips (mm): "
              + ", ".join(f"{j} {v:.0f}" for j, v in per_joint.items()), ""]
    atomic_write_text(OUT_DIR / "bench_retarget.md", "\n".join(lines))
    print("\n".join(lines[:6]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
