"""KITTI-style calibration files of the release (``calib/``): reading, validation and writing.

Each file holds one ``key: values`` per line.  Two kinds are used per stereo pair ``<left>-<right>``:

``calib_cam_to_cam_<left>-<right>.txt`` (KITTI raw's ``calib_cam_to_cam.txt``; index 00 = left, 01 = right)
    ``S_rect_00`` (w h), ``R_rect_00`` (3x3, row-major), ``P_rect_00`` (3x4), and the same for ``01``.
    ``P_rect_01`` applies to points in the rectified *left* frame and carries ``-f * baseline`` in
    ``[0, 3]``.  The raw image model ``K_0x`` (3x3) and ``D_0x`` (OpenCV radial-tangential, 4/5/8/12/14
    values) is kept when both are present (:class:`~pedx_graph.data.types.RawCamera`, used to undistort
    detections made on raw images), with the raw image size ``S_0x`` when given.  Other KITTI keys (``R_xx``,
    ``T_xx``, ``calib_time``, ...) are accepted and ignored.

``calib_cam_to_range_<left>.txt``
    ``R`` (3x3) and ``T`` (3), or ``Tr`` (3x4): ``range_p = R @ cam_p + T``, i.e. ``world_T_cam``
    mapping the left camera frame into the LiDAR (range) frame.

Required keys: ``P_rect_00``, ``P_rect_01``, ``R_rect_00`` and either ``R``+``T`` or ``Tr``.
``S_rect_00`` falls back to the known release image size of the left camera (with a warning).

Sanity at load (:class:`CalibrationLimits`): every value finite; ``P_rect_0x`` a rectified projection (third
row ``0 0 1``, no skew) whose focal lengths give a field of view of 5-170 degrees along each image axis and
whose principal point lies near the image; the right camera's ``P_rect_01`` with the left's focal lengths and
image rows (a rectified pair); the baseline 1 cm - 5 m; ``R_rect_0x`` and ``R`` rotations (orthonormal,
det +1); the left camera within 20 m of the LiDAR origin.  Each failure raises :class:`DataFormatError`
naming the file and the key, e.g. ``calib/calib_cam_to_cam_ylw79D0-red707B.txt: field 'P_rect_01': ...``.
"""
from __future__ import annotations

import logging
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pedx_graph.data.types import DataFormatError, RawCamera, StereoCalibration
from pedx_graph.utils import atomic_write_text

logger = logging.getLogger(__name__)

#: Rectified image sizes (width, height) of the release cameras (pedx-format notes).
RELEASE_IMAGE_SIZES: dict[str, tuple[int, int]] = {
    "blu79CF": (3645, 2687), "grn43E3": (3645, 2687),
    "ylw79D0": (3678, 2668), "red707B": (3678, 2668),
}

#: Tolerance on ``|R^T R - I|`` (max abs entry) and ``|det R - 1|`` for rotations read from text.
ROTATION_TOL = 1e-4

#: Largest accepted image side, pixels (the release's are 3645-3678 wide).
MAX_IMAGE_SIDE_PX = 100_000


