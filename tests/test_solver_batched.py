"""The batched evaluation path of the batch LM equals GTSAM's own evaluation of the same graph.

* the term cache (:class:`BatchedBodyModel`) serves a factor only at exactly the prefetched values;
* :class:`ChainLayout` + :func:`solve_chain` give GTSAM's damped Gauss-Newton step;
* :class:`BatchedLinearizer` gives ``graph.error`` and the chain system of ``graph.linearize``;
* the batched body-model, mixture, stereo and temporal functions equal their per-frame versions.
"""
from __future__ import annotations

import gtsam
import numpy as np
import pytest

from factors.stereo_reprojection import StereoKeypoints, build_stereo_setup, stereo_reprojection_batch
from factors.temporal_prior import temporal_prior_batch, temporal_prior_error
from factor_testing import make_test_calibration, random_rot3
from pedx_graph.graph.build import build_track_graph
from pedx_graph.solvers.batched import BatchedLinearizer
from pedx_graph.solvers.chain import ChainLayout, NotAChainError, solve_chain
from pedx_graph.solvers.lm import python_lm
from solver_fixtures import synthetic_config, synthetic_context, synthetic_track


@pytest.fixture(scope="module")
def problem_and_point():
    ctx = synthetic_context()
    track, _ = synthetic_track(ctx, num_frames=6, seed=3)
    problem = build_track_graph(track, ctx, synthetic_config())
    rng = np.random.default_rng(0)
    values = gtsam.Values(problem.initial)
    for k in problem.keys:                       # a generic point: every variable away from its start
        values.update(k.root, values.atRot3(k.root).compose(gtsam.Rot3.Expmap(rng.normal(scale=0.05, size=3))))
        values.update(k.trans, values.atVector(k.trans) + rng.normal(scale=0.05, size=3))
        values.update(k.body_pose, values.atVector(k.body_pose) + rng.normal(scale=0.1, size=69))
    betas_key = problem.keys[0].betas
    values.update(betas_key, rng.normal(scale=0.3, size=values.atVector(betas_key).shape[0]))
    return ctx, track, problem, values


def _assert_systems_equal(a, b, rtol=1e-9):
    for name in ("frame", "next", "frame_shape", "shape", "grad_frame", "grad_shape"):
        x, y = getattr(a, name), getattr(b, name)
        scale = max(np.abs(y).max(), 1e-12)
        np.testing.assert_allclose(x, y, rtol=0, atol=rtol * scale, err_msg=name)


def test_chain_solve_equals_gtsam_damped_step(problem_and_point):
    _, _, problem, values = problem_and_point
    linear = problem.graph.linearize(values)
    layout = ChainLayout(problem.keys, values.atVector(problem.keys[0].betas).shape[0])
    lam = 0.3
    delta = layout.to_vector_values(*solve_chain(layout.assemble(linear), lam))
    damped = linear.clone()
    for key in values.keys():
        d = values.zeroVectors().at(key).shape[0]
        damped.add(gtsam.JacobianFactor(key, np.sqrt(lam) * np.eye(d), np.zeros(d), gtsam.noiseModel.Unit.Create(d)))
    reference = damped.optimize()
    for key in values.keys():
        np.testing.assert_allclose(delta.at(key), reference.at(key), atol=1e-10 * max(1.0, np.abs(reference.at(key)).max()))


def test_layout_rejects_a_factor_linking_distant_frames(problem_and_point):
    _, _, problem, _ = problem_and_point
    layout = ChainLayout(problem.keys, 10)
    k0, k2 = problem.keys[0], problem.keys[2]
    with pytest.raises(NotAChainError):
        layout.segments((int(k0.trans), int(k2.trans)))


def _fresh(track, ctx, kinds_dropped=()):
    """The same track's graph built again, never prefetched, its term cache switched off: every factor's
    callback computes its own residual and Jacobians (``calls`` counts the refused look-ups)."""
    fresh = build_track_graph(track, ctx, synthetic_config())
    if kinds_dropped:
        fresh = fresh.without(kinds_dropped)
    calls = []
    fresh.body.lookup = lambda *args, **kwargs: calls.append(args[0])       # always None: never served
    return fresh, calls


def _random_point(problem, seed):
    """Random non-identity values: every root a random rotation, translations, body poses and betas random."""
    rng = np.random.default_rng(seed)
    values = gtsam.Values(problem.initial)
    for k in problem.keys:
        values.update(k.root, random_rot3(rng, max_angle=2.5))
        values.update(k.trans, values.atVector(k.trans) + rng.normal(scale=0.1, size=3))
        values.update(k.body_pose, rng.normal(scale=0.3, size=69))
    key = problem.keys[0].betas
    values.update(key, rng.normal(scale=0.8, size=values.atVector(key).shape[0]))
    return values


