"""End-to-end simulator tests on small scenes (stand-in body model, procedural gait, a few frames)."""
from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from pedx_graph.config import load_config
from pedx_graph.data import read_dataset, read_smpl_labels
from pedx_graph.data.calib import read_calibrations
from pedx_graph.data.labels2d import iter_label2d_files, read_label2d
from pedx_graph.data.ply import read_ply_points
from pedx_graph.sim import SimConfig, simulate
from test_sim_standin import standin_body_model


def small_config(n_frames: int = 4, n_pedestrians: int = 8) -> SimConfig:
    cfg = SimConfig()
    cfg.scene.n_frames = n_frames
    cfg.scene.n_pedestrians = n_pedestrians
    cfg.lidar.azimuth_step_deg = 0.36
    return cfg


@pytest.fixture(scope="module")
def body():
    return standin_body_model()


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory, body):
    out = tmp_path_factory.mktemp("sim")
    cfg = small_config(n_frames=5, n_pedestrians=12)
    summary = simulate(out, cfg, seed=3, body_model=body)
    return out, cfg, summary


def mesh_distance(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distance of (N, 3) points to a triangle mesh, via a dense surface sampling (~5 mm spacing)."""
    from scipy.spatial import cKDTree

    mesh = trimesh.Trimesh(vertices, faces, process=False)
    n = int(np.clip(mesh.area / 2.5e-5, 10_000, 200_000))
    samples, _ = trimesh.sample.sample_surface(mesh, n, seed=0)
    return cKDTree(np.concatenate([samples, vertices])).query(points)[0]


def _files_digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_layout_and_reader_round_trip(sim_run):
    out, cfg, summary = sim_run
    assert summary["labels_2d"] > 0 and summary["segments"] > 0
    for sub in ("calib", "labels/2d", "labels/3d/segment", "labels/3d/smpl", "pointclouds", "timestamps", "truth"):
        assert (out / sub).is_dir(), sub
    assert load_config(SimConfig, out / "sim_config.yaml") == cfg
    assert (out / "sim_config.yaml").read_text().startswith("# seed: 3\n")
    tracks = read_dataset(out)
    meta = json.loads((out / "truth" / "meta.json").read_text())
    tids = {p["tracking_id"] for p in meta["pedestrians"]}
    assert tracks and {t.tracking_id for t in tracks} <= tids
    smpl = read_smpl_labels(out)
    for track in tracks:
        assert all(len(tid) == 32 and int(tid, 16) >= 0 for tid in [track.tracking_id])
        labels = {lab.frame: lab for lab in smpl[(track.sequence, track.tracking_id)]}
        for tf in track.frames:
            assert tf.frame in labels                         # every labelled frame has its SMPL truth
            assert tf.left is not None or tf.right is not None
            np.testing.assert_allclose(tf.timestamp, tf.frame / cfg.scene.fps)
            truth = np.load(out / "truth" / track.sequence / f"{track.sequence}_{tf.frame:07d}.npz")
            key = f"segment_index__{track.tracking_id}"
            if len(tf.world_lidar_points):
                pts = truth["scene_points"][truth[key]]
                np.testing.assert_allclose(tf.world_lidar_points, pts, atol=1e-6)
    # the full-scene PLY holds the truth points first, then the lost returns as inf
    seq = meta["sequence"]
    frame0 = np.load(out / "truth" / seq / f"{seq}_0000000.npz")
    ply = read_ply_points(out / "pointclouds" / seq / f"{seq}_0000000.ply", mask_nonfinite=False)
    n = len(frame0["scene_points"])
    np.testing.assert_array_equal(ply[:n].astype(np.float32), frame0["scene_points"])
    assert np.all(np.isinf(ply[n:]))


def test_read_truth_frame(sim_run):
    from pedx_graph.sim import read_truth_frame

    out, cfg, _ = sim_run
    truth = read_truth_frame(out, cfg.scene.first_frame + 1)
    assert truth["scene_points"].shape[1] == 3 and len(truth["scene_object_id"]) == len(truth["scene_points"])
    labelled = [p for p in truth["people"].values() if p["labelled"]]
    assert labelled
    for person in labelled:
        assert person["keypoints"].shape == (18, 3) and person["joints"].shape == (24, 3)
        if len(person["segment_index"]):
            hit = truth["scene_object_id"][person["segment_index"]] == person["object_id"]
            np.testing.assert_array_equal(hit, person["segment_is_person"])


def test_smpl_truth_reproduces_truth_keypoints(sim_run, body):
    out, cfg, _ = sim_run
    smpl = read_smpl_labels(out)
    for (seq, tid), labels in list(smpl.items())[:4]:
        for lab in labels[:2]:
            truth = np.load(out / "truth" / seq / f"{seq}_{lab.frame:07d}.npz")
            kp = body.forward(lab.pose, lab.betas, lab.trans).keypoints
            np.testing.assert_allclose(kp, truth[f"keypoints__{tid}"], atol=1e-6)


def test_keypoint_labels_match_projection_within_noise(sim_run):
    out, cfg, _ = sim_run
    seq = cfg.scene.sequence
    calibs = read_calibrations(out / "calib")
    side_of = {}
    for name, calib in calibs.items():
        left, right = name.split("-")
        side_of[left], side_of[right] = (calib, 0), (calib, 1)
    err_vis, err_occ = [], []
    for path, camera, frame, tid in iter_label2d_files(out, seq):
        label = read_label2d(path, seq, camera, frame, tid)
        truth = np.load(out / "truth" / seq / f"{seq}_{frame:07d}.npz")
        calib, side = side_of[camera]
        uv = calib.project(truth[f"keypoints__{tid}"])[side]
        view = label.view
        assert view.polygon is not None and len(view.polygon) >= 3
        width, height = calib.image_size
        lab = view.labelled
        assert np.all((view.keypoints[lab] >= 0) & (view.keypoints[lab] <= [width, height]))
        err_vis.append((view.keypoints - uv)[lab & view.visible])
        err_occ.append((view.keypoints - uv)[lab & ~view.visible])
    err_vis, err_occ = np.concatenate(err_vis), np.concatenate(err_occ)
    assert len(err_vis) > 200
    rms_vis = np.sqrt(np.mean(err_vis ** 2))            # per axis
    assert abs(rms_vis - cfg.labels.visible_noise_px) < 0.25 * cfg.labels.visible_noise_px
    if len(err_occ) > 50:
        rms_occ = np.sqrt(np.mean(err_occ ** 2))
        assert abs(rms_occ - cfg.labels.occluded_noise_px) < 0.3 * cfg.labels.occluded_noise_px


def test_person_hits_lie_on_the_mesh(sim_run, body):
    """Points whose ray hit a person (exact membership) lie on that person's mesh up to the range noise."""
    out, cfg, _ = sim_run
    meta = json.loads((out / "truth" / "meta.json").read_text())
    seq = meta["sequence"]
    smpl = read_smpl_labels(out)
    checked = 0
    for (s, tid), labels in smpl.items():
        oid = next(p["object_id"] for p in meta["pedestrians"] if p["tracking_id"] == tid)
        lab = labels[0]
        truth = np.load(out / "truth" / seq / f"{seq}_{lab.frame:07d}.npz")
        pts = truth["scene_points"][truth["scene_object_id"] == oid]
        if len(pts) < 5:
            continue
        dist = mesh_distance(body.forward(lab.pose, lab.betas, lab.trans).vertices, body.faces, pts)
        assert np.mean(dist < 0.05) > 0.97
        checked += 1
    assert checked >= 3


def _lone_pedestrian_config(gate_m: float) -> SimConfig:
    cfg = small_config(n_frames=3, n_pedestrians=1)
    cfg.scene.n_parked_cars = cfg.scene.n_moving_cars = cfg.scene.n_buildings_per_corner = 0
    cfg.lidar.azimuth_step_deg = 0.18
    cfg.labels.segment_depth_gate_m = gate_m
    return cfg


def test_unoccluded_pedestrian_segment_is_mostly_on_the_person(tmp_path, body):
    """Lone pedestrian, default rig (cameras ahead of and below the LiDAR), default polygon noise:
    >= 90 % of the segment's points lie within 5 cm of the ground-truth mesh; the depth gate removes only
    points that are not on the person."""
    fractions, gated_on_person, raw_on_person, removed = [], 0, 0, 0
    for seed in range(3):
        runs = {}
        for gate in (0.0, 1.5):
            out = tmp_path / f"s{seed}-{gate}"
            simulate(out, _lone_pedestrian_config(gate), seed=seed, body_model=body)
            runs[gate] = out
        seq = SimConfig().scene.sequence
        for (s, tid), labels in read_smpl_labels(runs[1.5]).items():
            for lab in labels:
                name = f"{seq}_{lab.frame:07d}.npz"
                gated = np.load(runs[1.5] / "truth" / seq / name)
                raw = np.load(runs[0.0] / "truth" / seq / name)
                raw_on_person += int(raw[f"segment_is_person__{tid}"].sum())
                gated_on_person += int(gated[f"segment_is_person__{tid}"].sum())
                removed += len(raw[f"segment_index__{tid}"]) - len(gated[f"segment_index__{tid}"])
                idx = gated[f"segment_index__{tid}"]
                if len(idx) < 5:
                    continue
                dist = mesh_distance(body.forward(lab.pose, lab.betas, lab.trans).vertices, body.faces,
                                     gated["scene_points"][idx])
                fractions.append(np.mean(dist < 0.05))
    assert len(fractions) >= 3
    assert np.median(fractions) >= 0.9
    assert gated_on_person == raw_on_person > 0
    assert removed > 0  # the raw polygon assignment does pick up background here


def test_depth_gate_keeps_near_and_drops_far_points():
    from pedx_graph.data.segment_cut import depth_gate

    pts = np.array([[10.0, 0, 0], [10.2, 0, 0], [9.9, 0.1, 0], [10.1, 0, 1], [12.0, 0, 0], [5.0, 0, 0]])
    idx = np.arange(6)
    assert list(depth_gate(idx, pts, 0.6)) == [0, 1, 2, 3, 5]   # the occluder in front stays
    assert list(depth_gate(idx, pts, 0.0)) == list(idx)
    assert len(depth_gate(np.zeros(0, dtype=int), pts, 0.6)) == 0


def test_same_seed_same_bytes(tmp_path, body):
    cfg = small_config(n_frames=2, n_pedestrians=5)
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    simulate(a, cfg, seed=11, body_model=body)
    simulate(b, cfg, seed=11, body_model=body)
    simulate(c, cfg, seed=12, body_model=body)
    digest_a = _files_digest(a)
    assert len(digest_a) > 10
    assert digest_a == _files_digest(b)
    assert digest_a != _files_digest(c)
    with pytest.raises(FileExistsError, match="already holds"):
        simulate(c, cfg, seed=11, body_model=body)
    simulate(c, cfg, seed=11, body_model=body, overwrite=True, workers=2)   # frames in 2 processes
    assert _files_digest(c) == digest_a


def test_workers_in_a_script_without_main_guard_fail_with_a_clear_error(tmp_path):
    """Spawned workers import the calling script again; without a ``__main__`` guard they cannot start, and
    the call must say so instead of waiting on them for ever."""
    import subprocess
    import sys

    script = tmp_path / "unguarded.py"
    script.write_text("from pedx_graph.sim import SimConfig, simulate\n"
                      "cfg = SimConfig()\ncfg.scene.n_frames = 2\ncfg.scene.n_pedestrians = 1\n"
                      "cfg.lidar.azimuth_step_deg = 0.72\n"
                      f"simulate({str(tmp_path / 'out')!r}, cfg, seed=0, workers=2, overwrite=True)\n")
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=600)
    assert done.returncode != 0
    last = done.stderr.strip().splitlines()[-1]            # the parent's own error, after the workers'
    assert last.startswith("RuntimeError: simulate(workers=2)") and "__main__" in last


