"""The simulator's detector files: they parse with the project's readers, carry no ids, include bystanders and
false detections, sit on distorted raw images whose undistortion lands on the rectified projections, and are
reproducible from the seed."""
from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pytest

from pedx_graph.body import BodyModel
from pedx_graph.data.calib import read_calibrations, read_kitti_text
from pedx_graph.data.reader import read_smpl_labels
from pedx_graph.detections.coco import read_coco
from pedx_graph.detections.evaluate import detection_truth, read_detection_truth
from pedx_graph.detections.openpose import read_openpose
from pedx_graph.detections.undistort import find_camera, rectified
from pedx_graph.keypoints import load_keypoint_set, lower_body_mask, mirror_index
from pedx_graph.sim.config import DETECTOR_FORMATS, SimConfig
from pedx_graph.sim.detections import coco_paths
from scene_fixtures import small_scene, tree_digest

FORMATS = ("openpose_body25", "openpose_body25b", "coco")


def _config() -> SimConfig:
    cfg = SimConfig()
    cfg.detections.formats = FORMATS
    cfg.detections.clutter_per_image = 1.0
    cfg.labels.unlabelled_prob = 0.4          # bystanders: detected, never labelled
    return cfg


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return small_scene(tmp_path_factory.mktemp("simdet") / "scene", pedestrians=6, frames=4, seed=5,
                       config=_config())


def _read(root, fmt, seq):
    if fmt == "coco":
        images, results = coco_paths(root, seq)
        return read_coco(results, images=images)
    return read_openpose(root / "detections" / fmt / seq, keypoint_set=fmt.split("_")[1])


def test_files_parse_without_ids_and_match_their_truth(scene):
    seq = json.loads((scene / "truth" / "meta.json").read_text())["sequence"]
    sizes = {"openpose_body25": 25, "openpose_body25b": 25, "coco": 17}
    for fmt in FORMATS:
        dets = _read(scene, fmt, seq)
        records = read_detection_truth(scene, seq, fmt)
        assert len(dets) == len(records) > 0
        assert {d.keypoint_set for d in dets} == {DETECTOR_FORMATS[fmt]}
        assert all(d.image_uv.shape == (sizes[fmt], 2) and d.track_id is None for d in dets)
        kinds = Counter(detection_truth(d, records)["kind"] for d in dets)
        assert kinds["person"] > 0 and kinds["clutter"] > 0
        people = [r for r in records if r["kind"] == "person"]
        assert any(r["labelled"] for r in people) and any(not r["labelled"] for r in people)
        # detections of one image come in the order of their truth records
        for det in dets:
            record = detection_truth(det, records)
            assert (record["camera"], record["frame"]) == (det.camera, det.frame)


def test_calibration_has_a_raw_model_per_camera(scene):
    calibs = read_calibrations(scene / "calib")
    coefficients = []
    for name, calib in calibs.items():
        assert calib.left_raw is not None and calib.right_raw is not None
        entries = read_kitti_text(scene / "calib" / f"calib_cam_to_cam_{name}.txt")
        assert {"K_00", "D_00", "K_01", "D_01"} <= set(entries)
        coefficients += [tuple(calib.left_raw.raw_D), tuple(calib.right_raw.raw_D)]
    assert len(set(coefficients)) == 4                    # distortion varies per camera
    assert all(c[0] < 0 for c in coefficients)


def _labelled_detections(root):
    """``(detection, its truth record, pair calibration, side, (K, 2) rectified true projection)`` of every
    OpenPose BODY_25 detection of a labelled person at a labelled frame, and the pairs' calibrations."""
    seq = json.loads((root / "truth" / "meta.json").read_text())["sequence"]
    calibs = read_calibrations(root / "calib")
    truth = read_smpl_labels(root)
    model = BodyModel.load().for_keypoint_set("body25")
    records = read_detection_truth(root, seq, "openpose_body25")
    out = []
    for det in _read(root, "openpose_body25", seq):
        record = detection_truth(det, records)
        labels = {lab.frame: lab for lab in truth.get((seq, record.get("tracking_id")), [])}
        if record["kind"] != "person" or det.frame not in labels:
            continue
        lab = labels[det.frame]
        calib, side = find_camera(calibs, det.camera)
        expected = calib.project(model.keypoints(lab.pose, lab.betas, lab.trans))[0 if side == "left" else 1]
        out.append((det, record, calib, side, expected))
    return out, calibs


