"""E_tp (PedX Eq. 10): motion prior between consecutive frames, a GMM on a 75-d frame-to-frame difference.

The shared definition (:func:`pedx_graph.priors.difference.temporal_difference`; the temporal GMM is trained on it):

    d(i, j) = [ world_R_body_i^T (trans_j - trans_i)        (3)  translation step in the body frame of i, m
                Log(world_R_body_i^T world_R_body_j)         (3)  root rotation step, local rotation vector, rad
                body_pose_j - body_pose_i ]                  (69) body pose difference, rad

The translation step is expressed in the full body frame of frame i (SMPL axes: Y up, +Z forward), so d is
invariant to any rotation and translation of the world (the world's up axis never enters: mocap in a Y-up
frame and a LiDAR frame of any orientation — PedX's points z down — give the same d).  For a person walking forward the step is ~(0, 0, v dt).
``trans`` differences equal pelvis differences because the shape is shared by the track.

The prior is the 10-component GMM of the paper evaluated as a max-mixture (:class:`factors.common.MaxMixture`,
unit noise, residual 76 = 75 + 1).  Missing frames: when frame j is ``k = frame_gap`` frame periods after i,
the prior is evaluated at the per-frame average ``d / k`` with the covariances unchanged.  That equals
``cov(d) = k^2 Sigma`` (constant velocity, fully correlated steps), which is never tighter than the
independent-step model ``k Sigma``: a gap only weakens the prior.

Jacobians (right perturbations ``R <- R Exp(delta)``; ``s = R_i^T (t_j - t_i)``, ``w = Log(R_i^T R_j)``):
``ds/ddelta_i = hat(s)``, ``ds/dt_i = -R_i^T``, ``ds/dt_j = R_i^T``; ``dw/ddelta_j = J_r^-1(w)``,
``dw/ddelta_i = -J_r^-1(w) (R_i^T R_j)^T``; pose: ``-I`` and ``I``.
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.common import BODY_POSE_DIM, ROOT_DIM, TRANS_DIM, MaxMixture, as_f64, component_grams, mixture_for
from factors.terms import (NormalEquations, Prefetched, RowNoise, Term, cached_callback, concatenate,
                           factor_normal_equations, rows_normal_equations)
from pedx_graph.body.rotation import hat, right_jacobian_inverse
from pedx_graph.priors.difference import difference_parts, temporal_difference

#: The factor kind (``TrackProblem.factor_kinds``, the term cache's registry).
KIND = "temporal_prior"
#: Dimension of the temporal difference.
TEMPORAL_DIM = TRANS_DIM + ROOT_DIM + BODY_POSE_DIM          # 75
_DIMS = [ROOT_DIM, TRANS_DIM, BODY_POSE_DIM, ROOT_DIM, TRANS_DIM, BODY_POSE_DIM]


def sequence_differences(world_R_body: np.ndarray, trans: np.ndarray, body_pose: np.ndarray,
                         step: int = 1) -> np.ndarray:
    """``temporal_difference`` between frames t and t + ``step`` of one sequence: (T - step, 75).

    Inputs: rotations (T, 3, 3), trans (T, 3) metres, body poses (T, 69) radians, at the frame rate the prior
    is meant for (training data resampled to the PedX frame rate).
    """
    rot = np.asarray(world_R_body, dtype=np.float64)
    tr = np.asarray(trans, dtype=np.float64)
    bp = np.asarray(body_pose, dtype=np.float64)
    if not (rot.shape[0] == tr.shape[0] == bp.shape[0]) or step < 1:
        raise ValueError(f"sequence_differences: inconsistent lengths {rot.shape[0]}, {tr.shape[0]}, "
                         f"{bp.shape[0]} or step {step} < 1")
    return temporal_difference(rot[:-step], tr[:-step], bp[:-step], rot[step:], tr[step:], bp[step:])


def _difference_parts(world_R_body_i, trans_i, body_pose_i, world_R_body_j, trans_j, body_pose_j):
    """Batched over P pairs: :func:`pedx_graph.priors.difference.difference_parts` — d (P, 75), the step s
    (P, 3), R_i^T (P, 3, 3), R_ij = R_i^T R_j (P, 3, 3) — and J_r^-1(w) (P, 3, 3) of w = d[:, 3:6]."""
    pairs = len(as_f64(trans_i).reshape(-1, 3))
    d, step, rot_i_t, rel = difference_parts(
        as_f64(world_R_body_i).reshape(-1, 3, 3), as_f64(trans_i).reshape(-1, 3),
        as_f64(body_pose_i).reshape(pairs, -1), as_f64(world_R_body_j).reshape(-1, 3, 3),
        as_f64(trans_j).reshape(-1, 3), as_f64(body_pose_j).reshape(pairs, -1))
    return d, step, rot_i_t, rel, right_jacobian_inverse(d[:, 3:6])


def temporal_difference_jacobians(world_R_body_i: np.ndarray, trans_i: np.ndarray, body_pose_i: np.ndarray,
                                  world_R_body_j: np.ndarray, trans_j: np.ndarray, body_pose_j: np.ndarray
                                  ) -> tuple[np.ndarray, list[np.ndarray]]:
    """d(i, j) (75,) for one pair and its Jacobians w.r.t. (root_i, trans_i, pose_i, root_j, trans_j, pose_j).

    Blocks have shapes (75, 3), (75, 3), (75, 69), (75, 3), (75, 3), (75, 69).
    """
    d, step, rot_i_t, rel, jr_inv = _difference_parts(world_R_body_i, trans_i, body_pose_i,
                                                      world_R_body_j, trans_j, body_pose_j)
    blocks = _chain(np.eye(TEMPORAL_DIM)[None], step, rot_i_t, rel, jr_inv)
    return d[0], [b[0] for b in blocks]


def _chain(jac_x: np.ndarray, step: np.ndarray, rot_i_t: np.ndarray, rel: np.ndarray,
           jr_inv: np.ndarray) -> list[np.ndarray]:
    """``jac_x @ dd/d(key)`` for the six keys, batched over P pairs: ``jac_x`` (P, m, 75) the derivative
    w.r.t. d; returns six (P, m, k) blocks."""
    a_s, a_w, a_p = jac_x[:, :, 0:3], jac_x[:, :, 3:6], jac_x[:, :, 6:]
    a_w_jr = a_w @ jr_inv
    a_s_rt = a_s @ rot_i_t
    return [a_s @ hat(step) - a_w_jr @ np.swapaxes(rel, 1, 2), -a_s_rt, -a_p, a_w_jr, a_s_rt, a_p]


def temporal_prior_batch(world_R_body_i: np.ndarray, trans_i: np.ndarray, body_pose_i: np.ndarray,
                         world_R_body_j: np.ndarray, trans_j: np.ndarray, body_pose_j: np.ndarray,
                         mixture: MaxMixture, frame_gap: np.ndarray, want_jacobian: bool = False,
                         components: list | None = None) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """:func:`temporal_prior_error` for P pairs at once: residuals (P, 76) and six (P, 76, k) blocks.

    Inputs stacked over pairs: rotations (P, 3, 3), translations (P, 3), body poses (P, 69), gaps (P,).
    ``components``: a list that receives the selected mixture component of every pair (P,).
    """
    gap = np.asarray(frame_gap, dtype=np.float64).reshape(-1)
    d, step, rot_i_t, rel, jr_inv = _difference_parts(world_R_body_i, trans_i, body_pose_i,
                                                      world_R_body_j, trans_j, body_pose_j)
    r, best = mixture.residual_batch(d / gap[:, None])
    if components is not None:
        components.append(best)
    if not want_jacobian:
        return r, None
    jac_x = mixture.jacobians(best)
    if np.any(gap != 1.0):
        jac_x /= gap[:, None, None]
    return r, _chain(jac_x, step, rot_i_t, rel, jr_inv)


def temporal_prior_error(world_R_body_i: np.ndarray, trans_i: np.ndarray, body_pose_i: np.ndarray,
                         world_R_body_j: np.ndarray, trans_j: np.ndarray, body_pose_j: np.ndarray,
                         mixture: MaxMixture, frame_gap: int = 1, want_jacobian: bool = False
                         ) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Max-mixture residual (76,) of ``d(i, j) / frame_gap`` and its six Jacobian blocks when asked."""
    r, blocks = temporal_prior_batch(world_R_body_i, trans_i, body_pose_i, world_R_body_j, trans_j,
                                     body_pose_j, mixture, np.array([frame_gap]), want_jacobian)
    return r[0], None if blocks is None else [as_f64(b[0]) for b in blocks]


