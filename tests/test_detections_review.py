"""The import's identity review: stretches where two tracks came close in an image or on the ground, none elsewhere."""
import numpy as np

from pedx_graph.data.types import UNTRACKED
from pedx_graph.detections.association import DetectedTrack, DetectedTrackFrame
from pedx_graph.detections.review import (ReviewConfig, check_order, close_detections, close_frames,
                                         flagged_frames, review_stretches, review_summary, untracked_detections)
from pedx_graph.detections.types import Detection


def _person(u: float, height: float, foot_v: float = 900.0) -> np.ndarray:
    """(17, 2) COCO-like keypoints of a standing person: a column at ``u`` (+-5 % of the height), ``height``
    pixels tall, feet on row ``foot_v``."""
    rows = np.linspace(0.0, 1.0, 17)
    return np.c_[u + 0.05 * height * np.sin(7.0 * rows), foot_v - height + rows * height]


def _track(tid: str, columns: dict[int, float], height: float = 200.0, centres: dict | None = None,
           camera: str = "camL") -> DetectedTrack:
    frames = []
    for frame, u in sorted(columns.items()):
        det = Detection(camera=camera, frame=frame, keypoint_set="coco17", image_uv=_person(u, height),
                        confidence=np.full(17, 0.8), score=0.8, source=f"{tid}#{frame}")
        centre = None if centres is None or frame not in centres else np.asarray(centres[frame], dtype=float)
        frames.append(DetectedTrackFrame(frame=frame, detections={camera: det}, world_p=centre))
    return DetectedTrack(track_id=tid, frames=frames, pairs=("camL-camR",))


def test_two_walkers_passing_in_one_image_flag_the_frames_around_the_crossing():
    """Two people of one size walk towards each other in an image: their columns come within a fifth of their
    height at frames 17 and 18 only; the stretch is those frames widened by one (and cut at the tracks' last
    frame, 19), for both tracks; a third person elsewhere is flagged nowhere."""
    a = _track("a", {f: 300.0 + 20.0 * f for f in range(20)})
    b = _track("b", {f: 1000.0 - 20.0 * f for f in range(20)})
    far = _track("c", {f: 3000.0 for f in range(20)})
    same_frame = ReviewConfig(frame_step=0)
    assert close_frames([a, b, far], config=same_frame) == {("a", "b"): {17, 18}}
    stretches = review_stretches([a, b, far], config=same_frame)
    assert stretches == [{"tracks": ["a", "b"], "first_frame": 16, "last_frame": 19, "close_frames": [17, 18],
                          "frames_held": 8, "frames_missed": 0}]
    assert flagged_frames([a, b, far], stretches) == {"a": {16, 17, 18, 19}, "b": {16, 17, 18, 19}, "c": set()}
    wider = ReviewConfig(pad_frames=3, frame_step=0)
    assert review_stretches([a, b, far], config=wider)[0]["first_frame"] == 14


def test_a_detection_taken_where_the_own_person_was_missed_is_flagged_across_the_gap():
    """Track ``b`` is missed at frames 5-8 and at frame 7 holds a detection where ``a``'s person stood at
    frames 6 and 8 (``a`` has none at 7: ``b`` took it).  Never close to ``a`` at one frame, ``b`` is close
    one frame apart; the stretch runs on through ``b``'s gap to where each is seen again (4 to 9)."""
    a = _track("a", {f: 500.0 + 10.0 * f for f in range(12) if f != 7})
    b = _track("b", {f: 1500.0 for f in range(12) if not 5 <= f <= 8})
    b.frames.insert(5, _track("b", {7: 570.0}).frames[0])
    assert close_frames([a, b], config=ReviewConfig(frame_step=0)) == {}
    assert close_frames([a, b]) == {("a", "b"): {6, 7, 8}}
    # a holds 4-9 but 7, b holds 4, 7 and 9: 8 frames held, 4 missed inside their own spans
    assert review_stretches([a, b]) == [{"tracks": ["a", "b"], "first_frame": 4, "last_frame": 9,
                                         "close_frames": [6, 7, 8], "frames_held": 8, "frames_missed": 4}]


def test_overlap_of_people_of_very_different_size_or_rows_is_not_close():
    """A person twice as tall (twice as near) passing in front of another is not taken for it; nor is one
    whose keypoint rows do not overlap the other's (a person on a balcony above)."""
    near = _track("near", {f: 100.0 + 50.0 * f for f in range(20)}, height=400.0)
    far = _track("far", {f: 1100.0 - 50.0 * f for f in range(20)}, height=200.0)
    assert close_frames([near, far]) == {}
    above = _track("above", {f: 1100.0 - 50.0 * f for f in range(20)})
    for fr in above.frames:
        for det in fr.detections.values():
            det.image_uv[:, 1] -= 500.0
    assert close_frames([_track("a", {f: 100.0 + 50.0 * f for f in range(20)}), above]) == {}
    # the same two in different cameras are never compared in the image
    other_camera = _track("b", {f: 1100.0 - 50.0 * f for f in range(20)}, camera="camX")
    assert close_frames([_track("a", {f: 100.0 + 50.0 * f for f in range(20)}), other_camera]) == {}


