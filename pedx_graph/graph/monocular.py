"""Depth of a pedestrian seen by one camera, from body size: the body-size prior's depth and its sigma.

A single labelled image fixes every keypoint's ray but not the depth along it; what remains is the body's
size.  An upright pedestrian's vertical extents (head to neck, neck to hips, hips to knees, knees to
ankles) are known to a few per cent, so their image extents give the distance.

Geometry (rectified camera frame of the labelling camera, ``up`` the sequence's up axis in that frame):
a pixel ``(u, v)`` has the ray ``q = ((u - c_x) / f_x, (v - c_y) / f_y, 1)`` and the elevation
``tan e = (q . up) / |q - (q . up) up|``.  A point at horizontal distance ``D`` on that ray is ``D tan e``
above the camera, so a vertical segment ``a -> b`` of height ``H`` whose ends are at the same horizontal
distance gives

    t = tan e_a - tan e_b = H / D        (exact for any camera tilt or roll; no fronto-parallel assumption)

Every consecutive pair of labelled chain points (head or nose, neck or shoulders' mid-point, hips',
knees', ankles' mid-points) is one such measurement ``t_k = w H_k (1 + eps_k) + n_k`` of ``w = 1 / D``:

* ``eps_k`` (relative, correlated across segments): the shape prior's spread of the segment heights
  (``d log H_k / d beta`` of the body model, times the prior's sigma: mostly one common scale) plus the
  spread over walking poses (leg swing, knee flexion, trunk lean: heights of pose samples drawn from the
  pose prior, whose mean also sets ``H_k``, so the gait's average shortening is no bias), plus the
  depth difference of the two ends along the ray (``tan e_mid * d_delta / H``, from the pose samples'
  horizontal offsets at a random heading) and the segment's horizontal offset from the hips (``w delta``);
* ``n_k``: the click noise of the end points (per-keypoint pixel sigmas through ``d tan e / d(u, v)``;
  segments sharing an end point are correlated).

``w`` is the generalised least-squares estimate under that covariance (iterated: the covariance scales
with ``w``), ``D = 1 / w``, ``sigma_D = sigma_w / w^2``.  A segment set whose chi-square exceeds the 99.9 %
quantile (a mis-clicked point) is refitted without the chain point whose removal fits best.  The result
is the rectified depth ``z`` of the body centre (the hips' mid-point, else the torso's labelled joints,
as :mod:`pedx_graph.graph.init`): ``z = D / |q_c,horizontal|``.  Sigma: ~6-8 % of the depth with the shipped
model (its first shape coefficient alone changes the height by 6 % per standard deviation).

Nothing here assumes an axis: ``up`` comes from the caller (``GroundFrame.world_up``), else the camera's
image-up direction.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2 as chi2_dist

from pedx_graph.keypoints import PEDX_KEYPOINTS

_IDX = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}

#: Chain points: name -> the keypoints averaged (all must be labelled).
POINTS: dict[str, tuple[int, ...]] = {
    "head": (_IDX["head"],),
    "nose": (_IDX["nose"],),
    "neck": (_IDX["neck"],),
    "shoulders": (_IDX["lsho"], _IDX["rsho"]),
    "hips": (_IDX["lhip"], _IDX["rhip"]),
    "knees": (_IDX["lknee"], _IDX["rknee"]),
    "ankles": (_IDX["lankl"], _IDX["rankl"]),
}
_NAMES = tuple(POINTS)

#: The vertical chain, top to bottom; each slot takes its first labelled alternative.
CHAIN: tuple[tuple[str, ...], ...] = (("head", "nose"), ("neck", "shoulders"), ("hips",), ("knees",), ("ankles",))


@dataclass(frozen=True)
class BodySizePrior:
    """What the body model and the priors say about an upright pedestrian's vertical extents."""

    heights_m: np.ndarray
    """(N, P) height of each chain point (:data:`POINTS` order) in the body frame (model +Y, metres) for N
    walking poses drawn from the pose prior, at the mean shape."""
    horizontal_m: np.ndarray
    """(N, P, 2) the same points' horizontal body-frame coordinates (x, z), metres."""
    d_heights_d_betas: np.ndarray
    """(P, B) derivative of each point's height with respect to the shape coefficients (pose-averaged)."""
    shape_sigma: float
    """Standard deviation of the shape prior (betas ~ N(0, shape_sigma^2 I))."""

    def segment_statistics(self, pairs: list[tuple[str, str]]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                          np.ndarray]:
        """For segments ``(top, bottom)``: mean heights ``H`` (K,) m, the covariance of their relative errors
        from shape and pose (K, K), the variance of the ends' depth difference along a ray at a random
        heading (K,) m^2, and the variance of the segment mid-point's horizontal offset from the hips along
        that ray (K,) m^2."""
        top = np.array([_NAMES.index(a) for a, _ in pairs])
        bottom = np.array([_NAMES.index(b) for _, b in pairs])
        extents = self.heights_m[:, top] - self.heights_m[:, bottom]                      # (N, K)
        mean = extents.mean(axis=0)
        if np.any(mean <= 0):
            raise ValueError(f"body size prior: a segment of {pairs} is not vertical (mean height {mean})")
        rel = extents / mean - 1.0
        pose_cov = np.atleast_2d(np.cov(rel, rowvar=False))
        jac = (self.d_heights_d_betas[top] - self.d_heights_d_betas[bottom]) / mean[:, None]
        shape_cov = self.shape_sigma ** 2 * jac @ jac.T
        # a heading uniform relative to the ray: a horizontal offset h projects with variance |h|^2 / 2
        ends = self.horizontal_m[:, top] - self.horizontal_m[:, bottom]
        end_var = 0.5 * np.mean(np.sum(ends ** 2, axis=-1), axis=0)
        hips = self.horizontal_m[:, _NAMES.index("hips")][:, None]
        mid = 0.5 * (self.horizontal_m[:, top] + self.horizontal_m[:, bottom]) - hips
        mid_var = 0.5 * np.mean(np.sum(mid ** 2, axis=-1), axis=0)
        return mean, pose_cov + shape_cov, end_var, mid_var