def test_figure_renders(sim_run, tmp_path):
    from pedx_graph.sim.figure import render_frame      # matplotlib: a test dependency (pyproject [test])

    out, cfg, _ = sim_run
    png = render_frame(out, cfg.scene.first_frame + 2, tmp_path / "frame.png", dpi=40)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000


def test_default_body_model_smoke(tmp_path):
    """The shipped open model runs through the simulator (outward faces, keypoints, foot contact)."""
    from pedx_graph.body import BodyModel, default_model_path

    assert default_model_path().is_file(), "the shipped default body model is missing"
    body = BodyModel.load()
    cfg = small_config(n_frames=2, n_pedestrians=4)
    cfg.lidar.azimuth_step_deg = 0.72
    summary = simulate(tmp_path / "out", cfg, seed=1, body_model=body)
    assert summary["labels_2d"] > 0 and summary["smpl_labels"] > 0
    tracks = read_dataset(tmp_path / "out")
    assert tracks and all(len(t.tracking_id) == 32 for t in tracks)


def test_default_rig_writes_in_the_sim_frame(sim_run):
    """Default rig: output frame = sim frame (z up, LiDAR at the origin); meta's ground record says so."""
    out, cfg, summary = sim_run
    meta = json.loads((out / "truth" / "meta.json").read_text())
    assert meta["rig"] == "default" and summary["rig"] == "default"
    np.testing.assert_array_equal(meta["output_T_sim"], np.eye(4))
    assert meta["ground"] == {"world_up": [0.0, 0.0, 1.0], "ground_offset_m": -cfg.lidar.height_m}
    truth = np.load(out / "truth" / meta["sequence"] / f"{meta['sequence']}_0000000.npz")
    ground = truth["scene_points"][truth["scene_object_id"] == 0]
    assert np.percentile(np.abs(ground[:, 2] + cfg.lidar.height_m), 95) < 4 * cfg.lidar.range_noise_m
    assert summary["labelled_instances"] == summary["smpl_labels"]
    assert sum(summary["labelled_instances_per_pair"].values()) >= summary["labelled_instances"]
    assert summary["labelled_instances_both_pairs"] == 0          # forward and left pairs do not overlap
