"""Calibration of the marginal covariances on simulated data: NEES and 95 % ellipsoid coverage.

For every fitted frame (batch LM, staged, as ``pedx-graph fit``) and its joint marginal covariance
(``pedx_graph.solvers.marginals``, chain method), with ``e`` the error of the estimate against the
simulator's truth (same body model):

* keypoints: ``NEES_k = e_k^T Sigma_k^-1 e_k`` for each of the 18 keypoints (3 dof), ``Sigma_k`` the
  propagated keypoint covariance;
* translation: ``NEES = e_t^T Sigma_trans^-1 e_t`` (3 dof), SMPL ``trans``;

reported per distance bin (horizontal distance of the true pelvis from the LiDAR) as the mean NEES / dof
(calibrated: 1; goal 0.8-1.25) and the fraction inside the 95 % ellipsoid (``NEES <= chi2_3(0.95) =
7.815``; goal 92-97 %).  A consistent estimator has NEES ~ chi2_3 only if the model is right, so variants
switch off one suspected cause at a time: ``default`` (shipped config), ``matched_noise`` (the config's
noise set to the simulator's: 2 px visible / 8 px occluded clicks, 2 cm LiDAR range noise),
``gaussian`` (no robust losses), ``no_temporal_prior`` (the shipped temporal GMM favours standing
still; see the findings), ``no_chamfer`` / ``lidar_sigma_x3`` (the chamfer's points are not independent:
nearest-vertex matching on a vertex subset makes correlated errors); ``point_to_point_chamfer`` (same fit,
covariances with the chamfer factor's fixed-correspondence information instead of the point-to-plane
information of ``MarginalsConfig``); ``a+b`` combines variants.  Every variant is also reported on the
frames the diagnostics judge consistent (``fit_consistent``, see ``pedx_graph.solvers.diagnostics``).

    python benchmarks/bench_calibration.py [--seed 0] [--pedestrians 10] [--frames 50] [--variants ...]

Writes ``bench_calibration.json`` and ``bench_calibration.md`` into ``--out``.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_fit import SHARED_CMU, hardware, sim_config  # noqa: E402
from _common import public_args  # noqa: E402
from pedx_graph.data.reader import read_dataset, read_smpl_labels  # noqa: E402
from pedx_graph.eval.metrics import DISTANCE_BINS, distance_bin  # noqa: E402
from pedx_graph.graph.build import extract_estimate  # noqa: E402
from pedx_graph.graph.config import FitConfig  # noqa: E402
from pedx_graph.sim.simulate import simulate  # noqa: E402
from pedx_graph.solvers.fit import _context, solve_staged  # noqa: E402
from pedx_graph.solvers.diagnostics import track_extras  # noqa: E402
from pedx_graph.solvers.marginals import MarginalsConfig  # noqa: E402
from pedx_graph.utils import atomic_write_json, atomic_write_text  # noqa: E402

CHI2_3_95 = 7.814727903251178


def _modify(config: FitConfig, name: str, marginals: MarginalsConfig | None = None) -> None:
    if name == "default":
        return
    if name == "point_to_point_chamfer":
        marginals.chamfer_information = "point_to_point"
        return
    if name == "matched_noise":
        config.noise.keypoint_sigma_px = 2.0
        config.noise.occluded_keypoint_sigma_px = 8.0
        config.noise.lidar_sigma_m = 0.02
    elif name == "no_temporal_prior":
        config.terms.temporal_prior = False
    elif name == "no_chamfer":
        config.terms.lidar_chamfer = False
    elif name == "lidar_sigma_x3":
        config.noise.lidar_sigma_m *= 3.0
    elif name == "gaussian":
        config.noise.reprojection_loss = "none"
        config.noise.lidar_loss = "none"
        config.noise.translation_loss = "none"
    else:
        raise ValueError(f"unknown variant {name!r}")


def variant_config(name: str) -> tuple[FitConfig, MarginalsConfig]:
    """The fit and marginals configs of a variant; ``a+b`` applies both modifications."""
    config, marginals = FitConfig(), MarginalsConfig()
    for part in name.split("+"):
        _modify(config, part, marginals)
    return config, marginals


def nees(err: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(N,) ``e^T Sigma^-1 e`` for errors (N, 3) and covariances (N, 3, 3)."""
    return np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[..., None])[..., 0])


_FITS: dict = {}
"""Solved tracks by (track, fit config): variants that differ only in the marginals share one fit."""


def _solve(tr, ctx, config):
    key = (tr.sequence, tr.tracking_id, repr(config))
    if key not in _FITS:
        _FITS[key] = solve_staged(tr, ctx, config)
    return _FITS[key]


