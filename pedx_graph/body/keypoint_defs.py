"""Where the 18 PedX keypoints sit on a body model, as a small sparse linear map.

A keypoint set is ``keypoints = C_v @ vertices[vertex_ids] + C_j @ joints`` with ``C_v`` (K, m) over the few
vertices actually used and ``C_j`` (K, J) over the posed joints; equivalently one sparse (K, V + J) matrix over
``[vertices; joints]`` (:meth:`KeypointMap.as_sparse`).  Keypoints and their Jacobians therefore only need
those ``m`` vertices.

Sources, in order:

1. the model file's ``pedx_keypoint_names / pedx_keypoint_vertex_ids / pedx_keypoint_joint_ids`` keys;
2. for a real SMPL topology (V = 6890) without them, :data:`SMPL_TOPOLOGY_KEYPOINTS`: the vertex ids smplx uses
   for nose (332), right eye (6260), left eye (2800); the mouth by the rule in :data:`SMPL_MOUTH_RULE`
   (no confirmed SMPL lip-centre vertex id was found); the other keypoints are SMPL joints;
3. on request only (``joints_only=True``), a joints-only fallback for any other model: face keypoints
   (nose, eyes, mouth) are placed at the head joint (15).  This is crude (several cm off) and is logged.
"""
from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from pedx_graph.data.types import DataFormatError
from pedx_graph.keypoints import PEDX_KEYPOINTS
from pedx_graph.keypoints import KEYPOINT_SET_DIR, KeypointSet, keypoint_set_names, load_keypoint_set  # noqa: F401

log = logging.getLogger(__name__)

#: Vertex count of the SMPL topology.
SMPL_NUM_VERTICES = 6890

#: PedX keypoints that are SMPL joints (name -> joint index; SMPL's own joint names in comments).
SMPL_JOINT_KEYPOINTS: dict[str, int] = {
    "head": 15, "neck": 12,                     # head, neck
    "lsho": 16, "rsho": 17,                     # left/right_shoulder
    "lelb": 18, "relb": 19,                     # left/right_elbow
    "lwri": 20, "rwri": 21,                     # left/right_wrist
    "lhip": 1, "rhip": 2,                       # left/right_hip
    "lknee": 4, "rknee": 5,                     # left/right_knee
    "lankl": 7, "rankl": 8,                     # left/right_ankle
}

#: Face keypoints on the SMPL topology that are single vertices (smplx's vertex ids).
SMPL_VERTEX_KEYPOINTS: dict[str, int] = {"nose": 332, "reye": 6260, "leye": 2800}

#: Mouth on the SMPL topology: ``mouth = nose_vertex + 0.35 (neck_joint - head_joint)``, i.e. the nose tip
#: moved along the head's downward axis by 35 % of the head-neck joint distance (about 3 cm down and 1.5 cm
#: back on a mean body).  Coefficients over ``[vertex 332, joint 12, joint 15]``; they sum to one, so the
#: point moves rigidly with the head.  An approximation: PedX annotators click the lip centre.  Sanity check
#: on the open default model (its own lip-centre vertex, mean shape, T-pose): the rule lands 8 mm away.
SMPL_MOUTH_RULE: dict[str, tuple[tuple[int, float], ...]] = {
    "vertices": ((332, 1.0),),
    "joints": ((12, 0.35), (15, -0.35)),
}


