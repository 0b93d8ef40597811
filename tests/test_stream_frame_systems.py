"""The streamed frames' own factors linearised in one batch per sample (pedx_graph.solvers.frame_system)
against GTSAM's linearisation of the same factors, and the stream with and without it."""
import dataclasses

import gtsam
import numpy as np
import pytest

from solver_fixtures import synthetic_config, synthetic_context, synthetic_track, with_views
from pedx_graph.solvers.frame_system import hessian_factor
from pedx_graph.solvers.isam import IncrementalTrack
from pedx_graph.solvers.stream import StreamConfig, StreamingEstimator


@pytest.fixture(scope="module")
def ctx():
    return synthetic_context()


def _tracks(ctx):
    a, truth = synthetic_track(ctx, 4, seed=0)
    a = with_views(a, truth, ("lrLR", "lr", "L", "lrR"))   # 4, 2, 1 and 3 images (both stereo pairs)
    b, _ = synthetic_track(ctx, 4, seed=3, distance_m=13.0, with_right=False)
    b.tracking_id = "pedB"
    for fr in b.frames:                      # background caught by the polygon: robust chamfer / translation
        fr.world_lidar_points[:5] += np.array([2.0, 0.5, 0.0])
    c, _ = synthetic_track(ctx, 4, seed=5, distance_m=8.0, with_lidar=False)
    c.tracking_id = "pedC"
    return [a, b, c]


def _augmented(factor, keys) -> np.ndarray:
    graph = gtsam.GaussianFactorGraph()
    graph.push_back(factor)
    ordering = gtsam.Ordering()
    for k in keys:
        ordering.push_back(k)
    return graph.augmentedHessian(ordering)


def _steps(ctx, config, frames_before: int, with_ground: bool = False):
    """The steps of sample ``frames_before`` of three tracks (after streaming the earlier samples), their
    values moved off the initial ones so that the robust kernels and joint limits are exercised;
    ``with_ground``: the sequence's ground plane is known (at the lowest LiDAR point of the first track)."""
    tracks = _tracks(ctx)
    ground = None
    if with_ground:
        up = tracks[0].ground.world_up
        ground = dataclasses.replace(tracks[0].ground,
                                     ground_offset_m=float(np.min(tracks[0].frames[0].world_lidar_points @ up)))
    est = StreamingEstimator(ctx, config, StreamConfig(marginals=False, diagnostics=False), ground=ground)
    for j in range(frames_before):
        est.add_frame(tracks[0].frames[j].timestamp, {t.tracking_id: t.frames[j] for t in tracks},
                      tracks[0].calibrations)
    ts = tracks[0].frames[frames_before].timestamp
    steps = [est._begin(ts, t.tracking_id, t.frames[frames_before], t.calibrations) for t in tracks]
    rng = np.random.default_rng(1)
    for s in steps:
        keys = s.state.keys[s.i]
        pose = np.asarray(s.values.atVector(keys.body_pose)) + rng.normal(scale=0.2, size=69)
        pose[9] = 2.9                        # left knee beyond its limit
        s.values.update(keys.body_pose, pose)
        s.values.update(keys.trans, np.asarray(s.values.atVector(keys.trans)) + rng.normal(scale=0.05, size=3))
    return est, steps


