"""iSAM2 (pedx_graph.solvers.isam) and the streaming estimator against batch LM on tiny synthetic tracks."""
import gtsam
import numpy as np
import pytest

from solver_fixtures import synthetic_config, synthetic_context, synthetic_track
from pedx_graph.graph.build import build_track_graph, extract_estimate
from pedx_graph.graph.config import SolverConfig
from pedx_graph.solvers.isam import IsamConfig
from pedx_graph.solvers.isam_batch import isam_solve
from pedx_graph.solvers.lm import gauss_newton_step, local_config, python_lm
from pedx_graph.solvers.marginals import gtsam_marginals, isam_frame_covariance

TIGHT = SolverConfig(max_iterations=100, relative_error_tol=1e-8)


@pytest.fixture(scope="module")
def ctx():
    return synthetic_context()


@pytest.fixture(scope="module")
def smooth_case(ctx):
    """4 frames, chamfer off (a single optimum: solver agreement is then well defined), batch LM solution."""
    config = synthetic_config(lidar_chamfer=False)
    track, truth = synthetic_track(ctx, 4, seed=0)
    problem = build_track_graph(track, ctx, config)
    values, report = python_lm(problem.graph, problem.initial, TIGHT)
    return problem, values, report, truth


def test_isam_with_lm_finalisation_equals_batch(ctx, smooth_case):
    problem, batch, report, _ = smooth_case
    values, isam_report, track = isam_solve(problem, IsamConfig(), TIGHT)
    a, b = extract_estimate(problem, batch, ctx), extract_estimate(problem, values, ctx)
    assert isam_report.final_error == pytest.approx(report.final_error, rel=1e-5)
    np.testing.assert_allclose(b.world_keypoints, a.world_keypoints, atol=1e-3)        # metres
    np.testing.assert_allclose(b.betas, a.betas, atol=1e-3)
    assert len(isam_report.update_seconds) == len(problem.keys)
    assert track.finalized and track.factors.size() == problem.graph.size()


def test_pure_isam_finalisation_reaches_batch_within_thresholds(ctx, smooth_case):
    problem, batch, report, _ = smooth_case
    values, isam_report, _ = isam_solve(problem, IsamConfig(finalize="isam"))
    assert isam_report.final_error <= report.final_error * 1.01
    a, b = extract_estimate(problem, batch, ctx), extract_estimate(problem, values, ctx)
    assert np.max(np.linalg.norm(a.world_keypoints - b.world_keypoints, axis=-1)) < 0.03      # measured 0.0197 m


def test_isam_marginals_equal_batch_marginals(smooth_case):
    problem, _, _, _ = smooth_case
    _, _, track = isam_solve(problem, IsamConfig(finalize="isam"))
    theta = track.isam.getLinearizationPoint()        # the Bayes tree is the graph linearised here
    batch = gtsam_marginals(problem.graph, theta, problem.keys, 10)
    for i, keys in enumerate(problem.keys):
        cov = isam_frame_covariance(track.isam, keys, 10)
        np.testing.assert_allclose(cov, batch.frame_covariances[i], rtol=1e-6,
                                   atol=1e-9 * np.abs(batch.frame_covariances[i]).max())
        np.testing.assert_allclose(track.isam.marginalCovariance(keys.trans),
                                   gtsam.Marginals(problem.graph, theta).marginalCovariance(keys.trans), rtol=1e-6)


def test_lm_over_free_keys_holds_the_others():
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    graph.add(gtsam.BetweenFactorVector(1, 2, np.array([1.0, 0.0]), noise))
    graph.add(gtsam.PriorFactorVector(2, np.array([5.0, 5.0]), noise))
    values = gtsam.Values()
    values.insert(1, np.zeros(2))
    values.insert(2, np.zeros(2))
    out, _ = python_lm(graph, values, local_config(10), free_keys=[2])
    np.testing.assert_allclose(out.atVector(1), [0.0, 0.0])
    np.testing.assert_allclose(out.atVector(2), [3.0, 2.5], atol=1e-4)     # midway: x1 + (1, 0) and (5, 5)