@pytest.mark.parametrize("coarse", [False, True])
@pytest.mark.parametrize("seed", [0, 1])
def test_batched_linearizer_equals_a_fresh_gtsam_graph(problem_and_point, coarse, seed):
    """The batched linearizer's error and chain system equal GTSAM's linearisation of the same track built
    again and never prefetched (its factors compute their own rows), at random non-identity values."""
    ctx, track, full, _ = problem_and_point
    dropped = {"lidar_chamfer"} if coarse else set()
    problem = full.without(dropped) if coarse else full
    values = _random_point(problem, seed)
    lin = BatchedLinearizer(problem)
    served = sum(len(v) for v in lin.served.values())
    assert served >= 3 * len(problem.keys) - 1          # stereo, pose prior, temporal (+ chamfer) are batched
    err = lin.error(values)
    system = lin.system(values)
    fresh, calls = _fresh(track, ctx, dropped)
    reference_error = fresh.graph.error(values)
    reference = fresh.layout.assemble(fresh.graph.linearize(values))
    cached = sum(len(lin.served[k]) for k in ("stereo_reprojection", "lidar_chamfer", "pose_prior", "temporal_prior"))
    assert len(calls) == 2 * cached                     # error + linearize: every cached factor computed its rows
    assert err == pytest.approx(reference_error, rel=1e-10)
    _assert_systems_equal(system, reference)


def test_batched_linearizer_sees_a_changed_term(problem_and_point):
    """The comparison can fail: a reprojection noise that differs between the two graphs shows."""
    ctx, track, problem, _ = problem_and_point
    values = _random_point(problem, 2)
    config = synthetic_config()
    config.noise.keypoint_sigma_px *= 1.1
    other = build_track_graph(track, ctx, config)
    other.body.lookup = lambda *args, **kwargs: None
    lin = BatchedLinearizer(problem)
    assert lin.error(values) != pytest.approx(other.graph.error(values), rel=1e-3)


def test_batched_linearizer_with_active_joint_limits(problem_and_point):
    """Joint limits enter as diagonal information; some frames past a limit (knee and elbow bent backwards)."""
    from factors.joint_limits import DEFAULT_JOINT_LIMITS

    _, _, problem, point = problem_and_point
    values = gtsam.Values(point)
    for i in (1, 3, 4):
        k = problem.keys[i]
        pose = values.atVector(k.body_pose).copy()
        for lim in DEFAULT_JOINT_LIMITS[i % 2::2]:
            pose[lim.index] = lim.lower - 0.3 if lim.lower > -1.0 else lim.upper + 0.3
        values.update(k.body_pose, pose)
    lin = BatchedLinearizer(problem)
    assert lin.served["joint_limits"]
    assert lin.error(values) == pytest.approx(problem.graph.error(values), rel=1e-10)
    _assert_systems_equal(lin.system(values), problem.layout.assemble(problem.graph.linearize(values)))


def test_graph_built_from_an_earlier_init_is_the_same(problem_and_point):
    """build_track_graph(init=...) (the staged fit's second build) gives the graph built from scratch."""
    ctx, track, problem, values = problem_and_point
    again = build_track_graph(track, ctx, synthetic_config(), initial=values, init=problem.init)
    assert again.init is problem.init
    assert again.factor_kinds == problem.factor_kinds
    assert again.graph.error(values) == pytest.approx(problem.graph.error(values), rel=1e-12)


def test_term_cache_serves_only_the_prefetched_values(problem_and_point):
    ctx, track, problem, values = problem_and_point
    problem.prefetch(values, True)
    other = gtsam.Values(values)
    k = problem.keys[1]
    other.update(k.body_pose, other.atVector(k.body_pose) + 0.01)
    fresh = build_track_graph(track, ctx, synthetic_config())       # never prefetched: computes everything
    assert problem.graph.error(other) == pytest.approx(fresh.graph.error(other), rel=1e-12)
    assert problem.graph.error(values) == pytest.approx(fresh.graph.error(values), rel=1e-12)
    assert problem.body.lookup("pose_prior", [int(k.body_pose)], other, False) is None
    assert problem.body.lookup("pose_prior", [int(k.body_pose)], values, False) is not None


