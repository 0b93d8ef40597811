"""Shape prior: the track's shape coefficients ``betas ~ N(mean, sigma^2 I)`` (SMPL's betas are whitened PCA),
held inside the prior's support by a one-sided hinge.

Gaussian part (``make_shape_prior_factor``, a native ``gtsam.PriorFactorVector``, picklable)::

    r = (betas - mean) / sigma        (B,), unitless;   E = 0.5 ||r||^2

Support part (``make_shape_support_factor``, a ``gtsam.CustomFactor``), per coefficient ``i``::

    d_i = betas_i - mean_i
    r_i = (d_i - clip(d_i, -bound, bound)) / sigma_hinge      (B,), unitless, zero inside the support
    dr_i / dbetas_j = delta_ij [|d_i| > bound] / sigma_hinge   (the unwhitened Jacobian is 0 or 1)

``bound`` is in betas units (``support_sd * sigma``: the support in prior standard deviations); the energy
``0.5 ||r||^2`` is continuously differentiable (a quadratic wall starting at the bound), as the joint limits.
Why: the shape is one variable shared by all T frames of a track, so T frames of reprojection rows outweigh
one N(0, sigma^2) prior; where the data cannot fix size against depth (one camera, stereo at range) they
drove betas to ~10 (body volume doubled) or, with a wrong up axis, to -30 (a mirrored, inside-out mesh).
The hinge keeps every coefficient within the prior's support whatever the number of frames.

One factor of each per track (the shape is shared by all frames; PedX's shape-consistency term is realised
by sharing that one variable).  Frames: none (betas are frame-free); shapes: betas (B,).
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.common import as_f64, set_jacobians


def shape_prior_error(betas: np.ndarray, mean: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Unwhitened residual ``betas - mean`` (B,) and its Jacobian (identity, (B, B))."""
    betas = as_f64(betas)
    mean = np.zeros_like(betas) if mean is None else as_f64(mean)
    return betas - mean, np.eye(betas.size)


def make_shape_prior_factor(key_betas: int, num_betas: int = 10, sigma: float = 1.0,
                            mean: np.ndarray | None = None) -> gtsam.PriorFactorVector:
    """``PriorFactorVector`` on ``key_betas`` with mean ``mean`` (default 0) and isotropic ``sigma``."""
    if not sigma > 0:
        raise ValueError(f"shape prior sigma must be > 0, got {sigma}")
    mean = np.zeros(num_betas) if mean is None else as_f64(mean)
    if mean.shape != (num_betas,):
        raise ValueError(f"shape prior mean must be ({num_betas},), got {mean.shape}")
    return gtsam.PriorFactorVector(key_betas, mean, gtsam.noiseModel.Isotropic.Sigma(num_betas, float(sigma)))


def shape_support_error(betas: np.ndarray, bound: float, mean: np.ndarray | None = None,
                        want_jacobian: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Unwhitened hinge residual ``d - clip(d, -bound, bound)`` (B,) with ``d = betas - mean``, in betas units,
    and (when ``want_jacobian``) its Jacobian (B, B): diagonal, 1 where ``|d_i| > bound``, else 0."""
    betas = as_f64(betas)
    d = betas - (0.0 if mean is None else as_f64(mean))
    r = d - np.clip(d, -bound, bound)
    jac = np.diag((r != 0.0).astype(np.float64)) if want_jacobian else None
    return r, jac


def make_shape_support_factor(key_betas: int, num_betas: int = 10, bound: float = 3.5,
                              sigma_hinge: float = 0.02, mean: np.ndarray | None = None) -> gtsam.CustomFactor:
    """Hinge factor keeping every ``|betas_i - mean_i| <= bound`` (betas units) on ``key_betas`` (vector,
    ``num_betas``); ``sigma_hinge`` (betas units) is the noise of the wall: a coefficient ``sigma_hinge``
    beyond the bound costs 0.5, as one standard deviation of a Gaussian term."""
    if not (bound > 0 and np.isfinite(bound)):
        raise ValueError(f"shape support bound must be finite and > 0, got {bound}")
    if not sigma_hinge > 0:
        raise ValueError(f"shape support sigma must be > 0, got {sigma_hinge}")
    mean = np.zeros(num_betas) if mean is None else as_f64(mean).copy()
    if mean.shape != (num_betas,):
        raise ValueError(f"shape support mean must be ({num_betas},), got {mean.shape}")
    bound = float(bound)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        r, jac = shape_support_error(values.atVector(this.keys()[0]), bound, mean, H is not None)
        if H is not None:
            set_jacobians(H, [jac], num_betas, [num_betas])
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(num_betas, float(sigma_hinge)), [key_betas], error)


def shape_factors(key_betas: int, num_betas: int, sigma: float, support_sd: float, sigma_hinge: float
                  ) -> list:
    """The track's shape factors: the Gaussian prior ``N(0, sigma^2 I)`` and, when ``support_sd`` is finite and
    > 0, the support hinge at ``support_sd * sigma`` (the prior's support in prior standard deviations)."""
    out = [make_shape_prior_factor(key_betas, num_betas=num_betas, sigma=sigma)]
    if support_sd and np.isfinite(support_sd) and support_sd > 0:
        out.append(make_shape_support_factor(key_betas, num_betas=num_betas, bound=support_sd * sigma,
                                             sigma_hinge=sigma_hinge))
    return out


def consensus_shape(mean_target: np.ndarray, precision: float, sigma: float, bound: float | None,
                    sigma_hinge: float) -> np.ndarray:
    """Per coefficient, ``argmin_b 0.5 b^2 / sigma^2 + 0.5 (b - clip(b, -bound, bound))^2 / sigma_hinge^2
    + 0.5 precision (b - mean_target)^2`` (the ADMM consensus step with the shape prior and its support;
    ``bound`` None: no support).  The objective is convex and piecewise quadratic: the unconstrained minimum
    when it lies inside the bound, else the minimum of the outer quadratic on its side (closed form)."""
    m = as_f64(mean_target)
    inner = precision * m / (1.0 / sigma ** 2 + precision)
    if bound is None or not np.isfinite(bound):
        return inner
    w = 1.0 / sigma_hinge ** 2
    outer = (precision * m + np.sign(inner) * bound * w) / (1.0 / sigma ** 2 + precision + w)
    return np.where(np.abs(inner) <= bound, inner, outer)
