"""Measurement noise estimated from a dataset itself: per-keypoint click noise and LiDAR range noise.

**Click noise (pixels).**  In a rectified stereo pair a body point has the same image row in both images, so
for a keypoint clicked in both images of a pair the vertical disparity

    d = v_left - v_right = o_p + (n_left - n_right)                 (pixels)

is labelling noise plus the pair's rectification offset ``o_p`` (a small per-pair constant; real
blu79CF-grn43E3: about -1 px).  Per (sequence, pair) the offset is estimated, and per keypoint the scale
``s_k`` of the offset-free differences; with independent clicks of equal noise one click's sigma is
``s_k / sqrt(2)``.  The scale is the maximum-likelihood fit of a zero-mean Gaussian plus a broad uniform
outlier component (EM, :func:`robust_gaussian_scale`): outliers (a guessed occluded joint, a swapped label)
get no weight, and unlike the median absolute deviation it is not stuck on whole pixels when the clicks are
integers.  Integer clicks add the rounding variance ``1/12 px^2`` per click; it is part of the noise every
label carries and stays in the estimate (the record reports it separately).  Where the labels carry
occlusion flags, only keypoints flagged visible in both images count (the fit gives flagged-occluded rows
their own sigma); real PedX labels flag everything visible, so guessed joints enter as they do in the fit.
Offsets and scales are refined alternately (the offset is the inlier-weighted mean over the pair's
keypoints, each weighted by ``1 / s_k^2``).  A keypoint with fewer than ``min_keypoint_samples``
differences gets the pooled all-keypoint figure; a dataset with fewer than ``min_total_samples`` has no
estimate (None: the caller keeps its configured sigma).

**Range noise (metres).**  A spinning LiDAR's error is along each ray; a ray's direction carries none.
For every segment point ``p`` (the pedestrian's LiDAR points of one frame) with ray direction ``u`` from the
rig's viewpoint (``Track.ground.world_p_sensor``) and the ``lidar_neighbours - 1`` points of nearest ray
direction (``scipy.spatial.cKDTree``; along the scan line, the densest direction), the neighbours' offsets
along the ray (noisy) are regressed on their offsets across it (noise-free) with a local quadratic; the
residual at ``p`` divided by ``sqrt(1 - h)`` (``h``: its leverage, the degrees of freedom the local fit
used) has the range noise's variance.  Skipped: neighbourhoods wider than ``lidar_max_span_m`` across the
rays (sparse far returns, where the surface's own shape between neighbours dominates), across a depth jump,
or on a surface seen edge-on (silhouette edges).  The pooled residuals' scale is the same robust Gaussian
fit, so background points in a segment (the ground at the feet, a wall: as good a measure of range noise
when a neighbourhood lies on one surface) and the remaining edges, a minority, do not inflate it.  What a
single sweep cannot separate from the noise is the surface's shape beyond a quadratic between neighbours:
on the simulator's bodies (benchmarks/bench_noise.py) 2 cm of range noise reads 2.05-2.3 cm, 1 cm reads
1.4 cm, 0.5 cm reads 1.0 cm: an upper bound of small range noise (the chamfer term sees that roughness too).
Segments with few near returns give few usable fits: a dataset with fewer than ``lidar_min_residuals`` has
no estimate (None).

Input: a list of :class:`~pedx_graph.data.types.Track`; every stereo pair of a frame (the primary pair and
``TrackFrame.other_views``) counts.  :func:`estimate_noise` returns a :class:`NoiseEstimate`;
:func:`resolve_noise` turns it and a :class:`~pedx_graph.graph.config.NoiseConfig` into the sigmas a fit
uses (:func:`keypoint_row_sigmas_px`, :func:`chamfer_sigma_m`) and the ``summary.json`` record.
"""
from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from pedx_graph.keypoints import PEDX_KEYPOINTS

log = logging.getLogger(__name__)

