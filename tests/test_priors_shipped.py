"""The shipped priors: loadable, the right sizes, trained without the hold-out, sensible densities."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pedx_graph.motion import is_holdout, procedural_gait
from pedx_graph.priors import DATA_DIR, load_pose_prior, load_temporal_prior
from pedx_graph.priors.train import temporal_features


def test_loaders_return_the_shipped_priors():
    pose, temporal = load_pose_prior(), load_temporal_prior()
    assert (pose.num_components, pose.dim) == (8, 69) and pose.dt is None
    assert (temporal.num_components, temporal.dim) == (10, 75) and temporal.dt == pytest.approx(0.1)
    for prior in (pose, temporal):
        assert np.isclose(prior.weights.sum(), 1.0)
        eig = np.linalg.eigvalsh(prior.covariances)
        assert eig.min() > 0 and (eig[:, -1] / eig[:, 0]).max() < 1e6        # well-conditioned


def test_provenance_excludes_holdout():
    prov = json.loads((DATA_DIR / "provenance.json").read_text())
    assert prov["clips_train"] and not any(is_holdout(n) for n in prov["clips_train"])
    assert all(is_holdout(n) for n in prov["clips_holdout_evaluated"])
    ll = prov["log_likelihood"]
    assert ll["train"]["pose_ll_per_frame"] > ll["holdout"]["pose_ll_per_frame"]


def test_walking_is_more_likely_than_random_poses():
    pose, temporal = load_pose_prior(), load_temporal_prior()
    walk = procedural_gait("walk", 1.3, duration=4.0, fps=10.0, seed=0)
    rng = np.random.default_rng(0)
    noise = rng.normal(scale=0.5, size=(40, 69))
    assert np.median(pose.log_density(walk.body_pose_aa[:, 3:])) > np.median(pose.log_density(noise))
    d = temporal_features(walk, 10.0, 1)
    assert np.median(temporal.log_density(d)) > np.median(temporal.log_density(d + rng.normal(scale=0.2, size=d.shape)))
    r, jac, _ = pose.residual(walk.body_pose_aa[5, 3:], want_jacobian=True)
    assert r.shape == (70,) and jac.shape == (70, 69) and np.all(np.isfinite(r))


def test_prior_covariance_scale_widens_both_mixtures():
    from pedx_graph.graph.build import EstimatorContext
    from pedx_graph.graph.config import FitConfig

    base = EstimatorContext.create(FitConfig(prior_covariance_scale=1.0))
    config = FitConfig(prior_covariance_scale=3.0)
    wide = EstimatorContext.create(config)
    for a, b in ((base.pose_mixture, wide.pose_mixture), (base.temporal_mixture, wide.temporal_mixture)):
        np.testing.assert_allclose(b.lt, a.lt / np.sqrt(3.0))
        np.testing.assert_allclose(b.means, a.means)
        x = a.means[0] + 0.05
        assert 0.5 * np.sum(b.residual(x)[0][:-1] ** 2) == pytest.approx(0.5 * np.sum(a.residual(x)[0][:-1] ** 2) / 3.0)
    with pytest.raises(ValueError, match="prior_covariance_scale"):
        EstimatorContext.create(FitConfig(prior_covariance_scale=0.0))
