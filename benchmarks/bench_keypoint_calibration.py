"""Benchmark: a detector's keypoint definitions calibrated from its own fits (``pedx-graph calibrate-keypoints``).

Scenes: the detection benchmark's two (``bench_detections.scene_configs``: ``crossing`` and ``mixed``, default
rig), simulated with the detector's keypoints moved off the body model's definitions by about ``--shifts``
metres (``detections.definition_shift_m``: per format and scene, every keypoint moved by a difference of two
skin vertices, :func:`pedx_graph.sim.detections.shifted_definitions`; 0: on the definitions), on the default
rig or the real PedX rig (``--rig pedx``: z-down LiDAR frame).  Each format's detections are imported with the
simulator's ids (``use_file_ids``: the definitions isolated from the association), or as a user would,
through the association (``--associate``: frames scored against the person most of their detections belong
to, those placed more than 1 m off counted apart, as in ``bench_detections``), fitted with batch LM
(covariances on), and calibrated from that fit (:func:`pedx_graph.detections.calibrate_keypoints.estimate_offsets`,
the command's estimator, prior 5 cm);
then fitted again with the calibrated set (``FitConfig.keypoint_sets``) and calibrated again, ``--rounds``
times.  Each scene is its own detector (the simulator draws its offsets per scene), so each is calibrated
from its own fit only; nothing of the truth enters the calibration.

Reported per shift, format and round (both scenes pooled, frames of labelled people at 5-25 m from the
LiDAR): global and root-relative MPJPE of the 13 evaluation joints (mm), the share of the 18 fitted PedX
keypoints inside their 95 % covariance ellipsoid, and the calibrated offsets' distance from the simulator's
(mean over the set's keypoints, mm; round 0: the offsets' own size, as the fit uses none).

    python benchmarks/bench_keypoint_calibration.py [--seed 0] [--pedestrians 10] [--frames 20] [--workers 2]
                                                    [--shifts 0,0.02,0.04] [--rounds 3] [--step 1]
                                                    [--definition-sigma 0] [--rig default|pedx] [--associate]
                                                    [--out benchmarks/results/keypoint_calibration]
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

from _common import hardware, public_args, write_outputs  # noqa: E402
from bench_detections import (FORMATS, GOAL_RANGE_M, MATCH_RADIUS_M, RIGS, _truth_frames,  # noqa: E402
                              frame_owners, labelled_instances, read_format, scene_clouds, scene_configs,
                              with_true_ids)
from pedx_graph.data.calib import read_calibrations  # noqa: E402
from pedx_graph.data.ground import ground_from_calibrations  # noqa: E402
from pedx_graph.detections.association import associate  # noqa: E402
from pedx_graph.body import BodyModel  # noqa: E402
from pedx_graph.data.reader import read_dataset  # noqa: E402
from pedx_graph.detections.calibrate_keypoints import calibrated_set, estimate_offsets  # noqa: E402
from pedx_graph.detections.evaluate import read_detection_truth  # noqa: E402
from pedx_graph.detections.importer import ImportConfig, import_detections  # noqa: E402
from pedx_graph.eval.metrics import eval_joints, joint_errors  # noqa: E402
from pedx_graph.graph.config import FitConfig  # noqa: E402
from pedx_graph.graph.context import fit_body_model  # noqa: E402
from pedx_graph.sim.config import DETECTOR_FORMATS  # noqa: E402
from pedx_graph.sim.detections import shifted_definitions  # noqa: E402
from pedx_graph.sim.simulate import simulate  # noqa: E402
from pedx_graph.solvers.fit import fit_tracks  # noqa: E402
from pedx_graph.utils import atomic_write_json  # noqa: E402

#: 95 % quantile of chi-square with 3 dof: a keypoint inside its 95 % ellipsoid.
CHI2_3_95 = 7.814727903251178


def true_offsets(model: BodyModel, set_name: str, shift_m: float, seed: tuple) -> np.ndarray:
    """(K, 3) the simulated detector's offsets from the set's definitions, at rest (mean shape), metres."""
    base = model.for_keypoint_set(set_name)
    if shift_m <= 0:
        return np.zeros((base.keypoint_map.num_keypoints, 3))
    moved = shifted_definitions(base, shift_m, seed)
    rest_v = np.asarray(model.v_template)
    rest_j = model.rest_joints(np.zeros(model.num_betas))
    return moved.apply(rest_v[moved.vertex_ids], rest_j) - base.keypoint_map.apply(
        rest_v[base.keypoint_map.vertex_ids], rest_j)


def scored_rows(dataset, results, truth: dict, labelled: dict, owners: dict | None = None) -> list[dict]:
    """Per fitted frame of a labelled person at 5-25 m: global / root-relative MPJPE (mm) and the fitted
    keypoints inside their 95 % ellipsoid (of those with a covariance).  A track frame is scored against the
    person of its tracking id, or with ``owners`` (``bench_detections.frame_owners``: tracks of the
    association) against the person most of its detections belong to; a frame whose pelvis lies more than
    ``MATCH_RADIUS_M`` from that person's is a row with ``misplaced`` set (no MPJPE)."""
    rows = []
    for track, (result, _) in zip(dataset, results):
        if result is None:
            continue
        for i, frame in enumerate(result.frames):
            person = track.tracking_id if owners is None else owners.get((track.tracking_id, frame))
            chosen = [c for c in truth.get(frame, []) if c[0] == person and c[2]]
            distance = labelled.get(person, {}).get(frame)
            if not chosen or distance is None or not GOAL_RANGE_M[0] <= distance < GOAL_RANGE_M[1]:
                continue
            fitted = np.asarray(result.world_keypoints[i])
            if np.linalg.norm(fitted[[12, 13]].mean(axis=0) - chosen[0][1][[12, 13]].mean(axis=0)) > MATCH_RADIUS_M:
                rows.append({"misplaced": True})
                continue
            glob, rel = joint_errors(eval_joints(fitted[None]), eval_joints(chosen[0][1][None]))
            extra = result.extra_per_frame[i] if result.extra_per_frame else {}
            inside = None
            if extra.get("covariance_status") == "ok" and extra.get("cov_keypoints_3d") is not None:
                err = fitted - chosen[0][1]
                nees = np.einsum("ni,ni->n", err, np.linalg.solve(np.asarray(extra["cov_keypoints_3d"], float),
                                                                  err[..., None])[..., 0])
                inside = nees <= CHI2_3_95
            rows.append({"mpjpe_mm": 1000 * float(np.mean(glob)), "rel_mpjpe_mm": 1000 * float(np.mean(rel)),
                         "inside": inside})
    return rows


