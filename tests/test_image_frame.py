"""Raw or rectified: the import tells from the detections' own stereo rows which images a detector ran on, since a
calibration with raw keys (as PedX's, whose release ships only rectified images) does not say it."""
import json
import logging

import cv2
import numpy as np
import pytest

from pedx_graph.cli import main
from pedx_graph.config import load_config
from pedx_graph.data.labels2d import iter_label2d_files, read_label2d
from pedx_graph.data.types import RawCamera, StereoCalibration
from pedx_graph.detections.image_frame import ImageFrameConfig, image_frames, pixel_calibrations
from pedx_graph.detections.importer import ImportConfig
from pedx_graph.detections.types import Detection
from pedx_graph.detections.undistort import distort, undistort_rectify
from scene_fixtures import small_scene

FOCAL, SIZE = 3300.0, (3600, 2600)


def pair(name: str, turn_deg: float = 0.3, distinct: bool = True) -> StereoCalibration:
    """A rectified pair whose raw cameras differ from the rectified model (principal points, distortion; the right
    one turned by ``turn_deg`` about a skew axis); ``distinct`` False: both raw models are the rectified one."""
    rect_R = cv2.Rodrigues(np.radians([0.4, -0.7, 0.2]))[0]
    left_P = np.array([[FOCAL, 0, 1800.0, 0], [0, FOCAL, 1300.0, 0], [0, 0, 1, 0]])
    right_P = left_P.copy()
    right_P[0, 3] = -FOCAL * 0.3
    raws = []
    for P, shift, k1, turn in ((left_P, (8.0, -6.0), -0.10, 0.0), (right_P, (-5.0, 9.0), -0.06, turn_deg)):
        K = P[:, :3].copy()
        R = rect_R @ cv2.Rodrigues(np.radians(turn) * np.array([0.6, 0.64, 0.48]))[0]
        if distinct:
            K[:2, 2] += shift
            raws.append(RawCamera(raw_K=K, raw_D=np.array([k1, 0.02, 0.0, 0.0, 0.0]), rect_R_cam=R, P_rect=P))
        else:
            raws.append(RawCamera(raw_K=K, raw_D=np.zeros(5), rect_R_cam=rect_R, P_rect=P))
    return StereoCalibration(name=name, left_P_rect=left_P, right_P_rect=right_P, rect_R_cam=rect_R,
                             world_T_cam=np.eye(4), image_size=SIZE, left_raw=raws[0], right_raw=raws[1])


def people_detections(calib: StereoCalibration, images: str, people: int, seed: int = 0) -> list[Detection]:
    """``people`` standing figures (15 points, 1.7 m tall) at 6-30 m, one per frame, seen by both cameras with
    1.5 px noise; the pixels of the ``raw`` (distorted) or ``rectified`` images."""
    rng = np.random.default_rng(seed)
    template = np.c_[rng.uniform(-0.25, 0.25, 15), -np.linspace(0.0, 1.7, 15), rng.uniform(-0.1, 0.1, 15)]
    left, _, right = calib.name.partition("-")
    out = []
    for frame in range(people):
        depth = rng.uniform(6, 30)
        rect_p = template + [rng.uniform(-0.4, 0.4) * depth, 1.5, depth]
        for camera, P, raw in ((left, calib.left_P_rect, calib.left_raw), (right, calib.right_P_rect, calib.right_raw)):
            hom = np.c_[rect_p, np.ones(15)] @ P.T
            uv = hom[:, :2] / hom[:, 2:] + rng.normal(scale=1.5, size=(15, 2))
            if images == "raw":
                uv = distort(uv, raw)
            out.append(Detection(camera=camera, frame=frame, keypoint_set="body25", image_uv=uv,
                                 confidence=np.full(15, 0.9), score=0.9, source=f"{camera}_{frame}.json#people[0]"))
    return out


@pytest.mark.parametrize("images", ["raw", "rectified"])
def test_each_reading_is_told_from_the_stereo_rows(images):
    calib = pair("camA-camB")
    decided = image_frames(people_detections(calib, images, 40), {calib.name: calib}, ImageFrameConfig(), 0.2)
    record = decided["camA-camB"]
    assert record["images"] == images and record["decided_by"] == "stereo rows"
    assert record["matches"] == 40
    # the row differences of the true reading are noise; the other reading's carry the two raw models' difference
    rows = record["row_difference_px"]
    assert rows[images] < 2.0 < rows["raw" if images == "rectified" else "rectified"]
    assert abs(record["log_evidence_rectified"]) >= ImageFrameConfig().min_log_evidence


def test_alike_raw_models_are_undecided_and_read_as_raw_with_a_warning(caplog):
    calib = pair("camA-camB", distinct=False)
    with caplog.at_level(logging.WARNING):
        record = image_frames(people_detections(calib, "rectified", 40), {calib.name: calib}, ImageFrameConfig(),
                              0.2, "seqA")["camA-camB"]
    assert record["images"] == "raw" and "too close to tell" in record["decided_by"]
    assert "seqA" in caplog.text and "camA-camB" in caplog.text and "image_frame.images" in caplog.text


