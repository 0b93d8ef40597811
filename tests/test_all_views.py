"""Every camera that labels a pedestrian enters the graph: frames with 1, 2, 3 or 4 labelled images (two
stereo pairs), their reprojection factors, the batched linearisation of a track mixing them, and the
triangulation from all views."""
from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from factors.common import FrameKeys
from pedx_graph.graph.build import build_track_graph, frame_factors
from pedx_graph.graph.init import triangulate_frame
from pedx_graph.graph.triangulate import triangulate_views
from pedx_graph.solvers.batched import BatchedLinearizer
from solver_fixtures import synthetic_config, synthetic_context, synthetic_track, with_views

#: Labelled images per frame: l/r the test pair's left/right, L/R the second pair's.
PATTERNS = ("lrLR", "l", "lr", "LR", "lrL", "R")


@pytest.fixture(scope="module")
def ctx():
    return synthetic_context()


def _track(ctx, patterns=PATTERNS, seed=4, noise=1.0):
    track, truth = synthetic_track(ctx, num_frames=len(patterns), seed=seed)
    return with_views(track, truth, patterns, pixel_noise=noise, seed=seed), truth


def _moved(problem, seed=0):
    """A generic point: every variable away from the initial values."""
    rng = np.random.default_rng(seed)
    values = gtsam.Values(problem.initial)
    for k in problem.keys:
        values.update(k.root, values.atRot3(k.root).compose(gtsam.Rot3.Expmap(rng.normal(scale=0.05, size=3))))
        values.update(k.trans, values.atVector(k.trans) + rng.normal(scale=0.05, size=3))
        values.update(k.body_pose, values.atVector(k.body_pose) + rng.normal(scale=0.1, size=69))
    key = problem.keys[0].betas
    values.update(key, rng.normal(scale=0.3, size=values.atVector(key).shape[0]))
    return values


def _image_counts(problem):
    specs = problem.body.specs("stereo_reprojection")
    return [specs[tuple(k.as_list())].setup.num_images for k in problem.keys]


@pytest.mark.parametrize("coarse", [False, True])
def test_batched_linearizer_equals_a_fresh_graph(ctx, coarse):
    """A track mixing frames with 1, 2, 3 and 4 images: the batched linearizer's error and chain system (one
    batch padded to 4 images) equal GTSAM's linearisation of the same track built again and never
    prefetched, its term cache switched off (every factor computes its own rows)."""
    track, _ = _track(ctx)
    config = synthetic_config()
    batched, fresh = build_track_graph(track, ctx, config), build_track_graph(track, ctx, config)
    assert _image_counts(batched) == [len(p) for p in PATTERNS]
    if coarse:
        batched, fresh = batched.without({"lidar_chamfer"}), fresh.without({"lidar_chamfer"})
    fresh.body.lookup = lambda *args, **kwargs: None           # the cache never serves a factor
    values = _moved(batched)
    lin = BatchedLinearizer(batched)
    assert len(lin.served["stereo_reprojection"]) == len(PATTERNS)
    system = lin.system(values)
    assert [len(g["keys"]) for g in batched.body.batch("stereo_reprojection")] == [len(PATTERNS)]
    assert batched.body.batch("stereo_reprojection")[0]["uv"].shape[1] == 4
    assert lin.error(values) == pytest.approx(fresh.graph.error(values), rel=1e-10)
    reference = fresh.layout.assemble(fresh.graph.linearize(values))
    assert not fresh.body._terms and not fresh.body._keypoint_jacobians     # nothing was prefetched
    for name in ("frame", "next", "frame_shape", "shape", "grad_frame", "grad_shape"):
        got, want = getattr(system, name), getattr(reference, name)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * max(np.abs(want).max(), 1e-12), err_msg=name)


def test_all_views_switch_and_sides(ctx):
    """``terms.all_views`` False keeps the primary pair only (as before); the left/right switches apply to
    every pair; a frame labelled by the second pair alone keeps it as its primary pair."""
    track, _ = _track(ctx)
    counts = {}
    for all_views in (True, False):
        config = synthetic_config(all_views=all_views)
        counts[all_views] = _image_counts(build_track_graph(track, ctx, config))
    assert counts[True] == [4, 1, 2, 2, 3, 1]
    assert counts[False] == [2, 1, 2, 2, 2, 1]
    no_right = synthetic_config(right_reprojection=False)
    rng = np.random.default_rng(0)
    model = build_track_graph(track, ctx, no_right).body
    factor, kind = frame_factors(FrameKeys.for_frame(0), track.frames[0], track.calibrations, None, np.nan, 0.0, model,
                                 ctx, no_right, rng, ground=track.ground)[0]
    assert kind == "stereo_reprojection" and factor.dim() == 2 * 2 * 18       # two left images
    # a single calibration stands for the primary pair only
    factor, _ = frame_factors(FrameKeys.for_frame(0), track.frames[0], track.calibrations[track.frames[0].pair], None,
                              np.nan, 0.0, model, ctx, synthetic_config(), rng, ground=track.ground)[0]
    assert factor.dim() == 2 * 2 * 18


