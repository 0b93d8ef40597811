"""KITTI-style calibration files: round trip, KITTI extras, malformed inputs."""
from __future__ import annotations

import logging

import numpy as np
import pytest

from pedx_graph.data.calib import (
    cam_to_cam_path,
    cam_to_range_path,
    discover_pairs,
    read_calibrations,
    read_stereo_calibration,
    write_stereo_calibration,
)
from pedx_graph.data.types import DataFormatError, StereoCalibration


def rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def make_calib(name: str = "ylw79D0-red707B", focal: float = 2000.0, baseline: float = 0.5,
               yaw: float = 0.0) -> StereoCalibration:
    """A plausible roof rig: camera z forward = world x rotated by ``yaw``, 1.8 m above the LiDAR origin."""
    intrinsics = np.array([[focal, 0.0, 1800.0], [0.0, focal, 1300.0], [0.0, 0.0, 1.0]])
    left = np.hstack([intrinsics, np.zeros((3, 1))])
    right = left.copy()
    right[0, 3] = -focal * baseline
    world_R_cam = rot_z(yaw) @ np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    world_T_cam = np.eye(4)
    world_T_cam[:3, :3] = world_R_cam
    world_T_cam[:3, 3] = [0.3, -0.1, 1.8]
    return StereoCalibration(name=name, left_P_rect=left, right_P_rect=right, rect_R_cam=rot_z(0.01),
                             world_T_cam=world_T_cam, image_size=(3678, 2668))


def assert_calib_equal(a: StereoCalibration, b: StereoCalibration) -> None:
    assert a.name == b.name
    assert a.image_size == b.image_size
    for field in ("left_P_rect", "right_P_rect", "rect_R_cam", "world_T_cam"):
        np.testing.assert_allclose(getattr(a, field), getattr(b, field), rtol=0, atol=1e-12, err_msg=field)


def test_round_trip(tmp_path):
    calib = make_calib()
    write_stereo_calibration(tmp_path, calib)
    assert discover_pairs(tmp_path) == ["ylw79D0-red707B"]
    back = read_stereo_calibration(tmp_path, "ylw79D0-red707B")
    assert_calib_equal(calib, back)
    assert back.baseline_m == pytest.approx(0.5)
    assert back.focal_px == pytest.approx(2000.0)


def test_projection_of_a_point_ahead(tmp_path):
    calib = make_calib()
    write_stereo_calibration(tmp_path, calib)
    back = read_stereo_calibration(tmp_path, calib.name)
    world_p = np.array([20.3, -0.1, 1.8])  # 20 m straight ahead of the camera
    rect_p = back.world_to_rect(world_p)
    assert rect_p[2] == pytest.approx(20.0, abs=1e-2)
    left_uv, right_uv = back.project(world_p)
    disparity = left_uv[0] - right_uv[0]
    assert disparity == pytest.approx(back.focal_px * back.baseline_m / rect_p[2], rel=1e-9)


KITTI_CAM_TO_CAM = """calib_time: 09-Jan-2012 13:57:47
corner_dist: 9.950000e-02
S_00: 1.392000e+03 5.120000e+02
K_00: 9.842439e+02 0.000000e+00 6.900000e+02 0.000000e+00 9.808141e+02 2.331966e+02 0.000000e+00 0.000000e+00 1.000000e+00
D_00: -3.728755e-01 2.037299e-01 2.219027e-03 1.383707e-03 -7.233722e-02
R_00: 1.000000e+00 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00
T_00: 2.573699e-16 -1.059758e-16 1.614870e-16
S_rect_00: 1.242000e+03 3.750000e+02
R_rect_00: 9.999239e-01 9.837760e-03 -7.445048e-03 -9.869795e-03 9.999421e-01 -4.278459e-03 7.402527e-03 4.351614e-03 9.999631e-01
P_rect_00: 7.215377e+02 0.000000e+00 6.095593e+02 0.000000e+00 0.000000e+00 7.215377e+02 1.728540e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00
S_01: 1.392000e+03 5.120000e+02
S_rect_01: 1.242000e+03 3.750000e+02
R_rect_01: 9.996878e-01 -8.976826e-03 2.331651e-02 8.876121e-03 9.999508e-01 4.418952e-03 -2.335503e-02 -4.210612e-03 9.997184e-01
P_rect_01: 7.215377e+02 0.000000e+00 6.095593e+02 -3.875744e+02 0.000000e+00 7.215377e+02 1.728540e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00
"""


def test_kitti_extra_keys_and_tr(tmp_path):
    (tmp_path / "calib_cam_to_cam_camA-camB.txt").write_text(KITTI_CAM_TO_CAM)
    (tmp_path / "calib_cam_to_range_camA.txt").write_text(
        "calib_time: 15-Mar-2012 11:37:16\nTr: 0 0 1 0.27 -1 0 0 0 0 -1 0 1.7\n")
    calib = read_stereo_calibration(tmp_path, "camA-camB")
    assert calib.image_size == (1242, 375)
    assert calib.baseline_m == pytest.approx(387.5744 / 721.5377, rel=1e-6)
    np.testing.assert_allclose(calib.world_T_cam[:3, 3], [0.27, 0.0, 1.7])
    # rotations read from 7-digit text are snapped to exact rotations
    np.testing.assert_allclose(calib.rect_R_cam.T @ calib.rect_R_cam, np.eye(3), atol=1e-12)