def test_undistorted_keypoints_land_on_the_rectified_projection(scene):
    """Raw pixels differ from the rectified projection of the format's own body points (distortion); once
    undistorted and rectified they agree to the detector noise."""
    found, calibs = _labelled_detections(scene)
    raw_err, rect_err = [], []
    for det, _, _, _, expected in found:
        ok = det.confidence > 0.5
        raw_err.append(np.linalg.norm(det.image_uv[ok] - expected[ok], axis=1))
        rect_err.append(np.linalg.norm(rectified(det, calibs)[ok] - expected[ok], axis=1))
    raw_err, rect_err = np.concatenate(raw_err), np.concatenate(rect_err)
    assert len(rect_err) > 50
    assert np.median(rect_err) < 7.0                       # measured 4.7 px (seed 5)
    assert np.median(raw_err) > 3 * np.median(rect_err)     # measured 28 px: the distortion is exercised


def test_swap_pairs_follow_the_names():
    assert mirror_index(("Nose", "LEye", "REye", "Neck")) == ((1, 2),)
    assert mirror_index(("nose", "right_eye", "left_eye")) == ((2, 1),)
    assert mirror_index(("lsho", "rsho", "neck")) == ((0, 1),)


def test_same_seed_same_bytes_and_off_by_default(tmp_path, scene):
    again = small_scene(tmp_path / "again", pedestrians=6, frames=4, seed=5, config=_config(), workers=2)
    first = {k: v for k, v in tree_digest(scene).items() if k.startswith(("detections", "truth/detections", "calib"))}
    second = {k: v for k, v in tree_digest(again).items() if k.startswith(("detections", "truth/detections", "calib"))}
    assert first == second and any(k.startswith("detections/coco") for k in first)
    plain = small_scene(tmp_path / "plain", pedestrians=2, frames=2, seed=5)
    assert not (plain / "detections").exists()
    assert all(c.left_raw is None for c in read_calibrations(plain / "calib").values())


def _row_errors(root) -> tuple[np.ndarray, np.ndarray]:
    """Rectified row errors (detection - true projection) of every keypoint a labelled person's detections
    hold in both images of a pair at one frame (confidence > 0.5): (left, right)."""
    found, calibs = _labelled_detections(root)
    errors = {}
    for det, record, calib, side, expected in found:
        err = np.where(det.confidence > 0.5, rectified(det, calibs)[:, 1] - expected[:, 1], np.nan)
        errors[(calib.name, det.frame, record["tracking_id"], side)] = err
    left, right = [], []
    for (pair, frame, tid, side), err in errors.items():
        if side == "left" and (pair, frame, tid, "right") in errors:
            both = np.isfinite(err) & np.isfinite(errors[(pair, frame, tid, "right")])
            left.append(err[both])
            right.append(errors[(pair, frame, tid, "right")][both])
    return np.concatenate(left), np.concatenate(right)


def test_a_detector_error_shared_by_the_cameras_cancels_in_the_stereo_rows(tmp_path, scene):
    """``stereo_shared_noise`` 1: a keypoint's noise is the same offset in both images, so its row errors
    agree between left and right (what the import's stereo-row noise check cannot see); by default the two
    images' errors are independent."""
    cfg = _config()
    cfg.detections.formats = ("openpose_body25",)
    cfg.detections.stereo_shared_noise = 1.0
    cfg.detections.keypoint_noise.outlier_prob = 0.0
    cfg.detections.keypoint_noise.swap_prob = 0.0
    shared = small_scene(tmp_path / "shared", pedestrians=6, frames=8, seed=5, config=cfg)
    for root, correlated in ((shared, True), (scene, False)):
        left, right = _row_errors(root)
        assert len(left) > 60, (root, len(left))
        r = np.corrcoef(left, right)[0, 1]
        assert (r > 0.8) if correlated else (abs(r) < 0.3), (root, r)


def _people_by_image(root, fmt, seq) -> dict[tuple, list[tuple[str, np.ndarray]]]:
    """(camera, frame, tracking id) -> [(truth kind, (K, 2) raw pixels)] of the person and part records."""
    records = read_detection_truth(root, seq, fmt)
    out: dict[tuple, list] = {}
    for det in _read(root, fmt, seq):
        record = detection_truth(det, records)
        if record["kind"] in ("person", "part"):
            out.setdefault((det.camera, det.frame, record["tracking_id"]), []).append((record["kind"], det.image_uv))
    return out