NUM_KEYPOINTS = len(PEDX_KEYPOINTS)
#: Standard deviation of rounding a click to a whole pixel, per click and axis, pixels.
QUANTISATION_PX = float(1.0 / np.sqrt(12.0))


@dataclass
class NoiseEstimateConfig:
    """Settings of :func:`estimate_noise` (counts and the local fits of the range-noise estimate)."""

    min_keypoint_samples: int = 30
    """A keypoint with fewer vertical disparities than this gets the pooled all-keypoint click noise."""
    min_total_samples: int = 100
    """Fewer vertical disparities than this in the whole dataset: no click-noise estimate (None)."""
    visible_only: bool = True
    """Only keypoints flagged visible in both images count (labels without occlusion flags flag all)."""
    lidar_neighbours: int = 5
    """Points of each local curve fit of the range-noise estimate (the point and its nearest neighbours)."""
    lidar_max_span_m: float = 0.1
    """A local neighbourhood reaching farther than this from its point across the rays is skipped, metres:
    at range the returns are sparse and the surface's own shape between them reads as noise (simulated
    bodies, noise-free ranges: ~4 mm at 0.1 m, ~8 mm at 0.2 m, ~11 mm at 0.3 m)."""
    lidar_max_depth_step_m: float = 0.3
    """A local neighbourhood with a neighbour farther than this along the ray is skipped (a depth jump:
    a limb in front of the torso, the background past the silhouette), metres."""
    lidar_max_slope: float = 1.0
    """Only surfaces facing the ray within ~45 deg count: the fitted ``|d range / d transverse|`` at the point
    at most this (silhouette edges, seen edge-on, are not followed by a local quadratic)."""
    lidar_min_residuals: int = 100
    """Fewer usable local-fit residuals than this in the whole dataset: no range-noise estimate (None)."""
    lidar_max_points: int = 200_000
    """At most this many segment points enter the range-noise estimate (whole frames, in track order)."""


@dataclass
class NoiseEstimate:
    """What :func:`estimate_noise` measured (see the module docstring)."""

    keypoint_sigma_px: np.ndarray | None
    """(18,) per-click noise (std. dev. per axis, pixels) in PEDX_KEYPOINTS order, rounding included; a
    keypoint with too few samples has the pooled figure.  None: too few samples in the whole dataset."""
    keypoint_counts: np.ndarray
    """(18,) vertical disparities used per keypoint."""
    keypoint_pooled: np.ndarray
    """(18,) bool: the keypoint had too few samples and carries ``pooled_sigma_px``."""
    pooled_sigma_px: float | None
    """Per-click noise of all keypoints pooled, pixels (None without an estimate)."""
    pair_offsets: list[dict] = field(default_factory=list)
    """Per (sequence, pair): ``{"sequence", "pair", "offset_px", "count", "sigma_px"}``: the median-like
    (inlier-weighted) vertical disparity ``v_left - v_right`` and the pair's pooled per-click noise."""
    integer_clicks: bool = False
    """Every click used is a whole pixel (then ``QUANTISATION_PX`` per click is inside the estimate)."""
    outlier_fraction: float | None = None
    """Fraction of the vertical disparities the robust fit gave to the outlier component (pooled)."""
    lidar_range_sigma_m: float | None = None
    """Range noise along the LiDAR rays, metres; None: too few usable points."""
    lidar_count: int = 0
    """Local-fit residuals the range noise was measured from."""
    lidar_segments: int = 0
    """Segments (track frames with LiDAR points) that contributed residuals."""
    lidar_outlier_fraction: float | None = None
    """Fraction of those residuals the robust fit gave to the outlier component."""
    method: str = "vertical disparity of rectified stereo clicks; LiDAR local curve fits along the rays"
    """How the figures were obtained (one line)."""
    config: dict = field(default_factory=dict)
    """The :class:`NoiseEstimateConfig` used."""

    @property
    def total_keypoint_samples(self) -> int:
        """Vertical disparities used over all keypoints."""
        return int(np.sum(self.keypoint_counts))

    def to_dict(self) -> dict:
        """JSON-ready record (``summary.json`` ``noise.estimate``): per-keypoint figures keyed by name."""
        sigma = self.keypoint_sigma_px
        return {
            "method": self.method,
            "keypoint_sigma_px": None if sigma is None else {n: float(s) for n, s in zip(PEDX_KEYPOINTS, sigma)},
            "keypoint_counts": {n: int(c) for n, c in zip(PEDX_KEYPOINTS, self.keypoint_counts)},
            "keypoint_pooled": [n for n, p in zip(PEDX_KEYPOINTS, self.keypoint_pooled) if p],
            "pooled_sigma_px": self.pooled_sigma_px,
            "keypoint_samples": self.total_keypoint_samples,
            "integer_clicks": bool(self.integer_clicks),
            "quantisation_px_per_click": QUANTISATION_PX if self.integer_clicks else 0.0,
            "outlier_fraction": self.outlier_fraction,
            "pair_offsets": [dict(p) for p in self.pair_offsets],
            "lidar_range_sigma_m": self.lidar_range_sigma_m,
            "lidar_count": int(self.lidar_count),
            "lidar_segments": int(self.lidar_segments),
            "lidar_outlier_fraction": self.lidar_outlier_fraction,
            "config": dict(self.config),
        }


