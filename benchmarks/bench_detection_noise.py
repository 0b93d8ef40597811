"""Benchmark / calibration: pixel noise of detector keypoints vs their confidence and the person's size (seeded).

The simulator writes detector output (``simulate --detections``: OpenPose BODY_25 / BODY_25B / COCO-18 and COCO
results on distorted raw images, confidences from its detector model, :mod:`pedx_graph.sim.detections`).  Here
every written detection of a *person* (the simulator's truth records: not clutter, not fragments) whose SMPL
truth exists at that frame is read back with our readers, undistorted and rectified
(:func:`pedx_graph.detections.undistort.rectified`), and compared with the exact rectified projection of the
true body's keypoints of the same set (the set's own definitions, ``BodyModel.for_keypoint_set``).  The
person's image height is measured on the detection itself (vertical span of its present rectified keypoints,
:func:`pedx_graph.detections.noise.detection_height_px`), as the import measures it.  Per keypoint set,
:func:`~pedx_graph.detections.noise.keypoint_scales` gives each keypoint's relative noise factor (confidence
>= 0.5); the residuals divided by their factor are pooled over all sets and
:func:`~pedx_graph.detections.noise.fit_noise_model` fits the size-independent floor and the
sigma-vs-confidence curve at the reference height (``DetectionNoiseConfig.reference_height_px``); the same fit
per set is reported for comparison.

The drop threshold is the lowest knot whose fitted sigma at the reference height is at most ``--max-sigma-px``
(a keypoint noisier than 10 % of the person's height says little, and the low-confidence bins hold the
detector model's gross outliers and left/right swaps: their RMS exceeds their robust sigma).

    python benchmarks/bench_detection_noise.py [--seed 0] [--scenes 2] [--pedestrians 8] [--frames 20]
                                               [--out benchmarks/results]

Writes ``bench_detection_noise.json`` and ``.md``; the pooled floor, curve and threshold and the per-set
keypoint factors are the defaults of :class:`pedx_graph.detections.noise.DetectionNoiseConfig`.
"""
from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import hardware, public_args  # noqa: E402
from pedx_graph.body import BodyModel  # noqa: E402
from pedx_graph.data.calib import read_calibrations  # noqa: E402
from pedx_graph.data.reader import read_smpl_labels  # noqa: E402
from pedx_graph.detections.coco import read_coco_results  # noqa: E402
from pedx_graph.detections.noise import (DetectionNoiseConfig, detection_height_px, fit_noise_model,  # noqa: E402
                                         keypoint_scales)
from pedx_graph.detections.openpose import read_openpose  # noqa: E402
from pedx_graph.detections.undistort import find_camera, rectified  # noqa: E402
from pedx_graph.sim.config import DETECTOR_FORMATS, SimConfig  # noqa: E402
from pedx_graph.sim.simulate import simulate  # noqa: E402
from pedx_graph.utils import atomic_write_json, atomic_write_text  # noqa: E402

KNOTS = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
_INDEX = re.compile(r"#(?:people)?\[(\d+)\]$")


def read_format(root: Path, fmt: str, seq: str) -> list:
    """The detections of one format, in the order of the simulator's truth records."""
    if fmt == "coco":
        folder = root / "detections" / "coco" / seq
        return read_coco_results(folder / "keypoint_results.json", images=folder / "image_list.json")
    dets = read_openpose(root / "detections" / fmt / seq, keypoint_set=DETECTOR_FORMATS[fmt])
    order = {n: i for i, n in enumerate(c for c in sorted({d.camera for d in dets}))}
    return sorted(dets, key=lambda d: (d.frame, order[d.camera], int(_INDEX.search(d.source).group(1))))