def test_a_split_person_is_its_upper_body_and_its_legs_in_the_openpose_files_only(tmp_path, scene):
    """``split_prob`` 1: every OpenPose person becomes two people, the upper body and the hips and legs, whose
    keypoints together are exactly the whole detection of the same seed without splits; COCO files (top-down
    detectors) are unchanged."""
    cfg = _config()
    cfg.detections.split_prob = 1.0
    split = small_scene(tmp_path / "split", pedestrians=6, frames=4, seed=5, config=cfg)
    seq = json.loads((scene / "truth" / "meta.json").read_text())["sequence"]
    for fmt in ("openpose_body25", "openpose_body25b"):
        lower = lower_body_mask(DETECTOR_FORMATS[fmt])
        whole, parts = _people_by_image(scene, fmt, seq), _people_by_image(split, fmt, seq)
        assert set(whole) == set(parts) and len(whole) > 10
        for key, [(kind, uv)] in whole.items():
            assert kind == "person"
            assert {k for k, _ in parts[key]} == {"part"} and 1 <= len(parts[key]) <= 2
            joined = np.full_like(uv, np.nan)
            for _, part_uv in parts[key]:
                present = np.all(np.isfinite(part_uv), axis=1)
                assert present.sum() >= 2 and (np.all(lower[present]) or not np.any(lower[present]))
                assert not np.any(np.isfinite(joined[present]))       # the parts share no keypoint
                joined[present] = part_uv[present]
            present = np.all(np.isfinite(uv), axis=1)
            missing = present & ~np.all(np.isfinite(joined), axis=1)  # only a part with < 2 keypoints is left out
            assert missing.sum() <= 1
            np.testing.assert_array_equal(joined[present & ~missing], uv[present & ~missing])
    digest = {k: v for k, v in tree_digest(scene).items() if k.startswith("detections/coco")}
    assert digest == {k: v for k, v in tree_digest(split).items() if k.startswith("detections/coco")}


def test_a_flipped_person_is_the_same_detection_with_left_and_right_swapped_in_every_camera(tmp_path, scene):
    """``flip_prob`` 1: every person's detection in every format and camera is the one of the same seed with
    each left/right pair swapped (keypoints and confidences): one draw per person and frame, its own."""
    cfg = _config()
    cfg.detections.flip_prob = 1.0
    flipped = small_scene(tmp_path / "flipped", pedestrians=6, frames=4, seed=5, config=cfg)
    seq = json.loads((scene / "truth" / "meta.json").read_text())["sequence"]
    for fmt in FORMATS:
        names = load_keypoint_set(DETECTOR_FORMATS[fmt]).keypoints
        order = np.arange(len(names))
        for a, b in mirror_index(names):
            order[a], order[b] = b, a
        whole, mirrored = _people_by_image(scene, fmt, seq), _people_by_image(flipped, fmt, seq)
        assert set(whole) == set(mirrored) and len(whole) > 10
        for key, [(kind, uv)] in whole.items():
            [(kind_flipped, uv_flipped)] = mirrored[key]
            assert kind == kind_flipped == "person"
            np.testing.assert_array_equal(uv_flipped, uv[order])


def test_an_exchanged_keypoint_keeps_its_confidence_when_asked(tmp_path, scene):
    """``swap_keeps_confidence``: the same draws, the same keypoint positions; a keypoint's confidence is only
    ever raised, only on left/right pairs — an exchanged keypoint scored by its distance from the mirror point
    it found, not from its own — and the exchanges the default model all but dropped come back confident."""
    cfg = _config()
    cfg.detections.swap_keeps_confidence = True
    confident = small_scene(tmp_path / "confident", pedestrians=6, frames=4, seed=5, config=cfg)
    seq = json.loads((scene / "truth" / "meta.json").read_text())["sequence"]
    raised = 0
    for fmt in FORMATS:
        paired = np.zeros(len(load_keypoint_set(DETECTOR_FORMATS[fmt]).keypoints), dtype=bool)
        for a, b in mirror_index(load_keypoint_set(DETECTOR_FORMATS[fmt]).keypoints):
            paired[[a, b]] = True
        plain, sure = _read(scene, fmt, seq), _read(confident, fmt, seq)
        assert len(plain) == len(sure) > 20
        for old, new in zip(plain, sure):
            assert (old.camera, old.frame) == (new.camera, new.frame)
            np.testing.assert_array_equal(old.image_uv, new.image_uv)
            assert np.all(new.confidence >= old.confidence - 1e-6)
            np.testing.assert_allclose(new.confidence[~paired], old.confidence[~paired], atol=1e-6)
            raised += int(np.sum((old.confidence < 0.1) & (new.confidence > 0.3)))
    assert raised >= 5


