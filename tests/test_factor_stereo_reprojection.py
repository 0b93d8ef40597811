"""Tests of factors/stereo_reprojection.py (E_J: every labelled image, one pair's two or any K >= 1)."""
import gtsam
import numpy as np
import pytest

from factors.common import FrameKeys, FrameState
from factors.stereo_reprojection import (DEFAULT_KEYPOINT_WEIGHTS, ImageKeypoints, StereoKeypoints,
                                         build_reprojection_setup, build_stereo_setup, make_reprojection_factor,
                                         make_stereo_reprojection_factor, stereo_dense_rows, stereo_pixels,
                                         stereo_reprojection_batch, stereo_reprojection_error)
from factor_testing import (ToyBodyModel, assert_factor_gradient, assert_factor_jacobians, frame_values,
                             make_test_calibration, standing_rotation)
from synthetic_model import synthetic_body_model
from pedx_graph.data.types import View2D

KEYS = FrameKeys.for_frame(2)


def _scene(rng, model):
    rot = standing_rotation(2.5) @ gtsam.Rot3.Expmap(rng.normal(scale=0.2, size=3)).matrix()
    trans = np.array([8.0, 0.5, 0.9]) + rng.normal(scale=0.2, size=3)
    body_pose = rng.normal(scale=0.2, size=69)
    betas = rng.normal(scale=0.5, size=model.num_betas)
    return rot, trans, body_pose, betas


def _labels(model, calib, state, rng, noise_px=0.0):
    kp = model.forward(state.full_pose, state.betas, state.trans).keypoints
    left, right = calib.project(kp)
    left = left + rng.normal(scale=noise_px, size=left.shape) if noise_px else left
    right = right + rng.normal(scale=noise_px, size=right.shape) if noise_px else right
    vis_l = rng.uniform(size=18) < 0.7
    vis_r = rng.uniform(size=18) < 0.7
    left[[3, 9]] = np.nan                          # not labelled in the left image
    vis_l[[3, 9]] = False
    return StereoKeypoints.from_views(View2D(left, vis_l), View2D(right, vis_r))


@pytest.mark.parametrize("model_kind", ["toy", "synthetic_smpl"])
def test_noise_free_zero_and_jacobians(model_kind):
    rng = np.random.default_rng(0)
    model = ToyBodyModel() if model_kind == "toy" else synthetic_body_model()
    calib = make_test_calibration()
    rot, trans, body_pose, betas = _scene(rng, model)
    state = FrameState.from_arrays(rot, trans, body_pose, betas)
    meas = _labels(model, calib, state, rng)
    f = make_stereo_reprojection_factor(KEYS, model, meas, calib, robust="none")
    v = frame_values(KEYS.as_list(), rot, trans, body_pose, betas)
    assert f.dim() == 2 * (16 + 18)
    np.testing.assert_allclose(f.unwhitenedError(v), 0.0, atol=1e-8)
    # perturbed state: Jacobians vs central differences, key by key
    v2 = frame_values(KEYS.as_list(), rot @ gtsam.Rot3.Expmap([0.1, -0.2, 0.05]).matrix(), trans + 0.1,
                      body_pose + rng.normal(scale=0.1, size=69), betas + 0.3)
    assert f.error(v2) > 1.0
    s2 = FrameState.from_arrays(v2.atRot3(KEYS.root).matrix(), v2.atVector(KEYS.trans),
                                v2.atVector(KEYS.body_pose), v2.atVector(KEYS.betas))
    setup = build_stereo_setup(meas, calib)
    r_only, _ = stereo_reprojection_error(model, s2, setup)
    r_with, _ = stereo_reprojection_error(model, s2, setup, want_jacobians=True)
    np.testing.assert_allclose(r_only, r_with, atol=1e-9)            # both evaluation paths agree
    assert_factor_jacobians(f, v2, rtol=1e-5, atol=1e-4)


def test_rows_sigmas_and_weights():
    rng = np.random.default_rng(1)
    model = ToyBodyModel()
    calib = make_test_calibration()
    state = FrameState.from_arrays(*_scene(rng, model))
    meas = _labels(model, calib, state, rng)
    weights = np.ones(18)
    weights[0] = 0.0                                # nose dropped
    weights[5] = 4.0                                # neck twice as certain
    setup = build_stereo_setup(meas, calib, sigma_px=2.0, sigma_occluded_px=8.0, keypoint_weights=weights)
    left_idx = setup.images[0].index
    assert 0 not in left_idx and 3 not in left_idx and 9 not in left_idx and 5 in left_idx
    sig_left = setup.sigmas[: 2 * left_idx.size].reshape(-1, 2)[:, 0]
    expected = np.where(meas.left_visible[left_idx], 2.0, 8.0) / np.sqrt(weights[left_idx])
    np.testing.assert_allclose(sig_left, expected)
    empty = StereoKeypoints.from_views(None, None)
    assert make_stereo_reprojection_factor(KEYS, model, empty, calib) is None


