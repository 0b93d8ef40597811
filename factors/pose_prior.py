"""E_P: Gaussian-mixture pose prior on the 69-d SMPL body pose, as a max-mixture residual.

PedX (Kim et al.) regularises each frame's body pose with a pose prior E_P (as in SMPLify, a GMM fitted to
motion capture).  Here the mixture is evaluated as a max-mixture (see :class:`factors.common.MaxMixture`):

    k*   = argmin_k 0.5 ||L_k^T (theta - mu_k)||^2 + c_k
    r    = [L_k*^T (theta - mu_k*) ; sqrt(2 (c_k* - c_min))]          (D + 1,) = (70,), unitless
    E_P  = 0.5 ||r||^2 = -log max_k w_k N(theta; mu_k, Sigma_k) + const

``theta`` (69,) is the axis-angle body pose (SMPL joints 1..23, radians, each relative to its parent).  The
noise model is unit (the mixture carries the scale); ``covariance_scale`` > 1 weakens the prior.  The
Jacobian is ``L_k*^T`` (first 69 rows) and zero on the last row.  The mixture parameters are plain arrays
(weights (K,), means (K, 69), prec_chol (K, 69, 69), precision = L L^T), e.g. from
``pedx_graph.priors.load_pose_prior()``.
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.common import BODY_POSE_DIM, MaxMixture, as_f64, component_grams, mixture_for
from factors.terms import (NormalEquations, Prefetched, RowNoise, Term, cached_callback, concatenate,
                           factor_normal_equations)

#: The factor kind (``TrackProblem.factor_kinds``, the term cache's registry).
KIND = "pose_prior"


def pose_prior_error(body_pose: np.ndarray, mixture: MaxMixture,
                     want_jacobian: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Max-mixture residual (D+1,) of the body pose (D,) and its Jacobian (D+1, D) when asked."""
    r, jac, _ = mixture.residual(body_pose, want_jacobian)
    return r, jac


def make_pose_prior_factor(key_body_pose: int, weights: np.ndarray | None = None,
                           means: np.ndarray | None = None, prec_chol: np.ndarray | None = None, *,
                           mixture: MaxMixture | None = None,
                           covariance_scale: float = 1.0, cache=None) -> gtsam.CustomFactor:
    """Unary max-mixture pose prior on ``key_body_pose`` (vector, 69).

    Pass either the arrays ``weights, means, prec_chol`` or a prebuilt ``mixture`` (shared by many factors;
    then ``covariance_scale`` is ignored: it is baked into the mixture).  ``cache``: a batched evaluator
    (``pedx_graph.graph.batch.BatchedBodyModel``) that may serve the residual for the current values.
    """
    mixture = mixture_for(BODY_POSE_DIM, "pose prior", weights, means, prec_chol, mixture, covariance_scale)
    if cache is not None:
        cache.register(KIND, [key_body_pose], mixture)

    def compute(keys, values: gtsam.Values, jacobians: bool):
        r, jac, _ = mixture.residual(values.atVector(keys[0]), jacobians)
        return as_f64(r), [jac]

    return gtsam.CustomFactor(noise_of(mixture).model(mixture.dim + 1), [key_body_pose],
                              cached_callback(KIND, cache, compute, lambda blocks: [mixture.dim]))


def noise_of(mixture: MaxMixture) -> RowNoise:
    """Unit noise: the mixture whitens (its spec is the mixture itself)."""
    return RowNoise(None)


def mixture_normal_equations(mixture: MaxMixture, r: np.ndarray, best: np.ndarray) -> tuple[np.ndarray, ...]:
    """Normal equations of G max-mixture factors (unit noise) with residuals ``r`` (G, D + 1) and selected
    components ``best`` (G,): ``A^T A`` = the component's Gram matrix, ``A^T b = -L_k r[:D]`` (the Jacobian is
    ``[L_k^T; 0]``), ``b^T b``."""
    grad = -np.einsum("fri,fr->fi", mixture.lt[best], r[:, :mixture.dim])
    return component_grams(mixture)[best], grad, np.sum(r * r, axis=1)


def assemble(cache, keys_list: list[tuple[int, ...]], jacobians: bool) -> NormalEquations:
    """The pose-prior factors ``keys_list`` (column: the body pose) from the cache's batched residuals (one
    group per mixture), else factor by factor."""
    groups = cache.batch(KIND)
    if {k for g in groups for k in g["keys"]} != set(keys_list):
        return factor_normal_equations(cache, KIND, keys_list, noise_of, jacobians)
    parts = []
    for g in groups:
        error = 0.5 * np.sum(g["r"] ** 2, axis=1)
        ne = NormalEquations(list(g["keys"]), error)
        if jacobians:
            ne.hess, ne.grad, ne.bb = mixture_normal_equations(g["mixture"], g["r"], g["best"])
        parts.append(ne)
    return concatenate(parts)


def evaluate(cache, specs: dict, prefetched: Prefetched) -> None:
    """The term cache's batched evaluation (:attr:`factors.terms.Term.evaluate`): one
    ``MaxMixture.residual_batch`` per mixture over the body poses of its factors' frames."""
    pose_index = {k.body_pose: i for i, k in enumerate(prefetched.keys)}
    for mixture in {id(m): m for m in specs.values()}.values():
        fkeys = [fk for fk, m in specs.items() if m is mixture and fk[0] in pose_index]
        res, best = mixture.residual_batch(np.stack([prefetched.states[pose_index[fk[0]]].body_pose for fk in fkeys]))
        cache.add_batch(KIND, {"keys": fkeys, "r": res, "best": best, "mixture": mixture})


def materialise(group: dict, n: int, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Factor ``n`` of a group of :func:`evaluate`: its residual and the selected component's Jacobian."""
    return group["r"][n], ([group["mixture"].jacobian(group["best"][n])] if jacobians else None)


TERM = Term(KIND, assemble, evaluate=evaluate, materialise=materialise)