# ------------------------------------------------------------------------------------ robust scale

def robust_gaussian_scale(values: np.ndarray, centre: float | None = 0.0, weights_out: bool = False,
                          max_iterations: int = 200, outlier_width_sds: float = 50.0):
    """Scale (and centre) of ``values`` under a Gaussian-plus-uniform-outliers model, maximum likelihood (EM).

    ``values`` (N,); ``centre``: the known centre, or None to estimate it too.  The outlier component is
    uniform over ``max(data span, outlier_width_sds * s0)`` (``s0``: 1.4826 * MAD), broad enough that it
    does not eat the Gaussian's own tails in small samples.  Returns ``(sigma, centre, outlier_fraction)``
    and, with ``weights_out``, the (N,) inlier probabilities too.  The scale is consistent for Gaussian
    data, and on integer-valued data it is the variance of the rounded values (rounding included), which a
    median absolute deviation (stuck on whole steps) is not.
    """
    x = np.asarray(values, dtype=float).reshape(-1)
    x = x[np.isfinite(x)]
    if x.size < 2:
        raise ValueError(f"robust_gaussian_scale needs at least 2 finite values, got {x.size}")
    mu = float(np.median(x)) if centre is None else float(centre)
    s = 1.4826 * float(np.median(np.abs(x - mu)))
    spread = float(np.std(x))
    if not s > 0:
        s = spread if spread > 0 else 1e-6
    width = max(float(x.max() - x.min()), outlier_width_sds * s)
    density = 1.0 / width
    eps = 0.05
    w = np.ones_like(x)
    for _ in range(max_iterations):
        z = (x - mu) / s
        g = (1.0 - eps) * np.exp(-0.5 * z * z) / (np.sqrt(2.0 * np.pi) * s)
        w = g / (g + eps * density)
        sw = float(w.sum())
        if not sw > 0:
            break
        if centre is None:
            mu = float(np.sum(w * x) / sw)
        s_new = max(float(np.sqrt(np.sum(w * (x - mu) ** 2) / sw)), 1e-9)
        eps = min(max(1.0 - sw / x.size, 0.0), 0.999)
        done = abs(s_new - s) <= 1e-9 * s
        s = s_new
        if done:
            break
    out = (float(s), float(mu), float(eps))
    return out + (w,) if weights_out else out


# ------------------------------------------------------------------------------------ click noise

def frame_stereo_views(frame) -> Iterator[tuple[str, object, object]]:
    """``(pair name, left View2D or None, right View2D or None)`` of every stereo pair labelling the instance
    at ``frame``: the primary pair, then ``frame.other_views`` when the frame has them."""
    yield frame.pair, frame.left, frame.right
    others = getattr(frame, "other_views", None) or {}
    for pair in sorted(others):
        if pair == frame.pair:
            continue
        views = others[pair]
        left, right = (views.left, views.right) if hasattr(views, "left") else views
        yield pair, left, right


