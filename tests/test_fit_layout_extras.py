"""A detector track's keypoints without a PedX row (ears, toes, heels, OpenPose's Neck / MidHip, ...) enter the
reprojection term as the fit layout's rows 18 .. 18 + E - 1, each its own point on the body model."""
import dataclasses
from collections import Counter

import gtsam
import numpy as np
import pytest

from factor_testing import assert_factor_jacobians, frame_values, make_test_calibration, standing_rotation
from factors.common import FrameKeys
from factors.stereo_reprojection import ImageKeypoints, image_projection, make_reprojection_factor
from pedx_graph.body import BodyModel
from pedx_graph.data.reader import read_dataset, read_smpl_labels
from pedx_graph.detections.fit_layout import extra_sources, fit_layout, layout_model, layout_track, row_sources
from pedx_graph.graph.build import build_track_graph
from pedx_graph.graph.config import FitConfig
from pedx_graph.graph.init import initialise_track
from pedx_graph.keypoints import PEDX_KEYPOINTS, load_keypoint_set
from pedx_graph.solvers.batched import BatchedLinearizer
from pedx_graph.solvers.context import estimator_context
from pedx_graph.solvers.fit import fit_track
from scene_fixtures import small_scene
from test_detections_fit import mpjpe, relabel

#: Each set's keypoints that fill no PedX row, in the set's order (the layout's extra rows).
EXPECTED_EXTRAS = {
    "coco17": ("left_ear", "right_ear"),
    "coco18": ("Neck", "REar", "LEar"),
    "body25": ("Neck", "MidHip", "REar", "LEar", "LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe",
               "RHeel"),
    "body25b": ("LEar", "REar", "Neck", "Head", "LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe",
                "RHeel"),
}


@pytest.fixture(scope="module")
def model():
    return BodyModel.load()


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = small_scene(tmp_path_factory.mktemp("extras") / "scene", pedestrians=3, frames=8, seed=1)
    tracks = [t for t in read_dataset(root) if len(t.frames) >= 6]
    return tracks, read_smpl_labels(root)


def random_body(rng, num_betas=10):
    """A non-identity pose (72,), shape and translation."""
    return rng.normal(scale=0.3, size=72), rng.normal(scale=0.8, size=num_betas), rng.normal(size=3)


@pytest.mark.parametrize("set_name", sorted(EXPECTED_EXTRAS))
def test_layout_rows_are_pedx_rows_then_the_sets_extra_keypoints(model, set_name):
    kset = load_keypoint_set(set_name)
    src, extra = row_sources(set_name), extra_sources(set_name)
    assert tuple(kset.keypoints[i] for i in extra) == EXPECTED_EXTRAS[set_name]
    # every keypoint of the set is used exactly once: in its PedX row or as an extra row
    assert sorted(src[src >= 0].tolist() + extra.tolist()) == list(range(len(kset.keypoints)))
    laid = layout_model(model, set_name)
    assert laid.keypoint_names == PEDX_KEYPOINTS + EXPECTED_EXTRAS[set_name]
    assert laid.report_model is model and model.report_model is model
    pose, betas, trans = random_body(np.random.default_rng(3))
    points = laid.keypoints(pose, betas, trans)
    own = model.for_keypoint_set(set_name).keypoints(pose, betas, trans)
    pedx = model.keypoints(pose, betas, trans)
    assert points.shape == (18 + len(extra), 3)
    for row in range(18):                       # PedX rows: the set's own point where it has one, else PedX's
        want = own[src[row]] if src[row] >= 0 else pedx[row]
        np.testing.assert_allclose(points[row], want, atol=1e-12)
    np.testing.assert_allclose(points[18:], own[extra], atol=1e-12)        # extra rows: the set's own points
    jac = laid.point_jacobians(pose, betas, trans)
    np.testing.assert_allclose(jac.points, points, atol=1e-12)
    assert np.asarray(jac.d_body_pose).shape == (18 + len(extra), 3, 69)


def test_pedx18_has_no_extra_rows(scene):
    tracks, _ = scene
    assert extra_sources("pedx18").size == 0
    ctx = estimator_context(FitConfig())
    laid, laid_ctx, _ = fit_layout(tracks[0], ctx, FitConfig())
    assert laid is tracks[0] and laid_ctx is ctx


