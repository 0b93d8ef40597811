"""Point-to-plane information of the LiDAR chamfer term in the marginal covariances (calibration, issue #5)."""
import numpy as np
import pytest

from solver_fixtures import synthetic_config, synthetic_context, synthetic_track
from factors.common import FrameState, group_robust_weights
from factors.lidar_chamfer import facing_margin, nearest_vertices
from pedx_graph.graph.build import build_track_graph
from pedx_graph.graph.config import SolverConfig
from pedx_graph.solvers.lm import python_lm
from pedx_graph.solvers.marginals import (MarginalsConfig, TRANS_SLICE, chamfer_plane_rows, compute_marginals,
                                          vertex_normals)


@pytest.fixture(scope="module")
def ctx():
    return synthetic_context()


@pytest.fixture(scope="module")
def solved(ctx):
    track, _ = synthetic_track(ctx, 3, seed=4, lidar_points=40)
    config = synthetic_config()
    problem = build_track_graph(track, ctx, config)
    values, _ = python_lm(problem.graph, problem.initial, SolverConfig(max_iterations=30))
    problem.prefetch(values, True)
    return track, config, problem, values


def test_plane_rows_equal_normal_projection_of_matched_vertices(ctx, solved):
    """The rows decoded from the linearised factor equal |M n| n^T J_v computed from the points directly."""
    track, config, problem, values = solved
    linear = problem.graph.linearize(values)
    rows = chamfer_plane_rows(linear, values, problem.keys, problem.factor_kinds, ctx.model)
    chamfer = [j for j, kind in enumerate(problem.factor_kinds) if kind == "lidar_chamfer"]
    assert chamfer and sorted(rows) == chamfer
    sigma, scale = config.noise.lidar_sigma_m, config.noise.lidar_loss_scale
    betas = np.asarray(values.atVector(problem.keys[0].betas))
    for j in chamfer:
        i = problem.factor_frames[j]
        k = problem.keys[i]
        pts = np.asarray(track.frames[i].world_lidar_points)
        assert len(pts) <= config.noise.lidar_max_points          # every point enters, in order
        state = FrameState.from_arrays(values.atRot3(k.root).matrix(), values.atVector(k.trans),
                                       values.atVector(k.body_pose), betas)
        sensor = track.ground.world_p_sensor if config.noise.lidar_seen_side else None
        margin = facing_margin(pts, track.ground.world_p_sensor, config.noise.lidar_viewpoint_offset_m,
                               np.radians(config.noise.lidar_normal_tolerance_deg))
        ids, verts = nearest_vertices(ctx.model, state, pts, ctx.chamfer_vertex_ids, sensor, margin)
        posed = np.asarray(ctx.model.forward(state.full_pose, betas, state.trans).vertices)
        n = vertex_normals(posed, np.asarray(ctx.model.faces))[ids]
        r = (verts - pts) / sigma
        g, h = group_robust_weights(np.linalg.norm(r, axis=1), config.noise.lidar_loss.replace("_", ""), scale)
        weight = (g[:, None, None] * np.eye(3) + h[:, None, None] * r[:, :, None] * r[:, None, :]) / sigma
        jac = ctx.model.point_jacobians(state.full_pose, betas, state.trans, vertex_ids=ids)
        jv = np.concatenate([jac.d_root, jac.d_trans, jac.d_body_pose, jac.d_betas], axis=-1)
        expected = (np.linalg.norm(np.einsum("mij,mj->mi", weight, n), axis=1)[:, None]
                    * np.einsum("mi,min->mn", n, jv))
        assert rows[j].shape == (len(pts), jv.shape[-1])
        np.testing.assert_allclose(rows[j], expected, atol=1e-6 * np.abs(expected).max())


def test_point_to_plane_widens_translation_and_keeps_point_to_point_on_request(ctx, solved):
    _, _, problem, values = solved
    kwargs = dict(factor_kinds=problem.factor_kinds, model=ctx.model)
    plane = compute_marginals(problem.graph, values, problem.keys, **kwargs)
    point = compute_marginals(problem.graph, values, problem.keys,
                              MarginalsConfig(chamfer_information="point_to_point"), **kwargs)
    bare = compute_marginals(problem.graph, values, problem.keys)      # no kinds: linearisation as is
    np.testing.assert_allclose(point.frame_covariances, bare.frame_covariances, rtol=1e-9, atol=1e-15)
    for cp, cq in zip(plane.frame_covariances, point.frame_covariances):
        vp, vq = np.trace(cp[TRANS_SLICE, TRANS_SLICE]), np.trace(cq[TRANS_SLICE, TRANS_SLICE])
        assert vp > 1.2 * vq                      # tangential sliding is no longer counted as information
        assert np.linalg.eigvalsh(cp).min() > 0


def test_undecodable_factor_keeps_its_linearisation(ctx, solved):
    """A factor mislabelled as chamfer (the stereo term) does not decode to mesh vertices: left as is."""
    _, _, problem, values = solved
    linear = problem.graph.linearize(values)
    kinds = ["lidar_chamfer" if kind == "stereo_reprojection" else "other" for kind in problem.factor_kinds]
    assert "lidar_chamfer" in kinds
    assert chamfer_plane_rows(linear, values, problem.keys, kinds, ctx.model) == {}


def test_unknown_chamfer_information_is_rejected(ctx, solved):
    _, _, problem, values = solved
    with pytest.raises(ValueError):
        compute_marginals(problem.graph, values, problem.keys, MarginalsConfig(chamfer_information="nope"),
                          factor_kinds=problem.factor_kinds, model=ctx.model)


@pytest.mark.parametrize("information", ["point_to_plane", "point_to_point"])
def test_batched_marginals_equal_the_linearised_graph_path(ctx, solved, information):
    """From the batched linearizer (matched vertices from the term cache, no callbacks) the covariances equal
    those of the GTSAM linearisation (matched vertices decoded from the Jacobian)."""
    from pedx_graph.solvers.marginals import problem_linearizer

    _, _, problem, values = solved
    config = MarginalsConfig(chamfer_information=information)
    kwargs = dict(factor_kinds=problem.factor_kinds, model=ctx.model)
    linearizer = problem_linearizer(problem)
    assert linearizer is not None and linearizer.served["lidar_chamfer"]
    fast = compute_marginals(problem.graph, values, problem.keys, config, linearizer=linearizer, **kwargs)
    slow = compute_marginals(problem.graph, values, problem.keys, config, **kwargs)
    scale = np.abs(slow.frame_covariances).max()
    np.testing.assert_allclose(fast.frame_covariances, slow.frame_covariances, rtol=0, atol=1e-7 * scale)
