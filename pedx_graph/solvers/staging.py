"""The staged LM solve of one track: coarse stage without the LiDAR chamfer, full stage, limb depth-flip
search when the track needs it; a single frame from several headings."""
from __future__ import annotations

import dataclasses

import numpy as np

from pedx_graph.data.types import Track
from pedx_graph.graph.build import build_track_graph
from pedx_graph.graph.config import FitConfig
from pedx_graph.graph.init import yaw_of
from pedx_graph.solvers.batched import BatchedLinearizer
from pedx_graph.solvers.flips import flip_search
from pedx_graph.solvers.lm import solve


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
    term from that estimate.  Then, for tracks at range walking towards or away from the camera, the limb
    depth-flip search (:mod:`pedx_graph.solvers.flips`, ``solver.flip_*``), which only ever lowers the
    error; tracks labelled in one camera per frame always get the search.  Returns (problem, values, report) of the final stage; the report's iterations and seconds
    cover every stage and the search, its initial error is the full graph's at the first stage's
    estimate, ``report.flips`` records the search (empty when it did not run)."""
    problem, values, report = _two_stages(track, ctx, config, yaw_override)
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
    """The staged fit itself: (problem, values, report) as :func:`solve_staged` before the flip search."""
    if not config.terms.lidar_chamfer:
        problem = build_track_graph(track, ctx, config, yaw_override=yaw_override)
        values, report = solve(problem.graph, problem.initial, config.solver, *solver_parts(problem, config))
        return problem, values, report
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
    if one_graph:
        problem.initial = coarse_values
    else:
        problem = build_track_graph(track, ctx, config, initial=coarse_values, init=coarse.init)
    values, report = solve(problem.graph, problem.initial, config.solver, *solver_parts(problem, config))
    report.iterations += coarse_report.iterations
    report.seconds += coarse_report.seconds
    return problem, values, report


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

