"""Per-frame fit-consistency flags of the diagnostics (frames whose estimate contradicts a non-robust term)."""
import gtsam
import numpy as np
import pytest

from solver_fixtures import synthetic_config, synthetic_context, synthetic_track
from pedx_graph.graph.build import build_track_graph
from pedx_graph.graph.config import SolverConfig
from pedx_graph.solvers.diagnostics import track_diagnostics
from pedx_graph.solvers.lm import python_lm


@pytest.fixture(scope="module")
def solved():
    ctx = synthetic_context()
    track, _ = synthetic_track(ctx, 3, seed=5)
    config = synthetic_config()
    problem = build_track_graph(track, ctx, config)
    values, _ = python_lm(problem.graph, problem.initial, SolverConfig(max_iterations=30))
    return ctx, config, problem, values


def test_solved_track_is_consistent(solved):
    ctx, config, problem, values = solved
    per_frame, track = track_diagnostics(problem, values, fit_config=config)
    assert all(f["fit_consistent"] and f["inconsistent_terms"] == [] for f in per_frame)
    assert track["diagnostics"]["inconsistent_frames"] == 0
    assert all(row["fit_consistent"] for row in track["diagnostics"]["per_frame"])


def test_frame_contradicting_its_pose_prior_is_flagged(solved):
    ctx, config, problem, values = solved
    bad = gtsam.Values(values)
    k = problem.keys[1]
    bad.update(k.body_pose, np.asarray(values.atVector(k.body_pose)) + 1.5)     # every joint 1.5 rad off
    per_frame, track = track_diagnostics(problem, bad, fit_config=config)
    assert per_frame[0]["fit_consistent"]
    assert not per_frame[1]["fit_consistent"] and "pose_prior" in per_frame[1]["inconsistent_terms"]
    # robust terms never flag: their outliers are rejected by design
    assert not {"stereo_reprojection", "lidar_chamfer", "translation_prior"} & set(per_frame[1]["inconsistent_terms"])
    assert track["diagnostics"]["inconsistent_frames"] >= 1
