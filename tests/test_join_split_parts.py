"""A person a bottom-up detector reported as two people (upper body; hips and legs) is one detection again:
joined when the two parts make one standing person, never with someone else's part, never a whole one."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pedx_graph.body import BodyModel
from pedx_graph.body.keypoint_defs import standing_keypoints_2d
from pedx_graph.data.calib import read_calibrations
from pedx_graph.detections.association import AssociationConfig, associate, join_misfit, join_split_parts
from pedx_graph.detections.evaluate import detection_records, read_detection_truth, score_tracks
from pedx_graph.detections.openpose import read_openpose
from pedx_graph.detections.types import Detection
from pedx_graph.keypoints import lower_body_mask
from pedx_graph.sim.config import SimConfig
from scene_fixtures import small_scene

SET = "body25"


def _person(u0: float, v0: float, height: float, rng, swing: float = 0.0) -> np.ndarray:
    """(25, 2) pixels of a standing person of ``height`` px whose top keypoint is at ``v0``, centred on
    ``u0``: the open model's proportions, the ankles and wrists swung by ``swing`` of the height, 1.5 px
    noise."""
    uv = standing_keypoints_2d(BodyModel.load(), SET) * height + [u0, v0]
    lower = lower_body_mask(SET)
    uv[lower & (uv[:, 1] > v0 + 0.8 * height), 0] += swing * height      # feet forward
    uv[~lower & (np.abs(uv[:, 1] - v0 - 0.43 * height) < 0.05 * height), 0] -= swing * height    # wrists back
    return uv + 1.5 * rng.normal(size=uv.shape)


def _farther(u0: float, v0: float, height: float, times: float, rng) -> np.ndarray:
    """Someone ``times`` as far as a 1.7 m walker of ``height`` px whose top is at ``v0``, on the same flat
    ground seen from 1.95 m up, in the same column: smaller, and higher in the image."""
    horizon = v0 - height * (1.95 - 1.7) / 1.7
    return _person(u0, horizon + (v0 - horizon) / times, height / times, rng)


def _det(uv: np.ndarray, keep: np.ndarray, name: str, score: float = 0.6) -> Detection:
    return Detection(camera="cam", frame=0, keypoint_set=SET, image_uv=np.where(keep[:, None], uv, np.nan),
                     confidence=np.where(keep, score, 0.0), score=score, source=f"f#people[{name}]")


def _items(dets):
    return [(d, d.image_uv.copy()) for d in dets]


def test_the_two_parts_of_one_walker_are_joined_into_one_detection():
    rng = np.random.default_rng(0)
    lower = lower_body_mask(SET)
    uv = _person(400.0, 300.0, 260.0, rng, swing=0.12)
    upper_part, lower_part = _det(uv, ~lower, "0", 0.7), _det(uv, lower, "1", 0.5)
    out = join_split_parts(_items([upper_part, lower_part]), AssociationConfig())
    assert len(out) == 1
    det, rect = out[0]
    np.testing.assert_allclose(det.image_uv, uv)
    np.testing.assert_allclose(rect, uv)
    assert det.source == "f#people[0] + f#people[1]"
    assert det.score == pytest.approx((0.7 * (~lower).sum() + 0.5 * lower.sum()) / len(lower))
    # switched off: as they came
    config = AssociationConfig(join_split_parts=False)
    assert [d for d, _ in join_split_parts(_items([upper_part, lower_part]), config)] == [upper_part, lower_part]


def test_a_part_is_joined_with_its_own_person_not_a_neighbour_or_someone_farther_away():
    rng = np.random.default_rng(1)
    lower = lower_body_mask(SET)
    walker = _person(400.0, 300.0, 260.0, rng)
    beside = _person(400.0 + 0.45 * 260.0, 300.0, 260.0, rng)        # someone half a body to the side
    farther = _farther(400.0, 300.0, 260.0, 2.0, rng)                # twice as far in the same column
    # the neighbour's or the far person's legs alone never join the walker's upper body
    for other in (beside, farther):
        out = join_split_parts(_items([_det(walker, ~lower, "0"), _det(other, lower, "1")]), AssociationConfig())
        assert len(out) == 2
    # with its own legs there too, the walker's upper body takes them; the neighbour's legs stay alone
    dets = [_det(beside, lower, "0"), _det(walker, ~lower, "1"), _det(walker, lower, "2")]
    out = join_split_parts(_items(dets), AssociationConfig())
    assert sorted(d.source for d, _ in out) == ["f#people[0]", "f#people[1] + f#people[2]"]
    # whole detections are never joined with anything
    whole = _det(walker, np.ones(len(lower), dtype=bool), "3")
    assert len(join_split_parts(_items([whole, _det(beside, lower, "4")]), AssociationConfig())) == 2


def test_join_misfit_is_small_for_one_person_and_large_across_people():
    rng = np.random.default_rng(2)
    lower = lower_body_mask(SET)
    walker = _person(400.0, 300.0, 260.0, rng, swing=0.1)
    up = np.where(~lower[:, None], walker, np.nan)
    rows, column = join_misfit(up, np.where(lower[:, None], walker, np.nan), SET)
    assert rows < 0.05 and column < 0.1
    far = _farther(400.0, 300.0, 260.0, 2.0, rng)
    assert join_misfit(up, np.where(lower[:, None], far, np.nan), SET)[0] > 3 * AssociationConfig().join_row_sigma


def _scene(root, split_prob: float):
    cfg = SimConfig()
    cfg.detections.formats = ("openpose_body25",)
    cfg.detections.split_prob = split_prob
    return small_scene(root, pedestrians=5, frames=8, seed=3, config=cfg)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """The same scene (seed) with OpenPose's people whole, and with every one split in two."""
    root = tmp_path_factory.mktemp("split")
    return _scene(root / "whole", 0.0), _scene(root / "split", 1.0)


