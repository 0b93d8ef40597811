"""Per-frame meshes of a fitted track as PLY and OBJ files (trimesh), in the LiDAR frame or the level frame.

A result's SMPL parameters (``labels/3d/smpl``) are in the LiDAR frame; :func:`track_meshes` evaluates the body
model on them, so a mesh has exactly the model's vertices and faces (no vertex merged or dropped: trimesh is
told not to process it) and is watertight exactly when the model's template is.  ``frame="world"`` maps
every vertex into the level frame of the sequence's derived ground (:func:`level_T_lidar`): x along the
reference forward direction, z along the derived up axis, the ground plane at z = 0 below the sensor.
Files: ``meshes/<seq>/<seq>_<frame:07d>_<tid>.{ply,obj}`` (binary PLY; OBJ text with 6-decimal vertices).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from pedx_graph.data.ground import GroundFrame
from pedx_graph.data.types import SmplLabel
from pedx_graph.utils import atomic_write_bytes

#: Output frames of the meshes.
MESH_FRAMES = ("lidar", "world")
#: Mesh file formats.
MESH_FORMATS = ("ply", "obj")


def level_T_lidar(ground: GroundFrame) -> np.ndarray:
    """(4, 4) LiDAR frame -> level frame of ``ground`` with its origin on the ground plane below the sensor
    (at the sensor when the ground plane is unknown)."""
    out = np.eye(4)
    out[:3, :3] = ground.world_R_level.T
    out[:3, 3] = -ground.world_R_level.T @ ground.world_p_sensor
    if ground.ground_offset_m is not None:
        out[2, 3] -= float(ground.ground_offset_m) - float(ground.world_up @ ground.world_p_sensor)
    return out


def track_vertices(model, labels: list[SmplLabel]) -> np.ndarray:
    """(T, V, 3) LiDAR-frame vertices of the body model posed by each label."""
    pose = np.stack([np.asarray(lab.pose, float) for lab in labels])
    betas = np.stack([np.asarray(lab.betas, float)[:model.num_betas] for lab in labels])
    trans = np.stack([np.asarray(lab.trans, float) for lab in labels])
    return np.asarray(model.forward(pose, betas, trans).vertices)


def make_mesh(vertices: np.ndarray, faces: np.ndarray):
    """A ``trimesh.Trimesh`` of exactly these vertices and faces (no merging, no reordering)."""
    import trimesh

    return trimesh.Trimesh(vertices=np.asarray(vertices, float), faces=np.asarray(faces, np.int64), process=False,
                           validate=False)


def mesh_bytes(mesh, file_format: str) -> bytes:
    """The mesh encoded as ``ply`` (binary little-endian) or ``obj`` (vertices and faces only)."""
    if file_format == "ply":
        return mesh.export(file_type="ply", encoding="binary")
    if file_format == "obj":
        text = mesh.export(file_type="obj", include_normals=False, include_color=False, include_texture=False,
                           digits=6, header=None)
        return text.encode("utf-8")
    raise ValueError(f"mesh format must be one of {MESH_FORMATS}, got {file_format!r}")


def mesh_path(out: str | os.PathLike, sequence: str, frame: int, tracking_id: str, file_format: str) -> Path:
    """``<out>/meshes/<seq>/<seq>_<frame:07d>_<tid>.<format>``."""
    return Path(out) / "meshes" / sequence / f"{sequence}_{frame:07d}_{tracking_id}.{file_format}"


def write_track_meshes(out: str | os.PathLike, model, labels: list[SmplLabel], ground: GroundFrame | None = None,
                       frame: str = "lidar", formats: tuple[str, ...] = MESH_FORMATS) -> list[Path]:
    """Write every frame's mesh of one track (module docstring); returns the paths.  ``ground`` is needed for
    ``frame="world"``."""
    if frame not in MESH_FRAMES:
        raise ValueError(f"mesh frame must be one of {MESH_FRAMES}, got {frame!r}")
    unknown = [f for f in formats if f not in MESH_FORMATS]
    if unknown:
        raise ValueError(f"mesh formats must be among {MESH_FORMATS}, got {unknown}")
    vertices = track_vertices(model, labels)
    if frame == "world":
        if ground is None:
            raise ValueError("meshes in the level world frame need the sequence's ground (summary.json 'ground')")
        out_T_lidar = level_T_lidar(ground)
        vertices = vertices @ out_T_lidar[:3, :3].T + out_T_lidar[:3, 3]
    written = []
    for lab, verts in zip(labels, vertices):
        mesh = make_mesh(verts, model.faces)
        for file_format in formats:
            path = mesh_path(out, lab.sequence, lab.frame, lab.tracking_id, file_format)
            written.append(atomic_write_bytes(path, mesh_bytes(mesh, file_format)))
    return written
