"""PedX keypoint definitions: file keys, SMPL topology defaults, joints-only fallback, sparse-map form."""
import numpy as np
import pytest
import scipy.sparse as sp

from pedx_graph.body import PEDX_KEYPOINTS, BodyModel
from pedx_graph.body.io import validate_model_arrays
from synthetic_model import synthetic_model_arrays
from pedx_graph.body.keypoint_defs import (SMPL_JOINT_KEYPOINTS, SMPL_VERTEX_KEYPOINTS, joints_only_map,
                                           keypoint_map_for_model, smpl_topology_map)
from pedx_graph.keypoints import PEDX_KEYPOINTS as NAMES_FROM_KEYPOINTS


def test_names_are_reexported():
    assert PEDX_KEYPOINTS is NAMES_FROM_KEYPOINTS and len(PEDX_KEYPOINTS) == 18


def test_smpl_topology_map():
    kp = smpl_topology_map()
    assert kp.names == PEDX_KEYPOINTS
    assert set(kp.vertex_ids) == {332, 6260, 2800}
    for name, vid in SMPL_VERTEX_KEYPOINTS.items():
        k = PEDX_KEYPOINTS.index(name)
        col = list(kp.vertex_ids).index(vid)
        assert kp.vertex_coeffs[k, col] == 1.0 and not kp.joint_coeffs[k].any()
    for name, jid in SMPL_JOINT_KEYPOINTS.items():
        k = PEDX_KEYPOINTS.index(name)
        assert kp.joint_coeffs[k, jid] == 1.0 and not kp.vertex_coeffs[k].any()
    # every keypoint (including the 3-term mouth rule) is an affine combination: it moves rigidly with trans
    np.testing.assert_allclose(kp.vertex_coeffs.sum(1) + kp.joint_coeffs.sum(1), 1.0, atol=1e-15)
    mouth = PEDX_KEYPOINTS.index("mouth")
    assert kp.vertex_coeffs[mouth, list(kp.vertex_ids).index(332)] == 1.0


def test_model_without_keys_needs_smpl_topology_or_explicit_fallback(synthetic_smpl_arrays):
    arrays = {k: v for k, v in synthetic_smpl_arrays.items() if not k.startswith("pedx_keypoint")}
    data = validate_model_arrays(arrays, source="custom.npz")
    with pytest.raises(ValueError, match=r"custom\.npz.*joints_only_keypoints"):
        keypoint_map_for_model(data)
    kp = keypoint_map_for_model(data, joints_only=True)
    assert kp.source == "joints-only" and kp.vertex_ids.size == 0
    model = BodyModel(data, kp)
    pose = np.random.default_rng(40).normal(scale=0.3, size=72)
    joints = model.joints(pose, np.zeros(10), np.zeros(3))
    np.testing.assert_allclose(model.keypoints(pose, np.zeros(10), np.zeros(3))[0], joints[15], atol=1e-14)
    assert np.array_equal(joints_only_map().joint_coeffs, kp.joint_coeffs)


def test_smpl_sized_model_without_keys_uses_smpl_ids():
    arrays = synthetic_model_arrays(num_vertices=6890, seed=3, with_keypoint_keys=False)
    model = BodyModel.from_data(validate_model_arrays(arrays))
    assert model.keypoint_map.source == "smpl-topology"
    rng = np.random.default_rng(41)
    pose, betas, trans = rng.normal(scale=0.4, size=72), rng.normal(size=10), rng.normal(size=3)
    out = model.forward(pose, betas, trans)
    np.testing.assert_allclose(out.keypoints[PEDX_KEYPOINTS.index("nose")], out.vertices[332], atol=1e-13)
    np.testing.assert_allclose(out.keypoints[PEDX_KEYPOINTS.index("lankl")], out.joints[7], atol=1e-13)
    np.testing.assert_allclose(model.keypoints(pose, betas, trans), out.keypoints, atol=1e-13)


def test_sparse_form_over_vertices_and_joints(synthetic_body_model):
    kp = synthetic_body_model.keypoint_map
    mat = kp.as_sparse(synthetic_body_model.num_vertices)
    assert sp.issparse(mat) and mat.shape == (18, synthetic_body_model.num_vertices + 24)
    assert mat.nnz == 18
    rng = np.random.default_rng(42)
    out = synthetic_body_model.forward(rng.normal(scale=0.4, size=72), rng.normal(size=10), rng.normal(size=3))
    stacked = np.concatenate([out.vertices, out.joints])
    np.testing.assert_allclose(mat @ stacked, out.keypoints, atol=1e-13)
