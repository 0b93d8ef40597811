"""The PedX rig of the simulator: real calibration in a z-down output frame, tilted ground, real-label quirks,
per-keypoint click noise (small scenes, stand-in body model)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scene_fixtures import tree_digest

from pedx_graph.config import ConfigError, load_config
from pedx_graph.data import read_smpl_labels
from pedx_graph.data.calib import read_calibrations
from pedx_graph.data.labels2d import iter_label2d_files, read_label2d
from pedx_graph.keypoints import PEDX_KEYPOINTS
from pedx_graph.sim import SimConfig, load_sim_config, pedx_rig_config, rig_config, simulate
from pedx_graph.sim import labels as sim_labels
from pedx_graph.sim.config import (PEDX_VERTICAL_DISPARITY_SD_PX, click_noise_from_vertical_disparity,
                                   pedx_click_noise_px)
from test_sim_standin import standin_body_model

#: The real rig's numbers (pedx-format notes): focal, principal point, size, P_rect_01[0, 3], T, optical axis.
REAL_PAIRS = {
    "blu79CF-grn43E3": (3332.51, (1857.0, 1334.9), (3645, 2687), -912.26, (-1.980, -0.235, -1.188),
                        (-0.99986, -0.0090, 0.0142)),
    "ylw79D0-red707B": (3266.70, (1845.0, 1333.4), (3678, 2668), -1074.30, (-2.243, 0.661, -1.140),
                        (-0.9579, 0.2864, -0.0217)),
}


def small_pedx(n_frames: int = 3, n_pedestrians: int = 10) -> SimConfig:
    cfg = rig_config("pedx")
    cfg.scene.n_frames = n_frames
    cfg.scene.n_pedestrians = n_pedestrians
    cfg.lidar.azimuth_step_deg = 0.72
    return cfg


@pytest.fixture(scope="module")
def body():
    return standin_body_model()


@pytest.fixture(scope="module")
def pedx_run(tmp_path_factory, body):
    out = tmp_path_factory.mktemp("pedx")
    cfg = small_pedx()
    cfg.labels.polygon_only_prob = 0.3           # frequent enough to be seen in a tiny scene
    cfg.labels.missing_keypoint_prob = 0.5
    summary = simulate(out, cfg, seed=1, body_model=body)
    return out, cfg, summary


# ---------------------------------------------------------------------------------------------- config

def test_pedx_preset_file_and_loader():
    from pedx_graph.motion.clips import project_root

    preset = project_root() / "configs" / "sim_pedx.yaml"
    assert load_config(SimConfig, preset) == pedx_rig_config()
    assert load_sim_config(preset) == pedx_rig_config() == load_sim_config(rig="pedx")
    assert load_sim_config() == SimConfig()


def test_rig_key_in_yaml_starts_from_the_preset(tmp_path):
    yaml_path = tmp_path / "p.yaml"
    yaml_path.write_text("rig: pedx\nscene:\n  n_frames: 3\ncameras:\n  left:\n    focal_px: 3000.0\n")
    cfg = load_sim_config(yaml_path)
    assert cfg.rig == "pedx" and cfg.scene.n_frames == 3 and cfg.cameras.left.focal_px == 3000.0
    assert cfg.cameras.left.optical_axis == pedx_rig_config().cameras.left.optical_axis   # merged, not replaced
    assert cfg.labels.occlusion_flags is False
    assert load_sim_config(yaml_path, rig="default").cameras.frame == "sim"              # the argument wins
    yaml_path.write_text("rig: nope\n")
    with pytest.raises(ConfigError, match="'rig'"):
        load_sim_config(yaml_path)
    cfg = pedx_rig_config()
    cfg.cameras.left.image_down = None
    with pytest.raises(ConfigError, match="cameras.left.optical_axis"):
        cfg.validate()


# ----------------------------------------------------------------------------------------- calibration

def test_pedx_calibration_reproduces_the_real_rig(pedx_run):
    out, _, _ = pedx_run
    calibs = read_calibrations(out / "calib")
    assert set(calibs) == set(REAL_PAIRS)
    for name, (focal, centre, size, p01, position, axis) in REAL_PAIRS.items():
        calib = calibs[name]
        assert calib.focal_px == pytest.approx(focal, abs=1e-9)
        np.testing.assert_allclose(calib.left_P_rect[:2, 2], centre, atol=1e-9)
        assert calib.image_size == size
        assert calib.right_P_rect[0, 3] == pytest.approx(p01, abs=1e-6)
        assert calib.baseline_m == pytest.approx(-p01 / focal, abs=1e-12)
        np.testing.assert_allclose(calib.world_T_cam[:3, 3], position, atol=1e-9)
        np.testing.assert_allclose(calib.world_T_cam[:3, 2], np.array(axis) / np.linalg.norm(axis), atol=1e-9)
        assert calib.world_T_cam[2, 1] > 0.99            # image-down ~ +z: the LiDAR frame's z points down
    left_centres = [calibs[n].world_T_cam[:3, 3] for n in REAL_PAIRS]
    assert np.linalg.norm(left_centres[0] - left_centres[1]) == pytest.approx(0.93, abs=0.02)
    axes = [calibs[n].world_T_cam[:3, 2] for n in REAL_PAIRS]
    assert np.degrees(np.arccos(axes[0] @ axes[1])) == pytest.approx(17.0, abs=1.0)


def test_pedx_bodies_and_ground_in_the_z_down_frame(pedx_run, body):
    out, cfg, _ = pedx_run
    meta = json.loads((out / "truth" / "meta.json").read_text())
    up = np.array(meta["ground"]["world_up"])
    offset = meta["ground"]["ground_offset_m"]
    tilt = np.degrees(np.arccos(up @ [0.0, 0.0, -1.0]))
    assert 0.5 < tilt < 1.5                             # ~1 degree between the frame and the ground
    assert offset == pytest.approx(-0.3, abs=1e-9)      # origin 0.3 m above the ground
    np.testing.assert_allclose(np.asarray(meta["output_T_sim"])[:3, 3], meta["world_p_lidar"])
    smpl = read_smpl_labels(out)
    assert smpl
    seq = meta["sequence"]
    for (_, tid), labels in smpl.items():
        for lab in labels:
            posed = body.forward(lab.pose, lab.betas, lab.trans)
            feet_z = posed.joints[[7, 8, 10, 11], 2]
            assert posed.joints[15, 2] < feet_z.min() - 1.0       # head above the feet = lower z
            height = posed.vertices @ up - offset
            assert abs(height.min()) < 1e-6                        # standing on the tilted ground
            truth = np.load(out / "truth" / seq / f"{seq}_{lab.frame:07d}.npz")
            np.testing.assert_allclose(posed.keypoints, truth[f"keypoints__{tid}"], atol=1e-9)
    truth = np.load(out / "truth" / seq / f"{seq}_{cfg.scene.first_frame:07d}.npz")
    ground = truth["scene_points"][truth["scene_object_id"] == 0].astype(float)
    assert len(ground) > 1000
    residual = ground @ up - offset
    assert np.percentile(np.abs(residual), 95) < 4 * cfg.lidar.range_noise_m
    lidar = np.asarray(meta["world_p_lidar"])
    assert lidar @ up - offset == pytest.approx(cfg.lidar.height_m, abs=1e-9)


# ---------------------------------------------------------------------------------------------- labels

def test_pedx_label_quirks(pedx_run):
    out, cfg, summary = pedx_run
    meta = json.loads((out / "truth" / "meta.json").read_text())
    seq = meta["sequence"]
    n_null = n_files = n_missing = 0
    for path, camera, frame, tid in iter_label2d_files(out, seq):
        raw = json.loads(path.read_text())
        n_files += 1
        record = json.loads((out / "truth" / seq / f"{seq}_{frame:07d}.json").read_text())["people"][tid]
        view_record = record["views"][camera]
        if raw["keypoint"] is None:
            n_null += 1
            assert view_record["quirk"] == "polygon_only" and raw["polygon"]
            continue
        assert all(kp["visible"] is True for kp in raw["keypoint"].values())          # no occlusion flag
        assert all(float(kp[a]).is_integer() for kp in raw["keypoint"].values() for a in "xy")
        expected = view_record["in_image"] - (view_record.get("quirk") == "missing_keypoint")
        assert len(raw["keypoint"]) == expected
        n_missing += view_record.get("quirk") == "missing_keypoint"
    assert n_null == summary["polygon_only_files"] > 0
    assert n_missing == summary["missing_keypoint_files"] > 0
    assert n_files == summary["labels_2d"]
    occluded = sum(r["views"][c]["visible"].count("0")
                   for f in sorted((out / "truth" / seq).glob("*.json"))
                   for r in json.loads(f.read_text())["people"].values()
                   for c in r["views"] if r["views"][c].get("labelled"))
    assert occluded > 0                                   # occluded keypoints were clicked, flagged visible


def test_pedx_right_image_vertical_offset(tmp_path, body):
    """Noise off: blu79CF-grn43E3's right clicks sit exactly 1 px lower than the projection (v_left - v_right
    = -1 px, the real rectification error); the other cameras' clicks sit on it."""
    cfg = small_pedx(n_frames=2, n_pedestrians=8)
    cfg.labels.keypoint_noise_px = (0.0,) * 18
    cfg.labels.occluded_noise_px = 0.0
    cfg.labels.integer_clicks = False
    cfg.labels.polygon_only_prob = 0.0
    out = tmp_path / "exact"
    simulate(out, cfg, seed=1, body_model=body)
    seq = cfg.scene.sequence
    calibs = read_calibrations(out / "calib")
    side = {}
    for name, calib in calibs.items():
        left, right = name.split("-")
        side[left], side[right] = (calib, 0), (calib, 1)
    offsets: dict[str, list] = {}
    for path, camera, frame, tid in iter_label2d_files(out, seq):
        label = read_label2d(path, seq, camera, frame, tid)
        truth = np.load(out / "truth" / seq / f"{seq}_{frame:07d}.npz")
        calib, index = side[camera]
        uv = calib.project(truth[f"keypoints__{tid}"])[index]
        height = calib.image_size[1]
        keep = label.view.labelled & (uv[:, 1] > 2) & (uv[:, 1] < height - 2)      # not clipped
        offsets.setdefault(camera, []).append(label.view.keypoints[keep] - uv[keep])
    assert set(offsets) == {"blu79CF", "grn43E3", "ylw79D0", "red707B"}
    for camera, values in offsets.items():
        values = np.concatenate(values)
        assert len(values) > 20
        np.testing.assert_allclose(values[:, 0], 0.0, atol=1e-6)
        np.testing.assert_allclose(values[:, 1], 1.0 if camera == "grn43E3" else 0.0, atol=1e-6)