def body_size_prior(model, pose_prior=None, shape_sigma: float = 1.0, num_samples: int = 512,
                    seed: int = 0) -> BodySizePrior:
    """The :class:`BodySizePrior` of ``model`` (a :class:`~pedx_graph.body.BodyModel`): ``num_samples`` body
    poses drawn (seeded) from ``pose_prior`` (a :class:`~pedx_graph.priors.gmm.GaussianMixturePrior`; None: the
    shipped pose prior, trained on walking motion capture), the root upright, the shape at the mean."""
    if pose_prior is None:
        from pedx_graph.priors import load_pose_prior

        pose_prior = load_pose_prior()
    if not shape_sigma > 0:
        raise ValueError(f"body size prior: shape_sigma must be > 0, got {shape_sigma}")
    rng = np.random.default_rng(seed)
    comp = rng.choice(pose_prior.num_components, size=num_samples, p=pose_prior.weights)
    chol = np.linalg.cholesky(pose_prior.covariances)
    body = pose_prior.means[comp] + np.einsum("nij,nj->ni", chol[comp], rng.standard_normal((num_samples, 69)))
    pose = np.concatenate([np.zeros((num_samples, 3)), body], axis=1)
    nb = model.num_betas
    points = _chain_points(model.keypoints(pose, np.zeros(nb)))                            # (N, P, 3)
    # heights are affine in the betas at a fixed pose: unit steps give the derivative exactly
    sub = pose[: min(num_samples, 32)]
    base = _chain_points(model.keypoints(sub, np.zeros(nb)))[..., 1]
    d_heights = np.stack([(_chain_points(model.keypoints(sub, np.eye(nb)[b]))[..., 1] - base).mean(axis=0)
                          for b in range(nb)], axis=1)
    return BodySizePrior(heights_m=points[..., 1], horizontal_m=points[..., [0, 2]], d_heights_d_betas=d_heights,
                         shape_sigma=float(shape_sigma))


