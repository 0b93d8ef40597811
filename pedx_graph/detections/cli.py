"""``pedx-graph import openpose|coco``: detector / annotation-tool keypoint files -> a PedX-layout dataset; and
``pedx-graph calibrate-keypoints``: the detector's own keypoint definitions measured from a fit of such a dataset."""
from __future__ import annotations

import argparse
import logging

from pedx_graph.execution.options import positive_int

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "import", help="import OpenPose / COCO keypoint files as a PedX-layout dataset",
        description="Read detector keypoints (OpenPose JSON: BODY_25, BODY_25B, COCO-18; COCO annotation or "
                    "results files) made on the raw or the rectified images (told per stereo pair from the "
                    "detections' rows, or --image-frame), at the calibration's size or resized (a COCO image list's "
                    "sizes, or --detector-image-scale; checked against the LiDAR) or in normalised coordinates, "
                    "undistort and rectify the raw ones with the calibration, "
                    "group them into people (the files' ids with --use-file-ids, else stereo + tracking "
                    "association) and write labels/2d in the PedX layout with keypoint_set, confidence and "
                    "sigma_px per keypoint, plus calib/ (copied), pointclouds/ (linked) and LiDAR segments cut "
                    "from the scene clouds.  Camera and frame come from the file names: PedX image names "
                    "<seq>_<cam>_<frame>, <cam>.<frame>, or --name-pattern.")
    p.add_argument("format", choices=["openpose", "coco"], help="input format")
    p.add_argument("input", nargs="+", help="OpenPose: JSON files or folders (searched recursively); "
                                            "COCO: one annotation or results file")
    p.add_argument("--calib", required=True,
                   help="a dataset root holding calib/ (its pointclouds/ and timestamps/ are used too) or a "
                        "folder of calib_cam_to_cam_*.txt / calib_cam_to_range_*.txt files")
    p.add_argument("--out", required=True, help="output dataset root (created)")
    p.add_argument("--keypoint-set", default=None, choices=["body25", "body25b", "coco18"],
                   help="OpenPose model (25 keypoints are BODY_25 unless body25b is named; 18 are COCO-18)")
    p.add_argument("--name-pattern", default=None,
                   help="regex with named groups camera, frame (and optionally sequence) matched against the "
                        "file / image name without its extension, e.g. '(?P<camera>cam\\d+)\\.(?P<frame>\\d+)'")
    p.add_argument("--camera", action="append", default=None, metavar="NAME=CALIB_NAME",
                   help="rename a camera of the file names to its calibration name (repeatable)")
    p.add_argument("--sequence", default=None, help="sequence name when the file names give none (default: "
                                                    "'detections')")
    p.add_argument("--images", default=None, help="COCO results: the file listing the images (an annotation "
                                                  "file), to resolve image ids to names")
    p.add_argument("--use-file-ids", action="store_true",
                   help="group by the ids in the files (OpenPose person_id, COCO track_id) instead of associating")
    p.add_argument("--config", default=None, help="YAML with an ImportConfig (noise: sigma curve, threshold)")
    p.add_argument("--image-frame", default=None, choices=["auto", "raw", "rectified"],
                   help="the images the detector ran on: raw (distorted) or rectified (e.g. a release's "
                        "rectified images); default auto: told per stereo pair from the detections' rows "
                        "(config: image_frame.images)")
    p.add_argument("--detector-image-scale", type=float, default=None, metavar="S",
                   help="the detector ran on the images resized by S (0.5: half their width and height); "
                        "default: from the files' image sizes (COCO image lists), else the calibration's size, "
                        "checked against the LiDAR (config: pixel_scale.scale)")
    p.add_argument("--raw-images", "--review-images", dest="raw_images", default=None, metavar="FOLDER",
                   help="the images the detections were made on, raw or rectified (searched recursively, found "
                        "by the names "
                        "the files give): written rectified into OUT/images/ (pedx-graph export draws on them; "
                        "write_images: false in --config to skip), and each stretch where two tracks came "
                        "close (or a track and a detection no track holds) drawn on them, one JPEG per stretch "
                        "in OUT/review/<sequence>/")
    p.add_argument("--identity-fixes", default=None, metavar="FILE",
                   help="a YAML file of identity fixes (exchange, move, split, merge, remove, add, checked: per "
                        "sequence, "
                        "naming the tracks as this import writes them) applied before the labels are written; "
                        "see docs/detections.md, 'Fixing who is who'")
    p.add_argument("--workers", type=positive_int, default=1,
                   help="local processes for the association, one stereo pair each (default 1: this process; "
                        "the same tracks with any number)")
    p.set_defaults(func=_run_import)

    c = subparsers.add_parser(
        "calibrate-keypoints", help="measure where a detector's keypoints sit on the body model from its fits",
        description="From an imported detection dataset and its fit (pedx-graph fit --out RESULTS), estimate how "
                    "far each keypoint of the detector's set lies from the definition the fit used, on the "
                    "body model (per keypoint, an offset that turns with the skin around it; its uncertainty "
                    "from the labels' sigmas), and write the moved sets as OUT/<set>.json, a table "
                    "OUT/calibration.md and OUT/fit_config.yaml (the fit's config with keypoint_sets: OUT). "
                    "A fit absorbs part of an offset: fit again with --config OUT/fit_config.yaml and "
                    "calibrate again from that fit, or let --rounds do it (3 rounds: docs/detections.md).")
    c.add_argument("dataset", help="the imported dataset (pedx-graph import --out)")
    c.add_argument("results", help="its fit's results folder (pedx-graph fit --out)")
    c.add_argument("--out", required=True, help="folder for the calibrated keypoint sets (created)")
    c.add_argument("--prior-sigma", type=float, default=0.05, metavar="METRES",
                   help="prior standard deviation of each keypoint's offset from the shipped definition per axis, "
                        "metres")
    c.add_argument("--rounds", type=positive_int, default=1,
                   help="calibrate, then fit the dataset again with the calibrated sets and calibrate from that fit, "
                        "this many rounds in all (each one's sets, config and fit in OUT/round<k>/; the last "
                        "round's in OUT)")
    c.add_argument("--workers", type=positive_int, default=1, help="local processes fitting the tracks (--rounds > 1)")
    c.set_defaults(func=_run_calibrate)