def test_gauss_newton_step_is_first_local_lm_iteration():
    """The cheap presolve step equals the first (accepted) iteration of LM over the free keys, held keys
    untouched."""
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 1.0)
    graph.add(gtsam.BetweenFactorVector(1, 2, np.array([1.0, 0.0]), noise))
    graph.add(gtsam.PriorFactorVector(2, np.array([5.0, 5.0]), noise))
    graph.add(gtsam.BetweenFactorVector(2, 4, np.array([1.0, 0.0]), noise))
    graph.add(gtsam.PriorFactorRot3(3, gtsam.Rot3.Rz(0.3), gtsam.noiseModel.Isotropic.Sigma(3, 0.5)))
    values = gtsam.Values()
    values.insert(1, np.zeros(2))
    values.insert(2, np.zeros(2))
    values.insert(3, gtsam.Rot3())
    values.insert(4, np.ones(2))
    lm, _ = python_lm(graph, values, local_config(1), free_keys=[2, 3])
    gn = gauss_newton_step(graph, values, [2, 3])
    np.testing.assert_allclose(gn.atVector(2), lm.atVector(2), atol=1e-9)
    np.testing.assert_allclose(gtsam.Rot3.Logmap(gn.atRot3(3)), gtsam.Rot3.Logmap(lm.atRot3(3)), atol=1e-9)
    np.testing.assert_allclose(gn.atVector(1), [0.0, 0.0])
    np.testing.assert_allclose(gn.atVector(4), [1.0, 1.0])
    values.insert(5, np.ones(3))                    # a free key no factor of the graph sees stays put
    gn = gauss_newton_step(graph, values, [2, 3, 5])
    np.testing.assert_allclose(gn.atVector(2), lm.atVector(2), atol=1e-9)
    np.testing.assert_allclose(gn.atVector(5), np.ones(3))


def test_presolve_methods_agree(ctx, smooth_case):
    problem, _, report, _ = smooth_case
    gn, gn_report, _ = isam_solve(problem, IsamConfig(finalize="isam", presolve_method="gn"))
    lm, lm_report, _ = isam_solve(problem, IsamConfig(finalize="isam", presolve_method="lm"))
    assert gn_report.final_error <= report.final_error * 1.01
    a, b = extract_estimate(problem, gn, ctx), extract_estimate(problem, lm, ctx)
    assert np.max(np.linalg.norm(a.world_keypoints - b.world_keypoints, axis=-1)) < 1e-9      # measured 1.6e-13 m
    with pytest.raises(ValueError, match="presolve_method"):
        isam_solve(problem, IsamConfig(presolve_method="newton"))


def test_shape_is_held_between_relinearisations(ctx):
    config = synthetic_config(lidar_chamfer=False)
    track, _ = synthetic_track(ctx, 3, seed=1)
    problem = build_track_graph(track, ctx, config)
    values, report, smoother = isam_solve(problem, IsamConfig(shape_relinearize_every=100, finalize="isam",
                                                              presolve_iterations=2))
    assert np.isfinite(report.final_error)
    assert all(u.seconds >= 0 for u in smoother.updates)
    with pytest.raises(RuntimeError, match="finalised"):
        smoother.add_frame(problem.keys[0], gtsam.NonlinearFactorGraph(), gtsam.Values())