def test_fit_with_both_pairs_places_pedestrians_better(ctx):
    """Stereo only (no LiDAR) at 12 m, three seeded tracks: with the second pair's images (0.9 m from the
    first) the fitted pelvis is nearer the truth along the viewing ray than with the primary pair alone
    (measured: mean 0.028 vs 0.094 m)."""
    from pedx_graph.solvers.fit import fit_track

    errors = {False: [], True: []}
    for seed in (7, 8, 9):
        track, truth = synthetic_track(ctx, num_frames=4, seed=seed, distance_m=12.0, with_lidar=False,
                                       pixel_noise=2.0)
        track = with_views(track, truth, ["lrLR"] * 4, pixel_noise=2.0, seed=seed)
        origin = track.calibrations[track.frames[0].pair].world_T_cam[:3, 3]
        real = np.array([ctx.model.forward(truth["pose"][i], truth["betas"], truth["trans"][i]).joints[0]
                         for i in range(len(track.frames))])
        ray = (real - origin) / np.linalg.norm(real - origin, axis=1, keepdims=True)
        for all_views in (False, True):
            config = synthetic_config(all_views=all_views)
            config.solver.flip_segments = ()
            result = fit_track(track, config, ctx)
            fitted = np.array([ctx.model.forward(result.pose[i], result.betas, result.trans[i]).joints[0]
                               for i in range(len(track.frames))])
            errors[all_views].extend(np.abs(np.sum((fitted - real) * ray, axis=1)))
    assert np.mean(errors[True]) < 0.5 * np.mean(errors[False])


def test_triangulate_views_exact_and_nan(ctx):
    """Noise-free labels: every keypoint labelled in >= 2 images is the truth (any mix of pairs); one image
    gives NaN; the primary pair alone equals the rectified-disparity triangulation."""
    track, truth = _track(ctx, patterns=("lrLR", "lL", "rR", "lrL", "R", "lr"), noise=0.0)
    for i, fr in enumerate(track.frames):
        got = triangulate_views(fr, track.calibrations)
        if len(fr.labelled_views()) < 2:
            assert np.all(np.isnan(got))
            continue
        np.testing.assert_allclose(got, truth["keypoints"][i], atol=1e-6)
    fr = track.frames[5]
    np.testing.assert_allclose(triangulate_views(fr, track.calibrations, all_pairs=False),
                               triangulate_frame(track, fr), atol=1e-6)
    partial = dataclasses.replace(track.frames[1])
    partial.left = dataclasses.replace(partial.left, keypoints=partial.left.keypoints.copy())
    partial.left.keypoints[[2, 7]] = np.nan                     # in the second pair's left image only
    got = triangulate_views(partial, track.calibrations)
    assert np.all(np.isnan(got[[2, 7]])) and np.all(np.isfinite(np.delete(got, [2, 7], axis=0)))
    hidden = dataclasses.replace(track.frames[0])            # visible: 0-8 in one image, 9-17 in three
    hidden.left = dataclasses.replace(hidden.left, visible=np.arange(18) >= 9)
    hidden.right = dataclasses.replace(hidden.right, visible=np.arange(18) >= 9)
    hidden.other_views = {n: (left, None) for n, (left, _) in hidden.other_views.items()}
    got = triangulate_views(hidden, track.calibrations, visible_only=True)
    assert np.all(np.isnan(got[:9]))
    np.testing.assert_allclose(got[9:], truth["keypoints"][0][9:], atol=1e-6)
    np.testing.assert_allclose(triangulate_views(hidden, track.calibrations), truth["keypoints"][0], atol=1e-6)


def test_wide_baseline_triangulation_is_more_precise(ctx):
    """With 1 px label noise at 25 m, the four images (two pairs 0.9 m apart) triangulate the keypoints'
    depth more precisely than the primary pair alone."""
    track, truth = synthetic_track(ctx, num_frames=8, seed=11, distance_m=25.0)
    track = with_views(track, truth, ["lrLR"] * 8, pixel_noise=1.0, seed=11)
    err = {True: [], False: []}
    for i, fr in enumerate(track.frames):
        for all_pairs in (True, False):
            got = triangulate_views(fr, track.calibrations, all_pairs=all_pairs)
            err[all_pairs].append(np.linalg.norm(got - truth["keypoints"][i], axis=1))
    rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in err.items()}
    assert rms[True] < 0.6 * rms[False]