def test_per_keypoint_click_noise_reproduces_the_measured_vertical_disparity():
    """Two independent integer clicks of the same point with the pedx profile: the robust SD of their
    difference per keypoint is the note's figure (the profile is that / sqrt(2), rounding removed)."""
    cfg = pedx_rig_config().labels
    rng = np.random.default_rng(0)
    uv_true = np.tile([[1000.3, 800.7]], (18, 1))
    visible = np.ones(18, bool)
    diffs = []
    for _ in range(3000):
        left, flags = sim_labels.keypoint_labels(uv_true, visible, visible, cfg, rng, (3000, 2000))
        right, _ = sim_labels.keypoint_labels(uv_true, visible, visible, cfg, rng, (3000, 2000))
        assert flags.all() and np.all(left == np.round(left))
        diffs.append(left[:, 1] - right[:, 1])
    diffs = np.array(diffs)
    robust_sd = 1.4826 * np.median(np.abs(diffs - np.median(diffs, axis=0)), axis=0)
    sd = diffs.std(axis=0)
    for j, name in enumerate(PEDX_KEYPOINTS):
        assert sd[j] == pytest.approx(PEDX_VERTICAL_DISPARITY_SD_PX[name], rel=0.06), name
        assert robust_sd[j] == pytest.approx(PEDX_VERTICAL_DISPARITY_SD_PX[name], rel=0.2), name
    profile = pedx_click_noise_px()
    assert profile[PEDX_KEYPOINTS.index("lhip")] > 3.5 * profile[PEDX_KEYPOINTS.index("nose")]
    assert click_noise_from_vertical_disparity(3.0, integer_clicks=False) == pytest.approx(3.0 / np.sqrt(2))


