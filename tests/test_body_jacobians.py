"""Analytic Jacobians of keypoints, vertices and joints against central finite differences.

Root: against the retraction ``world_R_body <- world_R_body Exp(delta)``; body pose, betas, trans: additive.
Checked at seeded random poses, at zero, at 1e-7 angles and at |theta| = pi - 1e-4.
"""
import numpy as np
import pytest

from pedx_graph.body import BodyModel
from pedx_graph.body.io import validate_model_arrays
from synthetic_model import synthetic_model_arrays
from pedx_graph.body.rotation import exp_so3, log_so3

STEP = 1e-6
ATOL = 2e-8       # central differences with h = 1e-6 on O(1) functions: truncation ~1e-12, rounding ~1e-10


def _pose_cases():
    rng = np.random.default_rng(20)
    axes = rng.normal(size=(24, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return {
        "random": rng.normal(scale=0.6, size=72),
        "zero": np.zeros(72),
        "tiny": (axes * 1e-7).ravel(),
        "near_pi": (axes * (np.pi - 1e-4)).ravel(),
        "mixed": np.where(rng.uniform(size=72) < 0.3, 0.0, rng.normal(scale=1.0, size=72)),
    }


POSES = _pose_cases()


def _numeric(fun, x, step=STEP):
    cols = [(fun(x + step * e) - fun(x - step * e)) / (2 * step) for e in np.eye(len(x))]
    return np.stack(cols, axis=-1)


def _check_all(model, pose, betas, trans, points_fn, jac):
    np.testing.assert_allclose(jac.points, points_fn(pose, betas, trans), atol=1e-12)
    # body pose, additive
    def body(x):
        return points_fn(np.concatenate([pose[:3], x]), betas, trans)
    np.testing.assert_allclose(jac.d_body_pose, _numeric(body, pose[3:]), atol=ATOL)
    # root, right perturbation through the rotation matrix (the GTSAM Rot3 retraction)
    world_r_body = exp_so3(pose[:3])

    def root(delta):
        p = pose.copy()
        p[:3] = log_so3(world_r_body @ exp_so3(delta))
        return points_fn(p, betas, trans)
    np.testing.assert_allclose(jac.d_root, _numeric(root, np.zeros(3)), atol=ATOL)
    np.testing.assert_allclose(jac.d_betas, _numeric(lambda b: points_fn(pose, b, trans), betas), atol=ATOL)
    np.testing.assert_allclose(jac.d_trans, _numeric(lambda t: points_fn(pose, betas, t), trans), atol=ATOL)


@pytest.mark.parametrize("case", sorted(POSES))
def test_keypoint_jacobians(case, synthetic_body_model):
    rng = np.random.default_rng(21)
    pose, betas, trans = POSES[case], rng.normal(size=10), rng.normal(size=3)
    jac = synthetic_body_model.point_jacobians(pose, betas, trans)
    assert jac.points.shape == (18, 3) and jac.d_body_pose.shape == (18, 3, 69)
    assert jac.d_root.shape == (18, 3, 3) and jac.d_betas.shape == (18, 3, 10) and jac.d_trans.shape == (18, 3, 3)
    _check_all(synthetic_body_model, pose, betas, trans, synthetic_body_model.keypoints, jac)


@pytest.mark.parametrize("case", ["random", "zero", "tiny", "near_pi"])
def test_vertex_subset_jacobians(case, synthetic_body_model):
    rng = np.random.default_rng(22)
    ids = np.array([0, 5, 123, 250, 299])
    pose, betas, trans = POSES[case], rng.normal(size=10), rng.normal(size=3)
    jac = synthetic_body_model.point_jacobians(pose, betas, trans, vertex_ids=ids)
    assert jac.points.shape == (5, 3)

    def fn(p, b, t):
        return synthetic_body_model.vertices_subset(p, b, t, ids)
    _check_all(synthetic_body_model, pose, betas, trans, fn, jac)


@pytest.mark.parametrize("case", ["random", "near_pi"])
def test_joint_jacobians(case, synthetic_body_model):
    rng = np.random.default_rng(23)
    pose, betas, trans = POSES[case], rng.normal(size=10), rng.normal(size=3)
    jac = synthetic_body_model.joints_and_jacobians(pose, betas, trans)
    assert jac.points.shape == (24, 3)
    _check_all(synthetic_body_model, pose, betas, trans, synthetic_body_model.joints, jac)


def test_jacobians_without_posedirs():
    arrays = synthetic_model_arrays(num_vertices=120, seed=5, with_posedirs=False)
    model = BodyModel.from_data(validate_model_arrays(arrays))
    assert model.posedirs is None
    rng = np.random.default_rng(24)
    pose, betas, trans = POSES["random"], rng.normal(size=10), rng.normal(size=3)
    _check_all(model, pose, betas, trans, model.keypoints, model.point_jacobians(pose, betas, trans))


def test_root_jacobian_is_rotation_about_the_pelvis_at_every_heading(synthetic_body_model):
    """d p / d delta = -hat(p - o_root) world_R_body (weights sum to one), finite at headings 0..2pi and pi."""
    rng = np.random.default_rng(25)
    betas, trans = rng.normal(size=10), rng.normal(size=3)
    body = rng.normal(scale=0.4, size=69)
    for heading in [0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi, 2 * np.pi - 1e-9]:
        root_aa = log_so3(exp_so3(np.array([0.0, 0.0, heading])) @ exp_so3(np.array([np.pi / 2, 0, 0])))
        pose = np.concatenate([root_aa, body])
        jac = synthetic_body_model.point_jacobians(pose, betas, trans)
        pelvis = synthetic_body_model.joints(pose, betas, trans)[0]
        lever = jac.points - pelvis
        world_r_body = exp_so3(root_aa)
        expect = np.stack([np.cross(world_r_body[:, m], lever) for m in range(3)], axis=-1)
        np.testing.assert_allclose(jac.d_root, expect, atol=1e-12)


def test_batched_jacobians_equal_single_frames(synthetic_body_model):
    rng = np.random.default_rng(26)
    pose = rng.normal(scale=0.5, size=(2, 3, 72))
    betas = rng.normal(size=(2, 3, 10))
    trans = rng.normal(size=(2, 3, 3))
    jac = synthetic_body_model.point_jacobians(pose, betas, trans)
    assert jac.d_body_pose.shape == (2, 3, 18, 3, 69)
    one = synthetic_body_model.point_jacobians(pose[1, 0], betas[1, 0], trans[1, 0])
    for name in ("points", "d_root", "d_body_pose", "d_trans", "d_betas"):
        np.testing.assert_allclose(getattr(jac, name)[1, 0], getattr(one, name), atol=1e-13)


def test_smpl_topology_keypoints_with_mouth_rule_have_correct_jacobians():
    """V = 6890 and no pedx keys: the SMPL vertex ids and the mouth rule (a 3-term affine map)."""
    arrays = synthetic_model_arrays(num_vertices=6890, seed=6, with_keypoint_keys=False)
    model = BodyModel.from_data(validate_model_arrays(arrays))
    assert model.keypoint_map.source == "smpl-topology"
    rng = np.random.default_rng(27)
    pose, betas, trans = POSES["random"], rng.normal(size=10), rng.normal(size=3)
    jac = model.point_jacobians(pose, betas, trans)
    _check_all(model, pose, betas, trans, model.keypoints, jac)