def make_temporal_prior_factor(key_root_i: int, key_trans_i: int, key_body_pose_i: int,
                               key_root_j: int, key_trans_j: int, key_body_pose_j: int,
                               weights: np.ndarray | None = None, means: np.ndarray | None = None,
                               prec_chol: np.ndarray | None = None, *, mixture: MaxMixture | None = None,
                               frame_gap: int = 1, covariance_scale: float = 1.0, cache=None) -> gtsam.CustomFactor:
    """Temporal max-mixture prior between frame i and frame j = i + ``frame_gap`` (frame periods).

    Pass the GMM arrays (weights (K,), means (K, 75), prec_chol (K, 75, 75)) or a prebuilt ``mixture``
    (then ``covariance_scale`` is ignored).  Keys: Rot3, vector 3, vector 69 for each frame.
    """
    mixture = mixture_for(TEMPORAL_DIM, "temporal prior", weights, means, prec_chol, mixture, covariance_scale)
    if int(frame_gap) != frame_gap or frame_gap < 1:
        raise ValueError(f"frame_gap must be a positive integer, got {frame_gap}")
    gap = int(frame_gap)
    rows = TEMPORAL_DIM + 1

    keys = [key_root_i, key_trans_i, key_body_pose_i, key_root_j, key_trans_j, key_body_pose_j]
    if cache is not None:
        cache.register(KIND, keys, (mixture, gap))

    def compute(k, values: gtsam.Values, jacobians: bool):
        return temporal_prior_error(values.atRot3(k[0]).matrix(), values.atVector(k[1]), values.atVector(k[2]),
                                    values.atRot3(k[3]).matrix(), values.atVector(k[4]), values.atVector(k[5]),
                                    mixture, gap, jacobians)

    return gtsam.CustomFactor(noise_of((mixture, gap)).model(rows), keys,
                              cached_callback(KIND, cache, compute, lambda blocks: _DIMS))


