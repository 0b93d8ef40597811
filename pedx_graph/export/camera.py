"""One rectified camera of a stereo pair: projection of world points and its Jacobian.

A camera is the left or the right image of a :class:`~pedx_graph.data.types.StereoCalibration`; pixels are
``uv = P_rect @ [rect_T_world @ world_p; 1]`` (dehomogenised), the rectified images of the release.  An image
file whose size differs from the calibration's ``image_size`` (a downscaled copy) is addressed through
``scale`` = its width over the calibration's (pixel centres kept: ``uv_image = (uv + 0.5) * scale - 0.5``).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from pedx_graph.data.calib import split_pair
from pedx_graph.data.types import StereoCalibration


@dataclass(frozen=True)
class Camera:
    """The ``side`` (``"left"`` / ``"right"``) camera ``name`` of the stereo pair ``calib``."""

    name: str
    """Camera name as in the release (e.g. ``ylw79D0``)."""
    side: str
    """``"left"`` (the pair's reference camera) or ``"right"``."""
    calib: StereoCalibration
    """The pair's calibration (world = the LiDAR frame of the results)."""

    @property
    def rect_P(self) -> np.ndarray:
        """(3, 4) projection of this camera applied to points in the pair's rectified left frame."""
        return self.calib.left_P_rect if self.side == "left" else self.calib.right_P_rect

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the calibration's images, pixels."""
        return tuple(int(v) for v in self.calib.image_size)

    @cached_property
    def world_center(self) -> np.ndarray:
        """(3,) optical centre in the world frame (the right camera: the left one moved by the baseline along
        the rectified x axis)."""
        return self.calib.camera_centre(self.side)

    def project(self, world_p: np.ndarray, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """(..., 3) world points -> ((..., 2) pixels of an image ``scale`` times the calibration's size,
        (...,) depth along the optical axis in metres).  Points with depth <= 0 give meaningless pixels."""
        rect_p = self.calib.world_to_rect(np.asarray(world_p, dtype=float))
        hom = rect_p @ self.rect_P[:, :3].T + self.rect_P[:, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = hom[..., :2] / hom[..., 2:3]
        return to_image_pixels(uv, scale), rect_p[..., 2]

    def jacobian(self, world_p: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """(..., 2, 3) derivative of the pixels (image ``scale``) with respect to the world point, px / m:
        ``d uv / d world_p = scale * (P[:2, :3] - uv_cal P[2, :3]) / h_z @ rect_R_world``."""
        rect_R_world = self.calib.rect_T_world[:3, :3]
        rect_p = self.calib.world_to_rect(np.asarray(world_p, dtype=float))
        hom = rect_p @ self.rect_P[:, :3].T + self.rect_P[:, 3]
        uv = hom[..., :2] / hom[..., 2:3]
        d_rect = (self.rect_P[:2, :3] - uv[..., :, None] * self.rect_P[2, :3]) / hom[..., 2:3, None]
        return scale * d_rect @ rect_R_world

    def image_covariance(self, world_p: np.ndarray, world_cov: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """(..., 2, 2) pixel covariance ``J Sigma J^T`` of (..., 3) points with (..., 3, 3) world covariances
        (first order through :meth:`jacobian`), px^2."""
        jac = self.jacobian(world_p, scale)
        return jac @ np.asarray(world_cov, dtype=float) @ np.swapaxes(jac, -1, -2)


def to_image_pixels(uv: np.ndarray, scale: float) -> np.ndarray:
    """Pixels of the calibration's image size -> pixels of an image ``scale`` times as large (pixel centres
    kept)."""
    return uv if scale == 1.0 else (uv + 0.5) * scale - 0.5


def dataset_cameras(calibrations: dict[str, StereoCalibration]) -> dict[str, Camera]:
    """Every camera of the given stereo pairs by name (both sides of each pair)."""
    out = {}
    for pair_name, calib in sorted(calibrations.items()):
        left, right = split_pair(pair_name)
        out[left] = Camera(left, "left", calib)
        out[right] = Camera(right, "right", calib)
    return out
