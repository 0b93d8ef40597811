"""Retargeting real CMU clips onto SMPL's tree (skipped when ../shared is absent)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pedx_graph.keypoints import SMPL_JOINTS
from pedx_graph.motion.bvh import read_bvh
from pedx_graph.motion.clips import HOLDOUT, is_holdout, list_clips
from pedx_graph.motion.retarget import (bvh_rest_joints, generic_rest_joints, load_cmu_clip, rest_facing_yaw,
                                        retarget_bvh, retarget_joint_error)

CMU = Path(__file__).resolve().parents[2] / "shared" / "mocap" / "cmu"
needs_cmu = pytest.mark.skipif(not (CMU / "clips.csv").is_file(), reason="../shared/mocap/cmu not present")

#: Mean horizontal speeds (m/s) listed for these clips in the mocap folder's README.
README_SPEEDS = {"07_01": 1.35, "12_01": 0.87, "09_01": 3.43}


@needs_cmu
def test_split_lists():
    train, hold = list_clips(CMU, "train"), list_clips(CMU, "holdout")
    assert len(train) + len(hold) == len(list_clips(CMU, "all"))
    assert {c.name for c in hold} == {c.name for c in list_clips(CMU, "all")
                                      if c.subject == "08" or c.name == "02_03"}
    assert not any(is_holdout(c.name) for c in train)
    assert HOLDOUT == ("08_*", "02_03")


@needs_cmu
@pytest.mark.parametrize("name", sorted(README_SPEEDS))
def test_retargeted_clip_is_plausible(name):
    clip = load_cmu_clip(CMU / f"{name}.bvh")
    assert clip.fps == pytest.approx(120.0, rel=1e-4)
    assert np.all(np.isfinite(clip.body_pose_aa))
    aa = clip.body_pose_aa.reshape(-1, 24, 3)
    for knee in ("left_knee", "right_knee"):
        rv = aa[:, SMPL_JOINTS.index(knee)]
        flex = np.degrees(rv[:, 0])
        assert np.percentile(flex, 1) > -5.0            # knees bend forward only (about +X)
        assert flex.max() > 40.0                         # and they do bend
        assert np.all(np.abs(np.degrees(rv[:, 1:])) < 45.0)
    # speed vs the README's mean speed (straight-line displacement / duration)
    disp = np.linalg.norm(clip.pelvis_world[-1, [0, 2]] - clip.pelvis_world[0, [0, 2]])
    assert disp / clip.duration == pytest.approx(README_SPEEDS[name], rel=0.08)
    # walks forward: velocity along the body's +Z axis
    fwd = clip.world_R_pelvis[:, :, 2]
    vel = np.gradient(clip.pelvis_world, axis=0) * clip.fps
    assert np.mean(np.sum(vel * fwd, axis=1)) > 0.8 * README_SPEEDS[name]
    # pelvis height: hip joints ~0.85 m, SMPL pelvis above them
    assert 0.85 < np.median(clip.pelvis_world[:, 1]) < 1.05


@needs_cmu
def test_rest_frame_faces_plus_z_and_left_is_plus_x():
    motion = read_bvh(CMU / "07_01.bvh")
    assert abs(rest_facing_yaw(motion)) < np.deg2rad(5)
    rest = bvh_rest_joints(motion)
    assert rest[SMPL_JOINTS.index("left_hip"), 0] > 0.05
    assert rest[SMPL_JOINTS.index("left_shoulder"), 0] > 0.05
    assert rest[SMPL_JOINTS.index("head"), 1] > 0.4


@needs_cmu
@pytest.mark.parametrize("name", ["07_01", "02_03"])
def test_transfer_consistency_and_body_error(name):
    motion = read_bvh(CMU / f"{name}.bvh")
    # with the BVH's own rest geometry, FK of the retargeted pose reproduces the BVH joints exactly
    exact = retarget_joint_error(motion, bvh_rest_joints(motion), scale_bones=False)
    assert exact.max_mm < 1e-6                               # measured 1.6e-12 mm (round-off)
    # a generic body (bone lengths matched, limb bones aligned at rest): legs exact, shoulders differ
    generic = retarget_joint_error(motion, generic_rest_joints())
    assert generic.mean_mm < 28.0                            # measured 16.9 (07_01) / 18.5 mm (02_03)
    for joint in ("left_knee", "right_knee", "left_ankle", "right_ankle"):
        assert generic.per_joint_mm[joint] < 1e-6            # measured 3e-13 mm: exact
    unaligned = retarget_joint_error(motion, generic_rest_joints(), align_bones=False)
    assert unaligned.mean_mm > generic.mean_mm


@needs_cmu
def test_retarget_requires_rest_frame():
    motion = read_bvh(CMU / "07_01.bvh", drop_first_frame=False)
    with pytest.raises(ValueError, match="T-pose"):
        retarget_bvh(motion)