def test_a_pair_with_too_few_people_follows_the_decided_pairs():
    first, second = pair("camA-camB"), pair("camC-camD")
    calibs = {first.name: first, second.name: second}
    dets = people_detections(first, "rectified", 40) + people_detections(second, "rectified", 3, seed=1)
    decided = image_frames(dets, calibs, ImageFrameConfig(), 0.2)
    assert decided["camA-camB"]["decided_by"] == "stereo rows"
    assert decided["camC-camD"]["images"] == "rectified"
    assert decided["camC-camD"]["decided_by"].startswith("the other pairs' stereo rows")
    # alone, the same few people decide nothing: read as raw
    alone = image_frames(people_detections(second, "rectified", 3, seed=1), {second.name: second},
                         ImageFrameConfig(), 0.2)["camC-camD"]
    assert alone["images"] == "raw" and "too few people matched" in alone["decided_by"]


def test_the_config_overrides_the_test_and_only_rectified_pairs_lose_their_raw_models():
    first, second = pair("camA-camB"), pair("camC-camD")
    dets = people_detections(first, "raw", 10) + people_detections(second, "raw", 10, seed=1)
    decided = image_frames(dets, {first.name: first, second.name: second}, ImageFrameConfig(images="rectified"), 0.2)
    assert {r["decided_by"] for r in decided.values()} == {"config"}
    calibs = pixel_calibrations({first.name: first, second.name: second},
                                {"camA-camB": {"images": "rectified"}, "camC-camD": {"images": "raw"}})
    assert calibs["camA-camB"].left_raw is None and calibs["camA-camB"].right_raw is None
    assert calibs["camC-camD"].left_raw is second.left_raw and calibs["camC-camD"].right_raw is second.right_raw
    assert calibs["camC-camD"].left_raw is not None
    with pytest.raises(ValueError, match="image_frame.images"):
        ImageFrameConfig(images="distorted")


def test_the_import_config_file_names_the_reading(tmp_path):
    path = tmp_path / "import.yaml"
    path.write_text("image_frame:\n  images: rectified\n")
    assert load_config(ImportConfig, path).image_frame.images == "rectified"


def _written_pixels_match(out, root, fmt_folder, read_as) -> int:
    """How many written labels' keypoints equal ``read_as(file pixels, camera)`` of a detection of their camera and
    frame (to 1e-3 px); asserts every label does."""
    from pedx_graph.detections.openpose import read_openpose

    dets = read_openpose(root / "detections" / fmt_folder, "body25")
    by_image = {}
    for det in dets:
        by_image.setdefault((det.camera, det.frame), []).append(read_as(det))
    seq = next((out / "labels" / "2d").iterdir()).name
    checked = 0
    for path, camera, frame, tid in iter_label2d_files(out, seq):
        view = read_label2d(path, seq, camera, frame, tid).view
        kept = np.all(np.isfinite(view.keypoints), axis=1)
        best = min(np.nan_to_num(np.abs(uv[kept] - view.keypoints[kept]), nan=np.inf).max()
                   for uv in by_image[(camera, frame)])
        assert best < 1e-3, (path.name, best)
        checked += 1
    return checked


@pytest.mark.parametrize("images", ["rectified", "raw"])
def test_import_reads_the_images_the_simulated_detector_ran_on(tmp_path, images):
    """The real rig's preset with the raw right cameras turned 0.5 degrees, the detector run on the raw or on the
    rectified images, the calibration with its raw keys either way: the import reads each pair as the detector
    ran, and every written keypoint is the file's pixel read that way (as it is, or undistorted and rectified)."""
    from pedx_graph.data.calib import read_calibrations
    from pedx_graph.detections.undistort import find_camera, raw_camera
    from pedx_graph.sim.config import pedx_rig_config

    config = pedx_rig_config()
    config.detections.formats = ("openpose_body25",)
    config.detections.detected_on = images
    config.detections.right_rect_rotation_deg = 0.5
    root = small_scene(tmp_path / "scene", pedestrians=4, frames=10, seed=0, config=config)
    calibrations = read_calibrations(root / "calib")
    assert all(c.left_raw is not None and c.right_raw is not None for c in calibrations.values())
    out = tmp_path / "imported"
    assert main(["import", "openpose", str(root / "detections" / "openpose_body25"), "--keypoint-set", "body25",
                 "--calib", str(root), "--out", str(out)]) == 0
    summary = json.loads((out / "import_summary.json").read_text())
    (record,) = summary["sequences"].values()
    assert {r["images"] for r in record["image_frame"].values()} == {images}
    assert any(r["decided_by"] == "stereo rows" for r in record["image_frame"].values())

    def read_as(det):
        if images == "rectified":
            return det.image_uv
        calib, side = find_camera(calibrations, det.camera)
        return undistort_rectify(det.image_uv, raw_camera(calib, side))

    assert _written_pixels_match(out, root, "openpose_body25", read_as) > 20
