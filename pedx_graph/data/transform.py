"""Move a whole release folder by one rigid motion ``dst_T_src``: every 3D quantity moves, the rest is copied.

``transform_dataset(src, dst, dst_T_src, body_model)`` writes a copy of the folder ``src`` into ``dst`` in
which every point, pose and frame that lives in the LiDAR (world) frame is expressed in a new frame, with
``dst_p = dst_R_src @ src_p + dst_t_src``:

* ``calib/calib_cam_to_range_<cam>.txt``: ``world_T_cam -> dst_T_src @ world_T_cam`` (the ``R``/``T`` or
  ``Tr`` values are rewritten from the file's own numbers; other lines, comments included, are kept);
  ``calib_cam_to_cam_*`` (camera-relative) is copied;
* ``pointclouds/<seq>/*.ply`` and ``labels/3d/segment/<seq>/*.ply``: ``x, y, z`` of every finite point moved
  and written as float64 (so a motion and its inverse give back the source to ~1e-15 m); non-finite rows
  (the release's masked ``inf`` points) and other vertex properties are kept as they are;
* ``labels/3d/smpl/<seq>/*.json``: the root orientation and ``trans`` (:func:`transform_smpl`); betas and
  the body pose are unchanged, so every vertex moves rigidly;
* the simulator's ``truth/<seq>/*.npz``: ``scene_points``, ``keypoints__<tid>`` and ``joints__<tid>`` moved
  (float64); ``truth/meta.json``: ``output_T_sim``, ``world_p_lidar`` and the ``ground`` record
  (``world_up``, ``ground_offset_m``: the plane ``world_up . p = ground_offset_m``) updated;
* everything else (2D labels, images, timestamps, ``sim_config.yaml``, ``summary.json``, per-frame truth
  JSON) is copied byte for byte.  (``sim_config.yaml`` then no longer describes the output frame of ``dst``:
  ``truth/meta.json`` does.)

The output is byte-stable: the same input and motion give the same files.  Extra (non-release) fields of SMPL
files are copied unchanged, with a warning: they cannot be moved without knowing what they mean.
"""
from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pedx_graph.data.calib import get_floats, read_kitti_text
from pedx_graph.data.npzfile import npz_bytes, read_npz
from pedx_graph.data.ply import read_ply_vertices
from pedx_graph.data.smpl_labels import SMPL_KEYS, read_smpl_label, smpl_label_to_json
from pedx_graph.data.types import DataFormatError
from pedx_graph.utils import atomic_write_bytes, atomic_write_json, atomic_write_text

logger = logging.getLogger(__name__)

__all__ = ["check_rigid", "transform_points", "transform_smpl", "transform_ground", "transform_dataset",
           "TRUTH_POINT_KEYS"]

#: Prefixes / names of the truth NPZ arrays that hold (..., 3) world points.
TRUTH_POINT_KEYS = ("scene_points", "keypoints__", "joints__")

_PLY_TYPE_NAMES = {"i1": "char", "u1": "uchar", "i2": "short", "u2": "ushort", "i4": "int", "u4": "uint",
                   "f4": "float", "f8": "double"}