def _chain_points(keypoints: np.ndarray) -> np.ndarray:
    """(..., P, 3) chain points (:data:`POINTS`) of keypoints (..., 18, 3)."""
    return np.stack([keypoints[..., list(idx), :].mean(axis=-2) for idx in POINTS.values()], axis=-2)


@dataclass
class MonocularDepth:
    """A one-camera depth from body size."""

    depth_m: float
    """Rectified depth (camera z, the same for both cameras of a rectified pair) of the body centre, metres:
    the convention of :class:`pedx_graph.graph.init.FrameMeasurements` (``lidar_depth``, ``stereo_depth``)."""
    sigma_m: float
    """Standard deviation of ``depth_m``, metres."""
    horizontal_distance_m: float
    """Horizontal distance (perpendicular to up) from the camera centre to the body, metres."""
    centre_uv: np.ndarray
    """(2,) pixel of the body centre (hips' mid-point, else the labelled torso joints' mean, else the chain
    points' mean) in the labelling image; back-project it at ``depth_m``."""
    side: str
    """``"left"`` or ``"right"``: the camera of the pair that labelled it."""
    segments: tuple[str, ...]
    """The vertical segments used, e.g. ``("head-neck", "neck-hips", ...)``."""
    chi2: float
    """Chi-square of the segments' agreement (``len(segments) - 1`` degrees of freedom)."""
    pair: str = ""
    """Stereo pair name (filled by :func:`track_monocular_depths`)."""


def _pixel_sigmas(sigma_px, occluded_sigma_px: float, visible: np.ndarray) -> np.ndarray:
    """(18,) pixel sigma of each keypoint: ``sigma_px`` (scalar or (18,)) where visible, else the occluded."""
    base = np.broadcast_to(np.asarray(sigma_px, dtype=float), (len(PEDX_KEYPOINTS),))
    return np.where(np.asarray(visible, dtype=bool), base, float(occluded_sigma_px))


def _elevation(uv: np.ndarray, intrinsics: tuple, up: np.ndarray) -> np.ndarray:
    """``tan e`` (...,) of pixels ``uv`` (..., 2) for the camera intrinsics ``(fx, fy, cx, cy)`` and ``up``."""
    fx, fy, cx, cy = intrinsics
    q = np.stack([(uv[..., 0] - cx) / fx, (uv[..., 1] - cy) / fy, np.ones(uv.shape[:-1])], axis=-1)
    vert = q @ up
    horiz = np.sqrt(np.maximum(np.sum(q * q, axis=-1) - vert ** 2, 1e-18))
    return vert / horiz


def _horizontal_norm(uv: np.ndarray, intrinsics: tuple, up: np.ndarray) -> float:
    fx, fy, cx, cy = intrinsics
    q = np.array([(uv[0] - cx) / fx, (uv[1] - cy) / fy, 1.0])
    return float(np.sqrt(max(q @ q - (q @ up) ** 2, 1e-18)))


def _centre_pixel(keypoints: np.ndarray, chain_uv: np.ndarray) -> np.ndarray:
    hips = keypoints[[_IDX["lhip"], _IDX["rhip"]]]
    if np.all(np.isfinite(hips)):
        return hips.mean(axis=0)
    torso = keypoints[[_IDX["lsho"], _IDX["rsho"], _IDX["lhip"], _IDX["rhip"]]]
    torso = torso[np.all(np.isfinite(torso), axis=1)]
    return torso.mean(axis=0) if len(torso) else chain_uv.mean(axis=0)


