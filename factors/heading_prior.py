"""E_D (PedX Eq. 3): the body faces the direction in which the LiDAR trajectory moves.

Measurement: the ground-plane heading of the pedestrian at this frame, from the LiDAR track (e.g. the
finite difference of the per-frame LiDAR point means), as a 2D direction ``h = (h_x, h_y)`` in the
sequence's *level frame* (or an angle from level +x toward +y), and the speed in m/s that produced it.
The level frame ``world_R_level`` (3, 3; columns forward, left, up; :class:`pedx_graph.data.ground.GroundFrame`)
is derived from the data: no axis of the world (LiDAR) frame is assumed to point up (real PedX: z down).

Prediction: the body's forward axis (SMPL +Z) in the level frame, projected on the ground plane,

    f = (level_R_world @ world_R_body @ [0, 0, 1])[:2]        (2,),   level_R_world = world_R_level^T

Residual (radians, wrapped to (-pi, pi] by construction, no branch at +-pi):

    r = atan2(h x f, h . f) = atan2(h_x f_y - h_y f_x, h_x f_x + h_y f_y)       (1,)

i.e. the signed angle from the measured heading to the body's heading (about the up axis).  Jacobian w.r.t.
the root's right perturbation ``world_R_body @ Exp(delta)``: ``dr/df = (d * [-h_y, h_x] - c * [h_x, h_y]) / |f|^2``
and ``df/ddelta = -(level_R_body @ hat(e_z))[:2]`` with ``level_R_body = level_R_world @ world_R_body``.  When
the forward axis is vertical (``|f| < 1e-6``, body lying face up/down) the heading is undefined: the residual
is 0 with a zero Jacobian.

Zero speed: the trajectory heading is noise when the pedestrian stands still, so the noise grows as the
speed drops,

    sigma = sigma0 * max(1, v0 / max(speed, 1e-3))            (radians)

and no factor is created below ``min_speed`` (:func:`make_heading_prior_factor` returns ``None``).  The
measured heading's own uncertainty ``sigma_traj`` (e.g. a far pedestrian's trajectory taken from noisy
stereo depth: ``pedx_graph.graph.init``) adds in quadrature: ``sqrt(sigma^2 + sigma_traj^2)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from factors.common import ROOT_DIM, as_f64, set_jacobians
from factors.terms import NormalEquations, RowNoise, Term, kernels, rows_normal_equations, stacked

#: The factor kind (``TrackProblem.factor_kinds``, the term cache's registry).
KIND = "heading_prior"

#: |f| below this (the body's forward axis is vertical) gives residual 0 and a zero Jacobian.
MIN_FORWARD_NORM = 1e-6

#: Speeds are clamped to at least this (m/s) in :func:`heading_sigma`.
MIN_SPEED_CLAMP = 1e-3


def heading_vector(level_heading: float | np.ndarray) -> np.ndarray:
    """Unit 2D heading (2,) from an angle (radians from level +x toward +y) or a 2D vector."""
    h = np.asarray(level_heading, dtype=np.float64)
    if h.ndim == 0:
        return np.array([np.cos(h), np.sin(h)])
    h = h.reshape(-1)[:2]
    n = float(np.hypot(h[0], h[1]))
    if h.size != 2 or not np.isfinite(n) or n < 1e-9:
        raise ValueError(f"heading vector must be a finite non-zero 2D vector, got {level_heading!r}")
    return h / n


def heading_sigma(speed: float, sigma0_rad: float, v0: float) -> float:
    """``sigma0 * max(1, v0 / max(speed, 1e-3))``: noise of the heading prior at ``speed`` m/s."""
    return float(sigma0_rad * max(1.0, v0 / max(float(speed), MIN_SPEED_CLAMP)))


def trajectory_headings(timestamps: np.ndarray, level_p_track: np.ndarray,
                        half_window_s: float = 0.25) -> tuple[np.ndarray, np.ndarray]:
    """Ground-plane heading and speed of a LiDAR track, for the heading prior's measurement.

    ``timestamps`` (T,) seconds (increasing), ``level_p_track`` (T, 3) e.g. the per-frame means of the
    instance's LiDAR points in the level frame (``GroundFrame.to_level``, metres).  For frame t the displacement is taken between the first and last
    frames within ``half_window_s`` seconds on either side (one-sided at the ends; the immediate neighbours
    when none is that close): ``heading = unit(dxy)`` (T, 2) and ``speed = |dxy| / dt`` (T,) m/s.  A frame
    without a neighbour, or with zero displacement, gets speed 0 and heading (1, 0) (no factor is made).
    """
    ts = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    pts = np.asarray(level_p_track, dtype=np.float64).reshape(-1, 3)
    if ts.size != pts.shape[0]:
        raise ValueError(f"trajectory_headings: {ts.size} timestamps for {pts.shape[0]} positions")
    if ts.size > 1 and np.any(np.diff(ts) <= 0):
        raise ValueError("trajectory_headings: timestamps must be strictly increasing")
    n = ts.size
    headings = np.tile([1.0, 0.0], (n, 1))
    speeds = np.zeros(n)
    for t in range(n):
        lo = int(np.searchsorted(ts, ts[t] - half_window_s, side="left"))
        hi = int(np.searchsorted(ts, ts[t] + half_window_s, side="right")) - 1
        lo = min(lo, max(t - 1, 0))
        hi = max(hi, min(t + 1, n - 1))
        if hi == lo:
            continue
        dxy = pts[hi, :2] - pts[lo, :2]
        dist = float(np.hypot(dxy[0], dxy[1]))
        if dist > 0:
            headings[t] = dxy / dist
            speeds[t] = dist / (ts[hi] - ts[lo])
    return headings, speeds


def heading_prior_batch(world_R_body: np.ndarray, level_heading: np.ndarray, world_R_level: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Signed angles (F,) from unit level-frame headings (F, 2) to the ground-plane forward of F rotations
    (F, 3, 3), and the Jacobians (F, 3) w.r.t. the root's right perturbation (zero where the forward axis is
    vertical); ``world_R_level`` (3, 3) or (F, 3, 3)."""
    level_R_world = np.swapaxes(as_f64(world_R_level), -1, -2)
    rot = np.matmul(level_R_world, as_f64(world_R_body).reshape(-1, 3, 3))         # level_R_body (F, 3, 3)
    h = as_f64(level_heading).reshape(-1, 2)
    hx, hy = h[:, 0], h[:, 1]
    fx, fy = rot[:, 0, 2], rot[:, 1, 2]               # world_R_body @ e_z, first two rows
    c = hx * fy - hy * fx
    d = hx * fx + hy * fy
    n2 = fx * fx + fy * fy
    ok = n2 >= MIN_FORWARD_NORM ** 2
    r = np.where(ok, np.arctan2(c, d), 0.0)
    inv = np.where(ok, 1.0 / np.where(ok, n2, 1.0), 0.0)
    dr_df = np.stack([d * -hy - c * hx, d * hx - c * hy], axis=1) * inv[:, None]          # (F, 2)
    # d(R e_z)/d delta = -R hat(e_z); hat(e_z) = [[0,-1,0],[1,0,0],[0,0,0]]
    df_ddelta = -np.stack([rot[:, :2, 1], -rot[:, :2, 0], np.zeros((len(rot), 2))], axis=2)   # (F, 2, 3)
    return r, np.einsum("fa,fab->fb", dr_df, df_ddelta)