def test_streaming_two_interleaved_tracks(ctx):
    from pedx_graph.solvers.stream import StreamConfig, StreamingEstimator

    config = synthetic_config()
    a, truth_a = synthetic_track(ctx, 4, seed=0)
    b, truth_b = synthetic_track(ctx, 3, seed=3, distance_m=13.0)
    b.tracking_id = "pedB"
    stream = StreamingEstimator(ctx, config, StreamConfig(track_timeout_s=0.05, causal_covariance=True),
                                sequence="synthetic")
    by_time = {}
    for tr in (a, b):
        for fr in tr.frames:
            by_time.setdefault(fr.timestamp, {})[tr.tracking_id] = fr
    # track b is seen at frames 0..2 only; a keeps going: b must end (timeout) before the stream does
    seen = []
    for ts in sorted(by_time):
        current = stream.add_frame(ts, by_time[ts], a.calibrations)
        seen.append(sorted(current))
        for est in current.values():
            assert est.world_keypoints.shape == (18, 3) and est.update_seconds >= est.isam_seconds > 0
            assert est.cpu_seconds > 0
            assert est.extra["cov_keypoints_3d"].shape == (18, 3, 3)
    assert seen[0] == sorted([a.tracking_id, "pedB"]) and seen[3] == [a.tracking_id]
    ended_early = stream.pop_finished()
    assert [r.tracking_id for r in ended_early] == ["pedB"]
    results = ended_early + stream.finish()
    assert sorted(r.tracking_id for r in results) == sorted([a.tracking_id, "pedB"])
    for r in results:
        truth = truth_a if r.tracking_id == a.tracking_id else truth_b
        mpjpe = np.linalg.norm(r.world_keypoints - truth["keypoints"], axis=-1).mean()
        assert mpjpe < 0.028                                # measured 0.013 / 0.019 m
        assert r.extra_track["stream_updates"] == len(r.frames)
        assert r.extra_per_frame[0]["covariance_status"] == "ok"
        assert np.asarray(r.extra_per_frame[0]["cov_keypoints_3d"]).shape == (18, 3, 3)
        assert "diagnostics" in r.extra_track
        labels = r.to_labels()
        assert len(labels) == len(r.frames)


def test_stream_dataset_writes_causal_and_smoothed_results(ctx, tmp_path):
    import argparse
    import json

    from pedx_graph.data.reader import read_smpl_labels
    from pedx_graph.data.writer import write_tracks
    from pedx_graph.solvers.stream import StreamConfig, stream_dataset
    from pedx_graph.solvers.stream_cli import register

    a, _ = synthetic_track(ctx, 3, seed=0)
    b, _ = synthetic_track(ctx, 2, seed=6, distance_m=12.0)
    b.tracking_id = "ped6"
    write_tracks(tmp_path / "data", [a, b])
    out = tmp_path / "results"
    summary = stream_dataset(tmp_path / "data", out, synthetic_config(), StreamConfig(), ctx=ctx)
    assert summary["total_frames"] == 5 and not summary["failed"]
    assert sorted(t["tracking_id"] for t in summary["tracks"]) == sorted([a.tracking_id, "ped6"])
    latency = summary["timings"]["update_ms"]          # times live in the summary's timings section only
    assert latency["median"] > 0 and latency["cpu_median"] > 0
    assert latency["isam_update_median"] <= latency["max"]
    smoothed = read_smpl_labels(out)
    causal = read_smpl_labels(out / "causal")
    assert sum(len(v) for v in smoothed.values()) == 5 and sum(len(v) for v in causal.values()) == 5
    on_disk = json.loads((out / "summary.json").read_text())
    assert on_disk["tracks"][0]["diagnostics"]["residuals"]
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["stream", "DATA", "--out", "OUT", "--causal-covariance"])
    assert args.causal_covariance and callable(args.func)


def test_stream_factors_match_batch_graph(ctx):
    """The streaming per-frame factors mirror build_track_graph (all kinds but the causal heading prior)."""
    from pedx_graph.solvers.stream import StreamConfig, StreamingEstimator

    config = synthetic_config()
    track, _ = synthetic_track(ctx, 4, seed=7)
    track.frames[1].world_lidar_points[:5] += np.array([3.0, 0.0, 0.0])      # background caught by the polygon
    problem = build_track_graph(track, ctx, config)
    stream = StreamingEstimator(ctx, config, StreamConfig(marginals=False, diagnostics=False))
    for fr in track.frames:
        stream.add_frame(fr.timestamp, {track.tracking_id: fr}, track.calibrations)
    state = stream.active[track.tracking_id]
    at = problem.initial

    def table(graph, kinds, frames):
        out = {}
        for j in range(graph.size()):
            if kinds[j] != "heading_prior":
                out[(kinds[j], frames[j])] = graph.at(j).error(at)
        return out

    batch = table(problem.graph, problem.factor_kinds, problem.factor_frames)
    streamed = table(state.smoother.factors, state.kinds, state.factor_frames)
    assert batch.keys() == streamed.keys()
    for key, value in batch.items():
        assert streamed[key] == pytest.approx(value, rel=1e-9, abs=1e-9), key


