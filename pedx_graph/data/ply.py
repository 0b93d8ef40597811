"""Point-cloud PLY files of the release: LiDAR scenes and per-instance segments.

Layout (relative to the dataset root, the folder holding ``labels/``):

* ``pointclouds/<seq>/<seq>_<frame:07d>.ply`` -- the full LiDAR scene of one frame;
* ``labels/3d/segment/<seq>/<seq>_<frame:07d>_<tid>.ply`` -- the LiDAR points of one pedestrian.

Both hold a ``vertex`` element with float properties ``x``, ``y``, ``z`` (metres, LiDAR frame); other
properties (intensity, ...) and other elements are ignored.  The scene files may contain ``inf`` points,
which are masked out on reading.

A small own parser is used instead of trimesh: trimesh returns an empty ``Scene`` (no vertices) for a
PLY with zero vertices, which is a legitimate segment, and its exporter stores float32 only.
Supported encodings: ``ascii``, ``binary_little_endian`` and ``binary_big_endian``.
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from pedx_graph.data.types import DataFormatError
from pedx_graph.utils import atomic_write_bytes

logger = logging.getLogger(__name__)

#: PLY scalar type names -> numpy dtype (without byte order).
_PLY_TYPES: dict[str, str] = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}

_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


def segment_path(root: str | os.PathLike, sequence: str, frame: int, tracking_id: str) -> Path:
    """``<root>/labels/3d/segment/<seq>/<seq>_<frame:07d>_<tid>.ply`` (root: folder holding ``labels/``)."""
    return Path(root) / "labels" / "3d" / "segment" / sequence / f"{sequence}_{int(frame):07d}_{tracking_id}.ply"


def pointcloud_path(root: str | os.PathLike, sequence: str, frame: int) -> Path:
    """``<root>/pointclouds/<seq>/<seq>_<frame:07d>.ply`` -- the full LiDAR scene of one frame."""
    return Path(root) / "pointclouds" / sequence / f"{sequence}_{int(frame):07d}.ply"


def _parse_header(path: Path, data: bytes) -> tuple[str, list[tuple[str, int, list]], int]:
    """Parse a PLY header: (format, [(element, count, [(prop, type | ('list', count_t, item_t))])], body offset)."""
    if not data.startswith(b"ply"):
        raise DataFormatError(path, "header", "not a PLY file (missing 'ply' magic)")
    end = data.find(b"end_header")
    if end < 0:
        raise DataFormatError(path, "header", "no 'end_header' line")
    newline = data.find(b"\n", end)
    if newline < 0:
        raise DataFormatError(path, "header", "truncated after 'end_header'")
    body_offset = newline + 1
    try:
        header = data[:end].decode("ascii")
    except UnicodeDecodeError as exc:
        raise DataFormatError(path, "header", "header is not ASCII") from exc
    fmt = None
    elements: list[tuple[str, int, list]] = []
    for lineno, raw in enumerate(header.splitlines()[1:], start=2):
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) < 2 or words[1] not in _FORMATS:
                raise DataFormatError(path, "format", f"unsupported PLY format line {raw.strip()!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit() or len(words[2].lstrip("0")) > 15:
                raise DataFormatError(path, "element", f"bad element line {lineno}: {raw.strip()[:80]!r}")
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise DataFormatError(path, "property", f"property before any element (line {lineno})")
            if words[-1] in {prop for prop, _ in elements[-1][2]}:
                raise DataFormatError(path, words[-1], f"property appears twice in element "
                                                       f"'{elements[-1][0]}' (line {lineno})")
            if len(words) == 5 and words[1] == "list":
                if words[2] not in _PLY_TYPES or words[3] not in _PLY_TYPES:
                    raise DataFormatError(path, words[4], f"unknown list property types on line {lineno}")
                elements[-1][2].append((words[4], ("list", words[2], words[3])))
            elif len(words) == 3 and words[1] in _PLY_TYPES:
                elements[-1][2].append((words[2], words[1]))
            else:
                raise DataFormatError(path, "property", f"bad property line {lineno}: {raw.strip()!r}")
        else:
            raise DataFormatError(path, "header", f"unknown header keyword on line {lineno}: {words[0]!r}")
    if fmt is None:
        raise DataFormatError(path, "format", "no 'format' line in the header")
    return fmt, elements, body_offset


def read_ply_vertices(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """All scalar properties of the ``vertex`` element of a PLY file, as 1-D arrays keyed by property name.

    Elements before ``vertex`` are skipped (binary list properties there are not supported); elements
    after it are not read.  Raises :class:`DataFormatError` naming the file and the offending field.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DataFormatError(path, None, f"cannot read file ({exc.strerror or exc})") from exc
    fmt, elements, offset = _parse_header(path, data)
    order = _FORMATS[fmt]
    if fmt == "ascii":
        lines = data[offset:].decode("ascii", errors="replace").splitlines()
        lines = [ln for ln in lines if ln.strip()]
        pos = 0
    for name, count, props in elements:
        is_vertex = name == "vertex"
        has_list = any(isinstance(t, tuple) for _, t in props)
        if fmt == "ascii":
            if not is_vertex:
                pos += count
                continue
            rows = lines[pos:pos + count]
            if len(rows) < count:
                raise DataFormatError(path, "vertex", f"expected {count} vertex lines, found {len(rows)}")
            if has_list:
                raise DataFormatError(path, "vertex", "list properties in the vertex element are not supported")
            table = np.zeros((count, len(props)))
            for i, row in enumerate(rows):
                words = row.split()
                if len(words) != len(props):
                    raise DataFormatError(path, "vertex", f"expected {len(props)} values per vertex line, "
                                                          f"found {len(words)} (vertex {i})")
                try:
                    table[i] = [float(w) for w in words]
                except ValueError as exc:
                    raise DataFormatError(path, "vertex", f"non-numeric vertex value ({exc})") from exc
            out = {}
            for i, (prop, ply_type) in enumerate(props):
                dtype = np.dtype(_PLY_TYPES[ply_type])
                column = table[:, i]
                if dtype.kind in "iu":      # integer properties: whole numbers inside the type's range
                    info = np.iinfo(dtype)
                    bad = ~np.isfinite(column) | (column != np.round(column)) | (column < info.min) \
                        | (column > info.max)
                    if bad.any():
                        raise DataFormatError(path, prop, f"value {float(column[bad][0])!r} is not a {ply_type}")
                out[prop] = column.astype(dtype)
            return out
        if has_list:
            raise DataFormatError(path, name, "binary list properties before the vertex element are not supported")
        dtype = np.dtype([(p, order + _PLY_TYPES[t]) for p, t in props])
        nbytes = dtype.itemsize * count
        if offset + nbytes > len(data):
            raise DataFormatError(path, name, f"file truncated: element needs {nbytes} bytes, "
                                              f"{len(data) - offset} left")
        if is_vertex:
            table = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
            return {p: table[p].astype(table[p].dtype.newbyteorder("=")) for p, _ in props}
        offset += nbytes
    raise DataFormatError(path, "vertex", "no 'vertex' element")


