"""``BodyModel``: a stateless SMPL-format body model layer (arrays only, never an estimate).

Inputs of every method (float arrays, broadcast against each other over leading dims ``...``):

* ``pose`` (..., 72): axis-angle of the 24 joints; ``pose[..., :3]`` is the root orientation ``world_R_body``
  (``Rot3.Logmap``), the other 69 entries are the body pose, each joint relative to its parent;
* ``betas`` (..., B) shape coefficients (``B = num_betas``);
* ``trans`` (..., 3) world translation (metres) added after skinning, as smplx does: the root rotates about
  the rest pelvis ``J_0(betas)``, so the pelvis lands at ``J_0(betas) + trans`` (not at ``trans``).

Outputs are in the world frame (the body frame rotated by the root and shifted by ``trans``), metres, float64.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from pedx_graph.body import jacobians as jac
from pedx_graph.body.io import ModelData, load_model_data
from pedx_graph.body.keypoint_defs import KeypointMap, keypoint_map_for_model, keypoint_set_map
from pedx_graph.body.lbs import (batch_rigid_transform, descendant_mask, pose_features, skin, skin_frames_last,
                                 vertices2joints)
from pedx_graph.body.normals import unit, vertex_normals
from pedx_graph.body.rotation import exp_and_right_jacobian, exp_so3, exp_so3_derivative

#: File name of the open default model inside ``pedx_graph/body/data``.
DEFAULT_MODEL_NAME = "pedx_open_neutral.npz"

#: Frames processed together in the full-mesh forward pass: memory ~ 16 V CHUNK doubles (56 MB for SMPL);
#: larger chunks amortise reading ``posedirs`` (34 MB for SMPL) once per chunk.
FORWARD_CHUNK = 64


def default_model_path() -> Path:
    """Path of the open default model shipped with the package (may not exist in a source checkout)."""
    return Path(__file__).resolve().parent / "data" / DEFAULT_MODEL_NAME


@dataclass(frozen=True)
class BodyOutput:
    """Result of :meth:`BodyModel.forward` (world frame, metres)."""

    vertices: np.ndarray
    """(..., V, 3) posed vertices."""
    joints: np.ndarray
    """(..., J, 3) posed joints."""
    keypoints: np.ndarray
    """(..., 18, 3) PedX keypoints (PEDX_KEYPOINTS order)."""


@dataclass(frozen=True)
class JacobianSetup:
    """What every Jacobian of N frames shares (:meth:`BodyModel.jacobian_setup`): the kinematics and the
    per-joint derivative bases.  Pass it to :meth:`BodyModel.point_jacobians`,
    :meth:`BodyModel.vertex_jacobians_per_frame` (and its ``kin`` to :meth:`BodyModel.vertices_subset`) for
    the same pose and betas to skip recomputing it."""

    kin: object
    """:class:`pedx_graph.body.lbs.Kinematics` (N frames)."""
    bases: np.ndarray
    """(N, J, 3, 3) parameter-to-world-rotation bases (:func:`pedx_graph.body.jacobians.rotation_bases`)."""
    dt_dbeta: np.ndarray
    """(N, J, 3, B) shape derivative of the skinning translations."""
    drot: np.ndarray | None
    """(N, J-1, 3, 3, 3) derivative of each body joint's rotation (None without pose correctives)."""

    def __iter__(self):               # kin, bases, dt_dbeta, drot = setup
        return iter((self.kin, self.bases, self.dt_dbeta, self.drot))

    def rows(self, index: np.ndarray) -> "JacobianSetup":
        """The setup of the frames ``index`` only."""
        kin = type(self.kin)(**{name: getattr(self.kin, name)[index] for name in self.kin.__dataclass_fields__})
        return JacobianSetup(kin, self.bases[index], self.dt_dbeta[index],
                             None if self.drot is None else self.drot[index])


@dataclass(frozen=True)
class _VertexSubset:
    """Model arrays of a few vertices, rows of the flat arrays ordered (vertex, coordinate)."""

    vertex_ids: np.ndarray
    template_flat: np.ndarray          # (3P,)
    shapedirs_flat: np.ndarray         # (3P, B)
    posedirs_flat: np.ndarray | None   # (3P, 207)
    weights: np.ndarray                # (P, J)


