"""The staged LM solve of one track: coarse stage without the LiDAR chamfer, a screen for images of someone
else between the stages, full stage, a screen for left/right labels exchanged, limb depth-flip search when
the track needs it; a single frame from several headings."""
from __future__ import annotations

import dataclasses
from collections import defaultdict

import numpy as np

from pedx_graph.data.types import Track
from factors.stereo_reprojection import image_projection
from pedx_graph.graph.build import build_track_graph, extract_estimate, fitted_views
from pedx_graph.graph.config import FitConfig
from pedx_graph.graph.init import yaw_of
from pedx_graph.solvers.batched import BatchedLinearizer
from pedx_graph.solvers.flips import flip_search
from pedx_graph.solvers.lm import solve
from pedx_graph.solvers.mirror import mirror_screen


def coarse_stage_config(config: FitConfig) -> FitConfig:
    """The first stage's config: no LiDAR chamfer term, the stereo reprojection with
    ``solver.coarse_reprojection_loss``."""
    return dataclasses.replace(
        config, terms=dataclasses.replace(config.terms, lidar_chamfer=False),
        noise=dataclasses.replace(config.noise, reprojection_loss=config.solver.coarse_reprojection_loss))


def solve_staged(track: Track, ctx, config: FitConfig, yaw_override=None):
    """Solve in two stages, as the paper's staged fitting: first without the LiDAR chamfer term (its
    nearest-vertex correspondences only pull the right way once the body is roughly in place) and with the
    stereo reprojection's ``solver.coarse_reprojection_loss`` (graduated non-convexity), then with every
    term from that estimate; between the two, images of someone else (:func:`outlier_views`, confirmed by
    running the first stage again without them) are taken out of the track, recorded in
    ``report.dropped_views``; after the second stage, the left/right label screen
    (:mod:`pedx_graph.solvers.mirror`, ``noise.left_right_swap_prob``) and, where it exchanged labels back,
    the second stage again from its estimate, at most twice (``report.mirrored_labels``).  Then, for tracks at range
    walking towards or away from the camera, the limb
    depth-flip search (:mod:`pedx_graph.solvers.flips`, ``solver.flip_*``), which only ever lowers the
    error; tracks labelled in one camera per frame always get the search.  Returns (problem, values, report) of the final stage; the report's iterations and seconds
    cover every stage and the search, its initial error is the full graph's at the first stage's
    estimate, ``report.flips`` records the search (empty when it did not run)."""
    track, problem, values, report = _two_stages(track, ctx, config, yaw_override)
    # one camera per frame: a limb mirrored across the viewing ray projects the same at any range and
    # heading, so such tracks always get the search; with stereo only far tracks walking along the ray do
    one_camera = all(len(fr.labelled_views(config.terms.all_views)) <= 1 for fr in track.frames)
    if config.solver.flip_segments and len(track.frames) > 1 and (one_camera or (
            track_distance_m(track, problem.init) >= config.solver.flip_min_distance_m and
            heading_ray_angle_deg(track, problem.init) <= config.solver.flip_max_heading_angle_deg)):
        values, flips = flip_search(problem, values, track, ctx, config, solver_parts(problem, config))
        report.final_error = flips.final_error
        report.iterations += flips.iterations
        report.seconds += flips.seconds
        report.flips = dataclasses.asdict(flips)
    return problem, values, report


def track_distance_m(track: Track, init) -> float:
    """Median distance (m) of the track's initial body centres from their frames' left cameras."""
    centres = np.stack([track.calibrations[fr.pair].world_T_cam[:3, 3] for fr in track.frames])
    dist = np.linalg.norm(np.asarray(init.world_p_centre, float) - centres, axis=1)
    dist = dist[np.isfinite(dist)]
    return float(np.median(dist)) if dist.size else float("nan")


def heading_ray_angle_deg(track: Track, init) -> float:
    """Median angle (degrees, 0-90) between the trajectory heading and the ray from the camera to the body,
    both laid on the ground plane (``track.ground``'s level frame): 0 walking straight towards or away
    from the camera, 90 walking across.  NaN (no frame with a known heading) compares false with every
    threshold."""
    centres = np.stack([track.calibrations[fr.pair].world_T_cam[:3, 3] for fr in track.frames])
    ray = track.ground.level_directions(np.asarray(init.world_p_centre, float) - centres)[:, :2]
    yaw = np.asarray(init.heading_yaw, float)
    heading = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    cos = np.abs(np.sum(ray * heading, axis=1)) / np.linalg.norm(ray, axis=1)
    cos = cos[np.isfinite(cos)]
    return float(np.degrees(np.arccos(np.clip(np.median(cos), 0.0, 1.0)))) if cos.size else float("nan")