def test_occluded_keypoints_use_the_occluded_noise_without_flags():
    cfg = pedx_rig_config().labels
    rng = np.random.default_rng(1)
    visible = np.arange(18) % 2 == 0
    errors = []
    for _ in range(500):
        uv, flags = sim_labels.keypoint_labels(np.full((18, 2), 900.0), visible, np.ones(18, bool), cfg, rng,
                                               (3000, 2000))
        assert flags.all()
        errors.append(uv[~visible] - 900.0)
    assert np.std(np.concatenate(errors)) == pytest.approx(np.hypot(cfg.occluded_noise_px, 12 ** -0.5), rel=0.08)


def test_file_quirks():
    cfg = SimConfig().labels
    uv = np.arange(36, dtype=float).reshape(18, 2)
    flags = np.ones(18, bool)
    rng = np.random.default_rng(0)
    assert sim_labels.file_quirks(uv, flags, cfg, rng)[2] is None           # defaults: no quirk
    cfg.polygon_only_prob = 1.0
    out_uv, out_flags, quirk = sim_labels.file_quirks(uv, flags, cfg, rng)
    assert quirk == "polygon_only" and np.isnan(out_uv).all() and not out_flags.any()
    cfg.polygon_only_prob, cfg.missing_keypoint_prob = 0.0, 1.0
    out_uv, out_flags, quirk = sim_labels.file_quirks(uv, flags, cfg, rng)
    assert quirk == "missing_keypoint" and np.isnan(out_uv[:, 0]).sum() == 1 and out_flags.sum() == 17
    assert np.isfinite(uv).all()                                              # inputs untouched


