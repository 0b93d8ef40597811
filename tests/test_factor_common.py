"""Tests of factors/common.py (noise models, Jacobian plumbing, key bundles) and a one-frame solve."""
import gtsam
import numpy as np
import pytest

from factors import (FrameKeys, FrameState, StereoKeypoints, make_heading_prior_factor, make_lidar_chamfer_factor,
                     make_noise, make_shape_prior_factor, make_stereo_reprojection_factor,
                     make_translation_prior_factor, read_frame_state)
from factors.common import set_jacobians
from factor_testing import frame_values, make_test_calibration, standing_rotation
from synthetic_model import synthetic_body_model
from pedx_graph.body.rotation import log_so3


def test_make_noise_kernels_and_validation():
    base = make_noise([1.0, 2.0])
    np.testing.assert_allclose(base.sigmas(), [1.0, 2.0])
    for kernel in ("gemanmcclure", "huber", "cauchy"):
        assert isinstance(make_noise(0.5, dim=4, robust=kernel), gtsam.noiseModel.Robust)
    with pytest.raises(ValueError, match="kernel"):
        make_noise(1.0, dim=2, robust="tukey-ish")
    with pytest.raises(ValueError, match="sigmas"):
        make_noise([1.0, 0.0])


def test_set_jacobians_checks_shapes():
    H = [None, None]
    set_jacobians(H, [np.zeros((4, 3)), np.ones((4, 69))], 4, [3, 69])
    assert H[1].flags["C_CONTIGUOUS"] and H[1].dtype == np.float64
    with pytest.raises(ValueError, match="expected"):
        set_jacobians(H, [np.zeros((4, 3)), np.zeros((3, 69))], 4, [3, 69])


def test_keys_and_state():
    keys = FrameKeys.for_frame(5)
    assert keys.as_list() == [gtsam.symbol(c, 5) for c in "rtp"] + [gtsam.symbol("b", 0)]
    rng = np.random.default_rng(0)
    rot = gtsam.Rot3.Expmap(rng.normal(size=3))
    v = frame_values(keys.as_list(), rot.matrix(), np.ones(3), np.zeros(69), np.zeros(10))
    s = read_frame_state(v, keys.as_list())
    np.testing.assert_allclose(s.root_rotvec, log_so3(rot.matrix()), atol=1e-12)
    assert s.full_pose.shape == (72,)


def test_one_frame_levenberg_marquardt_recovers_truth():
    """Stereo + LiDAR + priors on one frame (synthetic SMPL-format model): LM from a nearby start reaches the truth.

    (Point-to-point chamfer has local minima when the start is farther than the vertex spacing, as ICP does:
    the graph builder's initialisation and the stereo term must bring the estimate close first.)
    """
    rng = np.random.default_rng(3)
    model = synthetic_body_model(num_vertices=1000)
    calib = make_test_calibration()
    keys = FrameKeys.for_frame(0)
    truth = FrameState.from_arrays(standing_rotation(2.8), np.array([8.0, 0.4, 0.9]),
                                   rng.normal(scale=0.2, size=69), rng.normal(scale=0.5, size=10))
    out = model.forward(truth.full_pose, truth.betas, truth.trans)
    left, right = calib.project(out.keypoints)
    meas = StereoKeypoints(left, right, np.ones(18, bool), np.ones(18, bool))
    pts = out.vertices[rng.choice(1000, 100, replace=False)]
    graph = gtsam.NonlinearFactorGraph()
    graph.add(make_stereo_reprojection_factor(keys, model, meas, calib, sigma_px=1.0))
    graph.add(make_lidar_chamfer_factor(keys, model, pts, sigma_m=0.02))
    graph.add(make_heading_prior_factor(keys.root, 2.8, speed=1.3, world_R_level=np.eye(3)))
    graph.add(make_shape_prior_factor(keys.betas, sigma=3.0))
    graph.add(make_translation_prior_factor(keys.trans, keys.betas, model, pts, world_up=np.array([0.0, 0.0, 1.0]),
                                            world_p_sensor=np.zeros(3), sigma_ray_m=1.0,
                                            sigma_lateral_m=1.0, sigma_vertical_m=1.0))
    graph.add(gtsam.PriorFactorVector(keys.body_pose, truth.body_pose, gtsam.noiseModel.Isotropic.Sigma(69, 0.3)))
    init = frame_values(keys.as_list(), truth.world_R_body @ gtsam.Rot3.Expmap([0.01, 0.02, -0.02]).matrix(),
                        truth.trans + [0.02, -0.02, 0.01], truth.body_pose + rng.normal(scale=0.01, size=69),
                        truth.betas * 0.9)
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(50)
    result = gtsam.LevenbergMarquardtOptimizer(graph, init, params).optimize()
    est = read_frame_state(result, keys.as_list())
    assert graph.error(result) < 1e-3 * graph.error(init)
    kp_est = model.forward(est.full_pose, est.betas, est.trans).keypoints
    assert np.max(np.linalg.norm(kp_est - out.keypoints, axis=1)) < 0.01        # metres
    cov = gtsam.Marginals(graph, result).marginalCovariance(keys.trans)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