def _two_stages(track: Track, ctx, config: FitConfig, yaw_override=None):
    """The staged fit itself: (track, problem, values, report) as :func:`solve_staged` before the flip search;
    ``track`` without the images the screen dropped."""
    if not config.terms.lidar_chamfer:
        problem = build_track_graph(track, ctx, config, yaw_override=yaw_override)
        values, report = solve(problem.graph, problem.initial, config.solver, *solver_parts(problem, config))
        return _screened(track, ctx, config, problem, values, report)
    coarse_config = coarse_stage_config(config)
    coarse_solver = dataclasses.replace(config.solver, max_iterations=config.solver.coarse_max_iterations,
                                        relative_error_tol=config.solver.coarse_relative_error_tol)
    one_graph = coarse_config.noise.reprojection_loss == config.noise.reprojection_loss
    if one_graph:
        problem = build_track_graph(track, ctx, config, yaw_override=yaw_override)
        coarse = problem.without({"lidar_chamfer"})          # the same factors, the chamfer left out
    else:
        coarse = build_track_graph(track, ctx, coarse_config, yaw_override=yaw_override)
    coarse_values, coarse_report = solve(coarse.graph, coarse.initial, coarse_solver,
                                         *solver_parts(coarse, config))
    # an image of someone else attached to the track: taken out where the first stage, run again without it,
    # confirms it (the image still lies beyond the limit once it no longer pulls)
    suspects = outlier_views(track, view_residuals(track, ctx, coarse, coarse_values, config), config)
    dropped = []
    if suspects:
        def rebuilt(without, initial):
            """(full graph or None, first-stage graph) of the track without some images, from ``initial``."""
            if one_graph:
                full = build_track_graph(without, ctx, config, initial=initial, init=problem.init)
                return full, full.without({"lidar_chamfer"})
            return None, build_track_graph(without, ctx, coarse_config, initial=initial, init=coarse.init)

        trial = without_views(track, suspects)
        trial_problem, trial_coarse = rebuilt(trial, coarse_values)
        trial_values, again = solve(trial_coarse.graph, trial_coarse.initial, coarse_solver,
                                    *solver_parts(trial_coarse, config))
        coarse_report.iterations += again.iterations
        coarse_report.seconds += again.seconds
        after = view_residuals(track, ctx, trial_coarse, trial_values, config)
        confirmed = {(index, pair, side): z for (index, pair, side), z in suspects.items()
                     if any(p == pair and sd == side and z_after > config.solver.view_outlier_sigmas
                            for p, sd, z_after in after[index])}
        if confirmed:
            dropped = [{"frame": int(track.frames[index].frame), "pair": pair, "side": side,
                        "median_sigmas": round(float(z), 2)} for (index, pair, side), z in sorted(confirmed.items())]
            if len(confirmed) == len(suspects):
                track, full, coarse = trial, trial_problem, trial_coarse
            else:
                track = without_views(track, confirmed)
                full, coarse = rebuilt(track, trial_values)
            coarse_values = trial_values
            if one_graph:
                problem = full
    if one_graph:
        problem.initial = coarse_values
    else:
        problem = build_track_graph(track, ctx, config, initial=coarse_values, init=coarse.init)
    values, report = solve(problem.graph, problem.initial, config.solver, *solver_parts(problem, config))
    report.iterations += coarse_report.iterations
    report.seconds += coarse_report.seconds
    report.dropped_views = dropped
    return _screened(track, ctx, config, problem, values, report)


def _screened(track: Track, ctx, config: FitConfig, problem, values, report):
    """``(track, problem, values, report)`` after the left/right label screen (:mod:`pedx_graph.solvers.mirror`)
    at ``values``: where it exchanged labels back, the graph of the screened track solved again from
    ``values``, and screened once more (a body freed of one exchange can show another; at most two rounds);
    the report's iterations and seconds cover every solve, its initial error stays the first's;
    ``report.mirrored_labels`` records the exchanges in order."""
    mirrored = []
    for _ in range(2):
        track, found = mirror_screen(track, ctx, problem, values, config)
        if not found:
            break
        mirrored += found
        problem = build_track_graph(track, ctx, config, initial=values, init=problem.init)
        values, again = solve(problem.graph, problem.initial, config.solver, *solver_parts(problem, config))
        report.final_error = again.final_error
        report.iterations += again.iterations
        report.seconds += again.seconds
        report.converged = again.converged
        report.errors = list(report.errors) + list(again.errors)
    report.mirrored_labels = mirrored
    return track, problem, values, report