def test_one_camera_tracks(tmp_path, body):
    cfg = small_pedx(n_frames=3, n_pedestrians=6)
    cfg.labels.one_camera_track_prob = 1.0
    summary = simulate(tmp_path / "mono", cfg, seed=4, body_model=body)
    meta = json.loads((tmp_path / "mono" / "truth" / "meta.json").read_text())
    chosen = {p["tracking_id"]: p["label_camera"] for p in meta["pedestrians"]}
    assert all(chosen.values())
    cameras_of: dict[str, set] = {}
    for _, camera, _, tid in iter_label2d_files(tmp_path / "mono", meta["sequence"]):
        cameras_of.setdefault(tid, set()).add(camera)
    assert cameras_of and summary["one_camera_tracks"] == len(cameras_of) == summary["labelled_tracks"]
    for tid, cams in cameras_of.items():
        assert cams == {chosen[tid]}                      # no stereo at all
    assert summary["labelled_instances_one_image"] == summary["labelled_instances"]
    assert summary["labelled_instances_both_pairs"] == 0
    # a track labelled in a right camera only still gets LiDAR segments (segment_cameras = "any")
    right_only = [tid for tid, cams in cameras_of.items() if chosen[tid] in ("red707B", "grn43E3")]
    assert right_only
    segments = {p.name.split("_")[-1][:-4] for p in (tmp_path / "mono").rglob("labels/3d/segment/*/*.ply")}
    assert set(right_only) <= segments


def test_pedx_instances_seen_by_both_pairs(pedx_run):
    _, cfg, summary = pedx_run
    per_pair = summary["labelled_instances_per_pair"]
    assert set(per_pair) == set(REAL_PAIRS) and min(per_pair.values()) > 0
    assert summary["labelled_instances_both_pairs"] > 0
    dist = summary["labelled_distance_m"]
    assert cfg.labels.min_distance_m <= dist["min"] <= dist["max"] <= cfg.labels.max_distance_m


def test_pedx_same_seed_same_bytes_and_cli(tmp_path, body):
    from pedx_graph.body.io import save_model_npz
    from pedx_graph.cli import main
    from test_sim_standin import standin_model_arrays

    cfg = small_pedx(n_frames=2, n_pedestrians=5)
    simulate(tmp_path / "a", cfg, seed=9, body_model=body)
    simulate(tmp_path / "b", cfg, seed=9, body_model=body)
    simulate(tmp_path / "c", cfg, seed=10, body_model=body)
    digest = tree_digest(tmp_path / "a")
    assert len(digest) > 10 and digest == tree_digest(tmp_path / "b") and digest != tree_digest(tmp_path / "c")
    model = save_model_npz(tmp_path / "standin.npz", standin_model_arrays())
    preset = tmp_path / "small.yaml"
    preset.write_text("lidar:\n  azimuth_step_deg: 0.72\n")
    assert main(["simulate", str(tmp_path / "cli"), "--rig", "pedx", "--seed", "9", "--pedestrians", "5",
                 "--frames", "2", "--config", str(preset), "--body-model", str(model)]) == 0
    from_cli = tree_digest(tmp_path / "cli")
    assert from_cli.pop("sim_config.yaml") != digest.pop("sim_config.yaml")   # it names the body model file
    assert from_cli == digest
    written = load_sim_config(tmp_path / "cli" / "sim_config.yaml")
    assert written.rig == "pedx" and written.cameras.frame == "output"
