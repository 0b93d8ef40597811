"""Implausible estimates never pass as successes: each check of pedx_graph.solvers.plausibility on a fitted
track changed one way, and the issue's absurd inputs (a focal length of 1e-9 px, keypoints x 1e6, an extrinsic
shifted 5 m and 100 m) through the batch fit, ADMM, the stream and a dataset run: a failed track with the reason,
nothing written for it."""
from __future__ import annotations

import copy
import dataclasses
import json

import numpy as np
import pytest

from pedx_graph.data.calib import CalibrationLimits, get_floats, read_kitti_text
from pedx_graph.data.reader import read_dataset
from pedx_graph.data.types import DataFormatError, Track
from pedx_graph.graph.config import FitConfig
from pedx_graph.sim.config import SimConfig
from pedx_graph.sim.simulate import simulate
from pedx_graph.solvers.fit import _context, fit_dataset, fit_track
from pedx_graph.solvers.plausibility import ImplausibleEstimateError, PlausibilityConfig, check_track_result


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("plausibility_scene")
    cfg = SimConfig()
    cfg.scene.n_pedestrians = 3
    cfg.scene.n_frames = 5
    simulate(out, cfg, seed=3)
    return out


@pytest.fixture(scope="module")
def track(scene):
    return max(read_dataset(scene), key=lambda t: len(t.frames))


@pytest.fixture(scope="module")
def fitted(track):
    return fit_track(track, FitConfig(), _context(FitConfig()))


def reasons_of(result, track, config=None) -> list[str]:
    with pytest.raises(ImplausibleEstimateError) as info:
        check_track_result(result, track, config or FitConfig())
    assert track.tracking_id in str(info.value) and "\n" not in str(info.value)
    return info.value.reasons


def test_a_good_fit_passes_and_is_recorded(fitted, track):
    record = fitted.extra_track["plausibility"]
    assert 5.0 < record["max_distance_m"] < 60.0 and record["min_depth_m"] > 3.0
    assert record["max_abs_beta"] <= 3.5 + 0.25
    assert set(record["outlier_fraction"]) == {"stereo_reprojection", "lidar_chamfer"}
    assert max(record["outlier_fraction"].values()) < 0.5


def test_non_finite(fitted, track):
    bad = copy.deepcopy(fitted)
    bad.trans[1, 0] = np.nan
    bad.world_keypoints[1] = np.nan
    assert reasons_of(bad, track) == ["non_finite"]


def test_too_far_and_behind_the_camera(fitted, track):
    far = copy.deepcopy(fitted)
    ray = far.world_keypoints.mean(axis=1) - track.ground.world_p_sensor
    far.world_keypoints += 20.0 * ray[:, None, :]                           # ~20x the distance: > 200 m
    assert reasons_of(far, track) == ["too_far"]
    behind = copy.deepcopy(fitted)
    behind.world_keypoints -= 2.0 * ray[:, None, :]                         # mirrored through the rig
    assert "behind_camera" in reasons_of(behind, track)
    # the limit is the config's
    config = FitConfig(plausibility=PlausibilityConfig(max_distance_m=1e4))
    check_track_result(copy.deepcopy(far), track, config)


def test_shape_outside_the_prior(fitted, track):
    bad = copy.deepcopy(fitted)
    bad.betas[2] = -4.0                                                     # support 3.5 + margin 0.25
    assert reasons_of(bad, track) == ["shape_outside_prior"]
    bad.betas[2] = -3.7
    check_track_result(copy.deepcopy(bad), track, FitConfig())
    no_support = FitConfig()
    no_support.noise.shape_support_sd = 0.0                                 # no support term: max_abs_beta
    bad.betas[2] = -5.5
    assert reasons_of(bad, track, no_support) == ["shape_outside_prior"]


def test_inside_out_only_judged_on_a_closed_mesh(fitted, track):
    bad = copy.deepcopy(fitted)
    bad.extra_track["inside_out_frames"] = 2
    assert fitted.extra_track["mesh_closed"] is True
    assert reasons_of(bad, track) == ["inside_out"]
    bad.extra_track["mesh_closed"] = False
    check_track_result(bad, track, FitConfig())


def test_inconsistent_residuals(fitted, track):
    bad = copy.deepcopy(fitted)
    totals = bad.extra_track["diagnostics"]["residuals"]["stereo_reprojection"]
    totals["outlier_rows"] = int(0.75 * totals["rows"])
    assert reasons_of(bad, track) == ["inconsistent_residuals"]
    config = FitConfig(plausibility=PlausibilityConfig(max_outlier_fraction=0.8))
    check_track_result(copy.deepcopy(bad), track, config)
    # LiDAR rows: a segment may be mostly background; only a nearly complete rejection fails the track
    lidar = copy.deepcopy(fitted)
    chamfer = lidar.extra_track["diagnostics"]["residuals"]["lidar_chamfer"]
    chamfer["outlier_rows"] = int(0.6 * chamfer["rows"])
    check_track_result(copy.deepcopy(lidar), track, FitConfig())
    chamfer["outlier_rows"] = chamfer["rows"]
    assert reasons_of(lidar, track) == ["inconsistent_residuals"]
    config = FitConfig(plausibility=PlausibilityConfig(enabled=False))
    far = copy.deepcopy(bad)
    far.trans[:] = np.inf
    check_track_result(far, track, config)