def noise_of(spec: tuple[MaxMixture, int]) -> RowNoise:
    """Unit noise: the mixture whitens (the spec is ``(mixture, frame_gap)``)."""
    return RowNoise(None)


def _by_mixture(mixtures: list) -> list[list[int]]:
    """The positions of ``mixtures`` grouped by mixture object (first-seen order): one batched call each."""
    groups: dict[int, list[int]] = {}
    for n, mixture in enumerate(mixtures):
        groups.setdefault(id(mixture), []).append(n)
    return list(groups.values())


def pair_terms(pairs: list[tuple]) -> list[tuple[np.ndarray, list[np.ndarray]]]:
    """Residuals (76,) and six Jacobian blocks (as the factor's callback returns them) of several pairs of frames
    in one :func:`temporal_prior_batch` call per mixture: ``pairs`` of ``(frame i (world_R_body, trans,
    body_pose), frame j (the same), mixture, gap)``."""
    out: list = [None] * len(pairs)
    for members in _by_mixture([pair[2] for pair in pairs]):
        items = [pairs[n] for n in members]
        states = [np.stack([np.asarray(it[side][n], float) for it in items]) for side in (0, 1) for n in range(3)]
        r, blocks = temporal_prior_batch(*states, items[0][2], np.array([it[3] for it in items], float), True)
        for m, n in enumerate(members):
            out[n] = (np.ascontiguousarray(r[m]), [np.ascontiguousarray(b[m]) for b in blocks])
    return out