def view_residuals(track: Track, ctx, problem, values, config: FitConfig) -> list[list[tuple[str, str, float]]]:
    """Per frame, ``(pair, side, median whitened residual)`` of every image the graph fits at ``values``
    (:func:`~pedx_graph.graph.build.fitted_views`): the norm of
    each labelled keypoint's pixel error over its sigma (the label's own ``sigma_px``, else the config's
    ``noise.keypoint_sigma_px``), median over the image's keypoints."""
    est = extract_estimate(problem, values, ctx)
    betas = np.broadcast_to(est.betas, (len(est.pose), len(est.betas)))
    world_p = np.asarray(ctx.model.keypoints(est.pose, betas, est.trans))    # the label rows (a fit layout's too)
    default_sigma = float(config.noise.keypoint_sigma_px)
    out = []
    for i, frame in enumerate(track.frames):
        rows = []
        for pair, side, view in fitted_views(frame, config.terms):
            image_P_world = image_projection(track.calibrations[pair], side)
            hom = world_p[i] @ image_P_world[:, :3].T + image_P_world[:, 3]
            labelled = view.labelled & (hom[:, 2] > 0)
            if not labelled.any():
                continue
            sigma = np.full(len(view.keypoints), default_sigma)
            if view.sigma_px is not None:
                sigma = np.where(np.isfinite(view.sigma_px), view.sigma_px, default_sigma)
            error = np.linalg.norm(hom[labelled, :2] / hom[labelled, 2:3] - view.keypoints[labelled], axis=1)
            rows.append((pair, side, float(np.median(error / sigma[labelled]))))
        out.append(rows)
    return out


def outlier_views(track: Track, residuals: list[list[tuple[str, str, float]]], config: FitConfig
                  ) -> dict[tuple[int, str, str], float]:
    """``(frame index, pair, side) -> median whitened residual`` of the images that look like someone else's
    (:func:`view_residuals` per frame as ``residuals``): above ``solver.view_outlier_sigmas`` and above
    ``solver.view_outlier_ratio`` times the median of the frame's images within that limit; only in frames
    with at least two such images (with one, which of two images is someone else's is not told apart)."""
    limit = float(config.solver.view_outlier_sigmas)
    out = {}
    if not np.isfinite(limit):
        return out
    for index, rows in enumerate(residuals):
        fits = [z for _, _, z in rows if z <= limit]
        for pair, side, z in rows:
            if len(fits) >= 2 and z > limit and z > config.solver.view_outlier_ratio * float(np.median(fits)):
                out[index, pair, side] = z
    return out


def without_views(track: Track, views) -> Track:
    """The track without the given images (``(frame index, pair, side)``); a frame whose primary pair loses
    both images gets another of its pairs as primary (every frame keeps an image: callers never drop all)."""
    by_frame = defaultdict(set)
    for index, pair, side in views:
        by_frame[index].add((pair, side))
    frames = list(track.frames)
    for index, gone in by_frame.items():
        frame = frames[index]
        kept = {(pair, side): view for pair, side, view in frame.labelled_views() if (pair, side) not in gone}
        pairs = sorted({pair for pair, _ in kept}, key=lambda name: (name != frame.pair, name))
        other = {pair: (kept.get((pair, "left")), kept.get((pair, "right"))) for pair in pairs[1:]}
        frames[index] = dataclasses.replace(frame, pair=pairs[0], left=kept.get((pairs[0], "left")),
                                            right=kept.get((pairs[0], "right")), other_views=other)
    return dataclasses.replace(track, frames=frames)


def solver_parts(problem, config: FitConfig) -> tuple:
    """``(prefetch, layout, linearizer)`` for :func:`pedx_graph.solvers.lm.solve` as ``config.solver`` asks."""
    solver = config.solver
    if solver.linear_solver not in ("chain", "gtsam"):
        raise ValueError(f"solver.linear_solver must be 'chain' or 'gtsam', got {solver.linear_solver!r}")
    if solver.linearization not in ("batched", "graph"):
        raise ValueError(f"solver.linearization must be 'batched' or 'graph', got {solver.linearization!r}")
    layout = problem.layout if solver.linear_solver == "chain" else None
    linearizer = BatchedLinearizer(problem) if solver.linearization == "batched" and layout is not None else None
    return problem.prefetch, layout, linearizer


def single_frame_search(track: Track, ctx, config: FitConfig, n_headings: int = 8):
    """A single frame has no trajectory heading: start from the triangulated-torso heading and from
    ``n_headings`` evenly spaced headings, keep the solution of lowest final error."""
    base = build_track_graph(track, ctx, config)
    start = yaw_of(base.init.world_R_body[0], track.ground)
    candidates = [np.array([start])] + [
        np.array([yaw]) for yaw in np.linspace(-np.pi, np.pi, n_headings, endpoint=False)
        if abs(np.angle(np.exp(1j * (yaw - start)))) > 1e-3]
    best = None
    for yaw in candidates:
        problem, values, report = solve_staged(track, ctx, config, yaw_override=yaw)
        if best is None or report.final_error < best[2].final_error:
            best = (problem, values, report)
    return best

