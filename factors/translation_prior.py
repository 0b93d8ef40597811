"""E_T (PedX Eq. 2): the body's root lies at the mean of the pedestrian's LiDAR points, up to a known offset.

The LiDAR only sees the surface facing the sensor, so the mean ``m`` of the instance points (M, 3) sits in
front of the body's centre along the viewing ray, and its height depends on which parts are visible.  The
prior therefore compares the pelvis with ``m`` in a *sensor-ray frame* and allows for both effects:

    world_p_pelvis = J_0(betas) + trans                (SMPL: the root joint never moves with the pose)
    Q = [u, l, up]    u = unit ground-plane direction from the sensor to m,  l = up x u         (3, 3)
    r = Q^T (world_p_pelvis - m) - [depth_offset_m, 0, height_offset_m]                  (3,) metres

with per-axis sigmas ``(sigma_ray_m, sigma_lateral_m, sigma_vertical_m)``: the pelvis is expected
``depth_offset_m`` (default 0.10 m, about half a torso depth) *behind* the visible surface along the ray,
and the along-ray and vertical sigmas are larger than the lateral one (the offset varies with the
body's orientation and with occlusion).  World = LiDAR frame; ``world_up`` (3,) is the sequence's up axis
and ``world_p_sensor`` the rig's viewpoint, both derived from the data
(:class:`pedx_graph.data.ground.GroundFrame`; no axis of the LiDAR frame is assumed to point up).  ``J_0`` is linear in ``betas``, so ``J_0(betas) = J_0(0) + D betas`` is precomputed
from ``model.rest_joints`` once; the callback needs no body-model evaluation.  Keys: ``trans`` (3) and
``betas`` (B) only (the pelvis does not depend on the root rotation or the body pose).
Jacobians: ``dr/dtrans = Q^T``, ``dr/dbetas = Q^T D``.  If the points are (horizontally) at the sensor,
``u`` falls back to the ground-plane direction of the world axis most perpendicular to ``up``.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass

import gtsam
import numpy as np

from factors.common import TRANS_DIM, BodyModelLike, as_f64, set_jacobians
from factors.terms import NormalEquations, RowNoise, Term, kernels, rows_normal_equations, stacked

#: The factor kind (``TrackProblem.factor_kinds``, the term cache's registry).
KIND = "translation_prior"


def sensor_ray_frame(world_p_mean: np.ndarray, world_p_sensor: np.ndarray, world_up: np.ndarray) -> np.ndarray:
    """``world_R_ray`` (3, 3), columns ``[u, l, up]``: ground-plane viewing direction from the sensor, its left
    (``up x u``), and the up axis (unit ``world_up``)."""
    up = as_f64(world_up)
    up = up / np.linalg.norm(up)
    d = as_f64(world_p_mean) - as_f64(world_p_sensor)
    d = d - (d @ up) * up
    n = float(np.linalg.norm(d))
    if n < 1e-6:
        axis = np.eye(3)[int(np.argmin(np.abs(up)))]
        d = axis - (axis @ up) * up
        n = float(np.linalg.norm(d))
    u = d / n
    return np.stack([u, np.cross(up, u), up], axis=1)


_BASIS: list = [None, 0, None]       # [weakref to the model, num_betas, (rest, basis)] of the last call


def pelvis_shape_basis(model: BodyModelLike, num_betas: int) -> tuple[np.ndarray, np.ndarray]:
    """Rest pelvis ``J_0(0)`` (3,) and ``D = dJ_0/dbetas`` (3, B) from ``model.rest_joints`` (linear in betas).

    Remembered for the last model (every frame of a track asks for the same one); read-only arrays."""
    if _BASIS[0] is not None and _BASIS[0]() is model and _BASIS[1] == num_betas:
        return _BASIS[2]
    rest0 = np.asarray(model.rest_joints(np.zeros(num_betas)))[0]
    basis = np.stack([np.asarray(model.rest_joints(e))[0] - rest0 for e in np.eye(num_betas)], axis=1)
    out = (as_f64(rest0), as_f64(basis))
    for arr in out:
        arr.setflags(write=False)
    _BASIS[:] = [weakref.ref(model), num_betas, out]
    return out


def translation_prior_batch(trans: np.ndarray, betas: np.ndarray, pelvis_rest: np.ndarray,
                            pelvis_shapedirs: np.ndarray, world_p_mean: np.ndarray, world_R_ray: np.ndarray,
                            offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """F frames at once: residuals (F, 3) metres in each frame's ray frame and the Jacobians
    ``dr/dtrans = Q^T`` (F, 3, 3), ``dr/dbetas = Q^T D`` (F, 3, B); inputs stacked per frame (trans (F, 3),
    betas (F, B), means (F, 3), ray frames (F, 3, 3), offsets (F, 3))."""
    pelvis = pelvis_rest + as_f64(betas).reshape(len(world_R_ray), -1) @ pelvis_shapedirs.T \
        + as_f64(trans).reshape(-1, 3)
    q_t = np.swapaxes(as_f64(world_R_ray), 1, 2)
    r = np.einsum("fab,fb->fa", q_t, pelvis - world_p_mean) - offsets
    return r, q_t, q_t @ pelvis_shapedirs


def translation_prior_error(trans: np.ndarray, betas: np.ndarray, pelvis_rest: np.ndarray,
                            pelvis_shapedirs: np.ndarray, world_p_mean: np.ndarray, world_R_ray: np.ndarray,
                            offsets: np.ndarray, want_jacobians: bool = False
                            ) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Residual (3,) metres in the ray frame; Jacobians ``[dr/dtrans (3, 3), dr/dbetas (3, B)]`` when asked."""
    r, d_trans, d_betas = translation_prior_batch(trans, betas, pelvis_rest, pelvis_shapedirs,
                                                  as_f64(world_p_mean)[None], as_f64(world_R_ray)[None],
                                                  as_f64(offsets)[None])
    if not want_jacobians:
        return r[0], None
    return r[0], [as_f64(d_trans[0]), as_f64(d_betas[0])]


