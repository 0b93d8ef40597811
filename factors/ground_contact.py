"""E_G: the stance foot stands on the ground, once the sequence's ground plane is known.

A walking pedestrian always has a foot down.  The sequence's ground frame (``GroundFrame`` of
``pedx_graph.data.ground``: unit ``world_up`` (3,) derived from the data, the plane ``world_up . p =
ground_offset_m``) gives each ankle keypoint's height above the ground,

    h_a = world_up . world_p_a(root, trans, body_pose, betas) - ground_offset_m     a in {lankl, rankl}   (m)

and the lower ankle is the stance foot, ``s = argmin_a h_a`` (held within one evaluation, like a
max-mixture's component).  Its ankle should stand at the ankle's height above the sole,

    r = h_s - ankle_height_m                                                        (1,) metres

with ``ankle_height_m`` the body model's ankle keypoint height above its lowest vertex in the rest pose at
the mean shape (:func:`ankle_height_m`; the flat stance foot).  World = LiDAR frame, metres; no axis of it
is assumed to point up.  Noise: ``sigma_m`` metres (``NoiseConfig.ground_contact_sigma_m``, 0.06 m; 0
switches the term off), a Cauchy kernel (scale 2 in whitened units) so that a flight phase, a kerb or a stair costs
little.  Jacobian (1, 3 + 3 + 69 + B): ``world_up^T [d_root, d_trans, d_body_pose, d_betas]`` of the stance
ankle's keypoint (``BodyModel.point_jacobians``; right perturbation of the root).  Keys: ``[root, trans,
body_pose, betas]`` of the frame.  No factor when the ground plane is unknown (``ground_offset_m`` None).
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass
from typing import Sequence

import gtsam
import numpy as np

from factors.common import (BODY_POSE_DIM, ROOT_DIM, TRANS_DIM, BodyModelLike, FrameKeys, as_f64, frame_key_list,
                            read_frame_state, set_jacobians)
from factors.terms import NormalEquations, RowNoise, Term, kernels, rows_normal_equations, stacked
from pedx_graph.keypoints import PEDX_KEYPOINTS

#: The factor kind (``TrackProblem.factor_kinds``, the term cache's registry).
KIND = "ground_contact"
#: The ankle keypoints (PEDX_KEYPOINTS order): the lower one is the stance foot.
ANKLES = np.array([PEDX_KEYPOINTS.index("lankl"), PEDX_KEYPOINTS.index("rankl")])
_JACOBIANS = ("d_root", "d_trans", "d_body_pose", "d_betas")


@dataclass(frozen=True)
class GroundContactSpec:
    """A ground-contact factor's ground plane, ankle height and noise."""

    world_up: np.ndarray
    """(3,) unit up axis, world frame."""
    ground_offset_m: float
    """The ground plane ``world_up . p = ground_offset_m``, metres."""
    ankle_height_m: float
    """Height of the stance ankle's keypoint above the ground, metres."""
    sigma_m: float
    """Noise of the height, metres."""
    robust: str = "cauchy"
    robust_scale: float = 2.0


_HEIGHT: list = [None, 0.0]          # [weakref to the model, its ankle height]


def ankle_height_m(model: BodyModelLike) -> float:
    """The ankle keypoints' mean height above the lowest vertex in the rest pose at the mean shape (the body
    frame's +Y is up in the rest pose), metres; remembered for the last model."""
    if _HEIGHT[0] is not None and _HEIGHT[0]() is model:
        return _HEIGHT[1]
    num_betas = int(model.num_betas)
    rest = model.forward(np.zeros(72), np.zeros(num_betas), np.zeros(3))
    height = float(np.mean(np.asarray(rest.keypoints)[ANKLES, 1]) - np.min(np.asarray(rest.vertices)[:, 1]))
    _HEIGHT[:] = [weakref.ref(model), height]
    return height


def ground_contact_batch(ankles: np.ndarray, world_up: np.ndarray, ground_offset_m: np.ndarray,
                         ankle_height: np.ndarray, jacobians: Sequence[np.ndarray] | None = None
                         ) -> tuple[np.ndarray, np.ndarray | None]:
    """G frames at once: residuals (G,) metres of the stance (lower) ankle and, given the two ankles'
    Jacobians ``[d_root, d_trans, d_body_pose, d_betas]`` (each (G, 2, 3, k)), its Jacobian (G, 1, 75 + B).
    ``ankles`` (G, 2, 3) the world ankle keypoints (:data:`ANKLES`), ``world_up`` (G, 3), ``ground_offset_m``
    and ``ankle_height`` (G,)."""
    up = as_f64(world_up)
    heights = np.einsum("gai,gi->ga", as_f64(ankles), up) - ground_offset_m[:, None]                 # (G, 2)
    stance = np.argmin(heights, axis=1)
    rows = np.arange(len(stance))
    r = heights[rows, stance] - ankle_height
    if jacobians is None:
        return r, None
    jac = np.concatenate([np.einsum("gi,gik->gk", up, np.asarray(d)[rows, stance]) for d in jacobians], axis=1)
    return r, jac[:, None, :]


