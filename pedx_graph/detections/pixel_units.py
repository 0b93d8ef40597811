"""How a detector's keypoint coordinates map to the calibration's pixels: one definition, used by the simulator
to write them and by the import to read them back.

A detector's coordinates are pixels of the image it saw.  That image may be the calibrated camera's at its
own size (``S_rect_00``), or a resized copy of it (a 12 MP image shrunk before detection), and some tools
write coordinates normalised by the image's size instead of pixels (OpenPose's ``--keypoint_scale 3``: [0, 1]
from the top-left corner to the bottom-right one; ``4``: [-1, 1]).  With ``size`` the calibration's
``(width, height)`` in pixels and ``scale`` the ``(sx, sy)`` the detector's image was resized by::

    pixels:       x = sx * u
    unit:         x = sx * u / (sx * width)            = u / width
    signed_unit:  x = 2 * sx * u / (sx * width) - 1    = 2 u / width - 1

(``y`` alike with ``sy`` and ``height``); ``u`` the calibration's pixel.  Normalised coordinates carry no
scale: the resize cancels.
"""
from __future__ import annotations

import numpy as np

#: How coordinates may be expressed (``DetectorOutputConfig.pixel_units`` in the simulator; told from the
#: data by :mod:`pedx_graph.detections.pixel_scale` on import).
PIXEL_UNITS: tuple[str, ...] = ("pixels", "unit", "signed_unit")


def _check_units(units: str) -> None:
    if units not in PIXEL_UNITS:
        raise ValueError(f"pixel units must be one of {', '.join(PIXEL_UNITS)}, got {units!r}")


def to_detector_units(calib_uv: np.ndarray, size: tuple[float, float], scale: tuple[float, float] = (1.0, 1.0),
                      units: str = "pixels") -> np.ndarray:
    """(..., 2) calibration pixels -> the detector's coordinates (module docstring); NaN stays NaN."""
    _check_units(units)
    uv = np.asarray(calib_uv, dtype=float)
    if units == "pixels":
        return uv * np.asarray(scale, dtype=float)
    unit = uv / np.asarray(size, dtype=float)
    return unit if units == "unit" else 2.0 * unit - 1.0


def calibration_sized(image: np.ndarray, size: tuple[int, int], scale: tuple[float, float] | None) -> np.ndarray:
    """An image the detector saw, at the calibration's ``size`` (width, height): a copy resized by ``scale``
    (its pixels per calibration pixel; to within a pixel of rounding) is resized back, and with ``scale`` None
    (normalised coordinates, which say nothing of the image's size) any image of the calibration's aspect;
    another image is returned as it is."""
    import cv2

    height, width = image.shape[:2]
    if (width, height) == tuple(size):
        return image
    if scale is None:
        fits = abs(width / size[0] - height / size[1]) <= 1.0 / min(width, height)
    else:
        fits = abs(width - scale[0] * size[0]) <= 1.0 and abs(height - scale[1] * size[1]) <= 1.0
    return cv2.resize(image, (int(size[0]), int(size[1])), interpolation=cv2.INTER_LINEAR) if fits else image


def from_detector_units(det_uv: np.ndarray, size: tuple[float, float], scale: tuple[float, float] = (1.0, 1.0),
                        units: str = "pixels") -> np.ndarray:
    """(..., 2) the detector's coordinates -> calibration pixels: the inverse of :func:`to_detector_units`."""
    _check_units(units)
    xy = np.asarray(det_uv, dtype=float)
    if units == "pixels":
        return xy / np.asarray(scale, dtype=float)
    unit = xy if units == "unit" else (xy + 1.0) / 2.0
    return unit * np.asarray(size, dtype=float)