@dataclass
class CalibrationLimits:
    """What a calibration file may hold and still be read (:func:`read_cam_to_cam`, :func:`read_cam_to_range`).

    The defaults accept any ordinary rig (the release's cameras have a 57-59 degree horizontal field of view,
    baselines of 0.27-0.33 m, left cameras 2.3-2.4 m from the LiDAR origin) and refuse the absurd: a focal
    length of 1e-9 px, a baseline of 100 m, an extrinsic moved 100 m, a rotation that is not one.
    """

    min_fov_deg: float = 5.0
    """Smallest field of view along each image axis, degrees (``2 atan(size / 2 f)``; 5 degrees of a 3678 px
    wide image is a 42,000 px focal length, a long telephoto)."""
    max_fov_deg: float = 170.0
    """Largest field of view along each image axis, degrees (a pinhole model past ~170 degrees is no model)."""
    principal_point_margin: float = 0.5
    """The principal point may lie outside the image by at most this fraction of the image size."""
    rectified_focal_rel_tol: float = 1e-3
    """``P_rect_01``'s focal lengths may differ from ``P_rect_00``'s by this fraction (rounding in the file)."""
    rectified_row_tol_px: float = 2.0
    """``P_rect_01``'s principal row may differ from ``P_rect_00``'s by this many pixels; more and the rows of
    the two images do not correspond (not a rectified pair).  The principal columns may differ (a disparity
    offset, which ``P_rect_01`` carries)."""
    min_baseline_m: float = 0.01
    """Shortest stereo baseline ``-P_rect_01[0, 3] / P_rect_01[0, 0]``, metres."""
    max_baseline_m: float = 5.0
    """Longest stereo baseline, metres (two cameras of one pair on one vehicle)."""
    max_camera_distance_m: float | None = 20.0
    """Largest distance of a left camera from the origin of the LiDAR (world) frame, metres: the frame is the
    LiDAR's, on the same vehicle.  None: no limit (a dataset moved into another world frame on purpose)."""
    rotation_tol: float = ROTATION_TOL
    """Tolerance on ``max |R^T R - I|`` and ``|det R - 1|`` of every rotation read (``R_rect_0x``, ``R``)."""

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


def _check_rotation(rot: np.ndarray, path, key: str, tol: float = ROTATION_TOL) -> np.ndarray:
    with np.errstate(over="ignore", invalid="ignore"):     # huge entries: inf / nan, refused below
        err = np.abs(rot.T @ rot - np.eye(3)).max()
        det = np.linalg.det(rot)
    if not (err <= tol and abs(det - 1.0) <= tol):
        raise DataFormatError(path, key, f"not a rotation (max |R^T R - I| = {err:.2e}, det = {det:.6f})")
    # Remove the rounding of the text file: nearest rotation (polar decomposition).
    u, _, vt = np.linalg.svd(rot)
    return u @ vt


def _fov_deg(size_px: float, focal_px: float) -> float:
    return math.degrees(2.0 * math.atan2(size_px / 2.0, focal_px))


def check_rectified_projection(P: np.ndarray, image_size: tuple[int, int], path, key: str,
                               limits: CalibrationLimits) -> None:
    """A rectified KITTI projection ``[[fx, 0, cx, *], [0, fy, cy, *], [0, 0, 1, *]]`` whose focal lengths give a
    field of view within the limits and whose principal point lies near the ``(width, height)`` image;
    :class:`DataFormatError` naming ``path`` and ``key`` otherwise."""
    width, height = image_size
    fx, fy, cx, cy = P[0, 0], P[1, 1], P[0, 2], P[1, 2]
    if np.max(np.abs(P[2, :3] - [0.0, 0.0, 1.0])) > 1e-6:
        raise DataFormatError(path, key, f"third row must start with 0 0 1 (a rectified projection), "
                                         f"got {P[2, 0]:g} {P[2, 1]:g} {P[2, 2]:g}")
    if not (fx > 0 and fy > 0):
        raise DataFormatError(path, key, f"focal lengths must be positive, got fx = {fx:g}, fy = {fy:g} px")
    if abs(P[1, 0]) > 1e-6 * fy or abs(P[0, 1]) > 1e-3 * fx:
        raise DataFormatError(path, key, f"not a rectified projection (skew {P[0, 1]:g}, P[1, 0] = {P[1, 0]:g})")
    for axis, size, focal in (("horizontal", width, fx), ("vertical", height, fy)):
        fov = _fov_deg(size, focal)
        if not limits.min_fov_deg <= fov <= limits.max_fov_deg:
            raise DataFormatError(path, key, f"focal length {focal:g} px gives a {axis} field of view of "
                                             f"{fov:.3g} degrees over {size} px, outside "
                                             f"{limits.min_fov_deg:g}-{limits.max_fov_deg:g} degrees")
    margin = limits.principal_point_margin
    if not (-margin * width <= cx <= (1 + margin) * width and -margin * height <= cy <= (1 + margin) * height):
        raise DataFormatError(path, key, f"principal point ({cx:g}, {cy:g}) px lies far outside the "
                                         f"{width}x{height} image")


