"""Calibration sanity at load: each rule refuses a bad value with an error naming the file and the key, from a
simulated dataset's good files with one key changed; a camera that has labels but no usable calibration is
named, and its labels are skipped while the other pair's tracks are read."""
from __future__ import annotations

import logging
import shutil

import numpy as np
import pytest

from pedx_graph.data.calib import CalibrationLimits, get_floats, read_calibrations, read_kitti_text
from pedx_graph.data.reader import read_dataset
from pedx_graph.data.types import DataFormatError
from pedx_graph.sim import rig_config, simulate

PAIR = "ylw79D0-red707B"
CAM_TO_CAM = f"calib_cam_to_cam_{PAIR}.txt"
CAM_TO_RANGE = "calib_cam_to_range_ylw79D0.txt"


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("sanity_scene")
    cfg = rig_config("pedx")                   # the real rig's numbers, z-down LiDAR frame
    cfg.scene.n_pedestrians = 3
    cfg.scene.n_frames = 3
    cfg.scene.all_views_prob = 1.0             # labels in both pairs: a bad pair leaves the other's tracks
    summary = simulate(out, cfg, seed=12)
    assert summary["labelled_instances_both_pairs"] > 0
    return out


def values(calib_dir, name: str, key: str) -> np.ndarray:
    entries = read_kitti_text(calib_dir / name)
    return get_floats(entries, key, len(entries[key].split()), calib_dir / name)


def with_key(scene, tmp_path, name: str, key: str, new_values) -> object:
    """A copy of ``scene``'s calib folder whose file ``name`` has ``key`` replaced by ``new_values``."""
    calib = tmp_path / "calib"
    shutil.copytree(scene / "calib", calib)
    lines = []
    for line in (calib / name).read_text().splitlines():
        if line.split(":", 1)[0].strip() == key:
            line = f"{key}: " + " ".join(repr(float(v)) for v in np.ravel(new_values))
        lines.append(line)
    (calib / name).write_text("\n".join(lines) + "\n")
    return calib


def refused(calib_dir, name: str, key: str, match: str) -> str:
    """The error of reading ``calib_dir`` names ``name``, ``key`` and ``match``; returns it."""
    errors: dict[str, str] = {}
    read_calibrations(calib_dir, errors=errors)
    assert set(errors) == {PAIR}, errors
    message = errors[PAIR]
    assert f"{name}: field '{key}'" in message and match in message, message
    assert "\n" not in message
    return message


def test_the_simulated_calibration_passes(scene):
    errors: dict[str, str] = {}
    calibs = read_calibrations(scene / "calib", errors=errors)
    assert not errors and len(calibs) == 2


def scaled_focal(scene, factor: float) -> np.ndarray:
    P = values(scene / "calib", CAM_TO_CAM, "P_rect_00").reshape(3, 4).copy()
    P[0, 0] *= factor
    P[1, 1] *= factor
    return P


@pytest.mark.parametrize("factor", [1e-9 / 3266.7, 0.03, 20.0])    # f = 1e-9 px, 98 px (174 deg), 65,000 px
def test_focal_length_must_fit_the_image(scene, tmp_path, factor):
    calib = with_key(scene, tmp_path, CAM_TO_CAM, "P_rect_00", scaled_focal(scene, factor))
    message = refused(calib, CAM_TO_CAM, "P_rect_00", "horizontal field of view")
    assert "outside 5-170 degrees" in message


def test_principal_point_near_the_image(scene, tmp_path):
    P = values(scene / "calib", CAM_TO_CAM, "P_rect_00").reshape(3, 4).copy()
    P[0, 2] = 5 * 3678
    refused(with_key(scene, tmp_path, CAM_TO_CAM, "P_rect_00", P), CAM_TO_CAM, "P_rect_00", "principal point")


def test_projection_must_be_rectified(scene, tmp_path):
    P = 2.0 * values(scene / "calib", CAM_TO_CAM, "P_rect_00").reshape(3, 4)      # scaled: third row 0 0 2
    refused(with_key(scene, tmp_path, CAM_TO_CAM, "P_rect_00", P), CAM_TO_CAM, "P_rect_00", "0 0 1")


def test_right_projection_shares_the_left_intrinsics(scene, tmp_path):
    P = values(scene / "calib", CAM_TO_CAM, "P_rect_01").reshape(3, 4).copy()
    P[0, 0] *= 1.05
    P[1, 1] *= 1.05
    P[0, 3] *= 1.05                                         # same baseline, another focal length
    refused(with_key(scene, tmp_path, CAM_TO_CAM, "P_rect_01", P), CAM_TO_CAM, "P_rect_01",
            "not a rectified pair")
    P = values(scene / "calib", CAM_TO_CAM, "P_rect_01").reshape(3, 4).copy()
    P[1, 2] += 40.0                                         # rows 40 px apart
    refused(with_key(scene, tmp_path / "rows", CAM_TO_CAM, "P_rect_01", P), CAM_TO_CAM, "P_rect_01",
            "principal row")