# --- the absurd inputs, through the solvers ----------------------------------------------------------

def tiny_focal(calib):
    scale = 1e-9 / calib.left_P_rect[0, 0]
    left, right = calib.left_P_rect.copy(), calib.right_P_rect.copy()
    for P in (left, right):
        P[0, 0] *= scale
        P[1, 1] *= scale
        P[0, 3] *= scale
    return dataclasses.replace(calib, left_P_rect=left, right_P_rect=right)


def shifted(offset_m):
    def move(calib):
        world_T_cam = calib.world_T_cam.copy()
        world_T_cam[:3, 3] += offset_m
        return dataclasses.replace(calib, world_T_cam=world_T_cam)
    return move


def with_calibrations(track: Track, change) -> Track:
    return Track(track.sequence, track.tracking_id, track.frames,
                 {name: change(calib) for name, calib in track.calibrations.items()})


def with_scaled_keypoints(track: Track, factor: float) -> Track:
    def scale(view):
        return None if view is None else dataclasses.replace(view, keypoints=view.keypoints * factor)
    frames = [dataclasses.replace(fr, left=scale(fr.left), right=scale(fr.right)) for fr in track.frames]
    return Track(track.sequence, track.tracking_id, frames, track.calibrations)


@pytest.mark.parametrize("name, make, expected", [
    ("focal 1e-9 px", lambda tr: with_calibrations(tr, tiny_focal), "too_far"),
    ("keypoints x 1e6", lambda tr: with_scaled_keypoints(tr, 1e6), "too_far"),
    ("extrinsic +5 m", lambda tr: with_calibrations(tr, shifted([5.0, 0.0, 0.0])), "inconsistent_residuals"),
    ("extrinsic +100 m", lambda tr: with_calibrations(tr, shifted([0.0, 100.0, 0.0])), "inconsistent_residuals"),
])
def test_absurd_inputs_fail_the_track(track, name, make, expected):
    """The readers refuse these at load (calibration sanity, keypoints outside the image); built in memory they
    still reach the solver, and its estimate is refused."""
    with pytest.raises(ImplausibleEstimateError) as info:
        fit_track(make(track), FitConfig(), _context(FitConfig()))
    assert expected in info.value.reasons, (name, str(info.value))


def test_admm_refuses_the_same(track):
    from pedx_graph.solvers.admm import fit_track_admm

    bad = with_calibrations(track, shifted([5.0, 0.0, 0.0]))
    with pytest.raises(ImplausibleEstimateError, match="inconsistent_residuals"):
        fit_track_admm(bad, FitConfig(), _context(FitConfig()))


def _dataset_with_shifted_extrinsic(scene, tmp_path, offset_m: float):
    import shutil

    dataset = tmp_path / "ds"
    shutil.copytree(scene, dataset)
    path = dataset / "calib" / "calib_cam_to_range_ylw79D0.txt"
    entries = read_kitti_text(path)
    moved = get_floats(entries, "T", 3, path) + [offset_m, 0.0, 0.0]
    path.write_text(f"R: {entries['R']}\nT: {' '.join(repr(float(v)) for v in moved)}\n")
    return dataset


def test_dataset_run_records_failed_tracks_and_writes_none(scene, tmp_path):
    dataset = _dataset_with_shifted_extrinsic(scene, tmp_path, 5.0)       # within the 20 m calibration limit
    out = tmp_path / "out"
    summary = fit_dataset(dataset, out, FitConfig())
    n_tracks = len(read_dataset(dataset))
    assert len(summary["failed"]) == n_tracks and not summary["tracks"]
    for failed in summary["failed"]:
        assert "ImplausibleEstimateError" in failed["error"] and "inconsistent_residuals" in failed["error"]
    assert json.loads((out / "summary.json").read_text())["failed"]
    assert not (out / "labels").exists() or not any((out / "labels").rglob("*.json"))


def test_stream_refuses_the_same(scene, tmp_path):
    from pedx_graph.solvers.stream import StreamConfig, stream_dataset

    dataset = _dataset_with_shifted_extrinsic(scene, tmp_path, 5.0)
    out = tmp_path / "stream"
    summary = stream_dataset(dataset, out, FitConfig(), StreamConfig(marginals=False, diagnostics=False))
    failed = [f for f in summary["failed"] if "ImplausibleEstimateError" in f["error"]]
    assert {f["tracking_id"] for f in failed} == {t.tracking_id for t in read_dataset(dataset)}
    smoothed = out / "labels" / "3d" / "smpl"                  # (the causal per-frame estimates are under causal/)
    assert not smoothed.exists() or not any(smoothed.rglob("*.json"))


def test_calibration_limit_applies_through_the_fit_config(scene, tmp_path):
    dataset = _dataset_with_shifted_extrinsic(scene, tmp_path, 100.0)
    config = FitConfig(calibration_limits=CalibrationLimits(max_camera_distance_m=None))
    assert read_dataset(dataset, config=config.reader_config())
    with pytest.raises(DataFormatError, match="m from the LiDAR origin"):
        read_dataset(dataset, config=FitConfig().reader_config())
