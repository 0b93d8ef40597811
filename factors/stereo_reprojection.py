"""E_J,l + E_J,r (PedX): reprojection of the body model's 18 keypoints into both rectified stereo images.

Measurement model, for each labelled keypoint k of image c in {left, right} (pixels of the rectified image):

    rect_p_k = rect_T_world @ [world_p_k(root, trans, body_pose, betas); 1]      (metres, rectified left frame)
    [u w, v w, w] = P_rect_c @ [rect_p_k; 1]                                       (KITTI-style P, (3, 4))
    r_k,c = [u, v] - z_k,c                                                         (2,) pixels

``world_p_k`` comes from ``BodyModel.point_jacobians`` (world frame = LiDAR, metres).  Rows: the left
image's labelled keypoints (u, v each) in PEDX_KEYPOINTS order, then the right image's.  The depth ``w`` is
clamped to ``min_depth`` metres (its derivative is then dropped) so points behind the camera stay finite.

Noise: per-row sigma ``sigma_px`` for keypoints flagged visible, ``sigma_occluded_px`` for labelled but not
visible ones, divided by ``sqrt(weight_k)`` (``keypoint_weights``: relative weight of each keypoint's
squared error; 0 drops it; by default the hips get 0.25 because the annotators click the hip surface while
the model's hip joints sit inside the pelvis).  Optionally robust per row (``factors.common.make_noise``;
Geman-McClure by default, scale in whitened units).  Jacobians: ``d[u,v]/d world_p = (M[:2] - [u,v] M[2]) / w``
with ``M = P_rect[:, :3] @ rect_R_world``, chained with the body-model point Jacobians.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import gtsam
import numpy as np

from factors.common import (BODY_POSE_DIM, ROOT_DIM, TRANS_DIM, BodyModelLike, FrameKeys, FrameState, as_f64,
                            frame_key_list,
                            make_noise, read_frame_state, set_jacobians)
from pedx_graph.data.types import StereoCalibration, View2D
from pedx_graph.keypoints import PEDX_KEYPOINTS

NUM_KEYPOINTS = len(PEDX_KEYPOINTS)

#: Relative weights of the 18 keypoints' squared errors (PEDX_KEYPOINTS order): hips 0.25, others 1.
DEFAULT_KEYPOINT_WEIGHTS = np.array([0.25 if name in ("lhip", "rhip") else 1.0 for name in PEDX_KEYPOINTS])


@dataclass(frozen=True)
class StereoKeypoints:
    """2D keypoint labels of one pedestrian in both rectified images of a stereo pair."""

    left_uv: np.ndarray
    """(18, 2) pixels in the rectified left image, NaN where not labelled."""
    right_uv: np.ndarray
    """(18, 2) pixels in the rectified right image, NaN where not labelled."""
    left_visible: np.ndarray
    """(18,) bool, the annotator's visible flag in the left image."""
    right_visible: np.ndarray
    """(18,) bool, the visible flag in the right image."""

    @staticmethod
    def from_views(left: View2D | None, right: View2D | None) -> "StereoKeypoints":
        """From the ``TrackFrame.left`` / ``.right`` labels (either may be None: nothing labelled there)."""
        def parts(view):
            if view is None:
                return np.full((NUM_KEYPOINTS, 2), np.nan), np.zeros(NUM_KEYPOINTS, bool)
            return as_f64(view.keypoints), np.asarray(view.visible, dtype=bool)
        luv, lvis = parts(left)
        ruv, rvis = parts(right)
        return StereoKeypoints(luv, ruv, lvis, rvis)


@dataclass(frozen=True)
class _ImageRows:
    """Pre-selected rows of one image: keypoint indices (n,), measured uv (n, 2), M (3, 3), c (3,)."""

    index: np.ndarray
    uv: np.ndarray
    proj_m: np.ndarray
    proj_c: np.ndarray


@dataclass(frozen=True)
class StereoSetup:
    """Everything fixed at construction: selected rows of both images, their sigmas, the projections."""

    images: tuple[_ImageRows, _ImageRows]
    sigmas: np.ndarray
    """(m,) per-row sigmas in pixels."""
    min_depth: float

    @property
    def rows(self) -> int:
        return int(self.sigmas.size)


@dataclass(frozen=True)
class StereoTerm:
    """A stereo factor's fixed setup and its noise: per-row sigmas ``setup.sigmas`` (pixels) and the robust
    kernel (per row, scale in whitened units) of :func:`factors.common.make_noise`."""

    setup: StereoSetup
    robust: str
    robust_scale: float