@dataclass
class VerticalDisparities:
    """Every keypoint clicked in both images of a pair: its vertical disparity and where it came from."""

    disparity_px: np.ndarray
    """(N,) ``v_left - v_right``, pixels."""
    keypoint: np.ndarray
    """(N,) keypoint index (PEDX_KEYPOINTS order)."""
    group: np.ndarray
    """(N,) index into :attr:`groups`."""
    groups: list[tuple[str, str]]
    """(sequence, pair) of each group (one rectification offset each)."""
    integer_clicks: bool
    """Every click coordinate used is a whole pixel."""


def vertical_disparities(tracks: Iterable, visible_only: bool = True) -> VerticalDisparities:
    """Collect the vertical disparities of every keypoint labelled in both images of a pair (all pairs of
    every frame of every track; PedX-set labels only: imported detections carry their own ``sigma_px``).
    ``visible_only``: both clicks flagged visible."""
    values, kps, grp = [], [], []
    groups: dict[tuple[str, str], int] = {}
    integer = True
    for track in tracks:
        for frame in track.frames:
            for pair, left, right in frame_stereo_views(frame):
                if left is None or right is None:
                    continue
                if getattr(left, "keypoint_set", "pedx18") != "pedx18":   # detections carry their own sigma_px
                    continue
                lk = np.asarray(left.keypoints, dtype=float)
                rk = np.asarray(right.keypoints, dtype=float)
                both = np.all(np.isfinite(lk), axis=1) & np.all(np.isfinite(rk), axis=1)
                if visible_only:
                    both &= np.asarray(left.visible, bool) & np.asarray(right.visible, bool)
                idx = np.flatnonzero(both)
                if idx.size == 0:
                    continue
                key = (str(track.sequence), str(pair))
                g = groups.setdefault(key, len(groups))
                values.append(lk[idx, 1] - rk[idx, 1])
                kps.append(idx)
                grp.append(np.full(idx.size, g))
                if integer:
                    coords = np.concatenate([lk[idx, 1], rk[idx, 1]])
                    integer = bool(np.all(np.abs(coords - np.round(coords)) < 1e-6))
    if not values:
        return VerticalDisparities(np.zeros(0), np.zeros(0, int), np.zeros(0, int), [], False)
    return VerticalDisparities(np.concatenate(values), np.concatenate(kps).astype(int),
                               np.concatenate(grp).astype(int), list(groups), integer)


