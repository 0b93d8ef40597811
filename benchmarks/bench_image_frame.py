"""Benchmark: telling from the detections alone whether a detector ran on the raw or on the rectified images
(seeded; ``pedx_graph.detections.image_frame``).

A calibration with raw keys (``K_0x`` / ``D_0x``) does not say which images the detector saw: PedX ships only
rectified images while its calibration files carry the raw keys.  Per rig (the default one and the ``pedx``
preset), seed, the images the simulated detector ran on (``detections.detected_on``: raw or rectified) and
the turn of the raw right camera against the left (``detections.right_rect_rotation_deg``: 0, a parallel pair,
the simulator's default; and ``--rotation``, as real pairs are never quite parallel before rectification), a
small scene is simulated (``--pedestrians`` x ``--frames``, detector files of ``--formats``), and for each
format and stereo pair:

* the import's decision (:func:`~pedx_graph.detections.image_frame.image_frames`, default config): the
  reading, how it was decided, the people matched between the pair's images and the log evidence;
* what each reading does to the keypoints: every detection of a labelled person at a frame with a true
  body, its keypoints (confidence >= the import's threshold) read as raw (undistorted and rectified) and as
  rectified (as they are), against the true rectified pixels of the format's own body points (the true
  body's keypoints of that set, projected by the pair's rectified projection): the median error in pixels
  as decided, and under the wrong reading.

    python benchmarks/bench_image_frame.py [--seeds 0-4] [--rotation 0.5] [--workers 2] [--out benchmarks/results]

Writes ``bench_image_frame.json`` and ``.md``.
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import hardware, parse_seeds, public_args, rows_per_seed, write_outputs  # noqa: E402
from pedx_graph.eval.benchmark_tables import image_frame_table  # noqa: E402

RIGS = ("default", "pedx")
IMAGES = ("raw", "rectified")


def _scene(out: Path, rig: str, images: str, rotation: float, seed: int, pedestrians: int, frames: int,
           formats: tuple[str, ...]) -> Path:
    from pedx_graph.sim.config import SimConfig, pedx_rig_config
    from pedx_graph.sim.simulate import simulate

    config = SimConfig() if rig == "default" else pedx_rig_config()
    config.scene.n_pedestrians, config.scene.n_frames = pedestrians, frames
    config.detections.formats = formats
    config.detections.detected_on = images
    config.detections.right_rect_rotation_deg = rotation
    simulate(out, config, seed=seed, workers=1)
    return out


def _keypoint_errors(root: Path, fmt: str, seq: str, detections, calibrations, min_confidence: float
                     ) -> dict[str, dict[str, list]]:
    """Pair -> reading -> per detection of a labelled person, the median keypoint error (px) of that reading."""
    from pedx_graph.body import BodyModel
    from pedx_graph.data.reader import read_smpl_labels
    from pedx_graph.detections.evaluate import detection_truth, read_detection_truth
    from pedx_graph.detections.undistort import find_camera, raw_camera, undistort_rectify
    from pedx_graph.sim.config import DETECTOR_FORMATS

    model = BodyModel.load().for_keypoint_set(DETECTOR_FORMATS[fmt])
    bodies = {(tid, lab.frame): lab for (s, tid), labels in read_smpl_labels(root).items() if s == seq
              for lab in labels}
    records = read_detection_truth(root, seq, fmt)
    out: dict[str, dict[str, list]] = defaultdict(lambda: {"raw": [], "rectified": []})
    for det in detections:
        record = detection_truth(det, records)
        lab = bodies.get((record.get("tracking_id"), det.frame)) if record.get("kind") == "person" else None
        if lab is None or record.get("flipped"):
            continue
        calib, side = find_camera(calibrations, det.camera)
        true_uv = calib.project(model.keypoints(lab.pose, lab.betas, lab.trans))[0 if side == "left" else 1]
        kept = (np.asarray(det.confidence) >= min_confidence) & np.all(np.isfinite(det.image_uv), axis=1)
        if kept.sum() < 3:
            continue
        uv = np.where(kept[:, None], det.image_uv, np.nan)
        for reading, read in (("raw", undistort_rectify(uv, raw_camera(calib, side))), ("rectified", uv)):
            out[calib.name][reading].append(float(np.median(np.linalg.norm(read[kept] - true_uv[kept], axis=1))))
    return out


def run_seed(seed: int, rotation: float, pedestrians: int, frames: int, formats: tuple[str, ...]) -> list[dict]:
    """Every rig, reading and rotation of one seed (module docstring): one row per format and pair."""
    from pedx_graph.data.calib import read_calibrations
    from pedx_graph.detections.image_frame import ImageFrameConfig, image_frames
    from pedx_graph.detections.noise import DetectionNoiseConfig
    from bench_association import read_format

    logging.disable(logging.WARNING)          # an undecided pair warns: here it is counted
    min_confidence = DetectionNoiseConfig().min_confidence
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for rig in RIGS:
            for images in IMAGES:
                for turn in (0.0, rotation):
                    root = _scene(Path(tmp) / f"{rig}_{images}_{turn:g}", rig, images, turn, seed, pedestrians,
                                  frames, formats)
                    seq = next((root / "truth" / "detections").iterdir()).name
                    calibrations = read_calibrations(root / "calib")
                    for fmt in formats:
                        detections = read_format(root, fmt, seq)
                        t0 = time.perf_counter()
                        decided = image_frames(detections, calibrations, ImageFrameConfig(), min_confidence, seq)
                        seconds = time.perf_counter() - t0
                        errors = _keypoint_errors(root, fmt, seq, detections, calibrations, min_confidence)
                        for pair, record in sorted(decided.items()):
                            medians = {k: (float(np.median(v)) if v else None) for k, v in errors[pair].items()}
                            rows.append({"seed": seed, "rig": rig, "images": images, "rotation_deg": turn,
                                         "format": fmt, "pair": pair, "decision": record["images"],
                                         "decided_by": record["decided_by"], "matches": record.get("matches", 0),
                                         "log_evidence_rectified": record.get("log_evidence_rectified"),
                                         "right": record["images"] == images,
                                         "own_rows": record["decided_by"] == "stereo rows",
                                         "detections_scored": len(errors[pair]["raw"]),
                                         "keypoint_error_px": medians, "decide_seconds": seconds})
    return rows


def summarise(rows: list[dict]) -> list[dict]:
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for row in rows:
        groups[(row["rig"], row["images"], row["rotation_deg"])].append(row)
    out = []
    for (rig, images, turn), group in sorted(groups.items()):
        other = "raw" if images == "rectified" else "rectified"
        scored = [r for r in group if r["keypoint_error_px"][images] is not None]
        evidence = [abs(r["log_evidence_rectified"]) for r in group if r["log_evidence_rectified"] is not None]
        out.append({
            "rig": rig, "images": images, "rotation_deg": turn, "pairs": len(group),
            "right": sum(r["right"] for r in group),
            "right_by_own_rows": sum(r["right"] and r["own_rows"] for r in group),
            "wrong_by_own_rows": sum((not r["right"]) and r["own_rows"] for r in group),
            "wrong_undecided": sum((not r["right"]) and not r["own_rows"] for r in group),
            "median_matches": float(np.median([r["matches"] for r in group])),
            "median_abs_log_evidence": float(np.median(evidence)) if evidence else None,
            "keypoint_error_px_as_read": float(np.median([r["keypoint_error_px"][r["decision"]] for r in scored]))
            if scored else None,
            "keypoint_error_px_right_reading": float(np.median([r["keypoint_error_px"][images] for r in scored]))
            if scored else None,
            "keypoint_error_px_wrong_reading": float(np.median([r["keypoint_error_px"][other] for r in scored]))
            if scored else None,
            "median_decide_ms": 1000 * float(np.median([r["decide_seconds"] for r in group]))})
    return out


def markdown(result: dict) -> str:
    lines = ["# bench_image_frame: raw or rectified images, told from the detections' stereo rows", "",
             f"Command: `{result['command']}`", "",
             f"Method: see the script's docstring.  Seeds {', '.join(map(str, result['seeds']))}; "
             f"{result['pedestrians']} pedestrians x {result['frames']} frames per scene; formats "
             f"{', '.join(result['formats'])}; one row per rig, images the detector ran on and turn of the raw right "
             "camera (degrees), over seeds, formats and the pairs with a detection.  'By its rows': decided by the "
             "pair's own stereo rows; the other pairs follow the sequence's decided pairs, or, with none, are read as "
             "raw (what their raw keys suggest) and the import warns.  Keypoint error: the median over the pairs of "
             "the median per detection of its keypoints' distance from the true rectified pixels.", "",
             *image_frame_table(result)]
    lines += ["", f"Hardware: {result['hardware']}; {result['total_seconds']:.0f} s with {result['workers']} "
                  "worker(s).", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", default="0-4", help="seeds and inclusive ranges, comma-separated")
    parser.add_argument("--rotation", type=float, default=0.5,
                        help="turn of the raw right camera against the left, degrees (besides 0)")
    parser.add_argument("--pedestrians", type=int, default=8)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--formats", default="openpose_body25,coco")
    parser.add_argument("--workers", type=int, default=2, help="processes, one seed each")
    parser.add_argument("--name", default="bench_image_frame")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    seeds = parse_seeds(args.seeds)
    formats = tuple(f.strip() for f in args.formats.split(",") if f.strip())
    t0 = time.perf_counter()
    rows = rows_per_seed(run_seed, seeds, args.workers, args.rotation, args.pedestrians, args.frames, formats)
    result = {"seeds": seeds, "rotation_deg": args.rotation, "pedestrians": args.pedestrians,
              "frames": args.frames, "formats": list(formats), "workers": args.workers,
              "summary": summarise(rows), "rows": rows,
              "command": " ".join(["python benchmarks/bench_image_frame.py"] + public_args(argv)),
              "hardware": hardware(), "total_seconds": time.perf_counter() - t0}
    write_outputs(args.out, args.name, result, markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