def test_lm_with_batched_linearizer_follows_the_plain_lm(problem_and_point):
    ctx, track, _, _ = problem_and_point
    config = synthetic_config()
    config.solver.max_iterations = 4
    a = build_track_graph(track, ctx, config)
    est_a, rep_a = python_lm(a.graph, a.initial, config.solver, a.prefetch, a.layout, BatchedLinearizer(a))
    b = build_track_graph(track, ctx, config)
    est_b, rep_b = python_lm(b.graph, b.initial, config.solver)       # GTSAM linearize + QR, no cache
    assert rep_a.iterations == rep_b.iterations
    np.testing.assert_allclose(rep_a.errors, rep_b.errors, rtol=1e-7)
    for k in a.keys:
        np.testing.assert_allclose(est_a.atRot3(k.root).matrix(), est_b.atRot3(k.root).matrix(), atol=1e-7)
        for key in (k.trans, k.body_pose, k.betas):
            np.testing.assert_allclose(est_a.atVector(key), est_b.atVector(key), atol=1e-7)


def _random_frames(seed: int, n: int):
    """The synthetic model, a generator and ``n`` random frames' pose (n, 72), betas and trans."""
    model = synthetic_context().model
    rng = np.random.default_rng(seed)
    return (model, rng, rng.normal(scale=0.3, size=(n, 72)), rng.normal(size=(n, model.num_betas)),
            rng.normal(size=(n, 3)))


def test_vertex_jacobians_per_frame_equal_single_frame_calls():
    n = 5
    model, rng, pose, betas, trans = _random_frames(4, n)
    ids = np.stack([rng.choice(model.num_vertices, 7, replace=False) for _ in range(n)])
    batch = model.vertex_jacobians_per_frame(pose, betas, trans, ids)
    for i in range(n):
        one = model.point_jacobians(pose[i], betas[i], trans[i], vertex_ids=ids[i])
        for name in ("points", "d_root", "d_body_pose", "d_trans", "d_betas"):
            np.testing.assert_allclose(getattr(batch, name)[i], getattr(one, name), atol=1e-12, err_msg=name)
    with pytest.raises(ValueError):
        model.vertex_jacobians_per_frame(pose, betas, trans, ids[:2])


def test_shared_jacobian_setup_gives_the_same_results():
    """point_jacobians / vertex_jacobians_per_frame / vertices_subset with a precomputed setup (or some of
    its frames) equal the calls that compute it themselves."""
    model, rng, pose, betas, trans = _random_frames(7, 4)
    setup = model.jacobian_setup(pose, betas)
    names = ("points", "d_root", "d_body_pose", "d_trans", "d_betas")
    for a, b in ((model.point_jacobians(pose, betas, trans, setup=setup), model.point_jacobians(pose, betas, trans)),
                 (model.point_jacobians(pose, betas, trans, vertex_ids=[3, 9], setup=setup),
                  model.point_jacobians(pose, betas, trans, vertex_ids=[3, 9]))):
        for name in names:
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    frames = np.array([0, 2, 3])
    ids = np.stack([rng.choice(model.num_vertices, 5, replace=False) for _ in frames])
    a = model.vertex_jacobians_per_frame(pose[frames], betas[frames], trans[frames], ids, setup=setup.rows(frames))
    b = model.vertex_jacobians_per_frame(pose[frames], betas[frames], trans[frames], ids)
    for name in names:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    subset = np.arange(0, model.num_vertices, 3)
    np.testing.assert_allclose(model.vertices_subset(pose, betas, trans, subset, kinematics=setup.kin),
                               model.vertices_subset(pose, betas, trans, subset), rtol=0, atol=1e-12)
    with pytest.raises(ValueError):
        model.point_jacobians(pose[:2], betas[:2], trans[:2], setup=setup)


def test_unique_per_frame_equals_np_unique():
    from factors.lidar_chamfer import unique_per_frame

    rng = np.random.default_rng(8)
    ids = [rng.integers(0, 50, size=m) for m in (1, 6, 12, 3)]
    counts, padded, local = unique_per_frame(ids, 50)
    assert padded.shape == (4, max(len(np.unique(x)) for x in ids))
    for n, x in enumerate(ids):
        u = np.unique(x)
        assert counts[n] == len(u)
        np.testing.assert_array_equal(padded[n, :len(u)], u)
        assert np.all(padded[n, len(u):] == u[0])
    np.testing.assert_array_equal(local, np.concatenate([np.searchsorted(np.unique(x), x) for x in ids]))


