"""Tests of factors/ground_contact.py (the stance foot on the ground) and of its path through the registry."""
import dataclasses

import gtsam
import numpy as np
import pytest

from factors.common import FrameKeys
from factors.ground_contact import ANKLES, ankle_height_m, ground_contact_batch, make_ground_contact_factor
from factors.registry import OWN_FRAME_KINDS, TERMS
from factor_testing import ToyBodyModel, assert_factor_jacobians, frame_values, random_rot3
from pedx_graph.graph.build import build_track_graph
from pedx_graph.solvers.batched import BatchedLinearizer
from solver_fixtures import synthetic_config, synthetic_context, synthetic_track


def _random_point(rng, keys, num_betas):
    return frame_values(keys.as_list(), random_rot3(rng).matrix(), rng.normal(scale=2.0, size=3),
                        rng.normal(scale=0.3, size=69), rng.normal(scale=0.5, size=num_betas))


@pytest.mark.parametrize("seed", range(4))
def test_jacobians_equal_numerical_derivatives(seed):
    """At random non-identity points and a tilted up axis (not a world axis)."""
    rng = np.random.default_rng(seed)
    model = ToyBodyModel(seed=seed)
    keys = FrameKeys.for_frame(0)
    up = rng.normal(size=3)
    factor = make_ground_contact_factor(keys, model, up, ground_offset_m=rng.normal(), sigma_m=0.03, robust="none")
    assert_factor_jacobians(factor, _random_point(rng, keys, model.num_betas))


def test_residual_is_the_lower_ankle_height_minus_the_ankle_height():
    rng = np.random.default_rng(5)
    up = np.array([0.3, -0.2, -0.93])                   # a z-down world, slightly tilted
    up /= np.linalg.norm(up)
    points = rng.normal(size=(3, 18, 3))
    r, _ = ground_contact_batch(points[:, ANKLES], np.tile(up, (3, 1)), np.full(3, -1.5), np.full(3, 0.08))
    heights = points[:, ANKLES] @ up + 1.5
    np.testing.assert_allclose(r, heights.min(axis=1) - 0.08)
    assert 0.0 < ankle_height_m(synthetic_context().model) < 0.5      # ankle above the sole, body-sized


def test_registered_once_and_batched_equals_a_fresh_graph():
    """The term reaches the batched linearizer and the stream's frame systems through its registration; the
    batched system equals GTSAM's linearisation of a fresh, never prefetched graph."""
    assert "ground_contact" in TERMS and "ground_contact" in OWN_FRAME_KINDS
    ctx = synthetic_context()
    track, truth = synthetic_track(ctx, num_frames=4, seed=2)
    feet = truth["keypoints"][:, ANKLES] @ track.ground.world_up
    track.ground = dataclasses.replace(track.ground, ground_offset_m=float(feet.min()) - 0.08)
    config = synthetic_config()
    config.noise.ground_contact_sigma_m = 0.03
    problem, fresh = build_track_graph(track, ctx, config), build_track_graph(track, ctx, config)
    assert problem.factor_kinds.count("ground_contact") == 4
    fresh.body.lookup = lambda *args, **kwargs: None
    rng = np.random.default_rng(0)
    values = gtsam.Values(problem.initial)
    for k in problem.keys:
        values.update(k.root, values.atRot3(k.root).compose(gtsam.Rot3.Expmap(rng.normal(scale=0.2, size=3))))
        values.update(k.body_pose, rng.normal(scale=0.3, size=69))
    lin = BatchedLinearizer(problem)
    assert len(lin.served["ground_contact"]) == 4
    assert lin.error(values) == pytest.approx(fresh.graph.error(values), rel=1e-10)
    system, reference = lin.system(values), fresh.layout.assemble(fresh.graph.linearize(values))
    for name in ("frame", "next", "frame_shape", "shape", "grad_frame", "grad_shape"):
        got, want = getattr(system, name), getattr(reference, name)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max(), err_msg=name)
    assert build_track_graph(track, ctx, synthetic_config()).factor_kinds.count("ground_contact") == 4   # default on
    off = synthetic_config()
    off.noise.ground_contact_sigma_m = 0.0
    assert "ground_contact" not in build_track_graph(track, ctx, off).factor_kinds
    track.ground = dataclasses.replace(track.ground, ground_offset_m=None)      # plane unknown: no factor
    assert "ground_contact" not in build_track_graph(track, ctx, synthetic_config()).factor_kinds