def _scores(root, config=None):
    seq = json.loads((root / "truth" / "meta.json").read_text())["sequence"]
    dets = read_openpose(root / "detections" / "openpose_body25" / seq, keypoint_set=SET)
    records = read_detection_truth(root, seq, "openpose_body25")
    labelled = {}
    for path in sorted((root / "truth" / seq).glob("*.json")):
        doc = json.loads(path.read_text())
        for tid, person in doc["people"].items():
            if person.get("labelled"):
                labelled.setdefault(tid, {})[int(doc["frame"])] = 10.0
    tracks = associate(dets, read_calibrations(root / "calib"), config=config)
    score = score_tracks(tracks, records, labelled)
    views = [d for t in tracks for fr in t.frames for d in fr.detections.values()]
    return score, views, records


def test_a_scene_of_split_people_is_associated_as_if_they_were_whole(scenes):
    """Every OpenPose person split in two: with the joining, the tracks are those of the same scene without
    splits (people recovered, no switch, fragmentation or mixed frame more), each detection upper body and
    legs of one person; without it, the parts make extra tracks and fragment people."""
    whole, split = scenes
    lower = lower_body_mask(SET)
    keys = ("tracks", "false_tracks", "recovered", "id_switches", "fragmentations", "mixed_frames")
    reference, _, _ = _scores(whole)
    assert reference["recovered"] > 0
    joined, views, records = _scores(split)
    assert {k: joined[k] for k in keys} == {k: reference[k] for k in keys}

    def whole_share(views) -> float:          # views holding upper-body and leg keypoints
        return float(np.mean([d.present[lower].any() and d.present[~lower].any() for d in views]))

    assert whole_share(views) > 0.9
    assert all(len({r["tracking_id"] for r in detection_records(d, records)}) == 1 for d in views)
    apart, views, _ = _scores(split, AssociationConfig(join_split_parts=False))
    assert apart["fragmentations"] > 0 and apart["tracks"] > reference["tracks"]
    assert whole_share(views) < 0.1            # a clutter detection spans both
