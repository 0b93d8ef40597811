"""SMPL label files: ``labels/3d/smpl/<seq>/<seq>_<frame:07d>_<tid>.json`` (ground truth and our results).

The release's fields are ``betas`` (10 shape coefficients), ``pose`` (72, axis-angle, root first) and
``trans`` (3, metres), all in the LiDAR (world) frame.  Nested shapes such as ``(1, 10)`` betas or
``(24, 3)`` pose are accepted when their size matches and flattened.

Our own additional fields (``keypoints_3d``, ``covariance``, ...) are written as further top-level keys
from :attr:`SmplLabel.extra`; on reading, every key other than the three release keys goes back into
``extra`` unchanged.  (Sequence, frame and tracking id are in the file name, not in the JSON.)
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from pedx_graph.data.jsonfile import read_json_file
from pedx_graph.data.types import DataFormatError, SmplLabel
from pedx_graph.utils import atomic_write_json, to_jsonable

#: The release's keys and their lengths (``betas`` length configurable).
SMPL_KEYS: tuple[str, ...] = ("betas", "pose", "trans")
N_POSE = 72
N_TRANS = 3
N_BETAS = 10

_NAME_RE = re.compile(r"^(?P<frame>\d+)_(?P<tid>.+)\.json$")


def smpl_label_path(root: str | os.PathLike, sequence: str, frame: int, tracking_id: str) -> Path:
    """``<root>/labels/3d/smpl/<seq>/<seq>_<frame:07d>_<tid>.json`` (root: folder holding ``labels/``)."""
    return Path(root) / "labels" / "3d" / "smpl" / sequence / f"{sequence}_{int(frame):07d}_{tracking_id}.json"


def parse_smpl_label_name(path: str | os.PathLike, sequence: str) -> tuple[int, str] | None:
    """``(frame, tracking_id)`` from ``<seq>_<frame>_<tid>.json``, or None when the name does not match."""
    name = Path(path).name
    if not name.startswith(f"{sequence}_"):
        return None
    match = _NAME_RE.match(name[len(sequence) + 1:])
    return (int(match["frame"]), match["tid"]) if match else None


def _vector(value, length: int | None, path, field: str) -> np.ndarray:
    if value is None:
        raise DataFormatError(path, field, "missing")
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError) as exc:     # Overflow: an integer beyond the float range
        raise DataFormatError(path, field, f"not a numeric array ({exc})") from exc
    array = array.reshape(-1)
    if length is not None and array.size != length:
        raise DataFormatError(path, field, f"expected {length} values, found {array.size}")
    if length is None and array.size == 0:
        raise DataFormatError(path, field, "empty")
    if not np.all(np.isfinite(array)):
        raise DataFormatError(path, field, "non-finite value")
    return array


def smpl_label_from_json(data, path, sequence: str, frame: int, tracking_id: str,
                         n_betas: int | None = N_BETAS) -> SmplLabel:
    """Build a :class:`SmplLabel` from a parsed JSON object; :class:`DataFormatError` on bad fields.

    ``n_betas``: required length of ``betas`` (None: any non-empty length).
    """
    if not isinstance(data, dict):
        raise DataFormatError(path, "<json>", f"top level must be an object, got {type(data).__name__}")
    betas = _vector(data.get("betas"), n_betas, path, "betas")
    pose = _vector(data.get("pose"), N_POSE, path, "pose")
    trans = _vector(data.get("trans"), N_TRANS, path, "trans")
    extra = {k: v for k, v in data.items() if k not in SMPL_KEYS}
    return SmplLabel(sequence=sequence, frame=int(frame), tracking_id=tracking_id,
                     betas=betas, pose=pose, trans=trans, extra=extra)


def read_smpl_label(path: str | os.PathLike, sequence: str | None = None, frame: int | None = None,
                    tracking_id: str | None = None, n_betas: int | None = N_BETAS) -> SmplLabel:
    """Read one SMPL label file.

    Identity (sequence, frame, tracking id) is taken from the arguments, else from the file path
    (``<seq>/<seq>_<frame>_<tid>.json``).  Raises :class:`DataFormatError` naming file and field.
    """
    path = Path(path)
    if sequence is None:
        sequence = path.parent.name
    if frame is None or tracking_id is None:
        parsed = parse_smpl_label_name(path, sequence)
        if parsed is None:
            raise DataFormatError(path, "<file name>", f"does not match '{sequence}_<frame>_<tid>.json'")
        frame = parsed[0] if frame is None else frame
        tracking_id = parsed[1] if tracking_id is None else tracking_id
    data = read_json_file(path)
    return smpl_label_from_json(data, path, sequence, frame, tracking_id, n_betas=n_betas)


def smpl_label_to_json(label: SmplLabel, n_betas: int | None = N_BETAS) -> dict:
    """The JSON object of ``label``: the three release keys, then ``extra``'s keys (numpy converted)."""
    where = f"SmplLabel({label.sequence}, {label.frame}, {label.tracking_id})"
    data = {
        "betas": _vector(label.betas, n_betas, where, "betas").tolist(),
        "pose": _vector(label.pose, N_POSE, where, "pose").tolist(),
        "trans": _vector(label.trans, N_TRANS, where, "trans").tolist(),
    }
    clash = sorted(set(label.extra) & set(SMPL_KEYS))
    if clash:
        raise DataFormatError(where, f"extra.{clash[0]}", "extra field clashes with a release key")
    data.update(to_jsonable(dict(label.extra)))
    return data


def write_smpl_label(root: str | os.PathLike, label: SmplLabel, n_betas: int | None = N_BETAS) -> Path:
    """Write ``label`` atomically to its release path under ``root`` (folder holding ``labels/``)."""
    if "_" in label.sequence:
        raise ValueError(f"sequence names must not contain '_': {label.sequence!r}")
    path = smpl_label_path(root, label.sequence, label.frame, label.tracking_id)
    return atomic_write_json(path, smpl_label_to_json(label, n_betas=n_betas))