class BodyModel:
    """Stateless SMPL-format body model: LBS forward pass, PedX keypoints and analytic Jacobians.

    Build with :meth:`load` (a file) or :meth:`from_data` (validated arrays).  Holds only model arrays and
    derived constants; every method is a pure function of its arguments.
    """

    def __init__(self, data: ModelData, keypoint_map: KeypointMap | None):
        self.data = data
        self.keypoint_map = keypoint_map
        self.v_template = data.v_template
        self.shapedirs = data.shapedirs
        self.posedirs = data.posedirs
        self.j_regressor = data.j_regressor
        self.weights = data.weights
        self._parents = data.parents
        num_v = data.num_vertices
        self._shapedirs_flat = np.ascontiguousarray(self.shapedirs.reshape(num_v * 3, -1))        # (3V, B)
        self._posedirs_flat = (None if self.posedirs is None else
                               np.ascontiguousarray(self.posedirs.reshape(num_v * 3, -1)))        # (3V, 207)
        self._v_template_col = self.v_template.reshape(num_v * 3, 1)
        self._weights_csr = sp.csr_matrix(self.weights)
        self._desc = descendant_mask(self._parents)
        # Rest joints are linear in betas: J(beta) = J_template + J_shapedirs . beta.
        self._joint_template = vertices2joints(self.j_regressor, self.v_template)                   # (J, 3)
        jsd = self.j_regressor @ self.shapedirs.reshape(num_v, -1)                                 # (J, 3B)
        self._joint_shapedirs = np.asarray(jsd).reshape(len(self._parents), 3, -1)                # (J, 3, B)
        self._kp_subset = None
        self._last_subset = None
        self._rest_normals = None            # the template's vertex normals, computed on first use
        if keypoint_map is not None:
            if keypoint_map.vertex_ids.size:
                self._kp_subset = self._subset(keypoint_map.vertex_ids)
            used_j = np.flatnonzero(np.any(keypoint_map.joint_coeffs != 0.0, axis=0))
            self._kp_joint_pairs = (used_j, jac.ancestor_pairs(self._desc, used_j))
            self._kp_coeffs = np.concatenate([keypoint_map.joint_coeffs[:, used_j], keypoint_map.vertex_coeffs],
                                             axis=1)                                     # (K, Q + m)
            self._kp_gain = self._trans_gain(keypoint_map)

    # ----------------------------------------------------------------------------------- construction

    @classmethod
    def from_data(cls, data: ModelData, joints_only_keypoints: bool = False) -> "BodyModel":
        """Model from validated arrays; keypoints as in :func:`keypoint_map_for_model`."""
        return cls(data, keypoint_map_for_model(data, joints_only=joints_only_keypoints))

    @classmethod
    def load(cls, path: str | Path | None = None, num_betas: int = 10,
             joints_only_keypoints: bool = False) -> "BodyModel":
        """Load an SMPL-format ``.npz``/``.pkl`` (default: the open model ``pedx_open_neutral.npz``).

        Raises FileNotFoundError if the file is missing, ``ModelFormatError`` if it is malformed, ValueError
        if the PedX keypoints cannot be placed (see :mod:`pedx_graph.body.keypoint_defs`).
        """
        if path is None:
            path = default_model_path()
            if not path.is_file():
                raise FileNotFoundError(
                    f"the open default body model {DEFAULT_MODEL_NAME} is not installed (expected at "
                    f"pedx_graph/body/data/{DEFAULT_MODEL_NAME}); build it with tools/build_open_body_model.py "
                    f"or pass an SMPL-format .npz/.pkl path")
        return cls.from_data(load_model_data(path, num_betas=num_betas), joints_only_keypoints)

    # ------------------------------------------------------------------------------------- properties

    @property
    def faces(self) -> np.ndarray:
        """(F, 3) int64 triangle vertex indices."""
        return self.data.faces

    @property
    def parents(self) -> np.ndarray:
        """(J,) int64 parent joint of each joint, -1 for the root."""
        return self._parents

    @property
    def num_betas(self) -> int:
        return self.data.num_betas

    @property
    def num_vertices(self) -> int:
        return self.data.num_vertices

    @property
    def num_joints(self) -> int:
        return len(self._parents)

    @property
    def provenance(self) -> dict | None:
        """The file's provenance record (parsed JSON), or None."""
        return self.data.provenance

    @property
    def keypoint_names(self) -> tuple[str, ...]:
        return self._kpmap().names

    @property
    def source(self) -> str:
        return self.data.source

    @property
    def keypoint_set(self) -> str:
        """Name of the keypoint set :meth:`keypoints` returns (``"pedx18"`` unless :meth:`for_keypoint_set`)."""
        return getattr(self, "_keypoint_set", "pedx18")

    @property
    def report_model(self) -> "BodyModel":
        """The model whose keypoints results report (PedX's 18): this model, or for a detector track's fit
        layout (``pedx_graph.detections.fit_layout.layout_model``, 18 + E keypoints) the model it was made
        from."""
        return getattr(self, "_report_model", self)

    @report_model.setter
    def report_model(self, model: "BodyModel") -> None:
        self._report_model = model

    @property
    def keypoint_sets(self) -> dict:
        """Keypoint sets read from files of their own (set name -> ``KeypointSet``,
        :func:`pedx_graph.body.keypoint_defs.read_keypoint_set_folder`) whose definitions replace the shipped ones on
        this model; empty: the shipped sets."""
        return self.__dict__.get("_keypoint_sets", {})

    @keypoint_sets.setter
    def keypoint_sets(self, sets: dict) -> None:
        if self.__dict__.get("_set_models") or self.__dict__.get("_layout_models"):
            raise ValueError("keypoint sets must be given before the model's keypoint-set models are made")
        self._keypoint_sets = dict(sets)

    def keypoint_set_map(self, set_name: str) -> KeypointMap:
        """The :class:`KeypointMap` of keypoint set ``set_name`` on this model (:func:`keypoint_set_map`; a set
        of :attr:`keypoint_sets` replaces the shipped one)."""
        return keypoint_set_map(self.data, set_name, self.keypoint_sets.get(set_name))

    def for_keypoint_set(self, set_name: str) -> "BodyModel":
        """This model with :meth:`keypoints` (and their Jacobians) in keypoint set ``set_name``'s order and
        definitions; the same object for its own set, one cached model per set otherwise."""
        if set_name == self.keypoint_set:
            return self
        cache = self.__dict__.setdefault("_set_models", {})
        if set_name not in cache:
            other = BodyModel(self.data, self.keypoint_set_map(set_name))
            other._keypoint_set = set_name
            other._keypoint_sets = self.keypoint_sets
            cache[set_name] = other
        return cache[set_name]

    def __repr__(self) -> str:
        return (f"BodyModel(V={self.num_vertices}, J={self.num_joints}, B={self.num_betas}, "
                f"posedirs={'yes' if self.posedirs is not None else 'no'}, source={self.source!r})")

    # --------------------------------------------------------------------------------------- helpers

    def _kpmap(self) -> KeypointMap:
        if self.keypoint_map is None:
            raise ValueError(f"{self.source}: this model has no keypoint definition")
        return self.keypoint_map

    def _prepare(self, pose, betas, trans):
        """Flatten broadcast inputs to (N, 72), (N, B), (N, 3); returns them and the batch shape."""
        pose = np.asarray(pose, dtype=np.float64)
        betas = np.asarray(betas, dtype=np.float64)
        trans = np.zeros(3) if trans is None else np.asarray(trans, dtype=np.float64)
        num_j = self.num_joints
        if pose.shape[-1:] != (3 * num_j,):
            raise ValueError(f"pose must have shape (..., {3 * num_j}), got {pose.shape}")
        if betas.shape[-1:] != (self.num_betas,):
            raise ValueError(f"betas must have shape (..., {self.num_betas}), got {betas.shape}")
        if trans.shape[-1:] != (3,):
            raise ValueError(f"trans must have shape (..., 3), got {trans.shape}")
        lead = np.broadcast_shapes(pose.shape[:-1], betas.shape[:-1], trans.shape[:-1])
        num_n = int(np.prod(lead, dtype=np.int64))
        pose, betas, trans = (
            (arr if arr.shape[:-1] == lead else np.broadcast_to(arr, lead + arr.shape[-1:])).reshape(num_n, -1)
            for arr in (pose, betas, trans))
        return pose, betas, trans, lead

    def rest_joints(self, betas: np.ndarray) -> np.ndarray:
        """Rest (T-pose) joint locations ``J_regressor @ v_shaped``: betas (..., B) -> (..., J, 3)."""
        betas = np.asarray(betas, dtype=np.float64)
        return self._joint_template + np.einsum("jcb,...b->...jc", self._joint_shapedirs, betas)

    def _kinematics(self, pose, betas):
        axis_angle = pose.reshape(pose.shape[0], self.num_joints, 3)
        rot_mats = exp_so3(axis_angle)
        return batch_rigid_transform(rot_mats, self.rest_joints(betas), self._parents)

    def _subset(self, vertex_ids: np.ndarray) -> "_VertexSubset":
        """Model arrays gathered for a few vertices (cached for the keypoint vertices)."""
        for cached in (self._kp_subset, self._last_subset):
            if cached is not None and cached.vertex_ids.shape == vertex_ids.shape \
                    and np.array_equal(cached.vertex_ids, vertex_ids):
                return cached
        rows = (3 * vertex_ids[:, None] + np.arange(3)).ravel()
        sub = _VertexSubset(
            vertex_ids=vertex_ids, template_flat=self._v_template_col[rows, 0],
            shapedirs_flat=self._shapedirs_flat[rows],
            posedirs_flat=None if self._posedirs_flat is None else self._posedirs_flat[rows],
            weights=self.weights[vertex_ids])
        if len(vertex_ids) >= 64:         # large fixed sets (e.g. the chamfer candidates) are reused per call
            self._last_subset = sub
        return sub

    def _rest_points(self, sub: "_VertexSubset", betas, rot_mats):
        """Shaped + pose-corrected rest positions of a few vertices: (N, P, 3)."""
        flat = betas @ sub.shapedirs_flat.T + sub.template_flat                     # (N, 3P)
        if sub.posedirs_flat is not None:
            flat += pose_features(rot_mats) @ sub.posedirs_flat.T
        return flat.reshape(len(betas), -1, 3)

    # --------------------------------------------------------------------------------------- forward

    def forward(self, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray | None = None) -> BodyOutput:
        """Full LBS: vertices (..., V, 3), joints (..., J, 3), keypoints (..., 18, 3) in metres."""
        pose, betas, trans, lead = self._prepare(pose, betas, trans)
        num_n, num_v = pose.shape[0], self.num_vertices
        vertices = np.empty((num_n, num_v, 3))
        joints = np.empty((num_n, self.num_joints, 3))
        for start in range(0, num_n, FORWARD_CHUNK):
            sl = slice(start, min(start + FORWARD_CHUNK, num_n))
            kin = self._kinematics(pose[sl], betas[sl])
            # Frame-last layout (3V, n): shape and pose blend shapes are plain BLAS products.
            rest = self._shapedirs_flat @ betas[sl].T
            rest += self._v_template_col
            if self._posedirs_flat is not None:
                rest += self._posedirs_flat @ pose_features(kin.rot_mats).T
            posed = skin_frames_last(rest.reshape(num_v, 3, -1), self._weights_csr, kin.world_rot,
                                     kin.bone_trans)
            np.add(posed.transpose(2, 0, 1), trans[sl, None], out=vertices[sl])
            joints[sl] = kin.world_origin + trans[sl, None]
        keypoints = None
        if self.keypoint_map is not None:
            kp = self.keypoint_map
            keypoints = kp.apply(vertices[:, kp.vertex_ids], joints).reshape(lead + (kp.num_keypoints, 3))
        return BodyOutput(vertices=vertices.reshape(lead + (num_v, 3)),
                          joints=joints.reshape(lead + (self.num_joints, 3)), keypoints=keypoints)

    def joints(self, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray | None = None) -> np.ndarray:
        """Posed joints (..., J, 3) without computing any vertex."""
        pose, betas, trans, lead = self._prepare(pose, betas, trans)
        kin = self._kinematics(pose, betas)
        return (kin.world_origin + trans[:, None]).reshape(lead + (self.num_joints, 3))

    def vertices_subset(self, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray | None,
                        vertex_ids: np.ndarray, kinematics=None) -> np.ndarray:
        """Posed positions (..., P, 3) of the vertices ``vertex_ids`` (P,) only (``kinematics``: those of these
        pose and betas, e.g. a :class:`JacobianSetup`'s ``kin``, if already computed)."""
        pose, betas, trans, lead = self._prepare(pose, betas, trans)
        vertex_ids = np.asarray(vertex_ids, dtype=np.int64)
        kin = self._kinematics(pose, betas) if kinematics is None else kinematics
        sub = self._subset(vertex_ids)
        rest = self._rest_points(sub, betas, kin.rot_mats)
        pts = skin(rest, sub.weights, kin.world_rot, kin.bone_trans) + trans[:, None]
        return pts.reshape(lead + (len(vertex_ids), 3))

    def vertex_normals_subset(self, pose: np.ndarray, betas: np.ndarray, vertex_ids: np.ndarray,
                              kinematics=None) -> np.ndarray:
        """Unit normals (..., P, 3) of the posed vertices ``vertex_ids`` (P,): the rest template's area-weighted
        vertex normals turned by each vertex's blended joint rotation (skinning applied to directions; the
        shape and pose blend shapes' small tilt of the surface is left out).  For telling which side of the
        body faces a sensor, not for shading (:mod:`pedx_graph.solvers.marginals.normals` poses the faces
        for exact normals).  ``kinematics`` as in :meth:`vertices_subset`."""
        pose, betas, _, lead = self._prepare(pose, betas, None)
        vertex_ids = np.asarray(vertex_ids, dtype=np.int64)
        if self._rest_normals is None:
            self._rest_normals = vertex_normals(self.v_template, self.faces)
        kin = self._kinematics(pose, betas) if kinematics is None else kinematics
        turned = skin(self._rest_normals[vertex_ids], self.weights[vertex_ids], kin.world_rot,
                      np.zeros(kin.world_rot.shape[:-1]))
        return unit(turned).reshape(lead + (len(vertex_ids), 3))

    def keypoints(self, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray | None = None) -> np.ndarray:
        """PedX keypoints (..., 18, 3), computing only the few vertices they use."""
        kp = self._kpmap()
        pose, betas, trans, lead = self._prepare(pose, betas, trans)
        kin = self._kinematics(pose, betas)
        verts = np.zeros((pose.shape[0], 0, 3))
        if kp.vertex_ids.size:
            sub = self._subset(kp.vertex_ids)
            verts = skin(self._rest_points(sub, betas, kin.rot_mats), sub.weights, kin.world_rot, kin.bone_trans)
        out = kp.apply(verts, kin.world_origin) + self._trans_gain(kp)[None, :, None] * trans[:, None]
        return out.reshape(lead + (kp.num_keypoints, 3))

    @staticmethod
    def _trans_gain(kp: KeypointMap) -> np.ndarray:
        """(K,) how much each keypoint moves per unit ``trans`` (its coefficient sum; 1 for affine maps)."""
        return kp.vertex_coeffs.sum(axis=1) + kp.joint_coeffs.sum(axis=1)

    # ------------------------------------------------------------------------------------- Jacobians

    def jacobian_setup(self, pose: np.ndarray, betas: np.ndarray) -> JacobianSetup:
        """The kinematics and derivative bases of N frames, pose (N, 72) and betas (N, B), that every
        Jacobian method shares (see :class:`JacobianSetup`)."""
        pose, betas, _, _ = self._prepare(pose, betas, None)
        return self._jacobian_setup(pose, betas)

    def _jacobian_setup(self, pose, betas) -> JacobianSetup:
        axis_angle = pose.reshape(pose.shape[0], self.num_joints, 3)
        rot_mats, jr = exp_and_right_jacobian(axis_angle)
        kin = batch_rigid_transform(rot_mats, self.rest_joints(betas), self._parents)
        jr_body = jr[:, 1:]
        bases = jac.rotation_bases(kin, jr_body)
        dt_dbeta = jac.shape_chain_jacobian(kin, self._joint_shapedirs, self._parents, self._desc)
        drot = (exp_so3_derivative(axis_angle[:, 1:], rot_mats[:, 1:], jr_body) if self.posedirs is not None
                else None)
        return JacobianSetup(kin, bases, dt_dbeta, drot)

    def _setup_for(self, pose, betas, setup: JacobianSetup | None) -> JacobianSetup:
        """``setup`` when given (it must be that of these N frames), else computed."""
        if setup is None:
            return self._jacobian_setup(pose, betas)
        if setup.bases.shape[0] != pose.shape[0]:
            raise ValueError(f"setup is for {setup.bases.shape[0]} frames, got {pose.shape[0]}")
        return setup

    def _vertex_terms(self, kin, bases, dt_dbeta, drot, betas, vertex_ids):
        sub = self._subset(vertex_ids)
        rest = self._rest_points(sub, betas, kin.rot_mats)
        return jac.vertex_jacobians(kin, bases, rest, sub.weights, self._desc, sub.shapedirs_flat, dt_dbeta,
                                    sub.posedirs_flat, drot)

    def point_jacobians(self, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray | None = None,
                        vertex_ids: np.ndarray | None = None, setup: JacobianSetup | None = None
                        ) -> jac.PointJacobians:
        """Positions and analytic Jacobians of the 18 keypoints (``vertex_ids=None``) or of given vertices
        (``setup``: :meth:`jacobian_setup` of these pose and betas, if already computed).

        Returns :class:`pedx_graph.body.jacobians.PointJacobians` with ``points (..., N, 3)``,
        ``d_root (..., N, 3, 3)`` (right perturbation of ``world_R_body``), ``d_body_pose (..., N, 3, 69)``,
        ``d_trans (..., N, 3, 3)``, ``d_betas (..., N, 3, B)``; see docs/architecture.md.
        """
        pose, betas, trans, lead = self._prepare(pose, betas, trans)
        kin, bases, dt_dbeta, drot = self._setup_for(pose, betas, setup)
        if vertex_ids is not None:
            vertex_ids = np.asarray(vertex_ids, dtype=np.int64).reshape(-1)
            if vertex_ids.size and (vertex_ids.min() < 0 or vertex_ids.max() >= self.num_vertices):
                raise ValueError(f"vertex_ids must lie in [0, {self.num_vertices})")
            pts, d_root, d_body, d_betas = self._vertex_terms(kin, bases, dt_dbeta, drot, betas, vertex_ids)
            gain = np.ones(len(vertex_ids))
        else:
            kp = self._kpmap()
            used_j, pairs = self._kp_joint_pairs
            jterms = jac.joint_jacobians(kin, bases, used_j, self._desc, self._joint_shapedirs, dt_dbeta, pairs)
            if kp.vertex_ids.size:
                vterms = self._vertex_terms(kin, bases, dt_dbeta, drot, betas, kp.vertex_ids)
                terms = [np.concatenate([a, b], axis=1) for a, b in zip(jterms, vterms)]
            else:
                terms = list(jterms)
            # All four quantities through the (K, Q + m) keypoint coefficients in one product.
            num_n, num_q = pose.shape[0], terms[0].shape[1]
            widths = [int(np.prod(t.shape[2:])) for t in terms]
            packed = np.concatenate([t.reshape(num_n, num_q, -1) for t in terms], axis=2)
            combined = self._kp_coeffs @ packed
            bounds = np.cumsum([0] + widths)
            pts, d_root, d_body, d_betas = (
                combined[:, :, bounds[i]:bounds[i + 1]].reshape((num_n, kp.num_keypoints) + terms[i].shape[2:])
                for i in range(4))
            gain = self._kp_gain
        num_p = len(gain)
        pts = pts + gain[None, :, None] * trans[:, None]
        d_trans = gain[:, None, None] * np.eye(3)
        if lead:
            d_trans = np.broadcast_to(d_trans, lead + (num_p, 3, 3))
        return jac.PointJacobians(
            points=pts.reshape(lead + (num_p, 3)), d_root=d_root.reshape(lead + (num_p, 3, 3)),
            d_body_pose=d_body.reshape(lead + (num_p, 3, d_body.shape[-1])), d_trans=d_trans,
            d_betas=d_betas.reshape(lead + (num_p, 3, self.num_betas)))

    def vertex_jacobians_per_frame(self, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray,
                                   vertex_ids: np.ndarray, setup: JacobianSetup | None = None) -> jac.PointJacobians:
        """Positions and Jacobians of a different vertex set per frame, in one batched pass (``setup``:
        :meth:`jacobian_setup` of these pose and betas, if already computed).

        pose (N, 72), betas (N, B), trans (N, 3), vertex_ids (N, P) (pad short sets by repeating an id).
        Returns ``PointJacobians`` with points (N, P, 3), d_root (N, P, 3, 3), d_body_pose (N, P, 3, 69),
        d_trans (N, P, 3, 3), d_betas (N, P, 3, B) — row n, p equals
        ``point_jacobians(pose[n], betas[n], trans[n], vertex_ids=vertex_ids[n])`` at vertex p.
        """
        pose, betas, trans, lead = self._prepare(pose, betas, trans)
        ids = np.asarray(vertex_ids, dtype=np.int64)
        if ids.ndim != 2 or ids.shape[0] != pose.shape[0]:
            raise ValueError(f"vertex_ids must be (N={pose.shape[0]}, P), got {ids.shape}")
        if ids.size and (ids.min() < 0 or ids.max() >= self.num_vertices):
            raise ValueError(f"vertex_ids must lie in [0, {self.num_vertices})")
        num_n, num_p = ids.shape
        kin, bases, dt_dbeta, drot = self._setup_for(pose, betas, setup)
        rows = (3 * ids[:, :, None] + np.arange(3)).reshape(num_n, 3 * num_p)
        shapedirs = self._shapedirs_flat[rows]                                     # (N, 3P, B)
        flat = np.einsum("nb,ncb->nc", betas, shapedirs) + self._v_template_col[rows, 0]
        posedirs = None
        if self._posedirs_flat is not None:
            posedirs = self._posedirs_flat[rows]                                   # (N, 3P, 207)
            flat += np.einsum("nf,ncf->nc", pose_features(kin.rot_mats), posedirs)
        pts, d_root, d_body, d_betas = jac.vertex_jacobians(kin, bases, flat.reshape(num_n, num_p, 3),
                                                            self.weights[ids], self._desc, shapedirs, dt_dbeta,
                                                            posedirs, drot)
        return jac.PointJacobians(points=pts + trans[:, None], d_root=d_root, d_body_pose=d_body,
                                  d_trans=np.broadcast_to(np.eye(3), (num_n, num_p, 3, 3)), d_betas=d_betas)

    def joints_and_jacobians(self, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray | None = None,
                             joint_ids: np.ndarray | None = None) -> jac.PointJacobians:
        """Posed joints (all, or ``joint_ids``) and their analytic Jacobians (same layout as point_jacobians)."""
        pose, betas, trans, lead = self._prepare(pose, betas, trans)
        joint_ids = (np.arange(self.num_joints) if joint_ids is None
                     else np.asarray(joint_ids, dtype=np.int64).reshape(-1))
        kin, bases, dt_dbeta, _ = self._jacobian_setup(pose, betas)
        pts, d_root, d_body, d_betas = jac.joint_jacobians(kin, bases, joint_ids, self._desc,
                                                           self._joint_shapedirs, dt_dbeta)
        num_p = len(joint_ids)
        pts = pts + trans[:, None]
        return jac.PointJacobians(
            points=pts.reshape(lead + (num_p, 3)), d_root=d_root.reshape(lead + (num_p, 3, 3)),
            d_body_pose=d_body.reshape(lead + (num_p, 3, d_body.shape[-1])),
            d_trans=np.broadcast_to(np.eye(3), lead + (num_p, 3, 3)),
            d_betas=d_betas.reshape(lead + (num_p, 3, self.num_betas)))
