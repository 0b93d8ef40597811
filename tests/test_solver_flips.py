"""The limb depth-flip search: the mirror of a bone segment in depth, and the whole-track search that keeps a
mirror only when the graph's error drops."""
import copy
import dataclasses

import gtsam
import numpy as np
import pytest

from pedx_graph.body.lbs import batch_rigid_transform
from pedx_graph.body.rotation import exp_so3
from pedx_graph.graph.build import build_track_graph
from pedx_graph.solvers.fit import _solver_parts, heading_ray_angle_deg, solve_staged, track_distance_m
from pedx_graph.solvers.flips import SEGMENTS, flip_search, mirror_segment
from solver_fixtures import synthetic_config, synthetic_context, synthetic_track


def _joints(model, pose, betas, trans):
    rot = exp_so3(pose.reshape(len(pose), -1, 3))
    kin = batch_rigid_transform(rot, np.broadcast_to(model.rest_joints(betas), rot.shape[:-1]), model.parents)
    return kin.world_origin + trans[:, None]


def _random_state(model, n=5, seed=3):
    rng = np.random.default_rng(seed)
    pose = rng.normal(scale=0.4, size=(n, 72))
    betas = rng.normal(scale=0.5, size=model.num_betas)
    trans = rng.normal(scale=3.0, size=(n, 3)) + np.array([15.0, 0.0, 0.0])
    cameras = rng.normal(scale=1.0, size=(n, 3))
    return pose, betas, trans, cameras


@pytest.mark.parametrize("name", sorted(SEGMENTS))
def test_mirror_reflects_the_bone_in_the_plane_across_the_ray(name):
    ctx = synthetic_context()
    model = ctx.model
    pose, betas, trans, cameras = _random_state(model)
    parent, child = SEGMENTS[name]
    mirrored = mirror_segment(model, pose, betas, trans, cameras, (parent, child))
    before, after = _joints(model, pose, betas, trans), _joints(model, mirrored, betas, trans)
    # only the parent joint's rotation changes; the parent joint and everything outside its subtree stay
    changed = np.flatnonzero(np.any(np.abs(mirrored - pose) > 1e-12, axis=0))
    assert set(changed // 3) <= {parent}
    np.testing.assert_allclose(after[:, parent], before[:, parent], atol=1e-10)
    ray = before[:, parent] - cameras
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    bone = before[:, child] - before[:, parent]
    expected = bone - 2 * np.sum(bone * ray, axis=1, keepdims=True) * ray
    np.testing.assert_allclose(after[:, child] - after[:, parent], expected, atol=1e-9)
    # the mirror is an involution: mirroring twice gives back the same joints
    twice = mirror_segment(model, mirrored, betas, trans, cameras, (parent, child))
    np.testing.assert_allclose(_joints(model, twice, betas, trans), before, atol=1e-9)


def _solved_track(ctx, config):
    track, _ = synthetic_track(ctx, num_frames=4, seed=5, pixel_noise=0.5, distance_m=14.0)
    problem = build_track_graph(track, ctx, config)
    from pedx_graph.solvers.lm import solve

    values, _ = solve(problem.graph, problem.initial, config.solver, *_solver_parts(problem, config))
    return track, problem, values


def test_flip_search_undoes_a_mirrored_arm_and_never_raises_the_error():
    ctx = synthetic_context()
    config = synthetic_config()
    track, problem, solved = _solved_track(ctx, config)
    optimum = problem.graph.error(solved)
    # move the solution to the mirror basin of the right upper arm in every frame
    keys = problem.keys
    pose = np.stack([np.concatenate([gtsam.Rot3.Logmap(solved.atRot3(k.root)), solved.atVector(k.body_pose)])
                     for k in keys])
    trans = np.stack([solved.atVector(k.trans) for k in keys])
    betas = solved.atVector(keys[0].betas)
    cameras = np.stack([track.calibrations[fr.pair].world_T_cam[:3, 3] for fr in track.frames])
    wrong = mirror_segment(ctx.model, pose, betas, trans, cameras, SEGMENTS["right_upper_arm"])
    start = gtsam.Values(solved)
    for i, k in enumerate(keys):
        start.update(k.body_pose, np.ascontiguousarray(wrong[i, 3:]))
    assert problem.graph.error(start) > optimum + 1.0
    cfg = copy.deepcopy(config)
    cfg.solver.flip_segments = ("left_thigh", "right_upper_arm")
    values, report = flip_search(problem, start, track, ctx, cfg, _solver_parts(problem, cfg))
    assert report.tried == ["left_thigh", "right_upper_arm"]
    assert "right_upper_arm" in report.accepted
    assert report.final_error == pytest.approx(problem.graph.error(values))
    assert report.final_error <= optimum * (1 + 1e-3)
    # from the optimum itself nothing is accepted that raises the error
    values2, report2 = flip_search(problem, solved, track, ctx, cfg, _solver_parts(problem, cfg))
    assert report2.final_error <= optimum + 1e-9


def test_solve_staged_runs_the_search_only_for_tracks_walking_along_the_ray():
    ctx = synthetic_context()
    config = synthetic_config()
    config.solver.flip_min_distance_m = 0.0
    track, _ = synthetic_track(ctx, num_frames=4, seed=5, pixel_noise=0.5)
    problem, _, report = solve_staged(track, ctx, config)
    # the synthetic pedestrian walks along world +y, across the camera's +x view: angle ~90 degrees
    assert heading_ray_angle_deg(track, problem.init) > 60.0
    assert track_distance_m(track, problem.init) == pytest.approx(10.0, abs=1.0)
    assert report.flips == {}
    config.solver.flip_max_heading_angle_deg = 90.0
    config.solver.flip_segments = ("right_upper_arm",)
    _, values, report = solve_staged(track, ctx, config)
    assert report.flips["tried"] == ["right_upper_arm"]
    assert report.final_error == pytest.approx(report.flips["final_error"])
    unflipped = dataclasses.replace(config, solver=dataclasses.replace(config.solver, flip_segments=()))
    _, _, plain = solve_staged(track, ctx, unflipped)
    assert report.final_error <= plain.final_error + 1e-9