def test_people_walking_side_by_side_on_the_ground_are_close_however_they_look():
    """Centres 0.5 m apart on the ground are close at every frame where both have one (two stretches around
    a gap), even where the images keep them apart; 1.5 m apart they are not."""
    frames = range(12)
    a = _track("a", {f: 100.0 for f in frames}, centres={f: (10.0 + 0.1 * f, 0.0, 0.0) for f in frames})
    b = _track("b", {f: 2000.0 for f in frames},
               centres={f: (10.0 + 0.1 * f, 0.5, 0.0) for f in frames if not 4 <= f <= 7})
    stretches = review_stretches([a, b])
    assert [(s["first_frame"], s["last_frame"]) for s in stretches] == [(0, 4), (7, 11)]
    apart = _track("b", {f: 2000.0 for f in frames}, centres={f: (10.0 + 0.1 * f, 1.5, 0.0) for f in frames})
    assert review_stretches([a, apart]) == []


def test_the_review_reaches_the_fit_record_and_the_results_table(tmp_path, caplog):
    """A dataset with the import's ``import_summary.json``: the reader gives each track the stretches naming
    it (both ways), the fit's record lists those overlapping its frames, the results table prints them; a
    malformed summary warns, naming the file and field, and the labels are read all the same."""
    import json
    import logging

    from pedx_graph.data.reader import read_dataset
    from pedx_graph.eval.results_summary import results_tables
    from pedx_graph.graph.config import FitConfig
    from pedx_graph.solvers.fit import fit_task
    from scene_fixtures import small_scene

    root = small_scene(tmp_path / "scene", pedestrians=2, frames=3, seed=1)
    tracks = read_dataset(root)
    assert all(t.identity_review == [] for t in tracks)                     # hand labels: none
    seq = tracks[0].sequence
    a, b = sorted(t.tracking_id for t in tracks)[:2]
    first = min(fr.frame for t in tracks for fr in t.frames)
    stretches = [{"tracks": [a, b], "first_frame": first, "last_frame": first + 1, "close_frames": [first]},
                 {"tracks": [a, b], "first_frame": first + 100, "last_frame": first + 101, "close_frames": []},
                 {"tracks": [b], "first_frame": first + 200, "last_frame": first + 202, "close_frames": [first + 201],
                  "untracked": [{"camera": "camL", "frame": first + 201, "source": "x.json#people[1]"}]}]
    summary = {"sequences": {seq: {"identity_review": {"stretches": stretches}}}}
    (root / "import_summary.json").write_text(json.dumps(summary))
    by_id = {t.tracking_id: t for t in read_dataset(root)}
    assert by_id[b].identity_review == [{"other": a, "first_frame": first, "last_frame": first + 1},
                                        {"other": a, "first_frame": first + 100, "last_frame": first + 101},
                                        {"other": UNTRACKED, "first_frame": first + 200, "last_frame": first + 202}]
    assert len(by_id[a].identity_review) == 2                               # a one-track stretch names b only
    config = FitConfig()
    config.covariances = config.diagnostics = False
    record = fit_task(by_id[a], (config, "lm")).records[0]
    assert record["identity_review"] == [{"other": b, "first_frame": first, "last_frame": first + 1}]
    table = results_tables({"residuals": {}, "per_distance": {}, "tracks": [
        {"sequence": seq, "tracking_id": a, "frames": 3, "final_error": 1.0, "iterations": 2, "mesh_closed": True,
         "inside_out_frames": 0, "inconsistent_frames": 0, "depth_sources": {}, "max_distance_m": 10.0,
         "max_abs_beta": 0.5, "identity_review": record["identity_review"]}]})["tracks"]
    assert f"| {first}-{first + 1} ({b}) |" in table
    row = {"sequence": seq, "frames": 3, "final_error": 1.0, "iterations": 2, "mesh_closed": True,
           "inside_out_frames": 0, "inconsistent_frames": 0, "depth_sources": {}, "max_distance_m": 10.0,
           "max_abs_beta": 0.5, "identity_review": []}
    ids = results_tables({"residuals": {}, "per_distance": {}, "tracks": [
        dict(row, tracking_id="det000003"), dict(row, tracking_id="0123456789abcdef" * 2)]})["tracks"]
    assert f"| {seq} det000003 |" in ids and f"| {seq} 01234567 |" in ids     # an import's id whole, a hash cut
    summary["sequences"][seq]["identity_review"]["stretches"] = [{"tracks": [a], "first_frame": 0}]
    (root / "import_summary.json").write_text(json.dumps(summary))
    with caplog.at_level(logging.WARNING):
        again = read_dataset(root)
    assert len(again) == len(tracks) and all(t.identity_review == [] for t in again)
    assert "import_summary.json: field sequences." in caplog.text and "identity_review.stretches" in caplog.text


