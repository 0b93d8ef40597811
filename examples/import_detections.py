"""Import a detector's keypoints (OpenPose JSON) and fit them: no hand labels, no tracking ids.

The simulator writes what OpenPose (BODY_25) would give on the scene's raw, distorted images
(``SimConfig.detections.formats``): keypoints with confidences, missed people, fragments and clutter, no ids.
``read_openpose`` reads the files; ``import_detections`` undistorts and rectifies them with the calibration,
associates them into tracks (stereo, then over time), turns each confidence into a pixel noise and writes a
dataset in the release layout, with each person's LiDAR points cut from the scene clouds; ``fit_dataset`` fits
it.  The command-line way is the same:

    pedx-graph import openpose SCENE/detections/openpose_body25 --calib SCENE --out IMPORTED
    pedx-graph fit IMPORTED --out RESULTS

The import lists where two tracks came close (``IMPORTED/import_summary.json``, ``identity_review``); what a
look there finds wrong goes into a fixes file that the same import applies (docs/detections.md, "Fixing who
is who"):

    pedx-graph import openpose SCENE/detections/openpose_body25 --calib SCENE --out IMPORTED \
        --identity-fixes fixes.yaml

    python examples/import_detections.py --out example_out/detections --pedestrians 4 --frames 10

Each fitted track is matched to the labelled simulated person nearest to it and its keypoint error printed
(a track of a person the simulator never labelled, a bystander, has no truth: its nearest person is far);
writes ``OUT/detections_summary.json``.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from pedx_graph import (BodyModel, ImportConfig, SimConfig, fit_dataset, import_detections, read_openpose,
                        read_smpl_labels, simulate)


def nearest_person(fitted_labels, truth: dict, model: BodyModel) -> tuple[str | None, float]:
    """The labelled simulated person (tracking id) whose keypoints lie nearest the fitted track's over its frames, and
    that mean keypoint distance in metres."""
    best, best_error = None, float("inf")
    for (_, tid), labels in truth.items():
        by_frame = {lab.frame: lab for lab in labels}
        common = [lab for lab in fitted_labels if lab.frame in by_frame]
        if len(common) < len(fitted_labels) // 2 + 1:
            continue
        errors = []
        for lab in common:
            true = by_frame[lab.frame]
            world_p_true = model.forward(true.pose, true.betas, true.trans).keypoints       # (18, 3)
            errors.append(np.linalg.norm(np.asarray(lab.extra["keypoints_3d"]) - world_p_true, axis=1).mean())
        if np.mean(errors) < best_error:
            best, best_error = tid, float(np.mean(errors))
    return best, best_error


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--out", default="example_out/detections", help="output folder")
    parser.add_argument("--pedestrians", type=int, default=4, help="pedestrians in the scene")
    parser.add_argument("--frames", type=int, default=10, help="frames (10 Hz)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scene and its detections")
    args = parser.parse_args(argv)

    out = Path(args.out)
    sim = SimConfig()
    sim.scene.n_pedestrians, sim.scene.n_frames = args.pedestrians, args.frames
    sim.detections.formats = ("openpose_body25",)                    # also write OpenPose files, no ids
    scene = out / "scene"
    simulate(scene, sim, seed=args.seed, overwrite=True)

    detections = read_openpose([scene / "detections" / "openpose_body25"], "body25")
    imported = out / "imported"
    record = import_detections(detections, scene, imported, ImportConfig())   # -> labels/2d, calib, segments
    n_tracks = sum(s["tracks"] for s in record["sequences"].values())
    print(f"{record['detections']} detections -> {n_tracks} tracks")
    if n_tracks == 0:                        # nobody detected often enough to make a track: nothing to fit
        result = {"detections": record["detections"], "counts": None, "tracks": []}
        (out / "detections_summary.json").write_text(json.dumps(result, indent=1))
        return result
    summary = fit_dataset(imported, out / "results", overwrite=True)
    print(f"fitted {summary['counts']['done']} tracks ({summary['counts']['failed']} failed)")

    truth = read_smpl_labels(scene)                                  # the simulator's exact bodies
    model = BodyModel.load()
    tracks = []
    for (sequence, tid), labels in read_smpl_labels(out / "results").items():
        person, error = nearest_person(labels, truth, model)
        tracks.append({"tracking_id": tid, "frames": len(labels), "person": person, "keypoint_error_mm": 1e3 * error})
        print(f"{tid}: {len(labels)} frames, nearest person {person and person[:8]}, keypoint error "
              f"{1e3 * error:.0f} mm")
    result = {"detections": record["detections"], "counts": summary["counts"], "tracks": tracks}
    (out / "detections_summary.json").write_text(json.dumps(result, indent=1))
    return result


if __name__ == "__main__":
    main()