def read_cam_to_cam(path: str | os.PathLike, left_camera: str | None = None,
                    limits: CalibrationLimits | None = None) -> dict:
    """Parse and check a ``calib_cam_to_cam_<left>-<right>.txt`` file (module docstring: sanity at load).

    Returns a dict with ``left_P_rect`` (3, 4), ``right_P_rect`` (3, 4), ``rect_R_cam`` (3, 3, the left
    camera's ``R_rect_00``), ``right_rect_R_cam`` (3, 3 or None) and ``image_size`` (width, height).
    ``left_camera`` names the camera for the ``S_rect_00`` fallback.
    """
    limits = limits or CalibrationLimits()
    path = Path(path)
    entries = read_kitti_text(path)
    left_P = get_floats(entries, "P_rect_00", 12, path, (3, 4))
    right_P = get_floats(entries, "P_rect_01", 12, path, (3, 4))
    rect_R = _check_rotation(get_floats(entries, "R_rect_00", 9, path, (3, 3)), path, "R_rect_00",
                             limits.rotation_tol)
    right_rect_R = None
    if "R_rect_01" in entries:
        right_rect_R = _check_rotation(get_floats(entries, "R_rect_01", 9, path, (3, 3)), path, "R_rect_01",
                                       limits.rotation_tol)
    if "S_rect_00" in entries:
        size = get_floats(entries, "S_rect_00", 2, path)
        if np.any(size <= 0) or np.any(size > MAX_IMAGE_SIDE_PX) or np.any(size != np.round(size)):
            raise DataFormatError(path, "S_rect_00", f"image size must be two positive integers up to "
                                                     f"{MAX_IMAGE_SIDE_PX}, got {size}")
        image_size = (int(size[0]), int(size[1]))
    elif left_camera in RELEASE_IMAGE_SIZES:
        image_size = RELEASE_IMAGE_SIZES[left_camera]
        logger.warning("%s: field 'S_rect_00' missing; using the release image size %s of %s",
                       path, image_size, left_camera)
    else:
        raise DataFormatError(path, "S_rect_00", "required key missing (and the camera's size is not known)")
    if "S_rect_01" in entries:
        size_right = get_floats(entries, "S_rect_01", 2, path)
        if tuple(float(v) for v in size_right) != tuple(float(v) for v in image_size):
            logger.warning("%s: field 'S_rect_01' %s differs from S_rect_00 %s; using S_rect_00",
                           path, size_right, image_size)
    check_rectified_projection(left_P, image_size, path, "P_rect_00", limits)
    check_rectified_projection(right_P, image_size, path, "P_rect_01", limits)
    for index, name in ((0, "fx"), (1, "fy")):
        left_f, right_f = left_P[index, index], right_P[index, index]
        if abs(right_f - left_f) > limits.rectified_focal_rel_tol * left_f:
            raise DataFormatError(path, "P_rect_01", f"{name} = {right_f:g} px differs from P_rect_00's "
                                                     f"{left_f:g} px: not a rectified pair")
    if abs(right_P[1, 2] - left_P[1, 2]) > limits.rectified_row_tol_px:
        raise DataFormatError(path, "P_rect_01", f"principal row cy = {right_P[1, 2]:g} px differs from "
                                                 f"P_rect_00's {left_P[1, 2]:g} px: not a rectified pair")
    if abs(right_P[0, 2] - left_P[0, 2]) > 1e-6 * left_P[0, 0]:
        logger.warning("%s: field 'P_rect_01': principal column %g px differs from P_rect_00's %g px "
                       "(a disparity offset; used as written)", path, right_P[0, 2], left_P[0, 2])
    baseline = -(right_P[0, 3] - left_P[0, 3]) / right_P[0, 0]
    if not limits.min_baseline_m <= baseline <= limits.max_baseline_m:
        raise DataFormatError(path, "P_rect_01", f"baseline -P[0,3]/P[0,0] = {baseline:g} m, outside "
                                                 f"{limits.min_baseline_m:g}-{limits.max_baseline_m:g} m")
    left_raw = _read_raw_camera(entries, path, "00", rect_R, left_P)
    right_raw = _read_raw_camera(entries, path, "01", right_rect_R, right_P)
    return {"left_P_rect": left_P, "right_P_rect": right_P, "rect_R_cam": rect_R,
            "right_rect_R_cam": right_rect_R, "image_size": image_size,
            "left_raw": left_raw, "right_raw": right_raw}