def estimate_click_noise(samples: VerticalDisparities, config: NoiseEstimateConfig | None = None,
                         rounds: int = 4) -> dict:
    """Per-keypoint click noise and per-pair offsets from :func:`vertical_disparities` (module docstring).
    A click's noise is floored at the rounding's ``QUANTISATION_PX`` for integer clicks (0.01 px else).

    Returns a dict with ``keypoint_sigma_px`` ((18,) or None), ``keypoint_counts``, ``keypoint_pooled``,
    ``pooled_sigma_px``, ``pair_offsets``, ``outlier_fraction``.
    """
    config = config or NoiseEstimateConfig()
    d, kp, grp = samples.disparity_px, samples.keypoint, samples.group
    counts = np.bincount(kp, minlength=NUM_KEYPOINTS).astype(int)
    out = {"keypoint_sigma_px": None, "keypoint_counts": counts, "keypoint_pooled": np.ones(NUM_KEYPOINTS, bool),
           "pooled_sigma_px": None, "pair_offsets": [], "outlier_fraction": None}
    if d.size < max(int(config.min_total_samples), 2):
        return out
    n_groups = len(samples.groups)
    offsets = np.array([np.median(d[grp == g]) for g in range(n_groups)])
    few = counts < int(config.min_keypoint_samples)
    diff_sd = np.full(NUM_KEYPOINTS, np.nan)
    inlier = np.ones_like(d)
    pooled = (1.0, 0.0, 0.0)
    for _ in range(rounds):
        e = d - offsets[grp]
        pooled = robust_gaussian_scale(e, centre=0.0, weights_out=True)
        inlier = pooled[3].copy()
        for k in range(NUM_KEYPOINTS):
            sel = kp == k
            if few[k]:
                diff_sd[k] = pooled[0]
                continue
            s, _, _, w = robust_gaussian_scale(e[sel], centre=0.0, weights_out=True)
            diff_sd[k] = s
            inlier[sel] = w
        # a click is never better than its rounding (whole pixels) or than 0.01 px
        diff_sd = np.maximum(diff_sd, np.sqrt(2.0) * (QUANTISATION_PX if samples.integer_clicks else 0.01))
        weight = inlier / diff_sd[kp] ** 2
        for g in range(n_groups):
            sel = grp == g
            if np.sum(weight[sel]) > 0:
                offsets[g] += float(np.sum(weight[sel] * e[sel]) / np.sum(weight[sel]))
    e = d - offsets[grp]
    pairs = []
    for g, (sequence, pair) in enumerate(samples.groups):
        sel = grp == g
        sigma = robust_gaussian_scale(e[sel], centre=0.0)[0] / np.sqrt(2.0) if sel.sum() >= 2 else None
        pairs.append({"sequence": sequence, "pair": pair, "offset_px": float(offsets[g]), "count": int(sel.sum()),
                      "sigma_px": None if sigma is None else float(sigma)})
    out.update(keypoint_sigma_px=diff_sd / np.sqrt(2.0), keypoint_pooled=few,
               pooled_sigma_px=float(pooled[0] / np.sqrt(2.0)), pair_offsets=pairs,
               outlier_fraction=float(pooled[2]))
    return out


# ------------------------------------------------------------------------------------ range noise

def _viewpoint(track) -> np.ndarray:
    """The rig's viewpoint (rays start here): the track's ground frame's, else the mean camera centre."""
    ground = getattr(track, "ground", None)
    if ground is not None:
        return np.asarray(ground.world_p_sensor, dtype=float)
    centres = [np.asarray(c.world_T_cam, float)[:3, 3] for c in track.calibrations.values()]
    return np.mean(centres, axis=0) if centres else np.zeros(3)


