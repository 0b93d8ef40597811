"""OpenPose / COCO readers, file-name patterns, confidence -> sigma, and `pedx-graph import` on our own files.

Real sample files (../shared/detections: pose2sim demo output, BSD-3-Clause; mmpose test data, Apache-2.0;
cocoapi results example, Simplified BSD) are read when present and skipped cleanly when absent.
"""
import json
from pathlib import Path

import numpy as np
import pytest

from pedx_graph.data.types import DataFormatError
from pedx_graph.detections.coco import read_coco
from pedx_graph.detections.naming import compile_patterns, parse_name
from pedx_graph.detections.noise import (DetectionNoiseConfig, SigmaCurve, fit_noise_model, fit_sigma_curve,
                                         keypoint_scales)
from pedx_graph.detections.openpose import read_openpose

SHARED = Path(__file__).resolve().parents[2] / "shared" / "detections"


def write(path: Path, obj) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj))
    return path


def openpose_person(count: int, pid: int = -1, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    flat = []
    for k in range(count):
        if k == 3:
            flat += [0, 0, 0]                                 # not detected
        else:
            flat += [float(rng.uniform(100, 900)), float(rng.uniform(100, 900)), float(rng.uniform(0.3, 1))]
    return {"person_id": [pid], "pose_keypoints_2d": flat, "face_keypoints_2d": []}


def test_names():
    assert parse_name("20171207T2024_blu79CF_0000123.jpg") == parse_name("20171207T2024_blu79CF_0000123_keypoints.json")
    image = parse_name("20171207T2024_blu79CF_0000123_keypoints.json")
    assert (image.sequence, image.camera, image.frame) == ("20171207T2024", "blu79CF", 123)
    image = parse_name("cam01.0007.json", camera_names={"cam01": "ylw79D0"})
    assert (image.sequence, image.camera, image.frame) == (None, "ylw79D0", 7)
    image = parse_name("shot-A_frame12.png", compile_patterns(r"shot-(?P<camera>\w)_frame(?P<frame>\d+)"))
    assert (image.camera, image.frame) == ("A", 12)
    with pytest.raises(DataFormatError, match="weird.json.*file name"):
        parse_name("weird.json")
    with pytest.raises(ValueError, match="frame"):
        compile_patterns(r"(?P<camera>\w+)")


@pytest.mark.parametrize("count, named, expected", [(25, None, "body25"), (25, "body25b", "body25b"),
                                                    (18, None, "coco18")])
def test_openpose_own_files(tmp_path, count, named, expected):
    path = write(tmp_path / "seqA_camX_0000004_keypoints.json",
                 {"version": 1.3, "people": [openpose_person(count), openpose_person(count, pid=5, seed=1)]})
    dets = read_openpose(tmp_path, keypoint_set=named)
    assert len(dets) == 2 and all(d.keypoint_set == expected for d in dets)
    det = dets[0]
    assert (det.sequence, det.camera, det.frame, det.track_id) == ("seqA", "camX", 4, None)
    assert dets[1].track_id == "5"
    assert det.image == "seqA_camX_0000004"              # the image the detector saw, for the review sheets
    assert np.isnan(det.image_uv[3]).all() and det.confidence[3] == 0
    flat = np.array(openpose_person(count)["pose_keypoints_2d"]).reshape(-1, 3)
    np.testing.assert_allclose(det.image_uv[0], flat[0, :2])
    assert det.score == pytest.approx(flat[flat[:, 2] > 0, 2].mean())
    assert str(path) in det.source


@pytest.mark.parametrize("content, field", [
    ({"version": 1.3}, "people"),
    ({"people": [{"pose_keypoints_2d": [1, 2]}]}, "people[0].pose_keypoints_2d"),
    ({"people": [{"pose_keypoints_2d": [1.0] * 60}]}, "people[0].pose_keypoints_2d"),
    ({"people": [{"pose_keypoints_2d": [1, 2, "a"] * 25}]}, "people[0].pose_keypoints_2d"),
    ({"people": [{"pose_keypoints_2d": [1, 2, 3.0] * 25}]}, "people[0].pose_keypoints_2d"),
    ({"people": [{"person_id": ["x"], "pose_keypoints_2d": [1, 2, 0.5] * 25}]}, "people[0].person_id"),
])
def test_openpose_malformed(tmp_path, content, field):
    path = write(tmp_path / "cam1.0001.json", content)
    with pytest.raises(DataFormatError) as err:
        read_openpose(path)
    message = str(err.value)
    assert "\n" not in message and str(path) in message and f"field '{field}'" in message


def test_openpose_wrong_named_set(tmp_path):
    path = write(tmp_path / "cam1.0001.json", {"people": [openpose_person(18)]})
    with pytest.raises(DataFormatError, match="25 for body25b"):
        read_openpose(path, keypoint_set="body25b")


def coco_doc():
    kps = []
    for k in range(17):
        kps += [100 + k, 200 + k, (0, 1, 2)[k % 3]]
    return {"images": [{"id": 7, "file_name": "seqA_camX_0000009.jpg"}],
            "categories": [{"id": 1, "name": "person"}],
            "annotations": [{"id": 1, "image_id": 7, "category_id": 1, "bbox": [1, 2, 30, 40], "keypoints": kps,
                             "track_id": 3}]}


def test_coco_annotations_and_results(tmp_path):
    ann = write(tmp_path / "ann.json", coco_doc())
    (det,) = read_coco(ann)
    assert (det.sequence, det.camera, det.frame, det.track_id, det.keypoint_set) == ("seqA", "camX", 9, "3", "coco17")
    assert det.image == "seqA_camX_0000009"
    v = np.array([(0, 1, 2)[k % 3] for k in range(17)])
    np.testing.assert_array_equal(det.confidence, (v > 0).astype(float))
    np.testing.assert_array_equal(det.occluded, v == 1)
    assert np.isnan(det.image_uv[0]).all() and det.image_uv[2, 0] == 102
    np.testing.assert_array_equal(det.bbox, [1, 2, 30, 40])
    scores = np.linspace(0, 1, 17)
    res = write(tmp_path / "res.json", [{"image_id": 7, "category_id": 1, "score": 0.8,
                                         "keypoints": [v for k in range(17) for v in (10.0 * k, 5.0, scores[k])]}])
    (det,) = read_coco(res, images=ann)
    assert det.frame == 9 and det.score == 0.8 and det.occluded is None and det.image == "seqA_camX_0000009"
    np.testing.assert_allclose(det.confidence, scores)
    assert np.isnan(det.image_uv[0]).all()
    with pytest.raises(DataFormatError, match="image list"):
        read_coco(res)
    (det,) = read_coco(res, camera="camY")
    assert (det.camera, det.frame, det.image) == ("camY", 7, None)        # no image list: no image name


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d["annotations"][0].update(keypoints=[1, 2, 2] * 16), "annotations[0].keypoints"),
    (lambda d: d["annotations"][0].update(image_id=99), "annotations[0].image_id"),
    (lambda d: d["annotations"][0].update(bbox=[1, 2, -3, 4]), "annotations[0].bbox"),
    (lambda d: d["annotations"][0]["keypoints"].__setitem__(2, 5), "annotations[0].keypoints"),
    (lambda d: d.pop("annotations"), "annotations"),
    (lambda d: d["images"][0].pop("file_name"), "images[0]"),
])
def test_coco_malformed(tmp_path, mutate, field):
    doc = coco_doc()
    mutate(doc)
    path = write(tmp_path / "ann.json", doc)
    with pytest.raises(DataFormatError) as err:
        read_coco(path)
    assert "\n" not in str(err.value) and str(path) in str(err.value) and f"field '{field}'" in str(err.value)


