"""Benchmark: every labelled view vs the primary stereo pair only, on pedestrians seen by both pairs (seeded).

The simulator's default rig points its two pairs 90 degrees apart, so almost no pedestrian is seen by both.
Here the second pair (blu79CF-grn43E3) is turned to ``--yaw`` degrees from the first and placed beside it
like the real PedX rig (left cameras ~0.93 m apart, the real pairs' focal lengths and baselines: 3266.7 px /
0.329 m and 3332.5 px / 0.274 m; the simulator's walkways, pedestrians at ~9-41 m; held-out CMU motion when
../shared/mocap/cmu exists, else the procedural gait).  Each scene's tracks are fitted twice with the same
config except ``terms.all_views`` (True: both pairs' images in the reprojection term; False: the frame's
primary pair only), with the LiDAR segments and without them (the reader's ``read_segments=False``: stereo
only, as on the real hold-out copy without point clouds).

Reported on the frames labelled by both pairs (and, as a check, on frames labelled by one pair): the
pelvis' depth error (fitted minus true pelvis along the viewing ray from the primary pair's left camera;
mean and median of its absolute value, and its mean, the bias), global MPJPE over the 13 evaluation joints
and the root-relative MPJPE, overall and per distance bin.

    python benchmarks/bench_views.py [--seed 0] [--scenes 2] [--pedestrians 8] [--frames 12] [--yaw 20]
                                     [--rig overlap|default|pedx] [--out benchmarks/results]

Writes ``bench_views.json`` and ``bench_views.md`` into ``--out`` (``--rig default`` / ``--rig pedx``: the
simulator's rig presets, ``bench_views_<rig>_rig.*``; the default rig's pairs never overlap).
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
from pedx_graph.data.reader import ReaderConfig, read_dataset, read_smpl_labels  # noqa: E402
from pedx_graph.eval.metrics import DISTANCE_BINS, distance_bin, eval_joints, joint_errors  # noqa: E402
from pedx_graph.graph.config import FitConfig  # noqa: E402
from pedx_graph.sim.config import SimConfig, rig_config as sim_rig_config  # noqa: E402
from pedx_graph.sim.simulate import simulate  # noqa: E402
from pedx_graph.solvers.fit import _context, fit_track  # noqa: E402
from pedx_graph.utils import atomic_write_json, atomic_write_text  # noqa: E402

SHARED_CMU = ROOT.parent / "shared" / "mocap" / "cmu"


def rig_config(pedestrians: int, frames: int, yaw_deg: float, rig: str = "overlap") -> SimConfig:
    """The simulator's scene with the two pairs overlapping (see the module docstring); ``rig="default"``:
    the simulator's default rig (pairs 90 degrees apart) unchanged; ``rig="pedx"``: the simulator's real
    PedX rig preset (z-down LiDAR frame, the real cameras, real-label quirks and per-keypoint click noise)."""
    cfg = sim_rig_config(rig) if rig in ("default", "pedx") else SimConfig()
    cfg.scene.n_pedestrians = pedestrians
    cfg.scene.n_frames = frames
    if SHARED_CMU.is_dir():
        cfg.motion.motion_dir = str(SHARED_CMU)
        cfg.motion.split = "holdout"
    if rig in ("default", "pedx"):
        return cfg
    fwd, side = cfg.cameras.forward, cfg.cameras.left
    fwd.focal_px, fwd.baseline_m = 3266.7, 0.329
    side.focal_px, side.baseline_m = 3332.5, 0.274
    side.yaw_deg = float(yaw_deg)
    side.left_camera_xyz = (0.0, -0.9, -0.08)           # ~0.93 m from the first pair's left camera
    return cfg


def _pelvis_and_keypoints(model, pose, betas, trans) -> tuple[np.ndarray, np.ndarray]:
    out = model.forward(pose, betas, trans)
    return np.asarray(out.joints[0]), np.asarray(out.keypoints)


def frame_rows(track, result, truth_labels, model) -> list[dict]:
    """Per fitted frame: both pairs or one, distance, depth error along the ray, global and root-relative
    MPJPE (13 joints, mean over joints)."""
    truth = {lab.frame: lab for lab in truth_labels}
    rows = []
    for i, fr in enumerate(track.frames):
        lab = truth.get(fr.frame)
        if lab is None:
            continue
        pelvis_fit, kp_fit = _pelvis_and_keypoints(model, result.pose[i], result.betas, result.trans[i])
        pelvis_true, kp_true = _pelvis_and_keypoints(model, lab.pose, lab.betas, lab.trans)
        camera = track.calibrations[fr.pair].world_T_cam[:3, 3]
        ray = (pelvis_true - camera) / np.linalg.norm(pelvis_true - camera)
        glob, rel = joint_errors(eval_joints(np.asarray(result.world_keypoints[i])[None]), eval_joints(kp_true[None]))
        up = track.ground.world_up
        offset = pelvis_true - track.ground.world_p_sensor
        pairs = {p for p, _, v in fr.labelled_views() if v.labelled.any()}
        rows.append({"both_pairs": len(pairs) > 1, "images": len(fr.labelled_views()),
                     "distance_m": float(np.linalg.norm(offset - (offset @ up) * up)),
                     "depth_error_m": float((pelvis_fit - pelvis_true) @ ray),
                     "mpjpe_mm": 1000 * float(np.mean(glob)), "rel_mpjpe_mm": 1000 * float(np.mean(rel))})
    return rows


def _stats(rows: list[dict]) -> dict:
    if not rows:
        return {"frames": 0}
    depth = np.array([r["depth_error_m"] for r in rows])
    return {"frames": len(rows), "depth_abs_mean_m": float(np.mean(np.abs(depth))),
            "depth_abs_median_m": float(np.median(np.abs(depth))), "depth_bias_m": float(np.mean(depth)),
            "mpjpe_mm": float(np.mean([r["mpjpe_mm"] for r in rows])),
            "rel_mpjpe_mm": float(np.mean([r["rel_mpjpe_mm"] for r in rows]))}


def summarise_rows(rows: list[dict]) -> dict:
    out = {}
    for subset, keep in (("both_pairs", True), ("one_pair", False)):
        chosen = [r for r in rows if r["both_pairs"] == keep]
        out[subset] = {"all": _stats(chosen)}
        for lo, hi in DISTANCE_BINS:
            label = distance_bin(0.5 * (lo + hi))
            out[subset][label] = _stats([r for r in chosen if distance_bin(r["distance_m"]) == label])
    return out


def run(seed: int, scenes: int, pedestrians: int, frames: int, yaw_deg: float, work: Path,
        rig: str = "overlap") -> dict:
    base = FitConfig()
    base.covariances = False
    base.diagnostics = False
    ctx = _context(base)
    rows: dict[str, list] = {}
    counts = {"tracks": 0, "tracks_with_both_pairs": 0, "frames": 0, "frames_both_pairs": 0}
    seconds: dict[str, float] = {}
    for s in range(scenes):
        scene = work / f"scene{s}"
        simulate(scene, rig_config(pedestrians, frames, yaw_deg, rig), seed=seed + s)
        truth = read_smpl_labels(scene)
        for lidar in (True, False):
            tracks = read_dataset(scene, config=ReaderConfig(read_segments=lidar))
            if lidar:
                counts["tracks"] += len(tracks)
                counts["tracks_with_both_pairs"] += sum(any(fr.other_views for fr in t.frames) for t in tracks)
                counts["frames"] += sum(len(t) for t in tracks)
                counts["frames_both_pairs"] += sum(bool(fr.other_views) for t in tracks for fr in t.frames)
            for all_views in (True, False):
                name = f"{'lidar' if lidar else 'stereo_only'}/{'all_views' if all_views else 'primary_pair'}"
                config = copy.deepcopy(base)
                config.terms.all_views = all_views
                t0 = time.perf_counter()
                for track in tracks:
                    if not any(fr.other_views for fr in track.frames):
                        continue                  # tracks never seen by both pairs fit identically
                    result = fit_track(track, config, ctx)
                    rows.setdefault(name, []).extend(
                        frame_rows(track, result, truth.get((track.sequence, track.tracking_id), []), ctx.model))
                seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - t0
    return {"counts": counts, "variants": {name: summarise_rows(r) for name, r in rows.items()},
            "fit_seconds": seconds, "motion": "CMU hold-out clips" if SHARED_CMU.is_dir() else "procedural gait"}


def markdown(result: dict, command: str) -> str:
    c = result["counts"]
    lines = ["# bench_views: every labelled view vs the primary stereo pair", "",
             f"Command: `{command}`", "",
             f"Scenes: {result['scenes']} x {result['pedestrians']} pedestrians x {result['frames']} frames, "
             + {"overlap": f"second pair turned {result['yaw_deg']:g} deg and 0.93 m beside the first (real "
                           "PedX focal lengths and baselines)",
                "default": "the simulator's default rig (pairs 90 deg apart)",
                "pedx": "the simulator's pedx rig (the real cameras, z-down LiDAR frame, real-label quirks: "
                        "no occlusion flags, per-keypoint click noise, one-camera tracks)"}[result["rig"]]
             + f", {result['motion']}.  {c['tracks']} tracks, {c['tracks_with_both_pairs']} seen by both pairs at some "
             f"frame; {c['frames_both_pairs']} of {c['frames']} labelled frames seen by both pairs.  Only the "
             "tracks with such frames are fitted (the others fit identically either way).", "",
             "Depth error: fitted minus true pelvis along the ray from the primary pair's left camera.", ""]
    for subset, title in (("both_pairs", "Frames labelled by both pairs"), ("one_pair", "Frames labelled by one pair "
                                                                                          "(same tracks)")):
        lines += [f"## {title}", "", "| variant | bin | frames | mean abs depth (m) | median abs depth (m) | "
                  "depth bias (m) | MPJPE (mm) | root-rel. MPJPE (mm) |", "|---|---|---|---|---|---|---|---|"]
        for name, summary in result["variants"].items():
            for label, st in summary[subset].items():
                if not st["frames"]:
                    continue
                lines.append(f"| {name} | {label} | {st['frames']} | {st['depth_abs_mean_m']:.3f} | "
                             f"{st['depth_abs_median_m']:.3f} | {st['depth_bias_m']:+.3f} | {st['mpjpe_mm']:.1f} | "
                             f"{st['rel_mpjpe_mm']:.1f} |")
        lines.append("")
    lines += ["Fit wall seconds per variant: " + ", ".join(f"{k} {v:.1f}" for k, v in result["fit_seconds"].items()),
              "", f"Hardware: {result['hardware']}", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scenes", type=int, default=2)
    parser.add_argument("--pedestrians", type=int, default=8)
    parser.add_argument("--frames", type=int, default=12)
    parser.add_argument("--yaw", type=float, default=20.0, help="second pair's yaw, degrees (real PedX: ~17)")
    parser.add_argument("--rig", choices=("overlap", "default", "pedx"), default="overlap",
                        help="overlap: the second pair beside the first (default); default / pedx: the "
                             "simulator's rig presets")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench_views_") as tmp:
        result = run(args.seed, args.scenes, args.pedestrians, args.frames, args.yaw, Path(tmp), args.rig)
    result.update(seed=args.seed, scenes=args.scenes, pedestrians=args.pedestrians, frames=args.frames,
                  yaw_deg=args.yaw, rig=args.rig, hardware=hardware())
    command = " ".join(["python benchmarks/bench_views.py"] + public_args(argv))
    result["command"] = command
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    stem = "bench_views" if args.rig == "overlap" else f"bench_views_{args.rig}_rig"
    atomic_write_json(out / f"{stem}.json", result)
    atomic_write_text(out / f"{stem}.md", markdown(result, command))
    print(markdown(result, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
