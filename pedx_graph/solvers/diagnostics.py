"""Diagnostics of a fitted track: where the residuals are, which rows the robust losses rejected, and what
each frame's information leaves poorly constrained.  Written to the summary to spot bad labels.

Residuals, per factor at the estimate (``r`` the unwhitened residual, ``Sigma^-1/2`` the base noise):

* ``chi2 = ||Sigma^-1/2 r||^2`` (whitened squared norm, without the robust kernel), summed per factor kind
  and per frame, with the number of rows, so ``chi2 / rows`` ~ 1 for a consistent measurement;
* ``cost`` = the factor's contribution to the graph error (with the robust kernel);
* ``outlier_rows`` = rows whose robust weight ``w(r_row) < outlier_weight`` (for Geman-McClure with scale c:
  ``|r_row| > c`` whitened), i.e. measurements the robust loss effectively switched off.

Consistency of the fit, per frame: a factor without a robust kernel (the heading prior, the pose and temporal
max-mixtures, the joint limits) whose ``chi2`` at the estimate exceeds the ``consistency_quantile`` (99.9 %)
quantile of ``chi2(rows)`` contradicts the estimate beyond what its own noise model allows, so the Gaussian
covariance around that estimate is not to be trusted: the frame gets ``fit_consistent = False`` and
``inconsistent_terms`` (the kinds).  On the simulated benchmark scene these were the frames of tracks at
35-45 m without LiDAR points whose heading converged 60-100 degrees off (heading prior chi2 ~24 per frame,
against <= 1.8 in every other frame): mean keypoint error 0.56-0.67 m.  Robust factors are not tested (their
outliers are rejected by design, ``outlier_rows``).  The covariances of such frames are still written.

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

Plausibility of the written bodies (every result, :func:`body_plausibility`; with covariances and
diagnostics both off, from the track's shape in the rest pose only): per frame ``mesh_signed_volume_m3``,
the signed volume of the posed mesh with
the model's faces oriented outward at rest (a negative volume is an inside-out, mirrored body: a large
negative first shape coefficient does that); per track ``inside_out_frames`` (frames with a volume <= 0),
``min_mesh_signed_volume_m3``, ``mesh_volume_ratio`` (the median volume over the volume of the mean shape
at rest) and ``max_abs_beta``.  ``monocular`` (:func:`is_monocular`): no frame of the track has keypoints in
two cameras and none has LiDAR points, so its depth rests on the body-size prior alone.
"""
from __future__ import annotations

from collections import defaultdict

import gtsam
import numpy as np

from factors.translation_prior import sensor_ray_frame
from pedx_graph.data.ground import GroundFrame
from pedx_graph.solvers.marginals import FRAME_DIM, POSE_SLICE, ROOT_SLICE, TRANS_SLICE
from pedx_graph.graph.config import DiagnosticsConfig


def _factor_residual(factor, values: gtsam.Values, outlier_weight: float,
                     in_factor_robust: tuple[str, float, int] | None = None) -> tuple[float, float, int, int, bool]:
    """(chi2, cost, rows, outlier rows, robust) of one nonlinear factor at ``values`` (``robust``: the factor
    has a robust kernel, in its noise model or inside).

    ``in_factor_robust = (kernel, scale, group)``: the factor applies the kernel itself to groups of
    ``group`` whitened rows (``factors.common.robustify_groups``, unit noise model), so its residual ``s``
    has ``0.5 |s_g|^2 = rho(|r_g|)``; a group is an outlier when ``rho(|r_g|) > rho(scale)`` (it lies beyond
    the kernel's scale, where Geman-McClure's weight drops below 1/4) and all its rows are counted.  For
    such factors ``chi2`` is the robustified ``|s|^2``.
    """
    cost = float(factor.error(values))
    if not hasattr(factor, "unwhitenedError"):
        return 2.0 * cost, cost, 0, 0, False
    r = np.asarray(factor.unwhitenedError(values), float).reshape(-1)
    model = factor.noiseModel()
    if isinstance(model, gtsam.noiseModel.Robust):
        base, kernel = model.noise(), model.robust()
    else:
        base, kernel = model, None
    white = np.asarray(base.whiten(r), float).reshape(-1)
    outliers = 0
    robust = kernel is not None or (in_factor_robust is not None
                                    and in_factor_robust[0].lower() not in ("none", ""))
    if kernel is not None:
        outliers = int(sum(kernel.weight(float(abs(x))) < outlier_weight for x in white))
    elif in_factor_robust is not None and in_factor_robust[0].lower() not in ("none", ""):
        from factors.common import group_robust_weights

        name, scale, group = in_factor_robust
        g_c, _ = group_robust_weights(np.array([scale]), name.replace("_", ""), scale)
        rho_c = 0.5 * float(g_c[0] * scale) ** 2
        if white.size % group == 0:
            rho = 0.5 * (white.reshape(-1, group) ** 2).sum(axis=1)
            outliers = int(group * np.count_nonzero(rho > rho_c))
    return float(white @ white), cost, int(r.size), outliers, robust