def test_not_json(tmp_path):
    path = tmp_path / "cam1.0001.json"
    path.write_text("{oops")
    with pytest.raises(DataFormatError, match="not JSON"):
        read_openpose(path)
    with pytest.raises(DataFormatError, match="not JSON"):
        read_coco(path)


def test_confidence_noise_and_curve_fit():
    config = DetectionNoiseConfig(min_confidence=0.25, default=SigmaCurve((0.3, 0.9), (10.0, 2.0)), floor_px=0.0,
                                  keypoint_scale={})
    sigma = config.sigma("coco17", np.array([0.1, 0.3, 0.6, 0.95]))
    assert np.isnan(sigma[0]) and sigma[1] == 10.0 and sigma[2] == pytest.approx(6.0) and sigma[3] == 2.0
    # the noise scales with the person's measured height; the floor adds in quadrature; per-keypoint factors
    np.testing.assert_allclose(config.sigma("coco17", np.array([0.3, 0.9]), height_px=400.0), [20.0, 4.0])
    config.floor_px = 3.0
    np.testing.assert_allclose(config.sigma("coco17", np.array([0.3]), height_px=50.0), [np.hypot(3.0, 2.5)])
    config.keypoint_scale = {"coco17": (2.0, 0.5)}
    np.testing.assert_allclose(config.sigma("coco17", np.array([0.9, 0.9]), height_px=800.0),
                               [2.0 * np.hypot(3.0, 8.0), 0.5 * np.hypot(3.0, 8.0)])
    config.floor_px = 0.0
    config.keypoint_scale = {}
    sigma = config.sigma("coco17", np.ones(2), occluded=np.array([False, True]), annotation=True)
    np.testing.assert_allclose(sigma, [3.0, 7.5])
    # an annotation's keypoints get the set's per-keypoint factors too (a surface hip vs an eye)
    config.keypoint_scale = {"coco17": (2.0, 0.5)}
    np.testing.assert_allclose(config.sigma("coco17", np.ones(2), annotation=True), [6.0, 1.5])
    with pytest.raises(ValueError):
        SigmaCurve((0.5, 0.3), (1.0, 2.0))
    # Fit: residuals drawn with a known sigma per confidence come back.
    rng = np.random.default_rng(0)
    conf = rng.uniform(0.2, 1.0, 20000)
    true_sigma = 2.0 + 10.0 * (1 - conf)
    residual = rng.normal(size=(len(conf), 2)) * true_sigma[:, None]
    curve, rows = fit_sigma_curve(conf, residual, (0.3, 0.5, 0.7, 0.9))
    np.testing.assert_allclose(curve.sigma_px, [2.0 + 10.0 * (1 - k) for k in (0.3, 0.5, 0.7, 0.9)], rtol=0.12)
    assert all(r["count"] > 1000 for r in rows)
    # Size-scaled fit: a known floor and reference curve come back from people of many sizes.
    height = rng.uniform(40.0, 800.0, len(conf))
    true_sigma = np.hypot(2.0, (1.0 + 8.0 * (1 - conf)) * height / 200.0)
    residual = rng.normal(size=(len(conf), 2)) * true_sigma[:, None]
    floor, curve, rows = fit_noise_model(conf, residual, height, (0.3, 0.5, 0.7, 0.9), 200.0)
    assert floor == pytest.approx(2.0, abs=0.5)
    np.testing.assert_allclose(curve.sigma_px, [1.0 + 8.0 * (1 - k) for k in (0.3, 0.5, 0.7, 0.9)], rtol=0.12)
    index = rng.integers(0, 3, len(conf))
    scales = keypoint_scales(index, residual * np.array([1.0, 2.0, 1.0])[index][:, None], height, 3, 200.0)
    np.testing.assert_allclose(scales, [1.0, 2.0, 1.0], rtol=0.1)


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/detections is absent")
def test_real_openpose_body25b_samples():
    dets = read_openpose(SHARED / "openpose_body25b" / "cam01.0000.json", keypoint_set="body25b")
    assert len(dets) == 2 and all(d.keypoint_set == "body25b" and d.camera == "cam01" and d.frame == 0 for d in dets)
    assert all(d.track_id is None for d in dets)
    assert all(0 < d.score <= 1 and d.present.sum() >= 10 for d in dets)
    # Portrait 1088 x 1920 images: every present pixel inside.
    for det in dets:
        uv = det.image_uv[det.present]
        assert np.all((uv >= 0) & (uv <= [1088, 1920]))
    (assoc,) = read_openpose(SHARED / "openpose_body25b" / "cam01.0000.associated.json", keypoint_set="body25b",
                             name_pattern=r"(?P<camera>cam\d+)\.(?P<frame>\d+)\.associated")
    assert assoc.camera == "cam01"
    with pytest.raises(DataFormatError, match="25 for body25b|keypoints"):
        read_openpose(SHARED / "openpose_body25b" / "cam03.0000.json", keypoint_set="coco18")


