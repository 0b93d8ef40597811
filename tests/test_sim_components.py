"""Unit tests of the simulator's parts: config, scene, LiDAR, cameras, labels, pedestrians, CLI."""
from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from pedx_graph.config import ConfigError, from_dict, load_config
from pedx_graph.sim import cameras, labels, lidar
from pedx_graph.sim.config import LEFT_PAIR, LidarConfig, SimConfig, StereoPairConfig
from pedx_graph.sim.pedestrians import GaitClipSource, loop_clip, plan_pedestrians
from pedx_graph.sim.scene import GROUND_ID, MovingCar, RayScene, StaticScene, build_scene, car_mesh, retime_moving_cars
from test_sim_standin import standin_body_model, standin_model_arrays


def _box_scene(center, extents, object_id=1, ground_z=None):
    box = trimesh.creation.box(extents=extents)
    meshes = [(object_id, np.asarray(box.vertices) + center, np.asarray(box.faces))]
    if ground_z is not None:
        meshes.append((GROUND_ID, np.array([[-100, -100, ground_z], [100, -100, ground_z], [100, 100, ground_z],
                                            [-100, 100, ground_z]], float), np.array([[0, 1, 2], [0, 2, 3]])))
    return RayScene(meshes)


# ---------------------------------------------------------------------------------------------- config

def test_preset_mirrors_defaults():
    from pedx_graph.motion.clips import project_root

    assert load_config(SimConfig, project_root() / "configs" / "sim_default.yaml") == SimConfig()


def test_config_errors_name_the_key():
    with pytest.raises(ConfigError, match="scene.n_pedestrianz"):
        from_dict(SimConfig, {"scene": {"n_pedestrianz": 3}}, source="x.yaml")
    cfg = SimConfig()
    cfg.lidar.dropout_prob = 1.5
    with pytest.raises(ConfigError, match="lidar.dropout_prob"):
        cfg.validate("x.yaml")


# ----------------------------------------------------------------------------------------------- scene

def test_ray_scene_reports_first_hit_and_object_id():
    scene = _box_scene(np.array([10.0, 0.0, 0.0]), (1.0, 1.0, 1.0), object_id=7, ground_z=-2.0)
    dirs = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    dist, oid = scene.cast(np.zeros(3), dirs)
    np.testing.assert_allclose(dist[:2], [9.5, 2.0], atol=1e-5)
    assert list(oid) == [7, GROUND_ID, -1] and np.isinf(dist[2])


def test_intersection_scene_objects():
    cfg = SimConfig()
    scene = build_scene(cfg, np.random.default_rng(0))
    kinds = [o.kind for o in scene.objects]
    assert kinds[0] == "ground"
    assert kinds.count("parked_car") == cfg.scene.n_parked_cars
    assert kinds.count("moving_car") == cfg.scene.n_moving_cars
    assert len(scene.walkways) == 12
    v, f = car_mesh(4.5, 1.8, 1.5)
    assert np.isclose(v[:, 2].min(), 0.0) and np.isclose(v[:, 2].max(), 1.5)
    # moving cars move at their speed
    car = scene.moving_cars[0]
    shift = car.world_vertices(1.0, scene.ground_z).mean(0) - car.world_vertices(0.0, scene.ground_z).mean(0)
    assert np.isclose(np.linalg.norm(shift), car.speed_mps)


# ----------------------------------------------------------------------------------------------- LiDAR

def test_lidar_sweep_geometry_noise_and_dropout():
    cfg = LidarConfig(azimuth_step_deg=1.0, range_noise_m=0.02, dropout_prob=0.1)
    dirs = lidar.beam_directions(cfg)
    assert dirs.shape == (360 * 32, 3)
    elev = np.degrees(np.arcsin(dirs[:, 2]))
    np.testing.assert_allclose([elev.min(), elev.max()], [-30.67, 10.67], atol=1e-9)
    scene = _box_scene(np.array([0.0, 0.0, 60.0]), (1.0, 1.0, 1.0), ground_z=-cfg.height_m)
    sw = lidar.sweep(scene, cfg, np.random.default_rng(0), dirs)
    down = dirs[:, 2] < 0
    assert np.all(sw.object_id == GROUND_ID)                   # the box overhead is out of the beams
    err = np.linalg.norm(sw.world_points, axis=1) - sw.true_range_m
    assert abs(err.std() - 0.02) < 0.003
    np.testing.assert_allclose(sw.true_range_m * -sw.world_points[:, 2] / np.linalg.norm(sw.world_points, axis=1),
                               cfg.height_m, rtol=1e-3)         # true hits lie on the ground plane
    assert abs(len(sw.world_points) / down.sum() - 0.9) < 0.02   # 10 % dropout
    assert sw.n_dropped == down.sum() - len(sw.world_points)


