"""Batched body-model evaluation for the factors of one track.

GTSAM calls every CustomFactor on its own, so each per-frame factor would evaluate the body model for its
one frame: per-call numpy overhead then dominates (keypoints + Jacobians cost ~0.9 ms as a single-frame call
but ~0.13 ms per frame when batched over 100 frames, see benchmarks/results/bench_body.md).

:class:`BatchedBodyModel` wraps a :class:`~pedx_graph.body.BodyModel` and is handed to the factors instead of
the model.  Before the solver linearises or evaluates the graph it calls :meth:`prefetch` with the values:
all frames are evaluated in one batched call and cached by the exact bytes of each frame's
``(pose, betas, trans)``.  A factor's call with the same inputs is then a dictionary look-up; any other call
(gtsam's own optimisers, iSAM2, Marginals, a changed estimate) falls through to the model, so results never
depend on the cache — only speed does.

It is also the factors' *term cache* (``term_cache``): the factors of a track register what they measure
when they are built (:meth:`register`).  :meth:`prefetch` evaluates the body model for all frames and hands
it (:class:`factors.terms.Prefetched`) to every registered term that declares a batched evaluation
(``Term.evaluate`` in its ``factors/`` file, found through :data:`factors.registry.TERMS`; today the stereo,
chamfer, pose-prior and temporal terms), which files its batched arrays here (:meth:`add_batch`, read by
:meth:`batch` and by the term's assembler).  A factor's callback takes its residual and Jacobians from
:meth:`lookup` — the term's ``Term.materialise`` of its group, after checking that the values it is called
with are exactly the prefetched ones (otherwise it computes them itself) — so one GTSAM callback costs a
look-up instead of the term's numpy work.  Terms without ``evaluate`` (translation, heading, joint limits,
ground contact) only register their specs (their assemblers evaluate them in batch from
:attr:`frame_arrays` / :attr:`keypoint_arrays`).  Nothing here names a term.

Public API (all the factors, the terms' assemblers and the solvers use): :meth:`register`,
:meth:`clear_registry`, :meth:`specs`, :meth:`kinds`, :meth:`lookup`, :meth:`prefetch`, :meth:`batch`,
:meth:`factor_terms`, :meth:`add_batch`, :meth:`set_factor_terms`, :meth:`frame_index`, :meth:`memo`, :attr:`has_jacobians`, :attr:`frame_states`,
:attr:`frame_arrays`, :attr:`keypoint_arrays`, :attr:`chamfer_matches`, and the body-model methods
(``point_jacobians``, ``keypoints``, ``vertices_subset`` and the model's attributes).
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.common import FrameKeys, FrameState, read_frame_state
from factors.registry import TERMS
from factors.terms import Prefetched, jacobian_rows
from pedx_graph.body import BodyModel


def _tag(pose: np.ndarray, betas: np.ndarray, trans: np.ndarray | None) -> bytes:
    t = b"" if trans is None else np.ascontiguousarray(trans, dtype=np.float64).tobytes()
    return (np.ascontiguousarray(pose, dtype=np.float64).tobytes()
            + np.ascontiguousarray(betas, dtype=np.float64).tobytes() + t)


#: Keypoints computed outside a prefetch that are remembered (by the exact bytes of their inputs).
_RECENT = 8


class BatchedBodyModel:
    """A body model whose per-frame results are prefetched for all frames of a track at once."""

    def __init__(self, model: BodyModel, subset_vertex_ids: np.ndarray | None = None):
        self.model = model
        self.subset_vertex_ids = subset_vertex_ids
        self._keypoint_jacobians: dict = {}       # frame tag -> its row index in the prefetch, then its rows
        self._prefetch_jacobians = None
        self._keypoints: dict[bytes, np.ndarray] = {}
        self._subset_vertices: dict[bytes, np.ndarray] = {}
        self._recent_keypoints: dict[bytes, np.ndarray] = {}
        self._specs: dict[str, dict[tuple[int, ...], object]] = {}
        self._terms: dict[tuple[str, tuple[int, ...]], tuple] = {}
        self._terms_have_jacobians = False
        self._where: dict[tuple[str, tuple[int, ...]], tuple[dict, int]] = {}
        self._batches: dict[str, list[dict]] = {}
        self._key_bytes: dict[int, bytes] = {}
        self._root_keys: set[int] = set()
        self._last_signature: tuple | None = None
        self._memo: dict = {}
        self._frame_of: dict[int, int] = {}
        self._index_memo: dict[tuple, np.ndarray] = {}
        self._last_jacobians = False
        self.frame_states: tuple[list[FrameKeys], list[FrameState]] = ([], [])
        """The frame keys and states of the last prefetch."""
        self.frame_arrays: dict[str, np.ndarray] = {}
        """The states of the last prefetch stacked over frames: ``pose`` (T, 72), ``betas`` (T, B), ``trans``
        (T, 3), ``world_R_body`` (T, 3, 3)."""
        self.keypoint_arrays: dict[str, np.ndarray] = {}
        """The keypoints of every frame of the last prefetch: ``points`` (T, K, 3) and, with Jacobians,
        ``d_root``, ``d_trans`` (T, K, 3, 3), ``d_body_pose`` (T, K, 3, 69), ``d_betas`` (T, K, 3, B)."""
        self.chamfer_matches: dict[tuple[int, ...], np.ndarray] = {}
        """Chamfer factor keys -> the matched vertex id (M,) of each of its points at the last prefetch."""

    def __getattr__(self, name):          # faces, num_betas, rest_joints, ... come from the model
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.model, name)

    @property
    def term_cache(self) -> "BatchedBodyModel":
        """The object the factors register their terms with (this one)."""
        return self

    # -- term cache: the public API the factors and the solvers use -----------------------------------
    def register(self, kind: str, keys, spec) -> None:
        """A factor of ``kind`` on ``keys`` with its fixed measurement ``spec`` (see the module docstring)."""
        self._specs.setdefault(kind, {})[tuple(int(k) for k in keys)] = spec
        self._memo.clear()

    def clear_registry(self) -> None:
        """Forget every registered factor (the stream files one sample's specs at a time)."""
        self._specs = {}
        self._memo.clear()

    def specs(self, kind: str) -> dict[tuple[int, ...], object]:
        """The registered factors of ``kind``: their key tuples -> specs (do not modify)."""
        return self._specs.get(kind, {})

    def kinds(self) -> list[str]:
        """The kinds with registered factors."""
        return [kind for kind, specs in self._specs.items() if specs]

    @property
    def has_jacobians(self) -> bool:
        """Whether the last prefetch evaluated the terms with their Jacobians."""
        return self._terms_have_jacobians

    def factor_terms(self, kind: str, keys: tuple[int, ...]) -> tuple:
        """``(residual, blocks)`` of one registered factor at the last prefetch (what its GTSAM callback
        returns there; ``blocks`` None without Jacobians).  KeyError when the prefetch did not evaluate it."""
        hit = self._terms.get((kind, keys))
        if hit is None:
            hit = self._terms[(kind, keys)] = self._materialise(kind, *self._where[(kind, keys)])
        return hit

    def frame_index(self, keys_list) -> np.ndarray:
        """The frame (position in the last prefetch's keys) of each factor of ``keys_list``, by its first
        root, translation or body-pose key."""
        tag = tuple(keys_list)
        hit = self._index_memo.get(tag)
        if hit is None:
            where = self._frame_of
            hit = self._index_memo[tag] = np.array([next(where[k] for k in keys if k in where) for keys in keys_list],
                                                   dtype=np.int64)
        return hit

    def memo(self, name, build):
        """``build()``, remembered under ``name`` until the registry changes (for arrays derived from the
        fixed specs, e.g. stacked measurements)."""
        hit = self._memo.get(name)
        if hit is None:
            hit = self._memo[name] = build()
        return hit

    def lookup(self, kind: str, keys, values: gtsam.Values, jacobians: bool):
        """``(residual, blocks)`` of the factor ``kind`` on ``keys`` prefetched at exactly ``values``, or None."""
        name = (kind, tuple(keys))
        if jacobians and not self._terms_have_jacobians:
            return None
        hit = self._terms.get(name)
        if hit is None:
            where = self._where.get(name)
            if where is None:
                return None
            hit = self._terms[name] = self._materialise(kind, *where)
        cached = self._key_bytes
        roots = self._root_keys
        for key in keys:
            current = values.atRot3(key).matrix() if key in roots else values.atVector(key)
            if current.tobytes() != cached.get(key):
                return None
        return hit

    def batch(self, kind: str) -> list[dict]:
        """The batched results of ``kind`` at the last prefetch: groups with ``keys`` (the factors' key
        tuples) and their arrays (see :meth:`_evaluate_terms`)."""
        return self._batches.get(kind, [])

    def _materialise(self, kind: str, group: dict, n: int) -> tuple:
        """Factor ``n`` of a batched group as the ``(residual, blocks)`` its callback returns (its term's
        ``materialise``)."""
        term = TERMS.get(kind)
        if term is None or term.materialise is None:
            raise KeyError(kind)
        return term.materialise(group, n, self._terms_have_jacobians)

    def set_factor_terms(self, kind: str, keys: tuple[int, ...], terms: tuple) -> None:
        """File one factor's ``(residual, blocks)`` at the current prefetch (a term's ``Term.evaluate`` that
        does not batch these factors)."""
        self._terms[(kind, keys)] = terms

    def add_batch(self, kind: str, group: dict) -> None:
        """File a term's batched results at the current prefetch (from its ``Term.evaluate``): ``group`` holds
        ``keys`` (the factors' key tuples) and the term's arrays, read back by its ``Term.materialise``."""
        self._batches.setdefault(kind, []).append(group)
        for n, keys in enumerate(group["keys"]):
            self._where[(kind, keys)] = (group, n)

    def _evaluate_terms(self, keys: list[FrameKeys], states: list[FrameState], jac, keypoints,
                        kinds=None, setup=None, subset_vertices=None) -> None:
        """Every registered term (of ``kinds``; all when None) at the prefetched states; ``jac`` (keypoint
        Jacobians of all frames) or ``keypoints`` (T, N, 3) (N: the model's keypoints, 18 or a fit layout's
        18 + E), the model's Jacobian ``setup`` of all frames (with ``jac``) and the posed ``subset_vertices``
        (T, C, 3) (or None) from :meth:`prefetch`."""
        specs = self._specs if kinds is None else {k: v for k, v in self._specs.items() if k in kinds}
        jacobians = jac is not None
        self._terms.clear()
        self._where.clear()
        self._batches.clear()
        self.chamfer_matches.clear()
        self._terms_have_jacobians = jacobians
        prefetched = Prefetched(keys, states, jac, keypoints, setup, subset_vertices)
        for kind, term in TERMS.items():
            if term.evaluate is not None and specs.get(kind):
                term.evaluate(self, specs[kind], prefetched)

    # -- prefetch ------------------------------------------------------------------------------------
    def prefetch(self, values: gtsam.Values, keys: list[FrameKeys], jacobians: bool,
                 vertices: bool = True, kinds=None) -> None:
        """Evaluate every frame of ``keys`` at ``values`` in one batch (keypoints, with Jacobians when
        ``jacobians``; the subset vertices when ``vertices``, a subset is set and chamfer factors are
        registered; the registered terms of ``kinds``, all when None); forget older entries."""
        if not keys:
            return
        signature = (tuple(k.root for k in keys), vertices, kinds)
        if signature == self._last_signature and (self._last_jacobians or not jacobians) \
                and self._holds(values, keys):
            return                     # already evaluated at these values (with at least these derivatives)
        states = [read_frame_state(values, k.as_list()) for k in keys]
        pose = np.stack([s.full_pose for s in states])
        betas = np.stack([s.betas for s in states])
        trans = np.stack([s.trans for s in states])
        tags = [_tag(s.full_pose, s.betas, s.trans) for s in states]
        self._last_signature, self._last_jacobians = signature, jacobians
        self._keypoint_jacobians.clear()
        self._keypoints.clear()
        self._subset_vertices.clear()
        self._terms.clear()
        self._where.clear()
        self._batches.clear()
        self._key_bytes.clear()
        self.frame_states = (list(keys), states)
        self.frame_arrays = {"pose": pose, "betas": betas, "trans": trans,
                             "world_R_body": np.stack([st.world_R_body for st in states])}
        self._root_keys = {k.root for k in keys}
        frame_of = {int(key): i for i, k in enumerate(keys) for key in (k.root, k.trans, k.body_pose)}
        if frame_of != self._frame_of:
            self._frame_of, self._index_memo = frame_of, {}
        for k, st in zip(keys, states):
            self._key_bytes[k.root] = np.ascontiguousarray(st.world_R_body).tobytes()
            self._key_bytes[k.trans] = st.trans.tobytes()
            self._key_bytes[k.body_pose] = st.body_pose.tobytes()
            self._key_bytes[k.betas] = st.betas.tobytes()
        jac = kps = setup = None
        if jacobians:                 # kinematics and derivative bases shared by every Jacobian below
            setup = self.model.jacobian_setup(pose, betas)
            jac = self.model.point_jacobians(pose, betas, trans, setup=setup)
            self.keypoint_arrays = {name: getattr(jac, name)
                                    for name in ("points", "d_root", "d_trans", "d_body_pose", "d_betas")}
            self._prefetch_jacobians = jac          # a frame's rows are cut only when a factor asks (GTSAM path)
            for i, tag in enumerate(tags):
                self._keypoint_jacobians[tag] = i
        else:
            kps = self.model.keypoints(pose, betas, trans)
            self.keypoint_arrays = {"points": kps}
            for i, tag in enumerate(tags):
                self._keypoints[tag] = kps[i]
        verts = None
        if vertices and self.subset_vertex_ids is not None and any(
                self._specs.get(kind) for kind, term in TERMS.items() if term.subset_vertices):
            verts = self.model.vertices_subset(pose, betas, trans, self.subset_vertex_ids,
                                               kinematics=None if setup is None else setup.kin)
            for i, tag in enumerate(tags):
                self._subset_vertices[tag] = verts[i]
        if self._specs:
            self._evaluate_terms(keys, states, jac, kps, kinds, setup, verts)

    def _holds(self, values: gtsam.Values, keys: list[FrameKeys]) -> bool:
        """Whether ``values`` has exactly the prefetched value of every variable of ``keys`` (raw bytes of
        each rotation matrix and vector: cheaper than reading the frame states)."""
        cached = self._key_bytes
        shape_key = keys[0].betas
        if values.atVector(shape_key).tobytes() != cached.get(shape_key):
            return False
        for k in keys:
            if (values.atVector(k.body_pose).tobytes() != cached.get(k.body_pose)
                    or values.atVector(k.trans).tobytes() != cached.get(k.trans)
                    or values.atRot3(k.root).matrix().tobytes() != cached.get(k.root)
                    or k.betas != shape_key and values.atVector(k.betas).tobytes() != cached.get(k.betas)):
                return False
        return True

    def _frame_jacobians(self, tag):
        """The prefetched keypoint Jacobians of the frame ``tag`` (its rows of the prefetch's arrays), or None."""
        index = self._keypoint_jacobians.get(tag)
        if index is None:
            return None
        if not isinstance(index, int):
            return index
        rows = self._keypoint_jacobians[tag] = jacobian_rows(self._prefetch_jacobians, index)
        return rows

    # -- the BodyModel interface used by the factors -----------------------------------------------------
    def point_jacobians(self, pose, betas, trans=None, vertex_ids=None):
        if vertex_ids is None and np.ndim(pose) == 1:
            hit = self._frame_jacobians(_tag(pose, betas, trans))
            if hit is not None:
                return hit
        return self.model.point_jacobians(pose, betas, trans, vertex_ids=vertex_ids)

    def keypoints(self, pose, betas, trans=None):
        if np.ndim(pose) == 1:
            tag = _tag(pose, betas, trans)
            hit = self._keypoints.get(tag)
            if hit is not None:
                return hit
            jac = self._frame_jacobians(tag)
            if jac is not None:
                return jac.points
            hit = self._recent_keypoints.get(tag)
            if hit is None:        # outside the prefetch: remember a few (several factors of a frame ask in a row)
                if len(self._recent_keypoints) >= _RECENT:
                    self._recent_keypoints.pop(next(iter(self._recent_keypoints)))
                hit = self._recent_keypoints[tag] = self.model.keypoints(pose, betas, trans)
            return hit
        return self.model.keypoints(pose, betas, trans)

    def vertices_subset(self, pose, betas, trans, vertex_ids):
        subset = self.subset_vertex_ids
        if (np.ndim(pose) == 1 and subset is not None and np.shape(vertex_ids) == subset.shape
                and (vertex_ids is subset or np.array_equal(vertex_ids, subset))):
            hit = self._subset_vertices.get(_tag(pose, betas, trans))
            if hit is not None:
                return hit
        return self.model.vertices_subset(pose, betas, trans, vertex_ids)
