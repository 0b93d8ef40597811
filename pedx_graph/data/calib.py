"""KITTI-style calibration files of the release (``calib/``): reading, validation and writing.

Each file holds one ``key: values`` per line.  Two kinds are used per stereo pair ``<left>-<right>``:

``calib_cam_to_cam_<left>-<right>.txt`` (KITTI raw's ``calib_cam_to_cam.txt``; index 00 = left, 01 = right)
    ``S_rect_00`` (w h), ``R_rect_00`` (3x3, row-major), ``P_rect_00`` (3x4), and the same for ``01``.
    ``P_rect_01`` applies to points in the rectified *left* frame and carries ``-f * baseline`` in
    ``[0, 3]``.  Other KITTI keys (``S_xx``, ``K_xx``, ``D_xx``, ``R_xx``, ``T_xx``, ``calib_time``, ...)
    are accepted and ignored.

``calib_cam_to_range_<left>.txt``
    ``R`` (3x3) and ``T`` (3), or ``Tr`` (3x4): ``range_p = R @ cam_p + T``, i.e. ``world_T_cam``
    mapping the left camera frame into the LiDAR (range) frame.

Required keys: ``P_rect_00``, ``P_rect_01``, ``R_rect_00`` and either ``R``+``T`` or ``Tr``.
``S_rect_00`` falls back to the known release image size of the left camera (with a warning).
"""
from __future__ import annotations

import logging
import os
import re
from pathlib import Path

import numpy as np

from pedx_graph.data.types import DataFormatError, StereoCalibration
from pedx_graph.utils import atomic_write_text

logger = logging.getLogger(__name__)

#: Rectified image sizes (width, height) of the release cameras (pedx-format notes).
RELEASE_IMAGE_SIZES: dict[str, tuple[int, int]] = {
    "blu79CF": (3645, 2687), "grn43E3": (3645, 2687),
    "ylw79D0": (3678, 2668), "red707B": (3678, 2668),
}

#: Tolerance on ``|R^T R - I|`` (max abs entry) and ``|det R - 1|`` for rotations read from text.
ROTATION_TOL = 1e-4

_CAM_TO_CAM_RE = re.compile(r"^calib_cam_to_cam_(?P<left>[^-]+)-(?P<right>[^-]+)\.txt$")


def cam_to_cam_path(calib_dir: str | os.PathLike, pair: str) -> Path:
    """``<calib_dir>/calib_cam_to_cam_<left>-<right>.txt``."""
    return Path(calib_dir) / f"calib_cam_to_cam_{pair}.txt"


def cam_to_range_path(calib_dir: str | os.PathLike, pair: str) -> Path:
    """``<calib_dir>/calib_cam_to_range_<left>.txt`` for pair ``<left>-<right>``."""
    return Path(calib_dir) / f"calib_cam_to_range_{split_pair(pair)[0]}.txt"


def split_pair(pair: str) -> tuple[str, str]:
    """``"<left>-<right>"`` -> ``(left, right)``; camera names contain no ``-``."""
    parts = pair.split("-")
    if len(parts) != 2 or not all(parts):
        raise ValueError(f"stereo pair name must be '<left>-<right>', got {pair!r}")
    return parts[0], parts[1]


def discover_pairs(calib_dir: str | os.PathLike) -> list[str]:
    """Sorted pair names ``<left>-<right>`` of the ``calib_cam_to_cam_*.txt`` files in ``calib_dir``."""
    calib_dir = Path(calib_dir)
    if not calib_dir.is_dir():
        return []
    pairs = []
    for path in sorted(calib_dir.iterdir()):
        match = _CAM_TO_CAM_RE.match(path.name)
        if match:
            pairs.append(f"{match['left']}-{match['right']}")
    return pairs


