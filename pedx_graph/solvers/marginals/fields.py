"""The per-frame and per-track covariance fields written with a track's results (JSON output of marginals).

Keypoint covariances (metres^2, world frame): ``Sigma_k = J_k Sigma_i J_k^T`` with ``J_k = [d_root, d_trans,
d_body_pose, d_betas]`` (3, 75 + B) of keypoint k from ``BodyModel.point_jacobians`` (right perturbation of
the root, as the ``Rot3`` retraction).  A frame whose information needed the diffuse regulariser is
reported with ``covariance_status = "under_constrained"``; its covariances are written as null when any
standard deviation exceeds the limits of :class:`~pedx_graph.graph.config.MarginalsConfig`.

The keypoints are the reported ones, PedX's 18 of the model's ``report_model`` (a detector track's fit-layout
model has 18 + E keypoints of the set's own definitions: ``pedx_graph.detections.fit_layout``).
"""
from __future__ import annotations

import numpy as np

from factors.common import BODY_POSE_DIM
from pedx_graph.graph.config import MarginalsConfig
from pedx_graph.solvers.marginals.chain import POSE_SLICE, ROOT_SLICE, TRANS_SLICE, TrackMarginals


def _reported(model):
    """The model whose keypoints the results report (``BodyModel.report_model``; ``model`` itself without one)."""
    return getattr(model, "report_model", model)


def keypoint_covariances(model, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray,
                         frame_cov: np.ndarray) -> np.ndarray:
    """(18, 3, 3) covariances (m^2, world) of the reported keypoints of one frame from its joint marginal
    (75+B)^2."""
    jac = _reported(model).point_jacobians(np.asarray(pose, float), np.asarray(betas, float), np.asarray(trans, float))
    full = np.concatenate([np.asarray(jac.d_root), np.asarray(jac.d_trans), np.asarray(jac.d_body_pose),
                           np.asarray(jac.d_betas)], axis=-1)                 # (18, 3, 75 + B)
    return np.matmul(np.matmul(full, frame_cov), np.swapaxes(full, 1, 2))


def keypoint_covariances_batch(model, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray,
                               frame_covs: np.ndarray) -> np.ndarray:
    """(T, 18, 3, 3) keypoint covariances of T frames at once: pose (T, 72), betas (B,), trans (T, 3),
    joint marginals (T, 75 + B, 75 + B)."""
    pose = np.asarray(pose, float)
    betas_t = np.broadcast_to(np.asarray(betas, float), (len(pose), len(betas)))
    jac = _reported(model).point_jacobians(pose, betas_t, np.asarray(trans, float))
    full = np.concatenate([np.asarray(jac.d_root), np.asarray(jac.d_trans), np.asarray(jac.d_body_pose),
                           np.asarray(jac.d_betas)], axis=-1)                 # (T, 18, 3, 75 + B)
    return np.matmul(np.matmul(full, frame_covs[:, None]), np.swapaxes(full, -1, -2))


def frame_fields(model, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray, frame_cov: np.ndarray,
                 regularised: bool, config: MarginalsConfig, cov_keypoints: np.ndarray | None = None) -> dict:
    """The per-frame result fields: covariances of trans, root, body pose, keypoints, and a status
    (``cov_keypoints`` (18, 3, 3) when already computed)."""
    cov_trans = frame_cov[TRANS_SLICE, TRANS_SLICE]
    cov_root = frame_cov[ROOT_SLICE, ROOT_SLICE]
    sig_t = float(np.sqrt(max(np.max(np.linalg.eigvalsh(cov_trans)), 0.0)))
    sig_r = float(np.sqrt(max(np.max(np.linalg.eigvalsh(cov_root)), 0.0)))
    too_wide = sig_t > config.max_trans_sigma_m or sig_r > config.max_root_sigma_rad
    status = "under_constrained" if (regularised or too_wide) else "ok"
    if too_wide:
        return {"covariance_status": status, "cov_trans": None, "cov_root": None, "cov_body_pose": None,
                "cov_keypoints_3d": None, "sigma_trans_max_m": sig_t, "sigma_root_max_rad": sig_r}
    cov_pose = frame_cov[POSE_SLICE, POSE_SLICE]
    if config.body_pose_blocks:
        cov_pose = np.stack([cov_pose[3 * j:3 * j + 3, 3 * j:3 * j + 3] for j in range(BODY_POSE_DIM // 3)])
    return {"covariance_status": status, "cov_trans": cov_trans, "cov_root": cov_root,
            "cov_body_pose": cov_pose,
            "cov_keypoints_3d": (keypoint_covariances(model, pose, betas, trans, frame_cov)
                                 if cov_keypoints is None else cov_keypoints),
            "sigma_trans_max_m": sig_t, "sigma_root_max_rad": sig_r}


def marginals_to_fields(marginals: TrackMarginals, estimate, model,
                        config: MarginalsConfig | None = None) -> tuple[list[dict], dict]:
    """``(extra_per_frame, extra_track)`` for :class:`TrackResult` from computed marginals and the estimate
    (``estimate``: anything with ``pose (T, 72)``, ``betas (B,)``, ``trans (T, 3)``)."""
    config = config or MarginalsConfig()
    cov_kp = keypoint_covariances_batch(model, estimate.pose, estimate.betas, estimate.trans,
                                        marginals.frame_covariances)
    per_frame = [frame_fields(model, estimate.pose[i], estimate.betas, estimate.trans[i],
                              marginals.frame_covariances[i], bool(marginals.regularised[i]), config, cov_kp[i])
                 for i in range(len(estimate.pose))]
    n_bad = int(sum(f["covariance_status"] != "ok" for f in per_frame))
    track = {"cov_betas": marginals.shape_covariance, "marginals_method": marginals.method,
             "marginals_seconds": marginals.seconds, "marginals_under_constrained_frames": n_bad}
    return per_frame, track
