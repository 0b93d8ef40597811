"""`pedx-graph import openpose`: own OpenPose files made on distorted images of a simulated scene -> a dataset the
reader and the fit take, with the set's keypoints rectified back to the true pixels."""
import dataclasses
import json

import numpy as np

from pedx_graph.body import BodyModel
from pedx_graph.cli import main
from pedx_graph.data.calib import read_calibrations, write_stereo_calibration
from pedx_graph.data.reader import read_dataset, read_smpl_labels
from pedx_graph.data.types import RawCamera
from pedx_graph.detections.undistort import distort
from scene_fixtures import small_scene


def test_import_openpose_with_file_ids(tmp_path):
    root = small_scene(tmp_path / "scene", pedestrians=2, frames=4, seed=1)
    calibs = read_calibrations(root / "calib")
    # Give every camera a distorted raw image model and write it into the calibration files.
    raw_calibs = {}
    for name, calib in calibs.items():
        raws = [RawCamera(raw_K=P[:, :3].copy(), raw_D=np.array([-0.2, 0.08, 0.001, -0.001, 0.0]),
                          rect_R_cam=calib.rect_R_cam, P_rect=P) for P in (calib.left_P_rect, calib.right_P_rect)]
        raw_calibs[name] = dataclasses.replace(calib, left_raw=raws[0], right_raw=raws[1])
        write_stereo_calibration(root / "calib", raw_calibs[name])
    model = BodyModel.load().for_keypoint_set("body25")
    truth = read_smpl_labels(root)
    files = tmp_path / "openpose"
    expected = {}
    for number, ((seq, tid), labels) in enumerate(sorted(truth.items())):
        for lab in labels:
            world = model.keypoints(lab.pose, lab.betas, lab.trans)
            for name, calib in raw_calibs.items():
                for side, cam in zip(("left", "right"), name.split("-")):
                    rect = calib.project(world)[0 if side == "left" else 1]
                    raw_uv = distort(rect, calib.left_raw if side == "left" else calib.right_raw)
                    w, h = calib.image_size
                    if not np.all((raw_uv > 0) & (raw_uv < [w, h])):
                        continue
                    path = files / f"{seq}_{cam}_{lab.frame:07d}_keypoints.json"
                    doc = json.loads(path.read_text()) if path.is_file() else {"version": 1.3, "people": []}
                    flat = np.c_[raw_uv, np.full(25, 0.9)].ravel().tolist()
                    doc["people"].append({"person_id": [number], "pose_keypoints_2d": flat})
                    path.parent.mkdir(parents=True, exist_ok=True)
                    path.write_text(json.dumps(doc))
                    expected[(cam, lab.frame, str(number))] = rect
    assert expected
    out = tmp_path / "imported"
    assert main(["import", "openpose", str(files), "--calib", str(root), "--out", str(out), "--use-file-ids"]) == 0
    summary = json.loads((out / "import_summary.json").read_text())
    assert summary["keypoint_sets"] == ["body25"] and (out / "pointclouds").exists()
    tracks = read_dataset(out)
    assert {t.tracking_id for t in tracks} <= {str(i) for i in range(len(truth))} and tracks
    checked = 0
    cam_of = {(name, side): cam for name in raw_calibs for side, cam in zip(("left", "right"), name.split("-"))}
    for track in tracks:
        assert track.keypoint_set == "body25"
        for fr in track.frames:
            for pair, side, view in fr.labelled_views():
                want = expected[(cam_of[(pair, side)], fr.frame, track.tracking_id)]
                assert np.abs(view.keypoints - want).max() < 1e-3          # undistorted + rectified
                assert view.sigma_px is not None and np.all(view.sigma_px > 0)
                checked += 1
    assert checked >= len(expected) // 2