def segment_range_residuals(world_points: np.ndarray, world_p_sensor: np.ndarray, neighbours: int = 5,
                            max_span_m: float = 0.1, max_depth_step_m: float = 0.3,
                            max_slope: float = 1.0) -> np.ndarray:
    """Standardised local-fit residuals along the rays of one segment's (M, 3) points (module docstring).

    For each point ``p`` with ray direction ``u`` (from ``world_p_sensor``) and the ``neighbours - 1``
    points ``q`` of nearest ray directions: range offsets ``r_q = (q - p) . u`` (noisy) against transverse
    offsets ``s_q = ((q - p) - r_q u) . t`` (noise-free: a ray's direction carries no range noise; ``t`` the
    neighbourhood's principal transverse direction, along the scan line), a least-squares quadratic
    ``r(s)``; the residual at ``p`` over ``sqrt(1 - h)`` (``h`` its leverage).  Skipped: neighbourhoods
    wider than ``max_span_m`` across the rays (sparse returns at range, where the surface's shape between
    neighbours dominates; a noise-free width, so the selection does not depend on the noise), with a range
    step beyond ``max_depth_step_m`` (across a depth jump), and surfaces seen more obliquely than
    ``|dr/ds| <= max_slope`` at ``p`` (silhouette edges, where a quadratic does not follow the surface).
    Returns (n,) metres, one per usable point (each ~ N(0, sigma_range^2) for noise along the rays).
    """
    points = np.asarray(world_points, dtype=float).reshape(-1, 3)
    points = points[np.all(np.isfinite(points), axis=1)]
    k = int(neighbours)
    if k < 4:
        raise ValueError(f"lidar_neighbours must be >= 4 (a quadratic and one residual dof), got {k}")
    if len(points) < k:
        return np.zeros(0)
    ray = points - np.asarray(world_p_sensor, dtype=float)
    distance = np.linalg.norm(ray, axis=1)
    ray /= distance[:, None]
    # neighbours by ray direction (noise-free; scaled to metres at the segment's range): by 3D distance,
    # points whose range noise happens to agree would be preferred, and the residuals would shrink
    _, idx = cKDTree(ray * np.median(distance)).query(ray * np.median(distance), k=k)
    rel = points[idx] - points[:, None, :]                                # (n, k, 3); rel[:, 0] = 0
    r = np.einsum("nki,ni->nk", rel, ray)                                 # along the ray: noisy
    across = rel - r[..., None] * ray[:, None, :]                         # transverse: noise-free
    keep = (np.max(np.linalg.norm(across, axis=2), axis=1) <= max_span_m) & \
        (np.max(np.abs(r), axis=1) <= max_depth_step_m)
    if not keep.any():
        return np.zeros(0)
    r, across = r[keep], across[keep]
    centred = across - across.mean(axis=1, keepdims=True)
    _, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", centred, centred))
    s = np.einsum("nki,ni->nk", across, vecs[:, :, 2])                    # s = 0 at the point itself
    design = np.stack([s * s, s, np.ones_like(s)], axis=2)               # (n, k, 3)
    pinv = np.linalg.pinv(design)                                         # (n, 3, k)
    coef = np.einsum("njk,nk->nj", pinv, r)
    resid = r[:, 0] - coef[:, 2]                                          # at s = 0: r = 0, fit = constant
    lever = pinv[:, 2, 0]                                                 # h = [0, 0, 1] (A^T A)^-1 A^T e_0
    use = (lever < 0.95) & (np.abs(coef[:, 1]) <= max_slope)
    return resid[use] / np.sqrt(1.0 - lever[use])


def estimate_range_noise(tracks: Iterable, config: NoiseEstimateConfig | None = None) -> dict:
    """Range noise from every segment's local-fit residuals: ``{"sigma_m" (or None), "count", "segments",
    "outlier_fraction"}``."""
    config = config or NoiseEstimateConfig()
    residuals, segments, used = [], 0, 0
    for track in tracks:
        viewpoint = _viewpoint(track)
        for frame in track.frames:
            points = np.asarray(frame.world_lidar_points, dtype=float).reshape(-1, 3)
            if len(points) < config.lidar_neighbours or used >= config.lidar_max_points:
                continue
            used += len(points)
            r = segment_range_residuals(points, viewpoint, config.lidar_neighbours, config.lidar_max_span_m,
                                        config.lidar_max_depth_step_m, config.lidar_max_slope)
            if r.size:
                residuals.append(r)
                segments += 1
    r = np.concatenate(residuals) if residuals else np.zeros(0)
    if r.size < max(int(config.lidar_min_residuals), 2):
        return {"sigma_m": None, "count": int(r.size), "segments": segments, "outlier_fraction": None}
    sigma, _, eps = robust_gaussian_scale(r, centre=0.0)
    return {"sigma_m": float(sigma), "count": int(r.size), "segments": segments, "outlier_fraction": float(eps)}


def estimate_noise(tracks: Iterable, config: NoiseEstimateConfig | None = None) -> NoiseEstimate:
    """Click noise per keypoint and LiDAR range noise of a dataset's tracks (see the module docstring)."""
    config = config or NoiseEstimateConfig()
    if iter(tracks) is tracks:      # a one-shot iterator is kept for the two passes; a re-iterable is read twice
        tracks = list(tracks)
    samples = vertical_disparities(tracks, visible_only=config.visible_only)
    clicks = estimate_click_noise(samples, config)
    lidar = estimate_range_noise(tracks, config)
    return NoiseEstimate(keypoint_sigma_px=clicks["keypoint_sigma_px"], keypoint_counts=clicks["keypoint_counts"],
                         keypoint_pooled=clicks["keypoint_pooled"], pooled_sigma_px=clicks["pooled_sigma_px"],
                         pair_offsets=clicks["pair_offsets"],
                         integer_clicks=bool(samples.integer_clicks and samples.disparity_px.size > 0),
                         outlier_fraction=clicks["outlier_fraction"], lidar_range_sigma_m=lidar["sigma_m"],
                         lidar_count=lidar["count"], lidar_segments=lidar["segments"],
                         lidar_outlier_fraction=lidar["outlier_fraction"], config=dataclasses.asdict(config))


