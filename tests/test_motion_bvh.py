"""BVH parser and forward kinematics on a tiny synthetic file with known answers."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pedx_graph.motion.bvh import BvhError, euler_to_matrix, forward_kinematics, parse_bvh, read_bvh

TINY = """HIERARCHY
ROOT hip
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT thigh
  {
    OFFSET 10 0 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT shin
    {
      OFFSET 0 -40 0
      CHANNELS 3 Zrotation Xrotation Yrotation
      End Site
      {
        OFFSET 0 -40 0
      }
    }
  }
}
MOTION
Frames: 3
Frame Time: 0.0083333
0 90 0 0 0 0 0 0 0 0 0 0
1 2 3 0 90 0 0 0 0 0 0 0
5 80 -2 10 20 30 40 50 60 -70 80 -90
"""


def test_parse_structure_and_drop_first_frame():
    motion = parse_bvh(TINY, source="tiny.bvh")
    sk = motion.skeleton
    assert sk.names == ("hip", "thigh", "shin")
    assert sk.parents == (-1, 0, 1)
    assert sk.num_channels == 12
    assert motion.num_frames == 2
    np.testing.assert_allclose(motion.rest_channels[:3], [0, 90, 0])
    assert motion.fps == pytest.approx(120.0, rel=1e-4)
    kept = parse_bvh(TINY, drop_first_frame=False)
    assert kept.num_frames == 3 and kept.rest_channels is None


def test_fk_hand_checked_yaw():
    motion = parse_bvh(TINY)
    rot, pos = forward_kinematics(motion.skeleton, motion.channels[0], with_end_sites=True)
    # root at (1, 2, 3), turned +90 deg about Y: offset (10, 0, 0) -> (0, 0, -10)
    np.testing.assert_allclose(pos[0, 0], [1, 2, 3], atol=1e-12)
    np.testing.assert_allclose(pos[0, 1], [1, 2, -7], atol=1e-9)
    np.testing.assert_allclose(pos[0, 2], [1, -38, -7], atol=1e-9)
    np.testing.assert_allclose(pos[0, 3], [1, -78, -7], atol=1e-9)   # End Site


def test_fk_matches_scipy_intrinsic_euler():
    motion = parse_bvh(TINY)
    vals = motion.channels[1]
    rot, pos = forward_kinematics(motion.skeleton, vals)
    r_root = Rotation.from_euler("ZYX", vals[3:6], degrees=True).as_matrix()
    r_thigh = Rotation.from_euler("ZXY", vals[6:9], degrees=True).as_matrix()
    r_shin = Rotation.from_euler("ZXY", vals[9:12], degrees=True).as_matrix()
    np.testing.assert_allclose(rot[0, 0], r_root, atol=1e-12)
    np.testing.assert_allclose(rot[0, 2], r_root @ r_thigh @ r_shin, atol=1e-12)
    expect_thigh = vals[:3] + r_root @ [10, 0, 0]
    expect_shin = expect_thigh + r_root @ r_thigh @ [0, -40, 0]
    np.testing.assert_allclose(pos[0, 1], expect_thigh, atol=1e-9)
    np.testing.assert_allclose(pos[0, 2], expect_shin, atol=1e-9)


def test_euler_order_is_channel_order():
    a = np.array([30.0, -40.0, 50.0])
    np.testing.assert_allclose(euler_to_matrix(a, "ZXY"),
                               euler_to_matrix(a[:1], "Z") @ euler_to_matrix(a[1:2], "X") @ euler_to_matrix(a[2:], "Y"))


@pytest.mark.parametrize("broken, field", [
    (TINY.replace("Frames: 3", "Frames: 4"), "MOTION holds"),
    (TINY.replace("OFFSET 10 0 0", "OFFSET 10 zero 0"), "OFFSET of joint 'thigh'"),
    (TINY.replace("Zrotation Xrotation Yrotation\n    JOINT shin", "Zrotation Xrotation Wrotation\n    JOINT shin"),
     "unknown channel"),
])
def test_malformed_input_names_the_field(broken, field):
    with pytest.raises(BvhError, match=field):
        parse_bvh(broken, source="bad.bvh")


def test_read_missing_file(tmp_path):
    with pytest.raises(BvhError, match="not found"):
        read_bvh(tmp_path / "nope.bvh")
    path = tmp_path / "tiny.bvh"
    path.write_text(TINY)
    assert read_bvh(path).source == str(path)