@pytest.mark.skipif(not SHARED.is_dir(), reason="../shared/detections is absent")
def test_real_coco_samples():
    ann = SHARED / "coco" / "person_keypoints_annotations.json"
    dets = read_coco(ann, name_pattern=r"(?P<camera>)(?P<frame>\d+)")
    raw = json.loads(ann.read_text())
    expected = sum(1 for a in raw["annotations"] if any(a["keypoints"][2::3]))
    assert len(dets) == expected and all(d.keypoint_set == "coco17" and d.bbox is not None for d in dets)
    res = read_coco(SHARED / "coco" / "person_keypoints_results_format.json", camera="cam")
    assert len(res) > 100 and all(np.all((d.confidence >= 0) & (d.confidence <= 1)) for d in res)


def test_shipped_noise_defaults_are_the_calibration_result():
    result = json.loads((Path(__file__).resolve().parents[1] / "benchmarks" / "results"
                         / "bench_detection_noise.json").read_text())
    config = DetectionNoiseConfig()
    assert list(config.default.confidence_knots) == result["knots"]
    np.testing.assert_allclose(config.default.sigma_px, result["pooled"]["sigma_px"], atol=1e-3)
    assert config.min_confidence == result["pooled"]["min_confidence"]
    assert config.floor_px == result["pooled"]["floor_px"]
    assert config.reference_height_px == result["reference_height_px"]
    assert set(config.keypoint_scale) == set(result["sets"])
    for name, entry in result["sets"].items():
        np.testing.assert_allclose(config.keypoint_scale[name], entry["keypoint_scale"], atol=1e-3)
    assert np.all(np.diff(config.default.sigma_px) <= 0)        # less confident, noisier