def _keypoints(model: BodyModelLike, state) -> np.ndarray:
    """(K, 3) world keypoints; ``model.keypoints`` (cheap: few vertices) when the model has it."""
    if callable(getattr(model, "keypoints", None)):
        return model.keypoints(state.full_pose, state.betas, state.trans)
    return model.forward(state.full_pose, state.betas, state.trans).keypoints


def noise_of(spec: GroundContactSpec) -> RowNoise:
    """One row, ``sigma_m`` metres, the kernel on it."""
    return RowNoise(np.array([spec.sigma_m]), spec.robust, spec.robust_scale)


def make_ground_contact_factor(keys: FrameKeys | Sequence[int], model: BodyModelLike, world_up: np.ndarray,
                               ground_offset_m: float, sigma_m: float, robust: str = "cauchy",
                               robust_scale: float = 2.0) -> gtsam.CustomFactor:
    """Stance-foot ground contact on ``keys = [root, trans, body_pose, betas]``: ``world_up`` (3,) and
    ``ground_offset_m`` (m) the sequence's ground plane, ``sigma_m`` metres (see the module docstring)."""
    up = as_f64(world_up) / np.linalg.norm(world_up)
    if not (sigma_m > 0 and np.isfinite(ground_offset_m)):
        raise ValueError(f"ground contact: sigma_m must be > 0 and the ground offset finite, got {sigma_m}, "
                         f"{ground_offset_m}")
    spec = GroundContactSpec(up, float(ground_offset_m), ankle_height_m(model), float(sigma_m), robust,
                             float(robust_scale))
    cache = getattr(model, "term_cache", None)
    if cache is not None:
        cache.register(KIND, frame_key_list(keys), spec)
    offset, height = np.array([spec.ground_offset_m]), np.array([spec.ankle_height_m])

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        state = read_frame_state(values, this.keys())
        if H is None:
            points, jac = _keypoints(model, state), None
        else:
            kp = model.point_jacobians(state.full_pose, state.betas, state.trans)
            points, jac = kp.points, [np.asarray(getattr(kp, name))[None, ANKLES] for name in _JACOBIANS]
        r, d = ground_contact_batch(np.asarray(points)[None, ANKLES], up[None], offset, height, jac)
        if H is not None:
            b = d.shape[2] - ROOT_DIM - TRANS_DIM - BODY_POSE_DIM
            set_jacobians(H, np.split(d[0], np.cumsum([ROOT_DIM, TRANS_DIM, BODY_POSE_DIM]), axis=1), 1,
                          [ROOT_DIM, TRANS_DIM, BODY_POSE_DIM, b])
        return r

    return gtsam.CustomFactor(noise_of(spec).model(), frame_key_list(keys), error)


def assemble(cache, keys_list: list[tuple[int, ...]], jacobians: bool) -> NormalEquations:
    """The ground-contact factors ``keys_list`` from the cache's prefetched keypoints (and their Jacobians)."""
    frames = cache.frame_index(keys_list)
    kp = cache.keypoint_arrays
    ankles = (frames[:, None], ANKLES[None, :])                     # the two ankles of every frame
    st = stacked(cache, KIND, keys_list, ("world_up", "ground_offset_m", "ankle_height_m", "sigma_m"))
    r, jac = ground_contact_batch(kp["points"][ankles], st["world_up"], st["ground_offset_m"], st["ankle_height_m"],
                                  [kp[name][ankles] for name in _JACOBIANS] if jacobians else None)
    columns = None
    if jacobians:                  # the ankles do not move with most joints: only the columns that are not 0
        columns = np.flatnonzero(np.any(jac != 0.0, axis=(0, 1)))
        jac = jac[:, :, columns]
    return rows_normal_equations(keys_list, r[:, None], jac, 1.0 / st["sigma_m"][:, None],
                                 kernels(cache, KIND, keys_list, noise_of), columns)


def frame_factor(keys, frame, model, ctx, config, ground):
    """The frame's factor when ``config.noise.ground_contact_sigma_m`` > 0 and the ground plane is known."""
    sigma = config.noise.ground_contact_sigma_m
    if not sigma > 0 or ground is None or ground.ground_offset_m is None:
        return None
    return make_ground_contact_factor(keys, model, ground.world_up, ground.ground_offset_m, sigma)


TERM = Term(KIND, assemble, frame_factor=frame_factor)
