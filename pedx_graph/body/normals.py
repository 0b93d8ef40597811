"""Area-weighted vertex normals of a triangle mesh (posed body meshes, the rest template).

A vertex normal is the sum of the (area-scaled) normals ``(v1 - v0) x (v2 - v0)`` of the faces around the
vertex, normalised: summed through the sparse vertex-face incidence of the mesh (``scipy.sparse``).
"""
from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix


def face_incidence(faces: np.ndarray, num_vertices: int) -> csr_matrix:
    """(V, F) sparse vertex-face incidence (ones), to sum face quantities onto their vertices."""
    faces = np.asarray(faces, dtype=np.int64)
    rows = faces.reshape(-1)
    cols = np.repeat(np.arange(len(faces)), 3)
    return csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(num_vertices, len(faces)))


def face_normals(triangles: np.ndarray) -> np.ndarray:
    """Area-scaled normals (..., 3) of triangles (..., 3 corners, 3)."""
    return np.cross(triangles[..., 1, :] - triangles[..., 0, :], triangles[..., 2, :] - triangles[..., 0, :])


def unit(normals: np.ndarray) -> np.ndarray:
    """``normals`` (..., 3) scaled to unit length (zero vectors stay zero)."""
    return normals / np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-300)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, incidence=None) -> np.ndarray:
    """(V, 3) unit area-weighted vertex normals of a mesh (vertices (V, 3), faces (F, 3)); ``incidence``:
    :func:`face_incidence` of ``faces`` when already built."""
    faces = np.asarray(faces, dtype=np.int64)
    incidence = face_incidence(faces, len(vertices)) if incidence is None else incidence
    return unit(np.asarray(incidence @ face_normals(np.asarray(vertices)[faces])))
