"""What every track's graph shares (:class:`EstimatorContext`): the body model, the pose and temporal priors
as max-mixtures, the starting-pose templates, the chamfer vertex subset and the body-size prior."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factors.common import MaxMixture
from pedx_graph.body import BodyModel
from pedx_graph.graph.config import FitConfig
from pedx_graph.graph.monocular import BodySizePrior, body_size_prior
from pedx_graph.body.keypoint_defs import read_keypoint_set_folder
from pedx_graph.priors import load_pose_prior, load_temporal_prior


def farthest_point_subset(points: np.ndarray, count: int, seed: int = 0) -> np.ndarray:
    """Indices of ``count`` points spread over ``points`` (N, 3) by farthest-point sampling (seeded)."""
    n = len(points)
    if count >= n:
        return np.arange(n)
    rng = np.random.default_rng(seed)
    chosen = np.empty(count, dtype=np.int64)
    chosen[0] = rng.integers(n)
    dist = np.linalg.norm(points - points[chosen[0]], axis=1)
    for i in range(1, count):
        chosen[i] = int(np.argmax(dist))
        dist = np.minimum(dist, np.linalg.norm(points - points[chosen[i]], axis=1))
    return np.sort(chosen)


def neutral_template(means: np.ndarray) -> np.ndarray:
    """The pose prior's component mean (K, 69) nearest the rest pose, a copy: the starting body pose when
    nothing better is known (the heaviest component can be a reaching, arms-up pose)."""
    means = np.asarray(means, dtype=float)
    return means[int(np.argmin(np.linalg.norm(means, axis=1)))].copy()


def fit_body_model(config: FitConfig) -> BodyModel:
    """The body model a fit of ``config`` uses: ``config.body_model`` (empty: the shipped open model) with the
    keypoint sets of ``config.keypoint_sets`` in place of the shipped ones of their names."""
    model = BodyModel.load(config.body_model or None)
    if config.keypoint_sets:
        model.keypoint_sets = read_keypoint_set_folder(config.keypoint_sets)
    return model


@dataclass
class EstimatorContext:
    """What every track's graph shares: the body model, the priors and the chamfer vertex subset."""

    model: BodyModel
    pose_mixture: MaxMixture | None
    temporal_mixture: MaxMixture | None
    temporal_dt: float
    chamfer_vertex_ids: np.ndarray
    template_body_pose: np.ndarray
    template_candidates: np.ndarray | None = None
    """(C, 69) body poses tried per frame as the starting pose (best reprojection of the 2D labels)."""
    size_prior: BodySizePrior | None = None
    """The body model's segment heights over walking poses and shapes, for the depth of frames seen by one
    camera without LiDAR (:mod:`pedx_graph.graph.monocular`); None: such frames stay unplaced."""

    @staticmethod
    def create(config: FitConfig) -> "EstimatorContext":
        model = fit_body_model(config)
        pose_prior = load_pose_prior(config.pose_prior or None)
        temporal_prior = load_temporal_prior(config.temporal_prior or None)
        scale = float(config.prior_covariance_scale)
        if not scale > 0:
            raise ValueError(f"prior_covariance_scale must be > 0, got {config.prior_covariance_scale}")
        pose_mixture = MaxMixture.from_gmm(pose_prior, covariance_scale=scale)
        temporal_mixture = MaxMixture.from_gmm(temporal_prior, covariance_scale=scale)
        # Template candidates: the pose prior's component means and the rest pose; the neutral template
        # is the mean nearest the rest pose (the heaviest component can be a reaching, arms-up pose).
        means = np.asarray(pose_prior.means, dtype=float)
        template = neutral_template(means)
        candidates = np.vstack([means, np.zeros((1, means.shape[1]))])
        rest = model.forward(np.zeros(72), np.zeros(model.num_betas), np.zeros(3)).vertices
        ids = farthest_point_subset(rest, config.chamfer_vertices, seed=0)
        size_prior = body_size_prior(model, pose_prior, shape_sigma=config.noise.shape_sigma)
        return EstimatorContext(model=model, pose_mixture=pose_mixture, temporal_mixture=temporal_mixture,
                                temporal_dt=float(temporal_prior.dt), chamfer_vertex_ids=ids,
                                template_body_pose=template, template_candidates=candidates,
                                size_prior=size_prior)
