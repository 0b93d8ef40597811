"""No track left behind: a pedestrian labelled in one camera only, without LiDAR points, still gets a result,
placed in depth by the body-size prior, with a covariance that says how weak that depth is, and a flag."""
import dataclasses

import numpy as np
import pytest
from scene_fixtures import small_scene

from pedx_graph.data.reader import read_dataset, read_smpl_labels
from pedx_graph.graph.config import FitConfig
from pedx_graph.solvers.fit import _context, fit_track


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return small_scene(tmp_path_factory.mktemp("mono_scene"), pedestrians=4, frames=6, seed=8)


def _one_camera(track):
    """The track as if labelled in its primary left camera only, without LiDAR points."""
    frames = [dataclasses.replace(fr, right=None, other_views={}, world_lidar_points=np.zeros((0, 3)))
              for fr in track.frames if fr.left is not None and fr.left.labelled.sum() >= 8]
    return dataclasses.replace(track, frames=frames)


@pytest.mark.parametrize("ground_contact", [False, True])
def test_one_camera_tracks_get_results_with_an_honest_depth(scene, ground_contact):
    """Without the ground-contact term the depth comes from the body's size alone; with it (the ground plane
    of the scene is known) the stance foot on the ground fixes the depth along the camera's view down to the
    ground: a smaller error, and a covariance that still says how large it is."""
    truth = read_smpl_labels(scene)
    config = FitConfig()
    if not ground_contact:
        config.noise.ground_contact_sigma_m = 0.0
    ctx = _context(config)
    checked = 0
    for track in read_dataset(scene):
        mono = _one_camera(track)
        if len(mono.frames) < 3:
            continue
        result = fit_track(mono, config, ctx)
        assert result.extra_track["depth_from_body_size"] is True
        assert result.extra_track["monocular"] is True
        assert all(f["depth_source"] == "body_size" for f in result.extra_per_frame)
        assert result.extra_track["inside_out_frames"] == 0
        assert np.max(np.abs(result.betas)) <= 3.5 + 0.1
        by_frame = {lab.frame: lab for lab in truth[(track.sequence, track.tracking_id)]}
        z_errors, sigmas = [], []
        for i, frame in enumerate(result.frames):
            true_kp = np.asarray(ctx.model.keypoints(by_frame[frame].pose, by_frame[frame].betas,
                                                     by_frame[frame].trans))
            est_kp = result.world_keypoints[i]
            calib = mono.calibrations[mono.frames[i].pair]
            pelvis = [12, 13]
            z_errors.append(calib.world_to_rect(est_kp[pelvis].mean(0))[2] - calib.world_to_rect(true_kp[pelvis].mean(0))[2])
            cov = np.asarray(result.extra_per_frame[i]["cov_trans"])
            ray = calib.world_to_rect(est_kp[pelvis].mean(0)) @ calib.rect_T_world[:3, :3]
            ray /= np.linalg.norm(ray)
            sigmas.append(float(np.sqrt(ray @ cov @ ray)))
        z_errors, sigmas = np.abs(np.asarray(z_errors)), np.asarray(sigmas)
        distance = float(np.median([calib.world_to_rect(k.mean(0))[2] for k in result.world_keypoints]))
        if ground_contact:     # measured 0.009-0.017 of the distance (seed 8), sigma 0.24-0.54 m
            assert np.median(z_errors) < 0.025 * distance
        else:                  # the depth is known to the person's size (~6-8 % of the distance), and the covariance says so
            assert np.median(sigmas) > 0.03 * distance
            assert np.median(z_errors) < 0.1 * distance      # measured 0.046-0.070 of the distance (seed 8)
        assert np.median(z_errors) < 3.0 * np.median(sigmas)
        print(f"distance {distance:.1f} m: median |dz| {np.median(z_errors):.3f} m, median sigma {np.median(sigmas):.3f} m")
        checked += 1
    assert checked >= 2


def _polygon_only(view):
    return None if view is None else dataclasses.replace(view, keypoints=np.full_like(view.keypoints, np.nan),
                                                         visible=np.zeros_like(view.visible))


def test_polygon_only_track_with_lidar_gets_a_result_and_one_with_nothing_fails(scene):
    """Keypoint-free labels (polygon-only files) plus LiDAR: placed by the points; neither: a clear failure."""
    truth = read_smpl_labels(scene)
    config = FitConfig()
    ctx = _context(config)
    track = max(read_dataset(scene), key=lambda t: min(len(fr.world_lidar_points) for fr in t.frames))
    assert min(len(fr.world_lidar_points) for fr in track.frames) >= 20
    stripped = dataclasses.replace(track, frames=[
        dataclasses.replace(fr, left=_polygon_only(fr.left), right=_polygon_only(fr.right), other_views={})
        for fr in track.frames])
    result = fit_track(stripped, config, ctx)
    assert result.extra_track["depth_sources"] == {"lidar": len(track.frames)}
    by_frame = {lab.frame: lab for lab in truth[(track.sequence, track.tracking_id)]}
    for i, frame in enumerate(result.frames):
        g = by_frame[frame]
        true_pelvis = np.asarray(ctx.model.keypoints(g.pose, g.betas, g.trans))[[12, 13]].mean(axis=0)
        assert np.linalg.norm(result.world_keypoints[i, [12, 13]].mean(axis=0) - true_pelvis) < 0.18   # 0.07-0.12
    nothing = dataclasses.replace(stripped, frames=[dataclasses.replace(fr, world_lidar_points=np.zeros((0, 3)))
                                                    for fr in stripped.frames])
    with pytest.raises(ValueError, match="no LiDAR points"):
        fit_track(nothing, config, ctx)
