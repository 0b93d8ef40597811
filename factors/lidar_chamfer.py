"""E_3d (PedX Eq. 4): the instance's LiDAR points lie on the body surface (one-sided chamfer, point-to-point).

Measurement: the LiDAR points assigned to the pedestrian in this frame, ``world_p_i`` (M, 3), world (LiDAR)
frame, metres.  For each point its nearest posed model vertex ``n(i)`` among the vertices of the *current*
estimate is found at every evaluation (so correspondences are re-found at each linearisation, as in ICP):
by direct squared distances to every candidate vertex for a few points, by a k-d tree
(``scipy.spatial.cKDTree``) built over the vertices for many (:func:`nearest_indices`):

    r_i = world_v_n(i)(root, trans, body_pose, betas) - world_p_i           (3,) metres;   r = [r_1..r_M]  (3M,)

Point-to-point: the residual is the full 3D offset to the nearest vertex (not the distance along a
normal), so it is smooth at zero distance (r_i = 0 has a regular Jacobian).  Within one evaluation the
assignment n(i) is held fixed; the Jacobian uses ``BodyModel.point_jacobians`` of the matched vertices only.
Noise: isotropic ``sigma_m`` metres per coordinate; robust (Geman-McClure by default, scale in whitened
units) against points mislabelled as the pedestrian, by default on each point's 3D distance
(``rho(|r_i| / sigma_m)``, rotation invariant, :func:`factors.common.robustify_groups`), optionally per
coordinate row.  ``candidate_vertex_ids`` restricts the
vertices that can be matched (e.g. a decimated subset, to speed up the tree).

**Seen side.**  A LiDAR return lies on the part of the surface that faces the sensor.  With
``world_p_sensor`` (the rig's viewpoint, world frame) a point is matched only among the vertices whose
normal ``n_v`` faces it: ``n_v . (v - world_p_sensor) / |v - world_p_sensor| < facing_cos`` (normals from
:meth:`~pedx_graph.body.BodyModel.vertex_normals_subset`; ``facing_cos`` > 0 keeps grazing vertices, as the
viewpoint is not exactly the LiDAR's centre).  Without it, a body shifted a couple of decimetres along the
ray still finds a vertex near each point on its flanks or its back, and the term hardly resists the shift.
The facing set is part of the correspondence search: held fixed within one evaluation like ``n(i)``.  No factor is created for
zero points (:func:`make_lidar_chamfer_factor` returns ``None``).  The factor remembers the matches of its
last evaluation point (a pure memo of a deterministic function: LM evaluates the error at a new estimate
and then linearises at that same estimate, which then skips the forward pass and the tree).

Like ICP, nearest-vertex correspondences give local minima when the start is off by more than the vertex
spacing, and a Geman-McClure kernel with a small scale stalls far from the solution: initialise close
(stereo, translation prior) or anneal the kernel scale (e.g. ``gtsam.GncLMOptimizer``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import gtsam
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from factors.common import (BodyModelLike, FrameKeys, FrameState, as_f64, frame_key_list, read_frame_state,
                            robustify_groups)
from factors.terms import (NormalEquations, Prefetched, RowNoise, Term, cached_callback, concatenate,
                           factor_normal_equations, frame_dims, jacobian_rows)

#: The factor kind (``TrackProblem.factor_kinds``, the term cache's registry).
KIND = "lidar_chamfer"


def posed_vertices(model: BodyModelLike, state: FrameState, candidate_vertex_ids: np.ndarray | None) -> np.ndarray:
    """World positions (C, 3) of the candidate vertices (all vertices when None) at ``state``.

    A candidate set uses ``model.vertices_subset`` when the model has it (a batched track evaluator serves
    it from its cache); otherwise the full forward pass is indexed.
    """
    if candidate_vertex_ids is not None and hasattr(model, "vertices_subset"):
        return np.asarray(model.vertices_subset(state.full_pose, state.betas, state.trans, candidate_vertex_ids))
    verts = np.asarray(model.forward(state.full_pose, state.betas, state.trans).vertices)
    return verts if candidate_vertex_ids is None else verts[candidate_vertex_ids]


#: Up to this many points (per frame) their nearest vertices are found from all point-to-vertex squared
#: distances (``cdist``, ~4 ns per pair) rather than a k-d tree (its build costs ~0.15 us per vertex, the
#: query ~1.5 us per point): the crossover is at ~40-70 points whatever the vertex count (measured).
DIRECT_SEARCH_MAX_POINTS = 64


def nearest_indices(verts: np.ndarray, world_points: np.ndarray) -> np.ndarray:
    """Index (M,) into ``verts`` (C, 3) of the nearest vertex of each point (M, 3) (the exact nearest either way;
    lowest index among exactly equidistant vertices on the direct path)."""
    if len(world_points) <= DIRECT_SEARCH_MAX_POINTS:
        return cdist(world_points, verts, "sqeuclidean").argmin(axis=1)
    return cKDTree(verts, balanced_tree=False, compact_nodes=False).query(world_points)[1]


def facing_margin(world_points: np.ndarray, world_p_sensor: np.ndarray, viewpoint_offset_m: float,
                  normal_tolerance_rad: float) -> float:
    """The ``facing_cos`` of points (M, 3) seen from about ``world_p_sensor`` (3,): ``sin(atan(offset / d) +
    tolerance)``, ``d`` their median distance from it — the true sensor may lie ``viewpoint_offset_m`` away
    (its rays to the points then turn by up to ``atan(offset / d)``) and a vertex normal be
    ``normal_tolerance_rad`` off."""
    distance = float(np.median(np.linalg.norm(np.asarray(world_points, float) - world_p_sensor, axis=1)))
    angle = np.arctan2(viewpoint_offset_m, max(distance, 1e-9)) + normal_tolerance_rad
    return float(np.sin(min(angle, np.pi / 2)))


def facing_sensor(verts: np.ndarray, normals: np.ndarray, world_p_sensor: np.ndarray, facing_cos: float
                  ) -> np.ndarray:
    """(C,) bool: the vertices (C, 3) whose unit normals (C, 3) face the sensor at ``world_p_sensor`` (3,):
    ``n . (v - sensor) / |v - sensor| < facing_cos`` (module docstring, "Seen side")."""
    ray = verts - np.asarray(world_p_sensor, dtype=float)
    cos = np.einsum("ij,ij->i", normals, ray) / np.maximum(np.linalg.norm(ray, axis=1), 1e-12)
    return cos < facing_cos


def _nearest_among(verts: np.ndarray, world_points: np.ndarray, facing: np.ndarray | None) -> np.ndarray:
    """Index into ``verts`` of each point's nearest vertex, among the ``facing`` ones when given (all when
    none faces)."""
    if facing is None or not facing.any():
        return nearest_indices(verts, world_points)
    keep = np.flatnonzero(facing)
    return keep[nearest_indices(verts[keep], world_points)]


def nearest_vertices(model: BodyModelLike, state: FrameState, world_points: np.ndarray,
                     candidate_vertex_ids: np.ndarray | None = None, world_p_sensor: np.ndarray | None = None,
                     facing_cos: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Vertex id (M,) of the nearest posed vertex of each world point (M, 3), and that vertex's position (M, 3);
    with ``world_p_sensor``, among the vertices facing it (:func:`facing_sensor`)."""
    verts = posed_vertices(model, state, candidate_vertex_ids)
    facing = None
    if world_p_sensor is not None:
        ids = np.arange(model.num_vertices) if candidate_vertex_ids is None else candidate_vertex_ids
        normals = model.vertex_normals_subset(state.full_pose, state.betas, ids)
        facing = facing_sensor(verts, normals, world_p_sensor, facing_cos)
    nn = _nearest_among(verts, world_points, facing)
    ids = nn if candidate_vertex_ids is None else candidate_vertex_ids[nn]
    return np.asarray(ids, dtype=np.int64), verts[nn]


