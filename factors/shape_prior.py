"""Shape prior: the track's shape coefficients ``betas ~ N(mean, sigma^2 I)`` (SMPL's betas are whitened PCA).

    r = (betas - mean) / sigma        (B,), unitless;   E = 0.5 ||r||^2

One factor per track (the shape is shared by all frames; PedX's shape-consistency term is realised by
sharing that one variable).  It is a native ``gtsam.PriorFactorVector`` (no Python callback, picklable).
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.common import as_f64


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
