"""2D label JSON files: round trip, both folder layouts, null fields, malformed content."""
from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from pedx_graph.data.labels2d import (
    Label2D,
    iter_label2d_files,
    label2d_path,
    parse_label2d_name,
    read_label2d,
    write_label2d,
)
from pedx_graph.data.types import PEDX_KEYPOINTS, DataFormatError, View2D

TID = "0123456789abcdef0123456789abcdef"


def make_view(seed: int = 0, n_labelled: int = 12) -> View2D:
    rng = np.random.default_rng(seed)
    keypoints = rng.uniform(100, 3000, size=(18, 2))
    keypoints[n_labelled:] = np.nan
    visible = np.zeros(18, dtype=bool)
    visible[: n_labelled - 2] = True
    polygon = rng.uniform(100, 3000, size=(7, 2))
    return View2D(keypoints=keypoints, visible=visible, polygon=polygon)


def label(view: View2D | None = None, camera: str = "ylw79D0", frame: int = 42) -> Label2D:
    return Label2D(sequence="20171207T2024", camera=camera, frame=frame, tracking_id=TID,
                   category="pedestrian", view=view or make_view(), subtype="adult")


@pytest.mark.parametrize("flat", [False, True])
def test_round_trip(tmp_path, flat):
    lab = label()
    path = write_label2d(tmp_path, lab, flat=flat)
    expected = "labels/2d/20171207T2024/" + ("" if flat else "ylw79D0/")
    assert path.relative_to(tmp_path).as_posix() == f"{expected}20171207T2024_ylw79D0_0000042_{TID}.json"
    (found,) = list(iter_label2d_files(tmp_path, "20171207T2024"))
    assert found == (path, "ylw79D0", 42, TID)
    back = read_label2d(found[0], "20171207T2024", *found[1:])
    assert (back.category, back.subtype, back.frame, back.tracking_id) == ("pedestrian", "adult", 42, TID)
    np.testing.assert_array_equal(back.view.keypoints, lab.view.keypoints)
    np.testing.assert_array_equal(back.view.visible, lab.view.visible)
    np.testing.assert_array_equal(back.view.polygon, lab.view.polygon)
    assert back.n_labelled == 12


def test_json_fields_follow_release_names(tmp_path):
    path = write_label2d(tmp_path, label())
    data = json.loads(path.read_text())
    assert set(data) == {"tracking_id", "category", "subtype", "frame_id", "polygon", "keypoint"}
    assert set(data["keypoint"]) == set(PEDX_KEYPOINTS[:12])
    assert set(data["keypoint"]["nose"]) == {"x", "y", "visible"}


def write_raw(tmp_path, data) -> tuple:
    path = label2d_path(tmp_path, "20171207T2024", "ylw79D0", 42, TID)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path, "20171207T2024", "ylw79D0", 42, TID


def test_null_keypoint_and_polygon(tmp_path):
    args = write_raw(tmp_path, {"tracking_id": TID, "category": "pedestrian", "keypoint": None, "polygon": None})
    back = read_label2d(*args)
    assert back.n_labelled == 0 and back.view.polygon is None and not back.view.visible.any()


def test_missing_and_null_joint_entries_are_unlabelled(tmp_path, caplog):
    keypoint = {"nose": {"x": 10, "y": 20, "visible": False}, "neck": None,
                "lsho": {"x": None, "y": None, "visible": False}, "rsho": {"x": 1.5, "y": 2.5},
                "lear": {"x": 1, "y": 2, "visible": True}}
    args = write_raw(tmp_path, {"category": "pedestrian", "keypoint": keypoint, "polygon": []})
    with caplog.at_level(logging.WARNING):
        back = read_label2d(*args)
    assert back.view.labelled.tolist() == [n in ("nose", "rsho") for n in PEDX_KEYPOINTS]
    assert back.view.visible[PEDX_KEYPOINTS.index("rsho")]  # visible defaults to true
    assert not back.view.visible[PEDX_KEYPOINTS.index("nose")]
    assert back.view.polygon is None
    assert "keypoint.lear" in caplog.text and "unknown keypoint name" in caplog.text


@pytest.mark.parametrize("data, field", [
    ("{not json", "<json>"),
    ([1, 2], "<json>"),
    ({"keypoint": None}, "category"),
    ({"category": "pedestrian", "keypoint": {"nose": {"y": 3, "visible": True}}}, "keypoint.nose.x"),
    ({"category": "pedestrian", "keypoint": {"nose": {"x": "left", "y": 3}}}, "keypoint.nose.x"),
    ({"category": "pedestrian", "keypoint": {"nose": {"x": 1, "y": 3, "visible": "maybe"}}},
     "keypoint.nose.visible"),
    ({"category": "pedestrian", "keypoint": [1, 2]}, "keypoint"),
    ({"category": "pedestrian", "polygon": [[0, 0], [1, 1]]}, "polygon"),
    ({"category": "pedestrian", "polygon": [[0, 0], [1, 1], [2]]}, "polygon[2]"),
])
def test_malformed(tmp_path, data, field):
    args = write_raw(tmp_path, data)
    with pytest.raises(DataFormatError) as info:
        read_label2d(*args)
    assert args[0].name in str(info.value) and f"'{field}'" in str(info.value)


def test_file_names():
    assert parse_label2d_name(f"20171130T2000_blu79CF_0000007_{TID}.json", "20171130T2000") == \
        ("blu79CF", 7, TID)
    assert parse_label2d_name(f"20171130T2000_blu79CF_12_{TID}.json", "20171130T2000", "blu79CF") == \
        ("blu79CF", 12, TID)
    assert parse_label2d_name(f"20171130T2000_blu79CF_12_{TID}.json", "20171130T2000", "grn43E3") is None
    assert parse_label2d_name("20171130T2000_blu79CF.json", "20171130T2000") is None


def test_writer_validates(tmp_path):
    bad = make_view()
    bad.polygon = np.zeros((2, 2))
    with pytest.raises(ValueError, match="polygon"):
        write_label2d(tmp_path, label(bad))
    with pytest.raises(ValueError, match="_"):
        write_label2d(tmp_path, Label2D("seq_1", "cam", 1, TID, "pedestrian", make_view()))