def test_laid_out_views_carry_the_extra_pixels_and_their_own_sigma(scene, model):
    tracks, truth = scene
    track = relabel(tracks[0], truth[(tracks[0].sequence, tracks[0].tracking_id)], model, "body25", seed=4)
    fr = track.frames[0]
    raw = fr.left or fr.right
    sigma = np.linspace(1.0, 6.0, len(raw.keypoints))            # a different sigma per keypoint
    raw = dataclasses.replace(raw, sigma_px=sigma)
    track = dataclasses.replace(track, frames=[dataclasses.replace(fr, left=raw, right=None, other_views={})])
    view = layout_track(track, model_sigma_px=2.0).frames[0].left
    extra = extra_sources("body25")
    assert view.keypoints.shape == (28, 2) and view.visible.shape == (28,) and view.sigma_px.shape == (28,)
    np.testing.assert_array_equal(view.keypoints[18:], raw.keypoints[extra])
    np.testing.assert_allclose(view.sigma_px[18:], np.hypot(sigma[extra], 2.0))
    pedx = view.pedx_rows()
    assert pedx.keypoints.shape == (18, 2) and pedx.sigma_px.shape == (18,)
    np.testing.assert_array_equal(pedx.keypoints, view.keypoints[:18])


def _reprojection(problem, frame: int):
    (j,) = [j for j, (kind, f) in enumerate(zip(problem.factor_kinds, problem.factor_frames))
            if kind == "stereo_reprojection" and f == frame]
    return problem.graph.at(j)


def _move_pixel(track, frame: int, row: int, shift_px: float):
    """``track`` with keypoint ``row`` of the primary left view of ``frame`` moved right by ``shift_px``."""
    fr = track.frames[frame]
    kp = fr.left.keypoints.copy()
    kp[row, 0] += shift_px
    frames = list(track.frames)
    frames[frame] = dataclasses.replace(fr, left=dataclasses.replace(fr.left, keypoints=kp))
    return dataclasses.replace(track, frames=frames)


def _body25_problem(scene, model, index: int, seed: int):
    """``(graph, laid-out track, its context, config)`` of the scene's track ``index`` relabelled as BODY_25
    detections, in the fit layout."""
    tracks, truth = scene
    base = tracks[index]
    track = relabel(base, truth[(base.sequence, base.tracking_id)], model, "body25", seed=seed)
    config = FitConfig()
    laid, laid_ctx, _ = fit_layout(track, estimator_context(config), config)
    return build_track_graph(laid, laid_ctx, config), laid, laid_ctx, config


def test_extra_keypoints_enter_the_reprojection_term(scene, model):
    """Moving only an extra keypoint's pixel (a toe, a heel, an ear) changes the graph's reprojection
    residual; the factor has rows for every labelled keypoint of the set (PedX rows and extras)."""
    problem, laid, laid_ctx, config = _body25_problem(scene, model, 0, seed=5)
    values = problem.initial
    factor = _reprojection(problem, 0)
    images = len(laid.frames[0].labelled_views())
    labelled = sum(int(v.labelled.sum()) for _, _, v in laid.frames[0].labelled_views())
    assert labelled > images * 18 - 3 * images            # more rows than PedX's 18 minus head, mouth, neck
    assert factor.dim() == 2 * labelled
    error = factor.error(values)
    body25 = load_keypoint_set("body25").keypoints
    for name in ("LBigToe", "RHeel", "LEar", "MidHip"):
        row = 18 + list(extra_sources("body25")).index(body25.index(name))
        moved = _move_pixel(laid, 0, row, 25.0)
        other = build_track_graph(moved, laid_ctx, config, init=problem.init)
        assert _reprojection(other, 0).error(values) != pytest.approx(error, rel=1e-6), name
        assert _reprojection(other, 1).error(values) == pytest.approx(_reprojection(problem, 1).error(values),
                                                                      rel=1e-12)
    # the initialisation measures the PedX rows only: the same with the extra rows cut off
    pedx_only = dataclasses.replace(laid, frames=[fr.pedx_rows() for fr in laid.frames])
    a = initialise_track(laid)
    b = initialise_track(pedx_only)
    np.testing.assert_array_equal(a.world_p_centre, b.world_p_centre)
    np.testing.assert_array_equal(a.world_R_body, b.world_R_body)


