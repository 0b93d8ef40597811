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
``gaussian`` (no robust losses), ``trained_priors`` (``prior_covariance_scale = 1`` instead of the
default 3: the chain of per-frame pose priors and temporal priors then counts the prior several times,
see ``chain_prior_overcount``), ``no_temporal_prior`` (the shipped temporal GMM favours standing
still; see the findings), ``no_chamfer`` / ``lidar_sigma_x3`` (the chamfer's points are not independent:
nearest-vertex matching on a vertex subset makes correlated errors); ``point_to_point_chamfer`` (same fit,
covariances with the chamfer factor's fixed-correspondence information instead of the point-to-plane
information of ``MarginalsConfig``); ``upper_arm_flips`` (the limb depth-flip search without the
forearms, as before they were added to the default); ``no_ground_contact`` (without the stance-foot ground
contact term, as before it was added); ``a+b`` combines variants.  Every variant is also reported on the
frames the diagnostics judge consistent (``fit_consistent``, see ``pedx_graph.solvers.diagnostics``).
Per variant also: the NEES per keypoint group and distance, and the objective at the estimate and at the
truth per track and after LM started from the truth (``objective_at_truth``: LM from the truth ending
lower than the estimate means the fit stopped in a worse basin); once: how much the chain of priors tightens a frame's pose
prior (``chain_prior_overcount``).

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
from bench_solvers import values_of  # noqa: E402
from _common import cell, public_args  # noqa: E402
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
#: Keypoint groups of the per-distance tables (indices into PEDX_KEYPOINTS).
KEYPOINT_GROUPS = {"head": [0, 1, 2, 3, 4], "neck+shoulders": [5, 6, 7], "elbows": [8, 9], "wrists": [10, 11],
                   "hips": [12, 13], "knees": [14, 15], "ankles": [16, 17]}


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
    elif name == "no_ground_contact":
        config.noise.ground_contact_sigma_m = 0.0
    elif name == "trained_priors":
        config.prior_covariance_scale = 1.0
    elif name == "lidar_sigma_x3":
        config.noise.lidar_sigma_m *= 3.0
    elif name == "upper_arm_flips":
        config.solver.flip_segments = tuple(seg for seg in config.solver.flip_segments if "forearm" not in seg)
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
    energies = []
    failed, seconds = 0, 0.0
    for tr in tracks:
        t0 = time.perf_counter()
        try:
            problem, values, _ = _solve(tr, ctx, config)
            per_frame, track_fields = track_extras(problem, values, ctx, marginals_config=marginals_config,
                                                   fit_config=config)
        except Exception as exc:                       # noqa: BLE001 -- counted and reported, the run goes on
            print(f"track {tr.sequence}/{tr.tracking_id} failed: {exc!r}", file=sys.stderr)
            failed += 1
            continue
        if "marginals_error" in track_fields:
            failed += 1
            continue
        seconds += time.perf_counter() - t0
        est = extract_estimate(problem, values, ctx)
        labels = {lab.frame: lab for lab in truth.get((tr.sequence, tr.tracking_id), [])}
        if all(fr.frame in labels for fr in tr.frames):
            energies.append(objective_at_truth(problem, values, [labels[fr.frame] for fr in tr.frames], config))
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
            "consistent": np.array(consistent, dtype=bool), "failed_tracks": failed, "fit_seconds": seconds,
            "energies": energies}


def objective_at_truth(problem, values, labels, config=None) -> dict:
    """The track's objective (graph error) per factor kind at the estimate and at the simulator's truth, and
    the track's distance; with ``config``, also the total after LM started from the truth (``truth_solved``,
    the same graph and solver settings).  The truth itself is noisy against the labels and scores higher
    than a fit almost always; LM from the truth ending lower than the estimate is what shows that the fit
    stopped in a local minimum (a different basin), not the model's optimum."""
    truth = values_of(problem, np.stack([lab.pose for lab in labels]), labels[0].betas,
                      np.stack([lab.trans for lab in labels]))
    out = {"frames": len(labels), "estimate": {}, "truth": {}}
    for j, kind in enumerate(problem.factor_kinds):
        factor = problem.graph.at(j)
        for name, v in (("estimate", values), ("truth", truth)):
            out[name][kind] = out[name].get(kind, 0.0) + float(factor.error(v))
    pelvis = np.mean([lab.trans for lab in labels], axis=0)
    out["distance_m"] = float(np.hypot(pelvis[0], pelvis[1]))
    if config is not None:
        from pedx_graph.solvers.fit import _solver_parts
        from pedx_graph.solvers.lm import solve

        _, rep = solve(problem.graph, truth, config.solver, *_solver_parts(problem, config))
        out["truth_solved"] = float(rep.final_error)
        out["estimate_total"] = float(problem.graph.error(values))
    return out


