"""Diagnostics and extra fields of a solved track: its residual tables and consistency
(:mod:`pedx_graph.solvers.residuals`), what each frame's information leaves poorly constrained, and
:func:`track_extras`, which gathers them with the marginal covariances and the body checks
(:mod:`pedx_graph.solvers.body_checks`) into the fields written beside the estimate.

Consistency of the fit, per frame: a frame with a factor the estimate contradicts (``inconsistent`` in the
residual tables) gets ``fit_consistent = False`` and ``inconsistent_terms`` (the kinds), so the Gaussian
covariance around that estimate is not to be trusted.  On the simulated benchmark scene these were the
frames of tracks at 35-45 m without LiDAR points whose heading converged 60-100 degrees off (heading prior
chi2 ~24 per frame, against <= 1.8 in every other frame): mean keypoint error 0.56-0.67 m.  The
covariances of such frames are still written.

The track summary (``extra_track["diagnostics"]``) repeats per frame the chi2 and outlier rows by kind and
the weak-direction figures below (``per_frame``), so a dataset builder can scan one file.

Weakest directions, per frame, from the joint marginal covariance of the frame with the shape
(:mod:`pedx_graph.solvers.marginals`):

* ``sigma_depth_m``, ``sigma_lateral_m``, ``sigma_vertical_m``: translation standard deviations in the
  sensor-ray frame (ground-plane direction from the LiDAR at the world origin to the pedestrian, its left,
  world up); ``sigma_heading_rad``: the root's rotation about world up (``e_z^T R Sigma_root R^T e_z``);
* ``weakest``: the eigenvector of the largest eigenvalue of the *normalised* covariance (root / 0.1 rad,
  translation / 0.05 m, body pose / 0.2 rad, shape / 0.5), reported as the share of each block in it
  (``root``, ``trans_depth``, ``trans_lateral``, ``trans_vertical``, ``body_pose``, ``shape``) and its
  normalised standard deviation.
"""
from __future__ import annotations

import logging

import gtsam
import numpy as np
from scipy.linalg import LinAlgError

from factors.translation_prior import sensor_ray_frame
from pedx_graph.data.ground import GroundFrame
from pedx_graph.graph.build import extract_estimate
from pedx_graph.graph.config import DiagnosticsConfig
from pedx_graph.solvers.body_checks import body_plausibility, is_monocular
from pedx_graph.solvers.marginals import (FRAME_DIM, POSE_SLICE, ROOT_SLICE, TRANS_SLICE, marginals_to_fields,
                                          problem_marginals)
from pedx_graph.solvers.residuals import residual_tables

log = logging.getLogger(__name__)


def weak_directions(frame_cov: np.ndarray, world_R_body: np.ndarray, world_p_pelvis: np.ndarray,
                    ground: GroundFrame, config: DiagnosticsConfig | None = None) -> dict:
    """Standard deviations along the viewing ray / heading and the weakest normalised direction (the ray
    from ``ground.world_p_sensor`` laid on the ground plane; heading = rotation about ``ground.world_up``)."""
    config = config or DiagnosticsConfig()
    cov_t = frame_cov[TRANS_SLICE, TRANS_SLICE]
    world_R_ray = sensor_ray_frame(world_p_pelvis, ground.world_p_sensor, ground.world_up)
    ray_cov = world_R_ray.T @ cov_t @ world_R_ray
    up_in_body = world_R_body.T @ ground.world_up                  # heading = rotation about the up axis
    var_heading = float(up_in_body @ frame_cov[ROOT_SLICE, ROOT_SLICE] @ up_in_body)
    nb = frame_cov.shape[0] - FRAME_DIM
    scale = np.concatenate([np.full(3, config.ref_root_rad), np.full(3, config.ref_trans_m),
                            np.full(69, config.ref_body_pose_rad), np.full(nb, config.ref_shape)])
    # translation expressed in the ray frame before normalising
    rot = np.eye(FRAME_DIM + nb)
    rot[TRANS_SLICE, TRANS_SLICE] = world_R_ray.T
    norm_cov = (rot @ frame_cov @ rot.T) / np.outer(scale, scale)
    evals, evecs = np.linalg.eigh(0.5 * (norm_cov + norm_cov.T))
    v = evecs[:, -1] ** 2
    share = {"root": float(v[ROOT_SLICE].sum()), "trans_depth": float(v[3]), "trans_lateral": float(v[4]),
             "trans_vertical": float(v[5]), "body_pose": float(v[POSE_SLICE].sum()),
             "shape": float(v[FRAME_DIM:].sum())}
    dominant = max(share, key=share.get)
    return {"sigma_depth_m": float(np.sqrt(max(ray_cov[0, 0], 0.0))),
            "sigma_lateral_m": float(np.sqrt(max(ray_cov[1, 1], 0.0))),
            "sigma_vertical_m": float(np.sqrt(max(ray_cov[2, 2], 0.0))),
            "sigma_heading_rad": float(np.sqrt(max(var_heading, 0.0))),
            "weakest": {"dominant": dominant, "normalised_sigma": float(np.sqrt(max(evals[-1], 0.0))),
                        "share": share}}


