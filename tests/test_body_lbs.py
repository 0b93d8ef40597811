"""Forward pass: BodyModel and the lbs functions against an independent loop implementation of SMPL's LBS."""
import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from pedx_graph.body import PEDX_KEYPOINTS, BodyModel
from pedx_graph.body.lbs import lbs, vertices2joints


def reference_lbs(arrays, pose, betas, trans):
    """smplx-style LBS for one frame written as plain loops (steps 1-7 of smpl-conventions)."""
    v_template = np.asarray(arrays["v_template"], dtype=float)
    shapedirs = np.asarray(arrays["shapedirs"], dtype=float)[:, :, :len(betas)]
    posedirs = np.asarray(arrays["posedirs"], dtype=float)
    jreg = arrays["J_regressor"]
    jreg = jreg.toarray() if sp.issparse(jreg) else np.asarray(jreg)
    weights = np.asarray(arrays["weights"], dtype=float)
    parents = [int(p) if p != 4294967295 else -1 for p in np.asarray(arrays["kintree_table"])[0]]
    num_v, num_j = len(v_template), len(parents)
    v_shaped = v_template.copy()
    for b in range(len(betas)):
        v_shaped += betas[b] * shapedirs[:, :, b]
    rest = np.zeros((num_j, 3))
    for j in range(num_j):
        for v in range(num_v):
            rest[j] += jreg[j, v] * v_shaped[v]
    rots = [Rotation.from_rotvec(pose[3 * j:3 * j + 3]).as_matrix() for j in range(num_j)]
    feats = []
    for j in range(1, num_j):
        feats.extend((rots[j] - np.eye(3)).ravel())
    v_posed = v_shaped + np.einsum("vcp,p->vc", posedirs, np.array(feats))
    glob = []
    for j in range(num_j):
        local = np.eye(4)
        local[:3, :3] = rots[j]
        local[:3, 3] = rest[j] - (rest[parents[j]] if parents[j] >= 0 else 0.0)
        glob.append(local if parents[j] < 0 else glob[parents[j]] @ local)
    rel = []
    for j in range(num_j):
        a = glob[j].copy()
        a[:3, 3] -= glob[j][:3, :3] @ rest[j]
        rel.append(a)
    verts = np.zeros((num_v, 3))
    for v in range(num_v):
        blend = sum(weights[v, j] * rel[j] for j in range(num_j))
        verts[v] = (blend @ np.append(v_posed[v], 1.0))[:3]
    joints = np.array([g[:3, 3] for g in glob])
    return verts + trans, joints + trans


def _random_inputs(rng, num=3, scale=0.5):
    return rng.normal(scale=scale, size=(num, 72)), rng.normal(size=(num, 10)), rng.normal(size=(num, 3))


@pytest.mark.parametrize("kind", ["npz", "pkl"])
def test_forward_matches_reference_loop_lbs(kind, synthetic_smpl_arrays, synthetic_smpl_file, synthetic_smpl_pkl):
    model = BodyModel.load(synthetic_smpl_file if kind == "npz" else synthetic_smpl_pkl)
    pose, betas, trans = _random_inputs(np.random.default_rng(10))
    out = model.forward(pose, betas, trans)
    for i in range(len(pose)):
        ref_v, ref_j = reference_lbs(synthetic_smpl_arrays, pose[i], betas[i], trans[i])
        np.testing.assert_allclose(out.vertices[i], ref_v, atol=1e-9, rtol=0)
        np.testing.assert_allclose(out.joints[i], ref_j, atol=1e-9, rtol=0)


def test_pure_lbs_function_matches_model(synthetic_smpl_arrays, synthetic_body_model):
    a = synthetic_smpl_arrays
    pose, betas, trans = _random_inputs(np.random.default_rng(11))
    parents = synthetic_body_model.parents
    verts, joints = lbs(betas, pose, a["v_template"], a["shapedirs"], a["posedirs"], a["J_regressor"], parents,
                        a["weights"], trans)
    out = synthetic_body_model.forward(pose, betas, trans)
    np.testing.assert_allclose(verts, out.vertices, atol=1e-12)
    np.testing.assert_allclose(joints, out.joints, atol=1e-12)


def test_rest_pose_reproduces_template_and_regressed_joints(synthetic_smpl_arrays, synthetic_body_model):
    out = synthetic_body_model.forward(np.zeros(72), np.zeros(10), np.zeros(3))
    np.testing.assert_allclose(out.vertices, synthetic_smpl_arrays["v_template"], atol=1e-14)
    np.testing.assert_allclose(out.joints, synthetic_smpl_arrays["J_regressor"] @ synthetic_smpl_arrays["v_template"],
                               atol=1e-14)