def energy_summary(energies: list[dict]) -> dict:
    """Per distance bin: tracks whose truth has a lower objective than the estimate (a local minimum of the
    fit), and the mean objective per frame by term at the estimate and at the truth."""
    out = {}
    for lo, hi in DISTANCE_BINS:
        sel = [e for e in energies if distance_bin(e["distance_m"]) == f"{lo:g}-{hi:g}"]
        if not sel:
            continue
        frames = sum(e["frames"] for e in sel)
        kinds = sorted({k for e in sel for k in e["estimate"]})
        out[f"{lo:g}-{hi:g}"] = {
            "tracks": len(sel),
            "truth_lower": int(sum(sum(e["truth"].values()) < sum(e["estimate"].values()) for e in sel)),
            "truth_basin_lower": int(sum(e["truth_solved"] < 0.99 * e["estimate_total"] for e in sel
                                         if "truth_solved" in e)),
            "truth_solved_per_frame": (sum(e["truth_solved"] for e in sel if "truth_solved" in e)
                                       / max(1, sum(e["frames"] for e in sel if "truth_solved" in e))),
            "per_frame": {k: {"estimate": sum(e["estimate"].get(k, 0.0) for e in sel) / frames,
                              "truth": sum(e["truth"].get(k, 0.0) for e in sel) / frames} for k in kinds}}
    return out


def chain_prior_overcount(ctx, frames: int = 21) -> dict:
    """How much tighter the per-frame pose prior gets inside a chain of ``frames`` frames that also carries
    the temporal prior: both mixtures moment-matched to Gaussians (pose ``S_P``, temporal body-pose block
    ``S_T``), chain information ``I (x) S_P^-1 + L (x) S_T^-1`` (``L`` the path Laplacian), ratio of the pose
    prior's variance to the middle frame's marginal variance per pose dimension.  1 = the chain's prior on
    a single frame is the pose prior itself (what the data have); larger = the product of per-frame and
    pairwise priors counts the same prior knowledge several times."""
    def moment(mixture):
        log_w = -mixture.c - np.linalg.slogdet(mixture.lt)[1]          # c_k = -log w_k - log|det L_k| (+ const)
        w = np.exp(log_w - log_w.max())
        w = w / w.sum()
        covs = np.linalg.inv(np.einsum("kij,kil->kjl", mixture.lt, mixture.lt))        # (L L^T)^-1
        mean = w @ mixture.means
        diff = mixture.means - mean
        return (np.einsum("k,kij->ij", w, covs) + np.einsum("k,ki,kj->ij", w, diff, diff))

    pose_cov = moment(ctx.pose_mixture)
    temporal_cov = moment(ctx.temporal_mixture)[6:, 6:]
    n = pose_cov.shape[0]
    lap = np.diag([1.0] + [2.0] * (frames - 2) + [1.0]) - np.eye(frames, k=1) - np.eye(frames, k=-1)
    info = np.kron(np.eye(frames), np.linalg.inv(pose_cov)) + np.kron(lap, np.linalg.inv(temporal_cov))
    mid = frames // 2
    marginal = np.linalg.inv(info)[mid * n:(mid + 1) * n, mid * n:(mid + 1) * n]
    ratio = np.diag(pose_cov) / np.diag(marginal)
    from pedx_graph.keypoints import SMPL_JOINTS

    per_joint = {SMPL_JOINTS[j + 1]: float(ratio[3 * j:3 * j + 3].max()) for j in range(n // 3)}
    return {"frames": frames, "median_variance_ratio": float(np.median(ratio)), "max_variance_ratio_per_joint": per_joint}


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
                                    "translation": stats(data["tr_nees"][sel]),
                                    "keypoint_groups": {g: stats(data["kp_nees"][sel][:, idx])
                                                        for g, idx in KEYPOINT_GROUPS.items()}}
    # worst keypoints (mean NEES / dof)
    if data["kp_nees"].size:
        from pedx_graph.keypoints import PEDX_KEYPOINTS

        per_kp = data["kp_nees"].mean(axis=0) / 3
        out["per_keypoint_mean_nees_over_dof"] = {name: float(v) for name, v in zip(PEDX_KEYPOINTS, per_kp)}
    if split_consistent and data.get("energies"):
        out["objective_at_truth"] = energy_summary(data["energies"])
    if split_consistent:
        ok = data["consistent"]
        out["inconsistent_frames"] = int((~ok).sum())
        out["inconsistent_keypoint_error_mm_mean"] = (float(data["kp_err"][~ok].mean() * 1000) if (~ok).any()
                                                      else None)
        out["inconsistent_per_distance"] = {f"{lo:g}-{hi:g}": int(((bins == f"{lo:g}-{hi:g}") & ~ok).sum())
                                            for lo, hi in DISTANCE_BINS}
        out["consistent_only"] = summarise(_subset(data, ok), split_consistent=False)
    return out




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
                      f"{cell(res['inconsistent_keypoint_error_mm_mean'], '.1f')} mm. Without them:", ""]
            lines += _tables(res["consistent_only"], "frames judged consistent")
        lines += _group_table(res) + _energy_table(res)
    if result.get("prior_overcount"):
        po = result["prior_overcount"]
        top = sorted(po["max_variance_ratio_per_joint"].items(), key=lambda kv: -kv[1])[:8]
        lines += ["## The priors inside a chain of frames", "",
                  f"Variance of the per-frame pose prior over the marginal variance of the middle frame of a "
                  f"{po['frames']}-frame chain of pose + temporal priors (both moment-matched to Gaussians; "
                  "`chain_prior_overcount`). 1 would mean the chain's prior on one frame is the pose prior, i.e. "
                  "the spread of real poses; above 1 the product counts the same prior knowledge several times, "
                  f"and where the prior dominates (far, occluded) the covariances are too small by about this "
                  f"factor. Median over the 69 dimensions: {po['median_variance_ratio']:.1f}.", "",
                  "| joint (largest) | variance ratio |", "|---|---:|"]
        lines += [f"| {name} | {value:.1f} |" for name, value in top] + [""]
    if result.get("notes"):
        lines += ["## Findings", ""] + [f"- {n}" for n in result["notes"]]
    return "\n".join(lines) + "\n"


