"""Benchmark / calibration: pixel noise of detector keypoints as a function of their confidence (seeded).

The simulator writes detector output (``simulate --detections``: OpenPose BODY_25 / BODY_25B / COCO-18 and COCO
results on distorted raw images, confidences from its detector model, :mod:`pedx_graph.sim.detections`).  Here
every written detection of a *person* (the simulator's truth records: not clutter, not fragments) whose SMPL
truth exists at that frame is read back with our readers, undistorted and rectified
(:func:`pedx_graph.detections.undistort.rectified`), and compared with the exact rectified projection of the
true body's keypoints of the same set (the set's own definitions, ``BodyModel.for_keypoint_set``).  The
residuals are binned by confidence and :func:`pedx_graph.detections.noise.fit_sigma_curve` fits the
sigma-vs-confidence curve (robust spread per bin, non-increasing) per keypoint set and pooled over all sets.

The drop threshold is the lowest knot whose fitted sigma is at most ``--max-sigma-px`` (a keypoint noisier than
that says little about a pedestrian a few hundred pixels tall, and the low-confidence bins hold the detector
model's gross outliers and left/right swaps: their RMS exceeds their robust sigma).

    python benchmarks/bench_detection_noise.py [--seed 0] [--scenes 2] [--pedestrians 8] [--frames 20]
                                               [--out benchmarks/results]

Writes ``bench_detection_noise.json`` and ``.md``; the pooled curve and threshold are the defaults of
:class:`pedx_graph.detections.noise.DetectionNoiseConfig`.
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
from pedx_graph.detections.noise import fit_sigma_curve  # noqa: E402
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
    """Confidence (N,), residual (N, 2) px and person image height (N,) px of every present keypoint of every
    person detection of ``fmt`` with an SMPL truth."""
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
    conf, res, height = [], [], []
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
            h = float(np.ptp(true_uv[:, 1]))
            conf.append(det.confidence[ok])
            res.append(uv[ok] - true_uv[ok])
            height.append(np.full(int(ok.sum()), h))
    cat = (lambda xs, shape: np.concatenate(xs) if xs else np.zeros(shape))
    return {"confidence": cat(conf, (0,)), "residual": cat(res, (0, 2)), "height": cat(height, (0,))}


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
    out = {"sets": {}}
    pooled = {"confidence": [], "residual": []}
    for set_name, parts in sorted(data.items()):
        conf = np.concatenate([p["confidence"] for p in parts])
        res = np.concatenate([p["residual"] for p in parts])
        pooled["confidence"].append(conf)
        pooled["residual"].append(res)
        curve, rows = fit_sigma_curve(conf, res, KNOTS)
        out["sets"][set_name] = {"keypoints": int(len(conf)), "sigma_px": list(curve.sigma_px), "bins": rows,
                                 "min_confidence": threshold(KNOTS, curve.sigma_px, max_sigma_px)}
    conf = np.concatenate(pooled["confidence"])
    res = np.concatenate(pooled["residual"])
    curve, rows = fit_sigma_curve(conf, res, KNOTS)
    out["pooled"] = {"keypoints": int(len(conf)), "sigma_px": list(curve.sigma_px), "bins": rows,
                     "min_confidence": threshold(KNOTS, curve.sigma_px, max_sigma_px)}
    out["knots"] = list(KNOTS)
    return out


def markdown(result: dict, command: str) -> str:
    knots = result["knots"]
    lines = ["# Detector keypoint noise vs confidence (simulated detector)", "",
             "Method: `simulate --detections` (all formats) on seeded default-rig scenes; each person detection's "
             "keypoints read back with our readers, undistorted and rectified, and compared with the rectified "
             "projection of the true body's keypoints of the same set. Per confidence bin (nearest knot): "
             "robust sigma per axis (MAD x 1.4826 over both axes, non-increasing fit; a bin with fewer than 30 "
             "residuals takes its neighbour's value). The drop threshold is the lowest knot whose sigma is at "
             f"most {result['max_sigma_px']:g} px.", "",
             f"Command: `{command}`", "", f"Hardware: {hardware()}; {result['seconds']:.0f} s.", "",
             "| set | keypoints | min_confidence | " + " | ".join(f"sigma@{k:g}" for k in knots) + " |",
             "|---|---|---|" + "---|" * len(knots)]
    for name, entry in list(result["sets"].items()) + [("pooled (shipped default)", result["pooled"])]:
        lines.append(f"| {name} | {entry['keypoints']} | {entry['min_confidence']:g} | "
                     + " | ".join(f"{s:.2f}" for s in entry["sigma_px"]) + " |")
    lines += ["", "Pooled bins (count, robust sigma px, raw RMS px, fraction beyond 5 sigma):", "",
              "| knot | bin | count | sigma px | RMS px | beyond 5 sigma |", "|---|---|---|---|---|---|"]
    for row in result["pooled"]["bins"]:
        lo, hi = row["bin"]
        lines.append(f"| {row['knot']:g} | {lo:.2f}-{hi:.2f} | {row['count']} | {row['sigma_px']:.2f} | "
                     f"{row['rms_px']:.1f} | {row['frac_beyond_5sigma']:.3f} |")
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
