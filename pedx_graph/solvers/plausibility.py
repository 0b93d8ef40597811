"""Plausibility of a fitted track: refuse an estimate that no real pedestrian could be, before it is written.

:func:`check_track_result` runs on every solver's result (batch LM :func:`~pedx_graph.solvers.track_lm.fit_track`,
ADMM, the stream's smoothed tracks) and raises :class:`ImplausibleEstimateError` naming every check that failed;
the caller records the track as failed with that reason and writes nothing for it.  The checks, with the
thresholds of :class:`PlausibilityConfig`:

* ``non_finite``: a NaN or infinite pose, shape, translation, keypoint or final error.
* ``too_far``: the body centre (mean of its 18 keypoints) farther than ``max_distance_m`` (200 m) from the
  rig's viewpoint (``track.ground.world_p_sensor``) in some frame.  The labels' pedestrians are at 5-45 m;
  a LiDAR sees nothing of a pedestrian past ~100 m and a 12 MP camera makes one ~30 px tall at 200 m.
* ``behind_camera``: the body centre less than ``min_depth_m`` (0.5 m) in front of a camera whose image
  labels it at that frame (a labelled person is in front of the camera, and farther than an arm's length).
* ``shape_outside_prior``: a shape coefficient beyond the shape prior's support
  (``noise.shape_support_sd * noise.shape_sigma``, the hinge that holds ``|beta_i|`` within 3.5 prior SD)
  by more than ``shape_support_margin``: the hinge lets a strong pull end ~0.05 past the bound
  (``factors.shape_prior``), so 0.25 is a body the prior could not have produced.  Without a support term,
  ``max_abs_beta`` bounds it.
* ``inside_out``: a posed mesh with a non-positive signed volume (``inside_out_frames`` of
  :func:`~pedx_graph.solvers.body_checks.body_plausibility`): a mirrored body.  Judged only for a body model
  whose mesh is closed (``mesh_closed``; the volume of an open mesh has no sign to trust).
* ``inconsistent_residuals``: more than ``max_outlier_fraction`` (70 %) of the 2D keypoint rows
  (``stereo_reprojection``), or more than ``max_lidar_outlier_fraction`` (90 %) of the LiDAR rows
  (``lidar_chamfer``), rejected by the term's robust loss
  (``outlier_rows`` of :func:`~pedx_graph.solvers.residuals.residual_tables`: whitened residual past the
  loss scale, 3 sigma).  The robust losses exist to switch off a few bad clicks or points; when most of
  them are off, the measurements contradict each other and no body meets them (an extrinsic tens of metres
  off, labels of another person).  On the simulated benchmark scenes at most ~12 % of a term's rows are
  outliers as a rule, but a far or occluded pedestrian's polygon-cut segment can be mostly background (a
  legitimate track of the solver benchmark had 55 % of its chamfer rows rejected and a sound fit), so the
  LiDAR limit is high: a wrong extrinsic rejects 87-100 % of them.  The chi2 per row is not used: one absurd click (1e9 px) makes it 1e13 while the robust loss
  handles that click correctly.  A term with fewer than ``min_rows`` rows is not judged.

What was measured goes into ``result.extra_track["plausibility"]`` (written to the summary).
"""
from __future__ import annotations

import numpy as np

from pedx_graph.graph.config import PlausibilityConfig
from pedx_graph.solvers.residuals import residual_tables


class ImplausibleEstimateError(ValueError):
    """A fitted track is not a plausible pedestrian; ``reasons`` holds the failed checks' names (module
    docstring), the message says what was measured against which limit."""

    def __init__(self, sequence: str, tracking_id: str, reasons: list[tuple[str, str]]):
        self.reasons = [code for code, _ in reasons]
        self.sequence, self.tracking_id = sequence, tracking_id
        details = "; ".join(f"{code}: {text}" for code, text in reasons)
        super().__init__(f"track {sequence}/{tracking_id} is implausible ({details})")


#: Data terms whose robust losses reject outlier rows, judged by ``max_outlier_fraction``.
DATA_TERMS = ("stereo_reprojection", "lidar_chamfer")


def _shape_limit(config: PlausibilityConfig, fit_config) -> float:
    noise = getattr(fit_config, "noise", None)
    support = float(getattr(noise, "shape_support_sd", 0.0) or 0.0) * float(getattr(noise, "shape_sigma", 1.0))
    if 0.0 < support < np.inf:
        return support + config.shape_support_margin
    return config.max_abs_beta


def _residual_totals(result, fit_config, problem, values) -> dict | None:
    """Per-kind residual totals of the track: the diagnostics' when written, else computed when the solved
    problem is given, else None."""
    diagnostics = result.extra_track.get("diagnostics")
    if isinstance(diagnostics, dict) and isinstance(diagnostics.get("residuals"), dict):
        return diagnostics["residuals"]
    if problem is None or values is None:
        return None
    return residual_tables(problem, values, fit_config=fit_config)[1]


