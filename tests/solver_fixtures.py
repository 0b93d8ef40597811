"""Tiny synthetic tracks for the solver tests (iSAM2, ADMM, marginals): no shipped model or priors needed.

``synthetic_context`` builds an :class:`EstimatorContext` on the package's synthetic SMPL-format arrays with
single-Gaussian pose and temporal priors; ``synthetic_track`` renders a pedestrian walking across the view
of the test stereo pair (``factor_testing.make_test_calibration``: camera 1.5 m high looking along world
+x) into 2D keypoints (both images, pixel noise) and LiDAR points (sampled model vertices, range noise).
Everything is seeded.
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.common import MaxMixture
from factors.temporal_prior import TEMPORAL_DIM
from factor_testing import make_test_calibration, standing_rotation
from synthetic_model import synthetic_body_model
from pedx_graph.data.types import Track, TrackFrame, View2D
from pedx_graph.graph.context import EstimatorContext, farthest_point_subset
from pedx_graph.graph.config import FitConfig


def gaussian_mixture(mean: np.ndarray, sigma: np.ndarray) -> MaxMixture:
    """One-component :class:`MaxMixture` with diagonal covariance ``diag(sigma^2)``."""
    mean = np.asarray(mean, float)
    return MaxMixture(np.ones(1), mean[None], np.diag(1.0 / np.asarray(sigma, float))[None])


def synthetic_context(num_vertices: int = 400, chamfer_vertices: int = 200, dt: float = 0.1,
                      speed_mps: float = 1.3) -> EstimatorContext:
    """Context on a synthetic body model, pose prior N(0, 0.3^2), temporal prior around walking at ``speed_mps``."""
    model = synthetic_body_model(num_vertices=num_vertices)
    temporal_mean = np.zeros(TEMPORAL_DIM)
    temporal_mean[2] = speed_mps * dt                        # body-frame forward step (SMPL +Z)
    temporal_sigma = np.concatenate([[0.05, 0.05, 0.05], [0.08] * 3, [0.1] * 69])
    rest = model.forward(np.zeros(72), np.zeros(model.num_betas), np.zeros(3)).vertices
    return EstimatorContext(model=model, pose_mixture=gaussian_mixture(np.zeros(69), np.full(69, 0.3)),
                            temporal_mixture=gaussian_mixture(temporal_mean, temporal_sigma), temporal_dt=dt,
                            chamfer_vertex_ids=farthest_point_subset(rest, chamfer_vertices, seed=0),
                            template_body_pose=np.zeros(69))


def synthetic_config(**terms) -> FitConfig:
    """Default FitConfig with the chamfer subset matching :func:`synthetic_context`; ``terms`` switch terms."""
    config = FitConfig(chamfer_vertices=200)
    for name, value in terms.items():
        setattr(config.terms, name, value)
    return config


def synthetic_truth(ctx: EstimatorContext, num_frames: int, seed: int = 0, distance_m: float = 10.0,
                    speed_mps: float = 1.3, dt: float = 0.1) -> dict:
    """Ground truth of a pedestrian walking along world +y at ``distance_m`` in front of the test camera."""
    rng = np.random.default_rng(seed)
    nb = ctx.model.num_betas
    betas = rng.normal(scale=0.5, size=nb)
    yaw = np.pi / 2
    world_R_body = standing_rotation(yaw)
    phase = rng.uniform(0, 2 * np.pi, size=69)
    amp = rng.normal(scale=0.15, size=69)
    times = dt * np.arange(num_frames)
    body_pose = amp[None] * np.sin(2 * np.pi * 1.0 * times[:, None] + phase[None])
    trans = np.stack([np.full(num_frames, distance_m), -0.5 * speed_mps * dt * num_frames + speed_mps * times,
                      np.full(num_frames, 0.9)], axis=1)
    root = np.asarray(gtsam.Rot3.Logmap(gtsam.Rot3(world_R_body)))
    pose = np.concatenate([np.broadcast_to(root, (num_frames, 3)), body_pose], axis=1)
    return {"betas": betas, "pose": pose, "trans": trans, "times": times, "world_R_body": world_R_body}


def synthetic_track(ctx: EstimatorContext, num_frames: int = 4, seed: int = 0, pixel_noise: float = 1.0,
                    lidar_noise_m: float = 0.01, lidar_points: int = 60, distance_m: float = 10.0,
                    with_lidar: bool = True, with_right: bool = True) -> tuple[Track, dict]:
    """A seeded synthetic :class:`Track` and its truth dict (``betas``, ``pose`` (T, 72), ``trans`` (T, 3),
    ``keypoints`` (T, 18, 3))."""
    rng = np.random.default_rng(seed + 1000)
    truth = synthetic_truth(ctx, num_frames, seed=seed, distance_m=distance_m)
    calib = make_test_calibration()
    frames, keypoints = [], []
    for i in range(num_frames):
        out = ctx.model.forward(truth["pose"][i], truth["betas"], truth["trans"][i])
        keypoints.append(out.keypoints)
        left, right = calib.project(out.keypoints)
        vis = np.ones(18, bool)
        left_view = View2D(left + rng.normal(scale=pixel_noise, size=left.shape), vis.copy())
        right_view = View2D(right + rng.normal(scale=pixel_noise, size=right.shape), vis.copy()) \
            if with_right else None
        if with_lidar:
            ids = rng.choice(len(out.vertices), size=lidar_points, replace=False)
            pts = out.vertices[ids] + rng.normal(scale=lidar_noise_m, size=(lidar_points, 3))
        else:
            pts = np.zeros((0, 3))
        frames.append(TrackFrame(frame=i, timestamp=float(truth["times"][i]), pair=calib.name,
                                 left=left_view, right=right_view, world_lidar_points=pts))
    truth["keypoints"] = np.stack(keypoints)
    return Track(sequence="synthetic", tracking_id=f"ped{seed}", frames=frames,
                 calibrations={calib.name: calib}), truth


def second_test_calibration(yaw_deg: float = 20.0, offset_m: float = 0.9):
    """Another stereo pair (``"test-pair-b"``, the test pair's intrinsics): its left camera ``offset_m`` to the
    side of the test pair's (world +y), turned by ``yaw_deg`` about world z."""
    import dataclasses

    base = make_test_calibration()
    yaw = np.deg2rad(yaw_deg)
    turn = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    world_T_cam = base.world_T_cam.copy()
    world_T_cam[:3, :3] = turn @ world_T_cam[:3, :3]
    world_T_cam[:3, 3] += [0.0, offset_m, 0.0]
    return dataclasses.replace(base, name="test-pair-b", world_T_cam=world_T_cam)


def with_views(track: Track, truth: dict, patterns, pixel_noise: float = 1.0, seed: int = 0) -> Track:
    """``track`` with, per frame, the images named in ``patterns[i]`` (a string of ``l``/``r``: the test pair's
    left/right, ``L``/``R``: :func:`second_test_calibration`'s), relabelled from the truth with pixel noise.
    The test pair is the frame's primary pair when it labels the frame (the second pair's views go to
    ``TrackFrame.other_views``), else the second pair is."""
    rng = np.random.default_rng(seed + 2000)
    first = track.calibrations[track.frames[0].pair]
    second = second_test_calibration()
    for fr, kps, pattern in zip(track.frames, truth["keypoints"], patterns):
        views = {}
        for names, calib in (("lr", first), ("LR", second)):
            for name, uv in zip(names, calib.project(kps)):
                views[name] = View2D(uv + rng.normal(scale=pixel_noise, size=uv.shape), np.ones(18, bool))
        pairs = [(calib.name, tuple(views[n] if n in pattern else None for n in names))
                 for names, calib in (("lr", first), ("LR", second)) if set(names) & set(pattern)]
        (fr.pair, (fr.left, fr.right)), fr.other_views = pairs[0], dict(pairs[1:])
    track.calibrations[second.name] = second
    return track