def collect(tracks, truth, config, ctx, marginals_config: MarginalsConfig | None = None) -> dict:
    """Per-frame NEES arrays of one variant: keypoints (N, 18), translation (N,), distances (N,), and whether
    the diagnostics judged the frame's fit consistent (N,).  The covariances are the ones ``pedx-graph fit``
    writes (``track_extras``: chain marginals, point-to-plane chamfer information unless
    ``marginals_config`` says otherwise); frames with an under-constrained status are left out."""
    kp_nees, tr_nees, dist, visible, kp_err, consistent = [], [], [], [], [], []
    failed, seconds = 0, 0.0
    for tr in tracks:
        t0 = time.perf_counter()
        try:
            problem, values, _ = _solve(tr, ctx, config)
            per_frame, track_fields = track_extras(problem, values, ctx, marginals_config=marginals_config,
                                                   fit_config=config)
        except Exception:
            failed += 1
            continue
        if "marginals_error" in track_fields:
            failed += 1
            continue
        seconds += time.perf_counter() - t0
        est = extract_estimate(problem, values, ctx)
        labels = {lab.frame: lab for lab in truth.get((tr.sequence, tr.tracking_id), [])}
        for i, fr in enumerate(tr.frames):
            lab = labels.get(fr.frame)
            f = per_frame[i]
            if lab is None or f.get("covariance_status") != "ok":
                continue
            true_kp = np.asarray(ctx.model.keypoints(lab.pose, lab.betas, lab.trans))
            e = est.world_keypoints[i] - true_kp
            kp_nees.append(nees(e, np.asarray(f["cov_keypoints_3d"])))
            kp_err.append(np.linalg.norm(e, axis=1))
            et = est.trans[i] - lab.trans
            tr_nees.append(float(nees(et[None], np.asarray(f["cov_trans"])[None])[0]))
            consistent.append(bool(f.get("fit_consistent", True)))
            pelvis = true_kp[[12, 13]].mean(axis=0)
            dist.append(float(np.hypot(pelvis[0], pelvis[1])))
            vis = np.zeros(18, bool)
            for view in (fr.left, fr.right):
                if view is not None:
                    vis |= np.asarray(view.visible, bool) & view.labelled
            visible.append(vis)
    return {"kp_nees": np.array(kp_nees).reshape(-1, 18), "tr_nees": np.array(tr_nees), "dist": np.array(dist),
            "visible": np.array(visible, dtype=bool).reshape(-1, 18), "kp_err": np.array(kp_err).reshape(-1, 18),
            "consistent": np.array(consistent, dtype=bool), "failed_tracks": failed, "fit_seconds": seconds}


def stats(values: np.ndarray, dof: int = 3) -> dict:
    values = np.asarray(values, float).reshape(-1)
    if values.size == 0:
        return {"n": 0, "mean_nees_over_dof": None, "median_nees_over_dof": None, "coverage95": None}
    return {"n": int(values.size), "mean_nees_over_dof": float(values.mean() / dof),
            "median_nees_over_dof": float(np.median(values) / dof),
            "coverage95": float(np.mean(values <= CHI2_3_95))}


def _subset(data: dict, mask: np.ndarray) -> dict:
    return {k: (v[mask] if isinstance(v, np.ndarray) and len(v) == len(mask) else v) for k, v in data.items()}


def summarise(data: dict, split_consistent: bool = True) -> dict:
    bins = np.array([distance_bin(d) for d in data["dist"]], dtype=object)
    out = {"frames": int(len(data["dist"])), "failed_tracks": data["failed_tracks"],
           "fit_seconds": data["fit_seconds"],
           "overall": {"keypoints": stats(data["kp_nees"]), "keypoints_visible": stats(data["kp_nees"][data["visible"]]),
                       "keypoints_occluded": stats(data["kp_nees"][~data["visible"]]),
                       "translation": stats(data["tr_nees"]),
                       "keypoint_error_mm_mean": float(data["kp_err"].mean() * 1000) if data["kp_err"].size else None},
           "per_distance": {}}
    for lo, hi in DISTANCE_BINS:
        key = f"{lo:g}-{hi:g}"
        sel = bins == key
        out["per_distance"][key] = {"frames": int(sel.sum()), "keypoints": stats(data["kp_nees"][sel]),
                                    "translation": stats(data["tr_nees"][sel])}
    # worst keypoints (mean NEES / dof)
    if data["kp_nees"].size:
        from pedx_graph.keypoints import PEDX_KEYPOINTS

        per_kp = data["kp_nees"].mean(axis=0) / 3
        out["per_keypoint_mean_nees_over_dof"] = {name: float(v) for name, v in zip(PEDX_KEYPOINTS, per_kp)}
    if split_consistent:
        ok = data["consistent"]
        out["inconsistent_frames"] = int((~ok).sum())
        out["inconsistent_keypoint_error_mm_mean"] = (float(data["kp_err"][~ok].mean() * 1000) if (~ok).any()
                                                      else None)
        out["inconsistent_per_distance"] = {f"{lo:g}-{hi:g}": int(((bins == f"{lo:g}-{hi:g}") & ~ok).sum())
                                            for lo, hi in DISTANCE_BINS}
        out["consistent_only"] = summarise(_subset(data, ok), split_consistent=False)
    return out


def _f(x, spec=".2f"):
    return "-" if x is None else format(x, spec)