def _read_raw_camera(entries: dict[str, str], path, index: str, rect_R: np.ndarray | None,
                     P_rect: np.ndarray) -> RawCamera | None:
    """``K_<index>`` + ``D_<index>`` (+ the rectification) as a :class:`RawCamera`; None when a key is absent."""
    if f"K_{index}" not in entries or f"D_{index}" not in entries or rect_R is None:
        return None
    raw_K = get_floats(entries, f"K_{index}", 9, path, (3, 3))
    if not (raw_K[0, 0] > 0 and raw_K[1, 1] > 0 and np.allclose(raw_K[2], [0.0, 0.0, 1.0])
            and raw_K[1, 0] == 0 and raw_K[2, 0] == 0):
        raise DataFormatError(path, f"K_{index}", "not an intrinsic matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]] "
                                                  "with positive focal lengths")
    count = len(entries[f"D_{index}"].split())
    if count not in (4, 5, 8, 12, 14):
        raise DataFormatError(path, f"D_{index}", f"expected 4, 5, 8, 12 or 14 distortion coefficients, "
                                                  f"found {count}")
    raw_D = get_floats(entries, f"D_{index}", count, path)
    size = None
    if f"S_{index}" in entries:
        values = get_floats(entries, f"S_{index}", 2, path)
        if not (np.all(values >= 1) and np.all(values == np.round(values))):
            raise DataFormatError(path, f"S_{index}", f"raw image size must be two positive integers, got {values}")
        size = (int(values[0]), int(values[1]))
    return RawCamera(raw_K=raw_K, raw_D=raw_D, rect_R_cam=rect_R, P_rect=P_rect, image_size=size)


def read_cam_to_range(path: str | os.PathLike, limits: CalibrationLimits | None = None) -> np.ndarray:
    """(4, 4) ``world_T_cam`` from a ``calib_cam_to_range_<left>.txt`` (``R`` + ``T``, or ``Tr``): ``R`` a
    rotation, the camera within ``limits.max_camera_distance_m`` of the LiDAR origin."""
    limits = limits or CalibrationLimits()
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
    world_T_cam[:3, :3] = _check_rotation(rot, path, rot_key, limits.rotation_tol)
    distance = float(np.linalg.norm(trans))
    if limits.max_camera_distance_m is not None and distance > limits.max_camera_distance_m:
        raise DataFormatError(path, "T" if rot_key == "R" else "Tr",
                              f"the camera is {distance:.4g} m from the LiDAR origin (at most "
                              f"{limits.max_camera_distance_m:g} m on one vehicle)")
    world_T_cam[:3, 3] = trans
    return world_T_cam