def in_factor_robust_kinds(fit_config) -> dict:
    """Factor kinds that robustify inside the factor: kind -> (kernel, scale, rows per group)."""
    if fit_config is None:
        return {}
    noise = fit_config.noise
    return {"lidar_chamfer": (noise.lidar_loss, float(noise.lidar_loss_scale), 3)}


def residual_tables(problem, values: gtsam.Values, config: DiagnosticsConfig | None = None,
                    fit_config=None) -> tuple[list[dict], dict]:
    """Per-frame and per-track residual totals by factor kind (see the module docstring).  ``fit_config``
    (:class:`FitConfig`) tells which kinds carry their robust kernel inside the factor."""
    from scipy.stats import chi2 as chi2_dist

    config = config or DiagnosticsConfig()
    inside = in_factor_robust_kinds(fit_config)
    n = len(problem.keys)

    def empty():
        return {"chi2": 0.0, "cost": 0.0, "rows": 0, "outlier_rows": 0, "inconsistent": 0}

    frames = [defaultdict(empty) for _ in range(n)]
    track = defaultdict(empty)
    for j in range(problem.graph.size()):
        factor = problem.graph.at(j)
        if factor is None:
            continue
        kind, frame = problem.factor_kinds[j], problem.factor_frames[j]
        chi2, cost, rows, outliers, robust = _factor_residual(factor, values, config.outlier_weight,
                                                              inside.get(kind))
        bad = int(not robust and rows > 0 and chi2 > chi2_dist.ppf(config.consistency_quantile, rows))
        targets = [track] + ([frames[frame]] if frame >= 0 else [])
        for t in targets:
            t[kind]["chi2"] += chi2
            t[kind]["cost"] += cost
            t[kind]["rows"] += rows
            t[kind]["outlier_rows"] += outliers
            t[kind]["inconsistent"] += bad
    return [dict(f) for f in frames], dict(track)


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
    from pedx_graph.solvers.marginals import problem_marginals

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
    ``(extra_per_frame, extra_track)`` ready for :class:`~pedx_graph.solvers.fit.TrackResult`.  The body
    plausibility fields (:func:`body_plausibility`) are always computed (per frame when ``marginals`` or
    ``diagnostics``, else from the rest pose); ``frames`` (the track's
    :class:`~pedx_graph.data.types.TrackFrame` list) adds the ``monocular`` flag."""
    import logging

    from scipy.linalg import LinAlgError

    from pedx_graph.graph.build import extract_estimate
    from pedx_graph.solvers.marginals import marginals_to_fields, problem_marginals

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
            logging.getLogger(__name__).warning("marginals failed: %s", exc)
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


# --- plausibility of the written bodies -----------------------------------------------------------------
def _signed_volumes(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Signed volumes (...,) of triangle meshes ``vertices`` (..., V, 3) with ``faces`` (F, 3), m^3: by the
    divergence theorem with the field (0, 0, z), ``sum_f (z_a + z_b + z_c) / 3 * n_z,f / 2`` with
    ``n_f = (b - a) x (c - a)`` (= the sum of ``a . (b x c) / 6`` for a closed mesh; positive when the faces
    wind counter-clockwise seen from outside).  Taken about the vertices' mean: translation-free."""
    lead = vertices.shape[:-2]
    centred = (vertices - vertices.mean(axis=-2, keepdims=True)).reshape((-1,) + vertices.shape[-2:])
    order = np.asarray(faces, dtype=np.int64).T.ravel()                   # a's, then b's, then c's
    num = len(centred)
    x, y, z = (centred[:, :, k][:, order].reshape(num, 3, -1) for k in range(3))
    n_z = (x[:, 1] - x[:, 0]) * (y[:, 2] - y[:, 0]) - (y[:, 1] - y[:, 0]) * (x[:, 2] - x[:, 0])
    return (np.einsum("nf,nf->n", z.sum(axis=1), n_z) / 6.0).reshape(lead)


def mesh_is_closed(faces: np.ndarray) -> bool:
    """Every edge of the triangle mesh ``faces`` (F, 3) is shared by exactly two faces: a closed surface, whose
    signed volume tells inside from outside (SMPL-format bodies are; a test model of random triangles is not)."""
    cached = _CLOSED_MESHES.get(id(faces))
    if cached is not None and cached[0] is faces:          # a model's faces, checked once per process
        return cached[1]
    key = faces
    faces = np.asarray(faces, dtype=np.int64)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    closed = bool(len(counts)) and bool(np.all(counts == 2))
    _CLOSED_MESHES[id(key)] = (key, closed)
    return closed