def residuals(root: Path, fmt: str, model: BodyModel) -> dict[str, np.ndarray]:
    """Confidence (N,), residual (N, 2) px, person image height measured on the detection (N,) px and keypoint
    index (N,) of every present keypoint of every person detection of ``fmt`` with an SMPL truth."""
    seq = next(p.name for p in (root / "truth" / "detections").iterdir())
    truth_records = json.loads((root / "truth" / "detections" / seq / f"{fmt}.json").read_text())
    calibs = read_calibrations(root / "calib")
    smpl = {(tid, lab.frame): lab for (s, tid), labels in read_smpl_labels(root).items() for lab in labels}
    set_model = model.for_keypoint_set(DETECTOR_FORMATS[fmt])
    dets = read_format(root, fmt, seq)
    by_image: dict[tuple, list] = defaultdict(list)
    for det in dets:
        by_image[(det.camera, det.frame)].append(det)
    records: dict[tuple, list] = defaultdict(list)
    for rec in truth_records:
        records[(rec["camera"], rec["frame"])].append(rec)
    conf, res, height, kp_index = [], [], [], []
    for key, recs in records.items():
        found = by_image.get(key, [])
        if fmt == "coco":
            pairs = list(zip(sorted(recs, key=lambda r: r["index"]), found))
        else:
            index = {int(_INDEX.search(d.source).group(1)): d for d in found}
            pairs = [(r, index.get(r["index"])) for r in recs]
        for rec, det in pairs:
            if det is None or rec["kind"] != "person" or (rec["tracking_id"], rec["frame"]) not in smpl:
                continue
            lab = smpl[(rec["tracking_id"], rec["frame"])]
            world = set_model.keypoints(lab.pose, lab.betas, lab.trans)
            calib, side = find_camera(calibs, det.camera)
            true_uv = calib.project(world)[0 if side == "left" else 1]
            uv = rectified(det, calibs)
            ok = det.present & np.all(np.isfinite(uv), axis=1)
            h = detection_height_px(np.where(ok[:, None], uv, np.nan))
            conf.append(det.confidence[ok])
            res.append(uv[ok] - true_uv[ok])
            height.append(np.full(int(ok.sum()), h))
            kp_index.append(np.flatnonzero(ok))
    cat = (lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape))
    return {"confidence": cat(conf, (0,)), "residual": cat(res, (0, 2)), "height": cat(height, (0,)),
            "keypoint": cat(kp_index, (0,)).astype(int)}


def threshold(knots: tuple[float, ...], sigma_px: tuple[float, ...], max_sigma_px: float) -> float:
    """The lowest knot whose fitted sigma is at most ``max_sigma_px`` (the curve does not increase)."""
    ok = [k for k, s in zip(knots, sigma_px) if s <= max_sigma_px]
    return float(min(ok)) if ok else float(knots[-1])


def run(seed: int, scenes: int, pedestrians: int, frames: int, work: Path, max_sigma_px: float) -> dict:
    model = BodyModel.load()
    data: dict[str, list[dict]] = defaultdict(list)
    for s in range(scenes):
        cfg = SimConfig()
        cfg.scene.n_pedestrians = pedestrians
        cfg.scene.n_frames = frames
        cfg.detections.formats = tuple(DETECTOR_FORMATS)
        root = work / f"scene{s}"
        simulate(root, cfg, seed=seed + s)
        for fmt in DETECTOR_FORMATS:
            data[DETECTOR_FORMATS[fmt]].append(residuals(root, fmt, model))
    href = DetectionNoiseConfig().reference_height_px
    out = {"sets": {}, "reference_height_px": href}
    pooled = {"confidence": [], "residual": [], "height": []}
    for set_name, parts in sorted(data.items()):
        conf = np.concatenate([p["confidence"] for p in parts])
        res = np.concatenate([p["residual"] for p in parts])
        height = np.concatenate([p["height"] for p in parts])
        index = np.concatenate([p["keypoint"] for p in parts])
        good = conf >= 0.5
        scales = keypoint_scales(index[good], res[good], height[good], int(index.max()) + 1, href)
        res = res / scales[index][:, None]
        pooled["confidence"].append(conf)
        pooled["residual"].append(res)
        pooled["height"].append(height)
        floor, curve, rows = fit_noise_model(conf, res, height, KNOTS, href)
        out["sets"][set_name] = {"keypoints": int(len(conf)), "floor_px": floor, "sigma_px": list(curve.sigma_px),
                                 "bins": rows, "keypoint_scale": [float(v) for v in scales],
                                 "min_confidence": threshold(KNOTS, curve.sigma_px, max_sigma_px)}
    conf = np.concatenate(pooled["confidence"])
    res = np.concatenate(pooled["residual"])
    height = np.concatenate(pooled["height"])
    floor, curve, rows = fit_noise_model(conf, res, height, KNOTS, href)
    out["pooled"] = {"keypoints": int(len(conf)), "floor_px": floor, "sigma_px": list(curve.sigma_px),
                     "bins": rows, "min_confidence": threshold(KNOTS, curve.sigma_px, max_sigma_px)}
    out["knots"] = list(KNOTS)
    return out