@pytest.mark.parametrize("frames_before,with_ground", [(0, False), (2, False), (2, True)])
def test_batched_frame_systems_equal_gtsam_linearisation(ctx, frames_before, with_ground):
    """For the update (all own factors) and the presolve (without the chamfer, with the temporal prior to the
    held previous frame): the batched system of every pedestrian of the sample is GTSAM's Hessian of the same
    factors at the same point (the presolve: its block of the frame's variables), and ``hessian_factor``
    turns it into the same ``gtsam.HessianFactor``.  ``with_ground``: the ground-contact term switched on
    (a registered term reaches the frame systems through its registration alone)."""
    config = synthetic_config()
    if with_ground:
        config.noise.ground_contact_sigma_m = 0.03
    est, steps = _steps(ctx, config, frames_before, with_ground)
    if with_ground:
        assert all("ground_contact" in s.state.kinds[s.n_kinds:] for s in steps)
    for presolve in (True, False):
        est._systems(steps, presolve=presolve)
        for s in steps:
            keys = s.state.keys[s.i]
            system = s.presolve_system if presolve else s.own_system
            assert system is not None
            _, own = IncrementalTrack._split_own(keys, s.graph)
            kinds = s.state.kinds[s.n_kinds:]
            if presolve:     # without the chamfer, with the temporal prior's rows on the frame's variables
                own = gtsam.NonlinearFactorGraph()
                for j, kind in enumerate(kinds):
                    if kind not in ("lidar_chamfer", "shape_prior"):
                        own.add(s.graph.at(j))
                assert ("temporal_prior" in kinds) == (frames_before > 0)
            point = s.state.smoother._with_estimates(s.values, own.keyVector())
            reference = gtsam.HessianFactor(own.linearize(point))
            frame = set(keys.as_list())
            present = [k for k in keys.as_list() if k in set(own.keyVector())]
            held = [k for k in own.keyVector() if k not in frame]
            expected = _augmented(reference, present + held)
            if held:                         # the free block and its gradient (held keys' deltas are zero)
                zero = point.zeroVectors()
                n = sum(int(zero.at(k).shape[0]) for k in present)
                expected = np.block([[expected[:n, :n], expected[:n, -1:]], [expected[-1:, :n], expected[-1:, -1:]]])
            scale = np.abs(expected).max()
            if not presolve:
                got = _augmented(hessian_factor(keys, own.keyVector(), *system), present)
                np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9 * scale)
            # the dense system itself, on the columns [root, trans, body_pose, betas]
            h, eta, f = system
            dims = {keys.root: 3, keys.trans: 3, keys.body_pose: 69, keys.betas: ctx.model.num_betas}
            starts = {keys.root: 0, keys.trans: 3, keys.body_pose: 6, keys.betas: 75}
            cols = np.concatenate([np.arange(starts[k], starts[k] + dims[k]) for k in present])
            np.testing.assert_allclose(h[np.ix_(cols, cols)], expected[:-1, :-1], rtol=0, atol=1e-9 * scale)
            np.testing.assert_allclose(eta[cols], expected[:-1, -1], rtol=0, atol=1e-9 * scale)
            assert f == pytest.approx(expected[-1, -1], rel=1e-9)
            assert not np.any(np.delete(h, cols, axis=0)) and not np.any(np.delete(eta, cols))


def test_hessian_factor_on_fewer_keys():
    """A frame whose own factors touch only some of its variables gets a factor on just those."""
    from factors.common import FrameKeys

    keys = FrameKeys.for_frame(3)
    rng = np.random.default_rng(0)
    a = np.zeros((20, 85))
    a[:, 6:75] = rng.normal(size=(20, 69))                   # body pose only
    b = rng.normal(size=20)
    factor = hessian_factor(keys, [keys.body_pose], a.T @ a, a.T @ b, float(b @ b))
    assert list(factor.keys()) == [keys.body_pose]
    np.testing.assert_allclose(_augmented(factor, [keys.body_pose])[:-1, :-1], a[:, 6:75].T @ a[:, 6:75])


def test_stream_with_batched_systems_equals_gtsam_path(ctx):
    """Causal estimates with the batched systems equal those with GTSAM's linearisation (round-off)."""
    tracks = _tracks(ctx)
    outs = []
    for batched in (True, False):
        est = StreamingEstimator(ctx, synthetic_config(), StreamConfig(batched_frame_systems=batched,
                                                                       marginals=False, diagnostics=False))
        per_frame = []
        for j in range(4):
            current = est.add_frame(tracks[0].frames[j].timestamp, {t.tracking_id: t.frames[j] for t in tracks},
                                    tracks[0].calibrations)
            assert sorted(current) == sorted(t.tracking_id for t in tracks)
            per_frame.append({tid: e.world_keypoints for tid, e in current.items()})
        outs.append(per_frame)
    for with_batch, reference in zip(*outs):
        for tid in reference:
            np.testing.assert_allclose(with_batch[tid], reference[tid], atol=1e-7)