def test_trans_is_added_after_skinning(synthetic_body_model):
    rng = np.random.default_rng(12)
    pose, betas, _ = _random_inputs(rng, 1)
    shift = np.array([1.0, -2.0, 0.5])
    a = synthetic_body_model.forward(pose, betas, np.zeros(3))
    b = synthetic_body_model.forward(pose, betas, shift)
    np.testing.assert_allclose(b.vertices - a.vertices, np.broadcast_to(shift, a.vertices.shape), atol=1e-12)
    # the pelvis lands at R0 J_0(betas) + trans, not at trans
    np.testing.assert_allclose(b.joints[0, 0], synthetic_body_model.rest_joints(betas[0])[0] + shift, atol=1e-12)


def test_batching_and_broadcasting(synthetic_body_model):
    rng = np.random.default_rng(13)
    pose = rng.normal(scale=0.4, size=(2, 3, 72))
    betas = rng.normal(size=10)                 # shared by all frames
    trans = rng.normal(size=(3, 3))             # broadcast over the first axis
    out = synthetic_body_model.forward(pose, betas, trans)
    assert out.vertices.shape == (2, 3, synthetic_body_model.num_vertices, 3)
    assert out.joints.shape == (2, 3, 24, 3)
    assert out.keypoints.shape == (2, 3, len(PEDX_KEYPOINTS), 3)
    single = synthetic_body_model.forward(pose[1, 2], betas, trans[2])
    np.testing.assert_allclose(out.vertices[1, 2], single.vertices, atol=1e-13)
    assert out.vertices.dtype == np.float64


def test_many_frames_span_several_chunks(synthetic_body_model):
    from pedx_graph.body import model as model_module

    rng = np.random.default_rng(14)
    pose, betas, trans = _random_inputs(rng, model_module.FORWARD_CHUNK + 5, scale=0.3)
    out = synthetic_body_model.forward(pose, betas, trans)
    last = synthetic_body_model.forward(pose[-1], betas[-1], trans[-1])
    np.testing.assert_allclose(out.vertices[-1], last.vertices, atol=1e-13)


def test_fast_paths_equal_full_forward(synthetic_body_model):
    rng = np.random.default_rng(15)
    pose, betas, trans = _random_inputs(rng, 4)
    out = synthetic_body_model.forward(pose, betas, trans)
    np.testing.assert_allclose(synthetic_body_model.keypoints(pose, betas, trans), out.keypoints, atol=1e-13)
    np.testing.assert_allclose(synthetic_body_model.joints(pose, betas, trans), out.joints, atol=1e-13)
    ids = np.array([0, 17, 299, 17])
    np.testing.assert_allclose(synthetic_body_model.vertices_subset(pose, betas, trans, ids), out.vertices[:, ids],
                               atol=1e-13)


def test_keypoints_follow_the_file_definition(synthetic_smpl_arrays, synthetic_body_model):
    rng = np.random.default_rng(16)
    pose, betas, trans = _random_inputs(rng, 2)
    out = synthetic_body_model.forward(pose, betas, trans)
    vid = synthetic_smpl_arrays["pedx_keypoint_vertex_ids"]
    jid = synthetic_smpl_arrays["pedx_keypoint_joint_ids"]
    for k in range(len(PEDX_KEYPOINTS)):
        expect = out.vertices[:, vid[k]] if vid[k] >= 0 else out.joints[:, jid[k]]
        np.testing.assert_allclose(out.keypoints[:, k], expect, atol=1e-13)


def test_sparse_and_dense_regressor_agree(synthetic_smpl_arrays):
    reg = synthetic_smpl_arrays["J_regressor"]
    verts = np.random.default_rng(17).normal(size=(2, 4, reg.shape[1], 3))
    np.testing.assert_allclose(vertices2joints(reg, verts), vertices2joints(reg.toarray(), verts), atol=1e-13)


def test_input_shapes_are_checked(synthetic_body_model):
    with pytest.raises(ValueError, match="pose"):
        synthetic_body_model.forward(np.zeros(69), np.zeros(10), np.zeros(3))
    with pytest.raises(ValueError, match="betas"):
        synthetic_body_model.forward(np.zeros(72), np.zeros(11), np.zeros(3))