def test_people_and_cars_occlude_each_other_in_the_sweep():
    cfg = LidarConfig(azimuth_step_deg=0.5, range_noise_m=0.0, dropout_prob=0.0)
    near = trimesh.creation.box(extents=(0.5, 2.0, 4.0))
    far = trimesh.creation.box(extents=(0.5, 6.0, 4.0))
    scene = RayScene([(1, np.asarray(near.vertices) + [10, 0, 0], np.asarray(near.faces)),
                      (2, np.asarray(far.vertices) + [20, 0, 0], np.asarray(far.faces))])
    sw = lidar.sweep(scene, cfg, np.random.default_rng(0))
    az = np.degrees(np.arctan2(sw.world_points[:, 1], sw.world_points[:, 0]))
    assert np.all(sw.object_id[np.abs(az) < 5] == 1)          # behind the near box: nothing of the far one
    assert np.any(sw.object_id[np.abs(az) > 6] == 2)


# --------------------------------------------------------------------------------------------- cameras

def test_calibration_projection_and_rays():
    pair = StereoPairConfig(yaw_deg=90.0, pitch_deg=-3.0, left_camera_xyz=(0.1, 0.2, -0.1))
    calib = cameras.make_calibration(pair)
    assert np.isclose(calib.focal_px, pair.focal_px) and np.isclose(calib.baseline_m, pair.baseline_m)
    left, right = cameras.camera_views(calib)
    rng = np.random.default_rng(1)
    world_p = left.world_center + left.world_R_rect @ np.array([1.0, 0.5, 12.0]) + rng.normal(0, 0.1, (5, 3))
    for view in (left, right):
        uv, depth = view.project(world_p)
        np.testing.assert_allclose(uv, calib.project(world_p)[0 if view.side == "left" else 1], atol=1e-9)
        rays = view.pixel_rays(uv)
        to_p = world_p - view.world_center
        np.testing.assert_allclose(rays, to_p / np.linalg.norm(to_p, axis=1, keepdims=True), atol=1e-9)
    # disparity = f b / depth
    uv_l, depth = left.project(world_p)
    uv_r, _ = right.project(world_p)
    np.testing.assert_allclose(uv_l[:, 0] - uv_r[:, 0], pair.focal_px * pair.baseline_m / depth, rtol=1e-9)
    np.testing.assert_allclose(uv_l[:, 1], uv_r[:, 1], atol=1e-9)


def test_visibility_and_silhouette_polygon():
    calib = cameras.make_calibration(StereoPairConfig(pitch_deg=0.0, left_camera_xyz=(0.0, 0.0, 0.0),
                                                      rectification_deg=(0.0, 0.0, 0.0)))
    view = cameras.camera_views(calib)[0]
    person = trimesh.creation.box(extents=(0.4, 0.6, 1.8))
    wall = trimesh.creation.box(extents=(0.2, 0.3, 3.0))
    person_v = np.asarray(person.vertices) + [20, 0, 0]
    scene = RayScene([(5, person_v, np.asarray(person.faces)),
                      (6, np.asarray(wall.vertices) + [10, 0.2, 0], np.asarray(wall.faces))])
    pts = np.array([[20.0, -0.2, 0.0], [20.0, 0.2, 0.0]])     # centre-ish points inside the box
    vis = cameras.point_visibility(scene, view, pts, tolerance_m=0.25)
    assert list(vis) == [True, False]                          # the wall hides the +y half
    sil = cameras.visible_silhouette(scene, view, 5, person_v, max_cells=64)
    poly = cameras.silhouette_polygon(sil, epsilon_px=2.0)
    # world +y is image left: visible part of the front face y in [-0.3, 0.1] (wall edge y = 0.05 at x = 9.9)
    u = poly[:, 0]
    f, cx = calib.focal_px, calib.image_size[0] / 2
    np.testing.assert_allclose(u.min(), cx - f * 0.05 / 9.9, atol=3)
    np.testing.assert_allclose(u.max(), cx + f * 0.3 / 19.8, atol=3)
    inside = cameras.points_in_polygon(np.array([[u.mean(), calib.image_size[1] / 2], [10.0, 10.0]]), poly)
    assert list(inside) == [True, False]


