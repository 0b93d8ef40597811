"""Resampling on SO(3): keys preserved, slerp in between, no Euler wrap artefacts, repeats bridged."""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from pedx_graph.motion.clips import MotionClip
from pedx_graph.motion.resample import interpolate_rotvecs, resample_clip, slerp_quaternions


def _random_clip(n=25, fps=30.0, seed=3):
    rng = np.random.default_rng(seed)
    pose = Rotation.random(n * 24, random_state=seed).as_rotvec().reshape(n, 72)
    pelvis = np.cumsum(rng.normal(size=(n, 3)) * 0.05, axis=0)
    return MotionClip("rand", fps, pose, pelvis)


def _angle_between(rv_a, rv_b):
    rel = Rotation.from_rotvec(rv_a.reshape(-1, 3)).inv() * Rotation.from_rotvec(rv_b.reshape(-1, 3))
    return rel.magnitude()


def test_keys_preserved_when_upsampling():
    clip = _random_clip()
    up = resample_clip(clip, fps=90.0)
    assert up.num_frames == 3 * (clip.num_frames - 1) + 1
    assert np.max(_angle_between(up.body_pose_aa[::3], clip.body_pose_aa)) < 1e-9
    np.testing.assert_allclose(up.pelvis_world[::3], clip.pelvis_world, atol=1e-12)


def test_midpoints_equal_scipy_slerp_and_linear_translation():
    clip = _random_clip()
    up = resample_clip(clip, fps=60.0)
    mids = up.body_pose_aa[1::2].reshape(-1, 24, 3)
    for j in (0, 5, 23):
        key_rots = Rotation.from_rotvec(clip.body_pose_aa.reshape(-1, 24, 3)[:, j])
        ref = Slerp(clip.times, key_rots)(clip.times[:-1] + 0.5 / clip.fps).as_rotvec()
        assert np.max(_angle_between(mids[:, j], ref)) < 1e-9
    np.testing.assert_allclose(up.pelvis_world[1::2], 0.5 * (clip.pelvis_world[:-1] + clip.pelvis_world[1:]))


def test_interpolation_across_euler_wrap():
    # yaw +170 deg -> -170 deg (= +190): the short arc passes through 180, not through 0
    keys = Rotation.from_euler("y", [[170.0], [-170.0]], degrees=True).as_rotvec()
    mid = interpolate_rotvecs(np.array([0.0, 1.0]), keys, np.array([0.5]))
    yaw = Rotation.from_rotvec(mid[0]).as_euler("yxz", degrees=True)[0]
    assert abs(abs(yaw) - 180.0) < 1e-6
    quarter = interpolate_rotvecs(np.array([0.0, 1.0]), keys, np.array([0.25]))
    assert abs(Rotation.from_rotvec(quarter[0]).as_euler("yxz", degrees=True)[0] - 175.0) < 1e-6


def test_slerp_shortest_arc_with_sign_flipped_quaternion():
    q0 = Rotation.from_euler("x", 10, degrees=True).as_quat()
    q1 = -Rotation.from_euler("x", 50, degrees=True).as_quat()
    mid = Rotation.from_quat(slerp_quaternions(q0, q1, 0.5))
    assert abs(mid.as_euler("xyz", degrees=True)[0] - 30.0) < 1e-9
    assert np.allclose(slerp_quaternions(q0, q0, 0.3), q0)      # w ~ 0 branch


def test_repeated_frames_are_bridged():
    n = 11
    angles = np.linspace(0.0, 1.0, n)
    pose = np.zeros((n, 72))
    pose[:, 3] = angles
    pelvis = np.stack([angles, np.zeros(n), np.zeros(n)], axis=1)
    pose[5], pelvis[5] = pose[4], pelvis[4]          # dropped markers: frame 5 repeats frame 4
    clip = MotionClip("rep", 10.0, pose, pelvis)
    fixed = resample_clip(clip, fps=10.0)
    assert fixed.meta["dropped_repeats"] == 1
    np.testing.assert_allclose(fixed.body_pose_aa[5, 3], 0.5, atol=1e-12)
    np.testing.assert_allclose(fixed.pelvis_world[5, 0], 0.5, atol=1e-12)
    kept = resample_clip(clip, fps=10.0, drop_repeated=False)
    np.testing.assert_allclose(kept.body_pose_aa[5, 3], 0.4, atol=1e-12)


def test_downsample_frame_count_and_times():
    clip = _random_clip(n=121, fps=120.0)
    down = resample_clip(clip, fps=10.0)
    assert down.num_frames == 11 and down.fps == 10.0
    assert np.max(_angle_between(down.body_pose_aa, clip.body_pose_aa[::12])) < 1e-9
