"""Gaussian-mixture priors: storage (``.npz``), densities and the max-mixture residual.

A mixture has weights ``w_k`` (K,), means ``mu_k`` (K, D), covariances ``Sigma_k`` (K, D, D) and precision
Cholesky factors ``L_k`` (K, D, D) with ``L_k L_k^T = Sigma_k^-1`` (scikit-learn's ``precisions_cholesky_``).

Max-mixture residual (what a factor graph minimises; Olson & Agarwal 2013, SMPLify's pose prior)::

    c_k   = -log w_k - log det L_k          (= -log(w_k / sqrt(det Sigma_k)))
    c_min = min_k c_k
    k*    = argmin_k  0.5 ||L_k^T (x - mu_k)||^2 + c_k
    r(x)  = [ L_k*^T (x - mu_k*) ;  sqrt(2 (c_k* - c_min)) ]          (D + 1,)
    dr/dx = [ L_k*^T ; 0 ]                                            (D + 1, D)

Because ``-log(w_k N(x; mu_k, Sigma_k)) = 0.5 ||L_k^T (x - mu_k)||^2 + c_k + (D/2) log(2 pi)``,

    0.5 ||r(x)||^2 = min_k [ -log(w_k N_k(x)) ] - C,     C = c_min + (D/2) log(2 pi)

(:meth:`GaussianMixturePrior.residual_constant`): with a unit noise model the factor's error is the negative
log of the best component's weighted density, shifted to be >= 0 at the best mean. The selection ``k*`` is
piecewise constant, so the Jacobian ignores it.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
from scipy.special import logsumexp

from pedx_graph.utils import atomic_write_bytes


class PriorFormatError(ValueError):
    """A prior file is missing or malformed (the message names the file and the key)."""


class MaxMixture:
    """Gaussian mixture evaluated as a max-mixture residual (Olson & Agarwal 2013; SMPLify's pose prior).

    Components ``k`` with weight ``w_k``, mean ``mu_k`` (D,) and precision Cholesky factor ``L_k`` (D, D)
    (``precision_k = L_k L_k^T``, as scikit-learn's ``precisions_cholesky_``).  Per component

        c_k = -log w_k - log|det L_k|     (so -log(w_k N_k(x)) = 0.5 ||L_k^T (x - mu_k)||^2 + c_k + const)

    and with ``c_min = min_k c_k`` the residual is

        k*  = argmin_k 0.5 ||L_k^T (x - mu_k)||^2 + c_k
        r(x) = [L_k*^T (x - mu_k*) ; sqrt(2 (c_k* - c_min))]        (D + 1,)

    so ``0.5 ||r||^2 = -log max_k w_k N_k(x) + const`` (unit noise model).  The Jacobian is ``L_k*^T`` on the
    first D rows and zero on the last (the selection is piecewise constant).  ``covariance_scale`` s
    multiplies every covariance (``L_k -> L_k / sqrt(s)``); it changes every ``c_k`` by the same amount.
    """

    def __init__(self, weights: np.ndarray, means: np.ndarray, prec_chol: np.ndarray,
                 covariance_scale: float = 1.0) -> None:
        weights = np.asarray(weights, dtype=np.float64).reshape(-1)
        means = np.asarray(means, dtype=np.float64)
        prec_chol = np.asarray(prec_chol, dtype=np.float64)
        k = weights.size
        if means.ndim != 2 or means.shape[0] != k:
            raise ValueError(f"means must be (K={k}, D), got {means.shape}")
        d = means.shape[1]
        if prec_chol.shape != (k, d, d):
            raise ValueError(f"prec_chol must be (K={k}, D={d}, D={d}), got {prec_chol.shape}")
        if np.any(weights <= 0) or not np.all(np.isfinite(weights)):
            raise ValueError("mixture weights must be finite and > 0")
        if not covariance_scale > 0:
            raise ValueError(f"covariance_scale must be > 0, got {covariance_scale}")
        sign, logdet = np.linalg.slogdet(prec_chol)
        if np.any(sign == 0) or not np.all(np.isfinite(logdet)):
            raise ValueError("a precision Cholesky factor is singular")
        self.dim = d
        self.num_components = k
        self.means = np.ascontiguousarray(means)
        #: L_k^T / sqrt(s): (K, D, D), so that whitened = lt[k] @ (x - mu_k)
        self.lt = np.ascontiguousarray(np.swapaxes(prec_chol, 1, 2) / np.sqrt(covariance_scale))
        #: Jacobian of the residual per component: (K, D + 1, D), last row zero (read-only views handed out)
        self._jac = np.zeros((k, d + 1, d))
        self._jac[:, :d] = self.lt
        self._jac.setflags(write=False)
        c = -np.log(weights / weights.sum()) - logdet
        self.extra = np.sqrt(2.0 * (c - c.min()))          # (K,) >= 0
        self.c = c - c.min()

    @classmethod
    def from_gmm(cls, gmm: Any, covariance_scale: float = 1.0) -> "MaxMixture":
        """From any object with ``weights``, ``means`` and ``precisions_cholesky`` (or ``prec_chol``), e.g.
        a :class:`GaussianMixturePrior` or a fitted scikit-learn ``GaussianMixture``
        (``covariance_type="full"``)."""
        chol = getattr(gmm, "precisions_cholesky", None)
        if chol is None:
            chol = getattr(gmm, "precisions_cholesky_", None)
        if chol is None:
            chol = getattr(gmm, "prec_chol")
        weights = getattr(gmm, "weights", None)
        weights = getattr(gmm, "weights_") if weights is None else weights
        means = getattr(gmm, "means", None)
        means = getattr(gmm, "means_") if means is None else means
        return cls(weights, means, chol, covariance_scale=covariance_scale)

    def residual(self, x: np.ndarray, want_jacobian: bool = False) -> tuple[np.ndarray, np.ndarray | None, int]:
        """Max-mixture residual (D+1,), its Jacobian (D+1, D) (or None) and the selected component.

        The Jacobian is a read-only array shared between calls (copy it before modifying).
        """
        r, best = self.residual_batch(np.asarray(x, dtype=np.float64)[None])
        k = int(best[0])
        return r[0], (self._jac[k] if want_jacobian else None), k

    def residual_batch(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`residual` of N points at once: residuals (N, D+1) and selected components (N,).

        The Jacobian of row n is ``self.jacobian(best[n])`` (:meth:`jacobian`).
        """
        x = np.asarray(x, dtype=np.float64).reshape(-1, self.dim)
        white = np.empty((len(x), self.num_components, self.dim))                               # (N, K, D)
        for k in range(self.num_components):        # one (N, D) x (D, D) product per component
            np.matmul(x - self.means[k], self.lt[k].T, out=white[:, k])
        cost = 0.5 * np.einsum("nkd,nkd->nk", white, white) + self.c[None]
        best = np.argmin(cost, axis=1)
        rows = np.arange(len(best))
        return np.concatenate([white[rows, best], self.extra[best][:, None]], axis=1), best

    def jacobian(self, component: int) -> np.ndarray:
        """The residual's Jacobian (D+1, D) when ``component`` is selected (read-only, shared)."""
        return self._jac[int(component)]

    def jacobians(self, components: np.ndarray) -> np.ndarray:
        """:meth:`jacobian` of each of N selected components, stacked: (N, D+1, D) (a new array)."""
        return self._jac[np.asarray(components, dtype=np.int64)]

    def negative_log_likelihood(self, x: np.ndarray) -> float:
        """``0.5 ||r(x)||^2`` (max-mixture cost, up to a constant)."""
        r, _, _ = self.residual(x)
        return 0.5 * float(r @ r)


@dataclass(frozen=True)
class GaussianMixturePrior:
    """A trained Gaussian mixture with the max-mixture residual of the module docstring."""

    name: str
    """``"pose"`` or ``"temporal"`` (or any label)."""
    weights: np.ndarray
    """(K,) mixture weights, summing to 1."""
    means: np.ndarray
    """(K, D) component means."""
    covariances: np.ndarray
    """(K, D, D) component covariances."""
    precisions_cholesky: np.ndarray
    """(K, D, D) ``L_k`` with ``L_k L_k^T = Sigma_k^-1``."""
    dims: tuple[str, ...]
    """(D,) description of each dimension (joint and axis, unit)."""
    dt: float | None = None
    """Frame interval the temporal prior was trained at, seconds (None for the pose prior)."""
    meta: dict = field(default_factory=dict)
    """Provenance (training clips, seed, versions, log-likelihoods...)."""

    def __post_init__(self) -> None:
        w = np.asarray(self.weights, dtype=np.float64).reshape(-1)
        mu = np.asarray(self.means, dtype=np.float64)
        cov = np.asarray(self.covariances, dtype=np.float64)
        chol = np.asarray(self.precisions_cholesky, dtype=np.float64)
        k = w.size
        if mu.ndim != 2 or mu.shape[0] != k:
            raise ValueError(f"prior '{self.name}': means must be (K={k}, D), got {mu.shape}")
        d = mu.shape[1]
        for label, arr in (("covariances", cov), ("precisions_cholesky", chol)):
            if arr.shape != (k, d, d):
                raise ValueError(f"prior '{self.name}': {label} must be ({k}, {d}, {d}), got {arr.shape}")
        if np.any(w <= 0) or not np.all(np.isfinite(w)):
            raise ValueError(f"prior '{self.name}': weights must be finite and > 0")
        if len(self.dims) != d:
            raise ValueError(f"prior '{self.name}': {len(self.dims)} dim names for D = {d}")
        for attr, arr in (("weights", w / w.sum()), ("means", mu), ("covariances", cov),
                          ("precisions_cholesky", chol)):
            arr = np.ascontiguousarray(arr)
            arr.setflags(write=False)
            object.__setattr__(self, attr, arr)
        object.__setattr__(self, "dims", tuple(self.dims))

    # ------------------------------------------------------------------------------------------ sizes
    @property
    def num_components(self) -> int:
        return int(self.weights.size)

    @property
    def dim(self) -> int:
        return int(self.means.shape[1])

    @property
    def prec_chol(self) -> np.ndarray:
        """Alias of :attr:`precisions_cholesky` (the name ``factors.common.MaxMixture`` takes)."""
        return self.precisions_cholesky

    # ------------------------------------------------------------------------------- constant terms
    @property
    def component_constants(self) -> np.ndarray:
        """(K,) ``c_k = -log w_k - log det L_k`` (un-normalised)."""
        _, logdet = np.linalg.slogdet(self.precisions_cholesky)
        return -np.log(self.weights) - logdet

    @property
    def normalised_constants(self) -> np.ndarray:
        """(K,) ``c_k - min_k c_k`` (>= 0)."""
        c = self.component_constants
        return c - c.min()

    def residual_constant(self) -> float:
        """``C`` with ``0.5 ||r(x)||^2 = min_k [-log(w_k N_k(x))] - C`` (``C = c_min + (D/2) log 2 pi``)."""
        return float(self.component_constants.min() + 0.5 * self.dim * np.log(2.0 * np.pi))

    # ------------------------------------------------------------------------------------ densities
    def _whitened(self, x: np.ndarray) -> np.ndarray:
        """(..., K, D) ``L_k^T (x - mu_k)`` for x (..., D)."""
        diff = np.asarray(x, dtype=np.float64)[..., None, :] - self.means
        return np.einsum("kji,...kj->...ki", self.precisions_cholesky, diff)

    def component_log_densities(self, x: np.ndarray) -> np.ndarray:
        """(..., K) ``log(w_k N(x; mu_k, Sigma_k))``."""
        white = self._whitened(x)
        return (-0.5 * np.sum(white * white, axis=-1) - self.component_constants
                - 0.5 * self.dim * np.log(2.0 * np.pi))

    def log_density(self, x: np.ndarray) -> np.ndarray:
        """(...,) log of the full mixture density ``log sum_k w_k N_k(x)``."""
        return logsumexp(self.component_log_densities(x), axis=-1)

    # ---------------------------------------------------------------------------- max-mixture factor
    def max_mixture(self, covariance_scale: float = 1.0) -> "MaxMixture":
        """This mixture as a :class:`MaxMixture` (the one implementation of the residual; every covariance
        times ``covariance_scale``)."""
        if covariance_scale == 1.0:
            return self._unit_max_mixture
        return MaxMixture(self.weights, self.means, self.precisions_cholesky, covariance_scale=covariance_scale)

    @cached_property
    def _unit_max_mixture(self) -> "MaxMixture":
        return MaxMixture(self.weights, self.means, self.precisions_cholesky)

    def residual(self, x: np.ndarray, want_jacobian: bool = False
                 ) -> tuple[np.ndarray, np.ndarray | None, int]:
        """Max-mixture residual (D+1,), its Jacobian (D+1, D) or None, and the selected component k*
        (:meth:`MaxMixture.residual`)."""
        x = np.asarray(x, dtype=np.float64)
        if x.shape != (self.dim,):
            raise ValueError(f"prior '{self.name}': x must be ({self.dim},), got {x.shape}")
        return self.max_mixture().residual(x, want_jacobian)

    def residuals(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Batched :meth:`residual`: x (N, D) -> residuals (N, D+1) and selected components (N,)."""
        return self.max_mixture().residual_batch(np.atleast_2d(x))

    # ---------------------------------------------------------------------------------------- files
    def save_npz(self, path: str | os.PathLike) -> Path:
        """Write the prior atomically as ``.npz`` (arrays + ``dims`` + JSON ``meta``)."""
        import io
        buf = io.BytesIO()
        np.savez_compressed(buf, weights=self.weights, means=self.means, covariances=self.covariances,
                            precisions_cholesky=self.precisions_cholesky,
                            dims=np.array(self.dims), dt=np.array(np.nan if self.dt is None else self.dt),
                            name=np.array(self.name), meta=np.array(json.dumps(self.meta)))
        return atomic_write_bytes(path, buf.getvalue())

    @classmethod
    def load_npz(cls, path: str | os.PathLike) -> "GaussianMixturePrior":
        """Read a prior written by :meth:`save_npz` (PriorFormatError naming the file and key)."""
        path = Path(path)
        if not path.is_file():
            raise PriorFormatError(f"{path}: prior file not found")
        try:
            data = np.load(path, allow_pickle=False)
        except Exception as exc:
            raise PriorFormatError(f"{path}: not a readable .npz file ({exc})") from None
        with data:
            for key in ("weights", "means", "covariances", "precisions_cholesky", "dims"):
                if key not in data.files:
                    raise PriorFormatError(f"{path}: missing key '{key}'")
            dt = float(data["dt"]) if "dt" in data.files else float("nan")
            try:
                return cls(name=str(data["name"]) if "name" in data.files else path.stem,
                           weights=data["weights"], means=data["means"], covariances=data["covariances"],
                           precisions_cholesky=data["precisions_cholesky"],
                           dims=tuple(str(s) for s in data["dims"]),
                           dt=None if not np.isfinite(dt) else dt,
                           meta=json.loads(str(data["meta"])) if "meta" in data.files else {})
            except ValueError as exc:
                raise PriorFormatError(f"{path}: {exc}") from None


def from_sklearn(name: str, gmm, dims: tuple[str, ...], dt: float | None = None,
                 meta: dict | None = None) -> GaussianMixturePrior:
    """Wrap a fitted ``sklearn.mixture.GaussianMixture(covariance_type="full")``."""
    if getattr(gmm, "covariance_type", None) != "full":
        raise ValueError("only covariance_type='full' mixtures are supported")
    return GaussianMixturePrior(name=name, weights=gmm.weights_, means=gmm.means_, covariances=gmm.covariances_,
                                precisions_cholesky=gmm.precisions_cholesky_, dims=dims, dt=dt,
                                meta=dict(meta or {}))


def precision_cholesky_from_covariance(cov: np.ndarray) -> np.ndarray:
    """(K, D, D) ``L_k`` with ``L_k L_k^T = Sigma_k^-1`` (upper triangular, as scikit-learn)."""
    out = np.empty_like(cov)
    for k, sigma in enumerate(cov):
        chol = np.linalg.cholesky(sigma)                 # sigma = C C^T
        inv = np.linalg.solve(chol, np.eye(len(sigma)))  # C^-1
        out[k] = inv.T                                   # L = C^-T -> L L^T = C^-T C^-1 = sigma^-1
    return out