def test_keypoint_label_noise_and_flags():
    cfg = SimConfig().labels
    rng = np.random.default_rng(0)
    n = 18
    uv_true = np.full((n, 2), 500.0)
    uv_true[-1] = [-5.0, 10.0]
    visible = np.arange(n) % 2 == 0
    in_image = np.ones(n, bool)
    in_image[-1] = False
    errs_v, errs_o = [], []
    for _ in range(400):
        uv, vis = labels.keypoint_labels(uv_true, visible, in_image, cfg, rng, (1000, 1000))
        assert np.all(np.isnan(uv[-1])) and not vis[-1]
        assert np.array_equal(vis[:-1], visible[:-1])
        errs_v.append(uv[:-1][visible[:-1]] - 500)
        errs_o.append(uv[:-1][~visible[:-1]] - 500)
    assert abs(np.std(np.concatenate(errs_v)) - cfg.visible_noise_px) < 0.1
    assert abs(np.std(np.concatenate(errs_o)) - cfg.occluded_noise_px) < 0.4


# ----------------------------------------------------------------------------------------- pedestrians

def test_loop_clip_is_seamless_and_long():
    from pedx_graph.motion.gait import procedural_gait

    clip = procedural_gait("walk", 1.3, duration=3.0, fps=60.0, seed=1)
    looped = loop_clip(clip, 1000)
    assert looped.num_frames == 1000
    step = np.linalg.norm(np.diff(looped.pelvis_world[:, [0, 2]], axis=0), axis=1)
    assert step.max() < 3 * np.median(step)                   # no jump at the seams
    jump = np.abs(np.diff(looped.body_pose_aa[:, 3:], axis=0)).max(axis=1)
    assert jump.max() < 3 * np.percentile(jump, 99) + 0.05


def test_planned_pedestrians_walk_on_walkways_with_feet_on_the_ground():
    cfg = SimConfig()
    cfg.scene.n_frames = 12
    cfg.scene.n_pedestrians = 6
    body = standin_body_model()
    scene = build_scene(cfg, np.random.default_rng(0))
    people = plan_pedestrians(cfg, scene, body, np.random.default_rng(1), GaitClipSource())
    assert len({p.tracking_id for p in people}) == 6
    for p in people:
        assert len(p.tracking_id) == 32 and int(p.tracking_id, 16) >= 0
        assert np.all(np.abs(p.betas) <= cfg.scene.beta_clip)
        out = body.forward(p.pose, p.betas, p.trans)
        np.testing.assert_allclose(out.vertices[..., 2].min(axis=-1), scene.ground_z, atol=1e-9)
        head_up = out.joints[:, 15, 2] - out.joints[:, 0, 2]
        assert np.all(head_up > 0.4)                            # upright in the z-up world
        xy = p.world_pelvis_xy
        mid = len(xy) // 2
        dist = np.hypot(*xy[mid])
        assert cfg.labels.min_distance_m <= dist <= cfg.labels.max_distance_m
        speed = np.linalg.norm(xy[-1] - xy[0]) / ((len(xy) - 1) / cfg.scene.fps)
        assert 0.5 < speed < 2.3
        walkway = next(w for w in scene.walkways if w.name == p.walkway)
        travel = (xy[-1] - xy[0]) / np.linalg.norm(xy[-1] - xy[0])
        assert abs(travel @ walkway.direction) > 0.95           # walks along its walkway
        # facing the walking direction: body +Z (forward) of the pelvis ~ travel direction
        from scipy.spatial.transform import Rotation
        forward = Rotation.from_rotvec(p.pose[mid, :3]).apply([0.0, 0.0, 1.0])
        assert forward[:2] @ travel > 0.8


def _gap_to_car(car: MovingCar, time_s: float, xy: np.ndarray) -> float:
    """Horizontal distance (m) from ``xy`` to the car's footprint at ``time_s`` (0 inside), from its placed
    mesh (OpenCV's signed polygon distance to the convex hull of the vertices' xy)."""
    import cv2

    footprint = cv2.convexHull(car.world_vertices(time_s, 0.0)[:, :2].astype(np.float32))
    return max(-cv2.pointPolygonTest(footprint, (float(xy[0]), float(xy[1])), True), 0.0)


def _one_car_scene(start_xy, yaw_rad=np.pi / 2, speed=5.0) -> StaticScene:
    v, f = car_mesh(4.5, 1.8, 1.5)
    return StaticScene(ground_z=0.0, objects=[], static_meshes=[], walkways=[],
                       moving_cars=[MovingCar(1, np.asarray(start_xy, float), yaw_rad, speed, v, f)])