def test_mixture_and_temporal_batches_equal_single_calls():
    ctx = synthetic_context()
    rng = np.random.default_rng(5)
    from factors.common import MaxMixture
    k, d = 3, 6
    mix = MaxMixture(np.array([0.2, 0.5, 0.3]), rng.normal(size=(k, d)),
                     np.stack([np.linalg.cholesky(np.eye(d) * (i + 1)) for i in range(k)]))
    x = rng.normal(size=(9, d)) * 2
    r, best = mix.residual_batch(x)
    for i in range(len(x)):
        r1, j1, b1 = mix.residual(x[i], True)
        np.testing.assert_allclose(r[i], r1)
        assert best[i] == b1
        np.testing.assert_array_equal(mix.jacobian(best[i]), j1)
    p = 4
    rots = np.stack([gtsam.Rot3.Expmap(rng.normal(size=3)).matrix() for _ in range(2 * p)])
    tr = rng.normal(size=(2 * p, 3))
    bp = rng.normal(scale=0.2, size=(2 * p, 69))
    gaps = np.array([1, 2, 1, 3])
    rb, blocks = temporal_prior_batch(rots[:p], tr[:p], bp[:p], rots[p:], tr[p:], bp[p:], ctx.temporal_mixture,
                                      gaps, True)
    for i in range(p):
        r1, b1 = temporal_prior_error(rots[i], tr[i], bp[i], rots[p + i], tr[p + i], bp[p + i],
                                      ctx.temporal_mixture, int(gaps[i]), True)
        np.testing.assert_allclose(rb[i], r1, atol=1e-12)
        for a, b in zip(blocks, b1):
            np.testing.assert_allclose(a[i], b, atol=1e-12)


def test_stereo_batch_equals_single_frames():
    ctx = synthetic_context()
    model = ctx.model
    rng = np.random.default_rng(6)
    calib = make_test_calibration()
    setups = []
    for i in range(3):
        uv = rng.uniform(100, 900, size=(18, 2))
        uv[rng.choice(18, 4, replace=False)] = np.nan
        vis = rng.uniform(size=18) > 0.3
        meas = StereoKeypoints(uv, uv + [[-30.0, 0.0]], vis, vis)
        setups.append(build_stereo_setup(meas, calib, 2.0, 6.0))
    pose = rng.normal(scale=0.2, size=(3, 72))
    betas = rng.normal(size=(3, model.num_betas))
    trans = np.array([[8.0, 0.5, 0.0], [9.0, -0.5, 0.2], [12.0, 0.0, 0.1]])
    jac = model.point_jacobians(pose, betas, trans)
    batch = stereo_reprojection_batch(jac.points, setups, jac)
    for i in range(3):
        one = model.point_jacobians(pose[i], betas[i], trans[i])

        class Lead:
            pass
        lead = Lead()
        for name in ("d_root", "d_trans", "d_body_pose", "d_betas"):
            setattr(lead, name, np.asarray(getattr(one, name))[None])
        r1, b1 = stereo_reprojection_batch(np.asarray(one.points)[None], [setups[i]], lead)[0]
        np.testing.assert_allclose(batch[i][0], r1, atol=1e-9)
        for a, b in zip(batch[i][1], b1):
            np.testing.assert_allclose(a, b, atol=1e-9)


@pytest.mark.parametrize("per_point", [(True, False), (False, False)])
def test_chamfer_factors_served_factor_by_factor_equal_their_own_rows(per_point):
    """Chamfer factors whose noise settings differ (or that robustify per coordinate row) are evaluated by
    the term cache factor by factor: what it serves equals what each factor computes without the cache."""
    from factors.common import FrameKeys
    from factors.lidar_chamfer import make_lidar_chamfer_factor
    from pedx_graph.graph.batch import BatchedBodyModel

    ctx = synthetic_context()
    body = BatchedBodyModel(ctx.model)
    rng = np.random.default_rng(4)
    keys = [FrameKeys.for_frame(i) for i in range(2)]
    values = gtsam.Values()
    for i, k in enumerate(keys):
        values.insert(k.root, random_rot3(rng, max_angle=1.0))
        values.insert(k.trans, rng.normal(scale=0.5, size=3))
        values.insert(k.body_pose, rng.normal(scale=0.2, size=69))
    values.insert(keys[0].betas, rng.normal(scale=0.5, size=ctx.model.num_betas))
    factors, plain = [], []
    for i, (k, flag) in enumerate(zip(keys, per_point)):
        points = values.atVector(k.trans) + rng.normal(scale=0.3, size=(40, 3))
        kw = dict(sigma_m=0.03 * (i + 1), robust_per_point=flag)
        factors.append(make_lidar_chamfer_factor(k, body, points, **kw))
        plain.append(make_lidar_chamfer_factor(k, ctx.model, points, **kw))
    body.prefetch(values, keys, jacobians=True)
    assert body.batch("lidar_chamfer") == []                        # not one group: factor by factor
    for k in keys:
        assert body.lookup("lidar_chamfer", k.as_list(), values, True) is not None
    for cached, own in zip(factors, plain):
        a, b = cached.linearize(values), own.linearize(values)
        np.testing.assert_allclose(a.augmentedInformation(), b.augmentedInformation(), rtol=1e-10, atol=1e-9)
        assert cached.error(values) == pytest.approx(own.error(values), rel=1e-12)