def heading_prior_error(world_R_body: np.ndarray, level_heading: np.ndarray, world_R_level: np.ndarray,
                        want_jacobian: bool = False) -> tuple[np.ndarray, np.ndarray | None]:
    """Signed angle (1,) from the unit level heading (2,) to the body's ground-plane forward; Jacobian (1, 3)."""
    r, jac = heading_prior_batch(world_R_body, level_heading, world_R_level)
    return r, (jac if want_jacobian else None)


@dataclass(frozen=True)
class HeadingSpec:
    """A heading factor's measured unit level heading (2,), level frame (3, 3) and noise (sigma in radians,
    per-row robust kernel)."""

    level_heading: np.ndarray
    world_R_level: np.ndarray
    sigma_rad: float
    robust: str
    robust_scale: float


def make_heading_prior_factor(key_root: int, level_heading: float | np.ndarray, speed: float, *,
                              world_R_level: np.ndarray, sigma0_rad: float = 0.3, v0: float = 0.5, min_speed: float = 0.2,
                              robust: str = "none", robust_scale: float = 2.0,
                              cache=None, trajectory_sigma_rad: float = 0.0) -> gtsam.CustomFactor | None:
    """Heading prior on ``key_root`` (Rot3), or ``None`` when ``speed < min_speed`` (m/s).

    ``level_heading``: angle or 2D direction in the level frame ``world_R_level`` (3, 3, a rotation whose
    third column is the world's up; :attr:`pedx_graph.data.ground.GroundFrame.world_R_level`).

    ``sigma0_rad`` is the noise at speeds >= ``v0`` m/s; it grows as ``v0 / speed`` below (see the module
    docstring).  ``trajectory_sigma_rad``: the measured heading's own uncertainty (e.g. from the depth
    noise of the trajectory it was taken from), added in quadrature.  ``robust`` / ``robust_scale`` as :func:`factors.common.make_noise` (e.g. for pedestrians
    walking backwards or a flipped trajectory heading).
    """
    if not np.isfinite(speed) or speed < 0:
        raise ValueError(f"heading prior: speed must be finite and >= 0, got {speed}")
    if speed < min_speed:
        return None
    h = heading_vector(level_heading)
    level = as_f64(world_R_level)
    if level.shape != (3, 3) or not np.allclose(level.T @ level, np.eye(3), atol=1e-6):
        raise ValueError(f"heading prior: world_R_level must be a (3, 3) rotation, got {world_R_level!r}")
    if not (np.isfinite(trajectory_sigma_rad) and trajectory_sigma_rad >= 0):
        raise ValueError(f"heading prior: trajectory_sigma_rad must be finite and >= 0, got {trajectory_sigma_rad}")
    sigma = float(np.hypot(heading_sigma(speed, sigma0_rad, v0), trajectory_sigma_rad))
    spec = HeadingSpec(h, level, sigma, robust, float(robust_scale))
    if cache is not None:
        cache.register(KIND, [key_root], spec)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        r, jac = heading_prior_error(values.atRot3(this.keys()[0]).matrix(), h, level, H is not None)
        if H is not None:
            set_jacobians(H, [jac], 1, [ROOT_DIM])
        return r

    return gtsam.CustomFactor(noise_of(spec).model(), [key_root], error)


def noise_of(spec: HeadingSpec) -> RowNoise:
    """One row, ``sigma_rad`` radians, the kernel on it."""
    return RowNoise(np.array([spec.sigma_rad]), spec.robust, spec.robust_scale)


def assemble(cache, keys_list: list[tuple[int, ...]], jacobians: bool) -> NormalEquations:
    """The heading factors ``keys_list`` (column: the root) from their specs and the cache's prefetched
    rotations, in one :func:`heading_prior_batch` call."""
    frames = cache.frame_index(keys_list)
    st = stacked(cache, KIND, keys_list, ("level_heading", "world_R_level", "sigma_rad"))
    r, jac = heading_prior_batch(cache.frame_arrays["world_R_body"][frames], st["level_heading"], st["world_R_level"])
    return rows_normal_equations(keys_list, r[:, None], jac[:, None, :] if jacobians else None,
                                 1.0 / st["sigma_rad"][:, None], kernels(cache, KIND, keys_list, noise_of))


TERM = Term(KIND, assemble)
