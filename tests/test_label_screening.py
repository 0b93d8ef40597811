"""2D labels against the image: keypoints outside it by more than the margin are dropped with a warning naming the
file and field; a label with most of its keypoints outside (1e9 px, every coordinate x 1e6) is a warned, skipped
instance; nothing absurd reaches a track."""
from __future__ import annotations

import json
import logging
import shutil

import numpy as np
import pytest

from pedx_graph.data.labels2d import Label2D, screen_label
from pedx_graph.data.reader import ReaderConfig, read_dataset
from pedx_graph.data.types import PEDX_KEYPOINTS, DataFormatError, View2D
from pedx_graph.sim.config import SimConfig
from pedx_graph.sim.simulate import simulate

SIZE = (3678, 2668)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("screen_scene")
    cfg = SimConfig()
    cfg.scene.n_pedestrians = 3
    cfg.scene.n_frames = 4
    simulate(out, cfg, seed=3)
    return out


def label(keypoints: np.ndarray, polygon=None) -> Label2D:
    return Label2D(sequence="seq", camera="ylw79D0", frame=1, tracking_id="t", category="pedestrian",
                   view=View2D(keypoints=keypoints, visible=np.ones(18, bool), polygon=polygon))


def inside_keypoints(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform([1000, 800], [1200, 1600], size=(18, 2))


def test_keypoint_far_outside_dropped_with_file_and_field(caplog):
    keypoints = inside_keypoints()
    keypoints[PEDX_KEYPOINTS.index("lwri")] = [1e9, 1000.0]
    keypoints[PEDX_KEYPOINTS.index("nose")] = [1100.0, -400.0]          # 15 % above the top
    keypoints[PEDX_KEYPOINTS.index("lankl")] = [3678 + 0.03 * 3678, 2000]  # 3 % past the right edge: kept
    with caplog.at_level(logging.WARNING):
        out = screen_label(label(keypoints), SIZE, 0.05, "some/file.json")
    assert "some/file.json: field 'keypoint.nose'" in caplog.text and "'keypoint.lwri' (1e+09, 1000)" in caplog.text
    assert "lankl" not in caplog.text and len(caplog.records) == 1
    dropped = [PEDX_KEYPOINTS.index(n) for n in ("lwri", "nose")]
    assert np.all(np.isnan(out.view.keypoints[dropped])) and not out.view.visible[dropped].any()
    kept = np.setdiff1d(np.arange(18), dropped)
    np.testing.assert_array_equal(out.view.keypoints[kept], keypoints[kept])
    # no margin: the ankle 3 % past the edge goes too
    assert np.isnan(screen_label(label(keypoints), SIZE, 0.0, "f.json").view.keypoints[kept]).any()


def test_absurd_label_skipped_whole(caplog):
    with caplog.at_level(logging.WARNING):
        assert screen_label(label(inside_keypoints() * 1e6), SIZE, 0.05, "big.json") is None
    assert "big.json: field 'keypoint': 18 of 18 keypoints outside" in caplog.text and "instance skipped" in caplog.text


def test_polygon_outside_dropped_keypoints_kept(caplog):
    polygon = np.array([[1000.0, 800.0], [1200.0, 800.0], [1e7, 1600.0]])
    with caplog.at_level(logging.WARNING):
        out = screen_label(label(inside_keypoints(), polygon), SIZE, 0.05, "poly.json")
    assert out.view.polygon is None and "poly.json: field 'polygon'" in caplog.text
    np.testing.assert_array_equal(out.view.keypoints, inside_keypoints())


def test_label_inside_is_returned_unchanged():
    original = label(inside_keypoints(), np.array([[1000.0, 800.0], [1200.0, 800.0], [1100.0, 1600.0]]))
    assert screen_label(original, SIZE, 0.05) is original


def _edit_label(path, fn) -> None:
    data = json.loads(path.read_text())
    fn(data)
    path.write_text(json.dumps(data))


def test_reader_drops_and_skips_with_warnings(scene, tmp_path, caplog):
    dataset = tmp_path / "ds"
    shutil.copytree(scene, dataset)
    files = sorted((dataset / "labels" / "2d").rglob("*.json"))
    labelled = [p for p in files if json.loads(p.read_text()).get("keypoint")]
    one, whole = labelled[0], labelled[1]

    def far_nose(data):
        data["keypoint"]["nose"]["x"] = 1e9
    _edit_label(one, far_nose)

    def scaled(data):
        for entry in data["keypoint"].values():
            entry["x"] *= 1e6
            entry["y"] *= 1e6
    _edit_label(whole, scaled)
    with caplog.at_level(logging.WARNING):
        tracks = read_dataset(dataset)
    assert f"{one}: field 'keypoint.nose'" in caplog.text
    assert f"{whole}: field 'keypoint'" in caplog.text and "instance skipped" in caplog.text
    limit = 1.05 * max(SIZE)
    for track in tracks:
        for frame in track.frames:
            for _, _, view in frame.labelled_views():
                assert np.all(np.abs(view.keypoints[view.labelled]) < limit)
    reference = read_dataset(scene)
    assert sum(len(t.frames) for t in tracks) >= sum(len(t.frames) for t in reference) - 1


def test_every_label_absurd_is_one_clear_error(scene, tmp_path):
    dataset = tmp_path / "ds"
    shutil.copytree(scene, dataset)

    def scaled(data):
        for entry in (data.get("keypoint") or {}).values():
            entry["x"] *= 1e6
            entry["y"] *= 1e6
    for path in (dataset / "labels" / "2d").rglob("*.json"):
        _edit_label(path, scaled)
    with pytest.raises(DataFormatError) as info:
        read_dataset(dataset, config=ReaderConfig())
    message = str(info.value)
    assert "no track could be read" in message and "outside the image" in message and "\n" not in message
