"""Plausibility fields of a written track: the posed meshes' signed volumes (inside-out bodies), the shape's
extremes, and whether its depth rests on the body size alone (``monocular``).

Per frame ``mesh_signed_volume_m3``, the signed volume of the posed mesh with the model's faces oriented
outward at rest (a negative volume is an inside-out, mirrored body: a large negative first shape
coefficient does that); per track ``inside_out_frames`` (frames with a volume <= 0),
``min_mesh_signed_volume_m3``, ``mesh_volume_ratio`` (the median volume over the volume of the mean shape
at rest) and ``max_abs_beta``.  ``monocular`` (:func:`is_monocular`): no frame of the track has keypoints in
two cameras and none has LiDAR points, so its depth rests on the body-size prior alone.
"""
from __future__ import annotations

import logging

import numpy as np

log = logging.getLogger(__name__)


def _signed_volumes(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Signed volumes (...,) of triangle meshes ``vertices`` (..., V, 3) with ``faces`` (F, 3), m^3: by the
    divergence theorem with the field (0, 0, z), ``sum_f (z_a + z_b + z_c) / 3 * n_z,f / 2`` with
    ``n_f = (b - a) x (c - a)`` (= the sum of ``a . (b x c) / 6`` for a closed mesh; positive when the faces
    wind counter-clockwise seen from outside).  Taken about the vertices' mean: translation-free."""
    lead = vertices.shape[:-2]
    centred = (vertices - vertices.mean(axis=-2, keepdims=True)).reshape((-1,) + vertices.shape[-2:])
    order = np.asarray(faces, dtype=np.int64).T.ravel()                   # a's, then b's, then c's
    num = len(centred)
    x, y, z = (centred[:, :, k][:, order].reshape(num, 3, -1) for k in range(3))
    n_z = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (y[:, 1] - y[:, 0]) * (x[:, 2] - x[:, 0])
    return (np.einsum("nf,nf->n", z.sum(axis=1), n_z) / 6.0).reshape(lead)


def mesh_is_closed(faces: np.ndarray) -> bool:
    """Every edge of the triangle mesh ``faces`` (F, 3) is shared by exactly two faces: a closed surface, whose
    signed volume tells inside from outside (SMPL-format bodies are; a test model of random triangles is not)."""
    cached = _CLOSED_MESHES.get(id(faces))
    if cached is not None and cached[0] is faces:          # a model's faces, checked once per process
        return cached[1]
    key = faces
    faces = np.asarray(faces, dtype=np.int64)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    closed = bool(len(counts)) and bool(np.all(counts == 2))
    _CLOSED_MESHES[id(key)] = (key, closed)
    return closed


_CLOSED_MESHES: dict[int, tuple[np.ndarray, bool]] = {}


def _rest_orientation(model) -> tuple[float, float]:
    """``(sign, volume)``: the sign that makes the mean shape's rest mesh positive, and its volume, m^3."""
    rest = _signed_volumes(model.forward(np.zeros(72), np.zeros(model.num_betas)).vertices, model.faces)
    return (float(np.sign(rest)) or 1.0), abs(float(rest))


def mesh_signed_volumes(model, pose: np.ndarray, betas: np.ndarray, chunk: int = 32) -> np.ndarray:
    """Signed volume (T,) in m^3 of the posed mesh of each frame (``pose`` (T, 72), shared ``betas`` (B,)),
    with the model's faces oriented outward at rest: the sign is chosen so that the mean shape in the rest
    pose has a positive volume, whatever winding the model file uses.  Negative: the body is inside out.
    (The volume does not depend on the translation.)"""
    pose = np.asarray(pose, float).reshape(-1, 72)
    betas = np.asarray(betas, float)
    orientation, _ = _rest_orientation(model)
    out = np.empty(len(pose))
    for start in range(0, len(pose), chunk):
        part = pose[start:start + chunk]
        verts = model.forward(part, np.broadcast_to(betas, (len(part), betas.size))).vertices
        out[start:start + chunk] = orientation * _signed_volumes(verts, model.faces)
    return out


def body_plausibility(model, pose: np.ndarray, betas: np.ndarray, per_frame: bool = True
                      ) -> tuple[list[dict], dict]:
    """``(per_frame, track)`` plausibility fields of a fitted track (module docstring): the posed meshes'
    signed volumes, the count of inside-out frames, the volume relative to the mean shape's and the
    largest ``|beta_i|``.  An inside-out result is logged as a warning (it is a bug to fix).

    ``per_frame=False`` (a run with covariances and diagnostics off, timed as the solve alone: the posed
    meshes cost ~1-2 ms per frame) checks the track's shape in the rest pose instead (one mesh; a shape that
    turns the body inside out does so in every pose): ``mesh_check`` says which was done, the per-frame list
    is empty and ``inside_out_frames`` is all or none of the frames."""
    pose = np.asarray(pose, float).reshape(-1, 72)
    betas = np.asarray(betas, float)
    orientation, reference = _rest_orientation(model)
    if per_frame:
        volumes = mesh_signed_volumes(model, pose, betas)
    else:
        rest = model.forward(np.zeros(72), betas).vertices
        volumes = np.full(len(pose), orientation * float(_signed_volumes(rest, model.faces)))
    inside_out = int(np.count_nonzero(volumes <= 0.0))
    if inside_out:
        log.warning("%d of %d fitted meshes are inside out (max |beta| %.1f)",
                                            inside_out, len(volumes), float(np.max(np.abs(betas))))
    frames = [{"mesh_signed_volume_m3": float(v)} for v in volumes] if per_frame else []
    track = {"mesh_check": "per_frame" if per_frame else "rest_pose", "inside_out_frames": inside_out,
             "mesh_closed": mesh_is_closed(model.faces),
             "min_mesh_signed_volume_m3": float(volumes.min()) if len(volumes) else float("nan"),
             "mesh_volume_ratio": float(np.median(volumes) / reference) if len(volumes) else float("nan"),
             "max_abs_beta": float(np.max(np.abs(betas))) if betas.size else 0.0}
    return frames, track


def _frame_camera_count(frame) -> int:
    """Cameras with at least one labelled keypoint at ``frame`` (every stereo pair's views when the frame
    lists them, else its left and right)."""
    views = frame.labelled_views() if hasattr(frame, "labelled_views") else \
        [(None, side, view) for side, view in (("left", frame.left), ("right", frame.right)) if view is not None]
    return sum(bool(np.any(view.labelled)) for _, _, view in views)


def is_monocular(frames, min_lidar_points: int = 3) -> bool:
    """True when no frame has keypoints in two cameras and none has ``min_lidar_points`` finite LiDAR points
    (the initialisation's threshold for a LiDAR centroid): the track's depth comes from body size alone."""
    for frame in frames:
        if _frame_camera_count(frame) >= 2:
            return False
        points = np.asarray(frame.world_lidar_points, dtype=float).reshape(-1, 3)
        if np.count_nonzero(np.all(np.isfinite(points), axis=1)) >= min_lidar_points:
            return False
    return True