def _run_calibrate(args: argparse.Namespace) -> int:
    import sys
    from pathlib import Path

    import numpy as np

    from pedx_graph.config import load_config
    from pedx_graph.detections.calibrate_keypoints import calibrate_from_results
    from pedx_graph.graph.config import FitConfig
    from pedx_graph.keypoints import load_keypoint_set
    from pedx_graph.solvers.fit import fit_dataset

    if not args.prior_sigma > 0:
        raise ValueError(f"--prior-sigma must be > 0 metres, got {args.prior_sigma}")
    command = "pedx-graph " + " ".join(sys.argv[1:]) if sys.argv[1:] else "pedx-graph calibrate-keypoints"
    out, results = Path(args.out), Path(args.results)
    for k in range(1, args.rounds + 1):
        folder = out if k == args.rounds else out / f"round{k}"
        estimates = calibrate_from_results(args.dataset, results, folder, prior_sigma_m=args.prior_sigma,
                                           command=command)
        if k < args.rounds:
            moved = {name: float(np.median(1000 * np.linalg.norm(e.rest_offset_m, axis=1)))
                     for name, e in estimates.items()}
            print(f"round {k}: definitions moved by " + ", ".join(f"{n} {v:.0f} mm" for n, v in moved.items())
                  + f" (median); fitting again into {folder / 'fit'}")
            results = folder / "fit"
            fit_dataset(args.dataset, results, load_config(FitConfig, folder / "fit_config.yaml"),
                        workers=args.workers, overwrite=True)
    for name, est in estimates.items():
        length = 1000 * np.linalg.norm(est.offset_in_use_m + est.rest_offset_m, axis=1)
        change = 1000 * np.linalg.norm(est.rest_offset_m, axis=1)
        worst = int(np.argmax(length))
        print(f"{name}: {len(length)} keypoints {np.median(length):.0f} mm from the shipped definitions (median; "
              f"largest {length[worst]:.0f} mm, {load_keypoint_set(name).keypoints[worst]}), moved by "
              f"{np.median(change):.0f} mm this round (median); written {args.out}/{name}.json")
    print(f"fit again with: pedx-graph fit {args.dataset} --config {args.out}/fit_config.yaml --out <folder>")
    return 0


def _camera_names(items: list[str] | None) -> dict[str, str] | None:
    if not items:
        return None
    out = {}
    for item in items:
        name, sep, calib_name = item.partition("=")
        if not sep or not name or not calib_name:
            raise ValueError(f"--camera expects NAME=CALIB_NAME, got {item!r}")
        out[name] = calib_name
    return out


