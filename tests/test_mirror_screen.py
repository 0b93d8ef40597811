"""The left/right label screen (pedx_graph.solvers.mirror): an image's exchanged left/right labels are exchanged
back where the fitted body shows them exchanged, and nothing else is touched."""
import copy
import dataclasses
import math

import numpy as np
from scipy.spatial.transform import Rotation

from pedx_graph.detections.fit_layout import fit_layout, layout_names
from pedx_graph.graph.build import extract_estimate, reprojection_noise
from pedx_graph.keypoints import PEDX_KEYPOINTS, mirror_index
from pedx_graph.solvers.mirror import mirrored_view, neighbour_poses, pair_gains, prior_log_odds
from pedx_graph.solvers.staging import solve_staged
from solver_fixtures import synthetic_config, synthetic_context, synthetic_track

PAIRS = mirror_index(PEDX_KEYPOINTS)
WRISTS = (PEDX_KEYPOINTS.index("lwri"), PEDX_KEYPOINTS.index("rwri"))
ANKLES = (PEDX_KEYPOINTS.index("lankl"), PEDX_KEYPOINTS.index("rankl"))


def _exchanged(track, changes):
    """``track`` with, per ``(frame index, side)``, the listed row pairs of that image exchanged."""
    frames = list(track.frames)
    for (i, side), pairs in changes.items():
        frames[i] = dataclasses.replace(frames[i], **{side: mirrored_view(getattr(frames[i], side), pairs)})
    return dataclasses.replace(track, frames=frames)


def test_prior_log_odds():
    assert math.isclose(prior_log_odds(0.05), math.log(19.0))
    assert prior_log_odds(0.0) == math.inf


def test_mirrored_view_moves_labels_with_their_sigmas():
    ctx = synthetic_context()
    track, _ = synthetic_track(ctx, num_frames=1)
    view = dataclasses.replace(track.frames[0].left, sigma_px=np.arange(18, dtype=float) + 1.0)
    view.keypoints[WRISTS[1]] = np.nan                                   # one side unlabelled
    out = mirrored_view(view, [WRISTS])
    np.testing.assert_array_equal(out.keypoints[WRISTS[1]], view.keypoints[WRISTS[0]])
    assert np.all(np.isnan(out.keypoints[WRISTS[0]]))
    assert out.sigma_px[WRISTS[1]] == view.sigma_px[WRISTS[0]] and out.sigma_px[WRISTS[0]] == view.sigma_px[WRISTS[1]]
    others = [k for k in range(18) if k not in WRISTS]
    np.testing.assert_array_equal(out.keypoints[others], view.keypoints[others])


def test_gain_at_the_true_body_is_large_for_an_exchanged_pair_only():
    ctx = synthetic_context()
    track, truth = synthetic_track(ctx, num_frames=3, seed=3)
    calib = next(iter(track.calibrations.values()))
    noise = reprojection_noise(synthetic_config())
    limit = prior_log_odds(0.05)
    view = track.frames[2].left
    clean = pair_gains(truth["keypoints"][2], view, calib, "left", PAIRS, noise)
    assert np.all(clean < limit)
    swapped = pair_gains(truth["keypoints"][2], mirrored_view(view, [ANKLES]), calib, "left", PAIRS, noise)
    ankles = PAIRS.index(ANKLES)
    assert swapped[ankles] > limit
    assert math.isclose(swapped[ankles], -clean[ankles], rel_tol=1e-9)      # the same two hypotheses
    np.testing.assert_allclose(np.delete(swapped, ankles), np.delete(clean, ankles))