def test_a_duplicated_person_is_the_same_detection_again_and_the_association_drops_the_copy(tmp_path, scene):
    """``duplicate_prob`` 1: every person is reported twice in each image — the detection of the same seed
    without duplicates, unchanged, and a copy of its own noise draw (truth ``"duplicate": true``); the other
    draws are unchanged.  The association's duplicate test drops the copy or the original in nearly every
    image."""
    from pedx_graph.detections.association import AssociationConfig, _usable, drop_duplicates

    cfg = _config()
    cfg.detections.duplicate_prob = 1.0
    twice = small_scene(tmp_path / "twice", pedestrians=6, frames=4, seed=5, config=cfg)
    seq = json.loads((scene / "truth" / "meta.json").read_text())["sequence"]
    calibs = read_calibrations(twice / "calib")
    config = AssociationConfig()
    pairs = both_kept = 0
    for fmt in FORMATS:
        base_records, records = read_detection_truth(scene, seq, fmt), read_detection_truth(twice, seq, fmt)
        base = {}
        for det in _read(scene, fmt, seq):
            record = detection_truth(det, base_records)
            if record["kind"] == "person":
                base[(det.camera, det.frame, record["tracking_id"])] = det
        per_person: dict[tuple, list] = {}
        for det in _read(twice, fmt, seq):
            record = detection_truth(det, records)
            if record["kind"] == "person":
                key = (det.camera, det.frame, record["tracking_id"])
                per_person.setdefault(key, []).append((record.get("duplicate", False), det))
        assert set(per_person) == set(base) and len(base) > 10
        for key, found in per_person.items():
            assert sorted(flag for flag, _ in found) == [False, True]
            original = next(det for flag, det in found if not flag)
            np.testing.assert_array_equal(original.image_uv, base[key].image_uv)
            calib = find_camera(calibs, key[0])[0]
            items = [(det, _usable(rectified(det, calib), det.confidence, config.min_confidence)) for _, det in found]
            if min(np.all(np.isfinite(uv), axis=1).sum() for _, uv in items) < config.min_shared_keypoints:
                continue
            pairs += 1
            both_kept += len(drop_duplicates(items, config)) == 2
    assert pairs > 50 and both_kept <= 0.03 * pairs, (pairs, both_kept)


def test_the_detectors_own_definitions_lie_a_set_distance_off_the_fits():
    """``detections.definition_shift_m``: every keypoint of a set is moved by about that distance, the same
    move for a seed, turning with the body (a linear map of its posed vertices), and 0 keeps the fit's map."""
    from pedx_graph.sim.config import DetectorOutputConfig
    from pedx_graph.sim.detections import shifted_definitions

    model = BodyModel.load().for_keypoint_set("coco17")
    shifted = shifted_definitions(model, 0.03, (5, 12, 2))
    again = shifted_definitions(model, 0.03, (5, 12, 2))
    other = shifted_definitions(model, 0.03, (6, 12, 2))
    assert np.array_equal(shifted.vertex_coeffs, again.vertex_coeffs)
    assert not np.array_equal(shifted.vertex_coeffs, other.vertex_coeffs)
    pose = np.random.default_rng(0).normal(scale=0.3, size=72)
    body = model.forward(pose, np.zeros(model.num_betas), np.array([3.0, -1.0, 0.5]))
    ours = model.keypoint_map.apply(body.vertices[model.keypoint_map.vertex_ids], body.joints)
    theirs = shifted.apply(body.vertices[shifted.vertex_ids], body.joints)
    off = np.linalg.norm(theirs - ours, axis=1)
    assert np.all(off > 0.015) and np.all(off < 0.05) and 0.025 < np.median(off) < 0.04
    # still a map of the skin: the same moves at the rest pose measure the shift the ring was drawn at
    rest = model.forward(np.zeros(72), np.zeros(model.num_betas), np.zeros(3))
    ours = model.keypoint_map.apply(rest.vertices[model.keypoint_map.vertex_ids], rest.joints)
    rest_off = np.linalg.norm(shifted.apply(rest.vertices[shifted.vertex_ids], rest.joints) - ours, axis=1)
    assert np.all(np.abs(rest_off - 0.03) <= 0.25 * 0.03 + 1e-9)
    from pedx_graph.config import ConfigError

    with pytest.raises(ConfigError, match="detections.definition_shift_m"):
        SimConfig(detections=DetectorOutputConfig(definition_shift_m=0.5)).validate()
    with pytest.raises(ConfigError, match="detections.raw_margin_px"):
        SimConfig(detections=DetectorOutputConfig(raw_margin_px=(-1.0, 0.0))).validate()