def test_reprojection_jacobians_with_extra_rows(model):
    """The factor's Jacobians over 18 + E rows (BODY_25: E = 10) match GTSAM's numerical derivatives at a
    random non-identity point."""
    rng = np.random.default_rng(11)
    laid = layout_model(model, "body25")
    calib = make_test_calibration()
    keys = FrameKeys.for_frame(0)
    body_pose = rng.normal(scale=0.3, size=69)
    betas = rng.normal(scale=0.8, size=10)
    world_R_body = standing_rotation(0.7) @ gtsam.Rot3.Expmap(rng.normal(scale=0.2, size=3)).matrix()
    trans = np.array([8.0, 0.5, 0.4])
    root = gtsam.Rot3.Logmap(gtsam.Rot3(world_R_body))
    points = laid.keypoints(np.concatenate([root, body_pose]), betas, trans)
    assert points.shape == (28, 3)
    images = []
    for side in ("left", "right"):
        proj = image_projection(calib, side)
        hom = np.c_[points, np.ones(len(points))] @ proj.T
        uv = hom[:, :2] / hom[:, 2:] + rng.normal(scale=3.0, size=(len(points), 2))
        uv[4] = np.nan                                                     # mouth: not in BODY_25
        images.append(ImageKeypoints(uv, np.ones(len(points), bool), proj, side,
                                     np.linspace(2.0, 5.0, len(points))))
    factor = make_reprojection_factor(keys, laid, images, sigma_px=3.0, robust="none")
    assert factor.dim() == 2 * 2 * 27
    values = frame_values(keys.as_list(), world_R_body, trans - 0.03, body_pose + 0.05, betas)
    assert_factor_jacobians(factor, values, rtol=1e-4, atol=1e-4)


def test_batched_paths_equal_the_factors_own_rows_with_extra_rows(scene, model):
    """The batched linearizer (the term's assembler through the keypoints) gives the error and chain system
    of GTSAM's linearisation of a BODY_25 track's graph whose factors compute their own rows."""
    problem, laid, laid_ctx, config = _body25_problem(scene, model, 1, seed=6)
    rng = np.random.default_rng(2)
    values = gtsam.Values(problem.initial)
    for k in problem.keys:
        values.update(k.root, values.atRot3(k.root).compose(gtsam.Rot3.Expmap(rng.normal(scale=0.1, size=3))))
        values.update(k.body_pose, values.atVector(k.body_pose) + rng.normal(scale=0.2, size=69))
    values.update(problem.keys[0].betas, rng.normal(scale=0.5, size=10))
    lin = BatchedLinearizer(problem)
    error, system = lin.error(values), lin.system(values)
    assert len(lin.served["stereo_reprojection"]) == len(problem.keys)
    fresh = build_track_graph(laid, laid_ctx, config, init=problem.init)
    fresh.body.lookup = lambda *args, **kwargs: None                        # never served: own rows
    reference = fresh.layout.assemble(fresh.graph.linearize(values))
    assert error == pytest.approx(fresh.graph.error(values), rel=1e-10)
    for name in ("frame", "next", "frame_shape", "shape", "grad_frame", "grad_shape"):
        x, y = getattr(system, name), getattr(reference, name)
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-9 * max(np.abs(y).max(), 1e-12), err_msg=name)


def test_body25_tracks_fit_with_their_extra_keypoints(scene, model):
    """BODY_25 labels of the truth bodies (2 px noise, known ids) fit to a bounded keypoint error; results
    (keypoints and their covariances) are PedX's 18."""
    tracks, truth = scene
    config = FitConfig()
    config.covariances = True
    errors = []
    for track in tracks:
        labels = truth[(track.sequence, track.tracking_id)]
        result = fit_track(relabel(track, labels, model, "body25", seed=7), config)
        assert result.world_keypoints.shape == (len(track.frames), 18, 3)
        np.testing.assert_allclose(result.world_keypoints, model.keypoints(
            result.pose, np.broadcast_to(result.betas, (len(result.pose), 10)), result.trans), atol=1e-9)
        covs = [f["cov_keypoints_3d"] for f in result.extra_per_frame if f.get("cov_keypoints_3d") is not None]
        assert covs and all(np.shape(c) == (18, 3, 3) for c in covs)
        errors.append(mpjpe(result, labels, model))
    assert np.mean(errors) < 0.045, errors           # measured 0.030 m (tracks 27, 27, 36 mm)


def test_a_detector_track_not_laid_out_is_refused_by_name(scene, model):
    """Building the graph of a COCO track without its fit layout is a one-line error naming the track, its
    keypoint set and the layout to use (not a shape error deep in the initialisation)."""
    tracks, truth = scene
    base = tracks[0]
    track = relabel(base, truth[(base.sequence, base.tracking_id)], model, "coco17", seed=3)
    config = FitConfig()
    with pytest.raises(ValueError, match=r"'coco17' keypoints; lay the track out .*fit_layout") as err:
        build_track_graph(track, estimator_context(config), config)
    assert base.tracking_id in str(err.value) and "\n" not in str(err.value)


def _row_sigmas(problem, frame: int) -> np.ndarray:
    """The per-row sigmas (pixels) of a frame's reprojection factor: the term whitens its rows inside the
    factor, so they are read from the term's registered spec."""
    keys = tuple(_reprojection(problem, frame).keys())
    return np.asarray(problem.body.specs("stereo_reprojection")[keys].setup.sigmas)


