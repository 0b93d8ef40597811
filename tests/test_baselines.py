"""The paper's baselines (triangulation, left+disparity, SMPLify+disparity) on a small synthetic track.

The track is built here: a synthetic SMPL-format body walks across a test stereo pair; its 18 keypoints
are projected noise-free into both rectified images, with a few keypoints occluded or unlabelled.
"""
from __future__ import annotations

import gtsam
import numpy as np
import pytest

from factors.common import MaxMixture
from factor_testing import make_test_calibration
from synthetic_model import synthetic_body_model
from pedx_graph.baselines.left_disparity import (left_disparity_baseline, left_disparity_keypoints,
                                                 sample_disparity_map)
from pedx_graph.baselines.run import BASELINES, BaselineConfig, fit_dataset_baseline, run_baseline
from pedx_graph.baselines.smplify_disparity import (SmplifyDispConfig, fit_frame_monocular,
                                                    scale_about_camera, smplify_disparity_baseline)
from pedx_graph.baselines.triangulation import (KEYPOINT_SOURCES, STANDING_BODY_POSE, triangulation_baseline,
                                                triangulate_visible)
from pedx_graph.data.types import Track, TrackFrame, View2D
from pedx_graph.data.ground import make_ground_frame
from pedx_graph.graph.init import world_R_body_from_yaw
from pedx_graph.keypoints import PEDX_KEYPOINTS

K = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}
NUM_FRAMES = 5


@pytest.fixture(scope="module")
def model():
    return synthetic_body_model()


@pytest.fixture(scope="module")
def scene(model):
    """(track, truth keypoints (T, 18, 3), truth (pose (T, 72), trans (T, 3))): walking along world +y, 8 m
    in front of the cameras, betas 0."""
    calib = make_test_calibration()
    rng = np.random.default_rng(3)
    frames, truth, poses, transes = [], [], [], []
    root = gtsam.Rot3.Logmap(gtsam.Rot3(world_R_body_from_yaw(np.pi / 2, make_ground_frame([0, 0, 1], [1, 0, 0],
                                                                                           np.zeros(3)))))
    pelvis_rest = model.rest_joints(np.zeros(model.num_betas))[0]
    for i in range(NUM_FRAMES):
        pose = np.concatenate([root, STANDING_BODY_POSE + rng.normal(scale=0.05, size=69)])
        trans = np.array([8.0, -1.0 + 0.14 * i, 0.95]) - pelvis_rest
        kp = np.asarray(model.keypoints(pose, np.zeros(model.num_betas), trans))
        truth.append(kp)
        poses.append(pose)
        transes.append(trans)
        left_uv, right_uv = calib.project(kp)
        left_vis, right_vis = np.ones(18, bool), np.ones(18, bool)
        left_vis[K["mouth"]] = right_vis[K["mouth"]] = False        # labelled, never visible
        if i == 1:
            right_vis[K["lwri"]] = False                              # occluded on the right only
            left_vis[K["lelb"]] = False                               # occluded on the left only
        if i == 2:
            left_uv[K["rknee"]] = np.nan                              # not labelled on the left
            left_vis[K["rknee"]] = False
        if i == 3:
            right_uv[K["relb"]] = np.nan                              # labelled only on the left
            right_vis[K["relb"]] = False
        right = None if i == 4 else View2D(right_uv, right_vis)       # last frame: left image only
        frames.append(TrackFrame(frame=10 + i, timestamp=0.1 * i, pair=calib.name,
                                 left=View2D(left_uv, left_vis), right=right))
    track = Track(sequence="20990101T0000", tracking_id="0123456789abcdef0123456789abcdef", frames=frames,
                  calibrations={calib.name: calib})
    return track, np.stack(truth), (np.stack(poses), np.stack(transes))


def _codes(result) -> np.ndarray:
    return np.array([[KEYPOINT_SOURCES.index(s) for s in fr["keypoint_source"]] for fr in result.extra_per_frame])


def test_triangulation_exact_on_visible_and_fills_the_rest(model, scene):
    track, truth, _ = scene
    raw, _ = triangulate_visible(track)
    res = triangulation_baseline(track, model)
    measured = np.all(np.isfinite(raw), axis=2)
    np.testing.assert_allclose(res.world_keypoints[measured], truth[measured], atol=1e-9)
    assert not measured[1, K["lwri"]] and not measured[1, K["lelb"]] and not measured[2, K["rknee"]]
    assert not measured[:, K["mouth"]].any() and not measured[4].any()
    assert np.all(np.isfinite(res.world_keypoints))
    codes = _codes(res)
    assert np.all(codes[:, K["mouth"]] == KEYPOINT_SOURCES.index("body_fill"))
    assert codes[1, K["lwri"]] == KEYPOINT_SOURCES.index("temporal_fill")
    # temporal fill: the previous frame (tie) moved by the mean displacement of the joints both measured
    common = measured[0] & measured[1]
    expected = raw[0, K["lwri"]] + (raw[1, common] - raw[0, common]).mean(axis=0)
    np.testing.assert_allclose(res.world_keypoints[1, K["lwri"]], expected, atol=1e-12)
    filled = ~measured
    assert res.extra_track["keypoints_only"] is True
    assert res.extra_track["keypoints_filled"] == int(filled.sum())
    assert sum(fr["filled_keypoints"] for fr in res.extra_per_frame) == int(filled.sum())
    # fills are approximations (a standing pose, a 0.14 m step per frame): ~1.5x the measured 0.061 / 0.136 m
    err = np.linalg.norm(res.world_keypoints - truth, axis=-1)
    assert err[:, K["mouth"]].max() < 0.09 and err[filled].max() < 0.2
    np.testing.assert_allclose(res.pose, 0.0)
    np.testing.assert_allclose(res.trans, res.world_keypoints[:, [K["lhip"], K["rhip"]]].mean(axis=1))
    labels = res.to_labels()
    np.testing.assert_allclose(labels[2].extra["keypoints_3d"], res.world_keypoints[2])