def build_stereo_setup(measurement: StereoKeypoints, calibration: StereoCalibration, sigma_px: float = 2.0,
                       sigma_occluded_px: float = 6.0, keypoint_weights: np.ndarray | None = None,
                       min_depth: float = 0.1) -> StereoSetup:
    """Select the rows (labelled, finite, weight > 0) and their sigmas; precompute ``M``, ``c`` per image."""
    if not (sigma_px > 0 and sigma_occluded_px > 0 and min_depth > 0):
        raise ValueError("stereo reprojection: sigma_px, sigma_occluded_px and min_depth must be > 0")
    weights = DEFAULT_KEYPOINT_WEIGHTS if keypoint_weights is None else as_f64(keypoint_weights)
    if weights.shape != (NUM_KEYPOINTS,) or np.any(weights < 0):
        raise ValueError(f"keypoint_weights must be ({NUM_KEYPOINTS},) and >= 0, got {weights}")
    rect_T_world = calibration.rect_T_world
    images, sigmas = [], []
    for uv, vis, proj in ((measurement.left_uv, measurement.left_visible, calibration.left_P_rect),
                          (measurement.right_uv, measurement.right_visible, calibration.right_P_rect)):
        uv = as_f64(uv)
        vis = np.asarray(vis, dtype=bool)
        if uv.shape != (NUM_KEYPOINTS, 2) or vis.shape != (NUM_KEYPOINTS,):
            raise ValueError(f"stereo keypoints must be ({NUM_KEYPOINTS}, 2) with ({NUM_KEYPOINTS},) visible "
                             f"flags, got {uv.shape} and {vis.shape}")
        proj = as_f64(proj)
        use = np.all(np.isfinite(uv), axis=1) & (weights > 0)
        idx = np.flatnonzero(use)
        sig = np.where(vis[idx], sigma_px, sigma_occluded_px) / np.sqrt(weights[idx])
        sigmas.append(np.repeat(sig, 2))
        images.append(_ImageRows(index=idx, uv=uv[idx],
                                 proj_m=as_f64(proj[:, :3] @ rect_T_world[:3, :3]),
                                 proj_c=as_f64(proj[:, :3] @ rect_T_world[:3, 3] + proj[:, 3])))
    return StereoSetup(images=(images[0], images[1]), sigmas=np.concatenate(sigmas), min_depth=float(min_depth))


def _keypoints(model: BodyModelLike, state: FrameState) -> np.ndarray:
    """(18, 3) world keypoints; ``model.keypoints`` (cheap: few vertices) when the model has it."""
    if hasattr(model, "keypoints") and callable(model.keypoints):
        return model.keypoints(state.full_pose, state.betas, state.trans)
    return model.forward(state.full_pose, state.betas, state.trans).keypoints


