"""Tests of factors/lidar_chamfer.py (E_3d, PedX Eq. 4)."""
import gtsam
import numpy as np
import pytest

from factors.common import FrameKeys, FrameState
from scipy.spatial import cKDTree

from factors.lidar_chamfer import (DIRECT_SEARCH_MAX_POINTS, facing_margin, facing_sensor, lidar_chamfer_error,
                                   make_lidar_chamfer_factor, nearest_indices, nearest_vertices)
from factor_testing import ToyBodyModel, assert_factor_jacobians, frame_values, standing_rotation
from synthetic_model import synthetic_body_model

KEYS = FrameKeys.for_frame(0)


def _state(rng, model):
    rot = standing_rotation(0.4) @ gtsam.Rot3.Expmap(rng.normal(scale=0.2, size=3)).matrix()
    return FrameState.from_arrays(rot, np.array([6.0, -2.0, 0.9]), rng.normal(scale=0.2, size=69),
                                  rng.normal(scale=0.5, size=model.num_betas))


@pytest.mark.parametrize("model_kind", ["toy", "synthetic_smpl"])
def test_noise_free_zero_and_jacobians(model_kind):
    rng = np.random.default_rng(0)
    model = ToyBodyModel() if model_kind == "toy" else synthetic_body_model()
    s = _state(rng, model)
    verts = model.forward(s.full_pose, s.betas, s.trans).vertices
    pts = verts[rng.choice(len(verts), 40, replace=False)]
    f = make_lidar_chamfer_factor(KEYS, model, pts, robust="none")
    v = frame_values(KEYS.as_list(), s.world_R_body, s.trans, s.body_pose, s.betas)
    np.testing.assert_allclose(f.unwhitenedError(v), 0.0, atol=1e-12)      # zero distance
    assert_factor_jacobians(f, v, rtol=1e-5, atol=1e-6)                     # Jacobian regular at zero distance
    # points slightly off the surface (assignments stay stable under small perturbations)
    f2 = make_lidar_chamfer_factor(KEYS, model, pts + rng.normal(scale=0.002, size=pts.shape), robust="none")
    assert f2.error(v) > 0
    assert_factor_jacobians(f2, v, rtol=1e-5, atol=1e-6)


def test_correspondences_follow_the_estimate():
    rng = np.random.default_rng(1)
    model = ToyBodyModel()
    s = _state(rng, model)
    pts = model.forward(s.full_pose, s.betas, s.trans).vertices[:10]
    ids, _ = nearest_vertices(model, s, pts)
    np.testing.assert_array_equal(ids, np.arange(10))
    moved = FrameState.from_arrays(s.world_R_body, s.trans + [0.0, 0.0, 5.0], s.body_pose, s.betas)
    r, _ = lidar_chamfer_error(model, moved, pts)
    dist = np.linalg.norm(r.reshape(-1, 3), axis=1)
    assert np.all(dist < 5.0 + 1e-9) and np.all(dist > 3.0)


@pytest.mark.parametrize("num_points", [1, DIRECT_SEARCH_MAX_POINTS, DIRECT_SEARCH_MAX_POINTS + 1, 300])
def test_nearest_indices_equal_the_tree(num_points):
    """Both search paths (direct distances for few points, k-d tree for many) give the tree's nearest vertex."""
    rng = np.random.default_rng(num_points)
    verts = rng.normal(size=(700, 3)) * [0.2, 0.15, 0.8] + [6.0, -2.0, 0.9]
    pts = verts[rng.choice(len(verts), num_points)] + rng.normal(scale=0.05, size=(num_points, 3))
    np.testing.assert_array_equal(nearest_indices(verts, pts), cKDTree(verts).query(pts)[1])


def test_candidates_and_outliers():
    rng = np.random.default_rng(2)
    model = ToyBodyModel()
    s = _state(rng, model)
    verts = model.forward(s.full_pose, s.betas, s.trans).vertices
    cand = np.arange(0, model.num_vertices, 2)
    ids, _ = nearest_vertices(model, s, verts[:20], cand)
    assert np.all(ids % 2 == 0)
    pts = np.vstack([verts[cand[:30]], [[s.trans[0] + 3.0, s.trans[1], s.trans[2]]]])   # one point 3 m away
    v = frame_values(KEYS.as_list(), s.world_R_body, s.trans, s.body_pose, s.betas)
    gauss = make_lidar_chamfer_factor(KEYS, model, pts, robust="none", candidate_vertex_ids=cand)
    robust = make_lidar_chamfer_factor(KEYS, model, pts, candidate_vertex_ids=cand)
    assert robust.error(v) < 0.01 * gauss.error(v)