def test_noise_config_from_yaml(tmp_path):
    from pedx_graph.config import load_config
    from pedx_graph.detections.importer import ImportConfig

    path = tmp_path / "import.yaml"
    path.write_text("noise:\n  min_confidence: 0.4\n  floor_px: 0.0\n  default:\n    confidence_knots: [0.2, 0.8]\n"
                    "    sigma_px: [30.0, 4.0]\n  per_set:\n    coco17:\n      confidence_knots: [0.5]\n"
                    "      sigma_px: [2.5]\n")
    config = load_config(ImportConfig, path)
    np.testing.assert_allclose(config.noise.sigma("body25", np.array([0.5, 0.3])), [17.0, np.nan])
    np.testing.assert_allclose(config.noise.sigma("coco17", np.array([0.9])), [2.5])


def test_label_files_carry_keypoint_set_confidence_and_sigma(tmp_path):
    from pedx_graph.data.labels2d import Label2D, read_label2d, write_label2d
    from pedx_graph.data.types import View2D

    uv = np.full((17, 2), np.nan)
    uv[[0, 5, 11]] = [[10.0, 20.0], [30.0, 40.0], [50.0, 60.0]]
    sigma = np.where(np.isfinite(uv[:, 0]), 4.5, np.nan)
    conf = np.where(np.isfinite(uv[:, 0]), 0.7, np.nan)
    view = View2D(keypoints=uv, visible=np.isfinite(uv[:, 0]), keypoint_set="coco17", sigma_px=sigma, confidence=conf)
    label = Label2D(sequence="seqA", camera="camX", frame=3, tracking_id="det000001", category="pedestrian", view=view)
    path = write_label2d(tmp_path, label)
    doc = json.loads(path.read_text())
    assert doc["keypoint_set"] == "coco17" and doc["keypoint"]["left_hip"] == {"x": 50.0, "y": 60.0, "visible": True,
                                                                             "confidence": 0.7, "sigma_px": 4.5}
    back = read_label2d(path, "seqA", "camX", 3, "det000001").view
    assert back.keypoint_set == "coco17"
    np.testing.assert_array_equal(back.keypoints, uv)
    np.testing.assert_array_equal(back.sigma_px, sigma)
    np.testing.assert_array_equal(back.confidence, conf)
    for bad, field in ((dict(doc, keypoint_set="halpe"), "keypoint_set"),
                       (dict(doc, keypoint={"nose": {"x": 1, "y": 2, "sigma_px": -1}}), "keypoint.nose.sigma_px")):
        path.write_text(json.dumps(bad))
        with pytest.raises(DataFormatError, match=f"field '{field}'"):
            read_label2d(path, "seqA", "camX", 3, "det000001")
    # A PedX label file is unchanged: no keypoint_set field, no sigma.
    pedx = Label2D(sequence="seqA", camera="camX", frame=4, tracking_id="t", category="pedestrian",
                   view=View2D(keypoints=np.zeros((18, 2)), visible=np.ones(18, bool)))
    assert "keypoint_set" not in json.loads(write_label2d(tmp_path, pedx).read_text())