@pytest.mark.parametrize("edit, field", [  # missing key, 11 floats, non-numeric, 10 floats
    (lambda t: "\n".join(l for l in t.splitlines() if not l.startswith("P_rect_01")), "P_rect_01"),
    (lambda t: t.replace("P_rect_00: 2000.0 0.0", "P_rect_00: 2000.0"), "P_rect_00"),
    (lambda t: t.replace("R_rect_00: ", "R_rect_00: abc "), "R_rect_00"),
    (lambda t: t.replace("R_rect_00: ", "R_rect_00: 0.5 "), "R_rect_00"),
])
def test_malformed_cam_to_cam(tmp_path, edit, field):
    calib = make_calib()
    write_stereo_calibration(tmp_path, calib)
    path = cam_to_cam_path(tmp_path, calib.name)
    path.write_text(edit(path.read_text()))
    with pytest.raises(DataFormatError) as info:
        read_stereo_calibration(tmp_path, calib.name)
    assert path.name in str(info.value) and field in str(info.value)


def test_non_orthonormal_rotation(tmp_path):
    calib = make_calib()
    write_stereo_calibration(tmp_path, calib)
    path = cam_to_range_path(tmp_path, calib.name)
    path.write_text("R: 1 0 0 0 1 0 0 0 1.1\nT: 0 0 0\n")
    with pytest.raises(DataFormatError, match=r"calib_cam_to_range_ylw79D0\.txt: field 'R': not a rotation"):
        read_stereo_calibration(tmp_path, calib.name)


def test_wrong_count_of_T(tmp_path):
    calib = make_calib()
    write_stereo_calibration(tmp_path, calib)
    path = cam_to_range_path(tmp_path, calib.name)
    path.write_text("R: 1 0 0 0 1 0 0 0 1\nT: 0 0\n")
    with pytest.raises(DataFormatError, match=r"field 'T': expected 3 floats, found 2"):
        read_stereo_calibration(tmp_path, calib.name)


def test_negative_baseline_rejected(tmp_path):
    calib = make_calib()
    swapped = StereoCalibration(name=calib.name, left_P_rect=calib.left_P_rect,
                                right_P_rect=calib.right_P_rect * np.array([1, 1, 1, -1]),
                                rect_R_cam=calib.rect_R_cam, world_T_cam=calib.world_T_cam,
                                image_size=calib.image_size)
    write_stereo_calibration(tmp_path, swapped)
    with pytest.raises(DataFormatError, match="P_rect_01.*baseline"):
        read_stereo_calibration(tmp_path, calib.name)


def test_missing_size_falls_back_to_release_size(tmp_path, caplog):
    calib = make_calib()
    write_stereo_calibration(tmp_path, calib)
    path = cam_to_cam_path(tmp_path, calib.name)
    path.write_text("\n".join(l for l in path.read_text().splitlines() if not l.startswith("S_rect")))
    with caplog.at_level(logging.WARNING):
        back = read_stereo_calibration(tmp_path, calib.name)
    assert back.image_size == (3678, 2668)
    assert "S_rect_00" in caplog.text


def test_bad_pair_skipped_good_pair_kept(tmp_path, caplog):
    write_stereo_calibration(tmp_path, make_calib())
    write_stereo_calibration(tmp_path, make_calib("blu79CF-grn43E3", yaw=0.5))
    cam_to_range_path(tmp_path, "blu79CF-grn43E3").write_text("T: 0 0 0\n")
    with caplog.at_level(logging.WARNING):
        calibs = read_calibrations(tmp_path)
    assert list(calibs) == ["ylw79D0-red707B"]
    assert "calib_cam_to_range_blu79CF.txt" in caplog.text and "'R'" in caplog.text


def test_no_pair_readable_raises(tmp_path):
    with pytest.raises(DataFormatError, match="no 'calib_cam_to_cam"):
        read_calibrations(tmp_path)


def test_rectified_frame_to_world_and_camera_centres():
    """``rect_to_world`` inverts ``world_to_rect``; the left camera sits at the rectified frame's origin, the
    right one a baseline along the rectified x axis, where the right projection puts its principal ray."""
    from pedx_graph.sim.cameras import make_calibration
    from pedx_graph.sim.config import SimConfig

    rng = np.random.default_rng(5)
    for pair in SimConfig().cameras.pairs():
        calib = make_calibration(pair)
        world_p = rng.normal(scale=10.0, size=(20, 3))
        np.testing.assert_allclose(calib.rect_to_world(calib.world_to_rect(world_p)), world_p, atol=1e-9)
        np.testing.assert_allclose(calib.world_to_rect(calib.camera_centre("left")), 0.0, atol=1e-9)
        right = calib.world_to_rect(calib.camera_centre("right"))
        np.testing.assert_allclose(right, [calib.baseline_m, 0.0, 0.0], atol=1e-9)
        # a point on the right camera's optical axis projects to the right principal point
        ahead = calib.rect_to_world(right + [0.0, 0.0, 7.0])
        np.testing.assert_allclose(calib.project(ahead)[1], calib.right_P_rect[:2, 2], atol=1e-6)
        np.testing.assert_allclose(calib.world_R_rect @ calib.world_R_rect.T, np.eye(3), atol=1e-12)