def test_robust_kernel_acts_on_each_keypoints_offset():
    """The kernel takes a keypoint's whitened 2D offset in each image as a whole: a label whose column is
    300 px off and whose row is right loses both rows (a per-row kernel would keep its row).  Linearised,
    the rows are reweighted (IRLS): ``A^T b`` is the error's gradient, ``A^T A`` the reweighted one."""
    rng = np.random.default_rng(2)
    model = ToyBodyModel()
    calib = make_test_calibration()
    rot, trans, body_pose, betas = _scene(rng, model)
    state = FrameState.from_arrays(rot, trans, body_pose, betas)
    meas = _labels(model, calib, state, rng, noise_px=1.0)
    meas.right_uv[7, 0] += 300.0                     # one mislabelled keypoint: its column only
    v = frame_values(KEYS.as_list(), rot, trans, body_pose, betas)
    gauss = make_stereo_reprojection_factor(KEYS, model, meas, calib, robust="none")
    robust = make_stereo_reprojection_factor(KEYS, model, meas, calib, robust="gemanmcclure", robust_scale=3.0)
    white = np.asarray(gauss.whitenedError(v)).reshape(-1, 2)
    c = 3.0
    norm2 = np.sum(white ** 2, axis=1)
    assert robust.error(v) == pytest.approx(np.sum(0.5 * c * c * norm2 / (c * c + norm2)), rel=1e-9)
    assert robust.error(v) < 0.05 * gauss.error(v)
    row = 2 * (16 + 7)                               # the left image labels 16 keypoints, the right all 18
    assert abs(white[16 + 7, 0]) > 30 and abs(white[16 + 7, 1]) < 3
    a_gauss, _ = gauss.linearize(v).jacobian()
    a_robust, _ = robust.linearize(v).jacobian()
    for r in (row, row + 1):                         # both rows of the keypoint nearly switched off
        assert np.linalg.norm(a_robust[r]) < 0.1 * np.linalg.norm(a_gauss[r])
    kept = [r for r in range(len(a_gauss)) if r not in (row, row + 1)]
    ratio = np.linalg.norm(a_robust[kept], axis=1) / np.maximum(np.linalg.norm(a_gauss[kept], axis=1), 1e-12)
    assert np.median(ratio) > 0.8                    # inliers keep most of their weight
    w = (c * c / (c * c + norm2)) ** 2                # Geman-McClure's IRLS weight of each keypoint-image
    np.testing.assert_allclose(a_robust, np.repeat(np.sqrt(w), 2)[:, None] * a_gauss, rtol=1e-9, atol=1e-12)
    v2 = frame_values(KEYS.as_list(), rot @ gtsam.Rot3.Expmap([0.05, -0.1, 0.02]).matrix(), trans + 0.03,
                      body_pose + rng.normal(scale=0.05, size=69), betas + 0.1)
    assert_factor_gradient(robust, v2, rtol=1e-4, atol=1e-5)


def test_matches_gtsam_generic_stereo_factor():
    """Single keypoint at ``trans``: residual and d/dtrans agree with GenericStereoFactor3D."""
    model = ToyBodyModel()
    kp0 = model.keypoint_vertex_ids[0]
    model.template[kp0] = 0.0
    model.shapedirs[kp0] = 0.0
    model.posedirs[kp0] = 0.0                        # keypoint 0 == trans exactly
    calib = make_test_calibration(rect_angle=0.0)
    rng = np.random.default_rng(3)
    rot, _, body_pose, betas = _scene(rng, model)
    point = np.array([7.0, -0.8, 1.1])
    meas_l = np.full((18, 2), np.nan)
    meas_r = np.full((18, 2), np.nan)
    meas_l[0] = [1000.0, 640.0]
    meas_r[0] = [930.0, 640.0]
    meas = StereoKeypoints(meas_l, meas_r, np.ones(18, bool), np.ones(18, bool))
    ours = make_stereo_reprojection_factor(KEYS, model, meas, calib, robust="none", sigma_px=1.0)
    v = frame_values(KEYS.as_list(), rot, point, body_pose, betas)
    r = ours.unwhitenedError(v)                      # [uL, vL, uR, vR] - z

    k = calib.left_P_rect
    cal = gtsam.Cal3_S2Stereo(k[0, 0], k[1, 1], 0.0, k[0, 2], k[1, 2], calib.baseline_m)
    kx, kl = gtsam.symbol("x", 0), gtsam.symbol("l", 0)
    theirs = gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(1000.0, 930.0, 640.0),
                                         gtsam.noiseModel.Unit.Create(3), kx, kl, cal)
    tv = gtsam.Values()
    tv.insert(kx, gtsam.Pose3(calib.world_T_cam))
    tv.insert(kl, point)
    e = theirs.unwhitenedError(tv)                   # [uL, uR, v] - z
    np.testing.assert_allclose([r[0], r[2], r[1]], e, atol=1e-9)
    np.testing.assert_allclose(r[3], e[2], atol=1e-9)
    a_theirs = theirs.linearize(tv).jacobian()[0][:, 6:9]
    a_ours = ours.linearize(v).jacobian()[0][:, 3:6]
    np.testing.assert_allclose(a_ours[[0, 2, 1]], a_theirs, rtol=1e-9, atol=1e-9)


