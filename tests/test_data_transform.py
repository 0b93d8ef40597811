"""transform_dataset: a whole release folder moved by a rigid motion (calibration, clouds, segments, SMPL,
simulator truth); round trips, rigid bodies, byte stability, bad input."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scene_fixtures import tree_digest
from scipy.spatial.transform import Rotation

from pedx_graph.data import read_smpl_labels
from pedx_graph.data.calib import CalibrationLimits, read_calibrations, read_cam_to_range
from pedx_graph.data.npzfile import read_npz
from pedx_graph.data.ply import read_ply_points
from pedx_graph.data.transform import (check_rigid, transform_dataset, transform_ground, transform_points,
                                       transform_smpl)
from pedx_graph.sim import rig_config, simulate
from test_sim_standin import standin_body_model


#: A moved world frame puts the cameras tens of metres from its origin, beyond the calibration sanity limit
#: for a LiDAR frame (20 m): read moved calibrations without that limit.
MOVED_FRAME = CalibrationLimits(max_camera_distance_m=None)


def random_motion(rng: np.random.Generator, shift_m: float = 20.0) -> np.ndarray:
    """A random proper rigid motion (uniform rotation, shift up to ``shift_m`` per axis)."""
    motion = np.eye(4)
    motion[:3, :3] = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
    motion[:3, 3] = rng.uniform(-shift_m, shift_m, 3)
    return motion


@pytest.fixture(scope="module")
def body():
    return standin_body_model()


@pytest.fixture(scope="module", params=["pedx", "default"])
def sim_folder(request, tmp_path_factory, body):
    cfg = rig_config(request.param)
    cfg.scene.n_frames = 2
    cfg.scene.n_pedestrians = 6
    cfg.lidar.azimuth_step_deg = 0.72
    out = tmp_path_factory.mktemp(f"src-{request.param}")
    simulate(out, cfg, seed=3, body_model=body)
    return out


def test_round_trip_restores_the_dataset(sim_folder, body, tmp_path):
    src = sim_folder
    motion = random_motion(np.random.default_rng(0))
    moved, back = tmp_path / "moved", tmp_path / "back"
    counts = transform_dataset(src, moved, motion, body)
    assert counts["calib_range"] == 2 and counts["cloud"] > 2 and counts["smpl"] > 0 and counts["truth_npz"] == 2
    assert counts["meta"] == 1 and counts["copy"] > 0
    transform_dataset(moved, back, np.linalg.inv(motion), body)
    src_files = sorted(str(p.relative_to(src)) for p in src.rglob("*") if p.is_file())
    assert src_files == sorted(str(p.relative_to(back)) for p in back.rglob("*") if p.is_file())
    # calibration
    calib_src, calib_back = read_calibrations(src / "calib"), read_calibrations(back / "calib")
    for name, calib in calib_src.items():
        np.testing.assert_allclose(calib_back[name].world_T_cam, calib.world_T_cam, atol=1e-9)
        left = name.split("-")[0]
        raw_src = read_cam_to_range(src / "calib" / f"calib_cam_to_range_{left}.txt")
        np.testing.assert_allclose(read_cam_to_range(back / "calib" / f"calib_cam_to_range_{left}.txt"), raw_src,
                                   atol=1e-9)
        assert (back / "calib" / f"calib_cam_to_cam_{name}.txt").read_bytes() == \
            (src / "calib" / f"calib_cam_to_cam_{name}.txt").read_bytes()
    # clouds and segments (the masked inf rows stay inf)
    for ply in sorted(src.rglob("*.ply")):
        original = read_ply_points(ply, mask_nonfinite=False)
        restored = read_ply_points(back / ply.relative_to(src), mask_nonfinite=False)
        finite = np.all(np.isfinite(original), axis=1)
        assert np.array_equal(finite, np.all(np.isfinite(restored), axis=1))
        np.testing.assert_allclose(restored[finite], original[finite], atol=1e-9)
        assert np.all(np.isinf(restored[~finite]))
    # SMPL labels
    smpl_src, smpl_back = read_smpl_labels(src), read_smpl_labels(back)
    assert smpl_src.keys() == smpl_back.keys()
    for key, labels in smpl_src.items():
        for lab, lab_back in zip(labels, smpl_back[key]):
            np.testing.assert_allclose(lab_back.trans, lab.trans, atol=1e-9)
            np.testing.assert_allclose(lab_back.betas, lab.betas, atol=0)
            np.testing.assert_allclose(lab_back.pose[3:], lab.pose[3:], atol=0)
            np.testing.assert_allclose(Rotation.from_rotvec(lab_back.pose[:3]).as_matrix(),
                                       Rotation.from_rotvec(lab.pose[:3]).as_matrix(), atol=1e-9)
    # truth arrays and meta
    for npz in sorted((src / "truth").rglob("*.npz")):
        original, restored = read_npz(npz), read_npz(back / npz.relative_to(src))
        assert original.keys() == restored.keys()
        for key, value in original.items():
            np.testing.assert_allclose(restored[key], value, atol=1e-9, err_msg=key)
    meta_src = json.loads((src / "truth" / "meta.json").read_text())
    meta_back = json.loads((back / "truth" / "meta.json").read_text())
    np.testing.assert_allclose(meta_back["output_T_sim"], meta_src["output_T_sim"], atol=1e-9)
    np.testing.assert_allclose(meta_back["ground"]["world_up"], meta_src["ground"]["world_up"], atol=1e-12)
    assert meta_back["ground"]["ground_offset_m"] == pytest.approx(meta_src["ground"]["ground_offset_m"], abs=1e-9)
    # everything else is copied byte for byte
    for rel in ("summary.json", "sim_config.yaml"):
        assert (back / rel).read_bytes() == (src / rel).read_bytes()
    for label in sorted((src / "labels" / "2d").rglob("*.json")):
        assert (back / label.relative_to(src)).read_bytes() == label.read_bytes()


def test_everything_moves_rigidly_together(sim_folder, body, tmp_path):
    src = sim_folder
    motion = random_motion(np.random.default_rng(1))
    moved = tmp_path / "moved"
    transform_dataset(src, moved, motion, body)
    rot, shift = motion[:3, :3], motion[:3, 3]
    smpl_src, smpl_moved = read_smpl_labels(src), read_smpl_labels(moved)
    meta = json.loads((moved / "truth" / "meta.json").read_text())
    seq = meta["sequence"]
    up, offset = np.array(meta["ground"]["world_up"]), meta["ground"]["ground_offset_m"]
    calib_src = read_calibrations(src / "calib")
    calib_moved = read_calibrations(moved / "calib", MOVED_FRAME)
    n_checked = 0
    for key, labels in smpl_src.items():
        for lab, lab_moved in zip(labels, smpl_moved[key]):
            posed = body.forward(lab.pose, lab.betas, lab.trans)
            posed_moved = body.forward(lab_moved.pose, lab_moved.betas, lab_moved.trans)
            np.testing.assert_allclose(posed_moved.vertices, posed.vertices @ rot.T + shift, atol=1e-9)
            np.testing.assert_allclose(posed_moved.joints, posed.joints @ rot.T + shift, atol=1e-9)
            assert abs((posed_moved.vertices @ up - offset).min()) < 1e-6        # still on the (moved) ground
            truth = read_npz(moved / "truth" / seq / f"{seq}_{lab.frame:07d}.npz")
            np.testing.assert_allclose(truth[f"keypoints__{lab.tracking_id}"], posed_moved.keypoints, atol=1e-9)
            # the moved calibration sees the moved body at the same pixels
            for name, calib in calib_src.items():
                for a, b in zip(calib.project(posed.keypoints), calib_moved[name].project(posed_moved.keypoints)):
                    np.testing.assert_allclose(b, a, atol=1e-6)
            n_checked += 1
    assert n_checked > 3


def test_transform_is_byte_stable_and_refuses_bad_input(sim_folder, body, tmp_path):
    motion = random_motion(np.random.default_rng(2))
    transform_dataset(sim_folder, tmp_path / "a", motion, body)
    transform_dataset(sim_folder, tmp_path / "b", motion, body)
    assert tree_digest(tmp_path / "a") == tree_digest(tmp_path / "b")
    with pytest.raises(FileExistsError, match="not empty"):
        transform_dataset(sim_folder, tmp_path / "a", motion, body)
    transform_dataset(sim_folder, tmp_path / "a", np.eye(4), body, overwrite=True)
    assert tree_digest(tmp_path / "a") != tree_digest(tmp_path / "b")
    with pytest.raises(ValueError, match="inside"):
        transform_dataset(sim_folder, sim_folder / "sub", motion, body)
    scaled = motion.copy()
    scaled[:3, :3] *= 1.01
    with pytest.raises(ValueError, match="not a rotation"):
        transform_dataset(sim_folder, tmp_path / "c", scaled, body)
    mirrored = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="not a rotation"):
        check_rigid(mirrored)


def test_calibration_text_keeps_comments_and_tr_key(tmp_path, body):
    """A real-style cam_to_range file (comment, ``Tr``) is rewritten in place; other keys and lines are kept."""
    src = tmp_path / "src"
    calib_dir = src / "calib"
    calib_dir.mkdir(parents=True)
    world_R_cam = Rotation.from_rotvec([0.1, -1.4, 0.3]).as_matrix()
    tr = np.concatenate([world_R_cam, [[-1.98], [-0.235], [-1.188]]], axis=1)
    text = ("# l = R*S*c + T\ncalib_time: 07-Dec-2017 20:24:00\nS: 1.0\n"
            f"Tr: {' '.join(repr(float(v)) for v in tr.ravel())}\n")
    (calib_dir / "calib_cam_to_range_blu79CF.txt").write_text(text)
    motion = random_motion(np.random.default_rng(3))
    transform_dataset(src, tmp_path / "dst", motion, body)
    lines = (tmp_path / "dst" / "calib" / "calib_cam_to_range_blu79CF.txt").read_text().splitlines()
    assert lines[:3] == text.splitlines()[:3]
    moved = read_cam_to_range(tmp_path / "dst" / "calib" / "calib_cam_to_range_blu79CF.txt", MOVED_FRAME)
    world_T_cam = np.eye(4)
    world_T_cam[:3] = tr
    np.testing.assert_allclose(moved, motion @ world_T_cam, atol=1e-12)


def test_point_smpl_and_ground_helpers(body):
    rng = np.random.default_rng(4)
    motion = random_motion(rng)
    points = rng.normal(size=(5, 3))
    points[2] = np.inf
    moved = transform_points(motion, points)
    assert np.all(np.isinf(moved[2]))
    np.testing.assert_allclose(moved[[0, 1, 3, 4]], points[[0, 1, 3, 4]] @ motion[:3, :3].T + motion[:3, 3])
    np.testing.assert_array_equal(transform_points(np.eye(4), points), points)
    betas = rng.normal(size=10)
    pose = rng.normal(scale=0.3, size=(3, 72))
    trans = rng.normal(size=(3, 3))
    pose_m, trans_m = transform_smpl(motion, pose, trans, body.rest_joints(betas)[0])
    np.testing.assert_allclose(body.forward(pose_m, betas, trans_m).vertices,
                               body.forward(pose, betas, trans).vertices @ motion[:3, :3].T + motion[:3, 3],
                               atol=1e-9)
    up, offset = transform_ground(motion, [0.0, 0.0, 1.0], -1.5)
    on_plane = np.array([[3.0, -2.0, -1.5], [10.0, 4.0, -1.5]])
    np.testing.assert_allclose(transform_points(motion, on_plane) @ up, offset, atol=1e-12)
