"""Fitting tracks labelled in a detector's keypoint set: the set's own 3D points are projected (fit layout)."""
import dataclasses

import numpy as np
import pytest

from pedx_graph.body import BodyModel
from pedx_graph.body.keypoint_defs import load_keypoint_set
from pedx_graph.data.reader import read_dataset, read_smpl_labels
from pedx_graph.data.types import View2D
from pedx_graph.detections.fit_layout import layout_model, layout_track, row_sources
from pedx_graph.graph.config import FitConfig
from pedx_graph.keypoints import PEDX_KEYPOINTS
from pedx_graph.solvers.fit import fit_track
from scene_fixtures import small_scene

NOISE_PX = 2.0


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = small_scene(tmp_path_factory.mktemp("detfit") / "scene", pedestrians=3, frames=8, seed=1)
    tracks = [t for t in read_dataset(root) if len(t.frames) >= 6]
    truth = read_smpl_labels(root)
    return tracks, truth


def relabel(track, truth_labels, model: BodyModel, set_name: str, seed: int):
    """The track with every labelled view replaced by the truth body's keypoints of ``set_name`` (its own
    definitions), projected and perturbed by NOISE_PX, where at least one PedX keypoint was labelled."""
    by_frame = {lab.frame: lab for lab in truth_labels}
    set_model = model.for_keypoint_set(set_name)
    rng = np.random.default_rng(seed)
    frames = []
    for fr in track.frames:
        lab = by_frame[fr.frame]
        world = set_model.keypoints(lab.pose, lab.betas, lab.trans)

        def view(pair, side, old):
            if old is None:
                return None
            uv = track.calibrations[pair].project(world)[0 if side == "left" else 1]
            uv = uv + rng.normal(scale=NOISE_PX, size=uv.shape)
            k = len(uv)
            if set_name == "pedx18":                      # manual labels: the config's noise
                return View2D(keypoints=uv, visible=np.ones(k, bool))
            return View2D(keypoints=uv, visible=np.ones(k, bool), keypoint_set=set_name,
                          sigma_px=np.full(k, NOISE_PX), confidence=np.full(k, 0.9))
        frames.append(dataclasses.replace(
            fr, left=view(fr.pair, "left", fr.left), right=view(fr.pair, "right", fr.right),
            other_views={p: (view(p, "left", a), view(p, "right", b)) for p, (a, b) in fr.other_views.items()}))
    return dataclasses.replace(track, frames=frames)


def mpjpe(result, truth_labels, model) -> float:
    by_frame = {lab.frame: lab for lab in truth_labels}
    errs = []
    for i, frame in enumerate(result.frames):
        lab = by_frame[frame]
        true_kps = model.keypoints(lab.pose, lab.betas, lab.trans)
        errs.append(np.linalg.norm(result.world_keypoints[i] - true_kps, axis=1).mean())
    return float(np.mean(errs))


def test_layout_rows_use_the_sets_own_points():
    model = BodyModel.load()
    src = row_sources("coco17")
    coco = load_keypoint_set("coco17").keypoints
    assert src[PEDX_KEYPOINTS.index("head")] == -1 and src[PEDX_KEYPOINTS.index("mouth")] == -1
    assert coco[src[PEDX_KEYPOINTS.index("lhip")]] == "left_hip"
    pose, betas = np.zeros(72), np.zeros(10)
    laid = layout_model(model, "coco17").keypoints(pose, betas)
    own = model.for_keypoint_set("coco17").keypoints(pose, betas)
    pedx = model.keypoints(pose, betas)
    lhip = PEDX_KEYPOINTS.index("lhip")
    np.testing.assert_allclose(laid[lhip], own[coco.index("left_hip")], atol=1e-12)
    assert np.linalg.norm(laid[lhip] - pedx[lhip]) > 0.02          # the surface hip, not SMPL's joint
    np.testing.assert_allclose(laid[PEDX_KEYPOINTS.index("head")], pedx[PEDX_KEYPOINTS.index("head")], atol=1e-12)


def test_layout_track_moves_views_into_pedx_rows(scene):
    tracks, truth = scene
    model = BodyModel.load()
    track = tracks[0]
    coco_track = relabel(track, truth[(track.sequence, track.tracking_id)], model, "coco17", seed=1)
    assert coco_track.keypoint_set == "coco17"
    laid = layout_track(coco_track)
    assert laid.keypoint_set == "pedx18"
    view = laid.frames[0].left or laid.frames[0].right
    assert view.keypoints.shape == (18 + 2, 2)                   # the PedX rows, then COCO's two ears
    assert not view.labelled[PEDX_KEYPOINTS.index("head")] and view.labelled[PEDX_KEYPOINTS.index("lsho")]
    assert np.nanmax(view.sigma_px) == NOISE_PX
    laid = layout_track(coco_track, model_sigma_px=1.5)
    view = laid.frames[0].left or laid.frames[0].right
    assert np.nanmax(view.sigma_px) == pytest.approx(np.hypot(NOISE_PX, 1.5))


