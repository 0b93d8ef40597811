"""An image of someone else attached to a track (a detection the association gave the wrong person) is taken
out after the first stage, where running that stage again without it confirms it; a clean track keeps every
image."""
from __future__ import annotations

import numpy as np
import pytest

from pedx_graph.data.types import View2D
from pedx_graph.solvers.fit import fit_track
from solver_fixtures import second_test_calibration, synthetic_config, synthetic_context, synthetic_track, with_views

SEEDS = (3, 4)


@pytest.fixture(scope="module")
def ctx():
    return synthetic_context()


def _track(ctx, seed, wrong_frame=None):
    """Six frames at 20 m seen by both test pairs with LiDAR; at ``wrong_frame`` the second pair's right image
    holds someone walking 0.8 m beside the pedestrian."""
    track, truth = synthetic_track(ctx, num_frames=6, seed=seed, distance_m=20.0, pixel_noise=2.0)
    track = with_views(track, truth, ["lrLR"] * 6, pixel_noise=2.0, seed=seed)
    if wrong_frame is not None:
        second = second_test_calibration()
        frame = track.frames[wrong_frame]
        beside = truth["keypoints"][wrong_frame] + np.array([0.0, 0.8, 0.0])
        uv = second.project(beside)[1] + np.random.default_rng(seed).normal(scale=2.0, size=(18, 2))
        frame.other_views[second.name] = (frame.other_views[second.name][0], View2D(uv, np.ones(18, bool)))
    pelvis = np.array([ctx.model.forward(truth["pose"][i], truth["betas"], truth["trans"][i]).joints[0]
                       for i in range(len(track.frames))])
    return track, pelvis


def _fit(track, ctx, limit=None, **terms):
    config = synthetic_config(**terms)
    config.solver.flip_segments = ()
    if limit is not None:
        config.solver.view_outlier_sigmas = limit
    result = fit_track(track, config, ctx)
    pelvis = np.array([ctx.model.forward(result.pose[i], result.betas, result.trans[i]).joints[0]
                       for i in range(len(track.frames))])
    return result, pelvis


def test_someone_elses_image_is_dropped_and_the_fit_stays_on_the_pedestrian(ctx):
    """Two seeded tracks: the wrong image (and only it) is dropped and reported; the pelvis error over the
    track is below 45 mm (measured 25 / 35 mm; 26 / 19 mm while the reprojection kernel acted on each row,
    and 19-37 mm over kernel scales 3-4: two six-frame tracks at 20 m) and below 0.6x that of the fit
    keeping every image."""
    screened, kept = [], []
    for seed in SEEDS:
        track, truth = _track(ctx, seed, wrong_frame=2)
        result, pelvis = _fit(track, ctx)
        second = second_test_calibration().name
        assert [(d["frame"], d["pair"], d["side"]) for d in result.extra_track["dropped_views"]] == \
            [(2, second, "right")]
        screened.append(np.mean(np.linalg.norm(pelvis - truth, axis=1)))
        result, pelvis = _fit(track, ctx, np.inf)
        assert "dropped_views" not in result.extra_track
        kept.append(np.mean(np.linalg.norm(pelvis - truth, axis=1)))
    assert np.mean(screened) < 0.045
    assert np.mean(screened) < 0.6 * np.mean(kept)


def test_a_clean_track_keeps_every_image(ctx):
    for seed in SEEDS:
        track, _ = _track(ctx, seed)
        result, _ = _fit(track, ctx)
        assert "dropped_views" not in result.extra_track


def test_only_the_images_the_graph_fits_are_screened(ctx):
    """With ``terms.all_views`` off the second pair's images are not in the graph: its wrong image is neither
    judged nor reported."""
    track, _ = _track(ctx, SEEDS[0], wrong_frame=2)
    result, _ = _fit(track, ctx, all_views=False)
    assert "dropped_views" not in result.extra_track
