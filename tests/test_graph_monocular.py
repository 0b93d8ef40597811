"""Body-size depth of a pedestrian seen by one camera (pedx_graph.graph.monocular) against simulated truth.

Bodies: betas ~ N(0, 1) clipped at 2.5 (the simulator's), poses from the procedural gait (walk, jog, stand;
independent of the pose prior the estimator draws its pose statistics from), random heading, feet on the
ground, 5-45 m from a 3300 px camera 1.5 m high; 2 px click noise.
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from factor_testing import make_test_calibration
from pedx_graph.body import BodyModel
from pedx_graph.data.types import StereoCalibration, Track, TrackFrame, View2D
from pedx_graph.graph.monocular import (body_size_prior, frame_monocular_depth, monocular_depth,
                                        track_monocular_depths)
from pedx_graph.keypoints import PEDX_KEYPOINTS
from pedx_graph.motion.gait import procedural_gait

_IDX = {n: i for i, n in enumerate(PEDX_KEYPOINTS)}
WORLD_UP = np.array([0.0, 0.0, 1.0])
CLIP_TO_WORLD = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])   # clip Y up -> world z up


@pytest.fixture(scope="module")
def model():
    return BodyModel.load()


@pytest.fixture(scope="module")
def prior(model):
    return body_size_prior(model)


@pytest.fixture(scope="module")
def calib():
    return make_test_calibration(focal_px=3300.0, baseline_m=0.3)


@pytest.fixture(scope="module")
def gait_poses(model):
    rest = model.rest_joints(np.zeros(model.num_betas))
    return np.concatenate([procedural_gait(kind, speed, duration=3.0, seed=s, rest_joints=rest).body_pose_aa
                           for kind, speed in (("walk", 0.9), ("walk", 1.3), ("walk", 1.7), ("jog", 2.8),
                                               ("stand", 0.0)) for s in range(2)])


def _instance(model, calib, poses, rng, distance_m):
    """True world keypoints (18, 3) of a random body ``distance_m`` ahead of the camera, feet on z = 0."""
    betas = np.clip(rng.standard_normal(model.num_betas), -2.5, 2.5)
    pose = poses[rng.integers(len(poses))].copy()
    world_R = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)).as_matrix() @ CLIP_TO_WORLD \
        @ Rotation.from_rotvec(pose[:3]).as_matrix()
    pose[:3] = Rotation.from_matrix(world_R).as_rotvec()
    lowest = model.forward(pose, betas).vertices[:, 2].min()
    trans = np.array([distance_m, rng.uniform(-0.25, 0.25) * distance_m, -lowest])
    return model.keypoints(pose, betas) + trans


def _labels(calib, keypoints, side, rng, noise_px=2.0):
    uv_left, uv_right = calib.project(keypoints)
    uv = (uv_left if side == "left" else uv_right) + rng.normal(scale=noise_px, size=(18, 2))
    return View2D(uv, np.ones(18, dtype=bool))


def _true_depth(calib, keypoints):
    return float(calib.world_to_rect(keypoints[[_IDX["lhip"], _IDX["rhip"]]].mean(axis=0))[2])


def test_depth_error_matches_the_reported_sigma(model, prior, calib, gait_poses):
    """NEES about 1 over 300 instances at 5-45 m, both image sides (measured with this seed: NEES 0.79,
    95 % coverage 0.977, RMS error 5.9 % of the depth, median error -1.5 %, mean sigma 6.7 %, the sigma
    beyond 25 m 2.5x the sigma nearer; benchmarks/bench_monocular.py has the figures per distance)."""
    rng = np.random.default_rng(0)
    rows = []
    for i in range(300):
        distance = rng.uniform(5.0, 45.0)
        kp = _instance(model, calib, gait_poses, rng, distance)
        side = ("left", "right")[i % 2]
        est = monocular_depth(_labels(calib, kp, side, rng), calib, side, prior, world_up=WORLD_UP, sigma_px=2.0)
        assert est is not None and est.side == side and len(est.segments) == 4
        rows.append((_true_depth(calib, kp), est.depth_m, est.sigma_m))
    truth, depth, sigma = np.array(rows).T
    z = (depth - truth) / sigma
    assert 0.55 < np.mean(z ** 2) < 1.2
    assert np.mean(np.abs(z) < 1.96) > 0.92
    rel = (depth - truth) / truth
    assert np.sqrt(np.mean(rel ** 2)) < 0.088
    assert abs(np.median(rel)) < 0.023
    far = truth > 25.0                                     # the sigma grows with the distance
    assert np.mean(sigma[far]) > 1.65 * np.mean(sigma[~far])


def test_no_hidden_axis(prior, calib, model, gait_poses):
    """The same labels and calibration in a rotated, shifted world (e.g. PedX's z-down LiDAR frame) with its
    up vector give the same depth."""
    rng = np.random.default_rng(1)
    kp = _instance(model, calib, gait_poses, rng, 17.0)
    view = _labels(calib, kp, "left", rng)
    base = monocular_depth(view, calib, "left", prior, world_up=WORLD_UP)
    new_T_world = np.eye(4)
    new_T_world[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    new_T_world[:3, 3] = rng.normal(scale=5.0, size=3)
    moved = StereoCalibration(calib.name, calib.left_P_rect, calib.right_P_rect, calib.rect_R_cam,
                              new_T_world @ calib.world_T_cam, calib.image_size)
    est = monocular_depth(view, moved, "left", prior, world_up=new_T_world[:3, :3] @ WORLD_UP)
    assert est.depth_m == pytest.approx(base.depth_m, rel=1e-9)
    assert est.sigma_m == pytest.approx(base.sigma_m, rel=1e-9)
    # a wrong up (the world's +z in the z-down frame: 180 degrees off) does not give an upright body
    assert monocular_depth(view, moved, "left", prior, world_up=-(new_T_world[:3, :3] @ WORLD_UP)) is None


def test_partial_labels_and_a_misclick(prior, calib, model, gait_poses):
    rng = np.random.default_rng(2)
    kp = _instance(model, calib, gait_poses, rng, 20.0)
    truth = _true_depth(calib, kp)
    view = _labels(calib, kp, "left", rng)
    full = monocular_depth(view, calib, "left", prior, world_up=WORLD_UP, sigma_px=2.0)
    # no knees: hips to ankles in one segment
    no_knees = View2D(view.keypoints.copy(), view.visible.copy())
    no_knees.keypoints[[_IDX["lknee"], _IDX["rknee"]]] = np.nan
    est = monocular_depth(no_knees, calib, "left", prior, world_up=WORLD_UP, sigma_px=2.0)
    assert est.segments == ("head-neck", "neck-hips", "hips-ankles")
    # upper body only: weaker (the legs' length is missing)
    upper = View2D(view.keypoints.copy(), view.visible.copy())
    upper.keypoints[[_IDX[n] for n in ("lknee", "rknee", "lankl", "rankl")]] = np.nan
    est_upper = monocular_depth(upper, calib, "left", prior, world_up=WORLD_UP, sigma_px=2.0)
    assert est_upper.segments == ("head-neck", "neck-hips") and est_upper.sigma_m > full.sigma_m
    # a single chain point: no estimate
    lone = View2D(np.full((18, 2), np.nan), np.zeros(18, dtype=bool))
    lone.keypoints[_IDX["neck"]] = view.keypoints[_IDX["neck"]]
    assert monocular_depth(lone, calib, "left", prior) is None
    # both ankles clicked 150 px low (a mis-click on the shadow): the inconsistent point is dropped
    bad = View2D(view.keypoints.copy(), view.visible.copy())
    bad.keypoints[[_IDX["lankl"], _IDX["rankl"]], 1] += 150.0
    est_bad = monocular_depth(bad, calib, "left", prior, world_up=WORLD_UP, sigma_px=2.0)
    assert "knees-ankles" not in est_bad.segments
    assert abs(est_bad.depth_m - truth) < 3.0 * est_bad.sigma_m
    with pytest.raises(ValueError):
        monocular_depth(view, calib, "middle", prior)


def test_track_and_frame_estimates(prior, calib, model, gait_poses):
    rng = np.random.default_rng(3)
    frames, truths = [], []
    for i in range(3):
        kp = _instance(model, calib, gait_poses, rng, 12.0 + 4.0 * i)
        truths.append(_true_depth(calib, kp))
        right = _labels(calib, kp, "right", rng) if i < 2 else None
        frames.append(TrackFrame(frame=i, timestamp=0.1 * i, pair=calib.name, left=None, right=right))
    track = Track("seq", "tid", frames, {calib.name: calib})
    out = track_monocular_depths(track, prior, sigma_px=2.0)
    assert out[2] is None
    for est, truth in zip(out[:2], truths):
        assert est.side == "right" and est.pair == calib.name
        assert abs(est.depth_m - truth) < 3.0 * est.sigma_m
    assert frame_monocular_depth(frames[0], track.calibrations, prior, world_up=track.ground.world_up,
                                 sigma_px=2.0).depth_m == pytest.approx(out[0].depth_m)