def test_point_behind_camera_is_finite():
    model = ToyBodyModel()
    calib = make_test_calibration()
    rng = np.random.default_rng(4)
    rot, _, body_pose, betas = _scene(rng, model)
    state = FrameState.from_arrays(rot, np.array([-5.0, 0.0, 0.9]), body_pose, betas)
    meas = _labels(model, calib, FrameState.from_arrays(rot, np.array([8.0, 0.0, 0.9]), body_pose, betas), rng)
    setup = build_stereo_setup(meas, calib)
    r, blocks = stereo_reprojection_error(model, state, setup, want_jacobians=True)
    assert np.all(np.isfinite(r)) and all(np.all(np.isfinite(b)) for b in blocks)


# --- K >= 1 images (every camera that labels the pedestrian) -------------------------------------------

def _second_pair():
    """A second pair 0.9 m to the side of the test pair, turned 20 degrees (its own projections)."""
    import dataclasses

    base = make_test_calibration()
    turn = gtsam.Rot3.Rz(np.deg2rad(20.0)).matrix()
    world_T_cam = base.world_T_cam.copy()
    world_T_cam[:3, :3] = turn @ world_T_cam[:3, :3]
    world_T_cam[:3, 3] += [0.0, 0.9, 0.0]
    return dataclasses.replace(base, name="pair-b", world_T_cam=world_T_cam,
                               rect_R_cam=gtsam.Rot3.Rx(-0.01).matrix())


def _images(model, state, rng, count):
    """``count`` ImageKeypoints (left, right of the test pair, then of the second pair), labelled at ``state``
    with 3 px noise, a few keypoints missing in each, some not visible."""
    calibs = [(make_test_calibration(), "left"), (make_test_calibration(), "right"), (_second_pair(), "left"),
              (_second_pair(), "right")][:count]
    kp = model.forward(state.full_pose, state.betas, state.trans).keypoints
    out = []
    for calib, side in calibs:
        uv = calib.project(kp)[0 if side == "left" else 1] + rng.normal(scale=3.0, size=(18, 2))
        uv[rng.choice(18, 3, replace=False)] = np.nan
        view = View2D(uv, rng.uniform(size=18) < 0.7)
        out.append(ImageKeypoints.from_view(view, calib, side))
    return out


@pytest.mark.parametrize("count", [1, 2, 3, 4])
@pytest.mark.parametrize("model_kind", ["toy", "synthetic_smpl"])
def test_k_view_jacobians_match_numerical(count, model_kind):
    """K images, each with its own projection, per-keypoint sigmas: the residual is each image's projection
    minus its labels (image by image) and GTSAM's linearisation matches central differences at a random,
    non-identity state away from the labels."""
    rng = np.random.default_rng(10 + count)
    model = ToyBodyModel() if model_kind == "toy" else synthetic_body_model()
    rot, trans, body_pose, betas = _scene(rng, model)
    images = _images(model, FrameState.from_arrays(rot, trans, body_pose, betas), rng, count)
    sigma = rng.uniform(1.0, 6.0, size=18)
    sigma_occ = 3.0 * sigma
    f = make_reprojection_factor(KEYS, model, images, sigma_px=sigma, sigma_occluded_px=sigma_occ, robust="none")
    rows = sum(int(np.all(np.isfinite(im.uv), axis=1).sum()) for im in images)
    assert f.dim() == 2 * rows
    expected_sigma = np.concatenate([np.repeat(np.where(im.visible, sigma, sigma_occ)
                                               / np.sqrt(DEFAULT_KEYPOINT_WEIGHTS), 2)
                                     [np.repeat(np.all(np.isfinite(im.uv), axis=1), 2)] for im in images])
    setup = build_reprojection_setup(images, sigma_px=sigma, sigma_occluded_px=sigma_occ)
    np.testing.assert_allclose(setup.sigmas, expected_sigma, rtol=1e-12)
    np.testing.assert_allclose(f.noiseModel().sigmas(), 1.0)       # whitened inside the factor
    moved = (rot @ gtsam.Rot3.Expmap(rng.normal(scale=0.2, size=3)).matrix(), trans + rng.normal(scale=0.1, size=3),
             body_pose + rng.normal(scale=0.1, size=69), betas + rng.normal(scale=0.3, size=model.num_betas))
    v = frame_values(KEYS.as_list(), *moved)
    world_p = model.forward(np.concatenate([gtsam.Rot3.Logmap(gtsam.Rot3(moved[0])), moved[2]]), moved[3],
                            moved[1]).keypoints
    expected = []
    for im in images:
        hom = np.c_[world_p, np.ones(18)] @ im.image_P_world.T
        ok = np.all(np.isfinite(im.uv), axis=1)
        expected.append((hom[:, :2] / hom[:, 2:3] - im.uv)[ok].reshape(-1))
    np.testing.assert_allclose(f.unwhitenedError(v) * expected_sigma, np.concatenate(expected), atol=1e-6)
    assert f.error(v) > 1.0
    assert_factor_jacobians(f, v, rtol=1e-5, atol=1e-4)