def lidar_chamfer_error(model: BodyModelLike, state: FrameState, world_points: np.ndarray,
                        candidate_vertex_ids: np.ndarray | None = None, want_jacobians: bool = False,
                        matches: tuple[np.ndarray, np.ndarray] | None = None, vertex_jacobians=None
                        ) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Unwhitened residual (3M,) in metres and, when asked, ``[J_root, J_trans, J_body_pose, J_betas]``.

    ``matches`` = the output of :func:`nearest_vertices` at this same ``state``, if already known;
    ``vertex_jacobians`` = the body model's point Jacobians of ``np.unique(matched ids)`` at ``state`` (in
    that order), if already known (a batched evaluator computes them for all frames at once).
    """
    ids, verts = nearest_vertices(model, state, world_points, candidate_vertex_ids) if matches is None else matches
    if not want_jacobians:
        return (verts - world_points).reshape(-1), None
    unique, inverse = np.unique(ids, return_inverse=True)
    jac = vertex_jacobians if vertex_jacobians is not None else \
        model.point_jacobians(state.full_pose, state.betas, state.trans, vertex_ids=unique)
    r = (np.asarray(jac.points)[inverse] - world_points).reshape(-1)
    # d r_i / d x = d vertex_n(i) / d x: the matched vertices' Jacobian rows, gathered (no linear map).
    return r, [as_f64(np.asarray(getattr(jac, name), dtype=np.float64)[inverse].reshape(3 * len(ids), -1))
               for name in ("d_root", "d_trans", "d_body_pose", "d_betas")]


@dataclass(frozen=True)
class ChamferSpec:
    """What one chamfer factor measures and how (fixed at construction)."""

    world_points: np.ndarray
    """(M, 3) LiDAR points, world frame, metres."""
    candidate_vertex_ids: np.ndarray | None
    sigma_m: float
    robust: str
    robust_scale: float
    robust_per_point: bool
    world_p_sensor: np.ndarray | None = None
    """(3,) the viewpoint the points were seen from, world frame, metres; None: any vertex can be matched."""
    facing_cos: float = 0.0
    """A vertex faces the viewpoint when the cosine of its normal and the ray to it is below this."""


def spec_matches(model: BodyModelLike, state: FrameState, spec: ChamferSpec) -> tuple[np.ndarray, np.ndarray]:
    """:func:`nearest_vertices` of a factor's points at ``state``, as its spec says."""
    return nearest_vertices(model, state, spec.world_points, spec.candidate_vertex_ids, spec.world_p_sensor,
                            spec.facing_cos)


