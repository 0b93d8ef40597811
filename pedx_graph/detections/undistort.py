"""Raw (distorted) image pixels -> rectified pixels of the stereo pair, with the camera's K, D and R_rect.

The raw model is OpenCV's radial-tangential one (KITTI raw keys ``K_0x``, ``D_0x``); a raw pixel is undistorted
to a ray of the camera's frame, rotated by ``R_rect_0x`` into the rectified frame and projected with the left
3x3 of ``P_rect_0x`` (``cv2.undistortPoints`` with ``R`` and ``P``).  The inverse (:func:`distort`) is what the
simulator uses to write raw-image detections.
"""
from __future__ import annotations

from typing import Mapping

import cv2
import numpy as np

from pedx_graph.data.types import DataFormatError, RawCamera, StereoCalibration


def find_camera(calibration: StereoCalibration | Mapping[str, StereoCalibration],
                camera: str) -> tuple[StereoCalibration, str]:
    """``(pair calibration, side)`` of the camera named ``camera``: side ``"left"`` or ``"right"``.

    ``calibration`` is one pair or a dict of pairs (pair names ``<left>-<right>``); KeyError when no pair
    has the camera.
    """
    pairs = [calibration] if isinstance(calibration, StereoCalibration) else list(calibration.values())
    for calib in pairs:
        left, _, right = calib.name.partition("-")
        if camera == left:
            return calib, "left"
        if camera == right:
            return calib, "right"
    raise KeyError(f"camera {camera!r} is in no calibrated pair "
                   f"({', '.join(c.name for c in pairs) or 'none'})")


def raw_camera(calib: StereoCalibration, side: str) -> RawCamera | None:
    """The raw image model of the pair's ``side`` camera, or None when the calibration has none."""
    return calib.left_raw if side == "left" else calib.right_raw


def undistort_rectify(raw_uv: np.ndarray, raw: RawCamera) -> np.ndarray:
    """(K, 2) raw pixels -> (K, 2) rectified pixels of the same camera (NaN rows stay NaN)."""
    raw_uv = np.asarray(raw_uv, dtype=np.float64).reshape(-1, 2)
    out = np.full_like(raw_uv, np.nan)
    ok = np.all(np.isfinite(raw_uv), axis=1)
    if ok.any():
        pts = cv2.undistortPoints(raw_uv[ok].reshape(-1, 1, 2), raw.raw_K, raw.raw_D, R=raw.rect_R_cam,
                                  P=raw.P_rect[:, :3],
                                  criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12))
        out[ok] = pts.reshape(-1, 2)
    return out


def distort(rect_uv: np.ndarray, raw: RawCamera) -> np.ndarray:
    """(K, 2) rectified pixels -> (K, 2) raw (distorted) pixels of the same camera: the inverse of
    :func:`undistort_rectify` (NaN rows stay NaN)."""
    rect_uv = np.asarray(rect_uv, dtype=np.float64).reshape(-1, 2)
    out = np.full_like(rect_uv, np.nan)
    ok = np.all(np.isfinite(rect_uv), axis=1)
    if ok.any():
        hom = np.concatenate([rect_uv[ok], np.ones((int(ok.sum()), 1))], axis=1)
        rect_ray = hom @ np.linalg.inv(raw.P_rect[:, :3]).T
        cam_ray = rect_ray @ raw.rect_R_cam           # R_rect^T applied to row vectors
        pts, _ = cv2.projectPoints(cam_ray.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), raw.raw_K, raw.raw_D)
        out[ok] = pts.reshape(-1, 2)
    return out


def rectified(det, calibration: StereoCalibration | Mapping[str, StereoCalibration],
              require_raw: bool = False) -> np.ndarray:
    """(K, 2) rectified pixels of a :class:`~pedx_graph.detections.types.Detection` (NaN where absent).

    ``calibration``: the pair holding ``det.camera`` or a dict of pairs.  A camera without a raw model
    (no ``K_0x``/``D_0x`` in its file) has images that are already rectified: the pixels are returned as
    they are, unless ``require_raw`` (then :class:`DataFormatError` naming the detection's source).
    """
    calib, side = find_camera(calibration, det.camera)
    raw = raw_camera(calib, side)
    if raw is None:
        if require_raw:
            raise DataFormatError(det.source, "K_0x/D_0x",
                                  f"camera {det.camera} has no raw image model in pair {calib.name}'s calibration")
        return np.asarray(det.image_uv, dtype=np.float64).copy()
    return undistort_rectify(det.image_uv, raw)
