"""Marginal covariances (pedx_graph.solvers.marginals) and diagnostics on tiny synthetic tracks."""
import numpy as np
import pytest

from solver_fixtures import synthetic_config, synthetic_context, synthetic_track
from pedx_graph.graph.build import build_track_graph, extract_estimate
from pedx_graph.graph.config import SolverConfig
from pedx_graph.solvers.diagnostics import track_diagnostics, track_extras
from pedx_graph.solvers.lm import python_lm
from pedx_graph.solvers.marginals import (MarginalsConfig, compute_marginals, keypoint_covariances,
                                          track_marginals)


@pytest.fixture(scope="module")
def ctx():
    return synthetic_context()


@pytest.fixture(scope="module")
def solved(ctx):
    track, truth = synthetic_track(ctx, 4, seed=2)
    problem = build_track_graph(track, ctx, synthetic_config())
    values, _ = python_lm(problem.graph, problem.initial, SolverConfig(max_iterations=30))
    return problem, values, truth


def test_chain_marginals_equal_gtsam_marginals(solved):
    problem, values, _ = solved
    chain = compute_marginals(problem.graph, values, problem.keys)
    reference = compute_marginals(problem.graph, values, problem.keys, MarginalsConfig(method="gtsam"))
    assert chain.method == "chain" and reference.method == "gtsam"
    scale = np.abs(reference.frame_covariances).max()
    np.testing.assert_allclose(chain.frame_covariances, reference.frame_covariances, atol=1e-9 * scale)
    assert not chain.regularised.any()
    for cov in chain.frame_covariances:
        assert np.linalg.eigvalsh(cov).min() > 0


def test_keypoint_covariance_matches_sampling(ctx, solved):
    """Linear propagation vs Monte Carlo through the body model (small covariance: linear regime)."""
    import gtsam

    problem, values, _ = solved
    est = extract_estimate(problem, values, ctx)
    cov = compute_marginals(problem.graph, values, problem.keys).frame_covariances[1] * 1e-2
    analytic = keypoint_covariances(ctx.model, est.pose[1], est.betas, est.trans[1], cov)
    rng = np.random.default_rng(0)
    samples = rng.multivariate_normal(np.zeros(len(cov)), cov, size=4000)
    rot = gtsam.Rot3.Expmap(est.pose[1, :3])
    poses = np.stack([np.concatenate([gtsam.Rot3.Logmap(rot.compose(gtsam.Rot3.Expmap(s[:3]))),
                                      est.pose[1, 3:] + s[6:75]]) for s in samples])
    kps = ctx.model.keypoints(poses, est.betas + samples[:, 75:], est.trans[1] + samples[:, 3:6])
    empirical = np.stack([np.cov(kps[:, k].T) for k in range(18)])
    np.testing.assert_allclose(empirical, analytic, atol=0.1 * np.abs(analytic).max())


def test_track_marginals_fields(ctx, solved):
    problem, values, _ = solved
    per_frame, track = track_marginals(problem, values, ctx)
    assert len(per_frame) == len(problem.keys)
    first = per_frame[0]
    assert first["covariance_status"] == "ok"
    assert np.asarray(first["cov_trans"]).shape == (3, 3) and np.asarray(first["cov_root"]).shape == (3, 3)
    assert np.asarray(first["cov_body_pose"]).shape == (23, 3, 3)
    kp = np.asarray(first["cov_keypoints_3d"])
    assert kp.shape == (18, 3, 3) and np.all(np.linalg.eigvalsh(kp) > 0)
    assert np.asarray(track["cov_betas"]).shape == (10, 10)
    assert 0.001 < np.sqrt(np.asarray(first["cov_trans"])[0, 0]) < 0.2           # metres, 10 m away


def test_under_constrained_track_reports_and_carries_on(ctx):
    """One view, no LiDAR, no pose or temporal prior: body-pose directions have no information at all."""
    config = synthetic_config(lidar_chamfer=False, translation_prior=False, pose_prior=False,
                              temporal_prior=False, right_reprojection=False)
    track, _ = synthetic_track(ctx, 3, seed=4, with_lidar=False)     # right labels only initialise
    problem = build_track_graph(track, ctx, config)
    values, _ = python_lm(problem.graph, problem.initial, SolverConfig(max_iterations=5))
    per_frame, track_fields = track_marginals(problem, values, ctx)
    assert len(per_frame) == 3
    assert all(f["covariance_status"] in ("under_constrained", "failed") for f in per_frame)
    assert track_fields.get("marginals_under_constrained_frames", 3) == 3
    extras_frames, extras_track = track_extras(problem, values, ctx)        # diagnostics do not fail either
    assert len(extras_frames) == 3 and "diagnostics" in extras_track


def test_diagnostics_flag_a_bad_label(ctx):
    track, _ = synthetic_track(ctx, 4, seed=5)
    track.frames[2].left.keypoints[4] += np.array([60.0, -40.0])        # one wrong click, frame 2
    pts = track.frames[1].world_lidar_points
    pts[:4] += np.array([0.0, 0.0, 0.8])                                  # four mislabelled points, frame 1
    config = synthetic_config()
    problem = build_track_graph(track, ctx, config)
    values, _ = python_lm(problem.graph, problem.initial, SolverConfig(max_iterations=30))
    per_frame, track_fields = track_diagnostics(problem, values, ctx, fit_config=config)
    summary = track_fields["diagnostics"]
    assert per_frame[2]["residuals"]["stereo_reprojection"]["outlier_rows"] >= 1
    assert all(per_frame[i]["residuals"]["stereo_reprojection"]["outlier_rows"] == 0 for i in (0, 1, 3))
    chamfer = [per_frame[i]["residuals"]["lidar_chamfer"]["outlier_rows"] for i in range(4)]
    assert chamfer[1] >= 3 * 3 and chamfer[1] == max(chamfer)
    # chi2 without the kernels: the two frames holding the bad click and the bad points come first
    assert {w["frame_index"] for w in summary["worst_frames"][:2]} == {1, 2}
    weak = per_frame[0]["weak_directions"]
    assert weak["sigma_depth_m"] > 0 and weak["sigma_heading_rad"] > 0
    assert weak["weakest"]["dominant"] in weak["weakest"]["share"]


def test_batched_keypoint_covariances_equal_per_frame(ctx, solved):
    from pedx_graph.solvers.marginals import keypoint_covariances_batch

    problem, values, _ = solved
    est = extract_estimate(problem, values, ctx)
    covs = compute_marginals(problem.graph, values, problem.keys).frame_covariances
    batch = keypoint_covariances_batch(ctx.model, est.pose, est.betas, est.trans, covs)
    for i in range(len(covs)):
        np.testing.assert_allclose(batch[i], keypoint_covariances(ctx.model, est.pose[i], est.betas, est.trans[i],
                                                                  covs[i]), rtol=1e-10, atol=1e-14)
    linear = problem.graph.linearize(values)
    again = compute_marginals(problem.graph, values, problem.keys, linear=linear)
    np.testing.assert_allclose(again.frame_covariances, covs, rtol=1e-12, atol=1e-15)


def test_diagnostics_summary_lists_every_frame(ctx, solved):
    problem, values, _ = solved
    _, track_fields = track_diagnostics(problem, values, ctx)
    rows = track_fields["diagnostics"]["per_frame"]
    assert [r["frame_index"] for r in rows] == list(range(len(problem.keys)))
    assert "stereo_reprojection" in rows[0]["chi2"] and rows[0]["sigma_depth_m"] > 0