def test_moving_cars_yield_to_pedestrians():
    """A car whose drive would pass through a walker is retimed by the smallest whole number of frame periods
    that keeps its footprint the clearance away at every frame; one period less would not; a car that passes
    clear, and any car with clearance 0, are left as they were."""
    fps, frames, clearance = 10.0, 20, 1.0
    times = np.arange(frames) / fps
    walker = np.stack([np.full(frames, 0.4), -1.0 + 1.3 * times], axis=1)     # crossing the car's lane
    far = np.stack([np.full(frames, 9.0), np.zeros(frames)], axis=1)          # on a sidewalk, clear of it
    pelvis_xy = np.stack([walker, far])
    present = np.ones((2, frames), dtype=bool)
    present[1, :5] = False

    def nearest(car):
        return min(_gap_to_car(car, t, xy) for k, t in enumerate(times) for xy in pelvis_xy[:, k])

    scene = _one_car_scene([0.0, -8.0])
    car = scene.moving_cars[0]
    assert nearest(car) < 0.1                                   # as drawn, it drives through the walker
    start = car.start_xy.copy()
    (shift,) = retime_moving_cars(scene, pelvis_xy, present, fps, clearance)
    assert shift != 0 and abs(shift * fps - round(shift * fps)) < 1e-9
    heading = np.array([np.cos(car.yaw_rad), np.sin(car.yaw_rad)])
    np.testing.assert_allclose(car.start_xy, start + shift * car.speed_mps * heading)
    assert nearest(car) >= clearance - 1e-6
    for periods in range(-int(round(abs(shift) * fps)) + 1, int(round(abs(shift) * fps))):   # every smaller shift
        trial = _one_car_scene(start + periods / fps * car.speed_mps * heading).moving_cars[0]
        assert nearest(trial) < clearance

    clear = _one_car_scene([0.0, 30.0])                          # beyond the walker for the whole sequence
    assert retime_moving_cars(clear, pelvis_xy, present, fps, clearance) == [0.0]
    np.testing.assert_array_equal(clear.moving_cars[0].start_xy, [0.0, 30.0])
    off = _one_car_scene([0.0, -8.0])
    assert retime_moving_cars(off, pelvis_xy, present, fps, 0.0) == [0.0]
    np.testing.assert_array_equal(off.moving_cars[0].start_xy, [0.0, -8.0])


# ------------------------------------------------------------------------------------------------- CLI

def test_cli_simulate(tmp_path, capsys):
    from pedx_graph.body.io import save_model_npz
    from pedx_graph.cli import main

    model = save_model_npz(tmp_path / "standin.npz", standin_model_arrays())
    preset = tmp_path / "small.yaml"
    preset.write_text("lidar:\n  azimuth_step_deg: 0.72\ncameras:\n  label_right_images: false\n")
    out = tmp_path / "out"
    code = main(["simulate", str(out), "--seed", "5", "--pedestrians", "3", "--frames", "2", "--config", str(preset),
                 "--body-model", str(model)])
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["pedestrians"] == 3 and summary["frames"] == 2
    cfg = load_config(SimConfig, out / "sim_config.yaml")
    assert cfg.lidar.azimuth_step_deg == 0.72 and cfg.scene.n_pedestrians == 3
    assert cfg.cameras.left.name == LEFT_PAIR


def test_embree_backends_agree():
    """The direct Embree 4 binding and embreex (with back-face culling) give the same first hits."""
    from pedx_graph.sim.scene import _embree4

    if _embree4() is None:
        pytest.skip("direct Embree 4 binding not available (embreex is used)")
    cfg = SimConfig()
    scene = build_scene(cfg, np.random.default_rng(2))
    body = standin_body_model()
    v = body.forward(np.zeros(72), np.zeros(10)).vertices @ np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0.0]]).T
    meshes = scene.meshes_at(0.5) + [(100 + k, v + [8.0 + 1.5 * k, 0.4 * k - 2.0, -1.0], body.faces)
                                     for k in range(8)]
    viewpoints = np.array([[0.0, 0.0, 0.0], [0.27, 0.0, -0.08], [0.27, -0.5, -0.08]])
    fast = RayScene(meshes)
    slow = RayScene(meshes, viewpoints, backend="embreex")
    assert fast.backend == "embree4-ctypes" and slow.backend == "embreex"
    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(20_003, 3))
    dirs[:, 0] = np.abs(dirs[:, 0]) * 3
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for origin in viewpoints:
        d_fast, id_fast = fast.cast(origin, dirs)
        d_slow, id_slow = slow.cast(origin, dirs)
        assert np.mean(id_fast == id_slow) > 0.9999
        both = np.isfinite(d_fast) & np.isfinite(d_slow)
        assert np.array_equal(np.isfinite(d_fast), np.isfinite(d_slow))
        np.testing.assert_allclose(d_fast[both], d_slow[both], atol=1e-4)
        assert (id_fast >= 100).sum() > 100