def held_normal_equations(keys_list: list[tuple[int, ...]], pairs: list[tuple],
                          terms: list[tuple[np.ndarray, list[np.ndarray]]]) -> NormalEquations:
    """The temporal factors ``keys_list`` with frame i held (the stream's presolve: the previous frame at its
    estimate): their rows on frame j's columns ``[root_j, trans_j, body_pose_j]`` only (``columns`` 75..149),
    from the factors' ``terms`` (:func:`pair_terms` of ``pairs``) and their declared noise (:func:`noise_of`)
    through the shared assembler (:func:`factors.terms.rows_normal_equations`)."""
    residual = np.stack([r for r, _ in terms])
    jacobian = np.stack([np.concatenate(blocks[3:], axis=1) for _, blocks in terms])
    noises = [noise_of((mixture, gap)) for _, _, mixture, gap in pairs]
    inverse = np.stack([noise.inverse_sigmas(residual.shape[1]) for noise in noises])
    return rows_normal_equations(keys_list, residual, jacobian, inverse, [noise.kernel for noise in noises],
                                 columns=np.arange(TEMPORAL_DIM, 2 * TEMPORAL_DIM))


def pair_normal_equations(r: np.ndarray, blocks: list[np.ndarray], mixture: MaxMixture, best: np.ndarray,
                          gap: np.ndarray) -> dict[str, np.ndarray]:
    """Normal equations of P temporal factors in the compact form of their Jacobian ``A = [U_i, -L, U_j, L]``
    (U: the root and translation columns of frames i and j, (76, 6) each; L: the body-pose columns, the same
    up to sign for both frames, ``L = J_k[:, 6:] / gap`` of the selected component k):
    ``utu = U^T U`` (P, 12, 12), ``utl = U^T L`` (P, 12, 69), ``ltl = L^T L`` (P, 69, 69, from the
    component's Gram matrix), ``ub = -U^T r`` (P, 12), ``lb = L^T r`` (P, 69) (= ``(-L)^T b`` with b = -r).
    ``r`` (P, 76) and the six blocks of :func:`temporal_prior_batch`."""
    u = np.concatenate([blocks[0], blocks[1], blocks[3], blocks[4]], axis=2)          # (P, 76, 12)
    lm = blocks[2]                                      # -L (P, 76, 69), contiguous (a strided view, like
    u_t = np.swapaxes(u, 1, 2)                          # blocks[5], would make the batched matmul skip BLAS)
    utl = u_t @ lm
    utl *= -1.0
    ltl = component_grams(mixture, TRANS_DIM + ROOT_DIM)[best]
    if np.any(gap != 1.0):
        ltl = ltl / (gap ** 2)[:, None, None]
    return {"utu": u_t @ u, "utl": utl, "ltl": ltl, "ub": -(u_t @ r[:, :, None])[:, :, 0],
            "lb": (np.swapaxes(lm, 1, 2) @ r[:, :, None])[:, :, 0]}