# ------------------------------------------------------------------------------------ the fit's sigmas

def keypoint_row_sigmas_px(noise) -> np.ndarray:
    """(18,) per-row sigma (pixels) of visible keypoint labels in the fit, from a ``NoiseConfig``:
    ``sqrt(click_k^2 + keypoint_model_sigma_px^2)`` when ``keypoint_sigma_px_per_keypoint`` (click noise,
    from the data or the user) is set, else ``keypoint_sigma_px`` for every keypoint (the whole figure)."""
    clicks = getattr(noise, "keypoint_sigma_px_per_keypoint", None)
    if clicks is None:
        return np.full(NUM_KEYPOINTS, float(noise.keypoint_sigma_px))
    clicks = np.asarray(clicks, dtype=float).reshape(-1)
    if clicks.shape != (NUM_KEYPOINTS,) or not np.all(np.isfinite(clicks)) or np.any(clicks < 0):
        raise ValueError(f"noise.keypoint_sigma_px_per_keypoint must be {NUM_KEYPOINTS} values >= 0 "
                         f"(PEDX_KEYPOINTS order), got {clicks.tolist()}")
    model = float(getattr(noise, "keypoint_model_sigma_px", 0.0))
    sigmas = np.sqrt(clicks ** 2 + model ** 2)
    if np.any(sigmas <= 0):
        raise ValueError("noise: a keypoint's click noise and keypoint_model_sigma_px are both 0")
    return sigmas


def chamfer_sigma_m(noise) -> float:
    """Sigma (metres per coordinate) of the LiDAR chamfer term from a ``NoiseConfig``:
    ``sqrt(lidar_range_sigma_m^2 + lidar_model_sigma_m^2)`` when the range noise is set (from the data or the
    user), else ``lidar_sigma_m`` (the whole figure)."""
    range_sigma = getattr(noise, "lidar_range_sigma_m", None)
    if range_sigma is None:
        return float(noise.lidar_sigma_m)
    model = float(getattr(noise, "lidar_model_sigma_m", 0.0))
    sigma = float(np.hypot(float(range_sigma), model))
    if not sigma > 0:
        raise ValueError("noise: lidar_range_sigma_m and lidar_model_sigma_m are both 0")
    return sigma


@dataclass
class ResolvedNoise:
    """The noise a dataset is fitted with: the ``NoiseConfig`` to pass on (click and range noise filled in)
    and what was used, for ``summary.json``."""

    noise: object
    """The resolved ``NoiseConfig`` (a copy; the input is not changed)."""
    keypoint_sigma_px: np.ndarray
    """(18,) per-row sigma of visible keypoint labels (before the hip factor), pixels."""
    lidar_sigma_m: float
    """Sigma of the chamfer term, metres."""
    record: dict
    """JSON-ready record: sources, figures used, the estimate."""