def check_rigid(dst_T_src, tol: float = 1e-9) -> np.ndarray:
    """``dst_T_src`` as a (4, 4) float array; ``ValueError`` unless it is a proper rigid motion (rotation with
    ``|R^T R - I| <= tol``, ``det R > 0``, last row ``0 0 0 1``, finite)."""
    matrix = np.asarray(dst_T_src, dtype=np.float64)
    if matrix.shape != (4, 4) or not np.all(np.isfinite(matrix)):
        raise ValueError(f"dst_T_src must be a finite (4, 4) matrix, got shape {matrix.shape}")
    rot = matrix[:3, :3]
    if np.abs(rot.T @ rot - np.eye(3)).max() > tol or np.linalg.det(rot) <= 0:
        raise ValueError("dst_T_src[:3, :3] is not a rotation (orthonormal, det +1)")
    if not np.array_equal(matrix[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"dst_T_src's last row must be [0, 0, 0, 1], got {matrix[3].tolist()}")
    return matrix


def _is_identity(matrix: np.ndarray) -> bool:
    return bool(np.array_equal(matrix, np.eye(4)))


def transform_points(dst_T_src, src_points) -> np.ndarray:
    """(..., 3) points moved by ``dst_T_src`` (float64 copy); rows with a non-finite coordinate are kept as
    they are (masked ``inf`` points stay masked).  The identity returns an exact copy."""
    matrix = np.asarray(dst_T_src, dtype=np.float64)
    points = np.array(src_points, dtype=np.float64)
    if _is_identity(matrix) or points.size == 0:
        return points
    finite = np.all(np.isfinite(points), axis=-1)
    points[finite] = points[finite] @ matrix[:3, :3].T + matrix[:3, 3]
    return points


def transform_smpl(dst_T_src, pose, trans, rest_pelvis) -> tuple[np.ndarray, np.ndarray]:
    """SMPL parameters of a body moved by ``dst_T_src``: ``(pose (..., 72), trans (..., 3))`` copies.

    The root orientation becomes ``dst_R_src @ R_root``; with ``J0 = rest_pelvis`` (``rest_joints(betas)[0]``,
    the point the root rotates about) ``trans -> dst_R_src (J0 + trans) + dst_t_src - J0``.  Body pose and
    betas are unchanged, so every vertex and joint ``p`` becomes ``dst_R_src p + dst_t_src``.
    """
    matrix = np.asarray(dst_T_src, dtype=np.float64)
    pose = np.array(pose, dtype=np.float64)
    trans = np.array(trans, dtype=np.float64)
    if _is_identity(matrix):
        return pose, trans
    rot, shift = matrix[:3, :3], matrix[:3, 3]
    rest_pelvis = np.asarray(rest_pelvis, dtype=np.float64)
    root = Rotation.from_rotvec(pose[..., :3].reshape(-1, 3))
    pose[..., :3] = (Rotation.from_matrix(rot) * root).as_rotvec().reshape(pose[..., :3].shape)
    trans = (rest_pelvis + trans) @ rot.T + shift - rest_pelvis
    return pose, trans


def transform_ground(dst_T_src, world_up, ground_offset_m: float | None) -> tuple[np.ndarray, float | None]:
    """The plane ``{p : world_up . p = ground_offset_m}`` (and its up vector) after the motion ``dst_T_src``:
    ``up' = dst_R_src up``, ``offset' = offset + up' . dst_t_src`` (None stays None)."""
    matrix = np.asarray(dst_T_src, dtype=np.float64)
    up = matrix[:3, :3] @ np.asarray(world_up, dtype=np.float64)
    if ground_offset_m is None:
        return up, None
    return up, float(ground_offset_m) + float(up @ matrix[:3, 3])


# ------------------------------------------------------------------------------------------- files


def _fmt(values) -> str:
    return " ".join(f"{float(v)!r}" for v in np.asarray(values, dtype=np.float64).ravel())


def _cam_to_range_text(path: Path, dst_T_src: np.ndarray) -> str:
    """The text of a ``calib_cam_to_range`` file with its ``R``/``T`` (and/or ``Tr``) moved."""
    entries = read_kitti_text(path)
    rot, shift = dst_T_src[:3, :3], dst_T_src[:3, 3]
    new_values: dict[str, np.ndarray] = {}
    if "R" in entries or "T" in entries:
        cam_R = get_floats(entries, "R", 9, path, (3, 3))
        cam_t = get_floats(entries, "T", 3, path)
        new_values["R"] = rot @ cam_R
        new_values["T"] = rot @ cam_t + shift
    if "Tr" in entries:
        tr = get_floats(entries, "Tr", 12, path, (3, 4))
        new_values["Tr"] = np.concatenate([rot @ tr[:, :3], (rot @ tr[:, 3] + shift)[:, None]], axis=1)
    if not new_values:
        raise DataFormatError(path, "R", "required key missing (need 'R' and 'T', or 'Tr')")
    text = path.read_text(encoding="utf-8")
    lines = []
    for line in text.splitlines():
        stripped = line.strip()
        key = stripped.split(":", 1)[0].strip() if ":" in stripped and not stripped.startswith("#") else None
        lines.append(f"{key}: {_fmt(new_values[key])}" if key in new_values else line)
    return "\n".join(lines) + ("\n" if text.endswith("\n") else "")


def _ply_bytes(path: Path, dst_T_src: np.ndarray) -> bytes:
    """A binary little-endian PLY of the file's vertex element with ``x, y, z`` moved (float64)."""
    data = path.read_bytes()
    end = data.find(b"end_header")
    header = data[:max(end, 0)].decode("ascii", errors="replace")
    elements = [line.split()[1] for line in header.splitlines()
                if line.startswith("element ") and len(line.split()) > 1]
    if any(name != "vertex" for name in elements):
        logger.warning("%s: only the vertex element is kept (file has %s)", path, elements)
    props = read_ply_vertices(path)
    for axis in ("x", "y", "z"):
        if axis not in props:
            raise DataFormatError(path, axis, f"vertex property '{axis}' missing (have {sorted(props)})")
    xyz = transform_points(dst_T_src, np.stack([props["x"], props["y"], props["z"]], axis=-1))
    fields, columns = [], []
    for name, values in props.items():
        if name in ("x", "y", "z"):
            values = xyz[:, "xyz".index(name)]
        code = values.dtype.str[1:]
        if code not in _PLY_TYPE_NAMES:
            raise DataFormatError(path, name, f"unsupported property type {values.dtype}")
        fields.append((name, "<" + code))
        columns.append(values)
    table = np.empty(len(xyz), dtype=fields)
    for (name, _), values in zip(fields, columns):
        table[name] = values
    lines = ["ply", "format binary_little_endian 1.0", "comment pedx-graph", f"element vertex {len(table)}"]
    lines += [f"property {_PLY_TYPE_NAMES[code[1:]]} {name}" for name, code in fields]
    lines.append("end_header")
    return ("\n".join(lines) + "\n").encode("ascii") + table.tobytes()


def _smpl_bytes(path: Path, dst_T_src: np.ndarray, body_model, extra_keys: set) -> bytes:
    label = read_smpl_label(path, n_betas=None)
    if len(label.betas) != body_model.num_betas:
        raise DataFormatError(path, "betas", f"{len(label.betas)} values, the body model has {body_model.num_betas}")
    rest_pelvis = body_model.rest_joints(label.betas)[0]
    label.pose, label.trans = transform_smpl(dst_T_src, label.pose, label.trans, rest_pelvis)
    extra_keys.update(k for k in label.extra if k not in SMPL_KEYS)
    obj = smpl_label_to_json(label, n_betas=None)
    return (json.dumps(obj, separators=(",", ":")) + "\n").encode("utf-8")


def _truth_npz_bytes(path: Path, dst_T_src: np.ndarray) -> bytes:
    arrays = read_npz(path)
    for key, value in arrays.items():
        if key == "scene_points" or key.startswith(TRUTH_POINT_KEYS[1:]):
            if value.shape[-1:] != (3,):
                raise DataFormatError(path, key, f"expected (..., 3) points, got shape {value.shape}")
            arrays[key] = transform_points(dst_T_src, value)
    return npz_bytes(arrays)


def _meta_json(path: Path, dst_T_src: np.ndarray) -> dict:
    meta = json.loads(path.read_text(encoding="utf-8"))
    if not isinstance(meta, dict):
        raise DataFormatError(path, "<json>", "top level must be an object")
    if "output_T_sim" in meta:
        meta["output_T_sim"] = (dst_T_src @ np.asarray(meta["output_T_sim"], dtype=np.float64)).tolist()
    if "world_p_lidar" in meta:
        meta["world_p_lidar"] = transform_points(dst_T_src, meta["world_p_lidar"]).tolist()
    ground = meta.get("ground")
    if isinstance(ground, dict) and "world_up" in ground:
        up, offset = transform_ground(dst_T_src, ground["world_up"], ground.get("ground_offset_m"))
        meta["ground"] = {**ground, "world_up": up.tolist(), "ground_offset_m": offset}
    return meta


def _kind(rel: Path) -> str:
    """What a file is, from its path relative to the folder: calib_range, cloud, smpl, truth_npz, meta, copy."""
    parts = rel.parts
    name = rel.name
    if len(parts) >= 2 and parts[-2] == "calib" and name.startswith("calib_cam_to_range_") and name.endswith(".txt"):
        return "calib_range"
    if rel.suffix == ".ply" and ("pointclouds" in parts or ("segment" in parts and "3d" in parts)):
        return "cloud"
    if rel.suffix == ".json" and "smpl" in parts and "3d" in parts and "labels" in parts:
        return "smpl"
    if "truth" in parts and rel.suffix == ".npz":
        return "truth_npz"
    if "truth" in parts and name == "meta.json":
        return "meta"
    return "copy"


def transform_dataset(src: str | os.PathLike, dst: str | os.PathLike, dst_T_src, body_model,
                      overwrite: bool = False) -> dict[str, int]:
    """Write ``src`` moved by the rigid motion ``dst_T_src`` (4, 4) into ``dst`` (see the module docstring).

    ``body_model``: a :class:`pedx_graph.body.BodyModel` (its rest pelvis ``J0(betas)`` is needed to move SMPL
    ``trans``).  ``dst`` must not exist or be empty unless ``overwrite`` (then it is removed first); it may
    not be ``src`` or lie inside it.  Returns the number of files of each kind written (``calib_range``,
    ``cloud``, ``smpl``, ``truth_npz``, ``meta``, ``copy``).
    """
    matrix = check_rigid(dst_T_src)
    src, dst = Path(src), Path(dst)
    if not src.is_dir():
        raise FileNotFoundError(f"{src}: not a folder")
    src_abs, dst_abs = src.resolve(), dst.resolve()
    if dst_abs == src_abs or src_abs in dst_abs.parents:
        raise ValueError(f"{dst}: the destination may not be the source folder or lie inside it")
    if dst.exists() and any(dst.iterdir()):
        if not overwrite:
            raise FileExistsError(f"{dst}: exists and is not empty (use overwrite=True)")
        shutil.rmtree(dst)
    counts = dict.fromkeys(("calib_range", "cloud", "smpl", "truth_npz", "meta", "copy"), 0)
    extra_keys: set = set()
    for path in sorted(p for p in src.rglob("*") if p.is_file()):
        rel = path.relative_to(src)
        out = dst / rel
        kind = _kind(rel)
        if kind == "calib_range":
            atomic_write_text(out, _cam_to_range_text(path, matrix))
        elif kind == "cloud":
            atomic_write_bytes(out, _ply_bytes(path, matrix))
        elif kind == "smpl":
            atomic_write_bytes(out, _smpl_bytes(path, matrix, body_model, extra_keys))
        elif kind == "truth_npz":
            atomic_write_bytes(out, _truth_npz_bytes(path, matrix))
        elif kind == "meta":
            atomic_write_json(out, _meta_json(path, matrix))
        else:
            atomic_write_bytes(out, path.read_bytes())
        counts[kind] += 1
    if extra_keys:
        logger.warning("%s: SMPL files carry extra fields %s; copied unchanged (not moved)", src, sorted(extra_keys))
    return counts
