"""SMPL label JSON files: round trip with extra fields, shapes, malformed content."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pedx_graph.data.smpl_labels import read_smpl_label, smpl_label_path, write_smpl_label
from pedx_graph.data.types import DataFormatError, SmplLabel

TID = "fedcba9876543210fedcba9876543210"


def make_label(frame: int = 3, seed: int = 0) -> SmplLabel:
    rng = np.random.default_rng(seed)
    return SmplLabel(sequence="20171212T2030", frame=frame, tracking_id=TID, betas=rng.normal(size=10),
                     pose=rng.normal(size=72) * 0.2, trans=np.array([18.0, -2.0, -1.0]),
                     extra={"keypoints_3d": rng.normal(size=(18, 3)).tolist(),
                            "covariance": np.eye(3) * 0.01, "solver": {"name": "lm", "iterations": 7}})


def test_round_trip(tmp_path):
    label = make_label()
    path = write_smpl_label(tmp_path, label)
    assert path == smpl_label_path(tmp_path, "20171212T2030", 3, TID)
    assert path.name == f"20171212T2030_0000003_{TID}.json"
    data = json.loads(path.read_text())
    assert list(data)[:3] == ["betas", "pose", "trans"] and "covariance" in data  # extras at top level
    back = read_smpl_label(path)  # identity from the path
    assert (back.sequence, back.frame, back.tracking_id) == ("20171212T2030", 3, TID)
    for name in ("betas", "pose", "trans"):
        np.testing.assert_array_equal(getattr(back, name), getattr(label, name))
    assert back.extra["solver"] == {"name": "lm", "iterations": 7}
    np.testing.assert_array_equal(back.extra["covariance"], np.eye(3) * 0.01)
    np.testing.assert_array_equal(back.extra["keypoints_3d"], label.extra["keypoints_3d"])


def test_nested_shapes_accepted(tmp_path):
    path = smpl_label_path(tmp_path, "20171212T2030", 5, TID)
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps({"betas": [[0.1] * 10], "pose": [[0.0, 0.0, 0.1]] * 24, "trans": [1, 2, 3]}))
    back = read_smpl_label(path)
    assert back.betas.shape == (10,) and back.pose.shape == (72,) and back.extra == {}


@pytest.mark.parametrize("edit, field", [
    ({"betas": [0.0] * 9}, "betas"),
    ({"pose": [0.0] * 69}, "pose"),
    ({"trans": [0.0, "x", 1.0]}, "trans"),
    ({"trans": None}, "trans"),
    ({"pose": [float("nan")] * 72}, "pose"),
])
def test_malformed(tmp_path, edit, field):
    data = {"betas": [0.0] * 10, "pose": [0.0] * 72, "trans": [0.0, 0.0, 0.0]}
    data.update(edit)
    path = smpl_label_path(tmp_path, "20171212T2030", 5, TID)
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(data))  # NaN is written as the non-standard NaN token; Python reads it back
    with pytest.raises(DataFormatError) as info:
        read_smpl_label(path)
    assert path.name in str(info.value) and f"'{field}'" in str(info.value)


def test_any_betas_length_when_asked(tmp_path):
    label = make_label()
    label.betas = np.zeros(16)
    with pytest.raises(DataFormatError, match="betas"):
        write_smpl_label(tmp_path, label)
    path = write_smpl_label(tmp_path, label, n_betas=None)
    assert read_smpl_label(path, n_betas=None).betas.shape == (16,)


def test_extra_may_not_shadow_release_keys(tmp_path):
    label = make_label()
    label.extra["pose"] = [0.0]
    with pytest.raises(DataFormatError, match="extra.pose"):
        write_smpl_label(tmp_path, label)