_CLOSED_MESHES: dict[int, tuple[np.ndarray, bool]] = {}


def _rest_orientation(model) -> tuple[float, float]:
    """``(sign, volume)``: the sign that makes the mean shape's rest mesh positive, and its volume, m^3."""
    rest = _signed_volumes(model.forward(np.zeros(72), np.zeros(model.num_betas)).vertices, model.faces)
    return (float(np.sign(rest)) or 1.0), abs(float(rest))


def mesh_signed_volumes(model, pose: np.ndarray, betas: np.ndarray, chunk: int = 32) -> np.ndarray:
    """Signed volume (T,) in m^3 of the posed mesh of each frame (``pose`` (T, 72), shared ``betas`` (B,)),
    with the model's faces oriented outward at rest: the sign is chosen so that the mean shape in the rest
    pose has a positive volume, whatever winding the model file uses.  Negative: the body is inside out.
    (The volume does not depend on the translation.)"""
    pose = np.asarray(pose, float).reshape(-1, 72)
    betas = np.asarray(betas, float)
    orientation, _ = _rest_orientation(model)
    out = np.empty(len(pose))
    for start in range(0, len(pose), chunk):
        part = pose[start:start + chunk]
        verts = model.forward(part, np.broadcast_to(betas, (len(part), betas.size))).vertices
        out[start:start + chunk] = orientation * _signed_volumes(verts, model.faces)
    return out


def body_plausibility(model, pose: np.ndarray, betas: np.ndarray, per_frame: bool = True
                      ) -> tuple[list[dict], dict]:
    """``(per_frame, track)`` plausibility fields of a fitted track (module docstring): the posed meshes'
    signed volumes, the count of inside-out frames, the volume relative to the mean shape's and the
    largest ``|beta_i|``.  An inside-out result is logged as a warning (it is a bug to fix).

    ``per_frame=False`` (a run with covariances and diagnostics off, timed as the solve alone: the posed
    meshes cost ~1-2 ms per frame) checks the track's shape in the rest pose instead (one mesh; a shape that
    turns the body inside out does so in every pose): ``mesh_check`` says which was done, the per-frame list
    is empty and ``inside_out_frames`` is all or none of the frames."""
    pose = np.asarray(pose, float).reshape(-1, 72)
    betas = np.asarray(betas, float)
    orientation, reference = _rest_orientation(model)
    if per_frame:
        volumes = mesh_signed_volumes(model, pose, betas)
    else:
        rest = model.forward(np.zeros(72), betas).vertices
        volumes = np.full(len(pose), orientation * float(_signed_volumes(rest, model.faces)))
    inside_out = int(np.count_nonzero(volumes <= 0.0))
    if inside_out:
        import logging

        logging.getLogger(__name__).warning("%d of %d fitted meshes are inside out (max |beta| %.1f)",
                                            inside_out, len(volumes), float(np.max(np.abs(betas))))
    frames = [{"mesh_signed_volume_m3": float(v)} for v in volumes] if per_frame else []
    track = {"mesh_check": "per_frame" if per_frame else "rest_pose", "inside_out_frames": inside_out,
             "mesh_closed": mesh_is_closed(model.faces),
             "min_mesh_signed_volume_m3": float(volumes.min()) if len(volumes) else float("nan"),
             "mesh_volume_ratio": float(np.median(volumes) / reference) if len(volumes) else float("nan"),
             "max_abs_beta": float(np.max(np.abs(betas))) if betas.size else 0.0}
    return frames, track


def _frame_camera_count(frame) -> int:
    """Cameras with at least one labelled keypoint at ``frame`` (every stereo pair's views when the frame
    lists them, else its left and right)."""
    views = frame.labelled_views() if hasattr(frame, "labelled_views") else \
        [(None, side, view) for side, view in (("left", frame.left), ("right", frame.right)) if view is not None]
    return sum(bool(np.any(view.labelled)) for _, _, view in views)


def is_monocular(frames, min_lidar_points: int = 3) -> bool:
    """True when no frame has keypoints in two cameras and none has ``min_lidar_points`` finite LiDAR points
    (the initialisation's threshold for a LiDAR centroid): the track's depth comes from body size alone."""
    for frame in frames:
        if _frame_camera_count(frame) >= 2:
            return False
        points = np.asarray(frame.world_lidar_points, dtype=float).reshape(-1, 3)
        if np.count_nonzero(np.all(np.isfinite(points), axis=1)) >= min_lidar_points:
            return False
    return True
