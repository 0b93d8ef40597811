"""A dataset's camera images: where the release keeps them, reading one, and rectifying a raw image into one.

The release keeps each camera's *rectified* images as ``images/<seq>/<cam>/<seq>_<cam>_<frame:07d>.jpg``
(:func:`image_path`); the export draws its overlays on them.  A detector runs on the *raw* (distorted) images,
so a dataset imported from detections is given them rectified (:func:`rectify_image`): every rectified pixel
``(u, v)`` takes the raw pixel its ray comes from — the ray ``P_rect[:, :3]^-1 [u, v, 1]`` of the rectified
frame, rotated back by ``R_rect^T`` into the camera frame and projected with the raw ``K`` and ``D``
(OpenCV's radial-tangential model: ``cv2.initUndistortRectifyMap``), bilinearly interpolated.  The same model
maps the detections' keypoints (:mod:`pedx_graph.detections.undistort`), so the rectified images and the
rectified keypoints agree to the interpolation.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from pedx_graph.data.types import RawCamera


def image_path(root: str | os.PathLike, sequence: str, camera: str, frame: int, ext: str = "jpg") -> Path:
    """``<root>/images/<seq>/<cam>/<seq>_<cam>_<frame:07d>.<ext>`` (the release's image layout)."""
    return Path(root) / "images" / sequence / camera / f"{sequence}_{camera}_{frame:07d}.{ext}"


def read_image(path: str | os.PathLike) -> np.ndarray | None:
    """The (H, W, 3) BGR uint8 image at ``path``, or None when the file is absent or cannot be decoded."""
    import cv2

    path = Path(path)
    if not path.is_file():
        return None
    data = np.frombuffer(path.read_bytes(), dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    return image


def rectification_maps(raw: RawCamera, image_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """``(map_u, map_v)``, each (H, W) float32: the raw pixel each pixel of the rectified image of size
    ``image_size`` = (W, H) comes from (module docstring), for :func:`rectify_image`."""
    import cv2

    width, height = (int(v) for v in image_size)
    return cv2.initUndistortRectifyMap(np.asarray(raw.raw_K, np.float64), np.asarray(raw.raw_D, np.float64),
                                       np.asarray(raw.rect_R_cam, np.float64),
                                       np.asarray(raw.P_rect, np.float64)[:, :3], (width, height), cv2.CV_32FC1)


def rectify_image(raw_image: np.ndarray, maps: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The rectified image of ``raw_image`` (H', W', 3) through :func:`rectification_maps`; rectified pixels whose
    ray leaves the raw image are black."""
    import cv2

    return cv2.remap(raw_image, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