def test_left_disparity_exact_where_depth_is_known(model, scene):
    track, truth, _ = scene
    raw, source = left_disparity_keypoints(track)
    disp, tri, median = (KEYPOINT_SOURCES.index(n) for n in ("disparity", "triangulated", "median_depth"))
    assert source[0, K["lwri"]] == disp                     # visible in both: the labels' disparity
    assert source[1, K["lwri"]] == median                   # right label occluded: no disparity there
    assert source[1, K["lelb"]] == tri and np.all(source[:4, K["mouth"]] == tri)
    assert source[3, K["relb"]] == median
    assert np.all(source[4] == -1) and source[2, K["rknee"]] == -1
    exact = (source == disp) | (source == tri)
    np.testing.assert_allclose(raw[exact], truth[exact], atol=1e-9)
    # median depth: the right ray, a depth off by the body's depth extent at most
    assert np.linalg.norm(raw[source == median] - truth[source == median], axis=-1).max() < 0.38   # measured 0.254
    res = left_disparity_baseline(track, model)
    assert np.all(np.isfinite(res.world_keypoints))
    np.testing.assert_allclose(res.world_keypoints[exact], truth[exact], atol=1e-9)
    assert res.extra_track["keypoints_filled"] == int((source == -1).sum())
    assert np.linalg.norm(res.world_keypoints - truth, axis=-1).max() < 0.38         # measured 0.254 m


def test_sample_disparity_map_bilinear_and_invalid():
    height, width = 6, 8
    vv, uu = np.mgrid[0:height, 0:width]
    disp = 10.0 + 0.5 * uu + 0.25 * vv                       # a plane: bilinear sampling is exact
    uv = np.array([[2.3, 1.7], [6.99, 4.5], [0.0, 0.0], [7.5, 1.0], [np.nan, 1.0]])
    out = sample_disparity_map(disp, uv)
    np.testing.assert_allclose(out[:3], 10.0 + 0.5 * uv[:3, 0] + 0.25 * uv[:3, 1])
    assert np.all(np.isnan(out[3:]))
    disp[1:3, 2:4] = 0.0                                      # a matcher's "no match" region
    assert np.isnan(sample_disparity_map(disp, uv[:1]))[0]


def _test_mixture() -> MaxMixture:
    """A one-component pose prior around the standing pose (sigma 0.3 rad per component)."""
    return MaxMixture(np.ones(1), STANDING_BODY_POSE[None], np.eye(69)[None] / 0.3)


def test_smplify_disparity_finite_and_near_truth(model, scene):
    track, truth, _ = scene
    res = smplify_disparity_baseline(track, model, _test_mixture())
    assert np.all(np.isfinite(res.world_keypoints)) and np.all(np.isfinite(res.trans))
    err = np.linalg.norm(res.world_keypoints - truth, axis=-1)
    assert err.mean() < 0.0115 and err.max() < 0.085            # measured 0.0076 / 0.057 m
    assert res.extra_track["frames_fitted"] == NUM_FRAMES and res.extra_track["frames_unscaled"] == 1
    assert res.extra_track["keypoints_only"] is False
    scales = [fr["disparity_scale"] for fr in res.extra_per_frame]
    assert all(0.8 < s < 1.25 for s in scales) and scales[4] == 1.0
    assert res.solver == "baseline-smplify_disp" and res.betas.shape == (model.num_betas,)


def test_smplify_scaling_keeps_left_projection_and_sets_depth(model, scene):
    track, _, _ = scene
    calib = track.calibrations[track.frames[0].pair]
    fit = fit_frame_monocular(model, calib, track.frames[0].left, _test_mixture(), STANDING_BODY_POSE,
                              SmplifyDispConfig(yaw_candidates_deg=(0.0,)), ground=track.ground)
    scaled = scale_about_camera(calib, fit.world_keypoints, 1.7)
    np.testing.assert_allclose(calib.project(scaled)[0], calib.project(fit.world_keypoints)[0], atol=1e-9)
    np.testing.assert_allclose(calib.world_to_rect(scaled)[:, 2], 1.7 * calib.world_to_rect(fit.world_keypoints)[:, 2])