def test_the_staged_fit_exchanges_back_a_pair_the_other_image_contradicts():
    """Wrists exchanged in one image of a frame, the other image right: the screen after the second stage
    exchanges them back (recorded) and that frame's wrists come closer to the truth; nothing on clean labels, and
    nothing with the screen off."""
    ctx = synthetic_context()
    track, truth = synthetic_track(ctx, num_frames=6, seed=3)
    bad = _exchanged(track, {(2, "left"): [WRISTS]})

    def fit(labels, swap_prob):
        config = synthetic_config()
        config.noise.left_right_swap_prob = swap_prob
        problem, values, report = solve_staged(copy.deepcopy(labels), ctx, config)
        est = extract_estimate(problem, values, ctx)
        wrists = est.world_keypoints[2, list(WRISTS)] - truth["keypoints"][2, list(WRISTS)]
        return float(np.linalg.norm(wrists, axis=-1).mean()), report

    off_error, off = fit(bad, 0.0)
    on_error, on = fit(bad, 0.05)
    assert off.mirrored_labels == []
    assert [(r["frame"], r["side"], r["keypoints"]) for r in on.mirrored_labels] == [(2, "left", ["lwri", "rwri"])]
    assert on.mirrored_labels[0]["gain"] > prior_log_odds(0.05)
    assert on_error < 0.8 * off_error, (on_error, off_error)          # measured 0.54
    _, clean = fit(track, 0.05)
    assert clean.mirrored_labels == []


def test_detector_tracks_screen_with_the_detector_prior_and_their_own_pairs():
    config = synthetic_config()
    assert config.noise.left_right_swap_prob == 0.0 and config.noise.detector_left_right_swap_prob > 0
    names = layout_names("body25")
    pairs = {(names[a], names[b]) for a, b in mirror_index(names)}
    assert {("lsho", "rsho"), ("LBigToe", "RBigToe"), ("LHeel", "RHeel"), ("LEar", "REar")} <= pairs
    ctx = synthetic_context()
    track, _ = synthetic_track(ctx, num_frames=1)
    same = fit_layout(track, ctx, config)
    assert same[2] is config                                        # PedX labels: the manual prior (0)


def test_a_frame_confused_in_every_image_is_exchanged_back_whole():
    """Every pair exchanged in both images of one frame (a back view read as a front view by every camera):
    nothing in the frame contradicts the labels and the fit follows them; the body the neighbouring frames
    predict shows the exchange, and the whole images are exchanged back — the track ends as if clean."""
    ctx = synthetic_context()
    track, truth = synthetic_track(ctx, num_frames=6, seed=3)
    bad = _exchanged(track, {(3, "left"): list(PAIRS), (3, "right"): list(PAIRS)})

    def fit(labels, swap_prob):
        config = synthetic_config()
        config.noise.left_right_swap_prob = swap_prob
        problem, values, report = solve_staged(copy.deepcopy(labels), ctx, config)
        est = extract_estimate(problem, values, ctx)
        return np.linalg.norm(est.world_keypoints - truth["keypoints"], axis=-1).mean(axis=1), report

    off_error, _ = fit(bad, 0.0)
    on_error, on = fit(bad, 0.05)
    clean_error, clean = fit(track, 0.05)
    assert sorted((r["frame"], r["side"], r["keypoints"]) for r in on.mirrored_labels) == [
        (3, "left", "all"), (3, "right", "all")]
    assert clean.mirrored_labels == []
    # the track as a whole, and the exchanged frame (measured 12.6, 12.9 and 90.1 mm)
    assert on_error.mean() < 1.1 * clean_error.mean(), (on_error, clean_error)
    assert on_error[3] < 1.1 * clean_error[3] < 0.6 * off_error[3], (on_error, clean_error, off_error)


def test_neighbour_poses_interpolate_between_the_neighbours():
    rng = np.random.default_rng(0)
    pose = rng.normal(scale=0.3, size=(5, 72))
    times = np.array([0.0, 0.1, 0.3, 0.4, 1.0])
    out, usable = neighbour_poses(pose, times)
    assert usable.tolist() == [False, True, True, False, False]       # ends; frame 3's neighbours 0.7 s apart
    np.testing.assert_array_equal(out[~usable], pose[~usable])
    mid = Rotation.from_rotvec(out[1].reshape(24, 3))
    before, after = Rotation.from_rotvec(pose[0].reshape(24, 3)), Rotation.from_rotvec(pose[2].reshape(24, 3))
    # a third of the way from frame 0 to frame 2 (by time): the angles to the two neighbours are 1 : 2
    to_before = (mid.inv() * before).magnitude()
    to_after = (mid.inv() * after).magnitude()
    np.testing.assert_allclose(2 * to_before, to_after, rtol=1e-9)
