"""MPJPE metrics: joint selection, similarity alignment, weighting and distance bins."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from pedx_graph.eval.metrics import (eval_joints, eval_visibility, joint_errors, markdown_table,
                                     similarity_align, summarise)
from pedx_graph.keypoints import EVAL_JOINTS, PEDX_KEYPOINTS


def test_eval_joints_hip_is_midpoint():
    kp = np.random.default_rng(0).normal(size=(18, 3))
    out = eval_joints(kp)
    assert out.shape == (13, 3)
    hip = EVAL_JOINTS.index("hip")
    np.testing.assert_allclose(out[hip], 0.5 * (kp[PEDX_KEYPOINTS.index("lhip")] + kp[PEDX_KEYPOINTS.index("rhip")]))
    np.testing.assert_allclose(out[EVAL_JOINTS.index("rknee")], kp[PEDX_KEYPOINTS.index("rknee")])


def test_similarity_alignment_removes_similarity_transform():
    rng = np.random.default_rng(1)
    target = rng.normal(size=(13, 3))
    rot = Rotation.from_rotvec([0.3, -1.2, 2.0]).as_matrix()
    source = 1.7 * target @ rot.T + np.array([4.0, -2.0, 0.5])
    np.testing.assert_allclose(similarity_align(source, target), target, atol=1e-10)


def test_joint_errors_global_vs_root_relative():
    rng = np.random.default_rng(2)
    truth = rng.normal(size=(5, 13, 3))
    pred = truth + np.array([0.3, 0.0, 0.0])          # pure offset: global error 0.3, root-relative 0
    glob, rel = joint_errors(pred, truth)
    np.testing.assert_allclose(glob, 0.3)
    np.testing.assert_allclose(rel, 0.0, atol=1e-10)


def test_visibility_weighting_and_bins():
    glob = np.full((4, 13), 0.1)
    glob[:, 0] = 1.0                                   # a bad joint that is never visible
    weights = np.ones((4, 13))
    weights[:, 0] = 0.0
    summary = summarise(glob, glob, weights, np.array([6.0, 16.0, 30.0, 50.0]))
    assert summary["overall"]["global_mm"] == pytest.approx(100.0)
    assert summary["overall"]["global_all_joints_mm"] > 100.0
    assert summary["per_distance"]["5-15"]["frames"] == 1
    assert summary["per_distance"]["35-45"]["frames"] == 0
    assert "| rknee |" in markdown_table(summary)


def test_eval_visibility_hip_either_side():
    vis = np.zeros(18, dtype=bool)
    vis[PEDX_KEYPOINTS.index("lhip")] = True
    assert eval_visibility(vis)[EVAL_JOINTS.index("hip")]