def markdown(result: dict, command: str) -> str:
    knots = result["knots"]
    href = result["reference_height_px"]
    lines = ["# Detector keypoint noise vs confidence and person size (simulated detector)", "",
             "Method: `simulate --detections` (all formats) on seeded default-rig scenes; each person detection's "
             "keypoints read back with our readers, undistorted and rectified, and compared with the rectified "
             "projection of the true body's keypoints of the same set. Model: `sigma = k_scale[k] * "
             "sqrt(floor^2 + (curve(c) * h / h_ref)^2)`, `h` the person's height measured on the detection "
             f"(span of its present keypoints), h_ref = {href:g} px. Per set, each keypoint's factor is its "
             "robust spread of size-normalised residuals (confidence >= 0.5) over the set's median. Per "
             "confidence bin (nearest knot), the reference sigma makes the robust spread (MAD x 1.4826 over both "
             "axes) of the normalised residuals 1 (non-increasing fit); the floor is the one that equalises that "
             "spread over the height quartiles. The drop threshold is the lowest knot whose reference sigma is "
             f"at most {result['max_sigma_px']:g} px.", "",
             f"Command: `{command}`", "", f"Hardware: {hardware()}; {result['seconds']:.0f} s.", "",
             "| set | keypoints | floor px | min_confidence | "
             + " | ".join(f"sigma@{k:g}" for k in knots) + " |",
             "|---|---|---|---|" + "---|" * len(knots)]
    for name, entry in list(result["sets"].items()) + [("pooled (shipped default)", result["pooled"])]:
        lines.append(f"| {name} | {entry['keypoints']} | {entry['floor_px']:g} | {entry['min_confidence']:g} | "
                     + " | ".join(f"{s:.2f}" for s in entry["sigma_px"]) + " |")
    lines += ["", "Per-keypoint factors (shipped as `keypoint_scale`, set order):", ""]
    for name, entry in result["sets"].items():
        lines.append(f"- {name}: " + ", ".join(f"{v:.2f}" for v in entry["keypoint_scale"]))
    lines += ["", "Pooled bins (count, reference sigma px, RMS and fraction beyond 5 of the normalised "
              "residuals):", "",
              "| knot | bin | count | sigma px | RMS / sigma | beyond 5 sigma |", "|---|---|---|---|---|---|"]
    for row in result["pooled"]["bins"]:
        lo, hi = row["bin"]
        lines.append(f"| {row['knot']:g} | {lo:.2f}-{hi:.2f} | {row['count']} | {row['sigma_px']:.2f} | "
                     f"{row['rms_normalised']:.2f} | {row['frac_beyond_5sigma']:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--scenes", type=int, default=2)
    parser.add_argument("--pedestrians", type=int, default=8)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--max-sigma-px", type=float, default=20.0,
                        help="drop threshold: the lowest confidence knot whose sigma is at most this, px")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as work:
        result = run(args.seed, args.scenes, args.pedestrians, args.frames, Path(work), args.max_sigma_px)
    result["seconds"] = time.perf_counter() - t0
    result["max_sigma_px"] = args.max_sigma_px
    command = "python benchmarks/bench_detection_noise.py " + " ".join(public_args(sys.argv[1:] if argv is None
                                                                                  else argv))
    result["command"] = command.strip()
    out = Path(args.out)
    atomic_write_json(out / "bench_detection_noise.json", result)
    atomic_write_text(out / "bench_detection_noise.md", markdown(result, result["command"]))
    print(markdown(result, result["command"]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