@dataclass(frozen=True)
class KeypointMap:
    """Keypoints as a linear map over a few vertices and the joints: ``kp = C_v x[vertex_ids] + C_j joints``."""

    names: tuple[str, ...]
    """(K,) keypoint names (PEDX_KEYPOINTS order, or the order of a keypoint set's data file)."""
    vertex_ids: np.ndarray
    """(m,) distinct vertex ids used by any keypoint (int64, may be empty)."""
    vertex_coeffs: np.ndarray
    """(K, m) coefficients of those vertices."""
    joint_coeffs: np.ndarray
    """(K, J) coefficients of the posed joints."""
    source: str
    """How the map was obtained: 'file', 'smpl-topology', 'joints-only', or '<set>:open' / '<set>:smpl' for
    a keypoint set's data file (:func:`keypoint_set_map`)."""

    @property
    def num_keypoints(self) -> int:
        return len(self.names)

    def apply(self, vertices_subset: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """Keypoints (..., K, 3) from the used vertices (..., m, 3) and joints (..., J, 3)."""
        out = np.einsum("kj,...jc->...kc", self.joint_coeffs, joints)
        if self.vertex_ids.size:
            out = out + np.einsum("km,...mc->...kc", self.vertex_coeffs, vertices_subset)
        return out

    def as_sparse(self, num_vertices: int) -> sp.csr_matrix:
        """The map as one sparse (K, V + J) matrix over ``[vertices; joints]``."""
        num_k, num_j = self.joint_coeffs.shape
        full_v = sp.csr_matrix((self.vertex_coeffs.ravel(),
                                (np.repeat(np.arange(num_k), len(self.vertex_ids)),
                                 np.tile(self.vertex_ids, num_k))), shape=(num_k, num_vertices))
        out = sp.hstack([full_v, sp.csr_matrix(self.joint_coeffs)], format="csr")
        out.eliminate_zeros()
        return out


def _build(entries: dict[str, tuple[tuple[tuple[int, float], ...], tuple[tuple[int, float], ...]]],
           num_joints: int, source: str) -> KeypointMap:
    """entries: name -> ((vertex, coeff)...,), ((joint, coeff)...,) for every PEDX keypoint."""
    return _build_named(PEDX_KEYPOINTS, entries, num_joints, source)


def from_ids(vertex_ids: np.ndarray, joint_ids: np.ndarray, num_joints: int = 24,
             source: str = "file") -> KeypointMap:
    """Map from per-keypoint vertex ids / joint ids (18 each; exactly one of the two >= 0 per keypoint)."""
    entries = {}
    for k, name in enumerate(PEDX_KEYPOINTS):
        v, j = int(vertex_ids[k]), int(joint_ids[k])
        if (v >= 0) == (j >= 0):
            raise ValueError(f"keypoint '{name}': exactly one of vertex id ({v}) and joint id ({j}) must be >= 0")
        entries[name] = (((v, 1.0),), ()) if v >= 0 else ((), ((j, 1.0),))
    return _build(entries, num_joints, source)


def smpl_topology_map(num_joints: int = 24) -> KeypointMap:
    """The map for a real SMPL mesh (V = 6890) without pedx keypoint keys (see module docstring)."""
    entries = {}
    for name in PEDX_KEYPOINTS:
        if name in SMPL_JOINT_KEYPOINTS:
            entries[name] = ((), ((SMPL_JOINT_KEYPOINTS[name], 1.0),))
        elif name in SMPL_VERTEX_KEYPOINTS:
            entries[name] = (((SMPL_VERTEX_KEYPOINTS[name], 1.0),), ())
        elif name == "mouth":
            entries[name] = (SMPL_MOUTH_RULE["vertices"], SMPL_MOUTH_RULE["joints"])
        else:                                          # pragma: no cover - guarded by the names test
            raise KeyError(name)
    return _build(entries, num_joints, "smpl-topology")


def joints_only_map(num_joints: int = 24) -> KeypointMap:
    """Fallback without any vertex: face keypoints at the head joint (15), the rest at their SMPL joints."""
    entries = {name: ((), ((SMPL_JOINT_KEYPOINTS.get(name, 15), 1.0),)) for name in PEDX_KEYPOINTS}
    return _build(entries, num_joints, "joints-only")


def keypoint_map_for_model(data, joints_only: bool = False) -> KeypointMap:
    """The keypoint map of a :class:`pedx_graph.body.io.ModelData` (file keys > SMPL topology > fallback).

    Raises ValueError naming the model file when it has no keypoint keys, is not the SMPL topology and
    ``joints_only`` is False.
    """
    num_joints = len(data.parents)
    if data.keypoint_vertex_ids is not None:
        return from_ids(data.keypoint_vertex_ids, data.keypoint_joint_ids, num_joints, "file")
    if data.num_vertices == SMPL_NUM_VERTICES:
        if data.provenance is not None:
            log.warning("%s: 6890 vertices and a provenance record but no pedx keypoint keys; assuming the SMPL "
                        "topology (face keypoints at SMPL vertex ids), which is wrong for a re-meshed model",
                        data.source)
        return smpl_topology_map(num_joints)
    if joints_only:
        log.warning("%s: no pedx keypoint keys and not the SMPL topology; face keypoints (nose, eyes, mouth) "
                    "fall back to the head joint", data.source)
        return joints_only_map(num_joints)
    raise ValueError(
        f"{data.source}: the model has {data.num_vertices} vertices (not the SMPL topology, {SMPL_NUM_VERTICES}) "
        f"and no 'pedx_keypoint_names' / 'pedx_keypoint_vertex_ids' / 'pedx_keypoint_joint_ids' keys, so the "
        f"PedX face keypoints cannot be placed; add those keys or load with joints_only_keypoints=True")


# ------------------------------------------------------------------------------------------------ keypoint sets
# The sets' names and data files are read by :mod:`pedx_graph.keypoints` (the label readers need them below the
# body layer); re-exported here beside their definitions on the body model.


def faces_digest(faces: np.ndarray) -> str:
    """First 16 hex digits of the SHA-256 of the (F, 3) faces as int64: identifies a mesh topology."""
    return hashlib.sha256(np.ascontiguousarray(faces, dtype=np.int64).tobytes()).hexdigest()[:16]


def read_keypoint_set_file(path: str | Path) -> KeypointSet:
    """A keypoint set written outside the package (``pedx-graph calibrate-keypoints``: a shipped set with its
    definitions moved to a detector's points), checked against the shipped set of its name: the same
    keypoints in the same order, PedX equivalents and topologies, every point's definition a list of
    ``[id, coefficient]`` pairs.  Raises ``DataFormatError`` naming the file and the field."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataFormatError(path, None, f"not a readable JSON keypoint set ({exc})") from None
    if not isinstance(doc, dict):
        raise DataFormatError(path, None, "expected a JSON object")
    name = doc.get("name")
    if name not in keypoint_set_names() or name == "pedx18":
        raise DataFormatError(path, "name", f"expected one of the detector sets "
                              f"{', '.join(n for n in keypoint_set_names() if n != 'pedx18')}, got {name!r}")
    shipped = load_keypoint_set(name)
    if tuple(doc.get("keypoints") or ()) != shipped.keypoints:
        raise DataFormatError(path, "keypoints",
                              f"must be the {len(shipped.keypoints)} keypoints of {name} in its order")
    if doc.get("pedx_equivalent") != shipped.pedx_equivalent:
        raise DataFormatError(path, "pedx_equivalent", f"must be {name}'s")
    definitions = doc.get("definitions")
    if not isinstance(definitions, dict) or set(definitions) != set(shipped.definitions):
        raise DataFormatError(path, "definitions", f"must hold the topologies {sorted(shipped.definitions)}")
    for topology, entry in definitions.items():
        for key in ("num_vertices", "faces_sha256_16"):
            if key in shipped.definitions[topology] and entry.get(key) != shipped.definitions[topology][key]:
                raise DataFormatError(path, f"definitions.{topology}.{key}", f"must be {name}'s")
        points = entry.get("points")
        if not isinstance(points, dict) or set(points) != set(shipped.keypoints):
            raise DataFormatError(path, f"definitions.{topology}.points", "must define every keypoint of the set")
        limit = shipped.definitions[topology].get("num_vertices", 10 ** 9)
        for point, terms in points.items():
            for kind in ("vertices", "joints"):
                pairs = terms.get(kind) if isinstance(terms, dict) else None
                ok = isinstance(pairs, list) and all(
                    isinstance(x, list) and len(x) == 2 and isinstance(x[0], int) and isinstance(x[1], (int, float))
                    and 0 <= x[0] < (limit if kind == "vertices" else 64) and np.isfinite(x[1]) for x in pairs)
                if not ok:
                    raise DataFormatError(path, f"definitions.{topology}.points.{point}.{kind}",
                                          "expected a list of [id, coefficient] pairs within the model")
    return KeypointSet(name=name, keypoints=shipped.keypoints, pedx_equivalent=shipped.pedx_equivalent,
                       definitions=definitions, description=str(doc.get("description", "")))


def read_keypoint_set_folder(folder: str | Path) -> dict[str, KeypointSet]:
    """Every ``<set>.json`` of ``folder`` read by :func:`read_keypoint_set_file`, by set name (a file named
    other than its set is refused).  Raises ``DataFormatError`` for a missing folder or a bad file."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataFormatError(folder, None, "no such folder of keypoint sets")
    out = {}
    for path in sorted(folder.glob("*.json")):
        kset = read_keypoint_set_file(path)
        if kset.name != path.stem:
            raise DataFormatError(path, "name", f"a file named {path.name} must hold the set {path.stem!r}")
        out[kset.name] = kset
    return out


def set_topology(data, set_name: str) -> str:
    """Which of a keypoint set's definitions fit the model ``data``: ``"open"`` when its faces match the open
    model's digest, ``"smpl"`` for the SMPL topology (V = 6890); any other model raises ValueError naming it."""
    open_defs = load_keypoint_set(set_name).definitions["open"]
    if data.num_vertices == open_defs["num_vertices"] and faces_digest(data.faces) == open_defs["faces_sha256_16"]:
        return "open"
    if data.num_vertices == SMPL_NUM_VERTICES:
        return "smpl"
    raise ValueError(f"{data.source}: keypoint set {set_name!r} is defined on the open model and the SMPL "
                     f"topology only; this model has {data.num_vertices} vertices")


def keypoint_set_map(data, set_name: str, kset: KeypointSet | None = None) -> KeypointMap:
    """The :class:`KeypointMap` of keypoint set ``set_name`` on the model ``data`` (a ModelData).

    ``pedx18`` is the model's own PedX map (:func:`keypoint_map_for_model`).  Other sets use the data file's
    definitions for the model's topology (:func:`set_topology`): the shipped file's, or ``kset``'s (a set
    read from a file of its own, :func:`read_keypoint_set_file`).
    """
    if set_name == "pedx18":
        return keypoint_map_for_model(data)
    topology = set_topology(data, set_name)
    kset = load_keypoint_set(set_name) if kset is None else kset
    points = kset.definitions[topology]["points"]
    entries = {n: (tuple((int(v), float(c)) for v, c in points[n]["vertices"]),
                   tuple((int(j), float(c)) for j, c in points[n]["joints"])) for n in kset.keypoints}
    source = f"{set_name}:{topology}" if kset is load_keypoint_set(set_name) else f"{set_name}:{topology}:own-file"
    return _build_named(kset.keypoints, entries, len(data.parents), source)


def _build_named(names: tuple[str, ...], entries: dict, num_joints: int, source: str) -> KeypointMap:
    """entries: name -> ((vertex, coeff)...,), ((joint, coeff)...,) for every name of ``names``."""
    used = sorted({v for name in names for v, _ in entries[name][0]})
    col = {v: i for i, v in enumerate(used)}
    vertex_coeffs = np.zeros((len(names), len(used)))
    joint_coeffs = np.zeros((len(names), num_joints))
    for k, name in enumerate(names):
        verts, joints = entries[name]
        for v, c in verts:
            vertex_coeffs[k, col[v]] += c
        for j, c in joints:
            joint_coeffs[k, j] += c
    return KeypointMap(names=tuple(names), vertex_ids=np.array(used, dtype=np.int64),
                       vertex_coeffs=vertex_coeffs, joint_coeffs=joint_coeffs, source=source)


#: Shoulder joints' rotations (axis-angle, SMPL joints 16 / 17) that bring the rest pose's arms down.
_ARMS_DOWN = {16: (0.0, 0.0, -1.1), 17: (0.0, 0.0, 1.1)}


def standing_keypoints_3d(body_model, set_name: str) -> np.ndarray:
    """(K, 3) the keypoints of set ``set_name`` on ``body_model`` standing with its arms down (mean shape), in
    the model's own frame (SMPL: x the body's left, y up, z forward), metres."""
    pose = np.zeros(72)
    for joint, rotvec in _ARMS_DOWN.items():
        pose[3 * joint:3 * joint + 3] = rotvec
    model = body_model.for_keypoint_set(set_name)
    return np.asarray(model.forward(pose, np.zeros(model.num_betas)).keypoints, dtype=float)


def standing_keypoints_2d(body_model, set_name: str) -> np.ndarray:
    """(K, 2) the keypoints of set ``set_name`` on ``body_model`` standing with its arms down (mean shape),
    seen from the front: image-like coordinates (``v`` down), ``u`` centred, unit height (``v`` from 0 at
    the top keypoint to 1 at the bottom one)."""
    body_p = standing_keypoints_3d(body_model, set_name)
    uv = np.stack([-body_p[:, 0], -body_p[:, 1]], axis=1)
    uv -= [uv[:, 0].mean(), uv[:, 1].min()]
    return uv / max(np.ptp(uv[:, 1]), 1e-6)