def test_stream_initial_body_pose_and_presolve_subset(ctx):
    """Constant joint-angle velocity from the two previous estimates (at most one step ahead); the presolve
    leaves the excluded kinds out."""
    from pedx_graph.solvers.stream import StreamConfig
    from pedx_graph.solvers.stream.estimator import presolve_factors
    from pedx_graph.solvers.stream.prediction import predicted_body_pose
    from pedx_graph.solvers.stream.state import ActiveTrack

    track, _ = synthetic_track(ctx, 3, seed=2)
    state = ActiveTrack(sequence="s", tracking_id="p", calibrations={}, smoother=None,
                        rng=np.random.default_rng(0), frames=list(track.frames))
    p0, p1 = np.zeros(69), np.full(69, 0.1)
    state.before_previous = (np.eye(3), np.zeros(3), p0, np.zeros(10))
    state.previous = (np.eye(3), np.zeros(3), p1, np.zeros(10))
    np.testing.assert_allclose(predicted_body_pose(state, 2), np.full(69, 0.2))
    state.frames[2].timestamp = state.frames[1].timestamp + 5 * (state.frames[1].timestamp - state.frames[0].timestamp)
    np.testing.assert_allclose(predicted_body_pose(state, 2), np.full(69, 0.2))     # capped at one step
    np.testing.assert_allclose(predicted_body_pose(state, 2, constant_velocity=False), p1)
    graph = gtsam.NonlinearFactorGraph()
    noise = gtsam.noiseModel.Isotropic.Sigma(1, 1.0)
    for j in range(3):
        graph.add(gtsam.PriorFactorVector(j, np.zeros(1), noise))
    exclude = StreamConfig().presolve_exclude
    sub = presolve_factors(graph, ["stereo_reprojection", "lidar_chamfer", "pose_prior"], exclude)
    assert sub.size() == 2 and list(sub.keyVector()) == [0, 2]
    assert presolve_factors(graph, ["stereo_reprojection", "pose_prior", "pose_prior"], exclude) is None


def test_streaming_holds_shape_and_old_frames(ctx):
    """While streaming, the shape keeps its first linearisation point (its estimate still moves) and only
    the newest ``relinearize_window`` frames are relinearised."""
    config = synthetic_config(lidar_chamfer=False)
    track, _ = synthetic_track(ctx, 6, seed=4)
    problem = build_track_graph(track, ctx, config)
    cfg = IsamConfig(relinearize_skip=1, relinearize_window=2, finalize="isam")
    from pedx_graph.solvers.isam import IncrementalTrack
    from pedx_graph.solvers.isam_batch import frame_factor_groups, initial_frame_values

    smoother = IncrementalTrack.create(cfg, betas_key=problem.keys[0].betas)
    groups = frame_factor_groups(problem)
    previous, points = None, []
    for i, keys in enumerate(problem.keys):
        smoother.add_frame(keys, groups[i], initial_frame_values(problem, i, previous))
        previous = smoother.frame_estimate(keys)
        theta = smoother.isam.getLinearizationPoint()
        if i == 0:
            betas0 = np.asarray(theta.atVector(keys.betas)).copy()
        np.testing.assert_array_equal(theta.atVector(keys.betas), betas0)
        points.append([np.asarray(theta.atVector(problem.keys[j].body_pose)).copy() for j in range(i + 1)])
    # frame j may be relinearised up to update j + 2 (window 2), never after
    relinearised_late = False
    for j in range(len(problem.keys)):
        for i in range(j + 3, len(problem.keys)):
            np.testing.assert_array_equal(points[i][j], points[j + 2][j])
        relinearised_late |= any(not np.array_equal(points[i][j], points[j][j]) for i in range(j + 1, min(j + 3, len(points))))
    assert relinearised_late                     # relinearisation does happen inside the window
    assert not np.allclose(smoother.frame_estimate(problem.keys[-1])[3], betas0)
    values = smoother.finalize()
    assert np.isfinite(problem.graph.error(values))


