"""The error floor: the MPJPE an estimator with the graph's information would reach at the ground truth.

For every track of a simulated dataset the track's graph (simulator noise, Gaussian losses, the LiDAR points
that really lie on the person) is linearised at the true values; the chain marginals give each frame's
covariance, propagated to the 13 evaluated joints (``J Sigma J^T``), and the expected global and root-relative
errors follow by Monte Carlo (:func:`error_floor`).
"""
from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from pedx_graph.eval.metrics import eval_joints, eval_visibility, joint_errors, summarise
from pedx_graph.keypoints import EVAL_JOINTS, PEDX_KEYPOINTS

log = logging.getLogger(__name__)
_IDX = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}



def frame_visibility(track_frame) -> np.ndarray:
    """(18,) bool: labelled visible in the left or the right image (as :mod:`pedx_graph.eval.evaluate`)."""
    vis = np.zeros(len(PEDX_KEYPOINTS), dtype=bool)
    for view in (track_frame.left, track_frame.right):
        if view is not None:
            vis |= np.asarray(view.visible, dtype=bool) & view.labelled
    return vis


def eval_jacobian(full: np.ndarray) -> np.ndarray:
    """(..., 18, 3, D) keypoint Jacobians -> (..., 13, 3, D) of the evaluated joints (hip = mid-hips)."""
    out = []
    for name in EVAL_JOINTS:
        if name == "hip":
            out.append(0.5 * (full[..., _IDX["lhip"], :, :] + full[..., _IDX["rhip"], :, :]))
        else:
            out.append(full[..., _IDX[name], :, :])
    return np.stack(out, axis=-3)


