"""Noise from the data on simulated scenes: the estimate against the simulator's noise, the residuals at the
truth, and what the fit's sigmas do to the covariance calibration (NEES, 95 % coverage).

Per rig (``default``: z-up, 2 px clicks on every keypoint; ``pedx``: the real PedX rig, its per-keypoint
click-noise profile, integer clicks, no occlusion flags, a -1 px vertical disparity on one pair), seeded
scenes pooled as one dataset:

1. :func:`pedx_graph.data.noise_estimate.estimate_noise` against the simulator's settings (per keypoint:
   ``hypot(click, 1/sqrt(12))`` with integer clicks; LiDAR: ``lidar.range_noise_m``);
2. residuals at the simulator's truth (the model error the fit faces, measured): the visible labels minus the
   true keypoints' projections (robust scale per keypoint: click noise alone when the labels are clicks on the
   model's own keypoints), and the segment points' offsets to the nearest of the chamfer's vertex subset of the
   true body (robust scale per coordinate: range noise + vertex spacing + the segment's background);
3. the fit (batch LM, staged, chain marginals, as ``bench_calibration``) of the scene's tracks with the
   config's single sigmas (``config``: 3 px / 4 cm, as before), with the data estimate and no model term
   (``data_model0``: the sigma = the measured click / range noise only) and with the data estimate and the
   default model terms (``data_default``); keypoint and translation NEES / dof and 95 % coverage, MPJPE.

    python benchmarks/bench_noise.py [--seed 0] [--scenes 1] [--pedestrians 8] [--frames 20] [--rigs default pedx]

Writes ``bench_noise.json`` and ``bench_noise.md`` into ``--out``.
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import cell, hardware, public_args  # noqa: E402
from bench_calibration import collect, summarise  # noqa: E402
from bench_fit import SHARED_CMU  # noqa: E402
from pedx_graph.data.noise_estimate import (QUANTISATION_PX, estimate_noise, resolve_noise,  # noqa: E402
                                            robust_gaussian_scale)
from pedx_graph.data.reader import read_dataset, read_smpl_labels  # noqa: E402
from pedx_graph.graph.config import FitConfig  # noqa: E402
from pedx_graph.keypoints import PEDX_KEYPOINTS  # noqa: E402
from pedx_graph.sim.config import rig_config  # noqa: E402
from pedx_graph.sim.simulate import simulate  # noqa: E402
from pedx_graph.solvers.fit import _context  # noqa: E402
from pedx_graph.utils import atomic_write_json, atomic_write_text  # noqa: E402

VARIANTS = ("config", "data_model0", "data_default")
#: Median of the chi-square distribution with 3 degrees of freedom.
CHI2_3_MEDIAN = 2.365973884375338


def sim_truth_noise(cfg) -> dict:
    """The simulator's own noise: per-click sigma per keypoint (rounding included) and the range noise."""
    clicks = (np.full(18, cfg.labels.visible_noise_px) if cfg.labels.keypoint_noise_px is None
              else np.asarray(cfg.labels.keypoint_noise_px, float))
    if cfg.labels.integer_clicks:
        clicks = np.hypot(clicks, QUANTISATION_PX)
    return {"click_sigma_px": clicks, "range_sigma_m": float(cfg.lidar.range_noise_m)}