def test_smplify_frame_without_labels_is_filled(model, scene):
    track, truth, _ = scene
    frames = list(track.frames)
    frames[2] = TrackFrame(frame=frames[2].frame, timestamp=frames[2].timestamp, pair=frames[2].pair,
                           left=None, right=frames[2].right)
    short = Track(track.sequence, track.tracking_id, frames[:3], track.calibrations)
    res = smplify_disparity_baseline(short, model, _test_mixture(), config=SmplifyDispConfig(yaw_candidates_deg=(0.0,)))
    assert res.extra_track["frames_unfitted"] == 1 and res.extra_per_frame[2]["filled_from_frame"] == frames[1].frame
    assert np.all(np.isfinite(res.world_keypoints))
    assert np.linalg.norm(res.world_keypoints[2] - truth[2], axis=-1).mean() < 0.057        # measured 0.038 m


def test_run_baseline_dispatch(model, scene):
    track, _, _ = scene
    assert set(BASELINES) == {"triangulation", "left_disp", "smplify_disp"}
    assert run_baseline("triangulation", track, model).solver == "baseline-triangulation"
    assert run_baseline("left_disp", track, model).solver == "baseline-left_disp"
    with pytest.raises(ValueError, match="unknown baseline"):
        run_baseline("nope", track, model)


def test_smplify_with_the_shipped_pose_prior(model, scene):
    from pedx_graph.priors import DATA_DIR

    assert (DATA_DIR / "pose_gmm.npz").is_file(), "the shipped pose prior is missing"
    track, truth, _ = scene
    short = Track(track.sequence, track.tracking_id, track.frames[:2], track.calibrations)
    res = run_baseline("smplify_disp", short, model)
    assert np.all(np.isfinite(res.world_keypoints))
    assert np.linalg.norm(res.world_keypoints - truth[:2], axis=-1).mean() < 0.075        # measured 0.049 m


def test_dataset_run_writes_results_that_evaluate(tmp_path, scene, synthetic_track_model_file):
    from pedx_graph.body import BodyModel
    from pedx_graph.data.reader import read_smpl_labels
    from pedx_graph.data.types import SmplLabel
    from pedx_graph.data.writer import write_results, write_tracks
    from pedx_graph.eval.evaluate import evaluate

    track, truth, (poses, transes) = scene
    dataset, out = tmp_path / "data", tmp_path / "results"
    write_tracks(dataset, [track])
    config = BaselineConfig(body_model=str(synthetic_track_model_file))
    summary = fit_dataset_baseline(dataset, out, "left_disp", workers=1, config=config)
    assert summary["failed"] == [] and summary["total_frames"] == NUM_FRAMES
    assert summary["tracks"][0]["keypoints_only"] is True and (out / "baseline_config.yaml").is_file()
    labels = read_smpl_labels(out)[(track.sequence, track.tracking_id)]
    got = np.stack([np.asarray(lab.extra["keypoints_3d"], float) for lab in labels])
    np.testing.assert_allclose(got, run_baseline("left_disp", track, BodyModel.load(config.body_model)).world_keypoints)
    # ground truth: the SMPL parameters of the scene; the evaluation reads our keypoints_3d field
    model = BodyModel.load(config.body_model)
    write_results(dataset, [SmplLabel(track.sequence, fr.frame, track.tracking_id, np.zeros(10), poses[i], transes[i])
                            for i, fr in enumerate(track.frames)])
    report = evaluate(out, dataset, model)
    err = np.linalg.norm(got - truth, axis=-1)
    assert report["frames"] == NUM_FRAMES
    assert report["overall"]["global_all_joints_mm"] < 1000.0 * err.max() + 1e-6
    assert report["overall"]["global_mm"] < 28.0                  # measured 18.7 mm


@pytest.fixture(scope="module")
def synthetic_track_model_file(tmp_path_factory):
    from pedx_graph.body.io import save_model_npz
    from synthetic_model import synthetic_model_arrays

    return save_model_npz(tmp_path_factory.mktemp("model") / "synthetic.npz", synthetic_model_arrays(seed=0))


def test_baseline_command_with_workers(tmp_path, scene, synthetic_track_model_file):
    import argparse

    from pedx_graph.baselines.cli import register
    from pedx_graph.data.reader import read_smpl_labels
    from pedx_graph.data.writer import write_tracks

    track, _, _ = scene
    other = Track(track.sequence, "f" * 32, track.frames[:3], track.calibrations)
    write_tracks(tmp_path / "data", [track, other])
    parser = argparse.ArgumentParser()
    register(parser.add_subparsers())
    outs = {}
    for workers in (1, 2):
        out = tmp_path / f"out{workers}"
        args = parser.parse_args(["baseline", "triangulation", str(tmp_path / "data"), "--out", str(out),
                                  "--model", str(synthetic_track_model_file), "--workers", str(workers)])
        assert args.func(args) == 0
        outs[workers] = read_smpl_labels(out)
    assert set(outs[1]) == set(outs[2]) and len(outs[1]) == 2
    for key, labels in outs[1].items():
        for a, b in zip(labels, outs[2][key]):
            np.testing.assert_array_equal(a.extra["keypoints_3d"], b.extra["keypoints_3d"])

