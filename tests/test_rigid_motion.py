"""No hidden axis: move a whole simulated scene (calibration, point clouds, segments, truth) by a rigid motion,
fit it again, and the results move with it (issue: the real PedX LiDAR frame has z down, the simulator's z up).

The motions: the PedX convention (a half turn about x: z down), and random rotations with shifts.  Every fitted
keypoint, root orientation, translation and covariance must follow within 1 mm / 1e-3 rad.
"""
import numpy as np
import pytest
from scene_fixtures import small_scene
from scipy.spatial.transform import Rotation

from pedx_graph.body import BodyModel
from pedx_graph.data.calib import CalibrationLimits
from pedx_graph.data.reader import read_smpl_labels
from pedx_graph.data.transform import transform_dataset, transform_smpl
from pedx_graph.graph.config import FitConfig
from pedx_graph.solvers.fit import fit_dataset


def _motions() -> dict[str, np.ndarray]:
    z_down = np.eye(4)
    z_down[:3, :3] = np.diag([1.0, -1.0, -1.0])
    z_down[:3, 3] = [-2.0, 0.3, 0.4]
    out = {"z_down": z_down}
    rng = np.random.default_rng(2026)
    for name in ("random_a", "random_b"):
        motion = np.eye(4)
        motion[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        motion[:3, 3] = rng.uniform(-50.0, 50.0, 3)
        out[name] = motion
    return out


@pytest.fixture(scope="module")
def model():
    return BodyModel.load()


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return small_scene(tmp_path_factory.mktemp("rigid_scene"), pedestrians=3, frames=5, seed=5)


@pytest.fixture(scope="module")
def reference(scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("rigid_ref")
    summary = fit_dataset(scene, out, FitConfig())
    assert summary["tracks"] and not summary["failed"]
    return read_smpl_labels(out), summary


@pytest.mark.parametrize("name", sorted(_motions()))
def test_results_move_with_the_scene(name, scene, reference, model, tmp_path):
    dst_T_src = _motions()[name]
    rot, shift = dst_T_src[:3, :3], dst_T_src[:3, 3]
    moved = tmp_path / "moved"
    transform_dataset(scene, moved, dst_T_src, model)
    out = tmp_path / "fit"
    # the moved world frame puts the cameras up to ~90 m from its origin: lift the calibration sanity limit for a
    # LiDAR frame (20 m), which assumes the frame is the vehicle's
    summary = fit_dataset(moved, out, FitConfig(calibration_limits=CalibrationLimits(max_camera_distance_m=None)))
    ref_labels, ref_summary = reference
    assert len(summary["tracks"]) == len(ref_summary["tracks"]) and not summary["failed"]
    # the derived up axis moved with the data
    (seq, ground), = summary["ground"].items()
    np.testing.assert_allclose(ground["world_up"], rot @ np.asarray(ref_summary["ground"][seq]["world_up"]),
                               atol=1e-6)
    labels = read_smpl_labels(out)
    assert labels.keys() == ref_labels.keys()
    for key, labs in labels.items():
        for lab, ref in zip(labs, ref_labels[key], strict=True):
            assert lab.frame == ref.frame
            kp = np.asarray(lab.extra["keypoints_3d"])
            kp_ref = np.asarray(ref.extra["keypoints_3d"]) @ rot.T + shift
            assert np.max(np.linalg.norm(kp - kp_ref, axis=1)) < 1e-3            # 1 mm
            pose_ref, trans_ref = transform_smpl(dst_T_src, ref.pose, ref.trans,
                                                 model.rest_joints(ref.betas)[0])
            root_err = Rotation.from_rotvec(lab.pose[:3]) * Rotation.from_rotvec(pose_ref[:3]).inv()
            assert root_err.magnitude() < 1e-3                                       # 1e-3 rad
            np.testing.assert_allclose(lab.pose[3:], ref.pose[3:], atol=1e-3)
            np.testing.assert_allclose(lab.betas, ref.betas, atol=1e-3)
            np.testing.assert_allclose(lab.trans, trans_ref, atol=1e-3)
            if lab.extra.get("covariance_status") == "ok":
                cov = np.asarray(lab.extra["cov_keypoints_3d"])
                cov_ref = rot @ np.asarray(ref.extra["cov_keypoints_3d"]) @ rot.T
                np.testing.assert_allclose(cov, cov_ref, atol=1e-3 * np.max(np.abs(cov_ref)) + 1e-9)
