"""Fuzzing the detection readers: any JSON-ish content gives detections or a one-line DataFormatError naming
the file (hypothesis, derandomized, no example database)."""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.configuration import set_hypothesis_home_dir

from pedx_graph.data.types import DataFormatError
from pedx_graph.detections.coco import read_coco
from pedx_graph.detections.openpose import read_openpose

set_hypothesis_home_dir(Path(tempfile.gettempdir()) / "pedx-graph-hypothesis")
FUZZ = settings(max_examples=150, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck))

numbers = st.one_of(st.integers(-5, 3000), st.floats(allow_nan=True, allow_infinity=True), st.booleans(),
                    st.none(), st.text(max_size=3))
json_values = st.recursive(numbers, lambda inner: st.one_of(st.lists(inner, max_size=6),
                                                            st.dictionaries(st.text(max_size=8), inner, max_size=4)),
                           max_leaves=20)


def openpose_docs():
    flat = st.lists(numbers, min_size=0, max_size=80) | st.lists(st.floats(0, 1000), min_size=75, max_size=75)
    person = st.fixed_dictionaries({"pose_keypoints_2d": flat}, optional={"person_id": json_values})
    return st.one_of(json_values, st.fixed_dictionaries({"people": st.lists(person, max_size=3)},
                                                        optional={"version": numbers}))


def coco_docs():
    ann = st.fixed_dictionaries({"image_id": st.sampled_from([1, 2, 2.5, float("nan"), float("inf"), 10 ** 30, "x", None]),
                                 "keypoints": st.lists(numbers, max_size=54) | st.lists(st.integers(0, 2),
                                                                                          min_size=51, max_size=51)},
                                optional={"bbox": st.lists(numbers, min_size=4, max_size=4) | json_values,
                                          "category_id": numbers, "track_id": json_values, "score": numbers})
    image = st.fixed_dictionaries({"id": st.sampled_from([1, 2, "1", float("nan"), 1.5]),
                                   "file_name": st.sampled_from(["s_c_0000001.jpg", "c.7.png", "bad", 3])})
    annotation_file = st.fixed_dictionaries({"images": st.lists(image, max_size=2),
                                             "annotations": st.lists(ann, max_size=3)})
    return st.one_of(json_values, annotation_file, st.lists(ann, max_size=3))


def _check(read, path: Path, text: str):
    path.write_text(text)
    try:
        dets = read(path)
    except DataFormatError as exc:
        message = str(exc)
        assert "\n" not in message and str(path) in message
        return
    for det in dets:
        k = len(det.confidence)
        assert det.image_uv.shape == (k, 2) and np.all((det.confidence >= 0) & (det.confidence <= 1))
        present = det.confidence > 0
        assert np.all(np.isfinite(det.image_uv[present])) and np.all(np.isnan(det.image_uv[~present]))
        assert np.isfinite(det.score)
        assert det.bbox is None or (det.bbox.shape == (4,) and np.all(np.isfinite(det.bbox)))


@FUZZ
@given(doc=openpose_docs())
def test_openpose_reader_fuzz(doc):
    with tempfile.TemporaryDirectory() as tmp:
        _check(read_openpose, Path(tmp) / "cam1.0003.json", json.dumps(doc))


@FUZZ
@given(doc=coco_docs())
def test_coco_reader_fuzz(doc):
    with tempfile.TemporaryDirectory() as tmp:
        _check(lambda p: read_coco(p, camera="cam1"), Path(tmp) / "coco.json", json.dumps(doc))


@FUZZ
@given(data=st.binary(max_size=200))
def test_readers_on_arbitrary_bytes(data):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "cam1.0003.json"
        path.write_bytes(data)
        for read in (read_openpose, lambda p: read_coco(p, camera="cam1")):
            try:
                read(path)
            except DataFormatError as exc:
                assert "\n" not in str(exc) and str(path) in str(exc)