def summary(rows: list[dict]) -> dict:
    misplaced = sum(1 for r in rows if r.get("misplaced"))
    rows = [r for r in rows if not r.get("misplaced")]
    inside = [r["inside"] for r in rows if r["inside"] is not None]
    return {"frames": len(rows), "misplaced_frames": misplaced,
            "mpjpe_mm": float(np.mean([r["mpjpe_mm"] for r in rows])) if rows else None,
            "rel_mpjpe_mm": float(np.mean([r["rel_mpjpe_mm"] for r in rows])) if rows else None,
            "coverage_95": float(np.mean(np.concatenate(inside))) if inside else None}


def run(seed: int, pedestrians: int, frames: int, workers: int, shifts: list[float], rounds: int,
        work: Path, step: float = 1.0, definition_sigma_m: float = 0.0, rig: str = "default",
        associate_people: bool = False) -> dict:
    model = BodyModel.load()
    out: dict = {}
    for shift in shifts:
        configs = scene_configs(pedestrians, frames, detector_definition_shift_m=shift, rig=rig)
        per_format: dict = {fmt: {"rounds": [[] for _ in range(rounds + 1)],
                                  "offset_error_mm": [[] for _ in range(rounds + 1)]} for fmt in FORMATS}
        for s, (name, cfg) in enumerate(configs.items()):
            scene = work / f"shift{shift:g}" / name
            simulate(scene, cfg, seed=seed + s, workers=workers)
            seq = cfg.scene.sequence
            labelled = labelled_instances(scene, seq)
            truth = _truth_frames(scene, [cfg.scene.first_frame + k for k in range(cfg.scene.n_frames)])
            for f_index, fmt in enumerate(cfg.detections.formats):
                if fmt not in per_format:
                    continue
                set_name = DETECTOR_FORMATS[fmt]
                truth_offsets = true_offsets(model, set_name, shift, (seed + s, 12, f_index))
                detections = read_format(scene, fmt, seq)
                records = read_detection_truth(scene, seq, fmt)
                known = work / f"shift{shift:g}" / f"{name}_{fmt}"
                import_config = ImportConfig(use_file_ids=not associate_people)
                import_config.noise.definition_sigma_m = definition_sigma_m
                owners = None
                if associate_people:            # the import's own association; frames scored by their owners
                    calibs = read_calibrations(scene / "calib")
                    tracks = associate(detections, calibs, config=import_config.association,
                                       clouds=scene_clouds(scene, seq), ground=ground_from_calibrations(calibs, seq))
                    owners = frame_owners(tracks, records)
                    import_detections(detections, scene, known, config=import_config)
                else:
                    import_detections(with_true_ids(detections, records), scene, known, config=import_config)
                dataset = read_dataset(known) if (known / "labels").is_dir() else []
                folder, estimated = None, np.zeros_like(truth_offsets)
                for r in range(rounds + 1):
                    config = FitConfig(diagnostics=False, covariances=True,
                                       keypoint_sets=str(folder) if folder else "")
                    results = list(fit_tracks(dataset, config, workers=workers))
                    per_format[fmt]["rounds"][r] += scored_rows(dataset, results, truth, labelled, owners)
                    per_format[fmt]["offset_error_mm"][r].append(
                        1000 * float(np.mean(np.linalg.norm(estimated - truth_offsets, axis=1))))
                    if r == rounds:
                        break
                    used = fit_body_model(config)
                    fitted = [(track, res.frames, res.pose, res.betas, res.trans)
                              for track, (res, _) in zip(dataset, results) if res is not None]
                    basis, estimate = estimate_offsets(used, set_name, fitted, step=step)
                    estimated = estimated + estimate.rest_offset_m
                    folder = work / f"shift{shift:g}" / f"{name}_{fmt}_sets_round{r + 1}"
                    folder.mkdir(parents=True)
                    atomic_write_json(folder / f"{set_name}.json", calibrated_set(used, basis, estimate))
        out[f"{shift:g}"] = {fmt: {"rounds": [summary(rows) for rows in v["rounds"]],
                                   "offset_error_mm": [float(np.mean(e)) for e in v["offset_error_mm"]]}
                             for fmt, v in per_format.items()}
    return out


