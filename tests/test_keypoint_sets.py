"""Keypoint sets as data: names, definitions on the open model and on the SMPL topology, body-model maps."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pedx_graph.body import BodyModel
from pedx_graph.body.io import validate_model_arrays
from synthetic_model import synthetic_model_arrays
from pedx_graph.body.keypoint_defs import KEYPOINT_SET_DIR, keypoint_set_names, load_keypoint_set
from pedx_graph.detections.types import KEYPOINT_SET_NAMES
from pedx_graph.keypoints import PEDX_KEYPOINTS

REPO = Path(__file__).resolve().parents[1]

#: Format facts (detector-formats notes): the first and last names of each set, and their counts.
EXPECTED = {"coco17": (17, "nose", "right_ankle"), "coco18": (18, "Nose", "LEar"),
            "body25": (25, "Nose", "RHeel"), "body25b": (25, "Nose", "RHeel"), "pedx18": (18, "nose", "rankl")}


@pytest.fixture(scope="module")
def model():
    return BodyModel.load()


def test_every_set_is_shipped_with_the_format_order():
    assert set(keypoint_set_names()) == set(KEYPOINT_SET_NAMES)
    for name, (count, first, last) in EXPECTED.items():
        kset = load_keypoint_set(name)
        assert len(kset.keypoints) == count and kset.keypoints[0] == first and kset.keypoints[-1] == last
    assert load_keypoint_set("body25").keypoints[8] == "MidHip"
    assert load_keypoint_set("body25b").keypoints[17:19] == ("Neck", "Head")
    assert load_keypoint_set("pedx18").keypoints == PEDX_KEYPOINTS
    with pytest.raises(KeyError, match="unknown keypoint set"):
        load_keypoint_set("halpe26")


def test_lacking_names_stay_unlabelled():
    coco = load_keypoint_set("coco17")
    assert coco.index_of("head") is None and coco.index_of("mouth") is None and coco.index_of("neck") is None
    assert coco.index_of("lsho") == 5 and coco.index_of("rknee") == 14
    # COCO's hips are not PedX's (surface points, not the joint): no equivalent.
    assert coco.index_of("lhip") is None
    assert load_keypoint_set("body25").index_of("neck") is None      # OpenPose's Neck is mid-shoulder


def test_open_model_points_sit_where_the_rules_put_them(model):
    rest = model.forward(np.zeros(72), np.zeros(10))
    body25 = model.for_keypoint_set("body25")
    kps = body25.keypoints(np.zeros(72), np.zeros(10))
    names = load_keypoint_set("body25").keypoints
    at = {n: kps[i] for i, n in enumerate(names)}
    joints = rest.joints
    # Neck = mid-shoulder, MidHip = mean of the two hips.
    np.testing.assert_allclose(at["Neck"], 0.5 * (joints[16] + joints[17]), atol=1e-12)
    np.testing.assert_allclose(at["MidHip"], 0.5 * (at["LHip"] + at["RHip"]), atol=1e-12)
    # Surface hips: wider than SMPL's hip joints (the model's left is +x), on the correct side.
    assert at["LHip"][0] > joints[1][0] + 0.02 and at["RHip"][0] < joints[2][0] - 0.02
    # Ears lateral of the eyes and behind them; toes in front of the ankle, heels behind, all near the sole.
    assert at["LEar"][0] > at["LEye"][0] + 0.03 and at["LEar"][2] < at["LEye"][2] - 0.05
    sole = rest.vertices[:, 1].min()
    for side, ankle in (("L", joints[7]), ("R", joints[8])):
        assert at[f"{side}BigToe"][2] > ankle[2] + 0.1 and at[f"{side}Heel"][2] < ankle[2] - 0.03
        for part in ("BigToe", "SmallToe", "Heel"):
            assert at[f"{side}{part}"][1] < sole + 0.03
    # Big toe medial of the small toe.
    assert abs(at["LBigToe"][0]) < abs(at["LSmallToe"][0])
    # BODY_25B's head top is the highest point of the body.
    b25b = model.for_keypoint_set("body25b").keypoints(np.zeros(72), np.zeros(10))
    assert b25b[18][1] == pytest.approx(rest.vertices[:, 1].max())
    # Shared joints agree with PedX's points.
    pedx = model.keypoints(np.zeros(72), np.zeros(10))
    np.testing.assert_allclose(at["LKnee"], pedx[PEDX_KEYPOINTS.index("lknee")], atol=1e-12)


def test_set_keypoints_move_with_the_body_and_have_jacobians(model):
    rng = np.random.default_rng(3)
    pose, betas, trans = rng.normal(scale=0.3, size=72), rng.normal(size=10), rng.normal(size=3)
    coco = model.for_keypoint_set("coco17")
    assert coco is model.for_keypoint_set("coco17") and model.for_keypoint_set("pedx18") is model
    kps = coco.keypoints(pose, betas, trans)
    out = coco.forward(pose, betas, trans)
    np.testing.assert_allclose(out.keypoints, kps, atol=1e-12)
    eps = 1e-6
    jac = coco.point_jacobians(pose, betas, trans)
    d_pose = np.zeros(72)
    d_pose[3 * 18] = eps                                   # left elbow joint: moves the left wrist only
    moved = coco.keypoints(pose + d_pose, betas, trans)
    changed = np.flatnonzero(np.abs(moved - kps).max(axis=1) > 1e-10)
    assert set(changed) == {load_keypoint_set("coco17").keypoints.index("left_wrist")}
    assert jac is not None


def test_smpl_topology_definitions():
    arrays = synthetic_model_arrays(num_vertices=6890, seed=3, with_keypoint_keys=False)
    smpl_like = BodyModel.from_data(validate_model_arrays(arrays))
    rng = np.random.default_rng(5)
    pose, betas = rng.normal(scale=0.3, size=72), rng.normal(size=10)
    out = smpl_like.forward(pose, betas)
    for set_name in ("coco17", "coco18", "body25", "body25b"):
        kmap = smpl_like.keypoint_set_map(set_name)
        assert kmap.source == f"{set_name}:smpl"
        kps = smpl_like.for_keypoint_set(set_name).keypoints(pose, betas)
        names = load_keypoint_set(set_name).keypoints
        assert kps.shape == (len(names), 3) and np.all(np.isfinite(kps))
        # Every definition is an affine combination (weights sum to one): it moves rigidly with the body.
        np.testing.assert_allclose(kmap.vertex_coeffs.sum(axis=1) + kmap.joint_coeffs.sum(axis=1), 1.0,
                                   atol=1e-5)
    coco = load_keypoint_set("coco17").keypoints
    kps = smpl_like.for_keypoint_set("coco17").keypoints(pose, betas)
    np.testing.assert_allclose(kps[coco.index("left_ear")], out.vertices[583], atol=1e-12)
    np.testing.assert_allclose(kps[coco.index("right_knee")], out.joints[5], atol=1e-12)
    # Another topology has no definition.
    other = BodyModel.from_data(validate_model_arrays(synthetic_model_arrays(num_vertices=500, seed=1)))
    with pytest.raises(ValueError, match="open model and the SMPL topology"):
        other.for_keypoint_set("coco17")


def test_tool_rebuilds_the_shipped_files(tmp_path):
    subprocess.run([sys.executable, str(REPO / "tools" / "build_keypoint_sets.py"), "--out", str(tmp_path)],
                   check=True, capture_output=True)
    for path in sorted(KEYPOINT_SET_DIR.glob("*.json")):
        assert json.loads((tmp_path / path.name).read_text()) == json.loads(path.read_text()), path.name
