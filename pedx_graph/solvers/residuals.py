"""Residuals of a solved track by factor kind and frame: chi2, robust cost, rows the robust losses rejected,
and terms the estimate contradicts beyond their own noise model.

Per factor at the estimate (``r`` the unwhitened residual, ``Sigma^-1/2`` the base noise):

* ``chi2 = ||Sigma^-1/2 r||^2`` (whitened squared norm, without the robust kernel), summed per factor kind
  and per frame, with the number of rows, so ``chi2 / rows`` ~ 1 for a consistent measurement;
* ``cost`` = the factor's contribution to the graph error (with the robust kernel);
* ``outlier_rows`` = rows whose robust weight ``w(r_row) < outlier_weight`` (for Geman-McClure with scale c:
  ``|r_row| > c`` whitened), i.e. measurements the robust loss effectively switched off;
* ``inconsistent``: a factor without a robust kernel (the heading prior, the pose and temporal
  max-mixtures, the joint limits) whose ``chi2`` exceeds the ``consistency_quantile`` (99.9 %) quantile of
  ``chi2(rows)`` contradicts the estimate beyond what its own noise model allows (robust factors are not
  tested: their outliers are rejected by design).
"""
from __future__ import annotations

from collections import defaultdict

import gtsam
import numpy as np
from scipy.stats import chi2 as chi2_dist

from factors.common import group_norms_from_losses, group_robust_weights
from pedx_graph.graph.config import DiagnosticsConfig


def _factor_residual(factor, values: gtsam.Values, outlier_weight: float,
                     in_factor_robust: tuple[str, float, int] | None = None) -> tuple[float, float, int, int, bool]:
    """(chi2, cost, rows, outlier rows, robust) of one nonlinear factor at ``values`` (``robust``: the factor
    has a robust kernel, in its noise model or inside).

    ``in_factor_robust = (kernel, scale, group)``: the factor applies the kernel itself to groups of
    ``group`` whitened rows (``factors.common.robustify_groups``, unit noise model), so its residual ``s``
    has ``0.5 |s_g|^2 = rho(|r_g|)``; a group is an outlier when ``rho(|r_g|) > rho(scale)`` (it lies beyond
    the kernel's scale, where Geman-McClure's weight drops below 1/4) and all its rows are counted.  Its
    ``chi2`` is ``sum |r_g|^2``, each group's norm recovered from its loss
    (``factors.common.group_norms_from_losses``): without the kernel, as for every other factor.
    """
    cost = float(factor.error(values))
    if not hasattr(factor, "unwhitenedError"):
        return 2.0 * cost, cost, 0, 0, False
    r = np.asarray(factor.unwhitenedError(values), float).reshape(-1)
    model = factor.noiseModel()
    if isinstance(model, gtsam.noiseModel.Robust):
        base, kernel = model.noise(), model.robust()
    else:
        base, kernel = model, None
    white = np.asarray(base.whiten(r), float).reshape(-1)
    outliers = 0
    robust = kernel is not None or (in_factor_robust is not None
                                    and in_factor_robust[0].lower() not in ("none", ""))
    if kernel is not None:
        outliers = int(sum(kernel.weight(float(abs(x))) < outlier_weight for x in white))
    elif in_factor_robust is not None and in_factor_robust[0].lower() not in ("none", ""):
        name, scale, group = in_factor_robust
        g_c, _ = group_robust_weights(np.array([scale]), name.replace("_", ""), scale)
        rho_c = 0.5 * float(g_c[0] * scale) ** 2
        if white.size % group == 0:
            rho = 0.5 * (white.reshape(-1, group) ** 2).sum(axis=1)
            outliers = int(group * np.count_nonzero(rho > rho_c))
            norms = group_norms_from_losses(rho, name, scale)
            return float(norms @ norms), cost, int(r.size), outliers, robust
    return float(white @ white), cost, int(r.size), outliers, robust


def in_factor_robust_kinds(fit_config) -> dict:
    """Factor kinds that robustify inside the factor: kind -> (kernel, scale, rows per group)."""
    if fit_config is None:
        return {}
    noise = fit_config.noise
    return {"lidar_chamfer": (noise.lidar_loss, float(noise.lidar_loss_scale), 3),
            "stereo_reprojection": (noise.reprojection_loss, float(noise.reprojection_loss_scale), 2)}


def residual_tables(problem, values: gtsam.Values, config: DiagnosticsConfig | None = None,
                    fit_config=None) -> tuple[list[dict], dict]:
    """Per-frame and per-track residual totals by factor kind (module docstring).  ``fit_config``
    (:class:`FitConfig`) tells which kinds carry their robust kernel inside the factor."""
    config = config or DiagnosticsConfig()
    inside = in_factor_robust_kinds(fit_config)
    n = len(problem.keys)

    def empty():
        return {"chi2": 0.0, "cost": 0.0, "rows": 0, "outlier_rows": 0, "inconsistent": 0}

    frames = [defaultdict(empty) for _ in range(n)]
    track = defaultdict(empty)
    for j in range(problem.graph.size()):
        factor = problem.graph.at(j)
        if factor is None:
            continue
        kind, frame = problem.factor_kinds[j], problem.factor_frames[j]
        chi2, cost, rows, outliers, robust = _factor_residual(factor, values, config.outlier_weight,
                                                              inside.get(kind))
        bad = int(not robust and rows > 0 and chi2 > chi2_dist.ppf(config.consistency_quantile, rows))
        targets = [track] + ([frames[frame]] if frame >= 0 else [])
        for t in targets:
            t[kind]["chi2"] += chi2
            t[kind]["cost"] += cost
            t[kind]["rows"] += rows
            t[kind]["outlier_rows"] += outliers
            t[kind]["inconsistent"] += bad
    return [dict(f) for f in frames], dict(track)