def test_recorder_serves_batched_temporal_terms_only_at_their_point(ctx):
    """The temporal prior's callback takes the terms served by its frame's recorder at exactly the values
    they were computed at (the batched terms equal the callback's own), and computes them itself elsewhere."""
    from factors.common import FrameKeys
    from factors.temporal_prior import make_temporal_prior_factor
    from factors.temporal_prior import pair_terms
    from pedx_graph.solvers.frame_system import SpecRecorder

    ka, kb = FrameKeys.for_frame(0), FrameKeys.for_frame(1)
    recorder = SpecRecorder()
    factor = make_temporal_prior_factor(ka.root, ka.trans, ka.body_pose, kb.root, kb.trans, kb.body_pose,
                                        mixture=ctx.temporal_mixture, frame_gap=2, cache=recorder)
    plain = make_temporal_prior_factor(ka.root, ka.trans, ka.body_pose, kb.root, kb.trans, kb.body_pose,
                                       mixture=ctx.temporal_mixture, frame_gap=2)
    assert [kind for kind, _, _ in recorder.specs] == ["temporal_prior"]
    rng = np.random.default_rng(0)
    values = gtsam.Values()
    state = []
    for k in (ka, kb):
        rot = gtsam.Rot3.Expmap(rng.normal(scale=0.3, size=3))
        trans, pose = rng.normal(size=3), rng.normal(scale=0.2, size=69)
        values.insert(k.root, rot)
        values.insert(k.trans, trans)
        values.insert(k.body_pose, pose)
        state.append((rot.matrix(), trans, pose))
    (r, blocks), = pair_terms([(state[0], state[1], ctx.temporal_mixture, 2)])
    keys = recorder.specs[0][1]
    recorder.serve("temporal_prior", keys, [*state[0], *state[1]], r, blocks)
    expected = _augmented(plain.linearize(values), keys)
    np.testing.assert_allclose(_augmented(factor.linearize(values), keys), expected, rtol=1e-12, atol=1e-12)
    recorder.serve("temporal_prior", keys, [*state[0], *state[1]], np.zeros_like(r), blocks)    # a marker
    assert factor.error(values) == 0.0                                    # served at its point
    moved = gtsam.Values(values)
    moved.update(kb.trans, state[1][1] + 0.01)
    assert factor.error(moved) == pytest.approx(plain.error(moved), rel=1e-12) and plain.error(moved) > 0


def test_wildfire_threshold_keeps_the_newest_frame_and_the_final_start_exact(ctx):
    """With a (huge) wildfire threshold iSAM2 may stop back-substituting below the top of the tree: the newest
    frame's estimate (the causal output) is still exact, and :meth:`IncrementalTrack.estimate` (the
    finalisation's start) is the full back-substitution."""
    from pedx_graph.graph.build import build_track_graph
    from pedx_graph.solvers.isam import IsamConfig
    from pedx_graph.solvers.isam_batch import frame_factor_groups, initial_frame_values

    track, _ = synthetic_track(ctx, 12, seed=1)
    problem = build_track_graph(track, ctx, synthetic_config(lidar_chamfer=False))
    groups = frame_factor_groups(problem)
    smoothers = [IncrementalTrack.create(IsamConfig(wildfire_threshold=w), betas_key=problem.keys[0].betas)
                 for w in (0.0, 1e6)]
    previous = None
    for i, keys in enumerate(problem.keys):
        initial = initial_frame_values(problem, i, previous)
        exact, lazy = [(s.add_frame(keys, groups[i], initial), s.frame_estimate(keys))[1] for s in smoothers]
        for a, b in zip(lazy[1:], exact[1:]):
            np.testing.assert_allclose(a, b, atol=1e-9)
        previous = exact
    exact, lazy = smoothers[0].estimate(), smoothers[1].estimate()
    for keys in problem.keys:
        np.testing.assert_allclose(lazy.atVector(keys.body_pose), exact.atVector(keys.body_pose), atol=1e-9)
