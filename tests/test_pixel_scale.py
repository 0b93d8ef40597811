"""Detections made on resized images or written in normalised coordinates: read back to the calibration's pixels,
refused where the files or the LiDAR contradict the pixels (pedx_graph.detections.pixel_scale)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pedx_graph.cli import main
from pedx_graph.data.labels2d import iter_label2d_files, read_label2d
from pedx_graph.data.types import DataFormatError, StereoCalibration
from pedx_graph.detections.coco import read_coco
from pedx_graph.detections.pixel_scale import PixelScaleConfig, coordinate_units, detector_pixels
from pedx_graph.detections.pixel_units import PIXEL_UNITS, from_detector_units, to_detector_units
from pedx_graph.detections.types import Detection
from scene_fixtures import small_scene

SIZE = (2000, 1500)


@pytest.mark.parametrize("units", PIXEL_UNITS)
def test_units_go_there_and_back(units):
    rng = np.random.default_rng(0)
    uv = rng.uniform(-50, 2050, size=(30, 2))
    uv[3] = np.nan
    written = to_detector_units(uv, SIZE, (0.5, 0.4999), units)
    back = from_detector_units(written, SIZE, (0.5, 0.4999), units)
    assert np.all(np.isnan(back[3])) and np.allclose(back[~np.isnan(uv[:, 0])], uv[~np.isnan(uv[:, 0])])
    if units == "unit":
        assert np.allclose(to_detector_units([[2000.0, 1500.0]], SIZE, units=units), 1.0)
    if units == "signed_unit":
        assert np.allclose(to_detector_units([[0.0, 1500.0]], SIZE, units=units), [[-1.0, 1.0]])
    with pytest.raises(ValueError, match="pixel units"):
        to_detector_units(uv, SIZE, units="millimetres")


def test_the_units_are_told_from_the_coordinates():
    rng = np.random.default_rng(1)
    pixels = rng.uniform(0, 2000, size=(40, 2))
    assert coordinate_units(pixels, PixelScaleConfig()) == "pixels"
    assert coordinate_units(pixels / 2000, PixelScaleConfig()) == "unit"
    assert coordinate_units(pixels / 1000 - 1, PixelScaleConfig()) == "signed_unit"
    # a [0, 1] file with a point just outside the image is still [0, 1]; too few points say nothing
    almost = pixels / 2000
    almost[0] = (-0.01, 0.5)
    assert coordinate_units(almost, PixelScaleConfig()) == "unit"
    assert coordinate_units(pixels[:5] / 2000, PixelScaleConfig()) == "pixels"
    assert coordinate_units(pixels / 2000, PixelScaleConfig(units="pixels")) == "pixels"


def _pair() -> StereoCalibration:
    P = np.array([[1500.0, 0, 1000, 0], [0, 1500, 750, 0], [0, 0, 1, 0]])
    right = P.copy()
    right[0, 3] = -1500 * 0.5
    return StereoCalibration(name="camA-camB", left_P_rect=P, right_P_rect=right, rect_R_cam=np.eye(3),
                             world_T_cam=np.eye(4), image_size=SIZE)


def _detection(camera: str, uv: np.ndarray, size=None, source="dets.json#[0]") -> Detection:
    return Detection(camera=camera, frame=0, keypoint_set="coco17", image_uv=uv, confidence=np.full(len(uv), 0.9),
                     score=0.9, source=source, image_size=size, bbox=np.array([10.0, 20.0, 100.0, 300.0]))


def test_image_sizes_in_the_files_set_the_scale_per_axis_and_a_crop_is_refused():
    calib = _pair()
    uv = np.random.default_rng(2).uniform(0, 500, size=(17, 2))
    dets = [_detection("camA", uv, (1000, 750)), _detection("camB", uv, (1000, 750))]
    out, record = detector_pixels(dets, {calib.name: calib}, PixelScaleConfig())
    assert np.allclose(out[0].image_uv, uv * 2) and np.allclose(out[0].bbox, [20.0, 40.0, 200.0, 600.0])
    assert record["cameras"]["camA"] == {"units": "pixels", "scale": [0.5, 0.5], "from": "image sizes in the files"}
    assert record["lidar_check"] == {}          # no clouds: nothing to check against
    # a resize to whole pixels keeps the aspect to within its rounding; a crop does not
    out, _ = detector_pixels([_detection("camA", uv, (667, 500))], {calib.name: calib}, PixelScaleConfig())
    assert np.allclose(out[0].image_uv, uv * [2000 / 667, 3.0])
    with pytest.raises(DataFormatError, match=r"dets.json.*images \(width, height\).*1000x500.*cropped"):
        detector_pixels([_detection("camA", uv, (1000, 500))], {calib.name: calib}, PixelScaleConfig())
    with pytest.raises(DataFormatError, match="two sizes, 1000x750 and 2000x1500"):
        detector_pixels([_detection("camA", uv, (1000, 750)), _detection("camA", uv, (2000, 1500))],
                        {calib.name: calib}, PixelScaleConfig())


def test_pixels_beyond_the_image_are_refused():
    calib = _pair()
    rng = np.random.default_rng(3)
    dets = [_detection("camA", rng.uniform(0, 1, size=(17, 2)) * SIZE, source=f"f{i}.json#[0]") for i in range(10)]
    out, _ = detector_pixels(dets, {calib.name: calib}, PixelScaleConfig())
    assert np.allclose(out[4].image_uv, dets[4].image_uv)
    # the same pixels said to be of images shrunk to half: read twice as far out, most beyond the image
    with pytest.raises(DataFormatError, match=r"f\d\.json: field 'keypoints': .* beyond its image \(2000x1500"):
        detector_pixels(dets, {calib.name: calib}, PixelScaleConfig(scale=0.5))


def test_the_config_refuses_what_it_cannot_mean():
    with pytest.raises(ValueError, match="pixel_scale.units"):
        PixelScaleConfig(units="mm")
    with pytest.raises(ValueError, match="pixel_scale.scale"):
        PixelScaleConfig(scale=-1)


def test_coco_image_sizes_are_read_and_a_bad_one_is_named(tmp_path):
    listing = {"images": [{"id": 1, "file_name": "camA.0003.jpg", "width": 1000, "height": 750}]}
    (tmp_path / "list.json").write_text(json.dumps(listing))
    results = [{"image_id": 1, "category_id": 1, "keypoints": [10.0, 20.0, 0.9] * 17, "score": 0.9}]
    (tmp_path / "results.json").write_text(json.dumps(results))
    (det,) = read_coco(tmp_path / "results.json", tmp_path / "list.json")
    assert det.image_size == (1000, 750) and det.camera == "camA" and det.frame == 3
    listing["images"][0]["width"] = 0
    (tmp_path / "list.json").write_text(json.dumps(listing))
    with pytest.raises(DataFormatError, match=r"list.json: field 'images\[0\].width': must be a positive integer"):
        read_coco(tmp_path / "results.json", tmp_path / "list.json")


def _labels(out) -> dict:
    seq = next((out / "labels" / "2d").iterdir()).name
    labels = {}
    for path, camera, frame, tid in iter_label2d_files(out, seq):
        labels[path.name] = read_label2d(path, seq, camera, frame, tid).view.keypoints
    return labels


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """The real rig's preset, one scene written three ways by the simulated detector: pixels of the calibrated
    images, pixels of images shrunk to half, and [0, 1] coordinates (the same draws)."""
    from pedx_graph.sim.config import pedx_rig_config

    out = {}
    for name, scale, units in (("full", 1.0, "pixels"), ("half", 0.5, "pixels"), ("unit", 1.0, "unit")):
        config = pedx_rig_config()
        config.detections.formats = ("openpose_body25", "coco")
        config.detections.image_scale, config.detections.pixel_units = scale, units
        out[name] = small_scene(tmp_path_factory.mktemp(name), pedestrians=6, frames=10, seed=0, config=config)
    return out


def _import_openpose(root, out, *extra) -> int:
    return main(["import", "openpose", str(root / "detections" / "openpose_body25"), "--keypoint-set", "body25",
                 "--calib", str(root), "--out", str(out), *extra])


def test_resized_openpose_pixels_are_refused_then_read_as_told(scenes, tmp_path, capsys):
    """Pixels of half-size images, read as the calibration's, put nobody on the LiDAR's returns: the import
    refuses them in one line naming a file, the scale the LiDAR prefers and the option; told the resize, it
    writes the labels it writes from the full-size files (to the files' rounding)."""
    assert _import_openpose(scenes["full"], tmp_path / "full") == 0
    full = _labels(tmp_path / "full")
    summary = json.loads((tmp_path / "full" / "import_summary.json").read_text())
    (record,) = summary["sequences"].values()
    check = record["pixel_scale"]["lidar_check"]["all pairs"]
    assert check["judged"] and not check["contradicts"] and check["best_scale"] == pytest.approx(1.0, abs=0.05)
    capsys.readouterr()
    assert _import_openpose(scenes["half"], tmp_path / "refused") != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "_keypoints.json: field 'keypoints'" in err
    assert "--detector-image-scale (import.pixel_scale.scale; about 0.50 here)" in err and "0.50 x those read" in err
    assert _import_openpose(scenes["half"], tmp_path / "told", "--detector-image-scale", "0.5") == 0
    told = _labels(tmp_path / "told")
    assert told.keys() == full.keys() and len(full) > 50
    for name, keypoints in full.items():
        np.testing.assert_allclose(told[name], keypoints, atol=5e-3, err_msg=name)


def test_normalised_coordinates_and_coco_sizes_need_no_telling(scenes, tmp_path):
    assert _import_openpose(scenes["full"], tmp_path / "full") == 0
    assert _import_openpose(scenes["unit"], tmp_path / "unit") == 0
    full, unit = _labels(tmp_path / "full"), _labels(tmp_path / "unit")
    assert unit.keys() == full.keys()
    for name, keypoints in full.items():
        np.testing.assert_allclose(unit[name], keypoints, atol=5e-3, err_msg=name)
    coco = scenes["half"] / "detections" / "coco"
    (seq,) = [p.name for p in coco.iterdir()]
    assert main(["import", "coco", str(coco / seq / "keypoint_results.json"), "--images",
                 str(coco / seq / "image_list.json"), "--calib", str(scenes["half"]),
                 "--out", str(tmp_path / "coco")]) == 0
    summary = json.loads((tmp_path / "coco" / "import_summary.json").read_text())
    (record,) = summary["sequences"].values()
    assert {c["from"] for c in record["pixel_scale"]["cameras"].values()} == {"image sizes in the files"}
    assert all(c["scale"] == pytest.approx([0.5, 0.5], abs=5e-4) for c in record["pixel_scale"]["cameras"].values())
    assert not record["pixel_scale"]["lidar_check"]["all pairs"]["contradicts"]


def test_images_the_detector_saw_resized_are_brought_back_to_the_calibration_size(tmp_path):
    """The review sheets and the rectified images are drawn from the images the detector saw: a resized copy is
    resized back (the detections' pixels are the calibration's by then); other sizes are left alone."""
    from pedx_graph.detections.pixel_scale import resized_cameras
    from pedx_graph.detections.pixel_units import calibration_sized
    from pedx_graph.detections.rectified_images import _camera_job
    from pedx_graph.utils import encode_image

    half = np.zeros((750, 1000, 3), dtype=np.uint8)
    half[100:200, 300:400] = 255
    assert calibration_sized(half, SIZE, (0.5, 0.5)).shape == (1500, 2000, 3)
    assert calibration_sized(half[:, :999], SIZE, (0.5, 0.5)).shape == (1500, 2000, 3)    # within a pixel
    assert calibration_sized(half[:700], SIZE, (0.5, 0.5)).shape == (700, 1000, 3)        # another image
    assert calibration_sized(half, SIZE, None).shape == (1500, 2000, 3)                   # normalised: any size
    back = calibration_sized(half, SIZE, (0.5, 0.5))
    assert back[300, 700].max() == 255 and back[100, 100].max() == 0
    calib = _pair()
    record = {"cameras": {"camA": {"units": "pixels", "scale": [0.5, 0.5]},
                          "camB": {"units": "pixels", "scale": [1.0, 1.0]}}}
    assert resized_cameras(record, {calib.name: calib}) == {"camA": (SIZE, (0.5, 0.5))}
    source = tmp_path / "camA_0.jpg"
    source.write_bytes(encode_image(half, ".jpg"))
    done = _camera_job((tmp_path / "out", "seq", "camA", None, SIZE, [(0, source)], (SIZE, (0.5, 0.5))))
    assert done["written"] == 1
    import cv2
    (written,) = (tmp_path / "out").rglob("*.jpg")
    assert cv2.imread(str(written)).shape == (1500, 2000, 3)


def test_a_raw_image_size_is_a_calibrated_size_too(tmp_path):
    """Detections on raw images of another size than the rectified ones (KITTI's ``S_0x``): the raw size, and
    that size resized, are read as such; raw pixels beyond the rectified image are inside the raw one."""
    import dataclasses

    from pedx_graph.data.calib import format_cam_to_cam, read_cam_to_cam
    from pedx_graph.data.types import RawCamera

    base = _pair()
    K = np.array([[1800.0, 0, 1200], [0, 1800, 850], [0, 0, 1]])
    raws = [RawCamera(raw_K=K, raw_D=np.zeros(5), rect_R_cam=np.eye(3), P_rect=P, image_size=(2400, 1700))
            for P in (base.left_P_rect, base.right_P_rect)]
    calib = dataclasses.replace(base, left_raw=raws[0], right_raw=raws[1])
    path = tmp_path / "calib_cam_to_cam_camA-camB.txt"
    path.write_text(format_cam_to_cam(calib))
    assert "S_00: 2400.0 1700.0" in path.read_text()
    assert read_cam_to_cam(path, "camA")["left_raw"].image_size == (2400, 1700)
    uv = np.random.default_rng(4).uniform(0, 1, size=(17, 2)) * (2350, 1650)
    calibs = {calib.name: calib}
    out, record = detector_pixels([_detection("camA", uv, (2400, 1700))], calibs, PixelScaleConfig())
    assert record["cameras"]["camA"]["scale"] == [1.0, 1.0] and out[0].image_uv is not None
    out, record = detector_pixels([_detection("camA", uv / 2, (1200, 850))], calibs, PixelScaleConfig())
    assert record["cameras"]["camA"]["scale"] == [0.5, 0.5] and np.allclose(out[0].image_uv, uv)
    with pytest.raises(DataFormatError, match=r"1200x1000, none of its calibrated sizes 2000x1500 \(S_rect_00\), "
                                              r"2400x1700 \(S_00\) resized"):
        detector_pixels([_detection("camA", uv / 2, (1200, 1000))], calibs, PixelScaleConfig())
    # without S_00 the raw image is taken as twice the raw principal point: the same bounds
    bare = [dataclasses.replace(r, image_size=None) for r in raws]
    unsized = {calib.name: dataclasses.replace(calib, left_raw=bare[0], right_raw=bare[1])}
    detector_pixels([_detection("camA", uv, None, source=f"f{i}.json#[0]") for i in range(5)], unsized,
                    PixelScaleConfig())
    with pytest.raises(DataFormatError, match="beyond its image"):
        detector_pixels([_detection("camA", uv, None, source=f"f{i}.json#[0]") for i in range(5)], calibs | {
            calib.name: base}, PixelScaleConfig())
