"""Procedural gait: requested speed, alternating feet, plausible joints, seeds, paths; clip mirroring."""
from __future__ import annotations

import numpy as np
import pytest

from pedx_graph.keypoints import SMPL_JOINTS
from pedx_graph.motion.clips import MotionClip
from pedx_graph.motion.gait import procedural_gait
from pedx_graph.motion.retarget import generic_rest_joints, smpl_joint_positions

J = {n: i for i, n in enumerate(SMPL_JOINTS)}


def _joints(clip):
    return smpl_joint_positions(generic_rest_joints(), clip.body_pose_aa, clip.pelvis_world)


@pytest.mark.parametrize("kind, speed", [("walk", 0.6), ("walk", 1.3), ("walk", 1.9), ("jog", 3.0)])
def test_speed_and_alternating_feet(kind, speed):
    clip = procedural_gait(kind, speed, duration=6.0, fps=30.0, seed=4)
    disp = np.linalg.norm(clip.pelvis_world[-1, [0, 2]] - clip.pelvis_world[0, [0, 2]])
    assert disp / clip.duration == pytest.approx(speed, rel=0.02)
    pos = _joints(clip)
    fwd = clip.world_R_pelvis[:, :, 2]
    rel_l = np.sum((pos[:, J["left_ankle"]] - clip.pelvis_world) * fwd, axis=1)
    rel_r = np.sum((pos[:, J["right_ankle"]] - clip.pelvis_world) * fwd, axis=1)
    assert np.corrcoef(rel_l, rel_r)[0, 1] < -0.6          # feet alternate
    # one forward/backward swing of each foot per stride: zero crossings = 2 * strides
    crossings = np.sum(np.diff(np.sign(rel_l - rel_l.mean())) != 0)
    strides = clip.meta["gait"]["cadence"] / 2.0 * clip.duration
    assert abs(crossings - 2 * strides) <= 2
    # feet reach the floor, never far below it
    low = pos[:, [J["left_foot"], J["right_foot"], J["left_ankle"], J["right_ankle"]], 1].min()
    assert -0.04 < low < 0.04


def test_cadence_and_step_length_are_human():
    walk = procedural_gait("walk", 1.3, duration=2.0, seed=0).meta["gait"]
    assert 100 < 60 * walk["cadence"] < 120 and 0.6 < walk["step_length"] < 0.8
    jog = procedural_gait("jog", 3.0, duration=2.0, seed=0).meta["gait"]
    assert 150 < 60 * jog["cadence"] < 180


@pytest.mark.parametrize("kind, speed", [("walk", 1.4), ("jog", 3.5), ("stand", 0.0)])
def test_joint_ranges(kind, speed):
    clip = procedural_gait(kind, speed, duration=4.0, fps=30.0, seed=1)
    aa = np.degrees(clip.body_pose_aa.reshape(-1, 24, 3))
    for knee in ("left_knee", "right_knee"):
        assert aa[:, J[knee], 0].min() >= 0.0                    # flexion only, about +X
        assert np.abs(aa[:, J[knee], 1:]).max() < 1e-6
        assert aa[:, J[knee], 0].max() < 120.0
    hip_flex = -aa[:, [J["left_hip"], J["right_hip"]], 0]
    assert hip_flex.max() < 70.0 and hip_flex.min() > -30.0
    assert np.all(np.isfinite(clip.pelvis_world))


def test_deterministic_by_seed_and_consistent_across_fps():
    a = procedural_gait("walk", 1.2, duration=3.0, fps=10.0, seed=7)
    b = procedural_gait("walk", 1.2, duration=3.0, fps=10.0, seed=7)
    c = procedural_gait("walk", 1.2, duration=3.0, fps=10.0, seed=8)
    np.testing.assert_array_equal(a.body_pose_aa, b.body_pose_aa)
    assert not np.allclose(a.body_pose_aa, c.body_pose_aa)
    fine = procedural_gait("walk", 1.2, duration=3.0, fps=30.0, seed=7)
    assert fine.num_frames == 91 and a.num_frames == 31
    np.testing.assert_allclose(fine.pelvis_world[::3], a.pelvis_world, atol=1e-6)


def test_turning_along_a_path():
    radius = 5.0
    ang = np.linspace(0.0, np.pi / 2, 50)
    path = np.stack([radius * (1 - np.cos(ang)), radius * np.sin(ang)], axis=1)   # start +Z, end +X
    arc = radius * np.pi / 2
    clip = procedural_gait("walk", 1.3, duration=arc / 1.3, fps=10.0, path_xz=path, seed=2)
    fwd = clip.world_R_pelvis[:, :, 2]
    heading = np.degrees(np.arctan2(fwd[:, 0], fwd[:, 2]))
    assert abs(heading[5]) < 15.0 and abs(heading[-5] - 90.0) < 15.0
    end = clip.pelvis_world[-1, [0, 2]]
    assert np.linalg.norm(end - path[-1]) < 0.3


def test_stand_stays_put_and_validation():
    clip = procedural_gait("stand", duration=10.0, fps=10.0, seed=3)
    assert np.ptp(clip.pelvis_world[:, [0, 2]], axis=0).max() < 0.1
    with pytest.raises(ValueError, match="walking speed"):
        procedural_gait("walk", 4.0)
    with pytest.raises(ValueError, match="kind"):
        procedural_gait("crawl", 1.0)


def test_mirror_reflects_joint_positions():
    clip = procedural_gait("walk", 1.3, duration=2.0, fps=10.0, seed=5, heading=0.4)
    mirror = clip.mirrored()
    pos, pos_m = _joints(clip), _joints(mirror)            # the generic skeleton is left/right symmetric
    from pedx_graph.motion.clips import SMPL_MIRROR_PERMUTATION
    reflected = pos[:, list(SMPL_MIRROR_PERMUTATION)] * np.array([-1.0, 1.0, 1.0])
    np.testing.assert_allclose(pos_m, reflected, atol=1e-9)


def test_motion_clip_validation_and_trans():
    with pytest.raises(ValueError, match="body_pose_aa"):
        MotionClip("x", 10.0, np.zeros((3, 69)), np.zeros((3, 3)))
    clip = MotionClip("x", 10.0, np.zeros((2, 72)), np.ones((2, 3)))
    np.testing.assert_allclose(clip.trans_for(np.array([0.0, 0.2, 0.0])), [[1, 0.8, 1]] * 2)