def residuals_at_truth(tracks, truth, ctx) -> dict:
    """Robust scales of the labels' residuals at the true keypoints (per keypoint, px) and of the segment
    points' offsets to the true body's chamfer vertices (per coordinate, m, from the median squared offset:
    the points' range noise, the vertex spacing and the segment's background points)."""
    per_kp = [[] for _ in range(18)]
    chamfer = []
    from scipy.spatial import cKDTree

    for tr in tracks:
        labels = {lab.frame: lab for lab in truth.get((tr.sequence, tr.tracking_id), [])}
        for fr in tr.frames:
            lab = labels.get(fr.frame)
            if lab is None:
                continue
            body = ctx.model.forward(lab.pose, lab.betas, lab.trans)
            for pair, side, view in fr.labelled_views():
                uv = tr.calibrations[pair].project(body.keypoints)[0 if side == "left" else 1]
                ok = view.labelled & np.asarray(view.visible, bool)
                for k in np.flatnonzero(ok):
                    per_kp[k].extend(view.keypoints[k] - uv[k])
            points = np.asarray(fr.world_lidar_points, float).reshape(-1, 3)
            if len(points):
                verts = body.vertices[ctx.chamfer_vertex_ids]
                _, nearest = cKDTree(verts).query(points)
                chamfer.append(np.sum((points - verts[nearest]) ** 2, axis=1))
    kp = [robust_gaussian_scale(np.asarray(r))[0] if len(r) >= 10 else None for r in per_kp]
    ch = np.concatenate(chamfer) if chamfer else np.zeros(0)
    # per coordinate, from the median squared 3D offset (chi-square with 3 dof: median 2.366 sigma^2)
    return {"keypoint_px": kp, "keypoint_counts": [len(r) // 2 for r in per_kp],
            "chamfer_per_coordinate_m": float(np.sqrt(np.median(ch) / CHI2_3_MEDIAN)) if ch.size > 10 else None,
            "chamfer_points": int(ch.size)}


def collect_per_track(tracks, truth, config, ctx) -> dict:
    """``bench_calibration.collect`` track by track: ``{(sequence, tracking_id): data}``; a track it cannot score
    (e.g. extras without a per-frame record) is named on stderr and left out."""
    parts = {}
    for tr in tracks:
        try:
            parts[(tr.sequence, tr.tracking_id)] = collect([tr], truth, config, ctx)
        except Exception as exc:  # noqa: BLE001 -- reported; the variants are compared on the tracks all scored
            print(f"track {tr.sequence}/{tr.tracking_id} not scored: {exc!r}", file=sys.stderr)
    return parts


def pool(parts: list[dict]) -> dict:
    """One ``collect``-style dict from per-track ones."""
    out = {"failed_tracks": sum(p["failed_tracks"] for p in parts), "fit_seconds": sum(p["fit_seconds"] for p in parts),
           "energies": [e for p in parts for e in p["energies"]]}
    for key, shape in (("kp_nees", (0, 18)), ("tr_nees", (0,)), ("dist", (0,)), ("visible", (0, 18)),
                       ("kp_err", (0, 18)), ("consistent", (0,))):
        arrays = [p[key] for p in parts]
        out[key] = np.concatenate(arrays) if arrays else np.zeros(shape)
    return out


def variant_config(name: str, resolved_noise) -> FitConfig:
    """The fit config of a variant (``resolved_noise``: the data-resolved NoiseConfig)."""
    config = FitConfig()
    if name == "config":
        return config
    config.noise = dataclasses.replace(resolved_noise)
    if name == "data_model0":
        config.noise.keypoint_model_sigma_px = 0.0
        config.noise.lidar_model_sigma_m = 0.0
    elif name != "data_default":
        raise ValueError(f"unknown variant {name!r}")
    return config


def run_rig(rig: str, seed: int, pedestrians: int, frames: int, variants, work: Path, scenes: int = 1) -> dict:
    """One rig: ``scenes`` scenes (seeds ``seed``, ``seed + 1``, ...) pooled as one dataset."""
    cfg = rig_config(rig)
    cfg.scene.n_pedestrians = pedestrians
    cfg.scene.n_frames = frames
    if SHARED_CMU.is_dir():
        cfg.motion.motion_dir = str(SHARED_CMU)
        cfg.motion.split = "holdout"
    tracks, truth = [], {}
    for i in range(scenes):
        scene = work / f"{rig}{i}"
        simulate(scene, cfg, seed=seed + i)
        # sequence names unique over rigs and scenes (the simulator draws the same tracking ids from the same
        # seed, and bench_calibration caches fits by sequence, tracking id and config)
        for track in read_dataset(scene):
            track.sequence = f"{rig}{i}/{track.sequence}"
            tracks.append(track)
        truth.update({(f"{rig}{i}/{seq}", tid): labs for (seq, tid), labs in read_smpl_labels(scene).items()})
    sim_noise = sim_truth_noise(cfg)
    estimate = estimate_noise(tracks)
    resolved = resolve_noise(tracks, FitConfig().noise, estimate=estimate)
    ctx = _context(FitConfig())
    at_truth = residuals_at_truth(tracks, truth, ctx)
    out = {"rig": rig, "tracks": len(tracks), "frames": sum(len(t.frames) for t in tracks),
           "sim": {"click_sigma_px": dict(zip(PEDX_KEYPOINTS, sim_noise["click_sigma_px"].tolist())),
                   "range_sigma_m": sim_noise["range_sigma_m"],
                   "occlusion_flags": cfg.labels.occlusion_flags, "integer_clicks": cfg.labels.integer_clicks},
           "estimate": estimate.to_dict(), "resolved": resolved.record,
           "at_truth": {"keypoint_px": dict(zip(PEDX_KEYPOINTS, at_truth["keypoint_px"])),
                        "keypoint_counts": dict(zip(PEDX_KEYPOINTS, at_truth["keypoint_counts"])),
                        "chamfer_per_coordinate_m": at_truth["chamfer_per_coordinate_m"],
                        "chamfer_points": at_truth["chamfer_points"]},
           "variants": {}}
    fit_tracks = [t for t in tracks if len(t.frames) >= 2]
    per_variant = {name: collect_per_track(fit_tracks, truth, variant_config(name, resolved.noise),
                                           _context(FitConfig())) for name in variants}
    scored = [key for key in ((t.sequence, t.tracking_id) for t in fit_tracks)
              if all(key in parts for parts in per_variant.values())]
    out["tracks_scored"] = len(scored)
    for name, parts in per_variant.items():
        res = summarise(pool([parts[key] for key in scored]), split_consistent=False)
        res["keypoint_error_mm_mean"] = res["overall"]["keypoint_error_mm_mean"]
        out["variants"][name] = res
        print(rig, name, {k: res["overall"][k] for k in ("keypoints", "translation")}, flush=True)
    return out




def to_markdown(result: dict) -> str:
    lines = ["# Noise from the data (simulated scenes)", "", f"Command: `{result['command']}`  ",
             f"Hardware: {result['hardware']}  ",
             f"Scenes: {result.get('scenes', 1)} per rig (seeds from {result['seed']}), {result['pedestrians']} "
             f"pedestrians x {result['frames']} frames each "
             f"({result['motion']}); batch LM (staged) + chain marginals per track (as bench_calibration). NEES / "
             "dof should be 1 (goal 0.8-1.25), 95 % coverage 92-97 %.", ""]
    for rig, res in result["rigs"].items():
        est, sim, truth = res["estimate"], res["sim"], res["at_truth"]
        lines += [f"## Rig `{rig}` ({res['tracks']} tracks, {res['frames']} frames, {res.get('tracks_scored')} tracks "
                  f"of 2+ frames scored in every variant; occlusion flags "
                  f"{sim['occlusion_flags']}, integer clicks {sim['integer_clicks']})", "",
                  "Click noise per keypoint, px per click: the simulator's (rounding included), the estimate from "
                  "the vertical disparities (samples), the labels' residual at the true keypoints (visible labels).",
                  "", "| keypoint | simulator | estimate | samples | residual at truth |", "|---|---:|---:|---:|---:|"]
        for name in PEDX_KEYPOINTS:
            pooled = " (pooled)" if name in est["keypoint_pooled"] else ""
            sigma = (est["keypoint_sigma_px"] or {}).get(name)
            lines.append(f"| {name} | {sim['click_sigma_px'][name]:.2f} | {cell(sigma, '.2f')}{pooled} | "
                         f"{est['keypoint_counts'][name]} | {cell(truth['keypoint_px'][name], '.2f')} |")
        lines += ["", "Pair offsets (v_left - v_right): " + ", ".join(
            f"{p['sequence']} {p['pair']} {p['offset_px']:+.2f} px ({p['count']})" for p in est["pair_offsets"])
            + ".", "",
            f"LiDAR: simulator range noise {sim['range_sigma_m']:.3f} m; estimate "
            f"{cell(est['lidar_range_sigma_m'], '.4f')} m from {est['lidar_count']} local fits; the chamfer residual "
            f"at the truth (segment points to the nearest chamfer vertex of the true body, per coordinate from "
            f"the median squared offset, background points included): "
            f"{cell(truth['chamfer_per_coordinate_m'], '.4f')} m.", "",
            "| variant | keypoints NEES/dof | keypoints coverage | translation NEES/dof | translation coverage | "
            "mean keypoint error mm | frames |", "|---|---:|---:|---:|---:|---:|---:|"]
        for name, v in res["variants"].items():
            k, t = v["overall"]["keypoints"], v["overall"]["translation"]
            lines.append(f"| {name} | {cell(k['mean_nees_over_dof'], '.2f')} | {cell(100 * k['coverage95'], '.1f')} % | "
                         f"{cell(t['mean_nees_over_dof'], '.2f')} | {cell(100 * t['coverage95'], '.1f')} % | "
                         f"{cell(v['keypoint_error_mm_mean'], '.1f')} | {v['frames']} |")
        lines.append("")
    if result.get("notes"):
        lines += ["## Findings", ""] + [f"- {n}" for n in result["notes"]]
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pedestrians", type=int, default=8)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--scenes", type=int, default=1, help="scenes per rig (seed, seed + 1, ...), pooled")
    ap.add_argument("--rigs", nargs="+", default=["default", "pedx"])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")
    args_text = " ".join(public_args(argv if argv is not None else sys.argv[1:]))
    result = {"command": f"python benchmarks/bench_noise.py {args_text}".strip(),
              "seed": args.seed, "scenes": args.scenes, "pedestrians": args.pedestrians, "frames": args.frames,
              "motion": "CMU hold-out clips" if SHARED_CMU.is_dir() else "procedural gait", "rigs": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for rig in args.rigs:
            result["rigs"][rig] = run_rig(rig, args.seed, args.pedestrians, args.frames, args.variants, Path(tmp),
                                          args.scenes)
    result["hardware"] = hardware()
    out = Path(args.out)
    atomic_write_json(out / "bench_noise.json", result)
    atomic_write_text(out / "bench_noise.md", to_markdown(result))
    print(to_markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
