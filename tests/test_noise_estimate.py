"""Noise from the data (pedx_graph.data.noise_estimate): click noise per keypoint from the vertical disparity of
stereo clicks, LiDAR range noise from segment residuals, their use in the fit and the ``noise`` command."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from factor_testing import make_test_calibration
from pedx_graph.data.noise_estimate import (
    QUANTISATION_PX,
    NoiseEstimateConfig,
    chamfer_sigma_m,
    estimate_noise,
    estimate_range_noise,
    keypoint_row_sigmas_px,
    resolve_noise,
    robust_gaussian_scale,
)
from pedx_graph.data.types import Track, TrackFrame, View2D
from pedx_graph.graph.config import FitConfig, NoiseConfig
from pedx_graph.keypoints import PEDX_KEYPOINTS

#: Per-click noise of the synthetic annotators (pixels per axis), PedX-like: face ~1, hips ~4 px.
CLICK_SIGMA = np.array([1.0, 1.0, 1.0, 2.0, 1.0, 2.0, 2.0, 2.0, 3.0, 3.0, 3.5, 3.5, 4.0, 4.0, 3.0, 3.0, 2.0, 2.0])
#: True vertical rectification offset v_left - v_right of the two pairs, pixels.
OFFSETS = {"pair-a": 0.0, "pair-b": -0.7}


def _view(uv: np.ndarray, labelled: np.ndarray) -> View2D:
    uv = uv.copy()
    uv[~labelled] = np.nan
    return View2D(keypoints=uv, visible=labelled.copy())


def click_tracks(seed: int = 0, n_tracks: int = 40, n_frames: int = 10, sigma=CLICK_SIGMA, integer: bool = True,
                 outlier_prob: float = 0.03, label_prob=None) -> list[Track]:
    """Tracks whose frames are labelled in both images of pair-a (primary) and pair-b (``other_views``), each
    click = true position + N(0, sigma_k^2) per axis (+ the pair's vertical offset in the right image),
    rounded to whole pixels when ``integer``; a fraction of clicks is off by 20-60 px (gross mistakes)."""
    rng = np.random.default_rng(seed)
    label_prob = np.full(18, 0.9) if label_prob is None else np.asarray(label_prob, float)
    sigma = np.asarray(sigma, float)
    tracks = []
    for t in range(n_tracks):
        frames = []
        for f in range(n_frames):
            views = {}
            for pair, offset in OFFSETS.items():
                true_uv = rng.uniform([200, 200], [3400, 2400], size=(18, 2))
                clicks = []
                for shift in (0.0, -offset):                 # right image rows are offset by -offset
                    uv = true_uv + rng.normal(size=(18, 2)) * sigma[:, None]
                    uv[:, 1] += shift
                    bad = rng.random(18) < outlier_prob
                    uv[bad] += rng.choice([-1, 1], size=(bad.sum(), 2)) * rng.uniform(20, 60, size=(bad.sum(), 2))
                    clicks.append(np.round(uv) if integer else uv)
                labelled = rng.random(18) < label_prob
                views[pair] = (_view(clicks[0], labelled), _view(clicks[1], labelled))
            frames.append(TrackFrame(frame=f, timestamp=0.1 * f, pair="pair-a", left=views["pair-a"][0],
                                     right=views["pair-a"][1], other_views={"pair-b": views["pair-b"]}))
        tracks.append(Track(sequence="seq", tracking_id=f"t{t}", frames=frames, calibrations={}))
    return tracks


def test_robust_scale_is_consistent_on_integer_data_and_ignores_outliers():
    rng = np.random.default_rng(1)
    for sigma in (0.6, 1.5, 4.0):
        x = rng.uniform(0, 100, 20000)
        d = np.round(x + rng.normal(0, sigma, x.size)) - np.round(x + rng.normal(0, sigma, x.size))
        d[:1000] = rng.uniform(-80, 80, 1000)               # 5 % gross outliers
        s = robust_gaussian_scale(d)[0] / np.sqrt(2)
        assert s == pytest.approx(np.hypot(sigma, QUANTISATION_PX), rel=0.04)


def test_click_noise_per_keypoint_and_pair_offsets_are_recovered():
    est = estimate_noise(click_tracks())
    expected = np.hypot(CLICK_SIGMA, QUANTISATION_PX)             # rounding is part of what the fit sees
    assert est.integer_clicks
    assert est.keypoint_sigma_px.shape == (18,)
    assert not est.keypoint_pooled.any()
    assert np.all(est.keypoint_counts > 600)                     # both pairs counted (other_views too)
    rel = np.abs(est.keypoint_sigma_px / expected - 1)
    assert rel.max() < 0.12, dict(zip(PEDX_KEYPOINTS, np.round(rel, 3)))
    offsets = {p["pair"]: p["offset_px"] for p in est.pair_offsets}
    for pair, offset in OFFSETS.items():
        assert offsets[pair] == pytest.approx(offset, abs=0.1)
    record = est.to_dict()
    json.dumps(record)
    assert set(record["keypoint_sigma_px"]) == set(PEDX_KEYPOINTS)


def test_occlusion_flags_keep_guessed_clicks_out():
    tracks = click_tracks(seed=2)
    rng = np.random.default_rng(5)
    for tr in tracks:                                  # flagged-occluded clicks: guessed, 8 px more noise
        for fr in tr.frames:
            hidden = rng.random(18) < 0.3
            fr.left.keypoints[hidden, 1] += np.round(rng.normal(0.0, 8.0, hidden.sum()))
            fr.left.visible = fr.left.visible & ~hidden
    with_flags = estimate_noise(tracks)
    without = estimate_noise(tracks, NoiseEstimateConfig(visible_only=False))
    expected = np.hypot(CLICK_SIGMA, QUANTISATION_PX)
    assert np.abs(with_flags.keypoint_sigma_px / expected - 1).max() < 0.15
    assert np.all(without.keypoint_counts > with_flags.keypoint_counts)
    assert np.all(without.keypoint_sigma_px > with_flags.keypoint_sigma_px)
    assert np.mean(without.keypoint_sigma_px / with_flags.keypoint_sigma_px) > 1.1


def test_too_few_samples_fall_back():
    label_prob = np.full(18, 0.9)
    label_prob[PEDX_KEYPOINTS.index("lhip")] = 0.01              # lhip: a handful of clicks
    est = estimate_noise(click_tracks(seed=3, n_tracks=10, label_prob=label_prob))
    k = PEDX_KEYPOINTS.index("lhip")
    assert est.keypoint_counts[k] < 30 and est.keypoint_pooled[k]
    assert est.keypoint_sigma_px[k] == pytest.approx(est.pooled_sigma_px)
    assert est.keypoint_pooled.sum() == 1
    # a whole dataset with too few clicks: no estimate, the config's sigma stays
    small = estimate_noise(click_tracks(seed=4, n_tracks=1, n_frames=2))
    assert small.keypoint_sigma_px is None
    resolved = resolve_noise(click_tracks(seed=4, n_tracks=1, n_frames=2), NoiseConfig())
    assert resolved.record["keypoints"]["source"] == "config"
    assert np.all(resolved.keypoint_sigma_px == NoiseConfig().keypoint_sigma_px)


# ------------------------------------------------------------------------------------ LiDAR range noise

def scan_segment(rng, sensor, centre, sigma_m, background: bool = True, az_step_deg=0.18, el_step_deg=1.33):
    """A spinning-LiDAR scan (rays from ``sensor``, z up) of a pedestrian-like pair of vertical cylinders
    (torso r = 0.16 m over legs r = 0.07 m) at ``centre``, range noise ``sigma_m`` along each ray; with
    ``background``: a wall 1.2 m behind and the ground at the feet inside the same silhouette window, and
    a few stray returns (as a polygon-cut segment catches)."""
    rel = centre - sensor
    dist = np.hypot(rel[0], rel[1])
    half = np.arctan2(0.45, dist)
    az0 = np.arctan2(rel[1], rel[0])
    az = az0 + np.arange(-half, half, np.deg2rad(az_step_deg))
    el = np.deg2rad(np.arange(-30.0, 10.0, el_step_deg))
    a, e = np.meshgrid(az, el)
    rays = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], axis=-1).reshape(-1, 3)
    best = np.full(len(rays), np.inf)
    ground_z = centre[2]
    parts = [(np.array([0.0, 0.0]), 0.16, ground_z + 0.85, ground_z + 1.5),
             (np.array([0.0, 0.1]), 0.07, ground_z, ground_z + 0.85),
             (np.array([0.0, -0.1]), 0.07, ground_z, ground_z + 0.85)]
    for offset, radius, z0, z1 in parts:                        # ray / vertical cylinder
        c = centre[:2] + offset - sensor[:2]
        dxy = rays[:, :2]
        qa, qb, qc = np.sum(dxy ** 2, 1), -2 * dxy @ c, c @ c - radius ** 2
        disc = qb * qb - 4 * qa * qc
        t = np.where(disc > 0, (-qb - np.sqrt(np.maximum(disc, 0))) / (2 * qa), np.inf)
        z = sensor[2] + t * rays[:, 2]
        t = np.where((z >= z0) & (z <= z1), t, np.inf)
        best = np.minimum(best, t)
    person = np.isfinite(best)
    if background:
        normal = rel / np.linalg.norm(rel)
        normal[2] = 0.0
        normal /= np.linalg.norm(normal)
        wall = ((centre + 1.2 * normal - sensor) @ normal) / (rays @ normal)
        ground = np.where(rays[:, 2] < 0, (ground_z - sensor[2]) / np.minimum(rays[:, 2], -1e-9), np.inf)
        floor = np.minimum(wall, ground)
        best = np.where(np.isfinite(best), best, floor)
    keep = np.isfinite(best) & (best > 0)
    rng_noise = rng.normal(0.0, sigma_m, keep.sum())
    points = sensor + rays[keep] * (best[keep] + rng_noise)[:, None]
    if background:
        stray = sensor + rays[keep][rng.choice(keep.sum(), 5)] * rng.uniform(3, 40, (5, 1))
        points = np.vstack([points, stray])
    return points, person[keep].mean()


def lidar_tracks(seed: int, sigma_m: float, n_frames: int = 12, background: bool = True,
                 sensor=(0.3, -0.2, 1.9)) -> list[Track]:
    """Tracks of scanned pedestrians at 6-25 m, seen from ``sensor`` (the calibration's camera position, which
    the estimator takes as the rays' origin)."""
    rng = np.random.default_rng(seed)
    calib = make_test_calibration()
    calib.world_T_cam[:3, 3] = sensor
    tracks = []
    for t, dist in enumerate((6.0, 10.0, 15.0, 25.0)):
        frames = []
        for f in range(n_frames):
            angle = rng.uniform(-0.6, 0.6)
            centre = np.array([dist * np.cos(angle), dist * np.sin(angle), 0.0])
            points, _ = scan_segment(rng, np.asarray(sensor, float), centre, sigma_m, background)
            frames.append(TrackFrame(frame=f, timestamp=0.1 * f, pair=calib.name, left=None, right=None,
                                     world_lidar_points=points))
        tracks.append(Track(sequence="seq", tracking_id=f"t{t}", frames=frames, calibrations={calib.name: calib}))
    return tracks


@pytest.mark.parametrize("sigma_m", [0.01, 0.02, 0.04])
def test_range_noise_from_contaminated_segments(sigma_m):
    tracks = lidar_tracks(seed=int(sigma_m * 1000), sigma_m=sigma_m)
    result = estimate_range_noise(tracks)
    assert result["count"] > 1000 and result["segments"] >= 40
    assert result["sigma_m"] == pytest.approx(sigma_m, rel=0.1)


def test_range_noise_needs_enough_points():
    tracks = lidar_tracks(seed=7, sigma_m=0.02, n_frames=1)
    for tr in tracks:
        for fr in tr.frames:
            fr.world_lidar_points = fr.world_lidar_points[:6]
    assert estimate_range_noise(tracks)["sigma_m"] is None
    resolved = resolve_noise(tracks, NoiseConfig())
    assert resolved.record["lidar"]["source"] == "config"
    assert resolved.lidar_sigma_m == NoiseConfig().lidar_sigma_m


# ------------------------------------------------------------------------------------ resolution and the fit

def test_resolution_sources_and_model_terms():
    tracks = click_tracks(seed=5, n_tracks=10) + lidar_tracks(seed=5, sigma_m=0.02, n_frames=4)
    noise = NoiseConfig(keypoint_model_sigma_px=1.5, lidar_model_sigma_m=0.03)
    resolved = resolve_noise(tracks, noise)
    clicks = np.asarray(resolved.noise.keypoint_sigma_px_per_keypoint)
    assert resolved.record["keypoints"]["source"] == "data"
    assert np.allclose(resolved.keypoint_sigma_px, np.hypot(clicks, 1.5))
    assert resolved.record["lidar"]["source"] == "data"
    assert resolved.lidar_sigma_m == pytest.approx(np.hypot(resolved.noise.lidar_range_sigma_m, 0.03))
    assert noise.keypoint_sigma_px_per_keypoint is None          # the input config is not changed
    json.dumps(resolved.record)
    # explicit overrides win over the data
    override = tuple(float(v) for v in np.linspace(1, 5, 18))
    resolved = resolve_noise(tracks, NoiseConfig(keypoint_sigma_px_per_keypoint=override, lidar_range_sigma_m=0.01,
                                                 keypoint_model_sigma_px=0.0, lidar_model_sigma_m=0.0))
    assert resolved.record["keypoints"]["source"] == "override"
    assert np.allclose(resolved.keypoint_sigma_px, override)
    assert resolved.lidar_sigma_m == pytest.approx(0.01)
    # estimation switched off: the config's single figures, as before
    off = resolve_noise(tracks, NoiseConfig(keypoint_noise_from_data=False, lidar_noise_from_data=False))
    assert off.record["estimate"] is None
    assert np.all(off.keypoint_sigma_px == 3.0) and off.lidar_sigma_m == 0.04
    with pytest.raises(ValueError, match="keypoint_sigma_px_per_keypoint"):
        keypoint_row_sigmas_px(NoiseConfig(keypoint_sigma_px_per_keypoint=(1.0, 2.0)))
    assert chamfer_sigma_m(NoiseConfig()) == 0.04


def test_the_graph_uses_the_resolved_sigmas():
    from solver_fixtures import synthetic_context, synthetic_track

    from pedx_graph.graph.build import build_track_graph

    ctx = synthetic_context()
    track, _ = synthetic_track(ctx, num_frames=2)
    config = FitConfig(chamfer_vertices=200)
    clicks = np.linspace(1.0, 4.0, 18)
    config.noise.keypoint_sigma_px_per_keypoint = tuple(clicks)
    config.noise.keypoint_model_sigma_px = 1.0
    config.noise.hip_sigma_factor = 1.0
    config.noise.lidar_range_sigma_m = 0.012
    config.noise.lidar_model_sigma_m = 0.016
    problem = build_track_graph(track, ctx, config)
    row = np.hypot(clicks, 1.0)
    stereo = [problem.graph.at(j) for j, kind in enumerate(problem.factor_kinds) if kind == "stereo_reprojection"]
    chamfer = [problem.graph.at(j) for j, kind in enumerate(problem.factor_kinds) if kind == "lidar_chamfer"]
    assert stereo and chamfer
    specs = problem.body.specs("stereo_reprojection")   # whitened inside the factor: the sigmas of its spec
    for factor in stereo:                 # every keypoint labelled and visible in both images: rows (u, v)
        assert np.allclose(specs[tuple(factor.keys())].setup.sigmas, np.tile(np.repeat(row, 2), 2))
    # the chamfer whitens inside the factor: its Gaussian error at the initial values is that of a 2 cm sigma
    config.noise.lidar_loss = "none"

    def chamfer_error(noise_changes: dict) -> float:
        cfg = FitConfig(chamfer_vertices=200)
        cfg.noise = dataclasses.replace(config.noise, **noise_changes)
        prob = build_track_graph(track, ctx, cfg)
        return sum(prob.graph.at(j).error(prob.initial) for j, kind in enumerate(prob.factor_kinds)
                   if kind == "lidar_chamfer")

    resolved = chamfer_error({})
    assert resolved == pytest.approx(chamfer_error({"lidar_range_sigma_m": None, "lidar_sigma_m": 0.02}))
    assert resolved == pytest.approx(4 * chamfer_error({"lidar_range_sigma_m": None, "lidar_sigma_m": 0.04}))


def _sigmas(factor) -> np.ndarray:
    """Per-row sigmas of a factor's (possibly robust) diagonal noise model."""
    import gtsam

    model = factor.noiseModel()
    if isinstance(model, gtsam.noiseModel.Robust):
        model = model.noise()
    return np.asarray(model.sigmas())


def test_fit_dataset_estimates_uses_and_records_the_noise(tmp_path):
    from pedx_graph.config import load_config
    from pedx_graph.sim.config import SimConfig
    from pedx_graph.sim.simulate import simulate
    from pedx_graph.solvers.fit import fit_dataset

    cfg = SimConfig()
    cfg.scene.n_pedestrians = 3
    cfg.scene.n_frames = 4
    cfg.scene.distance_mean_m, cfg.scene.distance_std_m = 9.0, 2.0   # near: enough LiDAR points
    simulate(tmp_path / "scene", cfg, seed=3)
    config = FitConfig(covariances=False, diagnostics=False)
    config.solver.max_iterations = 3
    config.solver.coarse_max_iterations = 2
    config.solver.flip_segments = ()
    summary = fit_dataset(tmp_path / "scene", tmp_path / "out", config)
    noise = summary["noise"]
    assert noise["keypoints"]["source"] == "data" and noise["lidar"]["source"] == "data"
    assert noise["estimate"]["keypoint_samples"] >= 100
    clicks = np.array([noise["keypoints"]["click_sigma_px"][n] for n in PEDX_KEYPOINTS])
    assert np.abs(np.median(clicks) / cfg.labels.visible_noise_px - 1) < 0.25
    rows = np.array([noise["keypoints"]["row_sigma_px"][n] for n in PEDX_KEYPOINTS])
    assert np.allclose(rows, np.hypot(clicks, config.noise.keypoint_model_sigma_px))
    assert noise["lidar"]["chamfer_sigma_m"] == pytest.approx(
        np.hypot(noise["lidar"]["range_sigma_m"], config.noise.lidar_model_sigma_m))
    on_disk = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert on_disk["noise"]["keypoints"]["row_sigma_px"] == pytest.approx(noise["keypoints"]["row_sigma_px"])
    assert load_config(FitConfig, tmp_path / "out" / "fit_config.yaml") == config     # the config as given


def test_noise_command_prints_a_table_and_json(tmp_path, capsys):
    from pedx_graph.cli import main
    from pedx_graph.sim.config import SimConfig
    from pedx_graph.sim.simulate import simulate

    cfg = SimConfig()
    cfg.scene.n_pedestrians = 3
    cfg.scene.n_frames = 4
    simulate(tmp_path / "scene", cfg, seed=4)
    assert main(["noise", str(tmp_path / "scene")]) == 0
    text = capsys.readouterr().out
    assert "| nose |" in text and "LiDAR range noise" in text
    assert main(["noise", str(tmp_path / "scene"), "--json"]) == 0
    record = json.loads(capsys.readouterr().out)
    assert record["keypoints"]["source"] in ("data", "config")
    assert set(record["keypoints"]["row_sigma_px"]) == set(PEDX_KEYPOINTS)


def test_simulated_pedx_rig_per_keypoint_profile_is_recovered(tmp_path):
    """End to end: the simulator's PedX rig with its per-keypoint click-noise profile (integer clicks, a -1 px
    vertical disparity on blu79CF-grn43E3), occlusion flags on so that guessed joints stay out, 2 cm range
    noise; the estimate from the written dataset against the profile."""
    from pedx_graph.data.reader import read_dataset
    from pedx_graph.sim.config import LEFT_PAIR, rig_config
    from pedx_graph.sim.simulate import simulate

    cfg = rig_config("pedx")
    cfg.labels.occlusion_flags = True
    cfg.labels.one_camera_track_prob = 0.0
    cfg.scene.n_pedestrians = 12
    cfg.scene.n_frames = 30
    simulate(tmp_path / "scene", cfg, seed=0)
    est = estimate_noise(read_dataset(tmp_path / "scene"))
    expected = np.hypot(np.asarray(cfg.labels.keypoint_noise_px), QUANTISATION_PX)
    assert est.integer_clicks
    own = ~est.keypoint_pooled
    assert own.sum() >= 15
    rel = np.abs(est.keypoint_sigma_px / expected - 1)[own]
    assert rel.max() < 0.15, dict(zip(np.asarray(PEDX_KEYPOINTS)[own], np.round(rel, 3)))
    offsets = {p["pair"]: p["offset_px"] for p in est.pair_offsets}
    pair = cfg.cameras.left
    assert pair.name == LEFT_PAIR
    assert offsets[LEFT_PAIR] == pytest.approx(pair.vertical_disparity_px, abs=0.2)
    assert offsets[cfg.cameras.forward.name] == pytest.approx(0.0, abs=0.2)
    assert est.lidar_range_sigma_m == pytest.approx(cfg.lidar.range_noise_m, rel=0.25)