def read_ply_points(path: str | os.PathLike, mask_nonfinite: bool = True) -> np.ndarray:
    """(N, 3) float64 ``x, y, z`` of a point PLY; rows with any non-finite coordinate dropped when asked.

    Raises :class:`DataFormatError` when the file is malformed or lacks one of ``x``, ``y``, ``z``.
    """
    vertices = read_ply_vertices(path)
    for axis in ("x", "y", "z"):
        if axis not in vertices:
            raise DataFormatError(path, axis, f"vertex property '{axis}' missing (have {sorted(vertices)})")
    with np.errstate(invalid="ignore"):     # a signalling NaN (a binary float's bits) is quieted: no warning
        points = np.stack([vertices["x"], vertices["y"], vertices["z"]], axis=-1).astype(np.float64)
    if mask_nonfinite:
        finite = np.all(np.isfinite(points), axis=1)
        if not finite.all():
            logger.debug("%s: masked %d non-finite points of %d", path, int((~finite).sum()), len(points))
            points = points[finite]
    return points


def encode_ply_points(points: np.ndarray, binary: bool = True, dtype: str = "float64") -> bytes:
    """Encode (N, 3) points as a PLY (``binary_little_endian`` or ``ascii``) with ``x, y, z`` of ``dtype``."""
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {points.shape}")
    ply_type = {"float32": "float", "float64": "double"}.get(str(np.dtype(dtype)))
    if ply_type is None:
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    fmt = "binary_little_endian" if binary else "ascii"
    header = (f"ply\nformat {fmt} 1.0\ncomment pedx-graph\nelement vertex {len(points)}\n"
              f"property {ply_type} x\nproperty {ply_type} y\nproperty {ply_type} z\nend_header\n")
    if binary:
        body = points.astype("<" + np.dtype(dtype).str[1:]).tobytes()
    else:
        body = "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in points.astype(dtype).astype(float).tolist())
        body = body.encode("ascii")
    return header.encode("ascii") + body


def write_ply_points(path: str | os.PathLike, points: np.ndarray, binary: bool = True,
                     dtype: str = "float64") -> Path:
    """Write (N, 3) points as a PLY atomically (binary little endian by default, float64 by default)."""
    return atomic_write_bytes(path, encode_ply_points(points, binary=binary, dtype=dtype))