def test_no_points_and_bad_input():
    model = ToyBodyModel()
    assert make_lidar_chamfer_factor(KEYS, model, np.zeros((0, 3))) is None
    with pytest.raises(ValueError, match="non-finite"):
        make_lidar_chamfer_factor(KEYS, model, np.array([[0.0, np.nan, 1.0]]))
    with pytest.raises(ValueError, match="sigma_m"):
        make_lidar_chamfer_factor(KEYS, model, np.ones((2, 3)), sigma_m=0.0)


@pytest.mark.parametrize("kernel", ["gemanmcclure", "huber", "cauchy"])
def test_per_point_robust_jacobians_and_invariance(kernel):
    rng = np.random.default_rng(5)
    model = ToyBodyModel()
    s = _state(rng, model)
    verts = model.forward(s.full_pose, s.betas, s.trans).vertices
    pts = verts[:30] + rng.normal(scale=0.01, size=(30, 3))
    pts[0] += [0.3, 0.0, 0.0]                                   # an outlier, 0.3 m off
    f = make_lidar_chamfer_factor(KEYS, model, pts, sigma_m=0.02, robust=kernel, robust_scale=2.0)
    v = frame_values(KEYS.as_list(), s.world_R_body, s.trans, s.body_pose, s.betas)
    assert_factor_jacobians(f, v, rtol=1e-5, atol=1e-6)
    # per point: rho of the 3D distance, whatever the direction of the offset
    one_a = make_lidar_chamfer_factor(KEYS, model, verts[:1] + [0.3, 0.0, 0.0], sigma_m=0.02, robust=kernel,
                                      robust_scale=2.0, candidate_vertex_ids=np.array([0]))
    one_b = make_lidar_chamfer_factor(KEYS, model, verts[:1] + 0.3 / np.sqrt(3.0), sigma_m=0.02, robust=kernel,
                                      robust_scale=2.0, candidate_vertex_ids=np.array([0]))
    assert one_a.error(v) == pytest.approx(one_b.error(v), rel=1e-9)


# ------------------------------------------------------------------------------------------- seen side

def _shipped_state(rng, model, trans):
    rot = standing_rotation(0.4) @ gtsam.Rot3.Expmap(rng.normal(scale=0.1, size=3)).matrix()
    return FrameState.from_arrays(rot, np.asarray(trans, float), rng.normal(scale=0.15, size=69),
                                  rng.normal(scale=0.5, size=model.num_betas))


@pytest.fixture(scope="module")
def shipped_model():
    from pedx_graph.body import BodyModel
    return BodyModel.load()


def test_skinned_normals_follow_the_posed_mesh(shipped_model):
    """``vertex_normals_subset`` (template normals turned by the skinning) agrees with the area-weighted
    normals of the posed mesh."""
    from pedx_graph.body.normals import vertex_normals
    rng = np.random.default_rng(11)
    s = _shipped_state(rng, shipped_model, [12.0, 3.0, 0.9])
    exact = vertex_normals(shipped_model.forward(s.full_pose, s.betas, s.trans).vertices, shipped_model.faces)
    ids = rng.choice(shipped_model.num_vertices, 800, replace=False)
    approx = shipped_model.vertex_normals_subset(s.full_pose, s.betas, ids)
    cos = np.einsum("ij,ij->i", exact[ids], approx)
    np.testing.assert_allclose(np.linalg.norm(approx, axis=1), 1.0, atol=1e-12)
    assert np.median(cos) > 0.99 and np.mean(cos > 0.7) > 0.97