def resolve_noise(tracks: Iterable, noise, estimate: NoiseEstimate | None = None,
                  config: NoiseEstimateConfig | None = None) -> ResolvedNoise:
    """The effective noise of a dataset: ``noise`` (a ``NoiseConfig``) with the click noise per keypoint and
    the LiDAR range noise filled in from the data where ``keypoint_noise_from_data`` /
    ``lidar_noise_from_data`` ask for it and the config does not set them itself.

    Sources in the record: ``override`` (the config's per-keypoint click noise / range noise), ``data`` (the
    estimate), ``config`` (no estimate, or estimation off: ``keypoint_sigma_px`` / ``lidar_sigma_m`` as the
    whole sigma).  ``estimate``: an estimate already made (else one is made when needed, with ``config``;
    default: the ``NoiseConfig``'s minimum sample counts).
    """
    if config is None:
        config = NoiseEstimateConfig(
            min_keypoint_samples=int(getattr(noise, "keypoint_noise_min_samples", 30)),
            min_total_samples=max(100, int(getattr(noise, "keypoint_noise_min_samples", 30))),
            lidar_min_residuals=int(getattr(noise, "lidar_noise_min_samples", 100)))
    want_kp = bool(getattr(noise, "keypoint_noise_from_data", False))
    want_lidar = bool(getattr(noise, "lidar_noise_from_data", False))
    error = None
    if estimate is None and (want_kp or want_lidar):
        try:
            estimate = estimate_noise(tracks, config)
        except Exception as exc:  # noqa: BLE001 -- odd data never stops a fit: the config's sigmas are used
            error = f"{type(exc).__name__}: {exc}"
            log.warning("noise estimate failed (%s); the config's sigmas are used", error)
    changes = {}
    override = getattr(noise, "keypoint_sigma_px_per_keypoint", None)
    if override is not None:
        kp_source = "override"
    elif want_kp and estimate is not None and estimate.keypoint_sigma_px is not None:
        kp_source = "data"
        changes["keypoint_sigma_px_per_keypoint"] = tuple(float(v) for v in estimate.keypoint_sigma_px)
    else:
        kp_source = "config"
    if getattr(noise, "lidar_range_sigma_m", None) is not None:
        lidar_source = "override"
    elif want_lidar and estimate is not None and estimate.lidar_range_sigma_m is not None:
        lidar_source = "data"
        changes["lidar_range_sigma_m"] = float(estimate.lidar_range_sigma_m)
    else:
        lidar_source = "config"
    resolved = dataclasses.replace(noise, **changes) if changes else dataclasses.replace(noise)
    rows = keypoint_row_sigmas_px(resolved)
    chamfer = chamfer_sigma_m(resolved)
    clicks = getattr(resolved, "keypoint_sigma_px_per_keypoint", None)
    record = {
        "keypoints": {
            "source": kp_source,
            "click_sigma_px": None if clicks is None else {n: float(v) for n, v in zip(PEDX_KEYPOINTS, clicks)},
            "model_sigma_px": None if clicks is None else float(getattr(resolved, "keypoint_model_sigma_px", 0.0)),
            "row_sigma_px": {n: float(v) for n, v in zip(PEDX_KEYPOINTS, rows)},
            "occluded_row_sigma_px": float(resolved.occluded_keypoint_sigma_px),
            "hip_sigma_factor": float(getattr(resolved, "hip_sigma_factor", 1.0)),
        },
        "lidar": {
            "source": lidar_source,
            "range_sigma_m": getattr(resolved, "lidar_range_sigma_m", None),
            "model_sigma_m": (None if getattr(resolved, "lidar_range_sigma_m", None) is None
                              else float(getattr(resolved, "lidar_model_sigma_m", 0.0))),
            "chamfer_sigma_m": chamfer,
        },
        "estimate": None if estimate is None else estimate.to_dict(),
    }
    if error is not None:
        record["estimate_error"] = error
    if want_kp and kp_source == "config":
        log.info("keypoint click noise: no estimate from the data (%s vertical disparities); keypoint_sigma_px "
                 "= %g px is used", 0 if estimate is None else estimate.total_keypoint_samples,
                 resolved.keypoint_sigma_px)
    if want_lidar and lidar_source == "config":
        log.info("LiDAR range noise: no estimate from the data (%s residuals); lidar_sigma_m = %g m is used",
                 0 if estimate is None else estimate.lidar_count, resolved.lidar_sigma_m)
    return ResolvedNoise(noise=resolved, keypoint_sigma_px=rows, lidar_sigma_m=chamfer, record=record)