@pytest.mark.parametrize("baseline_m, match", [(-0.5, "baseline"), (0.001, "baseline"), (100.0, "baseline")])
def test_baseline_positive_and_plausible(scene, tmp_path, baseline_m, match):
    P = values(scene / "calib", CAM_TO_CAM, "P_rect_01").reshape(3, 4).copy()
    P[0, 3] = -P[0, 0] * baseline_m
    message = refused(with_key(scene, tmp_path, CAM_TO_CAM, "P_rect_01", P), CAM_TO_CAM, "P_rect_01", match)
    assert "0.01-5 m" in message


@pytest.mark.parametrize("key", ["R_rect_00", "R_rect_01"])
@pytest.mark.parametrize("kind", ["scaled", "mirrored"])
def test_rectification_rotations_are_rotations(scene, tmp_path, key, kind):
    rot = values(scene / "calib", CAM_TO_CAM, key).reshape(3, 3)
    bad = rot * 1.01 if kind == "scaled" else rot @ np.diag([1.0, 1.0, -1.0])     # det -1: a mirror
    refused(with_key(scene, tmp_path, CAM_TO_CAM, key, bad), CAM_TO_CAM, key, "not a rotation")


def test_extrinsic_rotation_is_a_rotation(scene, tmp_path):
    rot = values(scene / "calib", CAM_TO_RANGE, "R").reshape(3, 3)
    skewed = rot + 0.01 * np.arange(9).reshape(3, 3)
    refused(with_key(scene, tmp_path, CAM_TO_RANGE, "R", skewed), CAM_TO_RANGE, "R", "not a rotation")


def test_camera_within_reach_of_the_lidar(scene, tmp_path):
    shifted = values(scene / "calib", CAM_TO_RANGE, "T") + [100.0, 0.0, 0.0]          # an extrinsic 100 m off
    calib = with_key(scene, tmp_path, CAM_TO_RANGE, "T", shifted)
    refused(calib, CAM_TO_RANGE, "T", f"{np.linalg.norm(shifted):.4g} m from the LiDAR origin")
    # a dataset moved into another world frame on purpose reads with the limit lifted
    calibs = read_calibrations(calib, CalibrationLimits(max_camera_distance_m=None))
    np.testing.assert_allclose(calibs[PAIR].world_T_cam[:3, 3], shifted)


def test_non_finite_value_named(scene, tmp_path):
    rot = values(scene / "calib", CAM_TO_CAM, "R_rect_00").copy()
    rot[4] = np.nan
    refused(with_key(scene, tmp_path, CAM_TO_CAM, "R_rect_00", rot), CAM_TO_CAM, "R_rect_00", "non-finite")


def test_missing_cam_to_range_named_and_its_labels_skipped(scene, tmp_path, caplog):
    dataset = tmp_path / "ds"
    shutil.copytree(scene, dataset)
    (dataset / "calib" / CAM_TO_RANGE).unlink()
    with caplog.at_level(logging.WARNING):
        tracks = read_dataset(dataset)
    assert tracks and all(set(tr.calibrations) == {"blu79CF-grn43E3"} for tr in tracks)
    assert f"{CAM_TO_RANGE}: missing: stereo pair {PAIR} needs it" in caplog.text
    assert "camera ylw79D0 is in no calibrated stereo pair" in caplog.text


def test_missing_cam_to_cam_named(scene, tmp_path):
    dataset = tmp_path / "ds"
    shutil.copytree(scene, dataset)
    (dataset / "calib" / "calib_cam_to_cam_blu79CF-grn43E3.txt").unlink()
    (dataset / "calib" / CAM_TO_RANGE).write_text("R: 1 0 0 0 1 0 0 0 1.5\nT: 0 0 0\n")
    # no pair left: the error names what is wrong with the one that is there
    with pytest.raises(DataFormatError, match=rf"{CAM_TO_RANGE}: field 'R': not a rotation"):
        read_dataset(dataset)
    shutil.copy(scene / "calib" / CAM_TO_RANGE, dataset / "calib" / CAM_TO_RANGE)
    (dataset / "calib" / f"calib_cam_to_cam_{PAIR}.txt").rename(dataset / "calib" / "calib_cam_to_cam_xxx-yyy.txt")
    (dataset / "calib" / "calib_cam_to_range_xxx.txt").write_text((scene / "calib" / CAM_TO_RANGE).read_text())
    # the labelled cameras have no cam_to_cam file: the error names the file names that would calibrate them
    with pytest.raises(DataFormatError) as info:
        read_dataset(dataset)
    message = str(info.value)
    assert "no track could be read" in message and "calib_cam_to_cam_ylw79D0-<right>.txt" in message
    assert "calib_cam_to_cam_<left>-red707B.txt" in message and "\n" not in message