def _run_import(args: argparse.Namespace) -> int:
    from pedx_graph.config import load_config
    from pedx_graph.detections.importer import ImportConfig, import_detections

    config = load_config(ImportConfig, args.config)
    cameras = _camera_names(args.camera)
    if args.format == "openpose":
        from pedx_graph.detections.openpose import read_openpose
        detections = read_openpose(args.input, args.keypoint_set, args.name_pattern, cameras)
    else:
        from pedx_graph.detections.coco import read_coco
        if len(args.input) != 1:
            raise ValueError("coco: give exactly one annotation or results file")
        detections = read_coco(args.input[0], args.images, args.name_pattern, cameras)
    config.use_file_ids = config.use_file_ids or args.use_file_ids
    if args.image_frame is not None:
        config.image_frame.images = args.image_frame
    if args.detector_image_scale is not None:
        from pedx_graph.detections.pixel_scale import PixelScaleConfig
        config.pixel_scale = PixelScaleConfig(**{**vars(config.pixel_scale), "scale": args.detector_image_scale})
    summary = import_detections(detections, args.calib, args.out, config, sequence=args.sequence,
                                workers=args.workers, raw_images=args.raw_images,
                                identity_fixes=args.identity_fixes)
    tracks = sum(s["tracks"] for s in summary["sequences"].values())
    labels = sum(s["labels_written"] for s in summary["sequences"].values())
    print(f"imported {summary['detections']} detections as {tracks} tracks ({labels} label files) into {args.out}")
    from pedx_graph.data.types import UNTRACKED

    for seq, record in sorted(summary["sequences"].items()):
        scales = record.get("pixel_scale") or {}
        for camera, used in sorted((scales.get("cameras") or {}).items()):
            if used["units"] != "pixels" or used["scale"] != [1.0, 1.0]:
                print(f"  {seq}: camera {camera}: coordinates read as {used['units'].replace('_', ' ')}"
                      + (f" of images resized by {used['scale'][0]:.4g} x {used['scale'][1]:.4g}"
                         if used["units"] == "pixels" else "") + f" ({used['from']})")
        check = (scales.get("lidar_check") or {}).get("all pairs") or {}
        if check.get("judged"):
            print(f"  {seq}: {check['people_on_lidar']} of {check['people']} people matched in a pair's two images "
                  f"lie on the LiDAR's returns at the pixels' scale (pixel check)")
        for pair, frame in sorted((record.get("image_frame") or {}).items()):
            rows = frame.get("row_difference_px")
            measured = (f"; stereo rows {rows['raw']:.1f} px as raw, {rows['rectified']:.1f} px as rectified, "
                        f"{frame['matches']} people" if rows else "")
            print(f"  {seq}: pair {pair}: detections read as made on {frame['images']} images "
                  f"({frame['decided_by']}{measured})")
        interval = record.get("frame_interval")
        if interval:
            implied = (f"; {interval['walking_tracks']} walking tracks imply {interval['implied_interval_s']:.3f} s"
                       if interval.get("implied_interval_s") is not None else "")
            print(f"  {seq}: frames {interval['frame_interval_s']:.3f} s apart ({interval['from']}){implied}"
                  + ("" if interval["agrees"] else " -- check the frame rate (warning above)"))
        fixed = record.get("identity_fixes")
        if fixed:
            n = fixed["operations"]
            print(f"  {seq}: {n} identity fix operation{'' if n == 1 else 's'} applied ({fixed['detections_moved']} "
                  f"detections moved, {fixed['detections_added']} added, {fixed['detections_removed']} removed; "
                  f"tracks changed: "
                  f"{', '.join(fixed['tracks_changed']) or 'none'})")
        review = record.get("identity_review")
        checked = review.get("checked_stretches", 0) if review else 0
        if review and len(review["stretches"]) > checked:
            print(f"  {seq}: {len(review['stretches']) - checked} stretches where two tracks came close, or a "
                  f"track and a detection no track holds"
                  + (f" ({checked} more marked checked)" if checked else "") + " "
                  f"({review.get('unchecked_flagged_track_frames', review['flagged_track_frames'])} of "
                  f"{review['track_frames']} track frames): check who is "
                  f"who there (import_summary.json, sequences.{seq}.identity_review)")
            print(f"    what is wrong there goes into a fixes file for --identity-fixes (one entry per stretch "
                  f"to edit: {args.out}/identity_fixes_template.yaml)")
            for i in review.get("check_order", [])[:3]:
                stretch = review["stretches"][i]
                names = stretch["tracks"] if len(stretch["tracks"]) > 1 else stretch["tracks"] + [UNTRACKED]
                print(f"    check first: {' and '.join(names)}, frames {stretch['first_frame']}-"
                      f"{stretch['last_frame']} ({stretch['frames_missed']} of "
                      f"{stretch['frames_held'] + stretch['frames_missed']} of their frames missed)")
        sheets = record.get("review_sheets")
        drawn = [s for s in sheets["sheets"] if s["sheet"]] if sheets else []
        if drawn:
            with_image = sum(s["cells_with_image"] for s in drawn)
            print(f"  {seq}: {len(drawn)} review sheets in {args.out}/{sheets['folder']} "
                  f"({with_image} of {sum(s['cells'] for s in drawn)} cells on their image)")
        written = record.get("images")
        if written:
            print(f"  {seq}: {written['written']} images rectified into {args.out}/{written['folder']}"
                  + (f" ({written['without_image']} named by detections not in the folder)"
                     if written["without_image"] else ""))
            for camera, reason in sorted(written["skipped_cameras"].items()):
                print(f"    camera {camera} skipped: {reason}")
        check = record.get("stereo_noise_check")
        if check and check.get("scale") is not None:
            print(f"  {seq}: stereo rows show {check['scale']:.2f}x the noise model's keypoint noise "
                  f"({check['samples']} keypoints); sigmas x{check['applied']:.2f}")
            if check.get("by_confidence"):
                print("    by confidence: " + ", ".join(f"{b['knot']:g}: {b['scale']:.2f} (n {b['count']})"
                                                        for b in check["by_confidence"]))
    return 0