def test_a_point_is_matched_only_on_the_side_facing_the_sensor(shipped_model):
    """A point lying on a vertex that faces away from the sensor matches it without a viewpoint, and a
    vertex facing the sensor with one."""
    rng = np.random.default_rng(12)
    sensor = np.array([0.0, 0.0, 1.8])
    s = _shipped_state(rng, shipped_model, [14.0, -3.0, 0.9])
    verts = shipped_model.forward(s.full_pose, s.betas, s.trans).vertices
    normals = shipped_model.vertex_normals_subset(s.full_pose, s.betas, np.arange(len(verts)))
    facing = facing_sensor(verts, normals, sensor, 0.0)
    assert 0.3 < facing.mean() < 0.7                                # about half the body faces the sensor
    back = np.flatnonzero(~facing)[rng.choice((~facing).sum(), 5, replace=False)]
    ids, _ = nearest_vertices(shipped_model, s, verts[back])
    np.testing.assert_array_equal(ids, back)
    ids, matched = nearest_vertices(shipped_model, s, verts[back], world_p_sensor=sensor)
    assert facing[ids].all()
    assert np.all(np.linalg.norm(matched - verts[back], axis=1) > 0.01)


def test_the_seen_side_resists_a_slide_along_the_ray(shipped_model):
    """Points on the surface facing the sensor: sliding the body 0.2 m towards the sensor (the points then
    lie inside it, near its flanks and back) costs clearly more with the seen side than with any vertex."""
    rng = np.random.default_rng(13)
    sensor = np.zeros(3)
    s = _shipped_state(rng, shipped_model, [18.0, 4.0, 0.0])
    verts = shipped_model.forward(s.full_pose, s.betas, s.trans).vertices
    normals = shipped_model.vertex_normals_subset(s.full_pose, s.betas, np.arange(len(verts)))
    seen = np.flatnonzero(facing_sensor(verts, normals, sensor, -0.5))      # squarely facing: LiDAR returns
    pts = verts[rng.choice(seen, 40, replace=False)]
    ray = s.trans / np.linalg.norm(s.trans)
    slid = FrameState.from_arrays(s.world_R_body, s.trans - 0.2 * ray, s.body_pose, s.betas)
    errors = {}
    for name, kw in (("any", {}), ("seen", dict(world_p_sensor=sensor))):
        f = make_lidar_chamfer_factor(KEYS, shipped_model, pts, sigma_m=0.02, robust="none", **kw)
        v0 = frame_values(KEYS.as_list(), s.world_R_body, s.trans, s.body_pose, s.betas)
        v1 = frame_values(KEYS.as_list(), slid.world_R_body, slid.trans, slid.body_pose, slid.betas)
        assert f.error(v0) < 1e-20                                   # on the surface, seen side or not
        errors[name] = f.error(v1)
    assert errors["seen"] > 1.4 * errors["any"]                     # measured 1.8x


def test_seen_side_jacobians_and_margin(shipped_model):
    """With a viewpoint, the factor's Jacobians match numerical derivatives at a random non-identity state;
    the margin grows as the points come nearer the viewpoint and bad viewpoints are refused."""
    rng = np.random.default_rng(14)
    sensor = np.array([0.5, -0.3, 1.6])
    s = _shipped_state(rng, shipped_model, [9.0, 2.0, 0.9])
    verts = shipped_model.forward(s.full_pose, s.betas, s.trans).vertices
    pts = verts[rng.choice(len(verts), 30, replace=False)] + rng.normal(scale=0.002, size=(30, 3))
    f = make_lidar_chamfer_factor(KEYS, shipped_model, pts, world_p_sensor=sensor, facing_cos=0.1)
    v = frame_values(KEYS.as_list(), s.world_R_body, s.trans, s.body_pose, s.betas)
    assert f.error(v) > 0
    assert_factor_jacobians(f, v, rtol=1e-5, atol=1e-6)
    at_5 = facing_margin(np.array([[5.0, 0.0, 0.0]]), np.zeros(3), 2.5, np.radians(5.0))
    at_40 = facing_margin(np.array([[40.0, 0.0, 0.0]]), np.zeros(3), 2.5, np.radians(5.0))
    assert at_5 == pytest.approx(np.sin(np.arctan(0.5) + np.radians(5.0)))
    assert 0 < at_40 < at_5 < 1
    with pytest.raises(ValueError, match="world_p_sensor"):
        make_lidar_chamfer_factor(KEYS, shipped_model, pts, world_p_sensor=[0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="facing_cos"):
        make_lidar_chamfer_factor(KEYS, shipped_model, pts, world_p_sensor=sensor, facing_cos=1.5)