def _gls(t: np.ndarray, heights: np.ndarray, rel_cov: np.ndarray, end_rel_var: np.ndarray, mid_var: np.ndarray,
         noise_cov: np.ndarray) -> tuple[float, float, float]:
    """``(w, sigma_w, chi2)`` of ``t = w H (1 + eps) + n`` (module docstring), iterated on ``w``."""
    w = float(t.sum() / heights.sum())
    for _ in range(4):
        rel = rel_cov + np.diag(end_rel_var + mid_var * w ** 2)
        cov = w ** 2 * (heights[:, None] * rel * heights[None, :]) + noise_cov
        info = np.linalg.inv(cov)
        precision = float(heights @ info @ heights)
        w_new = float(heights @ info @ t) / precision
        if not w_new > 0:
            break
        w = w_new
    resid = t - w * heights
    return w, 1.0 / np.sqrt(precision), float(resid @ info @ resid)


def _estimate(chain: list[tuple[str, np.ndarray, float]], prior: BodySizePrior, intrinsics: tuple,
              up: np.ndarray) -> tuple[float, float, float, tuple[str, ...]] | None:
    """GLS over the consecutive segments of ``chain`` ((name, uv, pixel variance) top to bottom):
    ``(D, sigma_D, chi2, segment names)`` or None."""
    if len(chain) < 2:
        return None
    uv = np.stack([c[1] for c in chain])
    tan = _elevation(uv, intrinsics, up)
    # d tan / d(u, v) by central differences (0.5 px)
    step = 0.5
    grad = np.stack([(_elevation(uv + step * e, intrinsics, up) - _elevation(uv - step * e, intrinsics, up))
                     / (2 * step) for e in np.eye(2)], axis=-1)                         # (P, 2)
    tan_var = np.sum(grad ** 2, axis=-1) * np.array([c[2] for c in chain])            # (P,)
    k = len(chain) - 1
    diff = np.zeros((k, len(chain)))
    diff[np.arange(k), np.arange(k)] = 1.0
    diff[np.arange(k), np.arange(k) + 1] = -1.0
    t = diff @ tan
    pairs = [(chain[j][0], chain[j + 1][0]) for j in range(k)]
    heights, rel_cov, end_var, mid_var = prior.segment_statistics(pairs)
    if not t.sum() > 0:
        return None                                   # the chain upside down in the image: not upright
    tan_mid = 0.5 * (tan[:-1] + tan[1:])
    end_rel_var = tan_mid ** 2 * end_var / heights ** 2
    noise_cov = diff @ np.diag(tan_var) @ diff.T
    w, sigma_w, chi2 = _gls(t, heights, rel_cov, end_rel_var, mid_var, noise_cov)
    if not w > 0:
        return None
    return 1.0 / w, sigma_w / w ** 2, chi2, tuple(f"{a}-{b}" for a, b in pairs)


