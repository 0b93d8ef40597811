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

from factors.common import BODY_POSE_DIM, MaxMixture, as_f64, set_jacobians


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
    if mixture is None:
        if weights is None or means is None or prec_chol is None:
            raise ValueError("make_pose_prior_factor needs weights, means and prec_chol, or a mixture")
        mixture = MaxMixture(weights, means, prec_chol, covariance_scale=covariance_scale)
    if mixture.dim != BODY_POSE_DIM:
        raise ValueError(f"pose prior mixture must be {BODY_POSE_DIM}-d, got {mixture.dim}")
    rows = mixture.dim + 1

    if cache is not None:
        cache.register("pose_prior", [key_body_pose], mixture)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        hit = None if cache is None else cache.lookup("pose_prior", this.keys(), values, H is not None)
        if hit is not None:
            r, blocks = hit
            jac = None if blocks is None else blocks[0]
        else:
            r, jac, _ = mixture.residual(values.atVector(this.keys()[0]), H is not None)
        if H is not None:
            set_jacobians(H, [jac], rows, [mixture.dim])
        return as_f64(r)

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(rows), [key_body_pose], error)