@pytest.mark.parametrize("set_name", ["coco17", "body25b"])
def test_detector_sets_fit_close_to_pedx(scene, set_name):
    tracks, truth = scene
    model = BodyModel.load()
    config = FitConfig()
    config.covariances = False
    errors = {}
    for name in ("pedx18", set_name):
        errs = []
        for track in tracks:
            labels = truth[(track.sequence, track.tracking_id)]
            relabelled = relabel(track, labels, model, name, seed=7)
            errs.append(mpjpe(fit_track(relabelled, config), labels, model))
        errors[name] = float(np.mean(errs))
    print(errors)
    assert errors[set_name] < 1.5 * errors["pedx18"] + 0.005, errors


def test_click_noise_estimate_ignores_detection_labels(scene):
    from pedx_graph.data.noise_estimate import vertical_disparities

    tracks, truth = scene
    model = BodyModel.load()
    relabelled = [relabel(t, truth[(t.sequence, t.tracking_id)], model, "body25", seed=2) for t in tracks]
    assert len(vertical_disparities(tracks).disparity_px) > 0
    assert len(vertical_disparities(relabelled).disparity_px) == 0


def test_reprojection_rows_take_the_labels_own_sigma():
    from factors.stereo_reprojection import ImageKeypoints, build_reprojection_setup

    uv = np.full((18, 2), 100.0)
    uv[4] = np.nan                                        # not labelled: no row
    own = np.full(18, np.nan)
    own[[0, 12]] = [7.0, 5.0]                             # nose, lhip
    image = ImageKeypoints(uv, np.ones(18, bool), np.eye(3, 4), "test", own)
    weights = np.ones(18)
    weights[12] = 0.25
    setup = build_reprojection_setup([image], sigma_px=3.0, sigma_occluded_px=12.0, keypoint_weights=weights)
    sig = setup.sigmas.reshape(-1, 2)[:, 0]
    rows = list(setup.images[0].index)
    assert 4 not in rows
    assert sig[rows.index(0)] == 7.0 and sig[rows.index(12)] == 10.0 and sig[rows.index(1)] == 3.0
    plain = build_reprojection_setup([ImageKeypoints(uv, np.ones(18, bool), np.eye(3, 4))], sigma_px=3.0,
                                     keypoint_weights=np.ones(18))
    assert np.all(plain.sigmas == 3.0)


def test_admm_and_stream_fit_detector_tracks_and_report_pedx_keypoints(scene):
    from pedx_graph.solvers.admm import fit_track_admm
    from pedx_graph.solvers.context import estimator_context
    from pedx_graph.solvers.stream.config import StreamConfig
    from pedx_graph.solvers.stream.dataset import stream_track

    tracks, truth = scene
    model = BodyModel.load()
    track = tracks[0]
    labels = truth[(track.sequence, track.tracking_id)]
    coco = relabel(track, labels, model, "coco17", seed=7)
    config = FitConfig()
    ctx = estimator_context(config)
    lm_error = mpjpe(fit_track(coco, config, ctx), labels, model)
    admm = fit_track_admm(coco, config, ctx)
    assert admm.world_keypoints.shape == (len(track.frames), 18, 3)
    assert mpjpe(admm, labels, model) < 1.5 * lm_error + 0.01
    results, causal, failed = stream_track(coco, ctx, config, StreamConfig())
    assert results and not failed
    for res in results:
        # Reported keypoints are PedX's of the fitted body (not the set's surface hips in the hip rows).
        np.testing.assert_allclose(res.world_keypoints, model.keypoints(
            res.pose, np.broadcast_to(res.betas, (len(res.pose), len(res.betas))), res.trans), atol=1e-9)
        assert mpjpe(res, labels, model) < 1.5 * lm_error + 0.02
    assert all(est.world_keypoints.shape == (18, 3) for est in causal)


def test_covariances_are_recomputed_for_a_detector_dataset(scene, tmp_path):
    """A detector dataset fitted without covariances: the calibration's recomputation lays its tracks out
    as the fit did and gives each frame its 18 PedX keypoints' covariances."""
    from pedx_graph.data.writer import write_tracks
    from pedx_graph.eval.calibration import run_covariances
    from pedx_graph.solvers.fit import fit_dataset

    tracks, truth = scene
    model = BodyModel.load()
    write_tracks(tmp_path / "data", [relabel(t, truth[(t.sequence, t.tracking_id)], model, "coco17", seed=2)
                                     for t in tracks[:2]])
    assert {t.keypoint_set for t in read_dataset(tmp_path / "data")} == {"coco17"}
    config = FitConfig()
    config.covariances = False
    fit_dataset(tmp_path / "data", tmp_path / "results", config, workers=1)
    covs = run_covariances(tmp_path / "results", tmp_path / "data")
    assert len(covs) == sum(len(t.frames) for t in tracks[:2])
    for cov in covs.values():
        assert cov.shape == (18, 3, 3)
        assert np.all(np.linalg.eigvalsh(cov) > 0)
