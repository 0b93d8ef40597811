"""Prior training: hold-out exclusion, the shared temporal difference, a tiny seeded training run."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pedx_graph.motion import procedural_gait
from pedx_graph.priors.train import (HoldoutError, TrainConfig, assert_not_holdout, load_clips,
                                     temporal_difference, temporal_features, train_priors)

CMU = Path(__file__).resolve().parents[2] / "shared" / "mocap" / "cmu"
needs_cmu = pytest.mark.skipif(not (CMU / "clips.csv").is_file(), reason="../shared/mocap/cmu not present")


@pytest.mark.parametrize("name", ["08_01", "08_11.bvh", "02_03"])
def test_holdout_names_refused(name):
    with pytest.raises(HoldoutError):
        assert_not_holdout(["07_01", name])
    with pytest.raises(HoldoutError):           # refused before any file is read
        train_priors(motion_dir="does-not-exist", cfg=TrainConfig(clips=("07_01", name)))
    assert_not_holdout(["07_01", "02_01", "09_01"])


@needs_cmu
def test_training_clips_exclude_holdout():
    names = [c.name for c in load_clips(CMU, "train", names=("02_01", "07_01"))]
    assert names == ["02_01", "07_01"]
    with pytest.raises(HoldoutError):
        train_priors(CMU, None, TrainConfig(clips=("08_02",)))


def test_temporal_difference_is_heading_invariant_and_matches_factor():
    clip = procedural_gait("walk", 1.3, duration=3.0, fps=30.0, seed=0)
    turned = procedural_gait("walk", 1.3, duration=3.0, fps=30.0, seed=0, heading=2.0, start_xz=(5.0, -3.0))
    d_a = temporal_features(clip, 10.0, 3)
    d_b = temporal_features(turned, 10.0, 3)
    np.testing.assert_allclose(d_a, d_b, atol=1e-9)
    walk_step = d_a[:, 2].mean()
    assert walk_step == pytest.approx(0.13, abs=0.01)          # 1.3 m/s x 0.1 s along body +Z
    import factors.temporal_prior as tp
    assert tp.temporal_difference is temporal_difference      # one definition, trained on and evaluated
    rng = np.random.default_rng(1)
    rot_i, rot_j = Rotation.random(2, random_state=2).as_matrix()
    t_i, t_j, p_i, p_j = rng.normal(size=3), rng.normal(size=3), rng.normal(size=69), rng.normal(size=69)
    d = temporal_difference(rot_i, t_i, p_i, rot_j, t_j, p_j)
    np.testing.assert_allclose(Rotation.from_rotvec(d[3:6]).as_matrix(), rot_i.T @ rot_j, atol=1e-9)
    np.testing.assert_allclose(d[6:], p_j - p_i, atol=1e-12)


@needs_cmu
def test_tiny_training_run_is_seeded_and_writes_files(tmp_path):
    cfg = TrainConfig(clips=("07_01", "09_01"), n_pose=2, n_temporal=2, n_init=1, max_iter=30,
                      pose_fps=10.0, oversample=1, seed=3)
    a = train_priors(CMU, tmp_path, cfg, evaluate_holdout=False)
    b = train_priors(CMU, None, cfg, evaluate_holdout=False)
    np.testing.assert_allclose(a.pose.means, b.pose.means)
    assert a.provenance["clips_train"] == ["07_01", "09_01"]
    assert {p.name for p in tmp_path.iterdir()} == {"pose_gmm.npz", "temporal_gmm.npz", "provenance.json"}
    assert a.temporal.dt == pytest.approx(0.1) and a.temporal.dim == 75 and a.pose.dim == 69
    # constant (unobserved) dimensions get the explicit variance, not a near-zero one
    collar = [i for i, n in enumerate(a.pose.dims) if n.startswith("left_collar.")]
    np.testing.assert_allclose(a.pose.covariances[:, collar, collar], cfg.unobserved_std_pose ** 2)