def _step(step: float) -> str:
    return "" if step == 1.0 else f", each round's change times {step:g}"


def _sigma(sigma_m: float) -> str:
    return "" if sigma_m == 0 else f"; imported with `noise.definition_sigma_m` {sigma_m:g} m"


def markdown(result: dict, command: str) -> str:
    lines = ["# bench_keypoint_calibration: a detector's keypoint definitions calibrated from its own fits", "",
             f"Command: `{command}`", "",
             f"Seed {result['seed']}, {result['pedestrians']} pedestrians x {result['frames']} frames per scene, "
             f"both scenes of the detection benchmark ({result.get('rig', 'default')} rig); detections imported "
             + ("as a user would, without ids (the association; frames scored against the person most of their "
                "detections belong to, those placed more than 1 m off counted apart); " if result.get("associate")
                else "with the simulator's ids; ") +
             "method in the script's docstring.  Round 0: the shipped definitions; round r: fitted with the set "
             "calibrated from round r-1's fit" + _step(result.get("step", 1.0))
             + _sigma(result.get("definition_sigma_m", 0.0)) + ".  MPJPE at 5-25 m (mm), "
             "global / root-relative; coverage: fitted keypoints inside their 95 % ellipsoid; offset error: the "
             "calibrated offsets' mean distance from the "
             "simulator's (mm).", "",
             "| detector's offset | input | round | frames (misplaced) | MPJPE (mm) | root-rel. (mm) | 95 % coverage "
             "| offset error (mm) |",
             "|---|---|---:|---:|---:|---:|---:|---:|"]
    for shift, formats in result["shifts"].items():
        for fmt, v in formats.items():
            for r, (s, e) in enumerate(zip(v["rounds"], v["offset_error_mm"])):
                cov = "-" if s["coverage_95"] is None else f"{s['coverage_95']:.3f}"
                lines.append(f"| {float(shift) * 100:g} cm | {fmt} | {r} | {s['frames']} "
                             f"({s.get('misplaced_frames', 0)}) | {s['mpjpe_mm']:.1f} | {s['rel_mpjpe_mm']:.1f} | "
                             f"{cov} | {e:.1f} |")
    lines += ["", f"Hardware: {result['hardware']}; {result['total_seconds']:.0f} s in all.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--pedestrians", type=int, default=10)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2, help="processes for simulating and fitting")
    parser.add_argument("--shifts", default="0,0.02,0.04",
                        help="the simulated detector's offsets from the definitions, metres, comma-separated")
    parser.add_argument("--rounds", type=int, default=3, help="fit-and-calibrate rounds after the first fit")
    parser.add_argument("--step", type=float, default=1.0,
                        help="each round's change of the definitions times this (over-relaxation; 1: as estimated)")
    parser.add_argument("--definition-sigma", type=float, default=0.0,
                        help="import with this uncertainty of the detector's points about the definitions, metres "
                             "(import.noise.definition_sigma_m; 0: none)")
    parser.add_argument("--rig", choices=RIGS, default="default",
                        help="the simulated rig: the default one, or the real PedX rig (z-down LiDAR frame)")
    parser.add_argument("--associate", action="store_true",
                        help="import the detections as a user would, without ids (the association), instead of "
                             "grouped by the simulator's ids")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "keypoint_calibration"))
    args = parser.parse_args(argv)
    shifts = [float(x) for x in args.shifts.split(",")]
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench_keypoint_calibration_") as tmp:
        shifted = run(args.seed, args.pedestrians, args.frames, args.workers, shifts, args.rounds, Path(tmp),
                      args.step, args.definition_sigma, args.rig, args.associate)
    result = {"seed": args.seed, "pedestrians": args.pedestrians, "frames": args.frames, "workers": args.workers,
              "rounds": args.rounds, "step": args.step, "definition_sigma_m": args.definition_sigma,
              "rig": args.rig, "associate": args.associate, "shifts": shifted,
              "total_seconds": time.perf_counter() - t0, "hardware": hardware()}
    command = " ".join(["python benchmarks/bench_keypoint_calibration.py"] + public_args(argv))
    result["command"] = command
    write_outputs(args.out, "bench_keypoint_calibration", result, markdown(result, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
