"""Raw-image pixels -> rectified pixels (K, D, R_rect, P_rect) and the calibration's raw keys."""
import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pedx_graph.data.calib import read_stereo_calibration, write_stereo_calibration
from pedx_graph.data.types import DataFormatError, RawCamera, StereoCalibration
from pedx_graph.detections.types import Detection
from pedx_graph.detections.undistort import distort, find_camera, rectified, undistort_rectify


def raw_camera(seed: int) -> RawCamera:
    rng = np.random.default_rng(seed)
    raw_K = np.array([[2000.0 + 50 * rng.normal(), 0.0, 1800.0], [0.0, 2010.0, 1300.0], [0.0, 0.0, 1.0]])
    raw_D = np.array([-0.25, 0.12, 0.001, -0.0005, -0.03]) * (1 + 0.1 * rng.normal(size=5))
    rect_R = Rotation.from_rotvec(rng.normal(scale=0.02, size=3)).as_matrix()
    P_rect = np.array([[1900.0, 0.0, 1820.0, 0.0], [0.0, 1900.0, 1310.0, 0.0], [0.0, 0.0, 1.0, 0.0]])
    return RawCamera(raw_K=raw_K, raw_D=raw_D, rect_R_cam=rect_R, P_rect=P_rect)


def pair(seed: int = 0) -> StereoCalibration:
    left, right = raw_camera(seed), raw_camera(seed + 1)
    right_P = left.P_rect.copy()
    right_P[0, 3] = -1900.0 * 0.3
    right = RawCamera(right.raw_K, right.raw_D, right.rect_R_cam, right_P)
    return StereoCalibration(name="camA-camB", left_P_rect=left.P_rect, right_P_rect=right_P,
                             rect_R_cam=left.rect_R_cam, world_T_cam=np.eye(4), image_size=(3600, 2600),
                             left_raw=left, right_raw=right)


def test_round_trip_through_cv2_project_points():
    raw = raw_camera(3)
    rect_uv = np.random.default_rng(0).uniform([200, 200], [3400, 2400], (200, 2))
    # Distort independently of our code: rectified pixel -> ray in the camera frame -> cv2.projectPoints.
    rays = np.c_[rect_uv, np.ones(len(rect_uv))] @ np.linalg.inv(raw.P_rect[:, :3]).T @ raw.rect_R_cam
    raw_uv, _ = cv2.projectPoints(rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), raw.raw_K, raw.raw_D)
    back = undistort_rectify(raw_uv.reshape(-1, 2), raw)
    assert np.abs(back - rect_uv).max() < 1e-3
    np.testing.assert_allclose(distort(rect_uv, raw), raw_uv.reshape(-1, 2), atol=1e-6)
    # Distortion matters: without undistorting, pixels are off by many pixels at the image corners.
    assert np.abs(raw_uv.reshape(-1, 2) - rect_uv).max() > 20


def test_detection_of_either_camera_and_nan_rows():
    calib = pair()
    uv = np.array([[1000.0, 900.0], [np.nan, np.nan], [2500.0, 2000.0]])
    for camera, raw in (("camA", calib.left_raw), ("camB", calib.right_raw)):
        det = Detection(camera=camera, frame=0, keypoint_set="coco17", image_uv=distort(uv, raw),
                        confidence=np.array([1.0, 0.0, 1.0]), score=1.0, source="test")
        out = rectified(det, {calib.name: calib})
        assert np.isnan(out[1]).all()
        np.testing.assert_allclose(out[[0, 2]], uv[[0, 2]], atol=1e-3)
    assert find_camera(calib, "camB") == (calib, "right")
    with pytest.raises(KeyError, match="camC"):
        find_camera(calib, "camC")


def test_camera_without_raw_model_keeps_pixels_or_refuses():
    calib = StereoCalibration(name="camA-camB", left_P_rect=pair().left_P_rect, right_P_rect=pair().right_P_rect,
                              rect_R_cam=np.eye(3), world_T_cam=np.eye(4), image_size=(3600, 2600))
    det = Detection(camera="camA", frame=0, keypoint_set="coco17", image_uv=np.array([[5.0, 6.0]]),
                    confidence=np.array([1.0]), score=1.0, source="file.json#people[0]")
    np.testing.assert_array_equal(rectified(det, calib), [[5.0, 6.0]])
    with pytest.raises(DataFormatError, match="file.json"):
        rectified(det, calib, require_raw=True)


def test_calibration_files_keep_the_raw_keys(tmp_path):
    calib = pair()
    world_T_cam = np.eye(4)
    world_T_cam[:3, 3] = [0.5, 0.0, 1.0]
    calib = StereoCalibration(**{**calib.__dict__, "world_T_cam": world_T_cam})
    write_stereo_calibration(tmp_path, calib)
    back = read_stereo_calibration(tmp_path, calib.name)
    for side in ("left_raw", "right_raw"):
        got, want = getattr(back, side), getattr(calib, side)
        np.testing.assert_allclose(got.raw_K, want.raw_K)
        np.testing.assert_allclose(got.raw_D, want.raw_D)
        np.testing.assert_allclose(got.rect_R_cam, want.rect_R_cam, atol=1e-9)
    text = (tmp_path / "calib_cam_to_cam_camA-camB.txt").read_text()
    (tmp_path / "calib_cam_to_cam_camA-camB.txt").write_text(
        "\n".join(line if not line.startswith("D_00") else "D_00: 0.1 0.2 0.3" for line in text.splitlines()))
    with pytest.raises(DataFormatError, match="D_00"):
        read_stereo_calibration(tmp_path, calib.name)
