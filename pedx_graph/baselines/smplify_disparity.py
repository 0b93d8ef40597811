"""Baseline "SMPLify+disp" (paper Sec. V): a monocular per-frame body fit, placed metrically by disparity.

As the paper describes it: every frame on its own (no temporal term, no shared shape), the LEFT image's 2D
keypoints only, then scaled by stereo disparity because a monocular fit is scale-ambiguous.

Per frame, one small GTSAM graph over ``[root (Rot3), trans (3), body_pose (69), betas (10)]`` with

* ``factors.stereo_reprojection`` with the left labels only (``StereoKeypoints.from_views(left, None)``):
  ``r_k = project_left(world_p_k) - z_k`` pixels, per-row robust, occluded keypoints with a larger sigma;
* the GMM pose prior (``factors.pose_prior``, max-mixture) and joint limits (``factors.joint_limits``);
* the shape prior ``betas ~ N(0, shape_sigma^2 I)`` (``factors.shape_prior``).

No term fixes the depth: it comes only from the body's size in the image, as in SMPLify.  Like SMPLify the fit
starts upright with the translation from the torso's image length (``Z0 = f L_torso / l_torso``), first
solves the rigid placement (pose and shape held by tight priors), then everything; it tries the body facing
the camera and turned by each of ``yaw_candidates_deg`` and keeps the lowest final error.

**Metric placement.**  With ``J`` the keypoints visible in the left image that have a disparity ``d_k > 0``
(:func:`pedx_graph.baselines.left_disparity.disparity_depths`, ``Z_k = f b / d_k``), the fitted keypoints
are scaled about the left camera centre (rectified frame)::

    s = mean_J(Z_k) / mean_J(rect_z(fit_k)),      rect_p'_k = s rect_p_k

which leaves every left-image projection unchanged and puts the body at the disparity depth.  A frame
with no such keypoint keeps its monocular depth (``s = 1``, counted in ``frames_unscaled``).

**Output.**  ``world_keypoints`` (``keypoints_3d``) are the scaled keypoints (the evaluated quantity).
``pose`` is the frame's fit; ``trans`` is the fit's translation moved by the scaling of the hip midpoint
(the unscaled body placed where the scaled one is); the label ``betas`` are the track median of the
per-frame shapes, each frame's own shape is the extra field ``frame_betas``.  A frame that cannot be fitted
(fewer than ``min_keypoints`` left labels) gets the keypoints of the nearest fitted frame, moved as in
:func:`pedx_graph.baselines.triangulation.fill_missing_keypoints` (counted in ``frames_unfitted``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from factors.common import FrameKeys, MaxMixture
from factors.joint_limits import make_joint_limit_factor
from factors.pose_prior import make_pose_prior_factor
from factors.shape_prior import make_shape_prior_factor
from factors.stereo_reprojection import StereoKeypoints, make_stereo_reprojection_factor
from pedx_graph.baselines.left_disparity import DisparityLookup, back_project, disparity_depths
from pedx_graph.baselines.triangulation import (LHIP, NUM_KEYPOINTS, RHIP, SRC_DISPARITY, SRC_MISSING,
                                                fill_missing_keypoints)
from pedx_graph.data.types import StereoCalibration, Track, View2D
from pedx_graph.graph.config import SolverConfig
from pedx_graph.data.ground import GroundFrame
from pedx_graph.graph.init import world_R_body_from_yaw
from pedx_graph.keypoints import PEDX_KEYPOINTS
from pedx_graph.solvers.lm import python_lm

_IDX = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}
_TORSO = (_IDX["lsho"], _IDX["rsho"], _IDX["lhip"], _IDX["rhip"])
_ROBUST = {"geman_mcclure": "gemanmcclure", "gemanmcclure": "gemanmcclure", "huber": "huber",
           "cauchy": "cauchy", "none": "none"}


@dataclass
class SmplifyDispConfig:
    """Settings of the SMPLify+disp baseline (noise in physical units, defaults as the main estimator's)."""

    keypoint_sigma_px: float = 3.0
    """2D label noise of keypoints flagged visible, pixels."""
    occluded_keypoint_sigma_px: float = 12.0
    """2D label noise of keypoints labelled but not visible, pixels."""
    reprojection_loss: str = "geman_mcclure"
    """Robust loss per residual row: ``geman_mcclure``, ``huber``, ``cauchy`` or ``none``."""
    reprojection_loss_scale: float = 3.44
    """Scale of the robust loss in whitened units, on the length of a keypoint's 2D offset (as
    ``NoiseConfig.reprojection_loss_scale``)."""
    hip_sigma_factor: float = 2.0
    """Hip keypoints get this times the sigma (the model's hip joints sit inside the pelvis)."""
    joint_limit_sigma_rad: float = 0.05
    """Joint-limit hinge sigma, radians."""
    shape_sigma: float = 1.0
    """Shape prior ``betas ~ N(0, shape_sigma^2 I)``."""
    pose_prior_covariance_scale: float = 1.0
    """Multiplies every covariance of the pose GMM (> 1 weakens the prior)."""
    yaw_candidates_deg: tuple[float, ...] = (0.0, 180.0)
    """Initial headings tried, degrees relative to facing the camera (SMPLify tries the body and its flip)."""
    min_keypoints: int = 4
    """A frame needs at least this many left-image labels to be fitted."""
    default_depth_m: float = 15.0
    """Initial depth when neither the torso nor the keypoints' height span gives one, metres."""
    rigid_stage_sigma: float = 1e-3
    """Sigma of the priors holding pose and shape during the first (rigid placement) stage."""
    solver: SolverConfig = field(default_factory=lambda: SolverConfig(max_iterations=30))
    """Levenberg-Marquardt settings of each stage."""


@dataclass
class FrameFit:
    """Monocular fit of one frame (unscaled): world frame, metres."""

    pose: np.ndarray
    """(72,) axis-angle, root first."""
    betas: np.ndarray
    """(B,) the frame's own shape."""
    trans: np.ndarray
    """(3,) smplx translation."""
    world_keypoints: np.ndarray
    """(18, 3) keypoints of the fitted model."""
    initial_error: float
    final_error: float
    iterations: int
    yaw_candidate_deg: float


def _hip_weights(config: SmplifyDispConfig) -> np.ndarray:
    weights = np.ones(NUM_KEYPOINTS)
    weights[[LHIP, RHIP]] = 1.0 / config.hip_sigma_factor ** 2
    return weights


def initial_depth(model, calib: StereoCalibration, left: View2D, body_pose: np.ndarray,
                  default_depth_m: float) -> float:
    """SMPLify-style initial depth, metres: ``f L / l`` for a body length ``L`` (m) seen as ``l`` pixels.

    ``L`` is the torso length (shoulder midpoint to hip midpoint) of the model standing in ``body_pose``
    with betas 0, ``l`` its length in the left image; without the four torso labels, the vertical span of the
    labelled keypoints is compared with the same keypoints' span on the model.
    """
    kp = np.asarray(model.keypoints(np.concatenate([np.zeros(3), body_pose]), np.zeros(model.num_betas),
                                    np.zeros(3)), dtype=float)            # body frame: Y up
    uv = np.asarray(left.keypoints, dtype=float)
    f = calib.focal_px
    if np.all(left.labelled[list(_TORSO)]):
        body_len = np.linalg.norm(kp[list(_TORSO[:2])].mean(0) - kp[list(_TORSO[2:])].mean(0))
        image_len = np.linalg.norm(uv[list(_TORSO[:2])].mean(0) - uv[list(_TORSO[2:])].mean(0))
        if image_len > 2.0:
            return float(f * body_len / image_len)
    lab = left.labelled
    if lab.sum() >= 2:
        body_span = np.ptp(kp[lab, 1])
        image_span = np.ptp(uv[lab, 1])
        if image_span > 5.0 and body_span > 0.1:
            return float(f * body_span / image_span)
    return float(default_depth_m)


def _rect_to_world(calib: StereoCalibration, rect_p: np.ndarray) -> np.ndarray:
    world_T_rect = np.linalg.inv(calib.rect_T_world)
    return rect_p @ world_T_rect[:3, :3].T + world_T_rect[:3, 3]


def _build_graph(model, calib: StereoCalibration, left: View2D, keys: FrameKeys, mixture: MaxMixture,
                 config: SmplifyDispConfig, rigid_body_pose: np.ndarray | None) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    graph.add(make_stereo_reprojection_factor(
        keys, model, StereoKeypoints.from_views(left, None), calib, sigma_px=config.keypoint_sigma_px,
        sigma_occluded_px=config.occluded_keypoint_sigma_px, keypoint_weights=_hip_weights(config),
        robust=_ROBUST[config.reprojection_loss.lower()], robust_scale=config.reprojection_loss_scale))
    if rigid_body_pose is not None:       # stage 1: only root and trans move
        graph.add(gtsam.PriorFactorVector(keys.body_pose, rigid_body_pose,
                                          gtsam.noiseModel.Isotropic.Sigma(69, config.rigid_stage_sigma)))
        graph.add(make_shape_prior_factor(keys.betas, num_betas=model.num_betas, sigma=config.rigid_stage_sigma))
        return graph
    graph.add(make_pose_prior_factor(keys.body_pose, mixture=mixture))
    graph.add(make_joint_limit_factor(keys.body_pose, sigma_rad=config.joint_limit_sigma_rad))
    graph.add(make_shape_prior_factor(keys.betas, num_betas=model.num_betas, sigma=config.shape_sigma))
    return graph


def fit_frame_monocular(model, calib: StereoCalibration, left: View2D, mixture: MaxMixture,
                        template_body_pose: np.ndarray, config: SmplifyDispConfig | None = None, *,
                        ground: GroundFrame) -> FrameFit:
    """SMPLify-style fit of one frame to its left-image keypoints (see the module docstring); unscaled.
    ``ground``: the sequence's up axis and level frame (the candidate bodies stand upright in it)."""
    config = config or SmplifyDispConfig()
    if config.reprojection_loss.lower() not in _ROBUST:
        raise ValueError(f"unknown reprojection_loss {config.reprojection_loss!r}; choose one of {sorted(_ROBUST)}")
    uv = np.asarray(left.keypoints, dtype=float)
    lab = left.labelled
    if lab.sum() < config.min_keypoints:
        raise ValueError(f"only {int(lab.sum())} left keypoints labelled (need {config.min_keypoints})")
    template_body_pose = np.asarray(template_body_pose, dtype=float)
    depth = initial_depth(model, calib, left, template_body_pose, config.default_depth_m)
    anchor_set = np.zeros(NUM_KEYPOINTS, bool)
    anchor_set[[LHIP, RHIP]] = lab[[LHIP, RHIP]].all()
    if not anchor_set.any():
        anchor_set = lab.copy()
    target = back_project(calib, uv[anchor_set].mean(0, keepdims=True), np.array([depth]))[0]
    camera = np.linalg.inv(calib.rect_T_world)[:3, 3]
    towards_camera = camera - target
    level_towards = ground.level_directions(towards_camera)
    yaw_face = float(np.arctan2(level_towards[1], level_towards[0]))
    betas0 = np.zeros(model.num_betas)
    keys = FrameKeys.for_frame(0)
    best: FrameFit | None = None
    for yaw_deg in config.yaw_candidates_deg:
        world_R_body = world_R_body_from_yaw(yaw_face + np.deg2rad(yaw_deg), ground)
        pose0 = np.concatenate([gtsam.Rot3.Logmap(gtsam.Rot3(world_R_body)), template_body_pose])
        kp0 = np.asarray(model.keypoints(pose0, betas0, np.zeros(3)), dtype=float)
        values = gtsam.Values()
        values.insert(keys.root, gtsam.Rot3(world_R_body))
        values.insert(keys.trans, target - kp0[anchor_set].mean(0))
        values.insert(keys.body_pose, template_body_pose.copy())
        values.insert(keys.betas, betas0.copy())
        rigid = _build_graph(model, calib, left, keys, mixture, config, template_body_pose)
        values, rep1 = python_lm(rigid, values, config.solver)
        full = _build_graph(model, calib, left, keys, mixture, config, None)
        values, rep2 = python_lm(full, values, config.solver)
        if best is not None and rep2.final_error >= best.final_error:
            continue
        pose = np.concatenate([gtsam.Rot3.Logmap(values.atRot3(keys.root)), values.atVector(keys.body_pose)])
        betas = np.asarray(values.atVector(keys.betas), dtype=float)
        trans = np.asarray(values.atVector(keys.trans), dtype=float)
        best = FrameFit(pose=pose, betas=betas, trans=trans,
                        world_keypoints=np.asarray(model.keypoints(pose, betas, trans), dtype=float),
                        initial_error=float(rep1.initial_error), final_error=float(rep2.final_error),
                        iterations=rep1.iterations + rep2.iterations, yaw_candidate_deg=float(yaw_deg))
    assert best is not None, "yaw_candidates_deg must not be empty"
    return best


def disparity_scale(calib: StereoCalibration, world_keypoints: np.ndarray, depth: np.ndarray,
                    use: np.ndarray) -> float:
    """``s = mean(depth[use]) / mean(rect_z(world_keypoints[use]))``; 1 when ``use`` selects nothing."""
    if not np.any(use):
        return 1.0
    fitted = calib.world_to_rect(world_keypoints[use])[:, 2]
    return float(np.mean(depth[use]) / np.mean(fitted))


def scale_about_camera(calib: StereoCalibration, world_p: np.ndarray, scale: float) -> np.ndarray:
    """World points (..., 3) scaled by ``scale`` about the left camera centre (rectified frame)."""
    return _rect_to_world(calib, scale * calib.world_to_rect(world_p))


def smplify_disparity_baseline(track: Track, model, pose_mixture: MaxMixture,
                               template_body_pose: np.ndarray | None = None,
                               config: SmplifyDispConfig | None = None,
                               disparity: DisparityLookup | None = None):
    """Run SMPLify+disp on every frame of ``track``: a :class:`~pedx_graph.solvers.fit.TrackResult`.

    ``pose_mixture`` is the GMM pose prior (e.g. from ``pedx_graph.priors.load_pose_prior()``);
    ``template_body_pose`` (69,) the initial body pose (default: the mean of the mixture's cheapest
    component); ``disparity`` the disparity lookup (default: the labels' disparity).
    """
    from pedx_graph.solvers.fit import TrackResult

    config = config or SmplifyDispConfig()
    n = len(track.frames)
    if n == 0:
        raise ValueError(f"track {track.sequence}/{track.tracking_id} has no frames")
    if template_body_pose is None:
        template_body_pose = pose_mixture.means[int(np.argmin(pose_mixture.c))]
    t0 = time.perf_counter()
    nb = model.num_betas
    pose = np.zeros((n, 72))
    betas = np.full((n, nb), np.nan)
    trans = np.zeros((n, 3))
    keypoints = np.full((n, NUM_KEYPOINTS, 3), np.nan)
    per_frame: list[dict] = []
    fitted = np.zeros(n, bool)
    init_err = final_err = 0.0
    iterations = unscaled = 0
    for i, fr in enumerate(track.frames):
        info: dict = {"fitted": False}
        per_frame.append(info)
        if fr.left is None or fr.left.labelled.sum() < config.min_keypoints:
            continue
        calib = track.calibrations[fr.pair]
        fit = fit_frame_monocular(model, calib, fr.left, pose_mixture, template_body_pose, config,
                                  ground=track.ground)
        depth, source = disparity_depths(track, fr, disparity)
        use = source == SRC_DISPARITY
        scale = disparity_scale(calib, fit.world_keypoints, depth, use)
        unscaled += int(not use.any())
        keypoints[i] = scale_about_camera(calib, fit.world_keypoints, scale)
        hips_fit = fit.world_keypoints[[LHIP, RHIP]].mean(0)
        pose[i], betas[i] = fit.pose, fit.betas
        trans[i] = fit.trans + keypoints[i, [LHIP, RHIP]].mean(0) - hips_fit
        fitted[i] = True
        init_err += fit.initial_error
        final_err += fit.final_error
        iterations += fit.iterations
        info.update({"fitted": True, "disparity_scale": scale, "scale_keypoints": int(use.sum()),
                     "fit_error": fit.final_error, "fit_iterations": fit.iterations,
                     "yaw_candidate_deg": fit.yaw_candidate_deg, "frame_betas": fit.betas})
    if not fitted.any():
        raise ValueError(f"track {track.sequence}/{track.tracking_id}: no frame has {config.min_keypoints} "
                         "left-image keypoints to fit")
    if not fitted.all():
        source = np.where(fitted[:, None], 0, SRC_MISSING).astype(np.int8).repeat(NUM_KEYPOINTS, axis=1)
        keypoints, _ = fill_missing_keypoints(track, keypoints, source, model)
        done = np.flatnonzero(fitted)
        for i in np.flatnonzero(~fitted):
            j = int(done[np.argmin(np.abs(done - i) + 0.5 * (done > i))])
            pose[i], betas[i] = pose[j], betas[j]
            trans[i] = trans[j] + keypoints[i, [LHIP, RHIP]].mean(0) - keypoints[j, [LHIP, RHIP]].mean(0)
            per_frame[i]["filled_from_frame"] = int(track.frames[j].frame)
    extra_track = {"keypoints_only": False, "frames_fitted": int(fitted.sum()),
                   "frames_unfitted": int((~fitted).sum()), "frames_unscaled": int(unscaled)}
    return TrackResult(sequence=track.sequence, tracking_id=track.tracking_id,
                       frames=[fr.frame for fr in track.frames], pose=pose,
                       betas=np.median(betas[fitted], axis=0), trans=trans, world_keypoints=keypoints,
                       final_error=final_err, initial_error=init_err, iterations=iterations,
                       seconds=time.perf_counter() - t0, solver="baseline-smplify_disp",
                       extra_per_frame=per_frame, extra_track=extra_track)
