"""Raw images of a size of their own (KITTI's ``S_0x``, larger than the rectified images rectification crops):
simulated by ``detections.raw_margin_px`` and read back right, in pixels and in normalised coordinates
(pedx_graph.sim.detections, pedx_graph.detections.pixel_scale)."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from pedx_graph.cli import main
from pedx_graph.data.calib import read_calibrations
from pedx_graph.data.labels2d import iter_label2d_files, read_label2d
from pedx_graph.data.types import RawCamera, StereoCalibration
from pedx_graph.detections.pixel_scale import resized_cameras, seen_calibrations
from pedx_graph.detections.undistort import undistort_rectify
from scene_fixtures import small_scene

MARGIN = (200.0, 150.0)


def _labels(out) -> dict:
    seq = next((out / "labels" / "2d").iterdir()).name
    return {path.name: read_label2d(path, seq, camera, frame, tid).view.keypoints
            for path, camera, frame, tid in iter_label2d_files(out, seq)}


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """The real rig's preset, its raw images 400 x 300 px larger than the rectified ones, one scene written in
    the raw images' pixels and in [0, 1] of their size (the same draws)."""
    from pedx_graph.sim.config import pedx_rig_config

    out = {}
    for units in ("pixels", "unit"):
        config = pedx_rig_config()
        config.detections.formats = ("openpose_body25", "coco")
        config.detections.raw_margin_px, config.detections.pixel_units = MARGIN, units
        out[units] = small_scene(tmp_path_factory.mktemp(units), pedestrians=6, frames=10, seed=0, config=config)
    return out


def _import_openpose(root, out) -> int:
    return main(["import", "openpose", str(root / "detections" / "openpose_body25"), "--keypoint-set", "body25",
                 "--calib", str(root), "--out", str(out)])


def test_the_raw_images_size_is_written_and_the_detector_sees_past_the_rectified_image(scenes, tmp_path):
    calibrations = read_calibrations(scenes["pixels"] / "calib")
    for calib in calibrations.values():
        for raw in (calib.left_raw, calib.right_raw):
            assert raw.image_size == tuple(int(v + 2 * m) for v, m in zip(calib.image_size, MARGIN))
    seq = next((scenes["pixels"] / "detections" / "coco").iterdir()).name
    listing = json.loads((scenes["pixels"] / "detections" / "coco" / seq / "image_list.json").read_text())
    raw_sizes = {name: calib.left_raw.image_size for calib in calibrations.values()
                 for name in calib.name.split("-")}
    for image in listing["images"]:
        camera = image["file_name"].split("/")[-2]
        assert (image["width"], image["height"]) == raw_sizes[camera]
    coco = scenes["pixels"] / "detections" / "coco" / seq
    assert main(["import", "coco", str(coco / "keypoint_results.json"), "--images", str(coco / "image_list.json"),
                 "--calib", str(scenes["pixels"]), "--out", str(tmp_path / "coco")]) == 0
    (record,) = json.loads((tmp_path / "coco" / "import_summary.json").read_text())["sequences"].values()
    assert all(c["scale"] == [1.0, 1.0] and c["from"] == "image sizes in the files"
               for c in record["pixel_scale"]["cameras"].values())
    assert not record["pixel_scale"]["lidar_check"]["all pairs"]["contradicts"]
    # people seen by the raw image beyond the rectified one: their keypoints are rectified past its border
    assert _import_openpose(scenes["pixels"], tmp_path / "pixels") == 0
    points = np.concatenate([kp[np.isfinite(kp[:, 0])] for kp in _labels(tmp_path / "pixels").values()])
    width, height = next(iter(calibrations.values())).image_size
    beyond = (points[:, 0] < 0) | (points[:, 1] < 0) | (points[:, 0] > width) | (points[:, 1] > height)
    assert 0 < beyond.sum() < 0.2 * len(points)


def test_normalised_coordinates_of_larger_raw_images_are_read_as_their_pixels(scenes, tmp_path):
    """[0, 1] of a raw image larger than the rectified one, read at the rectified size, put every point off by
    a tenth of its distance to the image's corner; the raw model is given for that size instead, and the labels
    are those of the pixel files, with the same LiDAR support."""
    assert _import_openpose(scenes["pixels"], tmp_path / "pixels") == 0
    assert _import_openpose(scenes["unit"], tmp_path / "unit") == 0
    pixels, unit = _labels(tmp_path / "pixels"), _labels(tmp_path / "unit")
    assert unit.keys() == pixels.keys() and len(pixels) > 50
    for name, keypoints in pixels.items():
        np.testing.assert_allclose(unit[name], keypoints, atol=5e-3, err_msg=name)
    checks = [json.loads((tmp_path / v / "import_summary.json").read_text()) for v in ("pixels", "unit")]
    (a,), (b,) = (list(c["sequences"].values()) for c in checks)
    assert a["pixel_scale"]["lidar_check"]["all pairs"]["people_on_lidar"] == \
        b["pixel_scale"]["lidar_check"]["all pairs"]["people_on_lidar"]
    assert {pair["images"] for pair in b["image_frame"].values()} == {"raw"}


def _pair(raw_size) -> StereoCalibration:
    P = np.array([[1500.0, 0, 1000, 0], [0, 1500, 750, 0], [0, 0, 1, 0]])
    right = P.copy()
    right[0, 3] = -750.0
    raw_K = np.array([[1510.0, 0, 1200], [0, 1490, 900], [0, 0, 1]])
    raws = [RawCamera(raw_K=raw_K, raw_D=np.array([-0.1, 0.02, 0, 0, 0]), rect_R_cam=np.eye(3), P_rect=p,
                      image_size=raw_size) for p in (P, right)]
    return StereoCalibration(name="camA-camB", left_P_rect=P, right_P_rect=right, rect_R_cam=np.eye(3),
                             world_T_cam=np.eye(4), image_size=(2000, 1500), left_raw=raws[0], right_raw=raws[1])


def test_the_raw_model_is_given_for_the_pixels_as_read():
    calib = _pair((2400, 1800))
    record = {"camA": {"units": "unit", "scale": [1.0, 1.0]}, "camB": {"units": "pixels", "scale": [1.0, 1.0]}}
    seen = seen_calibrations({calib.name: calib}, record)[calib.name]
    assert seen.right_raw is calib.right_raw                     # pixels: its own model
    raw_uv = np.array([[300.0, 200.0], [1200.0, 900.0], [2300.0, 1700.0]])
    read = raw_uv / (2400, 1800) * (2000, 1500)                  # [0, 1] read at the rectified size
    np.testing.assert_allclose(undistort_rectify(read, seen.left_raw), undistort_rectify(raw_uv, calib.left_raw),
                               atol=1e-6)
    # the raw images the detector saw are brought to the size that model is for
    assert resized_cameras({"cameras": record}, {calib.name: calib}) == {"camA": ((2000, 1500), (1.2, 1.2))}
    # a raw image of the rectified size (or none given) needs nothing
    same = _pair((2000, 1500))
    assert seen_calibrations({same.name: same}, record)[same.name] is same
    none = dataclasses.replace(same, left_raw=dataclasses.replace(same.left_raw, image_size=None))
    assert seen_calibrations({none.name: none}, record)[none.name] is none
    assert resized_cameras({"cameras": record}, {none.name: none}) == {"camA": ((2000, 1500), None)}