def monocular_depth(view, calibration, side: str, prior: BodySizePrior, *, world_up: np.ndarray | None = None,
                    sigma_px: float | np.ndarray = 3.0, occluded_sigma_px: float = 12.0,
                    consistency_quantile: float = 0.999) -> MonocularDepth | None:
    """Depth of the body centre from one image's labels and body size (module docstring).

    ``view``: :class:`~pedx_graph.data.types.View2D` ((18, 2) rectified pixels, NaN = unlabelled);
    ``calibration``: the :class:`~pedx_graph.data.types.StereoCalibration` of its pair, ``side`` ``"left"``
    or ``"right"``; ``prior``: :func:`body_size_prior` of the body model; ``world_up`` (3,): the sequence's
    up axis in the world frame (``GroundFrame.world_up``; None: the camera's image-up direction);
    ``sigma_px`` (scalar or (18,)) / ``occluded_sigma_px``: click noise of visible / not-visible keypoints.
    Returns None when fewer than two chain points are labelled or the labels are not an upright body.
    """
    if side not in ("left", "right"):
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    proj = np.asarray(calibration.left_P_rect if side == "left" else calibration.right_P_rect, dtype=float)
    intrinsics = (proj[0, 0], proj[1, 1], proj[0, 2], proj[1, 2])
    rect_R_world = calibration.rect_T_world[:3, :3]
    up = np.array([0.0, -1.0, 0.0]) if world_up is None else rect_R_world @ np.asarray(world_up, dtype=float)
    up = up / np.linalg.norm(up)
    kp = np.asarray(view.keypoints, dtype=float)
    labelled = np.all(np.isfinite(kp), axis=1)
    var = _pixel_sigmas(sigma_px, occluded_sigma_px, view.visible) ** 2
    chain: list[tuple[str, np.ndarray, float]] = []
    for slot in CHAIN:
        for name in slot:
            idx = list(POINTS[name])
            if labelled[idx].all():
                chain.append((name, kp[idx].mean(axis=0), float(var[idx].sum()) / len(idx) ** 2))
                break
    best = _estimate(chain, prior, intrinsics, up)
    if best is not None and len(chain) >= 3 and \
            best[2] > chi2_dist.ppf(consistency_quantile, len(chain) - 2):
        # inconsistent segments: refit without the chain point whose removal fits best (a mis-click)
        trials = [_estimate(chain[:j] + chain[j + 1:], prior, intrinsics, up) for j in range(len(chain))]
        scored = [(chi2_dist.sf(tr[2], max(len(tr[3]) - 1, 1)) if len(tr[3]) > 1 else 0.5, j, tr)
                  for j, tr in enumerate(trials) if tr is not None]
        if scored:
            best = max(scored, key=lambda s: s[0])[2]
    if best is None:
        return None
    distance, sigma, chi2, names = best
    centre = _centre_pixel(kp, np.stack([c[1] for c in chain]))
    scale = 1.0 / _horizontal_norm(centre, intrinsics, up)
    return MonocularDepth(depth_m=float(distance * scale), sigma_m=float(sigma * scale),
                          horizontal_distance_m=float(distance), centre_uv=np.asarray(centre, dtype=float),
                          side=side, segments=names, chi2=float(chi2))


def frame_monocular_depth(frame, calibrations: dict, prior: BodySizePrior, *, world_up: np.ndarray | None = None,
                          sigma_px: float | np.ndarray = 3.0, occluded_sigma_px: float = 12.0
                          ) -> MonocularDepth | None:
    """The tightest :func:`monocular_depth` over the images labelling one
    :class:`~pedx_graph.data.types.TrackFrame` (every pair's when the frame lists them), or None."""
    views = frame.labelled_views() if hasattr(frame, "labelled_views") else \
        [(frame.pair, side, view) for side, view in (("left", frame.left), ("right", frame.right))
         if view is not None]
    best = None
    for pair, side, view in views:
        est = monocular_depth(view, calibrations[pair], side, prior, world_up=world_up, sigma_px=sigma_px,
                              occluded_sigma_px=occluded_sigma_px)
        if est is not None and (best is None or est.sigma_m < best.sigma_m):
            est.pair = pair
            best = est
    return best


def track_monocular_depths(track, prior: BodySizePrior, *, sigma_px: float | np.ndarray = 3.0,
                           occluded_sigma_px: float = 12.0) -> list[MonocularDepth | None]:
    """Per frame of ``track`` (:class:`~pedx_graph.data.types.Track`) its body-size depth
    (:func:`frame_monocular_depth`, up from ``track.ground``), None where no image gives one.  Temporal
    smoothing is the caller's (e.g. the initialisation's local-linear depth fit with these sigmas)."""
    world_up = None if track.ground is None else track.ground.world_up
    return [frame_monocular_depth(fr, track.calibrations, prior, world_up=world_up, sigma_px=sigma_px,
                                  occluded_sigma_px=occluded_sigma_px) for fr in track.frames]