def stereo_pixels(points: np.ndarray, setups: Sequence[StereoSetup], derivatives: bool = False
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """Pixels of all 18 keypoints of T frames (T, 18, 3) in both images, ``uv`` (T, 2, 18, 2), every frame
    with its own setup's projections, and (when ``derivatives``) ``d uv / d point`` (T, 2, 18, 2, 3)."""
    points = as_f64(points)
    proj_m = np.stack([[img.proj_m for img in su.images] for su in setups])          # (T, 2, 3, 3)
    proj_c = np.stack([[img.proj_c for img in su.images] for su in setups])          # (T, 2, 3)
    min_depth = np.array([su.min_depth for su in setups])[:, None, None]
    hom = points[:, None] @ np.swapaxes(proj_m, 2, 3) + proj_c[:, :, None]          # (T, 2, 18, 3)
    depth = hom[..., 2]
    clamped = depth < min_depth
    w = np.where(clamped, min_depth, depth)
    uv = hom[..., :2] / w[..., None]                                                 # (T, 2, 18, 2)
    if not derivatives:
        return uv, None
    keep = np.where(clamped, 0.0, 1.0)[..., None, None]
    d_uv = (proj_m[:, :, None, :2, :] - keep * uv[..., :, None] * proj_m[:, :, None, 2:3, :]) \
        / w[..., None, None]                                                         # (T, 2, 18, 2, 3)
    return uv, d_uv


def stereo_blocks(d_uv: np.ndarray, jac) -> list[np.ndarray]:
    """``[d uv / d root, trans, body_pose, betas]``, each (T, 2, 18, 2, k), from :func:`stereo_pixels`'
    ``d_uv`` and the keypoints' ``PointJacobians`` with leading dimension T."""
    return [d_uv @ np.asarray(getattr(jac, name), dtype=np.float64)[:, None]
            for name in ("d_root", "d_trans", "d_body_pose", "d_betas")]


def stereo_project(points: np.ndarray, setups: Sequence[StereoSetup], jac=None
                   ) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Pixels of all 18 keypoints of T frames in both images, ``uv`` (T, 2, 18, 2), and (when ``jac``, the
    keypoints' ``PointJacobians`` with leading dimension T, is given) ``[d uv / d root, trans, body_pose,
    betas]``, each (T, 2, 18, 2, k) — every frame with its own setup's projections, in batched products."""
    uv, d_uv = stereo_pixels(points, setups, jac is not None)
    return uv, None if jac is None else stereo_blocks(d_uv, jac)


def stereo_select(uv: np.ndarray, full: list[np.ndarray] | None, setup: StereoSetup, frame: int
                  ) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """One frame's factor rows out of :func:`stereo_project`: residual (m,) and blocks (m, k) or None."""
    left, right = setup.images
    r = np.concatenate([(uv[frame, 0, left.index] - left.uv).reshape(-1),
                        (uv[frame, 1, right.index] - right.uv).reshape(-1)])
    if full is None:
        return r, None
    return r, [as_f64(np.concatenate([b[frame, 0, left.index].reshape(-1, b.shape[-1]),
                                      b[frame, 1, right.index].reshape(-1, b.shape[-1])])) for b in full]


def stereo_reprojection_batch(points: np.ndarray, setups: Sequence[StereoSetup], jac=None
                              ) -> list[tuple[np.ndarray, list[np.ndarray] | None]]:
    """Unwhitened residuals and (when ``jac`` is given) Jacobian blocks of T frames at once.

    ``points`` (T, 18, 3) world keypoints; ``setups`` one :class:`StereoSetup` per frame; ``jac`` the
    keypoints' ``PointJacobians`` with leading dimension T (or None).  Returns per frame ``(r (m,),
    [J_root, J_trans, J_body_pose, J_betas] or None)``: :func:`stereo_project` then :func:`stereo_select`.
    """
    uv, full = stereo_project(points, setups, jac)
    return [stereo_select(uv, full, su, f) for f, su in enumerate(setups)]


def stereo_dense_rows(setup: StereoSetup) -> tuple[np.ndarray, np.ndarray]:
    """The setup's measurements and inverse sigmas laid out like :func:`stereo_project`'s ``uv`` rows:
    (2, 18, 2) each, with inverse sigma 0 (and measurement 0) on the rows the factor does not use."""
    meas = np.zeros((2, NUM_KEYPOINTS, 2))
    inv_sigma = np.zeros((2, NUM_KEYPOINTS, 2))
    start = 0
    for c, img in enumerate(setup.images):
        n = len(img.index)
        meas[c, img.index] = img.uv
        inv_sigma[c, img.index] = 1.0 / setup.sigmas[start:start + 2 * n].reshape(n, 2)
        start += 2 * n
    return meas, inv_sigma


def stereo_reprojection_error(model: BodyModelLike, state: FrameState, setup: StereoSetup,
                              want_jacobians: bool = False) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Unwhitened residual (m,) in pixels and, when asked, ``[J_root, J_trans, J_body_pose, J_betas]``."""
    if want_jacobians:
        jac = model.point_jacobians(state.full_pose, state.betas, state.trans)
        points = np.asarray(jac.points, dtype=np.float64)
        jac = _Leading(jac)
    else:                                    # residual only: the keypoints without their Jacobians
        jac = None
        points = np.asarray(_keypoints(model, state), dtype=np.float64)
    return stereo_reprojection_batch(points[None], [setup], jac)[0]


class _Leading:
    """A single frame's point Jacobians seen with a leading batch dimension of 1."""

    def __init__(self, jac):
        for name in ("d_root", "d_trans", "d_body_pose", "d_betas"):
            setattr(self, name, np.asarray(getattr(jac, name))[None])


def make_stereo_reprojection_factor(keys: FrameKeys | Sequence[int], model: BodyModelLike, measurement: StereoKeypoints,
                                    calibration: StereoCalibration, sigma_px: float = 2.0,
                                    sigma_occluded_px: float = 6.0, keypoint_weights: np.ndarray | None = None,
                                    robust: str = "gemanmcclure", robust_scale: float = 3.0,
                                    min_depth: float = 0.1) -> gtsam.CustomFactor | None:
    """Stereo keypoint reprojection factor on ``keys = [root, trans, body_pose, betas]``.

    Returns ``None`` when no keypoint is labelled (with weight > 0) in either image.  ``sigma_px`` /
    ``sigma_occluded_px`` in pixels; ``robust_scale`` in whitened units (sigmas).
    """
    setup = build_stereo_setup(measurement, calibration, sigma_px, sigma_occluded_px, keypoint_weights, min_depth)
    if setup.rows == 0:
        return None
    rows = setup.rows
    cache = getattr(model, "term_cache", None)
    if cache is not None:
        cache.register("stereo_reprojection", frame_key_list(keys), StereoTerm(setup, robust, float(robust_scale)))

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        hit = None if cache is None else cache.lookup("stereo_reprojection", this.keys(), values, H is not None)
        if hit is not None:
            r, blocks = hit
        else:
            state = read_frame_state(values, this.keys())
            r, blocks = stereo_reprojection_error(model, state, setup, H is not None)
        if H is not None:
            set_jacobians(H, blocks, rows, [ROOT_DIM, TRANS_DIM, BODY_POSE_DIM, np.shape(blocks[3])[1]])
        return r

    noise = make_noise(setup.sigmas, robust=robust, robust_scale=robust_scale)
    return gtsam.CustomFactor(noise, frame_key_list(keys), error)