@dataclass(frozen=True)
class TranslationSpec:
    """A translation factor's measurement (points' mean, ray frame, offsets), pelvis model and noise."""

    world_p_mean: np.ndarray
    world_R_ray: np.ndarray
    offsets: np.ndarray
    pelvis_rest: np.ndarray
    pelvis_shapedirs: np.ndarray
    sigmas: np.ndarray
    robust: str
    robust_scale: float


def make_translation_prior_factor(key_trans: int, key_betas: int, model: BodyModelLike, world_points: np.ndarray,
                                  *, world_up: np.ndarray, world_p_sensor: np.ndarray, num_betas: int = 10,
                                  depth_offset_m: float = 0.10, height_offset_m: float = 0.0,
                                  sigma_ray_m: float = 0.15, sigma_lateral_m: float = 0.10,
                                  sigma_vertical_m: float = 0.25, robust: str = "none",
                                  robust_scale: float = 3.0, cache=None) -> gtsam.CustomFactor | None:
    """Pelvis-to-LiDAR-mean prior on ``(trans, betas)``; ``None`` when there are no points.

    ``world_points`` (M, 3) metres; ``world_up`` (3,) and ``world_p_sensor`` (3,) from the sequence's
    :class:`~pedx_graph.data.ground.GroundFrame`; offsets and sigmas in metres (see the module docstring).  ``robust``
    (a kernel of :func:`factors.common.make_noise`, scale in sigmas) guards against frames whose 2D polygon
    picked up more background than person, so that the points' mean is off by metres.
    """
    pts = as_f64(world_points).reshape(-1, 3) if np.size(world_points) else np.zeros((0, 3))
    if pts.shape[0] == 0:
        return None
    if not np.all(np.isfinite(pts)):
        raise ValueError("translation prior: world_points contain non-finite values")
    mean = pts.mean(axis=0)
    world_R_ray = sensor_ray_frame(mean, world_p_sensor, world_up)
    offsets = np.array([depth_offset_m, 0.0, height_offset_m], dtype=np.float64)
    pelvis_rest, pelvis_dirs = pelvis_shape_basis(model, num_betas)
    sigmas = np.array([sigma_ray_m, sigma_lateral_m, sigma_vertical_m], dtype=np.float64)
    spec = TranslationSpec(mean, world_R_ray, offsets, pelvis_rest, pelvis_dirs, sigmas, robust, float(robust_scale))
    if cache is not None:
        cache.register(KIND, [key_trans, key_betas], spec)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        k = this.keys()
        r, blocks = translation_prior_error(values.atVector(k[0]), values.atVector(k[1]), pelvis_rest,
                                            pelvis_dirs, mean, world_R_ray, offsets, H is not None)
        if H is not None:
            set_jacobians(H, blocks, 3, [TRANS_DIM, num_betas])
        return r

    return gtsam.CustomFactor(noise_of(spec).model(), [key_trans, key_betas], error)


def noise_of(spec: TranslationSpec) -> RowNoise:
    """Per-axis sigmas (ray, lateral, vertical) in metres, the kernel per row."""
    return RowNoise(spec.sigmas, spec.robust, spec.robust_scale)


def assemble(cache, keys_list: list[tuple[int, ...]], jacobians: bool) -> NormalEquations:
    """The translation factors ``keys_list`` (columns ``[trans, betas]``) from their specs and the cache's
    prefetched states, in one :func:`translation_prior_batch` call."""
    frames = cache.frame_index(keys_list)
    arrays = cache.frame_arrays
    spec = cache.specs(KIND)[keys_list[0]]
    st = stacked(cache, KIND, keys_list, ("world_p_mean", "world_R_ray", "offsets", "sigmas"))
    r, d_trans, d_betas = translation_prior_batch(arrays["trans"][frames], arrays["betas"][frames], spec.pelvis_rest,
                                                  spec.pelvis_shapedirs, st["world_p_mean"], st["world_R_ray"],
                                                  st["offsets"])
    jac = np.concatenate([d_trans, d_betas], axis=2) if jacobians else None
    return rows_normal_equations(keys_list, r, jac, 1.0 / st["sigmas"], kernels(cache, KIND, keys_list, noise_of))


TERM = Term(KIND, assemble)