def read_kitti_text(path: str | os.PathLike) -> dict[str, str]:
    """Raw ``key -> value text`` of a KITTI-style file (blank lines and ``#`` comments skipped).

    Values are kept as text (``calib_time`` is not numeric); convert with :func:`get_floats`.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise DataFormatError(path, None, f"cannot read calibration file ({exc.strerror or exc})") from exc
    entries: dict[str, str] = {}
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        if ":" not in stripped:
            raise DataFormatError(path, f"line {lineno}", f"expected 'key: values', got {stripped[:60]!r}")
        key, value = stripped.split(":", 1)
        key = key.strip()
        if key in entries:
            raise DataFormatError(path, key, f"key appears twice (second time on line {lineno})")
        entries[key] = value.strip()
    return entries


def get_floats(entries: dict[str, str], key: str, count: int, path: str | os.PathLike,
               shape: tuple[int, ...] | None = None) -> np.ndarray:
    """The ``count`` finite floats of ``key`` (reshaped to ``shape``); :class:`DataFormatError` otherwise."""
    if key not in entries:
        raise DataFormatError(path, key, "required key missing")
    words = entries[key].split()
    try:
        values = np.array([float(w) for w in words], dtype=np.float64)
    except ValueError as exc:
        raise DataFormatError(path, key, f"non-numeric value ({exc})") from exc
    if values.size != count:
        raise DataFormatError(path, key, f"expected {count} floats, found {values.size}")
    if not np.all(np.isfinite(values)):
        raise DataFormatError(path, key, "non-finite value")
    return values.reshape(shape) if shape is not None else values


def _check_rotation(rot: np.ndarray, path, key: str) -> np.ndarray:
    err = np.abs(rot.T @ rot - np.eye(3)).max()
    det = np.linalg.det(rot)
    if err > ROTATION_TOL or abs(det - 1.0) > ROTATION_TOL:
        raise DataFormatError(path, key, f"not a rotation (max |R^T R - I| = {err:.2e}, det = {det:.6f})")
    # Remove the rounding of the text file: nearest rotation (polar decomposition).
    u, _, vt = np.linalg.svd(rot)
    return u @ vt


def read_cam_to_cam(path: str | os.PathLike, left_camera: str | None = None) -> dict:
    """Parse a ``calib_cam_to_cam_<left>-<right>.txt`` file.

    Returns a dict with ``left_P_rect`` (3, 4), ``right_P_rect`` (3, 4), ``rect_R_cam`` (3, 3, the left
    camera's ``R_rect_00``), ``right_rect_R_cam`` (3, 3 or None) and ``image_size`` (width, height).
    ``left_camera`` names the camera for the ``S_rect_00`` fallback.
    """
    path = Path(path)
    entries = read_kitti_text(path)
    left_P = get_floats(entries, "P_rect_00", 12, path, (3, 4))
    right_P = get_floats(entries, "P_rect_01", 12, path, (3, 4))
    rect_R = _check_rotation(get_floats(entries, "R_rect_00", 9, path, (3, 3)), path, "R_rect_00")
    right_rect_R = None
    if "R_rect_01" in entries:
        right_rect_R = _check_rotation(get_floats(entries, "R_rect_01", 9, path, (3, 3)), path, "R_rect_01")
    if left_P[0, 0] <= 0 or left_P[1, 1] <= 0 or left_P[2, 2] == 0:
        raise DataFormatError(path, "P_rect_00", "focal lengths must be positive and P[2, 2] non-zero")
    if not np.allclose(right_P[:, :3], left_P[:, :3], rtol=1e-6, atol=1e-6):
        logger.warning("%s: field 'P_rect_01': intrinsic part differs from P_rect_00 (not a rectified pair?)",
                       path)
    baseline = -(right_P[0, 3] - left_P[0, 3]) / right_P[0, 0]
    if not baseline > 0:
        raise DataFormatError(path, "P_rect_01", f"baseline -P[0,3]/P[0,0] must be positive, got {baseline:g} m")
    if "S_rect_00" in entries:
        size = get_floats(entries, "S_rect_00", 2, path)
        if np.any(size <= 0) or np.any(size != np.round(size)):
            raise DataFormatError(path, "S_rect_00", f"image size must be two positive integers, got {size}")
        image_size = (int(size[0]), int(size[1]))
    elif left_camera in RELEASE_IMAGE_SIZES:
        image_size = RELEASE_IMAGE_SIZES[left_camera]
        logger.warning("%s: field 'S_rect_00' missing; using the release image size %s of %s",
                       path, image_size, left_camera)
    else:
        raise DataFormatError(path, "S_rect_00", "required key missing (and the camera's size is not known)")
    if "S_rect_01" in entries:
        size_right = get_floats(entries, "S_rect_01", 2, path)
        if tuple(int(v) for v in size_right) != image_size:
            logger.warning("%s: field 'S_rect_01' %s differs from S_rect_00 %s; using S_rect_00",
                           path, size_right, image_size)
    return {"left_P_rect": left_P, "right_P_rect": right_P, "rect_R_cam": rect_R,
            "right_rect_R_cam": right_rect_R, "image_size": image_size}


def read_cam_to_range(path: str | os.PathLike) -> np.ndarray:
    """(4, 4) ``world_T_cam`` from a ``calib_cam_to_range_<left>.txt`` (``R`` + ``T``, or ``Tr``)."""
    path = Path(path)
    entries = read_kitti_text(path)
    if "R" in entries or "T" in entries:
        rot = get_floats(entries, "R", 9, path, (3, 3))
        trans = get_floats(entries, "T", 3, path)
        rot_key = "R"
    elif "Tr" in entries:
        tr = get_floats(entries, "Tr", 12, path, (3, 4))
        rot, trans, rot_key = tr[:, :3], tr[:, 3], "Tr"
    else:
        raise DataFormatError(path, "R", "required key missing (need 'R' and 'T', or 'Tr')")
    world_T_cam = np.eye(4)
    world_T_cam[:3, :3] = _check_rotation(rot, path, rot_key)
    world_T_cam[:3, 3] = trans
    return world_T_cam


def read_stereo_calibration(calib_dir: str | os.PathLike, pair: str) -> StereoCalibration:
    """The :class:`StereoCalibration` of pair ``<left>-<right>`` from the two files in ``calib_dir``."""
    left, _ = split_pair(pair)
    parsed = read_cam_to_cam(cam_to_cam_path(calib_dir, pair), left_camera=left)
    world_T_cam = read_cam_to_range(cam_to_range_path(calib_dir, pair))
    return StereoCalibration(name=pair, left_P_rect=parsed["left_P_rect"], right_P_rect=parsed["right_P_rect"],
                             rect_R_cam=parsed["rect_R_cam"], world_T_cam=world_T_cam,
                             image_size=parsed["image_size"])


def read_calibrations(calib_dir: str | os.PathLike) -> dict[str, StereoCalibration]:
    """Every stereo pair found in ``calib_dir`` (see :func:`discover_pairs`).

    A pair whose files are malformed is skipped with a warning naming file and field; raises
    :class:`DataFormatError` when no pair at all can be read.
    """
    calib_dir = Path(calib_dir)
    pairs = discover_pairs(calib_dir)
    if not pairs:
        raise DataFormatError(calib_dir, None, "no 'calib_cam_to_cam_<left>-<right>.txt' file found")
    calibrations: dict[str, StereoCalibration] = {}
    errors = []
    for pair in pairs:
        try:
            calibrations[pair] = read_stereo_calibration(calib_dir, pair)
        except DataFormatError as exc:
            logger.warning("skipping stereo pair %s: %s", pair, exc)
            errors.append(str(exc))
    if not calibrations:
        raise DataFormatError(calib_dir, None, "no stereo pair could be read: " + "; ".join(errors))
    return calibrations


def _fmt(values: np.ndarray) -> str:
    return " ".join(f"{float(v)!r}" for v in np.asarray(values, dtype=np.float64).ravel())


def format_cam_to_cam(calib: StereoCalibration, right_rect_R_cam: np.ndarray | None = None) -> str:
    """Text of ``calib_cam_to_cam_<pair>.txt``.

    ``right_rect_R_cam`` is ``R_rect_01``; by default the left one (an ideal rig whose two cameras share
    one orientation, as simulated).  Floats are written with ``repr`` so reading back is exact.
    """
    if right_rect_R_cam is None:
        right_rect_R_cam = calib.rect_R_cam
    width, height = calib.image_size
    lines = [
        f"S_rect_00: {float(width)!r} {float(height)!r}",
        f"R_rect_00: {_fmt(calib.rect_R_cam)}",
        f"P_rect_00: {_fmt(calib.left_P_rect)}",
        f"S_rect_01: {float(width)!r} {float(height)!r}",
        f"R_rect_01: {_fmt(right_rect_R_cam)}",
        f"P_rect_01: {_fmt(calib.right_P_rect)}",
    ]
    return "\n".join(lines) + "\n"


def format_cam_to_range(calib: StereoCalibration) -> str:
    """Text of ``calib_cam_to_range_<left>.txt``: ``R`` and ``T`` of ``world_T_cam``."""
    world_T_cam = np.asarray(calib.world_T_cam, dtype=np.float64)
    return f"R: {_fmt(world_T_cam[:3, :3])}\nT: {_fmt(world_T_cam[:3, 3])}\n"


def write_stereo_calibration(calib_dir: str | os.PathLike, calib: StereoCalibration,
                             right_rect_R_cam: np.ndarray | None = None) -> tuple[Path, Path]:
    """Write the two calibration files of ``calib`` into ``calib_dir`` atomically; returns their paths."""
    split_pair(calib.name)
    p1 = atomic_write_text(cam_to_cam_path(calib_dir, calib.name), format_cam_to_cam(calib, right_rect_R_cam))
    p2 = atomic_write_text(cam_to_range_path(calib_dir, calib.name), format_cam_to_range(calib))
    return p1, p2
