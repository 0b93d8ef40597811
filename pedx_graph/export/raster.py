"""Triangle meshes painted into an image with OpenCV: painter's order, back faces culled, Lambert shading.

``paint_meshes(image, camera, meshes)`` projects every mesh through ``camera`` (any object with
``project(world_p, scale) -> (uv, depth)`` and ``world_center``), drops the faces behind the near plane, outside
the image or facing away from the camera, sorts the rest of *all* meshes together from far to near by their
centroid's depth and fills each with ``cv2.fillConvexPoly`` (sub-pixel vertices, 4 fractional bits), so a
nearer person covers a farther one.  Each face's colour is the mesh's colour times
``ambient + (1 - ambient) * |cos|`` of the angle between its normal and the ray from the camera (a head-lamp).
Faces must be ordered counter-clockwise seen from outside (:func:`outward_faces`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Fractional bits of the sub-pixel vertex coordinates given to OpenCV.
SHIFT_BITS = 4
#: Faces with a vertex nearer than this to the camera plane are not drawn, metres.
NEAR_M = 0.1


@dataclass
class PaintedMesh:
    """One mesh to paint."""

    world_vertices: np.ndarray
    """(V, 3) vertices in the camera's world frame, metres."""
    faces: np.ndarray
    """(F, 3) vertex indices, counter-clockwise seen from outside."""
    colour_bgr: tuple[int, int, int]
    """Base colour (B, G, R), 0-255."""


def outward_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """``faces`` with their order reversed when the mesh's signed volume is negative (normals inwards)."""
    v = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    signed = np.einsum("ij,ij->i", v[faces[:, 0]], np.cross(v[faces[:, 1]], v[faces[:, 2]])).sum()
    return faces if signed >= 0 else faces[:, ::-1].copy()


def visible_faces(camera, mesh: PaintedMesh, image_size: tuple[int, int], scale: float = 1.0):
    """The faces of ``mesh`` to paint: ((N, 3, 2) pixels, (N,) centroid depth, (N,) shade in [0, 1]) of the
    faces in front of the near plane, overlapping the image and facing the camera."""
    v = np.asarray(mesh.world_vertices, dtype=float)
    uv, depth = camera.project(v, scale)
    tri_uv, tri_d = uv[mesh.faces], depth[mesh.faces]
    width, height = image_size
    keep = np.all(tri_d > NEAR_M, axis=1)
    keep &= (tri_uv[..., 0].max(axis=1) >= 0) & (tri_uv[..., 0].min(axis=1) < width)
    keep &= (tri_uv[..., 1].max(axis=1) >= 0) & (tri_uv[..., 1].min(axis=1) < height)
    tri_w = v[mesh.faces[keep]]
    normal = np.cross(tri_w[:, 1] - tri_w[:, 0], tri_w[:, 2] - tri_w[:, 0])
    centroid = tri_w.mean(axis=1)
    to_camera = camera.world_center - centroid
    facing = np.einsum("ij,ij->i", normal, to_camera)
    norms = np.linalg.norm(normal, axis=1) * np.linalg.norm(to_camera, axis=1)
    cos = np.divide(facing, norms, out=np.zeros_like(facing), where=norms > 0)
    front = cos > 0
    return tri_uv[keep][front], tri_d[keep][front].mean(axis=1), cos[front]


def paint_meshes(image: np.ndarray, camera, meshes: list[PaintedMesh], scale: float = 1.0,
                 ambient: float = 0.35) -> np.ndarray:
    """Paint ``meshes`` into ``image`` (H, W, 3 uint8, modified in place and returned) in painter's order
    (module docstring); ``scale``: the image's size over the camera calibration's."""
    import cv2

    height, width = image.shape[:2]
    parts_uv, parts_depth, parts_colour = [], [], []
    for mesh in meshes:
        tri_uv, depth, cos = visible_faces(camera, mesh, (width, height), scale)
        shade = ambient + (1.0 - ambient) * cos
        parts_uv.append(tri_uv)
        parts_depth.append(depth)
        parts_colour.append(np.clip(shade[:, None] * np.asarray(mesh.colour_bgr, float), 0, 255))
    if not parts_uv:
        return image
    tri_uv = np.concatenate(parts_uv)
    order = np.argsort(-np.concatenate(parts_depth), kind="stable")
    fixed = np.round(tri_uv[order] * (1 << SHIFT_BITS)).astype(np.int32)
    colours = np.concatenate(parts_colour)[order].round().astype(int).tolist()
    for tri, colour in zip(fixed, colours):
        cv2.fillConvexPoly(image, tri, colour, cv2.LINE_8, SHIFT_BITS)
    return image


def silhouette_mask(camera, mesh: PaintedMesh, image_size: tuple[int, int], scale: float = 1.0) -> np.ndarray:
    """(H, W) uint8 mask (255 inside) of the mesh's projection (its front faces filled)."""
    import cv2

    width, height = image_size
    mask = np.zeros((height, width), np.uint8)
    tri_uv, _, _ = visible_faces(camera, mesh, image_size, scale)
    if len(tri_uv):
        cv2.fillPoly(mask, list(np.round(tri_uv * (1 << SHIFT_BITS)).astype(np.int32)), 255, cv2.LINE_8,
                     SHIFT_BITS)
    return mask
