"""Area-weighted vertex normals of the posed body mesh (the surface directions of the chamfer's plane rows).

:func:`pedx_graph.body.normals.vertex_normals` does it for a whole posed mesh; :func:`matched_vertex_normals`
for a few vertices of many frames at once, posing only the corners of their faces.
"""
from __future__ import annotations

import numpy as np

from pedx_graph.body.normals import face_incidence, face_normals, unit, vertex_normals  # noqa: F401

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
    face_n = face_normals(posed[:, corner_index.reshape(-1, 3)])                       # (F, Fs, 3)
    num = len(posed)
    normals = np.asarray(sub[:, face_ids] @ face_n.transpose(1, 0, 2).reshape(len(face_ids), 3 * num))
    return unit(normals.reshape(len(vertex_ids), num, 3).transpose(1, 0, 2))
