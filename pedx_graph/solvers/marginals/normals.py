"""Area-weighted vertex normals of the posed body mesh (the surface directions of the chamfer's plane rows).

A vertex normal is the sum of the (area-scaled) normals ``(v1 - v0) x (v2 - v0)`` of the faces around the
vertex, normalised: summed through the sparse vertex-face incidence of the mesh (``scipy.sparse``).
:func:`vertex_normals` does it for a whole posed mesh; :func:`matched_vertex_normals` for a few vertices of
many frames at once, posing only the corners of their faces.
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


def _face_normals(triangles: np.ndarray) -> np.ndarray:
    """Area-scaled normals (..., 3) of triangles (..., 3 corners, 3)."""
    return np.cross(triangles[..., 1, :] - triangles[..., 0, :], triangles[..., 2, :] - triangles[..., 0, :])


def _unit(normals: np.ndarray) -> np.ndarray:
    return normals / np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-300)


def vertex_normals(vertices: np.ndarray, faces: np.ndarray, incidence=None) -> np.ndarray:
    """(V, 3) unit area-weighted vertex normals of a mesh (vertices (V, 3), faces (F, 3)); ``incidence``:
    :func:`face_incidence` of ``faces`` when already built."""
    faces = np.asarray(faces, dtype=np.int64)
    incidence = face_incidence(faces, len(vertices)) if incidence is None else incidence
    return _unit(np.asarray(incidence @ _face_normals(np.asarray(vertices)[faces])))


_INCIDENCE: list = [None, None]          # [model, its incidence]: the model is held, so never confused


def incidence_of(model):
    """:func:`face_incidence` of a body model's faces, built once per model (CSR rows = vertices)."""
    if _INCIDENCE[0] is not model:
        _INCIDENCE[:] = [model, face_incidence(np.asarray(model.faces, dtype=np.int64), int(model.num_vertices))]
    return _INCIDENCE[1]


def matched_vertex_normals(model, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray,
                           vertex_ids: np.ndarray) -> np.ndarray:
    """(F, U, 3) unit normals of the vertices ``vertex_ids`` (U,) of F posed frames (pose (F, 72), betas
    (F, B), trans (F, 3)): only the faces around them are posed (``model.vertices_subset`` of their corners)."""
    faces = np.asarray(model.faces, dtype=np.int64)
    sub = incidence_of(model)[vertex_ids]                                   # (U, all faces) sparse
    face_ids = np.unique(sub.indices)
    corners, corner_index = np.unique(faces[face_ids], return_inverse=True)
    posed = np.asarray(model.vertices_subset(pose, betas, trans, corners), float)      # (F, C, 3)
    face_n = _face_normals(posed[:, corner_index.reshape(-1, 3)])                       # (F, Fs, 3)
    num = len(posed)
    normals = np.asarray(sub[:, face_ids] @ face_n.transpose(1, 0, 2).reshape(len(face_ids), 3 * num))
    return _unit(normals.reshape(len(vertex_ids), num, 3).transpose(1, 0, 2))