def read_stereo_calibration(calib_dir: str | os.PathLike, pair: str,
                            limits: CalibrationLimits | None = None) -> StereoCalibration:
    """The :class:`StereoCalibration` of pair ``<left>-<right>`` from the two files in ``calib_dir`` (a missing
    file is a :class:`DataFormatError` naming it)."""
    left, _ = split_pair(pair)
    for path in (cam_to_cam_path(calib_dir, pair), cam_to_range_path(calib_dir, pair)):
        if not path.is_file():
            raise DataFormatError(path, None, f"missing: stereo pair {pair} needs it")
    parsed = read_cam_to_cam(cam_to_cam_path(calib_dir, pair), left_camera=left, limits=limits)
    world_T_cam = read_cam_to_range(cam_to_range_path(calib_dir, pair), limits=limits)
    return StereoCalibration(name=pair, left_P_rect=parsed["left_P_rect"], right_P_rect=parsed["right_P_rect"],
                             rect_R_cam=parsed["rect_R_cam"], world_T_cam=world_T_cam,
                             image_size=parsed["image_size"], left_raw=parsed["left_raw"],
                             right_raw=parsed["right_raw"])


def read_calibrations(calib_dir: str | os.PathLike, limits: CalibrationLimits | None = None,
                      errors: dict[str, str] | None = None) -> dict[str, StereoCalibration]:
    """Every stereo pair found in ``calib_dir`` (see :func:`discover_pairs`).

    A pair whose files are missing, malformed or fail the sanity checks (``limits``) is skipped with a warning
    naming file and field, and its message is put into ``errors`` (pair name -> message) when given; raises
    :class:`DataFormatError` when no pair at all can be read.
    """
    calib_dir = Path(calib_dir)
    if not calib_dir.is_dir():
        raise DataFormatError(calib_dir, None, "calibration folder missing (it holds the "
                                               "'calib_cam_to_cam_<left>-<right>.txt' files)")
    pairs = discover_pairs(calib_dir)
    if not pairs:
        raise DataFormatError(calib_dir, None, "no 'calib_cam_to_cam_<left>-<right>.txt' file found")
    calibrations: dict[str, StereoCalibration] = {}
    failed: dict[str, str] = {}
    for pair in pairs:
        try:
            calibrations[pair] = read_stereo_calibration(calib_dir, pair, limits)
        except DataFormatError as exc:
            logger.warning("skipping stereo pair %s: %s", pair, exc)
            failed[pair] = str(exc)
    if errors is not None:
        errors.update(failed)
    if not calibrations:
        raise DataFormatError(calib_dir, None, "no stereo pair could be read: " + "; ".join(failed.values()))
    return calibrations


def _fmt(values: np.ndarray) -> str:
    return " ".join(f"{float(v)!r}" for v in np.asarray(values, dtype=np.float64).ravel())


def format_cam_to_cam(calib: StereoCalibration, right_rect_R_cam: np.ndarray | None = None) -> str:
    """Text of ``calib_cam_to_cam_<pair>.txt``.

    ``right_rect_R_cam`` is ``R_rect_01``; by default the left one (an ideal rig whose two cameras share
    one orientation, as simulated).  Floats are written with ``repr`` so reading back is exact.
    """
    if right_rect_R_cam is None:
        right_rect_R_cam = calib.right_raw.rect_R_cam if calib.right_raw is not None else calib.rect_R_cam
    width, height = calib.image_size
    lines = [
        f"S_rect_00: {float(width)!r} {float(height)!r}",
        f"R_rect_00: {_fmt(calib.rect_R_cam)}",
        f"P_rect_00: {_fmt(calib.left_P_rect)}",
        f"S_rect_01: {float(width)!r} {float(height)!r}",
        f"R_rect_01: {_fmt(right_rect_R_cam)}",
        f"P_rect_01: {_fmt(calib.right_P_rect)}",
    ]
    for index, raw in (("00", calib.left_raw), ("01", calib.right_raw)):
        if raw is not None:
            lines += [f"K_{index}: {_fmt(raw.raw_K)}", f"D_{index}: {_fmt(raw.raw_D)}"]
            if raw.image_size is not None:
                lines.append(f"S_{index}: {float(raw.image_size[0])!r} {float(raw.image_size[1])!r}")
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