def test_frame_factors_enter_isam_linearised_and_are_relinearised_in_the_window():
    """A frame's own factors enter iSAM2 as one Gaussian factor at the presolved point; within the
    relinearisation window the point follows the estimate, after it never changes; finalising with iSAM2
    gives iSAM2 the nonlinear factors back."""
    from pedx_graph.solvers.isam import IncrementalTrack
    from pedx_graph.solvers.isam_batch import frame_factor_groups, initial_frame_values

    ctx = synthetic_context()
    track, _ = synthetic_track(ctx, 6, seed=5)
    problem = build_track_graph(track, ctx, synthetic_config(lidar_chamfer=False))
    smoother = IncrementalTrack.create(IsamConfig(relinearize_skip=1, relinearize_window=2, finalize="isam"),
                                       betas_key=problem.keys[0].betas)
    groups = frame_factor_groups(problem)
    previous, points, moved = None, [], False
    for i, keys in enumerate(problem.keys):
        smoother.add_frame(keys, groups[i], initial_frame_values(problem, i, previous))
        previous = smoother.frame_estimate(keys)
        assert [f.keys for f in smoother.linearized] == problem.keys[:i + 1]
        graph = smoother.isam.getFactorsUnsafe()
        for frame in smoother.linearized:
            assert isinstance(graph.at(frame.slot), gtsam.LinearContainerFactor)
        points.append([np.asarray(f.point.atVector(f.keys.body_pose)).copy() for f in smoother.linearized])
        for j in range(i - 2):                       # last in the window of 2 at update j + 2, then frozen
            np.testing.assert_array_equal(points[i][j], points[j + 2][j])
        moved |= any(not np.array_equal(points[i][j], points[i - 1][j]) for j in range(max(i - 2, 0), i))
    assert moved
    values = smoother.finalize()
    assert not smoother.linearized
    assert problem.graph.error(values) < problem.graph.error(problem.initial)


def test_stream_sample_drops_only_its_bad_observation(ctx):
    """The pedestrians of a sample go through the steps together: one that cannot be placed is dropped
    (its new track forgotten), the others get the same estimates as when streamed alone."""
    import dataclasses

    from pedx_graph.solvers.stream import StreamConfig, StreamingEstimator

    config = synthetic_config()
    a, _ = synthetic_track(ctx, 3, seed=0)
    b, _ = synthetic_track(ctx, 3, seed=3, distance_m=13.0)
    lost = dataclasses.replace(b.frames[0], left=None, right=None, world_lidar_points=np.zeros((0, 3)))
    together = StreamingEstimator(ctx, config, StreamConfig(marginals=False, diagnostics=False))
    alone = StreamingEstimator(ctx, config, StreamConfig(marginals=False, diagnostics=False))
    for j, fr in enumerate(a.frames):
        sample = {a.tracking_id: fr, "pedB": lost if j == 0 else b.frames[j]}
        current = together.add_frame(fr.timestamp, sample, a.calibrations)
        reference = alone.add_frame(fr.timestamp, {a.tracking_id: fr}, a.calibrations)
        assert sorted(current) == ([a.tracking_id] if j == 0 else sorted([a.tracking_id, "pedB"]))
        np.testing.assert_allclose(current[a.tracking_id].world_keypoints,
                                   reference[a.tracking_id].world_keypoints, atol=1e-9)
    assert len(together.active["pedB"].frames) == 2
