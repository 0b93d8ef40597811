"""Plausibility fields of every fitted track (pedx_graph.solvers.body_checks): the posed meshes' signed
volumes, inside-out frames, the largest |beta|, and the ``monocular`` flag."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scene_fixtures import small_scene

from pedx_graph.body import BodyModel
from pedx_graph.data.reader import read_dataset
from pedx_graph.data.types import TrackFrame, View2D
from pedx_graph.graph.config import FitConfig
from pedx_graph.solvers.body_checks import body_plausibility, is_monocular, mesh_signed_volumes
from pedx_graph.solvers.fit import _context, fit_track


@pytest.fixture(scope="module")
def model():
    return BodyModel.load()


def _walking_poses(n: int, seed: int = 0) -> np.ndarray:
    from pedx_graph.motion.gait import procedural_gait

    return procedural_gait("walk", 1.3, duration=0.1 * n, seed=seed).body_pose_aa[:n]


def test_normal_bodies_have_positive_volume(model):
    pose = _walking_poses(5)
    betas = np.random.default_rng(0).normal(size=model.num_betas)
    volumes = mesh_signed_volumes(model, pose, betas)
    assert np.all(volumes > 0.03) and np.all(volumes < 0.2)          # tens of litres, m^3
    per_frame, track = body_plausibility(model, pose, betas)
    assert track["inside_out_frames"] == 0 and track["max_abs_beta"] == pytest.approx(np.max(np.abs(betas)))
    assert [f["mesh_signed_volume_m3"] for f in per_frame] == pytest.approx(list(volumes))


def test_a_mirrored_body_is_detected_inside_out(model):
    """A large negative first shape coefficient scales the body through zero: on the shipped model the
    mesh turns inside out past beta_0 ~ -30 (at -30 itself it is still a sliver of 2 % of the volume,
    mirrored in two axes); -40 is inside out in every frame."""
    pose = _walking_poses(4)
    betas = np.zeros(model.num_betas)
    betas[0] = -40.0
    per_frame, track = body_plausibility(model, pose, betas)
    assert track["inside_out_frames"] == 4 and all(f["mesh_signed_volume_m3"] < 0 for f in per_frame)
    assert track["max_abs_beta"] == 40.0 and track["mesh_volume_ratio"] < 0
    betas[0] = -30.0
    assert body_plausibility(model, pose, betas)[1]["mesh_volume_ratio"] < 0.1
    # the sign follows the mesh, not the model file's winding
    flipped = dataclasses.replace(model.data, faces=model.data.faces[:, ::-1].copy())
    model_flipped = BodyModel.from_data(flipped)
    np.testing.assert_allclose(mesh_signed_volumes(model_flipped, pose, np.zeros(model.num_betas)),
                               mesh_signed_volumes(model, pose, np.zeros(model.num_betas)), rtol=1e-12)


def _view(n_labelled: int) -> View2D:
    kp = np.full((18, 2), np.nan)
    kp[:n_labelled] = 100.0
    return View2D(kp, np.arange(18) < n_labelled)


def test_monocular_flag():
    left_only = [TrackFrame(i, 0.1 * i, "p", _view(18), None) for i in range(3)]
    assert is_monocular(left_only)
    assert is_monocular([TrackFrame(0, 0.0, "p", _view(18), _view(0))])        # a right view with no keypoints
    assert not is_monocular(left_only + [TrackFrame(3, 0.3, "p", _view(18), _view(2))])
    assert not is_monocular(left_only + [TrackFrame(3, 0.3, "p", None, _view(5),
                                                    world_lidar_points=np.ones((3, 3)))])
    assert is_monocular([TrackFrame(0, 0.0, "p", None, _view(5), world_lidar_points=np.ones((2, 3)))])


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return small_scene(tmp_path_factory.mktemp("plausibility_scene"), pedestrians=2, frames=4, seed=1)


def test_a_normal_fit_writes_positive_volumes_everywhere(scene):
    config = FitConfig(covariances=False, diagnostics=True)
    ctx = _context(config)
    tracks = read_dataset(scene)
    assert tracks
    for track in tracks:
        result = fit_track(track, config, ctx)
        volumes = np.array([f["mesh_signed_volume_m3"] for f in result.extra_per_frame])
        assert len(volumes) == len(track.frames) and np.all(volumes > 0)
        assert result.extra_track["mesh_check"] == "per_frame" and result.extra_track["inside_out_frames"] == 0
        assert result.extra_track["max_abs_beta"] == pytest.approx(np.max(np.abs(result.betas)))
        assert result.extra_track["max_abs_beta"] <= config.noise.shape_support_sd + 0.1
        assert 0.6 < result.extra_track["mesh_volume_ratio"] < 1.6
        assert result.extra_track["monocular"] is False
        labels = result.to_labels()
        assert labels[0].extra["mesh_signed_volume_m3"] == pytest.approx(volumes[0])
    # covariances and diagnostics off (the solve timed alone): the track's shape is checked at rest
    quick = fit_track(tracks[0], FitConfig(covariances=False, diagnostics=False), ctx)
    assert quick.extra_track["mesh_check"] == "rest_pose" and quick.extra_track["inside_out_frames"] == 0
    assert "max_abs_beta" in quick.extra_track and "monocular" in quick.extra_track


def test_rest_pose_check_flags_an_inside_out_shape(model):
    betas = np.zeros(model.num_betas)
    betas[0] = -40.0
    frames, track = body_plausibility(model, _walking_poses(3), betas, per_frame=False)
    assert frames == [] and track["mesh_check"] == "rest_pose" and track["inside_out_frames"] == 3