def track_diagnostics(problem, values: gtsam.Values, ctx=None, marginals=None,
                      config: DiagnosticsConfig | None = None, fit_config=None) -> tuple[list[dict], dict]:
    """``(extra_per_frame, extra_track)``: residual tables and, when covariances are available (``marginals``
    given, or ``ctx`` given so they can be computed), the weakest directions of every frame."""
    config = config or DiagnosticsConfig()
    per_frame_tables, track_table = residual_tables(problem, values, config, fit_config)
    per_frame = [{"residuals": t, "inconsistent_terms": sorted(k for k, v in t.items() if v["inconsistent"])}
                 for t in per_frame_tables]
    for f in per_frame:
        f["fit_consistent"] = not f["inconsistent_terms"]
    if marginals is None and ctx is not None:
        try:
            marginals = problem_marginals(problem, values, ctx)
        except Exception as exc:  # diagnostics never fail a track
            marginals = None
            track_table = dict(track_table)
            per_frame[0]["weak_directions_error"] = f"{type(exc).__name__}: {exc}"
    ground = getattr(problem, "ground", None)
    if marginals is not None and ctx is not None and ground is not None:
        betas = np.asarray(values.atVector(problem.keys[0].betas), float)
        pelvis_rest = ctx.model.rest_joints(betas)[0]
        for i, k in enumerate(problem.keys):
            rot = values.atRot3(k.root).matrix()
            pelvis = pelvis_rest + np.asarray(values.atVector(k.trans), float)
            per_frame[i]["weak_directions"] = weak_directions(marginals.frame_covariances[i], rot, pelvis, ground,
                                                              config)
    # frames ranked by chi2 per row (all kinds)
    scores = []
    for i, t in enumerate(per_frame_tables):
        rows = sum(v["rows"] for v in t.values())
        chi2 = sum(v["chi2"] for v in t.values())
        scores.append((chi2 / rows if rows else 0.0, i))
    worst = [{"frame_index": i, "chi2_per_row": s} for s, i in sorted(scores, reverse=True)[:config.worst_frames]]
    compact = []
    for i, f in enumerate(per_frame):
        row = {"frame_index": i,
               "chi2": {kind: v["chi2"] for kind, v in f["residuals"].items()},
               "outlier_rows": {kind: v["outlier_rows"] for kind, v in f["residuals"].items() if v["outlier_rows"]},
               "fit_consistent": f["fit_consistent"]}
        weak = f.get("weak_directions")
        if weak is not None:
            row.update({"sigma_depth_m": weak["sigma_depth_m"], "sigma_lateral_m": weak["sigma_lateral_m"],
                        "sigma_heading_rad": weak["sigma_heading_rad"], "weakest": weak["weakest"]["dominant"]})
        compact.append(row)
    summary = {"residuals": track_table, "worst_frames": worst,
               "outlier_rows": int(sum(v["outlier_rows"] for v in track_table.values())),
               "inconsistent_frames": int(sum(not f["fit_consistent"] for f in per_frame)),
               "per_frame": compact}
    if marginals is not None:
        sb = marginals.shape_covariance
        summary["shape_sigma_max"] = float(np.sqrt(max(np.max(np.linalg.eigvalsh(sb)), 0.0)))
    return per_frame, {"diagnostics": summary}


def track_extras(problem, values: gtsam.Values, ctx, marginals: bool = True, diagnostics: bool = True,
                 marginals_config=None, diagnostics_config: DiagnosticsConfig | None = None, fit_config=None,
                 frames=None) -> tuple[list[dict], dict]:
    """Marginal covariances and diagnostics of one solved track, sharing one marginals computation:
    ``(extra_per_frame, extra_track)`` ready for :class:`~pedx_graph.solvers.result.TrackResult`.  The body
    plausibility fields (:func:`body_plausibility`) are always computed (per frame when ``marginals`` or
    ``diagnostics``, else from the rest pose); ``frames`` (the track's
    :class:`~pedx_graph.data.types.TrackFrame` list) adds the ``monocular`` flag."""
    if fit_config is not None:                  # the fit's config sections unless given explicitly
        marginals_config = marginals_config or fit_config.marginals
        diagnostics_config = diagnostics_config or fit_config.diagnostics_thresholds
    per_frame: list[dict] = [{} for _ in problem.keys]
    track: dict = {}
    est = extract_estimate(problem, values, ctx)
    checks, track_checks = body_plausibility(ctx.model, est.pose, est.betas, per_frame=marginals or diagnostics)
    for f, g in zip(per_frame, checks):
        f.update(g)
    track.update(track_checks)
    if frames is not None:
        track["monocular"] = is_monocular(frames)
    computed = None
    if marginals or diagnostics:
        try:
            computed = problem_marginals(problem, values, ctx, marginals_config)
        except (RuntimeError, LinAlgError, ValueError) as exc:
            log.warning("marginals failed: %s", exc)
            track["marginals_error"] = f"{type(exc).__name__}: {exc}"
            for f in per_frame:
                f["covariance_status"] = "failed"
    if marginals and computed is not None:
        fields, track_fields = marginals_to_fields(computed, est, ctx.model, marginals_config)
        track.update(track_fields)
        for f, g in zip(per_frame, fields):
            f.update(g)
    if diagnostics:
        fields, track_fields = track_diagnostics(problem, values, ctx if computed is not None else None,
                                                 computed, diagnostics_config, fit_config)
        track.update(track_fields)
        for f, g in zip(per_frame, fields):
            f.update(g)
    return per_frame, track