def _viewpoint(track) -> np.ndarray:
    if getattr(track, "ground", None) is not None:
        return np.asarray(track.ground.world_p_sensor, dtype=float)
    centres = [np.asarray(c.world_T_cam, float)[:3, 3] for c in track.calibrations.values()]
    return np.mean(centres, axis=0) if centres else np.zeros(3)


def check_track_result(result, track, fit_config=None, problem=None, values=None):
    """``result`` (a :class:`~pedx_graph.solvers.fit.TrackResult` of ``track``) when it is a plausible
    pedestrian, with ``extra_track["plausibility"]`` filled; :class:`ImplausibleEstimateError` naming every
    failed check otherwise (module docstring).  ``fit_config`` (:class:`~pedx_graph.graph.config.FitConfig`)
    gives the limits (``plausibility``) and the shape prior's support; ``problem`` / ``values`` (the solved
    graph) give the residuals when the result carries no diagnostics."""
    config = getattr(fit_config, "plausibility", None) or PlausibilityConfig()
    if not config.enabled:
        return result
    reasons: list[tuple[str, str]] = []
    record: dict = {}
    arrays = {"pose": result.pose, "betas": result.betas, "trans": result.trans,
              "keypoints": result.world_keypoints, "final_error": np.asarray(result.final_error, float)}
    bad = [name for name, value in arrays.items() if not np.all(np.isfinite(np.asarray(value, dtype=float)))]
    if bad:
        reasons.append(("non_finite", f"non-finite {', '.join(bad)}"))
    keypoints = np.asarray(result.world_keypoints, dtype=float).reshape(len(result.frames), -1, 3)
    with np.errstate(invalid="ignore"):
        centres = keypoints.mean(axis=1)                                      # (T, 3) body centres
    finite = np.all(np.isfinite(centres), axis=1)
    if finite.any():
        distance = np.linalg.norm(centres - _viewpoint(track), axis=1)
        far = int(np.argmax(np.where(finite, distance, -np.inf)))
        record["max_distance_m"] = float(distance[far])
        if distance[far] > config.max_distance_m:
            reasons.append(("too_far", f"the body is {distance[far]:.3g} m from the rig's viewpoint at frame "
                                       f"{result.frames[far]} (at most {config.max_distance_m:g} m)"))
        depths = []
        for centre, ok, frame in zip(centres, finite, track.frames):
            if not ok:
                continue
            for pair, side, _ in frame.labelled_views():
                depth = float(track.calibrations[pair].world_to_rect(centre)[2])
                depths.append(depth)
                if depth < config.min_depth_m and not any(code == "behind_camera" for code, _ in reasons):
                    reasons.append(("behind_camera", f"the body centre is at depth {depth:.3g} m in the {side} "
                                                     f"camera of {pair} that labels it at frame {frame.frame} "
                                                     f"(at least {config.min_depth_m:g} m in front)"))
        if depths:
            record["min_depth_m"] = float(min(depths))
    betas = np.asarray(result.betas, dtype=float)
    if betas.size and np.all(np.isfinite(betas)):
        limit = _shape_limit(config, fit_config)
        index = int(np.argmax(np.abs(betas)))
        record["max_abs_beta"] = float(abs(betas[index]))
        if abs(betas[index]) > limit:
            reasons.append(("shape_outside_prior", f"shape coefficient beta_{index} = {betas[index]:.3g} is "
                                                   f"beyond the shape prior's support (|beta| <= {limit:g})"))
    inside_out = result.extra_track.get("inside_out_frames")
    if inside_out and result.extra_track.get("mesh_closed", True):
        reasons.append(("inside_out", f"the body mesh is inside out in {inside_out} of {len(result.frames)} "
                                      f"frames"))
    totals = _residual_totals(result, fit_config, problem, values)
    if totals is not None:
        fractions = {}
        for kind in DATA_TERMS:
            entry = totals.get(kind)
            if not entry or not entry.get("rows"):
                continue
            rows, outliers = int(entry["rows"]), int(entry["outlier_rows"])
            fractions[kind] = outliers / rows
            limit = config.max_lidar_outlier_fraction if kind == "lidar_chamfer" else config.max_outlier_fraction
            if rows >= config.min_rows and outliers > limit * rows:
                reasons.append(("inconsistent_residuals",
                                f"{kind}: {outliers} of {rows} rows ({100 * outliers / rows:.0f} %) rejected as "
                                f"outliers by the robust loss (at most {100 * limit:g} %): "
                                f"the measurements cannot all be met (a wrong calibration?)"))
        record["outlier_fraction"] = fractions
    if reasons:
        raise ImplausibleEstimateError(result.sequence, result.tracking_id, reasons)
    result.extra_track["plausibility"] = record
    return result
