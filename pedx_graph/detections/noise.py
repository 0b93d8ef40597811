"""Detector confidences -> per-keypoint pixel noise (sigma, px) and the drop threshold, in physical units.

A detector's confidence is no noise model; what the fit needs is the pixel standard deviation of a keypoint
of that confidence.  :class:`DetectionNoiseConfig` holds it as a piecewise-linear curve ``sigma_px(c)`` over
confidence knots (per keypoint set, one default curve for sets without their own), and the confidence below
which a keypoint is dropped (treated as absent, never invented).  The curve is *measured*, not chosen:
:func:`fit_sigma_curve` fits it from residuals of simulated detections against the true projections
(``benchmarks/bench_detection_noise.py`` runs it on the simulator's detector output and writes the numbers
that are shipped here as defaults).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: 1 / Phi^-1(3/4): the median absolute deviation of a normal variable times this is its standard deviation.
MAD_TO_SIGMA = 1.4826


@dataclass
class SigmaCurve:
    """Pixel noise of a keypoint as a function of its detector confidence (per axis, rectified pixels)."""

    confidence_knots: tuple[float, ...] = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
    """Confidences (increasing; detectors' are in [0, 1]) at which the noise is given; constant beyond the end
    knots."""
    sigma_px: tuple[float, ...] = (48.219, 20.659, 14.164, 11.361, 9.548, 7.317, 5.126, 3.65, 3.116)
    """Standard deviation per image axis at each knot, pixels (linear in between).  Default: the pooled fit over
    all keypoint sets of ``python benchmarks/bench_detection_noise.py --scenes 2 --pedestrians 8 --frames 20``
    (benchmarks/results/bench_detection_noise.md)."""

    def __post_init__(self) -> None:
        knots, sig = np.asarray(self.confidence_knots, float), np.asarray(self.sigma_px, float)
        if knots.ndim != 1 or knots.shape != sig.shape or len(knots) == 0:
            raise ValueError("confidence_knots and sigma_px must be two equally long non-empty lists")
        if np.any(np.diff(knots) <= 0) or not np.all(np.isfinite(knots)):
            raise ValueError(f"confidence_knots must increase, got {list(knots)}")
        if np.any(~np.isfinite(sig)) or np.any(sig <= 0):
            raise ValueError(f"sigma_px must be positive, got {list(sig)}")

    def __call__(self, confidence: np.ndarray) -> np.ndarray:
        """Sigma (px) of each confidence (same shape)."""
        return np.interp(np.asarray(confidence, dtype=float), self.confidence_knots, self.sigma_px)


@dataclass
class DetectionNoiseConfig:
    """How detector confidences become pixel noise for the fit (``pedx-graph import``, the labels' sigma_px)."""

    min_confidence: float = 0.3
    """Keypoints whose confidence is below this are dropped (unlabelled).  Default: the lowest knot whose
    simulated-detector sigma is at most 20 px (benchmarks/results/bench_detection_noise.md; below it the
    residuals are tens of pixels with heavy tails: gross outliers and left/right swaps)."""
    default: SigmaCurve = field(default_factory=SigmaCurve)
    """Sigma-vs-confidence curve of every keypoint set without its own entry in :attr:`per_set`."""
    per_set: dict[str, SigmaCurve] = field(default_factory=dict)
    """Keypoint set name (``coco17``, ``body25``, ...) -> its own curve."""
    annotation_sigma_px: float = 3.0
    """Sigma of a keypoint from a manual annotation file (COCO annotations: confidence 1 by visibility, no
    detector score), pixels per axis."""
    occluded_sigma_factor: float = 2.5
    """An annotation's keypoint marked labelled-but-not-visible (COCO ``v = 1``) gets this many times the
    sigma (the clicks land on a guessed position)."""

    def __post_init__(self) -> None:
        # a YAML file gives the curves as mappings
        if isinstance(self.default, dict):
            self.default = SigmaCurve(**self.default)
        self.per_set = {name: curve if isinstance(curve, SigmaCurve) else SigmaCurve(**curve)
                        for name, curve in dict(self.per_set).items()}

    def curve(self, keypoint_set: str) -> SigmaCurve:
        """The curve used for ``keypoint_set``."""
        return self.per_set.get(keypoint_set, self.default)

    def sigma(self, keypoint_set: str, confidence: np.ndarray, occluded: np.ndarray | None = None,
              annotation: bool = False) -> np.ndarray:
        """(K,) sigma (px) per keypoint; NaN where the keypoint is dropped (confidence below the threshold).

        ``annotation``: the keypoints are a manual annotation (sigma :attr:`annotation_sigma_px`, times
        :attr:`occluded_sigma_factor` where ``occluded``), not detector output.
        """
        confidence = np.asarray(confidence, dtype=float)
        if annotation:
            out = np.full(confidence.shape, float(self.annotation_sigma_px))
        else:
            out = self.curve(keypoint_set)(confidence)
        if occluded is not None:
            out = np.where(np.asarray(occluded, dtype=bool), out * self.occluded_sigma_factor, out)
        return np.where(confidence >= max(self.min_confidence, 1e-12), out, np.nan)


def fit_sigma_curve(confidence: np.ndarray, residual_px: np.ndarray, knots: tuple[float, ...],
                    min_samples: int = 30) -> tuple[SigmaCurve, list[dict]]:
    """Fit a :class:`SigmaCurve` from detections' residuals against the truth.

    ``confidence`` (N,), ``residual_px`` (N, 2) rectified pixel errors of the same keypoints.  Each knot's sigma
    is the robust spread (``MAD * 1.4826`` over both axes) of the residuals whose confidence is nearest to that
    knot (bins bounded by the midpoints between knots); a bin with fewer than ``min_samples`` takes its
    neighbour's value.  Returns the curve and a per-bin table (knot, bin range, count, sigma, raw RMS,
    fraction beyond 5 sigma).
    """
    confidence = np.asarray(confidence, dtype=float)
    residual_px = np.asarray(residual_px, dtype=float).reshape(-1, 2)
    knots = tuple(float(k) for k in knots)
    edges = np.concatenate([[-np.inf], 0.5 * (np.array(knots[1:]) + np.array(knots[:-1])), [np.inf]])
    rows, sigmas = [], []
    for i, knot in enumerate(knots):
        sel = (confidence >= edges[i]) & (confidence < edges[i + 1])
        res = residual_px[sel]
        count = int(sel.sum())
        if count >= min_samples:
            centred = res - np.median(res, axis=0)
            sigma = float(MAD_TO_SIGMA * np.median(np.abs(centred)))
            rms = float(np.sqrt(np.mean(res ** 2)))
            beyond = float(np.mean(np.abs(centred) > 5 * sigma)) if sigma > 0 else 0.0
        else:
            sigma, rms, beyond = float("nan"), float("nan"), float("nan")
        sigmas.append(sigma)
        rows.append({"knot": knot, "bin": [float(edges[i]), float(edges[i + 1])], "count": count,
                     "sigma_px": sigma, "rms_px": rms, "frac_beyond_5sigma": beyond})
    sig = np.array(sigmas)
    if np.all(np.isnan(sig)):
        raise ValueError("no confidence bin holds enough residuals to fit a sigma")
    good = np.flatnonzero(~np.isnan(sig))
    for i in np.flatnonzero(np.isnan(sig)):
        sig[i] = sig[good[np.argmin(np.abs(good - i))]]
    # A noise that grows as confidence falls: enforce monotonic non-increase (pool adjacent violators).
    sig = _non_increasing(sig, np.array([max(r["count"], 1) for r in rows], dtype=float))
    return SigmaCurve(confidence_knots=knots, sigma_px=tuple(round(float(s), 3) for s in sig)), rows


def _non_increasing(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted least-squares non-increasing fit (pool-adjacent-violators)."""
    blocks = [[float(v), float(w), 1] for v, w in zip(values, weights)]
    merged: list[list[float]] = []
    for block in blocks:
        merged.append(block)
        while len(merged) > 1 and merged[-2][0] < merged[-1][0]:
            v2, w2, n2 = merged.pop()
            v1, w1, n1 = merged.pop()
            merged.append([(v1 * w1 + v2 * w2) / (w1 + w2), w1 + w2, n1 + n2])
    return np.concatenate([[v] * int(n) for v, _, n in merged])
