"""Detector confidences and person size -> per-keypoint pixel noise (sigma, px) and the drop threshold.

A detector's confidence is no noise model; what the fit needs is the pixel standard deviation of a keypoint.
A detector's pixel error grows with the person's image size (COCO's OKS likewise scores keypoint error
relative to the object's scale), so the model is::

    sigma_px(c, h, k) = k_scale[k] * sqrt(floor_px^2 + (curve(c) * h / reference_height_px)^2)

``c`` the keypoint's confidence, ``h`` the person's image height measured on the detection itself (vertical
span of its present keypoints, rectified pixels, :func:`detection_height_px`; never from truth), ``curve`` a
piecewise-linear sigma at the reference height over confidence knots (one default curve, optionally one per
keypoint set), ``k_scale`` a per-keypoint relative factor per keypoint set (wrists are noisier than
shoulders, like OKS's per-keypoint sigmas; 1 where none is given) and ``floor_px`` the size-independent
part.  Keypoints below ``min_confidence`` are dropped (treated as absent, never invented).  Everything is
*measured*, not chosen: :func:`fit_noise_model` fits it from residuals of simulated detections against the
true projections (``benchmarks/bench_detection_noise.py`` runs it on the simulator's detector output and
writes the numbers that are shipped here as defaults).  A real detector is not the simulated one:
:func:`stereo_row_scale` checks the model against a dataset's own stereo rows (no truth needed) and gives
the factor by which the data show it too confident, which the import applies.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

#: 1 / Phi^-1(3/4): the median absolute deviation of a normal variable times this is its standard deviation.
MAD_TO_SIGMA = 1.4826


@dataclass
class SigmaCurve:
    """Pixel noise of a keypoint of a person of the reference height as a function of its detector confidence
    (per axis, rectified pixels)."""

    confidence_knots: tuple[float, ...] = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
    """Confidences (increasing; detectors' are in [0, 1]) at which the noise is given; constant beyond the end
    knots."""
    sigma_px: tuple[float, ...] = (30.938, 15.584, 10.837, 7.745, 6.802, 5.262, 3.345, 1.898, 1.192)
    """Standard deviation per image axis at each knot for a person of
    :attr:`DetectionNoiseConfig.reference_height_px`, pixels (linear in between; scales with the person's
    height).  Default: the pooled fit over all keypoint sets of ``python benchmarks/bench_detection_noise.py``
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
        """Sigma (px at the reference height) of each confidence (same shape)."""
        return np.interp(np.asarray(confidence, dtype=float), self.confidence_knots, self.sigma_px)


def detection_height_px(uv: np.ndarray) -> float:
    """A person's image height measured on its detection: the vertical span of its present keypoints ((K, 2)
    pixels, NaN = absent), pixels; 0 with fewer than two."""
    v = np.asarray(uv, dtype=float).reshape(-1, 2)
    v = v[np.all(np.isfinite(v), axis=1), 1]
    return float(np.ptp(v)) if len(v) >= 2 else 0.0


@functools.lru_cache(maxsize=None)
def standing_span_m(keypoint_set: str) -> float:
    """The vertical span of ``keypoint_set``'s keypoints on the open model's mean shape standing, metres (a
    person's image height in pixels over it: its pixels per metre)."""
    from pedx_graph.body.templates import open_standing_keypoints_3d

    return float(np.ptp(open_standing_keypoints_3d(keypoint_set)[:, 1]))


#: Shipped per-keypoint relative factors (``python benchmarks/bench_detection_noise.py``).
_KEYPOINT_SCALE: dict[str, tuple[float, ...]] = {
    "body25": (0.492, 1, 0.894, 1.561, 1.65, 1.054, 1.51, 1.563, 1.704, 1.836, 1.365, 1.01, 2.002, 1.44, 1.02,
               0.51, 0.492, 0.716, 0.667, 0.957, 0.879, 0.969, 0.948, 0.928, 0.987),
    "body25b": (0.513, 0.516, 0.487, 0.743, 0.673, 1.05, 0.984, 1.626, 1.507, 1.636, 1.566, 2.026, 1.908, 1.486,
                1.38, 0.937, 0.969, 0.994, 1.141, 1.001, 1.005, 1, 0.946, 0.927, 0.939),
    "coco17": (0.49, 0.46, 0.507, 0.72, 0.647, 0.935, 1, 1.487, 1.375, 1.721, 1.536, 2.222, 1.968, 1.4, 1.462,
               0.945, 0.978),
    "coco18": (0.458, 0.97, 0.89, 1.311, 1.414, 1.03, 1.36, 1.469, 1.96, 1.278, 0.852, 1.996, 1.32, 0.894, 0.399,
               0.504, 0.66, 0.675),
}


@dataclass
class DetectionNoiseConfig:
    """How detector confidences and person size become pixel noise for the fit (``pedx-graph import``, the
    labels' sigma_px; model in the module docstring)."""

    min_confidence: float = 0.2
    """Keypoints whose confidence is below this are dropped (unlabelled).  Default: the lowest knot whose
    simulated-detector sigma at the reference height is at most 10 % of it
    (benchmarks/results/bench_detection_noise.md; below it the residuals are tens of percent of the person's
    height with heavy tails: gross outliers and left/right swaps)."""
    reference_height_px: float = 200.0
    """The person image height the curves' ``sigma_px`` are given for, pixels (a convention of the curves,
    not a property of the data)."""
    floor_px: float = 1.75
    """Size-independent part of a detected keypoint's noise per axis (added in quadrature), pixels.
    Default: measured with the curve (benchmarks/results/bench_detection_noise.md)."""
    default: SigmaCurve = field(default_factory=SigmaCurve)
    """Sigma-vs-confidence curve of every keypoint set without its own entry in :attr:`per_set`."""
    per_set: dict[str, SigmaCurve] = field(default_factory=dict)
    """Keypoint set name (``coco17``, ``body25``, ...) -> its own curve."""
    keypoint_scale: dict[str, tuple[float, ...]] = field(default_factory=lambda: dict(_KEYPOINT_SCALE))
    """Keypoint set name -> a relative noise factor per keypoint in the set's order (median 1); a set without
    an entry uses 1 for every keypoint.  Default: measured per set
    (benchmarks/results/bench_detection_noise.md)."""
    annotation_sigma_px: float = 3.0
    """Sigma of a keypoint of median difficulty from a manual annotation file (COCO annotations: confidence 1
    by visibility, no detector score), pixels per axis; each keypoint gets it times its set's
    :attr:`keypoint_scale` factor (surface hips and wrists are clicked less precisely than eyes, as in the
    PedX click noise the simulator's factors come from)."""
    occluded_sigma_factor: float = 2.5
    """An annotation's keypoint marked labelled-but-not-visible (COCO ``v = 1``) gets this many times the
    sigma (the clicks land on a guessed position)."""
    definition_sigma_m: float = 0.0
    """How far the detector's own points may lie from the body model's definitions of them, metres on the body
    per axis (a detector's "hip" is its training labels' idea, not ours): added in quadrature to every
    keypoint's sigma as pixels at the person's scale (:meth:`definition_sigma_px`), after the stereo-row check
    (an offset common to both images of a pair cancels in their rows).  0 = the detector's points taken for
    the definitions, as the simulator's are by default.  What 2 and 4 cm cost, and what this term gives back:
    docs/detections.md, "A detector whose points are not our definitions"."""

    def __post_init__(self) -> None:
        # a YAML file gives the curves as mappings
        if isinstance(self.default, dict):
            self.default = SigmaCurve(**self.default)
        self.per_set = {name: curve if isinstance(curve, SigmaCurve) else SigmaCurve(**curve)
                        for name, curve in dict(self.per_set).items()}
        self.keypoint_scale = {name: tuple(float(v) for v in values)
                               for name, values in dict(self.keypoint_scale).items()}
        for name, values in self.keypoint_scale.items():
            if not values or not all(np.isfinite(v) and v > 0 for v in values):
                raise ValueError(f"keypoint_scale[{name!r}] must be positive numbers, got {list(values)}")

    def curve(self, keypoint_set: str) -> SigmaCurve:
        """The curve used for ``keypoint_set``."""
        return self.per_set.get(keypoint_set, self.default)

    def scale(self, keypoint_set: str, count: int) -> np.ndarray:
        """(count,) per-keypoint relative factors of ``keypoint_set`` (ones when the set has none or they do
        not fit its size)."""
        values = self.keypoint_scale.get(keypoint_set)
        if values is None or len(values) != count:
            return np.ones(count)
        return np.asarray(values, dtype=float)

    def definition_sigma_px(self, keypoint_set: str, height_px: float) -> float:
        """:attr:`definition_sigma_m` in pixels for a person of image height ``height_px`` (the span of its
        present keypoints, :func:`detection_height_px`): times ``height_px`` over the set's keypoint span on
        the open model's mean shape standing (:func:`standing_span_m`), the person's pixels per metre."""
        if self.definition_sigma_m <= 0:
            return 0.0
        return float(self.definition_sigma_m) * max(float(height_px), 0.0) / standing_span_m(keypoint_set)

    def sigma(self, keypoint_set: str, confidence: np.ndarray, occluded: np.ndarray | None = None,
              annotation: bool = False, height_px: float | None = None) -> np.ndarray:
        """(K,) sigma (px) per keypoint; NaN where the keypoint is dropped (confidence below the threshold).

        ``height_px``: the person's image height measured on the detection (:func:`detection_height_px`);
        None = the reference height.  ``annotation``: the keypoints are a manual annotation (sigma
        :attr:`annotation_sigma_px` times the keypoint's :attr:`keypoint_scale` factor, times
        :attr:`occluded_sigma_factor` where ``occluded``), not detector output.
        """
        confidence = np.asarray(confidence, dtype=float)
        if annotation:
            out = float(self.annotation_sigma_px) * self.scale(keypoint_set, confidence.shape[-1])
        else:
            height = self.reference_height_px if height_px is None else max(float(height_px), 0.0)
            relative = self.curve(keypoint_set)(confidence) * height / self.reference_height_px
            out = np.hypot(self.floor_px, relative) * self.scale(keypoint_set, confidence.shape[-1])
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


def _robust_sigma(residual: np.ndarray) -> float:
    """Robust per-axis spread of (N, 2) residuals: 1.4826 MAD over both axes about their median."""
    centred = residual - np.median(residual, axis=0)
    return float(MAD_TO_SIGMA * np.median(np.abs(centred)))


def keypoint_scales(keypoint: np.ndarray, residual_px: np.ndarray, height_px: np.ndarray, count: int,
                    reference_height_px: float, min_samples: int = 30) -> np.ndarray:
    """(count,) relative noise factor of each keypoint of a set (median 1): the robust spread of its residuals
    divided by the person's relative height ``h / reference_height_px``, over the median of those spreads.
    ``keypoint`` (N,) index of each residual; a keypoint with fewer than ``min_samples`` residuals gets 1."""
    keypoint = np.asarray(keypoint, dtype=int)
    scaled = np.asarray(residual_px, dtype=float).reshape(-1, 2) / (
        np.maximum(np.asarray(height_px, dtype=float), 1.0) / reference_height_px)[:, None]
    spread = np.full(count, np.nan)
    for k in range(count):
        sel = keypoint == k
        if sel.sum() >= min_samples:
            spread[k] = _robust_sigma(scaled[sel])
    if np.all(np.isnan(spread)):
        return np.ones(count)
    out = spread / np.nanmedian(spread)
    return np.round(np.where(np.isnan(out), 1.0, out), 3)


def fit_noise_model(confidence: np.ndarray, residual_px: np.ndarray, height_px: np.ndarray,
                    knots: tuple[float, ...], reference_height_px: float,
                    floors_px: tuple[float, ...] = tuple(np.arange(0.0, 6.01, 0.25)), min_samples: int = 30
                    ) -> tuple[float, SigmaCurve, list[dict]]:
    """Fit the size-scaled model of the module docstring (floor and curve; residuals already divided by their
    keypoint's factor) from detections' residuals against the truth.

    ``confidence`` (N,), ``residual_px`` (N, 2) rectified pixel errors, ``height_px`` (N,) the person's image
    height measured on its detection.  For each candidate floor, each knot's reference sigma ``g`` makes the
    robust spread (1.4826 MAD over both axes) of ``residual / sqrt(floor^2 + (g h / h_ref)^2)`` equal 1 over
    the residuals nearest that knot (bisection; a bin with fewer than ``min_samples`` takes its neighbour's
    value); the floor kept is the one whose normalised residuals have the most equal spread over the four
    height quartiles (the model's claim: the same noise per sigma at every size).  Returns the floor, the
    (non-increasing) curve and a per-bin table (knot, bin, count, reference sigma, the normalised residuals'
    RMS and fraction beyond 5 sigma).
    """
    confidence = np.asarray(confidence, dtype=float)
    residual_px = np.asarray(residual_px, dtype=float).reshape(-1, 2)
    rel = np.maximum(np.asarray(height_px, dtype=float), 1.0) / reference_height_px
    knots = tuple(float(k) for k in knots)
    edges = np.concatenate([[-np.inf], 0.5 * (np.array(knots[1:]) + np.array(knots[:-1])), [np.inf]])
    bins = [(confidence >= edges[i]) & (confidence < edges[i + 1]) for i in range(len(knots))]
    counts = np.array([int(b.sum()) for b in bins])
    if np.all(counts < min_samples):
        raise ValueError("no confidence bin holds enough residuals to fit a sigma")
    quartiles = np.quantile(rel, [0.25, 0.5, 0.75])
    size_bin = np.searchsorted(quartiles, rel)

    def fit_bins(floor: float) -> np.ndarray:
        out = np.full(len(knots), np.nan)
        for i, sel in enumerate(bins):
            if counts[i] < min_samples:
                continue
            res, r = residual_px[sel], rel[sel]
            lo, hi = 1e-3, 1e4
            for _ in range(60):                       # spread decreases as g grows
                g = np.sqrt(lo * hi)
                spread = _robust_sigma(res / np.hypot(floor, g * r)[:, None])
                lo, hi = (g, hi) if spread > 1.0 else (lo, g)
            out[i] = np.sqrt(lo * hi)
        good = np.flatnonzero(~np.isnan(out))
        for i in np.flatnonzero(np.isnan(out)):
            out[i] = out[good[np.argmin(np.abs(good - i))]]
        return _non_increasing(out, np.maximum(counts, 1).astype(float))

    best = None
    for floor in floors_px:
        g = fit_bins(float(floor))
        sigma = np.hypot(floor, np.interp(confidence, knots, g) * rel)
        z = residual_px / sigma[:, None]
        spreads = [_robust_sigma(z[size_bin == q]) for q in range(4) if np.sum(size_bin == q) >= min_samples]
        badness = float(np.sum(np.log(np.array(spreads)) ** 2))
        if best is None or badness < best[0]:
            best = (badness, float(floor), g, z)
    _, floor, g, z = best
    rows = []
    for i, sel in enumerate(bins):
        zs = z[sel]
        rows.append({"knot": knots[i], "bin": [float(edges[i]), float(edges[i + 1])], "count": int(counts[i]),
                     "sigma_px": float(g[i]),
                     "rms_normalised": float(np.sqrt(np.mean(zs ** 2))) if len(zs) else float("nan"),
                     "frac_beyond_5sigma": float(np.mean(np.abs(zs) > 5)) if len(zs) else float("nan")})
    curve = SigmaCurve(confidence_knots=knots, sigma_px=tuple(round(float(v), 3) for v in g))
    return floor, curve, rows


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


@dataclass
class StereoRowCheck:
    """The data's own lower bound of the detector noise (:func:`stereo_row_scale`), for one sequence."""

    scale: float | None
    """Robust spread (1.4826 MAD) of the row differences in units of their predicted standard deviation;
    None when there were fewer than the minimum samples."""
    samples: int
    """Keypoints seen in both images of a pair (after the confidence threshold)."""
    applied: float
    """The factor every sigma of the sequence was multiplied by: ``max(1, scale)`` (1 without an estimate)."""
    pair_offsets_px: dict[str, float] = field(default_factory=dict)
    """Per stereo pair, the rows' common offset: the median of ``v_left - v_right`` weighted by the inverse
    predicted variance (the rectification's own offset), pixels."""
    by_confidence: list[dict] = field(default_factory=list)
    """The same scale per confidence knot (``knot``, ``count``, ``scale``) over the keypoints whose less
    confident image is nearest that knot (knots with fewer than ``min_bin_samples`` left out): whether the
    curve's *shape* fits the data, not only its level.  A diagnostic: only :attr:`applied` is used."""

    def record(self) -> dict:
        return {"scale": None if self.scale is None else round(self.scale, 4), "samples": self.samples,
                "applied": round(self.applied, 4),
                "pair_offsets_px": {k: round(v, 3) for k, v in sorted(self.pair_offsets_px.items())},
                "by_confidence": [dict(b, scale=round(b["scale"], 4)) for b in self.by_confidence]}


def _weighted_median(x: np.ndarray, weights: np.ndarray) -> float:
    """The value where the cumulative weight of the sorted ``x`` reaches half the total."""
    order = np.argsort(x)
    cumulative = np.cumsum(weights[order])
    return float(x[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def stereo_row_scale(rows: dict[str, tuple[np.ndarray, ...]], min_samples: int = 200,
                     knots: tuple[float, ...] | None = None, min_bin_samples: int = 50) -> StereoRowCheck:
    """How far the keypoint noise the data show exceeds the noise model, from rectified rows alone (no truth).

    In a rectified pair a body point lies on one image row in both images, so for a keypoint detected in the
    left and the right image of a pair, ``d = v_left - v_right = o_p + n_left - n_right`` (pixels): the two
    detections' vertical errors plus the pair's rectification offset ``o_p``.  With the noise model's sigmas
    ``s_left``, ``s_right`` (:meth:`DetectionNoiseConfig.sigma`, per keypoint, confidence and size) the
    normalised differences ``z = (d - o_p) / sqrt(s_left^2 + s_right^2)`` have a spread of 1 if the model
    is right and the two images' errors are independent.  ``rows``: pair name -> ``(d (N,), predicted sd
    (N,))`` or ``(d, sd, confidence (N,))`` (the lower of the two images' confidences: with ``knots``, the
    scale is also given per knot, :attr:`StereoRowCheck.by_confidence`); ``o_p`` is each pair's median
    ``d`` weighted by ``1 / sd^2``; the spread is ``1.4826 MAD`` of ``z`` (the estimator the curves are
    fitted with, so 1 means agreement in the sense they were fitted).  The same row principle
    gives manual labels their click noise (:mod:`pedx_graph.data.noise_estimate`, absolute per keypoint);
    here it checks a model whose shape (confidence, size, keypoint) is given, so one factor is estimated.

    A *lower* bound only: an error the detector makes alike in both images (a keypoint definition that differs
    from ours, a hidden wrist guessed the same way twice) cancels in ``d``, and only the vertical axis is
    seen.  So the data can show the model too confident (scale > 1: a noisier detector than the one the
    curves were measured on) but never prove it too cautious; ``applied`` is ``max(1, scale)``.
    """
    offsets, z, conf = {}, [], []
    for pair, (d, sd, *more) in sorted(rows.items()):
        d, sd = np.asarray(d, dtype=float).reshape(-1), np.asarray(sd, dtype=float).reshape(-1)
        c = np.asarray(more[0], dtype=float).reshape(-1) if more else np.full(d.shape, np.nan)
        ok = np.isfinite(d) & np.isfinite(sd) & (sd > 0)
        if not ok.any():
            continue
        offsets[pair] = _weighted_median(d[ok], 1.0 / sd[ok] ** 2)
        z.append((d[ok] - offsets[pair]) / sd[ok])
        conf.append(c[ok])
    z = np.concatenate(z) if z else np.zeros(0)
    conf = np.concatenate(conf) if conf else np.zeros(0)
    if len(z) < max(int(min_samples), 2):
        return StereoRowCheck(scale=None, samples=int(len(z)), applied=1.0, pair_offsets_px=offsets)
    def spread(values: np.ndarray) -> float:            # about 0: each pair's offset is already removed
        return float(MAD_TO_SIGMA * np.median(np.abs(values)))

    scale = spread(z)
    bins = []
    if knots is not None and np.isfinite(conf).any():
        knots = np.asarray(knots, dtype=float)
        nearest = np.argmin(np.abs(conf[:, None] - knots[None, :]), axis=1)
        for i, knot in enumerate(knots):
            sel = (nearest == i) & np.isfinite(conf)
            if sel.sum() >= max(int(min_bin_samples), 2):
                bins.append({"knot": float(knot), "count": int(sel.sum()), "scale": spread(z[sel])})
    return StereoRowCheck(scale=scale, samples=int(len(z)), applied=max(1.0, scale), pair_offsets_px=offsets,
                          by_confidence=bins)