def to_markdown(result: dict) -> str:
    lines = ["# Calibration of the marginal covariances (simulated data)", "",
             f"Command: `{result['command']}`  ", f"Hardware: {result['hardware']}  ",
             f"Scene: seed {result['seed']}, {result['pedestrians']} pedestrians x {result['frames']} frames "
             f"per scene, {result.get('scenes', 'one')} scene(s) "
             f"({result['motion']}); batch LM (staged) + chain marginals per track. NEES / dof should be 1 "
             "(goal 0.8-1.25); coverage of the 95 % ellipsoid 92-97 %.", ""]
    for name, res in result["variants"].items():
        lines += [f"## Variant `{name}`", ""] + _tables(res, "all frames with covariances")
        if "consistent_only" in res:
            lines += [f"{res['inconsistent_frames']} frames flagged `fit_consistent = false` by the diagnostics "
                      f"(per distance bin {res['inconsistent_per_distance']}), mean keypoint error "
                      f"{_f(res['inconsistent_keypoint_error_mm_mean'], '.1f')} mm. Without them:", ""]
            lines += _tables(res["consistent_only"], "frames judged consistent")
    if result.get("notes"):
        lines += ["## Findings", ""] + [f"- {n}" for n in result["notes"]]
    return "\n".join(lines) + "\n"


def _tables(res: dict, title: str) -> list[str]:
    lines = []
    o = res["overall"]
    lines += [f"{title}: {res['frames']} frames, {res['failed_tracks']} tracks failed; mean keypoint error "
              f"{_f(o['keypoint_error_mm_mean'], '.1f')} mm.", "",
              "| set | n | mean NEES/dof | median NEES/dof | 95 % coverage |", "|---|---:|---:|---:|---:|"]
    for label, key in (("keypoints (all 18)", "keypoints"), ("keypoints labelled visible", "keypoints_visible"),
                       ("keypoints not visible", "keypoints_occluded"), ("translation", "translation")):
        s = o[key]
        lines.append(f"| {label} | {s['n']} | {_f(s['mean_nees_over_dof'])} | {_f(s['median_nees_over_dof'])} | "
                     f"{_f(None if s['coverage95'] is None else 100 * s['coverage95'], '.1f')} % |")
    lines += ["", "| distance (m) | frames | keypoints NEES/dof | keypoints coverage | translation NEES/dof | "
              "translation coverage |", "|---|---:|---:|---:|---:|---:|"]
    for key, row in res["per_distance"].items():
        k, t = row["keypoints"], row["translation"]
        lines.append(f"| {key} | {row['frames']} | {_f(k['mean_nees_over_dof'])} | "
                     f"{_f(None if k['coverage95'] is None else 100 * k['coverage95'], '.1f')} % | "
                     f"{_f(t['mean_nees_over_dof'])} | {_f(None if t['coverage95'] is None else 100 * t['coverage95'], '.1f')} % |")
    lines.append("")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pedestrians", type=int, default=10)
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--variants", nargs="+", default=["default", "point_to_point_chamfer", "lidar_sigma_x3"])
    ap.add_argument("--per-bin-scenes", action="store_true",
                    help="one scene per distance bin (as bench_fit: the simulator's distance distribution centred "
                         "on the bin, seed + bin index), pooled; otherwise one scene with the default distances")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = ap.parse_args(argv)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")
    ctx = _context(FitConfig())
    result = {"command": "python benchmarks/bench_calibration.py " + " ".join(public_args(argv if argv is not None else sys.argv[1:])),
              "hardware": hardware(), "seed": args.seed, "pedestrians": args.pedestrians, "frames": args.frames,
              "motion": "CMU hold-out clips" if SHARED_CMU.is_dir() else "procedural gait", "variants": {}}
    with tempfile.TemporaryDirectory() as tmp:
        tracks, truth = [], {}
        scenes = list(enumerate(DISTANCE_BINS)) if args.per_bin_scenes else [(0, None)]
        for b, bin_range in scenes:
            scene = Path(tmp) / f"scene{b}"
            cfg = sim_config(args.pedestrians, args.frames)
            if bin_range is not None:
                lo, hi = bin_range
                cfg.scene.distance_mean_m = 0.5 * (lo + hi)
                cfg.scene.distance_std_m = 0.35 * (hi - lo)
            simulate(scene, cfg, seed=args.seed + b)
            scene_tracks = [t for t in read_dataset(scene) if len(t.frames) >= 2]
            for t in scene_tracks:
                t.sequence = f"scene{b}/{t.sequence}"
            tracks += scene_tracks
            truth.update({(f"scene{b}/{seq}", tid): labs for (seq, tid), labs in read_smpl_labels(scene).items()})
        result["scenes"] = "one per distance bin (seed + bin index)" if args.per_bin_scenes else "one"
        for name in args.variants:
            fit_config, marginals_config = variant_config(name)
            data = collect(tracks, truth, fit_config, ctx, marginals_config)
            result["variants"][name] = summarise(data)
            print(name, result["variants"][name]["overall"], flush=True)
    out = Path(args.out)
    atomic_write_json(out / "bench_calibration.json", result)
    atomic_write_text(out / "bench_calibration.md", to_markdown(result))
    print(to_markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