def test_robust_noise_reweights_each_row_in_linearization():
    """Scalar scheme: per-row IRLS weights sqrt(w(r_i)), Geman-McClure w = c^4 / (c^2 + r^2)^2."""
    r = np.array([0.5, 0.5, 0.5, 10.0])
    jac = np.arange(8.0).reshape(4, 2) + 1.0

    def err(this, values, H):
        if H is not None:
            H[0] = jac
        return r

    f = gtsam.CustomFactor(make_noise(1.0, dim=4, robust="gemanmcclure", robust_scale=1.0), [1], err)
    v = gtsam.Values()
    v.insert(1, np.zeros(2))
    a, b = f.linearize(v).jacobian()
    sw = 1.0 / (1.0 + r ** 2)
    np.testing.assert_allclose(a, sw[:, None] * jac, rtol=1e-12)
    np.testing.assert_allclose(b, -sw * r, rtol=1e-12)


@pytest.mark.parametrize("kernel", ["gemanmcclure", "huber", "cauchy"])
def test_group_robust_transform(kernel):
    from factors.common import robustify_groups
    c = 1.5
    rho = {"gemanmcclure": lambda n: 0.5 * c * c * n * n / (c * c + n * n),
           "huber": lambda n: np.where(n <= c, 0.5 * n * n, c * n - 0.5 * c * c),
           "cauchy": lambda n: 0.5 * c * c * np.log1p(n * n / (c * c))}[kernel]
    rng = np.random.default_rng(7)
    white = np.vstack([np.zeros(3), 1e-5 * rng.normal(size=3), rng.normal(size=(6, 3)) * 2.0, [[8.0, -3.0, 1.0]]])
    s, _ = robustify_groups(white, kernel, c)
    np.testing.assert_allclose(0.5 * (s.reshape(-1, 3) ** 2).sum(axis=1), rho(np.linalg.norm(white, axis=1)),
                               rtol=1e-10, atol=1e-14)
    # Jacobian of s w.r.t. white (identity blocks) vs central differences
    eye = [np.eye(white.size)]
    _, (jac,) = robustify_groups(white, kernel, c, eye)
    num = np.zeros_like(jac)
    eps = 1e-6
    for k in range(white.size):
        d = np.zeros(white.size)
        d[k] = eps
        sp, _ = robustify_groups((white.reshape(-1) + d).reshape(-1, 3), kernel, c)
        sm, _ = robustify_groups((white.reshape(-1) - d).reshape(-1, 3), kernel, c)
        num[:, k] = (sp - sm) / (2 * eps)
    np.testing.assert_allclose(jac, num, atol=1e-7)


@pytest.mark.parametrize("kernel", ["none", "gemanmcclure", "huber", "cauchy"])
def test_group_norms_are_recovered_from_their_losses(kernel):
    """The inverse of each kernel: a group's whitened norm from the loss ``|s|^2 / 2`` of its robustified
    rows, inliers and outliers (a 400-sigma offset too)."""
    from factors.common import group_norms_from_losses, robustify_groups
    c = 3.0
    rng = np.random.default_rng(8)
    white = np.vstack([np.zeros(2), rng.normal(size=(20, 2)) * 2.0, [[0.0, 40.0], [-400.0, 3.0]]])
    s, _ = robustify_groups(white, kernel, c)
    loss = 0.5 * (s.reshape(-1, 2) ** 2).sum(axis=1)
    np.testing.assert_allclose(group_norms_from_losses(loss, kernel, c), np.linalg.norm(white, axis=1),
                               rtol=1e-6, atol=1e-9)