def pair_dense(pair: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pair_normal_equations` as dense ``A^T A`` (P, 150, 150) and ``A^T b`` (P, 150) over the keys
    ``[root_i, trans_i, body_pose_i, root_j, trans_j, body_pose_j]``."""
    utu, utl, ltl, ub, lb = pair["utu"], pair["utl"], pair["ltl"], pair["ub"], pair["lb"]
    si, pi, sj, pj = slice(0, 6), slice(6, 75), slice(75, 81), slice(81, 150)
    hess = np.empty((len(utu), 150, 150))
    hess[:, si, si], hess[:, si, sj] = utu[:, :6, :6], utu[:, :6, 6:]
    hess[:, sj, si], hess[:, sj, sj] = utu[:, 6:, :6], utu[:, 6:, 6:]
    hess[:, si, pi], hess[:, si, pj] = -utl[:, :6], utl[:, :6]
    hess[:, sj, pi], hess[:, sj, pj] = -utl[:, 6:], utl[:, 6:]
    hess[:, pi, si], hess[:, pj, si] = np.swapaxes(hess[:, si, pi], 1, 2), np.swapaxes(hess[:, si, pj], 1, 2)
    hess[:, pi, sj], hess[:, pj, sj] = np.swapaxes(hess[:, sj, pi], 1, 2), np.swapaxes(hess[:, sj, pj], 1, 2)
    hess[:, pi, pi], hess[:, pj, pj] = ltl, ltl
    hess[:, pi, pj], hess[:, pj, pi] = -ltl, -ltl
    return hess, np.concatenate([ub[:, :6], -lb, ub[:, 6:], lb], axis=1)


def assemble(cache, keys_list: list[tuple[int, ...]], jacobians: bool) -> NormalEquations:
    """The temporal factors ``keys_list`` from the cache's batched pairs (one group per mixture) in the compact
    form of :func:`pair_normal_equations` (``structure``; ``hess`` left None: :func:`pair_dense` forms it), else
    factor by factor (dense)."""
    groups = cache.batch(KIND)
    if {k for g in groups for k in g["keys"]} != set(keys_list):
        return factor_normal_equations(cache, KIND, keys_list, noise_of, jacobians)
    parts = []
    for g in groups:
        ne = NormalEquations(list(g["keys"]), 0.5 * np.sum(g["r"] ** 2, axis=1))
        if jacobians:
            ne.structure = pair_normal_equations(g["r"], g["blocks"], g["mixture"], g["best"], g["gap"])
            ne.bb = np.sum(g["r"] ** 2, axis=1)
        parts.append(ne)
    if len(parts) == 1:
        return parts[0]
    out = concatenate(parts)           # several mixtures: one dense system
    if jacobians:
        dense = [pair_dense(p.structure) for p in parts]
        out.hess, out.grad = np.concatenate([h for h, _ in dense]), np.concatenate([g for _, g in dense])
        out.bb = np.concatenate([p.bb for p in parts])
    return out


def evaluate(cache, specs: dict, prefetched: Prefetched) -> None:
    """The term cache's batched evaluation (:attr:`factors.terms.Term.evaluate`): the factors whose two frames
    were prefetched, one :func:`temporal_prior_batch` per mixture, filed with their selected components."""
    frame_of, states = prefetched.frame_of, prefetched.states
    items = [(fk, mixture, gap) for fk, (mixture, gap) in specs.items() if fk[0] in frame_of and fk[3] in frame_of]
    for members in _by_mixture([mixture for _, mixture, _ in items]):
        group = [items[n] for n in members]
        a = [states[frame_of[fk[0]]] for fk, _, _ in group]
        b = [states[frame_of[fk[3]]] for fk, _, _ in group]
        gaps = np.array([gap for _, _, gap in group], dtype=np.float64)
        best: list = []
        res, blocks = temporal_prior_batch(
            np.stack([s.world_R_body for s in a]), np.stack([s.trans for s in a]),
            np.stack([s.body_pose for s in a]), np.stack([s.world_R_body for s in b]),
            np.stack([s.trans for s in b]), np.stack([s.body_pose for s in b]), group[0][1],
            gaps, prefetched.jacobians, components=best)
        cache.add_batch(KIND, {"keys": [fk for fk, _, _ in group], "r": res, "blocks": blocks,
                               "mixture": group[0][1], "best": best[0], "gap": gaps})


def materialise(group: dict, n: int, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Factor ``n`` of a group of :func:`evaluate`: its residual and six Jacobian blocks."""
    return group["r"][n], ([blk[n] for blk in group["blocks"]] if jacobians else None)


TERM = Term(KIND, assemble, own_frame=False, evaluate=evaluate, materialise=materialise)