def _group_table(res: dict) -> list[str]:
    groups = list(KEYPOINT_GROUPS)
    lines = ["Keypoint NEES/dof by group and distance (all frames with covariances):", "",
             "| distance (m) | " + " | ".join(groups) + " |", "|---|" + "---:|" * len(groups)]
    for key, row in res["per_distance"].items():
        g = row.get("keypoint_groups", {})
        lines.append(f"| {key} | " + " | ".join(cell(g.get(name, {}).get("mean_nees_over_dof"), '.2f') for name in groups) + " |")
    return lines + [""]


def _energy_table(res: dict) -> list[str]:
    energy = res.get("objective_at_truth")
    if not energy:
        return []
    lines = ["Objective per frame at the estimate / at the truth (all terms, and the two motion priors), and "
             "after LM started from the truth (same graph and solver). The raw truth scores higher than a fit "
             "almost always (it is noisy against the labels); LM from the truth ending more than 1 % below the "
             "estimate shows the fit stopped in another, worse basin (a local minimum).", "",
             "| distance (m) | tracks | truth lower | LM from truth > 1 % lower | total | LM from truth | "
             "pose prior | temporal prior |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for key, row in energy.items():
        pf = row["per_frame"]
        tot_e, tot_t = sum(v["estimate"] for v in pf.values()), sum(v["truth"] for v in pf.values())
        pair = (lambda k: f"{pf[k]['estimate']:.1f} / {pf[k]['truth']:.1f}" if k in pf else "-")
        lines.append(f"| {key} | {row['tracks']} | {row['truth_lower']} | {row.get('truth_basin_lower', '-')} | "
                     f"{tot_e:.1f} / {tot_t:.1f} | {cell(row.get('truth_solved_per_frame'), '.1f')} | "
                     f"{pair('pose_prior')} | {pair('temporal_prior')} |")
    return lines + [""]


def _tables(res: dict, title: str) -> list[str]:
    lines = []
    o = res["overall"]
    lines += [f"{title}: {res['frames']} frames, {res['failed_tracks']} tracks failed; mean keypoint error "
              f"{cell(o['keypoint_error_mm_mean'], '.1f')} mm.", "",
              "| set | n | mean NEES/dof | median NEES/dof | 95 % coverage |", "|---|---:|---:|---:|---:|"]
    for label, key in (("keypoints (all 18)", "keypoints"), ("keypoints labelled visible", "keypoints_visible"),
                       ("keypoints not visible", "keypoints_occluded"), ("translation", "translation")):
        s = o[key]
        lines.append(f"| {label} | {s['n']} | {cell(s['mean_nees_over_dof'], '.2f')} | {cell(s['median_nees_over_dof'], '.2f')} | "
                     f"{cell(None if s['coverage95'] is None else 100 * s['coverage95'], '.1f')} % |")
    lines += ["", "| distance (m) | frames | keypoints NEES/dof | keypoints coverage | translation NEES/dof | "
              "translation coverage |", "|---|---:|---:|---:|---:|---:|"]
    for key, row in res["per_distance"].items():
        k, t = row["keypoints"], row["translation"]
        lines.append(f"| {key} | {row['frames']} | {cell(k['mean_nees_over_dof'], '.2f')} | "
                     f"{cell(None if k['coverage95'] is None else 100 * k['coverage95'], '.1f')} % | "
                     f"{cell(t['mean_nees_over_dof'], '.2f')} | {cell(None if t['coverage95'] is None else 100 * t['coverage95'], '.1f')} % |")
    lines.append("")
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pedestrians", type=int, default=10)
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--variants", nargs="+", default=["default", "trained_priors", "point_to_point_chamfer"])
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
        result["prior_overcount"] = chain_prior_overcount(ctx)
        for name in args.variants:
            fit_config, marginals_config = variant_config(name)
            data = collect(tracks, truth, fit_config, _context(fit_config), marginals_config)
            result["variants"][name] = summarise(data)
            print(name, result["variants"][name]["overall"], flush=True)
    out = Path(args.out)
    atomic_write_json(out / "bench_calibration.json", result)
    atomic_write_text(out / "bench_calibration.md", to_markdown(result))
    print(to_markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
