"""Tests of pedx_graph/data/ground.py: up, ground plane and viewpoint derived from the data, never assumed."""
import dataclasses
import logging

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from factor_testing import make_test_calibration
from pedx_graph.data.ground import (GroundConfig, GroundFrame, calibration_up, estimate_ground,
                                    fit_ground_plane, make_ground_frame)
from pedx_graph.data.types import StereoCalibration


def _moved(calib: StereoCalibration, new_T_old: np.ndarray, name: str | None = None) -> StereoCalibration:
    """The same pair with its LiDAR frame replaced by ``new`` (``new_T_old`` (4, 4) rigid)."""
    return dataclasses.replace(calib, name=name or calib.name, world_T_cam=new_T_old @ calib.world_T_cam)


def _rigid(rng) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = Rotation.random(random_state=rng).as_matrix()
    out[:3, 3] = rng.uniform(-20, 20, 3)
    return out


def _street(rng, n=4000, up=np.array([0.0, 0.0, 1.0]), ground_height=-1.5, tilt_deg=1.0):
    """Scene points: a road tilted by ``tilt_deg`` about x, a building wall, a car roof, noise."""
    tilt = Rotation.from_rotvec([np.radians(tilt_deg), 0.0, 0.0]).as_matrix()
    normal = tilt @ up
    xy = rng.uniform(-30, 30, (n, 2))
    road = np.c_[xy, np.zeros(n)]
    road = road - np.outer(road @ normal, normal) + ground_height * normal + rng.normal(0, 0.02, (n, 1)) * normal
    wall = np.c_[np.full(n // 2, 12.0), rng.uniform(-30, 30, n // 2), rng.uniform(-1.5, 8.0, n // 2)]
    roof = np.c_[rng.uniform(4, 8, n // 3), rng.uniform(2, 4, n // 3), np.full(n // 3, 0.0)]
    return np.concatenate([road, wall, roof]), normal, ground_height


def _z_down_calibration() -> StereoCalibration:
    """A pair whose LiDAR frame has z pointing down (as the real PedX frame): the camera's image-down is +z."""
    calib = make_test_calibration()
    flip = np.diag([1.0, -1.0, -1.0, 1.0])          # z-up world -> z-down world (rotation by pi about x)
    return _moved(calib, flip)


def test_calibration_up_of_a_z_down_rig():
    up, record = calibration_up({"a-b": _z_down_calibration()}, "seq")
    np.testing.assert_allclose(up, [0.0, 0.0, -1.0], atol=1e-9)
    assert record["camera_up_disagreement_deg"] < 1e-6
    ground = estimate_ground({"a-b": _z_down_calibration()}, sequence="seq")
    assert ground.source == "calibration" and ground.ground_offset_m is None
    np.testing.assert_allclose(ground.world_R_level.T @ ground.world_R_level, np.eye(3), atol=1e-12)
    assert np.linalg.det(ground.world_R_level) == pytest.approx(1.0)
    # an upright body stands with its +Y (head) along -z in this frame
    body = ground.world_R_body_from_yaw(0.7)
    np.testing.assert_allclose(body[:, 1], [0, 0, -1], atol=1e-12)
    assert ground.yaw_of(body) == pytest.approx(0.7)


def test_the_level_rotation_is_made_once_read_only_and_anew_for_a_new_frame():
    """``world_R_level`` is kept with its frame object and cannot be changed in place; a frame made from it
    with another up axis (``dataclasses.replace``) gets its own."""
    ground = estimate_ground({"a-b": _z_down_calibration()}, sequence="seq")
    rotation = ground.world_R_level
    assert ground.world_R_level is rotation
    with pytest.raises(ValueError):
        rotation[0, 0] = 2.0
    turned = dataclasses.replace(ground, world_up=-ground.world_up)
    np.testing.assert_allclose(turned.world_R_level[:, 2], -ground.world_up)
    np.testing.assert_allclose(np.linalg.det(turned.world_R_level), 1.0)
    point = np.array([3.0, -2.0, 1.5])
    assert turned.to_level(point)[2] == pytest.approx(-ground.to_level(point)[2])


def test_ground_fit_finds_the_tilted_road_not_walls_or_roofs():
    rng = np.random.default_rng(0)
    points, normal, height = _street(rng)
    fit = fit_ground_plane(points, np.array([0.0, 0.0, 1.0]), min_inliers=200)
    assert fit is not None
    n, d, count = fit
    assert np.degrees(np.arccos(n @ normal)) < 0.1
    assert d == pytest.approx(height, abs=0.01)
    assert count > 3000
    ground = estimate_ground({"a-b": make_test_calibration()}, [points], sequence="seq")
    assert ground.source == "pointclouds"
    np.testing.assert_allclose(ground.world_up, n, atol=1e-12)
    assert ground.height(np.array([0.0, 0.0, height])) == pytest.approx(0.0, abs=0.02)
    assert abs(ground.details["ground_tilt_from_cameras_deg"] - 1.0) < 0.1


def test_segments_lowest_points_give_the_ground_when_no_cloud():
    rng = np.random.default_rng(1)
    segments = []
    for _ in range(30):
        centre = np.r_[rng.uniform(5, 40, 2), 0.0]
        body = centre + np.c_[rng.normal(0, 0.15, (80, 2)), rng.uniform(0.0, 1.7, 80)]
        segments.append(body + [0.0, 0.0, -1.8])
    ground = estimate_ground({"a-b": make_test_calibration()}, None, segments, sequence="seq")
    assert ground.source == "segments"
    # the lowest LiDAR return of a person is a few centimetres above the soles (beam spacing)
    assert ground.ground_offset_m == pytest.approx(-1.8, abs=0.1)
    np.testing.assert_allclose(ground.world_up, [0, 0, 1], atol=0.02)


def test_too_few_ground_points_warn_and_fall_back_to_the_calibration(caplog):
    rng = np.random.default_rng(2)
    with caplog.at_level(logging.WARNING):
        ground = estimate_ground({"a-b": make_test_calibration()}, [rng.normal(size=(20, 3))], [], sequence="SEQX")
    assert ground.source == "calibration" and ground.ground_offset_m is None
    assert ground.details["ground_fallback"] == "calibration"
    assert any("SEQX" in r.getMessage() for r in caplog.records)


def test_cameras_that_disagree_about_up_are_named(caplog):
    calib = make_test_calibration()
    tilted = dataclasses.replace(calib, name="c-d")
    rot = np.eye(4)
    rot[:3, :3] = Rotation.from_rotvec([0.0, 0.0, np.radians(10.0)]).as_matrix()
    tilted = dataclasses.replace(tilted, world_T_cam=calib.world_T_cam @ rot)     # camera rolled 10 degrees
    with caplog.at_level(logging.WARNING):
        _, record = calibration_up({"a-b": calib, "c-d": tilted}, "SEQY", max_disagreement_deg=3.0)
    assert record.get("camera_up_warning") is True
    assert any("SEQY" in r.getMessage() and "disagree" in r.getMessage() for r in caplog.records)


def test_config_overrides():
    rng = np.random.default_rng(3)
    points, _, _ = _street(rng, tilt_deg=0.0)
    config = GroundConfig(world_up=(0.0, 0.0, 2.0), ground_offset_m=-1.0, sensor_xyz=(1.0, 2.0, 3.0))
    ground = estimate_ground({"a-b": make_test_calibration()}, [points], sequence="s", config=config)
    assert ground.source == "config"
    np.testing.assert_allclose(ground.world_up, [0, 0, 1])
    assert ground.ground_offset_m == -1.0
    np.testing.assert_allclose(ground.world_p_sensor, [1, 2, 3])
    with pytest.raises(ValueError, match="source"):
        estimate_ground({"a-b": make_test_calibration()}, config=GroundConfig(source="sky"))


def test_round_trip_through_a_record():
    ground = make_ground_frame([0.1, 0.2, -1.0], [1.0, 0.0, 0.0], [1.0, 2.0, 3.0], 0.3, "segments", {"n": 4})
    again = GroundFrame.from_dict(ground.to_dict())
    for name in ("world_up", "world_forward", "world_p_sensor"):
        np.testing.assert_allclose(getattr(again, name), getattr(ground, name))
    assert again.ground_offset_m == ground.ground_offset_m and again.source == "segments"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_derived_frame_moves_with_the_data(seed):
    """No hidden axis: rigidly move the calibration and the points, and the derived ground moves along."""
    rng = np.random.default_rng(seed)
    calibs = {"a-b": make_test_calibration(), "c-d": dataclasses.replace(make_test_calibration(baseline_m=0.3),
                                                                          name="c-d")}
    points, _, _ = _street(rng)
    segments = [points[:50] + [5.0, 0.0, 0.0]]
    before = estimate_ground(calibs, [points], segments, sequence="s")
    new_T_old = _rigid(rng)
    rot, shift = new_T_old[:3, :3], new_T_old[:3, 3]
    moved = {name: _moved(c, new_T_old) for name, c in calibs.items()}
    after = estimate_ground(moved, [points @ rot.T + shift], [s @ rot.T + shift for s in segments], sequence="s")
    np.testing.assert_allclose(after.world_up, rot @ before.world_up, atol=1e-9)
    np.testing.assert_allclose(after.world_forward, rot @ before.world_forward, atol=1e-9)
    np.testing.assert_allclose(after.world_p_sensor, rot @ before.world_p_sensor + shift, atol=1e-9)
    assert after.ground_offset_m == pytest.approx(before.ground_offset_m + after.world_up @ shift, abs=1e-9)
    probe = rng.normal(size=(5, 3)) * 10
    np.testing.assert_allclose(after.to_level(probe @ rot.T + shift), before.to_level(probe), atol=1e-9)