def test_per_keypoint_sigmas_and_validation():
    rng = np.random.default_rng(20)
    model = ToyBodyModel()
    state = FrameState.from_arrays(*_scene(rng, model))
    images = _images(model, state, rng, 2)
    sigma = np.linspace(1.0, 5.0, 18)
    setup = build_reprojection_setup(images, sigma_px=sigma, sigma_occluded_px=12.0,
                                     keypoint_weights=np.ones(18))
    first = setup.images[0]
    np.testing.assert_allclose(setup.sigmas[:2 * first.index.size:2],
                               np.where(images[0].visible[first.index], sigma[first.index], 12.0))
    with pytest.raises(ValueError, match="sigma_px"):
        build_reprojection_setup(images, sigma_px=np.ones(17))
    with pytest.raises(ValueError, match="sigma_occluded_px"):
        build_reprojection_setup(images, sigma_occluded_px=-1.0)


def test_stereo_pair_factor_is_the_two_image_factor():
    """``make_stereo_reprojection_factor`` (one pair) equals ``make_reprojection_factor`` of its two images;
    an image without labels is left out of the setup."""
    rng = np.random.default_rng(21)
    model = ToyBodyModel()
    calib = make_test_calibration()
    rot, trans, body_pose, betas = _scene(rng, model)
    meas = _labels(model, calib, FrameState.from_arrays(rot, trans, body_pose, betas), rng, noise_px=2.0)
    v = frame_values(KEYS.as_list(), rot, trans + 0.05, body_pose, betas)
    pair = make_stereo_reprojection_factor(KEYS, model, meas, calib, robust="none")
    images = make_reprojection_factor(KEYS, model, meas.images(calib), robust="none")
    np.testing.assert_allclose(pair.unwhitenedError(v), images.unwhitenedError(v), atol=1e-12)
    left_only = StereoKeypoints.from_views(View2D(meas.left_uv, meas.left_visible), None)
    setup = build_stereo_setup(left_only, calib)
    assert setup.num_images == 1 and setup.images[0].index.size == 16


def test_batch_with_different_image_counts_equals_single_frames():
    """Frames with 1, 4 and 2 images in one batch (padded to 4): each frame's rows and blocks equal its own
    single-frame evaluation, and the padding rows carry inverse sigma 0."""
    rng = np.random.default_rng(22)
    model = synthetic_body_model()
    setups, states = [], []
    for count in (1, 4, 2):
        rot, trans, body_pose, betas = _scene(rng, model)
        state = FrameState.from_arrays(rot, trans, body_pose, betas)
        setups.append(build_reprojection_setup(_images(model, state, rng, count)))
        states.append(FrameState.from_arrays(rot, trans + 0.1, body_pose, betas))
    pose = np.stack([s.full_pose for s in states])
    betas = np.stack([s.betas for s in states])
    trans = np.stack([s.trans for s in states])
    jac = model.point_jacobians(pose, betas, trans)
    uv, d_uv = stereo_pixels(jac.points, setups, True)
    assert uv.shape == (3, 4, 18, 2) and d_uv.shape == (3, 4, 18, 2, 3)
    batch = stereo_reprojection_batch(jac.points, setups, jac)
    for i, su in enumerate(setups):
        r1, b1 = stereo_reprojection_error(model, states[i], su, want_jacobians=True)
        np.testing.assert_allclose(batch[i][0], r1, atol=1e-9)
        for a, b in zip(batch[i][1], b1):
            np.testing.assert_allclose(a, b, atol=1e-9)
        meas, inv = stereo_dense_rows(su, 4)
        assert not np.any(inv[su.num_images:]) and not np.any(d_uv[i, su.num_images:])
        assert np.count_nonzero(inv) == su.rows
