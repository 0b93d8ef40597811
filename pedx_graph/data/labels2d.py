"""2D label JSON files of the release: one file per instance per image.

Layout (relative to the dataset root, the folder holding ``labels/``), both variants accepted:

* ``labels/2d/<seq>/<cam>/<seq>_<cam>_<frame:07d>_<tid>.json`` (the public loader's layout);
* ``labels/2d/<seq>/<seq>_<cam>_<frame:07d>_<tid>.json`` (flat, read by two third-party tools).

Sequence and camera names contain no ``_``; the tracking id is the rest of the name.  The file name is
authoritative for (sequence, camera, frame, tracking id): it is what links a 2D label to its segment and
SMPL files.  Fields of the JSON object:

``tracking_id`` (str), ``category`` (``pedestrian`` / ``vehicle``), ``subtype``, ``frame_id``,
``polygon``: list of ``[x, y]`` pixels (at least 3), or null;
``keypoint``: dict keyed by the 18 :data:`PEDX_KEYPOINTS` names, each ``{"x", "y", "visible"}``, or null.
Our own extension for imported detections (``pedx-graph import``): ``keypoint_set`` (absent = ``pedx18``;
else ``coco17``, ``coco18``, ``body25``, ``body25b``) names the set whose names key ``keypoint``, and each
entry may carry ``confidence`` (the detector's, [0, 1]) and ``sigma_px`` (its pixel noise per axis, > 0).
A missing name = not labelled; an entry that is null, or whose ``x`` and ``y`` are both null, is not
labelled either.  ``visible`` defaults to true when absent.  Unknown keypoint names are warned about and
ignored.  Any other malformation raises :class:`DataFormatError` naming the file and the field.

Against the image (:func:`screen_label`, applied by the reader, which knows the camera's image size): a keypoint
outside the image by more than a margin is dropped with a warning naming the file and the field; a label with
more than half of its keypoints outside (a 1e9 px click, every coordinate multiplied by 1e6) is skipped
whole with a warning; polygon vertices outside drop the polygon.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pedx_graph.data.jsonfile import read_json_file
from pedx_graph.data.types import PEDX_KEYPOINTS, DataFormatError, View2D
from pedx_graph.keypoints import keypoint_set_names, load_keypoint_set
from pedx_graph.utils import atomic_write_json

logger = logging.getLogger(__name__)

_KEYPOINT_INDEX = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}
_NAME_RE = re.compile(r"^(?P<cam>[^_]+)_(?P<frame>\d+)_(?P<tid>.+)\.json$")
_NAME_IN_CAM_RE = re.compile(r"^(?P<frame>\d+)_(?P<tid>.+)\.json$")


@dataclass
class Label2D:
    """One 2D label file: a single instance in a single rectified image."""

    sequence: str
    """Sequence name (from the file path)."""
    camera: str
    """Camera name, e.g. ``"ylw79D0"`` (from the file path)."""
    frame: int
    """Frame number (from the file name)."""
    tracking_id: str
    """Tracking id (from the file name; shared with the segment and SMPL files)."""
    category: str
    """``"pedestrian"`` or ``"vehicle"`` (any string is kept)."""
    view: View2D
    """Keypoints (all NaN when the file's ``keypoint`` is null) and polygon (None when null)."""
    subtype: str | None = None
    """The release's ``subtype`` field, kept verbatim (None when absent)."""
    frame_id: object = None
    """The file's ``frame_id`` field, kept verbatim (its format is undocumented)."""

    @property
    def n_labelled(self) -> int:
        """Number of keypoints with a 2D position."""
        return int(self.view.labelled.sum())


def label2d_path(root: str | os.PathLike, sequence: str, camera: str, frame: int, tracking_id: str,
                 flat: bool = False) -> Path:
    """Path of a 2D label file under ``root`` (the folder holding ``labels/``); ``flat``: no camera folder."""
    folder = Path(root) / "labels" / "2d" / sequence
    if not flat:
        folder = folder / camera
    return folder / f"{sequence}_{camera}_{int(frame):07d}_{tracking_id}.json"


def parse_label2d_name(path: str | os.PathLike, sequence: str,
                       camera: str | None = None) -> tuple[str, int, str] | None:
    """``(camera, frame, tracking_id)`` from a 2D label file name, or None when it does not match.

    ``camera``: the camera folder the file sits in (None for the flat layout).
    """
    name = Path(path).name
    prefix = f"{sequence}_"
    if not name.startswith(prefix):
        return None
    rest = name[len(prefix):]
    if camera is not None:
        if not rest.startswith(f"{camera}_"):
            return None
        match = _NAME_IN_CAM_RE.match(rest[len(camera) + 1:])
        return (camera, int(match["frame"]), match["tid"]) if match else None
    match = _NAME_RE.match(rest)
    return (match["cam"], int(match["frame"]), match["tid"]) if match else None


def iter_label2d_files(root: str | os.PathLike, sequence: str) -> Iterator[tuple[Path, str, int, str]]:
    """Yield ``(path, camera, frame, tracking_id)`` of every 2D label file of ``sequence`` (both layouts).

    Files whose name does not follow the pattern are skipped with a warning.  Sorted by path.
    """
    seq_dir = Path(root) / "labels" / "2d" / sequence
    if not seq_dir.is_dir():
        return
    for entry in sorted(seq_dir.iterdir()):
        if entry.is_dir():
            for path in sorted(entry.glob("*.json")):
                parsed = parse_label2d_name(path, sequence, entry.name)
                if parsed is None:
                    logger.warning("%s: file name does not match '%s_%s_<frame>_<tid>.json'; skipped",
                                   path, sequence, entry.name)
                    continue
                yield (path, *parsed)
        elif entry.suffix == ".json":
            parsed = parse_label2d_name(entry, sequence)
            if parsed is None:
                logger.warning("%s: file name does not match '%s_<cam>_<frame>_<tid>.json'; skipped",
                               entry, sequence)
                continue
            yield (entry, *parsed)


def _number(value, path, field: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        if isinstance(value, str):
            try:
                value = float(value)
            except ValueError:
                raise DataFormatError(path, field, f"not a number: {value!r}") from None
        else:
            raise DataFormatError(path, field, f"not a number: {value!r}")
    try:
        value = float(value)
    except OverflowError:           # an integer beyond the float range
        raise DataFormatError(path, field, "number out of the float range") from None
    if not np.isfinite(value):
        raise DataFormatError(path, field, f"non-finite value {value!r}")
    return value


def _flag(value, path, field: str) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, (int, float)) and value in (0, 1):
        return bool(value)
    if isinstance(value, str) and value.strip().lower() in ("true", "false", "0", "1"):
        return value.strip().lower() in ("true", "1")
    raise DataFormatError(path, field, f"not a boolean: {value!r}")


def parse_keypoints(data, path, names: tuple[str, ...] = PEDX_KEYPOINTS) -> tuple[np.ndarray, np.ndarray]:
    """(18, 2) pixels (NaN = not labelled) and (18,) visible flags from a ``keypoint`` value (dict or None);
    ``names``: the keypoint set's names (K of them) when not PedX's."""
    index_of = _KEYPOINT_INDEX if names is PEDX_KEYPOINTS else {n: i for i, n in enumerate(names)}
    keypoints = np.full((len(names), 2), np.nan)
    visible = np.zeros(len(names), dtype=bool)
    if data is None:
        return keypoints, visible
    if not isinstance(data, dict):
        raise DataFormatError(path, "keypoint", f"must be an object keyed by joint name or null, "
                                                f"got {type(data).__name__}")
    for name, entry in data.items():
        field = f"keypoint.{name}"
        index = index_of.get(name)
        if index is None:
            logger.warning("%s: field '%s': unknown keypoint name, ignored", path, field)
            continue
        if entry is None:
            continue
        if not isinstance(entry, dict):
            raise DataFormatError(path, field, f"must be an object {{x, y, visible}}, got {type(entry).__name__}")
        for axis in ("x", "y"):
            if axis not in entry:
                raise DataFormatError(path, f"{field}.{axis}", "missing")
        if entry["x"] is None and entry["y"] is None:
            continue
        keypoints[index, 0] = _number(entry["x"], path, f"{field}.x")
        keypoints[index, 1] = _number(entry["y"], path, f"{field}.y")
        visible[index] = _flag(entry.get("visible", True), path, f"{field}.visible")
    return keypoints, visible


def parse_polygon(data, path) -> np.ndarray | None:
    """(K, 2) float polygon (K >= 3) from a ``polygon`` value, or None when null or empty."""
    if data is None:
        return None
    if not isinstance(data, list):
        raise DataFormatError(path, "polygon", f"must be a list of [x, y] or null, got {type(data).__name__}")
    if not data:
        return None
    points = []
    for i, vertex in enumerate(data):
        if not isinstance(vertex, (list, tuple)) or len(vertex) != 2:
            raise DataFormatError(path, f"polygon[{i}]", f"must be [x, y], got {vertex!r}"[:120])
        points.append([_number(vertex[0], path, f"polygon[{i}].x"), _number(vertex[1], path, f"polygon[{i}].y")])
    if len(points) < 3:
        raise DataFormatError(path, "polygon", f"needs at least 3 points, got {len(points)}")
    return np.asarray(points, dtype=np.float64)


def read_label2d(path: str | os.PathLike, sequence: str, camera: str, frame: int, tracking_id: str) -> Label2D:
    """Read one 2D label file (identity from the caller, i.e. the file path).

    Raises :class:`DataFormatError` naming the file and the field on malformed content.  A JSON
    ``tracking_id`` that differs from the file name's is warned about (the file name wins).
    """
    path = Path(path)
    data = read_json_file(path)
    if not isinstance(data, dict):
        raise DataFormatError(path, "<json>", f"top level must be an object, got {type(data).__name__}")
    if "category" not in data:
        raise DataFormatError(path, "category", "missing")
    category = data["category"]
    if not isinstance(category, str):
        raise DataFormatError(path, "category", f"must be a string, got {category!r}")
    file_tid = data.get("tracking_id")
    if file_tid is not None and str(file_tid) != tracking_id:
        logger.warning("%s: field 'tracking_id' %r differs from the file name's %r; using the file name",
                       path, file_tid, tracking_id)
    keypoint_set, names = _keypoint_set(data, path)
    keypoints, visible = parse_keypoints(data.get("keypoint"), path, names)
    sigma_px, confidence = _parse_noise(data.get("keypoint"), path, names) if keypoint_set != "pedx18" else (None,
                                                                                                            None)
    polygon = parse_polygon(data.get("polygon"), path)
    subtype = data.get("subtype")
    return Label2D(sequence=sequence, camera=camera, frame=int(frame), tracking_id=tracking_id,
                   category=category, view=View2D(keypoints=keypoints, visible=visible, polygon=polygon,
                                                  keypoint_set=keypoint_set, sigma_px=sigma_px,
                                                  confidence=confidence),
                   subtype=None if subtype is None else str(subtype), frame_id=data.get("frame_id"))


def _keypoint_set(data: dict, path) -> tuple[str, tuple[str, ...]]:
    """The file's ``keypoint_set`` and its names (PedX's when absent)."""
    name = data.get("keypoint_set", "pedx18")
    if name == "pedx18":
        return "pedx18", PEDX_KEYPOINTS
    if not isinstance(name, str) or name not in keypoint_set_names():
        raise DataFormatError(path, "keypoint_set", f"unknown set {name!r} (known: {', '.join(keypoint_set_names())})")
    return name, load_keypoint_set(name).keypoints


def _parse_noise(data, path, names: tuple[str, ...]) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(K,) ``sigma_px`` and ``confidence`` of the entries (NaN where absent; None when no entry has one)."""
    out = {"sigma_px": np.full(len(names), np.nan), "confidence": np.full(len(names), np.nan)}
    for i, name in enumerate(names):
        entry = data.get(name) if isinstance(data, dict) else None
        if not isinstance(entry, dict):
            continue
        for key in out:
            if entry.get(key) is not None:
                value = _number(entry[key], path, f"keypoint.{name}.{key}")
                if (key == "sigma_px" and not value > 0) or (key == "confidence" and not 0 <= value <= 1):
                    raise DataFormatError(path, f"keypoint.{name}.{key}",
                                          f"must be {'> 0' if key == 'sigma_px' else 'in [0, 1]'}, got {value:g}")
                out[key][i] = value
    return tuple(None if np.all(np.isnan(v)) else v for v in (out["sigma_px"], out["confidence"]))


def _outside(points: np.ndarray, image_size: tuple[int, int], margin: float) -> np.ndarray:
    """(N,) bool: the (N, 2) pixel points lie outside the image widened by ``margin`` of its size per side."""
    width, height = image_size
    x, y = points[:, 0], points[:, 1]
    return ((x < -margin * width) | (x > (1.0 + margin) * width)
            | (y < -margin * height) | (y > (1.0 + margin) * height))


def screen_label(label: Label2D, image_size: tuple[int, int], margin: float = 0.05,
                 path: str | os.PathLike | None = None) -> Label2D | None:
    """``label`` without what cannot be in its ``(width, height)`` image, or None when the whole label is absurd.

    A keypoint more than ``margin`` (a fraction of the image width / height) outside the image is dropped (NaN,
    not visible); the warning names ``path`` and the fields.  When more than half of the labelled keypoints are
    outside, the rest are not to be trusted either (a label scaled or shifted wholesale): None, with a warning.
    Polygon vertices outside drop the polygon (it is not used by the fit).
    """
    where = path if path is not None else f"{label.sequence}/{label.camera}/{label.frame}/{label.tracking_id}"
    size_text = f"{image_size[0]}x{image_size[1]}"
    view = label.view
    labelled = view.labelled
    outside = np.zeros(len(labelled), dtype=bool)
    outside[labelled] = _outside(view.keypoints[labelled], image_size, margin)
    polygon = view.polygon
    if polygon is not None and np.any(_outside(np.asarray(polygon, dtype=float), image_size, margin)):
        logger.warning("%s: field 'polygon': vertices outside the %s image by more than %g %%; polygon dropped",
                       where, size_text, 100 * margin)
        polygon = None
    n_out, n_labelled = int(outside.sum()), int(labelled.sum())
    if n_out and 2 * n_out > n_labelled:
        first = int(np.flatnonzero(outside)[0])
        logger.warning("%s: field 'keypoint': %d of %d keypoints outside the %s image by more than %g %% (e.g. "
                       "%s at (%.4g, %.4g) px); instance skipped", where, n_out, n_labelled, size_text,
                       100 * margin, _names(view)[first], *view.keypoints[first])
        return None
    if n_out:
        fields = ", ".join(f"'keypoint.{_names(view)[i]}' ({view.keypoints[i, 0]:.4g}, {view.keypoints[i, 1]:.4g})"
                           for i in np.flatnonzero(outside))
        logger.warning("%s: field %s: outside the %s image by more than %g %%; dropped", where, fields, size_text,
                       100 * margin)
    if not n_out and polygon is view.polygon:
        return label
    keypoints = view.keypoints.copy()
    visible = view.visible.copy()
    keypoints[outside] = np.nan
    visible[outside] = False
    return dataclasses.replace(label, view=dataclasses.replace(view, keypoints=keypoints, visible=visible,
                                                               polygon=polygon))


def _names(view: View2D) -> tuple[str, ...]:
    if view.keypoint_set == "pedx18":
        return PEDX_KEYPOINTS
    return load_keypoint_set(view.keypoint_set).keypoints


def label2d_to_json(label: Label2D) -> dict:
    """The JSON object of a :class:`Label2D` (keypoint null when none is labelled; unlabelled joints omitted)."""
    view = label.view
    labelled = view.labelled
    keypoint = None
    if labelled.any():
        keypoint = {name: {"x": float(view.keypoints[i, 0]), "y": float(view.keypoints[i, 1]),
                           "visible": bool(view.visible[i])}
                    for i, name in enumerate(_names(view)) if labelled[i]}
        for key in ("confidence", "sigma_px"):
            values = getattr(view, key)
            if values is not None:
                for i, name in enumerate(_names(view)):
                    if labelled[i] and np.isfinite(values[i]):
                        keypoint[name][key] = float(values[i])
    polygon = None if view.polygon is None else np.asarray(view.polygon, dtype=float).tolist()
    extra = {} if view.keypoint_set == "pedx18" else {"keypoint_set": view.keypoint_set}
    return {
        **extra,
        "tracking_id": label.tracking_id,
        "category": label.category,
        "subtype": label.subtype,
        "frame_id": label.frame if label.frame_id is None else label.frame_id,
        "polygon": polygon,
        "keypoint": keypoint,
    }


def write_label2d(root: str | os.PathLike, label: Label2D, flat: bool = False) -> Path:
    """Write ``label`` atomically to its release path under ``root`` (folder holding ``labels/``)."""
    if "_" in label.sequence or "_" in label.camera:
        raise ValueError(f"sequence and camera names must not contain '_': {label.sequence!r}, {label.camera!r}")
    if label.view.keypoints.shape != (len(_names(label.view)), 2):
        raise ValueError(f"keypoints must have shape ({len(_names(label.view))}, 2) for keypoint set "
                         f"{label.view.keypoint_set}, got {label.view.keypoints.shape}")
    if label.view.polygon is not None:
        polygon = np.asarray(label.view.polygon, dtype=float)
        if polygon.ndim != 2 or polygon.shape[1] != 2 or len(polygon) < 3 or not np.isfinite(polygon).all():
            raise ValueError(f"polygon must be (K >= 3, 2) finite pixels, got shape {polygon.shape}")
    path = label2d_path(root, label.sequence, label.camera, label.frame, label.tracking_id, flat=flat)
    return atomic_write_json(path, label2d_to_json(label))
