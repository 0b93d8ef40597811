"""Tests of pedx_graph/graph/init.py's depth trajectory: LiDAR depths that contradict the keypoints, and
tracks whose frames are measured by different stereo pairs."""
import dataclasses

import numpy as np

from factor_testing import make_test_calibration
from pedx_graph.data.ground import make_ground_frame
from pedx_graph.graph.init import FrameMeasurements, initialise_from_measurements

GROUND = make_ground_frame([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.5], 0.0)
FPS = 10.0


def _walk(n: int = 12, start=(16.0, 1.0), velocity=(-1.2, 0.6)) -> np.ndarray:
    """(n, 3) pelvis positions of a straight walk at 0.9 m height, world metres (10 frames per second)."""
    t = np.arange(n)[:, None] / FPS
    return np.column_stack([np.asarray(start) + t * np.asarray(velocity), np.full(n, 0.9)])


def _rotated_pair(angle_deg: float, centre) -> object:
    """The test pair turned about the vertical by ``angle_deg`` and moved to ``centre``, named ``pair-b``."""
    calib = make_test_calibration()
    a = np.radians(angle_deg)
    rot = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    world_T_cam = calib.world_T_cam.copy()
    world_T_cam[:3, :3] = rot @ world_T_cam[:3, :3]
    world_T_cam[:3, 3] = centre
    return dataclasses.replace(calib, name="pair-b", world_T_cam=world_T_cam)


def _measure(calib, world_p: np.ndarray, time: float, rng, lidar_depth: float | None = None) -> FrameMeasurements:
    """One frame's measurements of a pelvis at ``world_p``: its pixel in the left image, its stereo depth
    with 0.1 m of noise (sigma 0.2), and a LiDAR depth and centroid when ``lidar_depth`` is given."""
    rect = calib.world_to_rect(world_p)
    p = calib.left_P_rect
    uv = np.array([p[0, 0] * rect[0] / rect[2] + p[0, 2], p[1, 1] * rect[1] / rect[2] + p[1, 2]])
    centroid = np.full(3, np.nan)
    if lidar_depth is not None:
        centroid = calib.rect_to_world(rect * lidar_depth / rect[2])
    return FrameMeasurements(time=time, calibration=calib, lidar_centroid=centroid,
                             lidar_depth=np.nan if lidar_depth is None else float(lidar_depth),
                             stereo_depth=float(rect[2] + rng.normal(scale=0.1)), stereo_sigma=0.2,
                             centre_pixel=(uv, "left"), torso_yaw=np.nan, placeable=True,
                             depth_source="lidar" if lidar_depth is not None else "stereo",
                             stereo_source="stereo")


def _speeds(centre: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(centre[:, :2], axis=0), axis=1) * FPS


def test_lidar_depths_of_the_background_are_refused():
    """Four frames whose LiDAR points are a wall 7 m behind the person (two pairs of neighbours, more than a
    running median removes): the frames are placed by stereo and the trajectory stays the walk."""
    rng = np.random.default_rng(0)
    calib = make_test_calibration()
    truth = _walk()
    background = {4, 5, 7, 8}
    frames = []
    for i, p in enumerate(truth):
        depth = float(calib.world_to_rect(p)[2])
        frames.append(_measure(calib, p, i / FPS, rng, depth + (7.0 if i in background else 0.05)))
    init = initialise_from_measurements(frames, GROUND, "test")
    assert np.max(np.linalg.norm(init.world_p_centre - truth, axis=1)) < 0.3
    np.testing.assert_allclose(_speeds(init.world_p_centre), np.hypot(1.2, 0.6), atol=0.4)
    assert [init.depth_source[i] for i in sorted(background)] == ["stereo"] * 4
    assert init.depth_source[0] == "lidar"


def test_a_track_measured_by_two_pairs_keeps_one_trajectory():
    """Frames 0-7 seen by one pair, 8-11 by another turned 30 degrees and a metre aside: each frame's depth
    is along its own pair's axis, the smoothed trajectory is the straight walk all through."""
    rng = np.random.default_rng(1)
    pair_a, pair_b = make_test_calibration(), _rotated_pair(30.0, [0.4, 0.9, 1.5])
    truth = _walk()
    frames = [_measure(pair_a if i < 8 else pair_b, p, i / FPS, rng) for i, p in enumerate(truth)]
    init = initialise_from_measurements(frames, GROUND, "test")
    assert np.max(np.linalg.norm(init.world_p_centre - truth, axis=1)) < 0.3
    np.testing.assert_allclose(_speeds(init.world_p_centre), np.hypot(1.2, 0.6), atol=0.4)
    heading = np.degrees(init.heading_yaw)
    np.testing.assert_allclose(heading, np.degrees(np.arctan2(0.6, -1.2)), atol=10.0)


def test_lidar_keeps_the_lead_when_most_frames_disagree_with_stereo():
    """Stereo 5 m off in every frame (a wrong calibration, not the points): nothing is refused."""
    rng = np.random.default_rng(2)
    calib = make_test_calibration()
    truth = _walk()
    frames = []
    for i, p in enumerate(truth):
        m = _measure(calib, p, i / FPS, rng, float(calib.world_to_rect(p)[2]) + 0.05)
        frames.append(dataclasses.replace(m, stereo_depth=m.stereo_depth + 5.0))
    init = initialise_from_measurements(frames, GROUND, "test")
    assert init.depth_source == ["lidar"] * len(truth)
    assert np.max(np.linalg.norm(init.world_p_centre - truth, axis=1)) < 0.3