def noise_of(spec: ChamferSpec) -> RowNoise:
    """The factor's noise model: unit when robust per point (whitened and robustified inside, by
    :func:`chamfer_whiten`), else ``sigma_m`` per coordinate row with the kernel per row."""
    if spec.robust_per_point:
        return RowNoise(None)
    return RowNoise(np.array([spec.sigma_m]), spec.robust, spec.robust_scale)


def chamfer_whiten(offsets: np.ndarray, blocks: list[np.ndarray] | None, spec: ChamferSpec
                   ) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Per-point robust whitening of point-to-vertex offsets (M, 3) metres and their Jacobian blocks (each
    (3M, k)): ``s_i = g(|e_i|) e_i`` with ``e_i = offset_i / sigma_m`` (:func:`factors.common.robustify_groups`).
    Returns ``s`` (3M,) and the transformed blocks (the factor's residual under its unit noise model)."""
    inv = 1.0 / spec.sigma_m
    return robustify_groups(np.asarray(offsets, dtype=np.float64).reshape(-1, 3) * inv, spec.robust,
                            spec.robust_scale, blocks, block_scale=inv)


def chamfer_residual(model: BodyModelLike, state: FrameState, spec: ChamferSpec, want_jacobians: bool,
                     matches: tuple[np.ndarray, np.ndarray] | None = None, vertex_jacobians=None
                     ) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """The factor's residual (whitened and robustified per point when ``spec.robust_per_point``, else
    unwhitened) and Jacobian blocks; ``matches`` / ``vertex_jacobians`` as in :func:`lidar_chamfer_error`."""
    matches = spec_matches(model, state, spec) if matches is None else matches
    r, blocks = lidar_chamfer_error(model, state, spec.world_points, spec.candidate_vertex_ids, want_jacobians,
                                    matches, vertex_jacobians)
    if spec.robust_per_point:
        r, blocks = chamfer_whiten(r, blocks, spec)
    return r, blocks


def chamfer_normal_equations(group: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened normal equations of a term cache's chamfer group: per factor ``(A^T A, A^T b, b^T b)``.

    ``group["a"]`` (P, 3, D) the points' whitened, robustified rows over the factor's columns,
    ``group["s"]`` (P, 3) their whitened residuals, ``group["offsets"]`` (F + 1,) where each factor's
    points start.  Every factor's points are padded with zero rows to the largest count, so all factors
    take one batched product.  Returns hess (F, D, D), grad (F, D) = ``-A^T s``, cost (F,) = ``s^T s``."""
    offsets, a, s = group["offsets"], group["a"], group["s"]
    counts = np.diff(offsets)
    num, width = len(counts), int(counts.max())
    frame = np.repeat(np.arange(num), counts)
    slot = np.arange(len(a)) - offsets[frame]
    rows = np.zeros((num, width, 3, a.shape[2]))
    rhs = np.zeros((num, width, 3))
    rows[frame, slot] = a
    rhs[frame, slot] = s
    rows = rows.reshape(num, 3 * width, a.shape[2])
    rows_t = np.swapaxes(rows, 1, 2)
    return (rows_t @ rows, -(rows_t @ rhs.reshape(num, 3 * width, 1))[:, :, 0],
            np.bincount(frame, weights=np.sum(s * s, axis=1), minlength=num))


def assemble(cache, keys_list: list[tuple[int, ...]], jacobians: bool) -> NormalEquations:
    """The chamfer factors ``keys_list`` at the cache's last prefetch: from its all-frames group (rows
    already whitened and robustified per point) when it holds exactly these factors, else factor by factor."""
    groups = cache.batch(KIND)
    if {k for g in groups for k in g["keys"]} != set(keys_list) or (jacobians and any(g["a"] is None for g in groups)):
        return factor_normal_equations(cache, KIND, keys_list, noise_of, jacobians)
    parts = []
    for g in groups:
        counts = np.diff(g["offsets"])
        error = 0.5 * np.bincount(np.repeat(np.arange(len(counts)), counts), weights=np.sum(g["s"] ** 2, axis=1),
                                  minlength=len(counts))
        if jacobians:
            hess, grad, bb = chamfer_normal_equations(g)
            parts.append(NormalEquations(list(g["keys"]), error, hess, grad, bb))
        else:
            parts.append(NormalEquations(list(g["keys"]), error))
    return concatenate(parts)


def make_lidar_chamfer_factor(keys: FrameKeys | Sequence[int], model: BodyModelLike, world_points: np.ndarray,
                              sigma_m: float = 0.03, robust: str = "gemanmcclure", robust_scale: float = 3.0,
                              candidate_vertex_ids: np.ndarray | None = None,
                              robust_per_point: bool = True, world_p_sensor: np.ndarray | None = None,
                              facing_cos: float = 0.0) -> gtsam.CustomFactor | None:
    """LiDAR-to-mesh factor on ``keys = [root, trans, body_pose, betas]``; ``None`` when there are no points.

    ``world_points`` (M, 3) metres, world frame; ``sigma_m`` metres per coordinate; ``robust_scale`` in
    whitened units.  ``robust_per_point`` (default): the kernel acts on each point's whitened 3D distance
    (rotation invariant; applied inside the callback, unit noise model, so ``unwhitenedError`` returns the
    robustified whitened residual); otherwise on each coordinate row through GTSAM's ``Robust`` noise model.
    ``world_p_sensor`` (3,) metres, world frame: points match only vertices facing it (module docstring,
    "Seen side"; ``facing_cos`` its grazing margin); None: any vertex.
    """
    pts = as_f64(world_points).reshape(-1, 3) if np.size(world_points) else np.zeros((0, 3))
    if pts.shape[0] == 0:
        return None
    if not np.all(np.isfinite(pts)):
        raise ValueError("lidar chamfer: world_points contain non-finite values")
    if not sigma_m > 0:
        raise ValueError(f"lidar chamfer: sigma_m must be > 0, got {sigma_m}")
    cand = None if candidate_vertex_ids is None else np.asarray(candidate_vertex_ids, dtype=np.int64).reshape(-1)
    if cand is not None and cand.size == 0:
        raise ValueError("lidar chamfer: candidate_vertex_ids is empty")
    sensor = None
    if world_p_sensor is not None:
        sensor = as_f64(world_p_sensor).reshape(-1)
        if sensor.shape != (3,) or not np.all(np.isfinite(sensor)):
            raise ValueError(f"lidar chamfer: world_p_sensor must be 3 finite numbers, got {world_p_sensor!r}")
    if not -1.0 <= facing_cos <= 1.0:
        raise ValueError(f"lidar chamfer: facing_cos must lie in [-1, 1], got {facing_cos}")
    rows = 3 * pts.shape[0]
    memo: dict = {}             # last (state bytes -> matches): LM evaluates the error, then linearises there
    spec = ChamferSpec(pts, cand, float(sigma_m), robust, float(robust_scale), bool(robust_per_point), sensor,
                       float(facing_cos))
    cache = getattr(model, "term_cache", None)
    if cache is not None:
        cache.register(KIND, frame_key_list(keys), spec)

    def compute(keys, values: gtsam.Values, jacobians: bool):
        state = read_frame_state(values, keys)
        tag = b"".join(a.tobytes() for a in (state.root_rotvec, state.trans, state.body_pose, state.betas))
        matches = memo.get(tag)
        if matches is None:
            matches = spec_matches(model, state, spec)
            memo.clear()
            memo[tag] = matches
        return chamfer_residual(model, state, spec, jacobians, matches)

    return gtsam.CustomFactor(noise_of(spec).model(rows), frame_key_list(keys),
                              cached_callback(KIND, cache, compute, frame_dims))


def unique_per_frame(ids: list[np.ndarray], num_vertices: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
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


def _nearest(cache, state: FrameState, spec: ChamferSpec, subset_vertices: np.ndarray | None,
             subset_normals: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`spec_matches` of one factor, searched directly in the prefetched posed subset vertices (C, 3)
    of the term cache (and their normals (C, 3), when the spec has a viewpoint) when its candidates are that
    subset."""
    cand, subset = spec.candidate_vertex_ids, cache.subset_vertex_ids
    if subset_vertices is None or cand is None or not (cand is subset or np.array_equal(cand, subset)):
        return spec_matches(cache, state, spec)
    facing = None
    if spec.world_p_sensor is not None:
        facing = facing_sensor(subset_vertices, subset_normals, spec.world_p_sensor, spec.facing_cos)
    nn = _nearest_among(subset_vertices, spec.world_points, facing)
    return cand[nn], subset_vertices[nn]


def _group(cache, chamfer: list, matches: list, vjac, local) -> None:
    """The factors of all frames as one group: every point's whitened, per-point robustified residual ``s``
    (N, 3) and (with ``vjac``, the padded per-frame vertex Jacobians, and ``local``, each point's matched
    vertex's position in its frame's row of them) its Jacobian rows ``a`` (N, 3, 75 + B) — one
    :func:`chamfer_whiten` call for all points."""
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
    cache.add_batch(KIND, {"keys": [fk for fk, _ in chamfer], "offsets": offsets, "s": s_flat.reshape(-1, 3),
                           "a": a})


def evaluate(cache, specs: dict, prefetched: Prefetched) -> None:
    """The term cache's batched evaluation (:attr:`factors.terms.Term.evaluate`): each factor's nearest
    vertices (its k-d tree or direct search, in the prefetched subset when it can), recorded in
    ``cache.chamfer_matches``; with Jacobians the matched vertices' Jacobians of every frame in one batched
    pass; one group for all factors when they share a per-point robust noise setting, else factor by factor."""
    frame_of, states = prefetched.frame_of, prefetched.states
    chamfer = [(fk, spec) for fk, spec in specs.items() if fk[0] in frame_of]
    if not chamfer:
        return
    frames = np.array([frame_of[fk[0]] for fk, _ in chamfer], dtype=np.int64)
    fstates = [states[f] for f in frames]
    subset = prefetched.subset_vertices
    normals = None
    if subset is not None and any(spec.world_p_sensor is not None for _, spec in chamfer):
        arrays = cache.frame_arrays          # the subset's normals of every frame in one batched pass
        setup = prefetched.setup
        normals = cache.model.vertex_normals_subset(arrays["pose"], arrays["betas"], cache.subset_vertex_ids,
                                                    kinematics=None if setup is None else setup.kin)
    matches = [_nearest(cache, st, spec, None if subset is None else subset[f],
                        None if normals is None else normals[f])
               for st, f, (_, spec) in zip(fstates, frames, chamfer)]
    vjac = distinct = local = None
    if prefetched.jacobians:          # the matched vertices' Jacobians of every frame in one batched pass
        distinct, padded, local = unique_per_frame([ids for ids, _ in matches], cache.model.num_vertices)
        arrays = cache.frame_arrays
        every = len(frames) == len(states) and np.array_equal(frames, np.arange(len(states)))
        setup = prefetched.setup
        vjac = cache.model.vertex_jacobians_per_frame(
            arrays["pose"][frames], arrays["betas"][frames], arrays["trans"][frames], padded,
            setup=setup if every else setup.rows(frames))
    for (fk, _), match in zip(chamfer, matches):
        cache.chamfer_matches[fk] = match[0]
    kernels = {(spec.sigma_m, spec.robust, spec.robust_scale, spec.robust_per_point) for _, spec in chamfer}
    if len(kernels) == 1 and chamfer[0][1].robust_per_point:
        _group(cache, chamfer, matches, vjac, local)
        return
    for n, ((fk, spec), st, match) in enumerate(zip(chamfer, fstates, matches)):      # mixed noise settings
        vj = None if vjac is None else jacobian_rows(jacobian_rows(vjac, n), slice(0, distinct[n]))
        cache.set_factor_terms(KIND, fk, chamfer_residual(cache, st, spec, prefetched.jacobians, match, vj))


def materialise(group: dict, n: int, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Factor ``n`` of a group of :func:`evaluate`: its points' rows and the blocks ``[root, trans,
    body_pose, betas]``."""
    lo, hi = group["offsets"][n], group["offsets"][n + 1]
    r = group["s"][lo:hi].reshape(-1)
    if not jacobians:
        return r, None
    rows = group["a"][lo:hi].reshape(3 * (hi - lo), -1)
    bounds = np.cumsum([0, 3, 3, 69])
    return r, [np.ascontiguousarray(rows[:, bounds[i]:bounds[i + 1]]) for i in range(3)] + \
        [np.ascontiguousarray(rows[:, bounds[3]:])]


TERM = Term(KIND, assemble, evaluate=evaluate, materialise=materialise, subset_vertices=True)