def expected_errors(cov13: np.ndarray, truth13: np.ndarray, samples: int,
                    rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Expected per-joint errors (13,) in metres, (global, root-relative), of an estimate distributed as
    ``truth13 + N(0, cov13)``: ``E ||delta_j||`` and the root-relative error after the similarity alignment,
    by Monte Carlo with ``samples`` draws.  ``cov13`` (39, 39), ``truth13`` (13, 3)."""
    n = truth13.size
    cov = 0.5 * (cov13 + cov13.T)
    w, v = np.linalg.eigh(cov)
    root = v * np.sqrt(np.clip(w, 0.0, None))
    delta = (rng.normal(size=(samples, n)) @ root.T).reshape(samples, *truth13.shape)
    glob, rel = joint_errors(truth13[None] + delta, np.broadcast_to(truth13, delta.shape))
    return glob.mean(axis=0), rel.mean(axis=0)



def floor_fit_config(truth: str | os.PathLike, base=None):
    """The fit config of the floor: the estimator's terms with the simulator's noise (read from
    ``sim_config.yaml`` when present: 2D click noise, LiDAR range noise), Gaussian losses, no hip inflation."""
    import copy

    import yaml

    from pedx_graph.graph.config import FitConfig

    config = copy.deepcopy(base) if base is not None else FitConfig()
    sim_path = Path(truth) / "sim_config.yaml"
    labels, lidar = {}, {}
    if sim_path.is_file():
        data = yaml.safe_load(sim_path.read_text()) or {}
        labels, lidar = data.get("labels", {}), data.get("lidar", {})
    config.noise.keypoint_sigma_px = float(labels.get("visible_noise_px", 2.0))
    config.noise.occluded_keypoint_sigma_px = float(labels.get("occluded_noise_px", 8.0))
    config.noise.lidar_sigma_m = max(float(lidar.get("range_noise_m", 0.02)), 1e-3)
    config.noise.hip_sigma_factor = 1.0
    config.noise.reprojection_loss = "none"
    config.noise.lidar_loss = "none"
    return config


def _true_person_points(truth_root: Path, track, frame_index: int) -> np.ndarray:
    """The frame's segment points restricted to those really on the person (simulator truth), if known."""
    fr = track.frames[frame_index]
    path = truth_root / "truth" / track.sequence / f"{track.sequence}_{fr.frame:07d}.npz"
    if not path.is_file():
        return fr.world_lidar_points
    with np.load(path) as npz:
        key = f"segment_is_person__{track.tracking_id}"
        if key not in npz.files:
            return fr.world_lidar_points
        mask = np.asarray(npz[key], dtype=bool)
    if len(mask) != len(fr.world_lidar_points):
        return fr.world_lidar_points
    return fr.world_lidar_points[mask]


def smpl_values(keys, labels):
    """gtsam Values holding the SMPL parameters of ``labels`` (one per frame, same order as ``keys``):
    ``world_R_body = Exp(pose[:3])``, ``trans``, ``body_pose = pose[3:]``, the first label's ``betas``."""
    import gtsam

    values = gtsam.Values()
    values.insert(keys[0].betas, np.asarray(labels[0].betas, dtype=float))
    for k, lab in zip(keys, labels):
        values.insert(k.root, gtsam.Rot3.Expmap(np.asarray(lab.pose[:3], dtype=float)))
        values.insert(k.trans, np.asarray(lab.trans, dtype=float))
        values.insert(k.body_pose, np.asarray(lab.pose[3:], dtype=float))
    return values


def error_floor(truth: str | os.PathLike, fit_config=None, samples: int = 64, seed: int = 0,
                exact_segments: bool = True) -> dict:
    """Predicted MPJPE of an estimator with the graph's information at the ground truth.

    For every track of ``truth`` (a simulated dataset): the track's graph (:func:`floor_fit_config`:
    simulator noise, Gaussian losses; the LiDAR points restricted to the person's own points when
    ``exact_segments``) is linearised at the ground-truth values; the chain marginals give each frame's
    joint covariance ``Sigma_i`` (75 + B); the evaluated joints' covariance is ``J Sigma_i J^T`` (39, 39)
    with ``J`` the joints' Jacobian; the expected global and root-relative errors per joint follow by
    Monte Carlo (:func:`expected_errors`).  Frames whose information needed the diffuse regulariser
    (not observable) are left out and counted.  Returns the :func:`summarise` dict plus ``excluded_frames``.
    """
    import dataclasses

    from pedx_graph.data.reader import read_dataset, read_smpl_labels
    from pedx_graph.graph.build import EstimatorContext, build_track_graph
    from pedx_graph.solvers.marginals import compute_marginals

    truth_root = Path(truth)
    config = fit_config or floor_fit_config(truth_root)
    ctx = EstimatorContext.create(config)
    gt = read_smpl_labels(truth_root)
    rng = np.random.default_rng(seed)
    glob_all, rel_all, w_all, dist_all = [], [], [], []
    excluded = 0
    for track in read_dataset(truth_root):
        by_frame = {lab.frame: lab for lab in gt.get((track.sequence, track.tracking_id), [])}
        keep = [i for i, fr in enumerate(track.frames) if fr.frame in by_frame]
        if not keep:
            continue
        frames = [track.frames[i] for i in keep]
        if exact_segments:
            frames = [dataclasses.replace(fr, world_lidar_points=_true_person_points(truth_root, track, i))
                      for i, fr in zip(keep, frames)]
        sub = dataclasses.replace(track, frames=frames)
        labels = [by_frame[fr.frame] for fr in frames]
        problem = build_track_graph(sub, ctx, config)
        values = smpl_values(problem.keys, labels)
        problem.prefetch(values, True)
        marg = compute_marginals(problem.graph, values, problem.keys)
        pose = np.stack([lab.pose for lab in labels])
        trans = np.stack([lab.trans for lab in labels])
        betas = np.broadcast_to(np.asarray(labels[0].betas, float), (len(labels), len(labels[0].betas)))
        jac = ctx.model.point_jacobians(pose, betas, trans)
        full = np.concatenate([np.asarray(jac.d_root), np.asarray(jac.d_trans), np.asarray(jac.d_body_pose),
                               np.asarray(jac.d_betas)], axis=-1)                  # (T, 18, 3, 75 + B)
        j13 = eval_jacobian(full).reshape(len(labels), 39, -1)
        truth13 = eval_joints(np.asarray(jac.points))
        for i, fr in enumerate(frames):
            if marg.regularised[i]:
                excluded += 1
                continue
            cov13 = j13[i] @ marg.frame_covariances[i] @ j13[i].T
            g, r = expected_errors(cov13, truth13[i], samples, rng)
            glob_all.append(g)
            rel_all.append(r)
            w_all.append(eval_visibility(frame_visibility(fr)))
            pelvis = truth13[i][EVAL_JOINTS.index("hip")]
            dist_all.append(float(track.ground.horizontal_distance(pelvis)))
    if not glob_all:
        raise ValueError(f"{truth}: no frame with ground truth for the error floor")
    out = summarise(np.array(glob_all), np.array(rel_all), np.array(w_all), np.array(dist_all))
    out["excluded_frames"] = excluded
    out["samples_per_frame"] = samples
    out["noise"] = {"keypoint_sigma_px": config.noise.keypoint_sigma_px,
                    "occluded_keypoint_sigma_px": config.noise.occluded_keypoint_sigma_px,
                    "lidar_sigma_m": config.noise.lidar_sigma_m, "exact_segments": exact_segments}
    return out
