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
when they are built (:meth:`register`).  :meth:`prefetch` evaluates the stereo, chamfer, pose-prior and
temporal terms for all frames in batched calls (``stereo_pixels``, the chamfer's matched-vertex
Jacobians of every frame in one pass after its per-frame k-d trees, ``MaxMixture.residual_batch``,
``temporal_prior_batch``) and keeps the batched arrays (:meth:`batch`, used by
:class:`pedx_graph.solvers.batched.BatchedLinearizer`).  A factor's callback takes its residual and
Jacobians from :meth:`lookup` — after checking that the values it is called with are exactly the
prefetched ones (otherwise it computes them itself) — so one GTSAM callback costs a look-up instead of the
term's numpy work.  The translation, heading, joint-limit and ground-contact factors only register their
specs (their assemblers evaluate them in batch from :attr:`frame_arrays` / :attr:`keypoint_arrays`).

Public API (all the factors, the terms' assemblers and the solvers use): :meth:`register`,
:meth:`clear_registry`, :meth:`specs`, :meth:`kinds`, :meth:`lookup`, :meth:`prefetch`, :meth:`batch`,
:meth:`factor_terms`, :meth:`frame_index`, :meth:`memo`, :attr:`has_jacobians`, :attr:`frame_states`,
:attr:`frame_arrays`, :attr:`keypoint_arrays`, :attr:`chamfer_matches`, and the body-model methods
(``point_jacobians``, ``keypoints``, ``vertices_subset`` and the model's attributes).
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from factors.common import FrameKeys, FrameState, read_frame_state
from factors.lidar_chamfer import chamfer_residual, chamfer_whiten, nearest_indices, nearest_vertices
from factors.stereo_reprojection import stereo_blocks, stereo_pixels, stereo_select
from factors.temporal_prior import temporal_prior_batch
from pedx_graph.body import BodyModel


def _tag(pose: np.ndarray, betas: np.ndarray, trans: np.ndarray | None) -> bytes:
    t = b"" if trans is None else np.ascontiguousarray(trans, dtype=np.float64).tobytes()
    return (np.ascontiguousarray(pose, dtype=np.float64).tobytes()
            + np.ascontiguousarray(betas, dtype=np.float64).tobytes() + t)


def _unique_per_frame(ids: list[np.ndarray], num_vertices: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sorted distinct vertex ids of each frame's (non-empty) ``ids``, from one ``np.unique`` over all
    frames: their counts (F,), padded into one (F, W) array (short rows repeat their first id), and the
    position of every id in its frame's row (the ids of all frames concatenated)."""
    counts = np.array([len(x) for x in ids])
    frame = np.repeat(np.arange(len(ids)), counts)
    distinct, inverse = np.unique(frame * num_vertices + np.concatenate(ids), return_inverse=True)
    owner, vertex = np.divmod(distinct, num_vertices)
    starts = np.searchsorted(owner, np.arange(len(ids) + 1))
    padded = np.repeat(vertex[starts[:-1], None], int(np.diff(starts).max()), axis=1)
    padded[owner, np.arange(len(distinct)) - starts[owner]] = vertex
    return np.diff(starts), padded, inverse.reshape(-1) - starts[frame]


#: Keypoints computed outside a prefetch that are remembered (by the exact bytes of their inputs).
_RECENT = 8


@dataclass(frozen=True)
class _FrameJacobians:
    points: np.ndarray
    d_root: np.ndarray
    d_body_pose: np.ndarray
    d_trans: np.ndarray
    d_betas: np.ndarray


class BatchedBodyModel:
    """A body model whose per-frame results are prefetched for all frames of a track at once."""

    def __init__(self, model: BodyModel, subset_vertex_ids: np.ndarray | None = None):
        self.model = model
        self.subset_vertex_ids = subset_vertex_ids
        self._keypoint_jacobians: dict[bytes, _FrameJacobians] = {}
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
        """Factor ``n`` of a batched group as the ``(residual, blocks)`` its callback returns."""
        jac = self._terms_have_jacobians
        if kind == "stereo_reprojection":
            if jac and "full" not in group:
                group["full"] = stereo_blocks(group["d_uv"], group["jac"])
            return stereo_select(group["uv"], group.get("full"), group["setups"][n], n)
        if kind == "pose_prior":
            return group["r"][n], ([group["mixture"].jacobian(group["best"][n])] if jac else None)
        if kind == "temporal_prior":
            return group["r"][n], ([blk[n] for blk in group["blocks"]] if jac else None)
        if kind == "lidar_chamfer":
            lo, hi = group["offsets"][n], group["offsets"][n + 1]
            r = group["s"][lo:hi].reshape(-1)
            if not jac:
                return r, None
            rows = group["a"][lo:hi].reshape(3 * (hi - lo), -1)
            bounds = np.cumsum([0, 3, 3, 69])
            return r, [np.ascontiguousarray(rows[:, bounds[i]:bounds[i + 1]]) for i in range(3)] + \
                [np.ascontiguousarray(rows[:, bounds[3]:])]
        raise KeyError(kind)

    def _chamfer_batch(self, chamfer: list, matches: list, vjac, local) -> None:
        """The chamfer factors of all frames as one group: every point's whitened, per-point robustified
        residual ``s`` (N, 3) and (with ``vjac``, the padded per-frame vertex Jacobians, and ``local``, each
        point's matched vertex's position in its frame's row of them) its Jacobian rows ``a`` (N, 3, 75 + B)
        — one :func:`factors.common.robustify_groups` call for all points."""
        spec = chamfer[0][1]
        counts = np.array([len(m[0]) for m in matches])
        offsets = np.concatenate([[0], np.cumsum(counts)])
        points = np.concatenate([sp.world_points for _, sp in chamfer])
        verts = np.concatenate([m[1] for m in matches])
        a = None
        if vjac is not None:
            frame_idx = np.repeat(np.arange(len(matches)), counts)
            a = np.concatenate([vjac.d_root[frame_idx, local], vjac.d_trans[frame_idx, local],
                                vjac.d_body_pose[frame_idx, local], vjac.d_betas[frame_idx, local]], axis=2)
        s_flat, blocks = chamfer_whiten(verts - points, None if a is None else [a.reshape(-1, a.shape[2])], spec)
        if a is not None:
            a = blocks[0].reshape(a.shape)
        self._add_batch("lidar_chamfer", {"keys": [fk for fk, _ in chamfer], "offsets": offsets,
                                          "s": s_flat.reshape(-1, 3), "a": a})

    def _nearest(self, state: FrameState, spec, subset_vertices: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """:func:`nearest_vertices` of one chamfer factor, searched directly in the prefetched posed subset
        vertices (C, 3) when its candidates are that subset."""
        cand = spec.candidate_vertex_ids
        if subset_vertices is None or cand is None or not (
                cand is self.subset_vertex_ids or np.array_equal(cand, self.subset_vertex_ids)):
            return nearest_vertices(self, state, spec.world_points, cand)
        nn = nearest_indices(subset_vertices, spec.world_points)
        return cand[nn], subset_vertices[nn]

    def _add_batch(self, kind: str, group: dict) -> None:
        self._batches.setdefault(kind, []).append(group)
        for n, keys in enumerate(group["keys"]):
            self._where[(kind, keys)] = (group, n)

    def _evaluate_terms(self, keys: list[FrameKeys], states: list[FrameState], jac, keypoints,
                        kinds=None, setup=None, subset_vertices=None) -> None:
        """Every registered term (of ``kinds``; all when None) at the prefetched states; ``jac`` (keypoint
        Jacobians of all frames) or ``keypoints`` (T, 18, 3), the model's Jacobian ``setup`` of all frames
        (with ``jac``) and the posed ``subset_vertices`` (T, C, 3) (or None) from :meth:`prefetch`."""
        specs = self._specs if kinds is None else {k: v for k, v in self._specs.items() if k in kinds}
        jacobians = jac is not None
        self._terms.clear()
        self._where.clear()
        self._batches.clear()
        self.chamfer_matches.clear()
        self._terms_have_jacobians = jacobians
        frame_of = {k.root: i for i, k in enumerate(keys)}
        stereo = specs.get("stereo_reprojection", {})
        if stereo:
            fkeys = [fk for fk in stereo if fk[0] in frame_of]
            idx = np.array([frame_of[fk[0]] for fk in fkeys], dtype=np.int64)
            sub = None if jac is None else _FrameJacobians(jac.points[idx], jac.d_root[idx], jac.d_body_pose[idx],
                                                           jac.d_trans[idx], jac.d_betas[idx])
            points = keypoints[idx] if jac is None else sub.points
            setups = [stereo[fk].setup for fk in fkeys]
            uv, d_uv = stereo_pixels(points, setups, jacobians)
            self._add_batch("stereo_reprojection", {"keys": fkeys, "uv": uv, "d_uv": d_uv, "jac": sub,
                                                    "setups": setups})
        chamfer = [(fk, spec) for fk, spec in specs.get("lidar_chamfer", {}).items() if fk[0] in frame_of]
        if chamfer:
            frames = np.array([frame_of[fk[0]] for fk, _ in chamfer], dtype=np.int64)
            fstates = [states[f] for f in frames]
            matches = [self._nearest(st, spec, None if subset_vertices is None else subset_vertices[f])
                       for st, f, (_, spec) in zip(fstates, frames, chamfer)]
            vjac = distinct = local = None
            if jacobians:             # the matched vertices' Jacobians of every frame in one batched pass
                distinct, padded, local = _unique_per_frame([ids for ids, _ in matches], self.model.num_vertices)
                arrays = self.frame_arrays
                every = len(frames) == len(states) and np.array_equal(frames, np.arange(len(states)))
                vjac = self.model.vertex_jacobians_per_frame(
                    arrays["pose"][frames], arrays["betas"][frames], arrays["trans"][frames], padded,
                    setup=setup if every else setup.rows(frames))
            for (fk, _), match in zip(chamfer, matches):
                self.chamfer_matches[fk] = match[0]
            kernels = {(spec.sigma_m, spec.robust, spec.robust_scale, spec.robust_per_point) for _, spec in chamfer}
            if len(kernels) == 1 and chamfer[0][1].robust_per_point:
                self._chamfer_batch(chamfer, matches, vjac, local)
            else:                     # mixed noise settings: factor by factor
                for n, ((fk, spec), st, match) in enumerate(zip(chamfer, fstates, matches)):
                    vj = None if vjac is None else _FrameJacobians(
                        *(getattr(vjac, f)[n, :distinct[n]]
                          for f in ("points", "d_root", "d_body_pose", "d_trans", "d_betas")))
                    self._terms[("lidar_chamfer", fk)] = chamfer_residual(self, st, spec, jacobians, match, vj)
        prior = specs.get("pose_prior", {})
        pose_index = {k.body_pose: i for i, k in enumerate(keys)}
        for mixture in {id(m): m for m in prior.values()}.values():
            fkeys = [fk for fk, m in prior.items() if m is mixture and fk[0] in pose_index]
            res, best = mixture.residual_batch(np.stack([states[pose_index[fk[0]]].body_pose for fk in fkeys]))
            self._add_batch("pose_prior", {"keys": fkeys, "r": res, "best": best, "mixture": mixture})
        temporal = specs.get("temporal_prior", {})
        groups: dict[int, list] = {}
        for fk, (mixture, gap) in temporal.items():
            if fk[0] not in frame_of or fk[3] not in frame_of:
                continue
            groups.setdefault(id(mixture), []).append((fk, mixture, gap))
        for items in groups.values():
            a = [states[frame_of[fk[0]]] for fk, _, _ in items]
            b = [states[frame_of[fk[3]]] for fk, _, _ in items]
            gaps = np.array([gap for _, _, gap in items], dtype=np.float64)
            best: list = []
            res, blocks = temporal_prior_batch(
                np.stack([s.world_R_body for s in a]), np.stack([s.trans for s in a]),
                np.stack([s.body_pose for s in a]), np.stack([s.world_R_body for s in b]),
                np.stack([s.trans for s in b]), np.stack([s.body_pose for s in b]), items[0][1],
                gaps, jacobians, components=best)
            self._add_batch("temporal_prior", {"keys": [fk for fk, _, _ in items], "r": res, "blocks": blocks,
                                               "mixture": items[0][1], "best": best[0], "gap": gaps})

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
            for i, tag in enumerate(tags):
                self._keypoint_jacobians[tag] = _FrameJacobians(jac.points[i], jac.d_root[i], jac.d_body_pose[i],
                                                                jac.d_trans[i], jac.d_betas[i])
        else:
            kps = self.model.keypoints(pose, betas, trans)
            self.keypoint_arrays = {"points": kps}
            for i, tag in enumerate(tags):
                self._keypoints[tag] = kps[i]
        verts = None
        if vertices and self.subset_vertex_ids is not None and self._specs.get("lidar_chamfer"):
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

    # -- the BodyModel interface used by the factors -----------------------------------------------------
    def point_jacobians(self, pose, betas, trans=None, vertex_ids=None):
        if vertex_ids is None and np.ndim(pose) == 1:
            hit = self._keypoint_jacobians.get(_tag(pose, betas, trans))
            if hit is not None:
                return hit
        return self.model.point_jacobians(pose, betas, trans, vertex_ids=vertex_ids)

    def keypoints(self, pose, betas, trans=None):
        if np.ndim(pose) == 1:
            tag = _tag(pose, betas, trans)
            hit = self._keypoints.get(tag)
            if hit is not None:
                return hit
            jac = self._keypoint_jacobians.get(tag)
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