def test_stretches_where_a_track_missed_its_person_are_checked_first():
    """Two crossings: ``a`` and ``b`` pass each other seen in every frame; ``c`` and ``d`` pass while ``d`` is
    missed for the three frames before they meet (where a tracker takes one for the other).  The second is
    checked first, though it comes second in the list; equal shares go shortest first."""
    a = _track("a", {f: 300.0 + 20.0 * f for f in range(20)})
    b = _track("b", {f: 1000.0 - 20.0 * f for f in range(20)})
    c = _track("c", {f: 2300.0 + 20.0 * f for f in range(20)})
    d = _track("d", {f: 3000.0 - 20.0 * f for f in range(20) if not 14 <= f <= 16})
    summary = review_summary([a, b, c, d], config=ReviewConfig(frame_step=0))
    stretches = summary["stretches"]
    assert [s["tracks"] for s in stretches] == [["a", "b"], ["c", "d"]]
    assert stretches[0]["frames_missed"] == 0 and stretches[1]["frames_missed"] == 3
    assert summary["check_order"] == [1, 0]
    even = [{"frames_held": 9, "frames_missed": 0}, {"frames_held": 4, "frames_missed": 0},
            {"frames_held": 6, "frames_missed": 2}]
    assert check_order(even) == [2, 1, 0]


def _loose(u: float, frame: int, height: float = 200.0, source: str = "loose", camera: str = "camL") -> Detection:
    """A detection no track holds: a standing person at column ``u``."""
    return Detection(camera=camera, frame=frame, keypoint_set="coco17", image_uv=_person(u, height),
                     confidence=np.full(17, 0.7), score=0.7, source=f"{source}#{frame}")


def test_a_detection_no_track_holds_beside_a_track_flags_that_track_alone():
    """Track ``a`` walks right in one image.  At frame 7 a detection of someone its size stands a tenth of a
    height beside it and no track holds it (the association kept one of two people on one ray): a stretch
    naming ``a`` alone lists it, frames 6-8 (compared at one frame).  Detections no track holds that are far off
    in the image, twice as tall, or in another camera flag nothing; with ``ReviewConfig.untracked`` off,
    nothing either.  Compared one frame apart as well (the default), ``a``'s frames 6 and 8 are close to it
    too (a at 560 and 580 px)."""
    a = _track("a", {f: 500.0 + 10.0 * f for f in range(12)})
    b = _track("b", {f: 2500.0 for f in range(12)})
    beside = _loose(570.0 + 20.0, 7, source="beside")
    loose = [beside, _loose(1500.0, 7, source="far"), _loose(580.0, 3, height=400.0, source="tall"),
             _loose(560.0, 6, source="other_camera", camera="camR")]
    same_frame = ReviewConfig(frame_step=0)
    pairs, lone = close_detections([a, b], config=same_frame, untracked=loose)
    assert pairs == {} and lone == {"a": {7: [beside]}}
    assert review_stretches([a, b], config=same_frame, untracked=loose) == [
        {"tracks": ["a"], "first_frame": 6, "last_frame": 8, "close_frames": [7], "frames_held": 3,
         "frames_missed": 0, "untracked": [{"camera": "camL", "frame": 7, "source": "beside#7"}]}]
    assert review_stretches([a, b], config=ReviewConfig(frame_step=0, untracked=False), untracked=loose) == []
    assert review_stretches([a, b], config=same_frame) == []
    _, lone = close_detections([a, b], untracked=loose)
    assert lone == {"a": {6: [beside], 7: [beside], 8: [beside]}}
    stretch, = review_stretches([a, b], untracked=loose)
    assert (stretch["first_frame"], stretch["last_frame"], stretch["untracked"]) == \
        (5, 9, [{"camera": "camL", "frame": 7, "source": "beside#7"}])


def test_untracked_detections_are_those_no_track_holds_joined_parts_included():
    """A track's detection joined from an upper and a lower part holds both parts' sources; the detections left
    are those of no track, in their order."""
    a = _track("a", {0: 500.0, 1: 510.0})
    joined = a.frames[1].detections["camL"]
    a.frames[1].detections["camL"] = Detection(camera="camL", frame=1, keypoint_set="coco17",
                                               image_uv=joined.image_uv, confidence=joined.confidence, score=0.8,
                                               source="up#1 + low#1")
    read = [a.frames[0].detections["camL"], _loose(900.0, 0, source="x"), _loose(510.0, 1, source="up"),
            _loose(510.0, 1, source="low"), _loose(510.0, 1, source="a"), _loose(510.0, 1, camera="camR",
                                                                                source="up")]
    assert [d.source for d in untracked_detections(read, [a])] == ["x#0", "a#1", "up#1"]