def test_a_detector_tracks_hips_keep_their_own_sigma_pedx_hips_get_the_hip_factor(scene, model):
    """``hip_sigma_factor`` stands for PedX's hip rows projecting the model's hip joints while the labels mark
    the surface.  A detector set's hip rows project its own surface hips and their labels carry their own
    sigma (with the hips' ambiguity in it): in the fit layout every row keeps the label's sigma (combined
    with the model error), the hips too; PedX labels still get the factor on the hips."""
    tracks, truth = scene
    base = tracks[0]
    config = FitConfig()
    assert config.noise.hip_sigma_factor == 2.0
    hips = [PEDX_KEYPOINTS.index("lhip"), PEDX_KEYPOINTS.index("rhip")]
    for set_name in ("coco17", "body25"):
        track = relabel(base, truth[(base.sequence, base.tracking_id)], model, set_name, seed=6)
        laid, laid_ctx, laid_config = fit_layout(track, estimator_context(config), config)
        assert laid_config.noise.hip_sigma_factor == 1.0 and config.noise.hip_sigma_factor == 2.0
        # and the left/right label screen with the detector's prior, the manual labels' (0) untouched
        assert laid_config.noise.left_right_swap_prob == config.noise.detector_left_right_swap_prob > 0
        assert config.noise.left_right_swap_prob == 0.0
        problem = build_track_graph(laid, laid_ctx, laid_config)
        view = laid.frames[0].labelled_views()[0][2]
        assert view.labelled[hips].all()
        sigmas = _row_sigmas(problem, 0)
        want = view.sigma_px[view.labelled]          # the label's sigma, the model error already combined in
        np.testing.assert_allclose(sigmas[:2 * len(want)], np.repeat(want, 2), rtol=1e-9)
    # PedX labels: the hips' rows are the factor times the others'
    problem = build_track_graph(base, estimator_context(config), config)
    view = base.frames[0].labelled_views()[0][2]
    labelled = np.flatnonzero(view.labelled)
    sigmas = _row_sigmas(problem, 0)[:2 * len(labelled):2]
    on_hips = np.isin(labelled, hips)
    assert on_hips.any()
    ratio = sigmas[on_hips] / np.median(sigmas[~on_hips])
    assert np.all(ratio > 1.5 * config.noise.hip_sigma_factor / 2.0)


def test_a_detector_tracks_exchanged_labels_are_exchanged_back(scene, model):
    """BODY_25 labels (known ids) with one image's legs exchanged (knees, ankles, toes, heels) in frame 3 and
    every pair of both images exchanged in frame 4 (a back view read as a front view): the fit's left/right
    screen exchanges frame 4's images back whole and, in the end, nothing else whole, and the error comes
    back near the clean labels'; with the screen off the exchanges stay."""
    from pedx_graph.keypoints import mirror_index
    from pedx_graph.solvers.mirror import mirrored_view

    names = load_keypoint_set("body25").keypoints
    pairs = mirror_index(names)
    legs = [p for p in pairs if any(part in names[p[0]] for part in ("Knee", "Ankle", "Toe", "Heel"))]
    assert len(legs) == 5
    errors = {"clean": [], "on": [], "off": []}
    for track in scene[0]:
        labels = scene[1][(track.sequence, track.tracking_id)]
        clean = relabel(track, labels, model, "body25", seed=7)
        frames = list(clean.frames)
        frames[3] = dataclasses.replace(frames[3], left=mirrored_view(frames[3].left, legs))
        frames[4] = dataclasses.replace(frames[4], left=mirrored_view(frames[4].left, pairs),
                                        right=mirrored_view(frames[4].right, pairs))
        bad = dataclasses.replace(clean, frames=frames)
        for name, labelled, swap_prob in (("clean", clean, 0.05), ("on", bad, 0.05), ("off", bad, 0.0)):
            config = FitConfig()
            config.noise.detector_left_right_swap_prob = swap_prob
            result = fit_track(labelled, config)
            errors[name].append(mpjpe(result, labels, model))
            records = result.extra_track.get("mirrored_labels", [])
            # images exchanged whole an odd number of times (a later pass may exchange one back)
            counts = Counter((r["frame"], r["side"]) for r in records if r["keypoints"] == "all")
            whole = sorted(k for k, n in counts.items() if n % 2)
            if name == "on":
                f4 = int(frames[4].frame)
                assert whole == [(f4, "left"), (f4, "right")], records
            else:
                assert whole == [] and (name == "clean" or records == [])
    on, off, clean = (float(np.mean(errors[k])) for k in ("on", "off", "clean"))
    assert on < 0.6 * off and on < 1.25 * clean, errors        # measured 0.42 x and 1.06 x
