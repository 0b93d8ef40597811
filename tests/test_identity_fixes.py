"""A reviewer's identity fixes (pedx_graph.detections.fixes): read from YAML, applied to the tracks, errors that
name the file and the operation; the truth's fixes (evaluate.truth_fixes) give every detection back to its
person; `pedx-graph import --identity-fixes` writes the fixed tracks."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from pedx_graph.cli import main
from pedx_graph.data.reader import read_dataset
from pedx_graph.data.types import DataFormatError
from pedx_graph.detections.fixes import IdentityFix, apply_fixes, read_fixes
from pedx_graph.detections.types import Detection
from scene_fixtures import small_scene
from test_detections_import import distorted_rig, write_openpose_truth

CAMERAS = {"L", "R", "L2", "R2"}


def _det(camera: str, frame: int, name: str) -> Detection:
    return Detection(camera=camera, frame=frame, keypoint_set="coco17", image_uv=np.zeros((17, 2)),
                     confidence=np.ones(17), score=1.0, source=name)


def _groups(spec: dict[str, dict[int, tuple[str, ...]]]) -> dict:
    """track -> frame -> camera -> detection named ``<track>/<frame>/<camera>`` (where it started)."""
    return {tid: {f: {c: _det(c, f, f"{tid}/{f}/{c}") for c in cams} for f, cams in frames.items()}
            for tid, frames in spec.items()}


def _names(groups: dict) -> dict:
    return {tid: {f: {c: d.source for c, d in cams.items()} for f, cams in frames.items()}
            for tid, frames in groups.items()}


def test_read_fixes_parses_every_operation(tmp_path):
    path = tmp_path / "fixes.yaml"
    path.write_text("""
seqA:
  - exchange: [det000006, det000007]
    frames: [14, 18]
    cameras: [red707B]
  - move: [det000011, det000006]
    frames: 16
    cameras: ylw79D0
  - split: det000011
    at: 14
    new_id: det000031
  - merge: [det000002, det000009, det000010]
  - remove: det000004
seqB: []
""")
    fixes = read_fixes(path)
    assert list(fixes) == ["seqA", "seqB"] and fixes["seqB"].operations == ()
    assert fixes["seqA"].made_for is None
    ex, mv, sp, mg, rm = fixes["seqA"].operations
    assert (ex.kind, ex.tracks, ex.first_frame, ex.last_frame, ex.cameras) == \
        ("exchange", ("det000006", "det000007"), 14, 18, ("red707B",))
    assert (mv.first_frame, mv.last_frame, mv.cameras) == (16, 16, ("ylw79D0",))
    assert (sp.kind, sp.tracks, sp.first_frame, sp.new_id) == ("split", ("det000011",), 14, "det000031")
    assert mg.tracks == ("det000002", "det000009", "det000010") and mg.first_frame is None
    assert (rm.kind, rm.first_frame, rm.last_frame, rm.cameras) == ("remove", None, None, None)
    assert ex.where == "seqA[0].exchange" and rm.where == "seqA[4].remove"
    assert ex.selects(14, "red707B") and ex.selects(18, "red707B")
    assert not ex.selects(13, "red707B") and not ex.selects(19, "red707B") and not ex.selects(15, "ylw79D0")
    (tmp_path / "ids.yaml").write_text("seqA:\n  - exchange: [3, '4']\n    cameras: 0\n"
                                       "  - split: 5\n    at: 2\n    new_id: 9\n")
    ex, sp = read_fixes(tmp_path / "ids.yaml")["seqA"].operations      # numeric file ids, unquoted
    assert ex.tracks == ("3", "4") and ex.cameras == ("0",) and (sp.tracks, sp.new_id) == (("5",), "9")
    (tmp_path / "empty.yaml").write_text("")
    assert read_fixes(tmp_path / "empty.yaml") == {}


@pytest.mark.parametrize("text, field", [
    ("seq: [exchange: [a, b]\n", None),                                     # not YAML
    ("- exchange: [a, b]\n", None),                                         # not a mapping of sequences
    ("seq: {exchange: [a, b]}\n", "seq.exchange"),                          # not a list of operations
    ("seq: remove a\n", "seq"),
    ("seq:\n  - [a, b]\n", "seq[0]"),
    ("seq:\n  - exchange: [a, b]\n    move: [a, b]\n", "seq[0]"),           # two kinds
    ("seq:\n  - swap: [a, b]\n", "seq[0]"),                                 # no kind
    ("seq:\n  - exchange: [a, b]\n    at: 3\n", "seq[0].at"),               # an option of another kind
    ("seq:\n  - exchange: [a]\n", "seq[0].exchange"),                       # one track
    ("seq:\n  - merge: [a]\n", "seq[0].merge"),
    ("seq:\n  - move: [a, a]\n", "seq[0].move"),
    ("seq:\n  - remove: 7.5\n", "seq[0].remove"),
    ("seq:\n  - remove: [true]\n", "seq[0].remove"),
    ("seq:\n  - remove: a\n    frames: [5, 3]\n", "seq[0].frames"),
    ("seq:\n  - remove: a\n    frames: [1, 2, 3]\n", "seq[0].frames"),
    ("seq:\n  - remove: a\n    frames: true\n", "seq[0].frames"),
    ("seq:\n  - remove: a\n    cameras: []\n", "seq[0].cameras"),
    ("seq:\n  - split: a\n", "seq[0].at"),
    ("seq:\n  - split: a\n    at: x\n", "seq[0].at"),
    ("seq:\n  - split: a\n    at: 3\n    new_id: [4]\n", "seq[0].new_id"),
    ("seq:\n  - checked: [a, b, c]\n", "seq[0].checked"),
    ("seq:\n  - add: a\n    cameras: L\n", "seq[0].frames"),
    ("seq:\n  - add: a\n    frames: 3\n", "seq[0].cameras"),
    ("seq:\n  - add: a\n    frames: 3\n    cameras: L\n    detection: -1\n", "seq[0].detection"),
    ("seq:\n  - add: a\n    frames: [3, 4]\n    cameras: L\n    detection: 2\n", "seq[0].detection"),
    ("seq:\n  - remove: a\n    detection: 2\n", "seq[0].detection"),
    ("seq:\n  made_for: 12\n  operations: []\n", "seq.made_for"),
    ("seq:\n  made_on: abc\n", "seq.made_on"),
    ("seq:\n  made_for: abc\n  operations: {remove: a}\n", "seq.operations"),
    ("seq:\n  operations:\n    - remove: a\n      at: 3\n", "seq.operations[0].at"),
])
def test_a_malformed_fixes_file_names_the_file_and_the_field(tmp_path, text, field):
    path = tmp_path / "fixes.yaml"
    path.write_text(text)
    with pytest.raises(DataFormatError) as info:
        read_fixes(path)
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message
    assert info.value.field == field


def test_fixes_exchange_move_split_merge_and_remove_detections():
    groups = _groups({"a": {0: ("L", "R"), 1: ("L", "R"), 2: ("L",), 3: ("L", "R")},
                      "b": {0: ("L", "R"), 1: ("L",), 2: ("L", "R"), 3: ("R",)},
                      "det000007": {5: ("L2",)}})
    fixes = [IdentityFix("exchange", ("a", "b"), 1, 2, ("L",), where="s[0].exchange"),
             IdentityFix("move", ("b", "a"), 2, 2, ("R",), where="s[1].move"),
             IdentityFix("split", ("a",), 3, where="s[2].split"),
             IdentityFix("merge", ("b", "det000007"), where="s[3].merge"),
             IdentityFix("remove", ("b",), 0, 0, where="s[4].remove")]
    fixed, record = apply_fixes(groups, fixes, "f.yaml", CAMERAS)
    assert _names(fixed) == {
        "a": {0: {"L": "a/0/L", "R": "a/0/R"}, 1: {"L": "b/1/L", "R": "a/1/R"}, 2: {"L": "b/2/L", "R": "b/2/R"}},
        "b": {1: {"L": "a/1/L"}, 2: {"L": "a/2/L"}, 3: {"R": "b/3/R"}, 5: {"L2": "det000007/5/L2"}},
        "det000008": {3: {"L": "a/3/L", "R": "a/3/R"}},        # the next free detNNNNNN
    }
    assert all(d.track_id == tid for tid, frames in fixed.items() for cams in frames.values() for d in cams.values())
    assert record == {"operations": 5, "detections_moved": 4 + 1 + 1, "detections_added": 0, "detections_removed": 2,
                      "tracks_changed": ["a", "b", "det000007", "det000008"]}
    assert _names(groups)["a"][1] == {"L": "a/1/L", "R": "a/1/R"}          # the input is left as it was
    # a whole track removed is gone; a split names its new track when asked to
    fixed, _ = apply_fixes(groups, [IdentityFix("remove", ("b",)), IdentityFix("split", ("a",), 2, new_id="c")],
                           "f.yaml", CAMERAS)
    assert sorted(fixed) == ["a", "c", "det000007"] and sorted(fixed["c"]) == [2, 3]


def test_add_gives_a_detection_no_track_holds_and_remove_makes_one():
    groups = _groups({"a": {0: ("L",), 2: ("L",)}, "b": {0: ("R",)}})
    loose = [_det("R", 1, "f1.json#people[0]"), _det("R", 2, "f2.json#people[0]"), _det("R", 2, "f2.json#people[4]"),
             _det("L", 1, "r.json#[17]"), _det("L", 2, "g.json#people[1]")]
    fixes = [IdentityFix("add", ("a",), 1, 1, ("L", "R"), where="s[0].add"),         # the one there in each
             IdentityFix("add", ("a",), 2, 2, ("R",), detection=4, where="s[1].add"),  # named by its index
             IdentityFix("remove", ("b",), 0, 0, ("R",), where="s[2].remove"),         # becomes untracked ...
             IdentityFix("add", ("a",), 0, 0, ("R",), where="s[3].add")]               # ... and is given to a
    fixed, record = apply_fixes(groups, fixes, "f.yaml", CAMERAS, loose)
    assert _names(fixed) == {"a": {0: {"L": "a/0/L", "R": "b/0/R"}, 1: {"L": "r.json#[17]", "R": "f1.json#people[0]"},
                                   2: {"L": "a/2/L", "R": "f2.json#people[4]"}}}
    assert (record["detections_added"], record["detections_removed"]) == (4, 1)
    for fix, words in [(IdentityFix("add", ("a",), 2, 2, ("R",), where="s[0].add"),
                        "2 untracked detections of camera R at frame 2 (name one with `detection`)"),
                       (IdentityFix("add", ("a",), 1, 1, ("R",), detection=3, where="s[0].add"),
                        "0 untracked detections with index 3 of camera R at frame 1"),
                       (IdentityFix("add", ("a",), 3, 3, ("R",), where="s[0].add"), "0 untracked detections"),
                       (IdentityFix("add", ("a",), 2, 2, ("L",), where="s[0].add"), "a already holds camera L at frame 2")]:
        with pytest.raises(DataFormatError, match=re.escape(words)):
            apply_fixes(groups, [fix], "f.yaml", CAMERAS, loose)


@pytest.mark.parametrize("fix, words", [
    (IdentityFix("exchange", ("a", "zz"), where="s[0].exchange"), "no track zz"),
    (IdentityFix("remove", ("a",), cameras=("Q",), where="s[0].remove"), "no camera Q"),
    (IdentityFix("exchange", ("a", "b"), 7, 9, where="s[0].exchange"), "selects no detection"),
    (IdentityFix("move", ("a", "b"), 0, 0, ("L",), where="s[0].move"), "b already holds camera L at frame 0"),
    (IdentityFix("move", ("a", "b"), 9, 9, where="s[0].move"), "selects no detection"),
    (IdentityFix("merge", ("a", "b"), where="s[0].merge"), "both hold camera L at frame 0"),
    (IdentityFix("split", ("a",), 0, where="s[0].split"), "does not split a"),
    (IdentityFix("split", ("a",), 1, new_id="b", where="s[0].split"), "new_id b is a track already"),
    (IdentityFix("remove", ("a",), 4, 6, where="s[0].remove"), "selects no detection"),
])
def test_a_fix_that_would_do_nothing_or_put_two_detections_in_one_place_is_an_error(fix, words):
    groups = _groups({"a": {0: ("L", "R"), 1: ("L",)}, "b": {0: ("L",), 2: ("R",)}})
    with pytest.raises(DataFormatError) as info:
        apply_fixes(groups, [fix], "f.yaml", CAMERAS)
    assert str(info.value).startswith("f.yaml: field 's[0].") and words in str(info.value)


def _scored_tracks():
    """Tracks with one person's detections on another's track (and a track of clutter), their truth records."""
    from pedx_graph.detections.association import DetectedTrack, DetectedTrackFrame

    records = []

    def det(frame, camera, kind, tid=None):
        records.append({"camera": camera, "frame": frame, "index": len(records), "kind": kind,
                        **({"tracking_id": tid} if tid else {})})
        return Detection(camera=camera, frame=frame, keypoint_set="coco17", image_uv=np.zeros((17, 2)),
                         confidence=np.ones(17), score=1.0, source=f"x.json#[{len(records) - 1}]")

    def track(name, items):
        frames = {}
        for f, cam, kind, tid in items:
            frames.setdefault(f, {})[cam] = det(f, cam, kind, tid)
        return DetectedTrack(track_id=name, pairs=("L-R",),
                             frames=[DetectedTrackFrame(frame=f, detections=d) for f, d in sorted(frames.items())])

    # t1 is a's, but holds b at frames 2-3 (both cameras) and at frame 4 in R; t2 is b's and holds a at 2-3;
    # t3 holds c once (c owns no track) among its own d; t4 is clutter
    t1 = track("t1", [(f, cam, "person", "a") for f in range(2) for cam in "LR"]
               + [(f, cam, "person", "b") for f in (2, 3) for cam in "LR"]
               + [(4, "L", "person", "a"), (4, "R", "person", "b")] + [(f, "L", "person", "a") for f in (5, 6, 7)])
    t2 = track("t2", [(f, cam, "person", "b") for f in (0, 1) for cam in "LR"]
               + [(f, cam, "person", "a") for f in (2, 3) for cam in "LR"])
    t3 = track("t3", [(f, "L", "person", "d") for f in range(3)] + [(3, "L", "person", "c")])
    t4 = track("t4", [(f, "L", "clutter", None) for f in range(3)])
    # no track holds: a's R at frames 5 and 6 (t1 has L alone there), d's R at frame 1, c's and clutter
    untracked = [det(5, "R", "person", "a"), det(6, "R", "person", "a"), det(1, "R", "person", "d"),
                 det(1, "R", "person", "c"), det(2, "R", "clutter")]
    return [t1, t2, t3, t4], records, untracked


def test_the_truths_fixes_give_every_detection_back_to_its_person():
    from pedx_graph.detections.evaluate import score_tracks, truth_fixes

    tracks, records, untracked = _scored_tracks()
    labelled = {p: {f: 10.0 for f in range(8)} for p in "abcd"}
    before = score_tracks(tracks, records, labelled)
    assert before["id_switches"] >= 4 and before["others_detections"] == 4 + 1 + 4 + 1
    fixes = truth_fixes(tracks, records, {"L", "R"})
    # consecutive frames alike written as one: the exchange of frames 2-3 in both cameras, b's R at frame 4
    # moved (t2 has no frame 4), c's detection removed (c owns no track)
    assert [(f.kind, f.tracks, f.first_frame, f.last_frame, f.cameras) for f in fixes] == [
        ("exchange", ("t1", "t2"), 2, 3, ("L", "R")), ("move", ("t1", "t2"), 4, 4, ("R",)),
        ("remove", ("t3",), 3, 3, ("L",))]
    groups = {t.track_id: {fr.frame: dict(fr.detections) for fr in t.frames} for t in tracks}
    fixed, _ = apply_fixes(groups, fixes, "<truth>", {"L", "R"})
    from pedx_graph.detections.association import DetectedTrack, DetectedTrackFrame
    after = score_tracks([DetectedTrack(track_id=tid, pairs=("L-R",), frames=[
        DetectedTrackFrame(frame=f, detections=cams) for f, cams in sorted(frames.items())])
        for tid, frames in fixed.items()], records, labelled)
    assert after["id_switches"] == 0 and after["others_detections"] == 0 and after["mixed_frames"] == 0
    assert after["own_detections"] == before["own_detections"] + 9        # the moved ones, now their own
    # looking only inside a stretch naming t1 and t2 over frames 2-3 fixes those frames alone
    stretch = [{"tracks": ["t1", "t2"], "first_frame": 2, "last_frame": 3}]
    assert [(f.kind, f.first_frame, f.last_frame) for f in truth_fixes(tracks, records, {"L", "R"}, stretch)] == \
        [("exchange", 2, 3)]
    assert truth_fixes(tracks, records, {"L", "R"}, []) == []
    # the detections no track holds: each person's given to its track (two in frame 1's R image: named by index)
    adds = truth_fixes(tracks, records, {"L", "R"}, untracked=untracked)[3:]
    assert [(f.kind, f.tracks, f.first_frame, f.last_frame, f.cameras, f.detection) for f in adds] == [
        ("add", ("t1",), 5, 6, ("R",), None), ("add", ("t3",), 1, 1, ("R",), int(untracked[2].source.rsplit("[", 1)[1].rstrip("]")))]
    fixed, record = apply_fixes(groups, fixes + adds, "<truth>", {"L", "R"}, untracked)
    assert record["detections_added"] == 3 and fixed["t3"][1]["R"].source == untracked[2].source
    # inside stretches only those a one-track stretch lists
    stretch = [{"tracks": ["t3"], "first_frame": 0, "last_frame": 2,
                "untracked": [{"camera": "R", "frame": 1, "source": untracked[2].source}]}]
    assert [(f.kind, f.tracks) for f in truth_fixes(tracks, records, {"L", "R"}, stretch, untracked)] == \
        [("add", ("t3",))]


def test_import_applies_the_fixes_file_and_names_a_bad_one_in_one_line(tmp_path, capsys):
    root = small_scene(tmp_path / "scene", pedestrians=2, frames=4, seed=1)
    raw_calibs = distorted_rig(root)
    files = tmp_path / "openpose"
    expected = write_openpose_truth(root, raw_calibs, files)
    args = ["import", "openpose", str(files), "--calib", str(root), "--use-file-ids"]
    assert main(args + ["--out", str(tmp_path / "plain")]) == 0
    plain = {t.tracking_id: t for t in read_dataset(tmp_path / "plain")}
    assert sorted(plain) == ["0", "1"]
    seq = plain["0"].sequence
    frames = sorted({fr.frame for fr in plain["0"].frames} & {fr.frame for fr in plain["1"].frames})
    at = frames[len(frames) // 2]
    digest = json.loads((tmp_path / "plain" / "import_summary.json").read_text())["sequences"][seq]["tracks_digest"]
    fixes = tmp_path / "fixes.yaml"
    fixes.write_text(f"{seq}:\n  made_for: '{digest}'\n  operations:\n"
                     f"    - exchange: ['0', '1']\n      frames: [{at}, {max(frames)}]\n")
    out = tmp_path / "fixed"
    assert main(args + ["--out", str(out), "--identity-fixes", str(fixes)]) == 0
    assert "1 identity fix operation applied" in capsys.readouterr().out
    assert (out / "identity_fixes.yaml").read_text() == fixes.read_text()       # kept beside what it made
    record = json.loads((out / "import_summary.json").read_text())["sequences"][seq]["identity_fixes"]
    assert record["operations"] == 1 and record["tracks_changed"] == ["0", "1"] and record["detections_moved"] > 0
    cam_of = {(name, side): cam for name in raw_calibs for side, cam in zip(("left", "right"), name.split("-"))}
    checked = 0
    for track in read_dataset(out):
        for fr in track.frames:
            for pair, side, view in fr.labelled_views():
                person = track.tracking_id if fr.frame < at else {"0": "1", "1": "0"}[track.tracking_id]
                want = expected[(cam_of[(pair, side)], fr.frame, person)]
                assert np.abs(view.keypoints - want).max() < 1e-3
                checked += fr.frame >= at
    assert checked > 0
    assert json.loads((out / "import_summary.json").read_text())["sequences"][seq]["tracks_digest"] == digest
    # fixes made for other tracks (another version, config or detections) are refused, not applied
    fixes.write_text(f"{seq}:\n  made_for: 0123456789abcdef\n  operations:\n    - remove: '0'\n")
    assert main(args + ["--out", str(tmp_path / "other"), "--identity-fixes", str(fixes)]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(fixes) in err and f"{seq}.made_for" in err and digest in err
    # a fix naming a track the import does not have: one line naming the file and the operation, exit 1
    fixes.write_text(f"{seq}:\n  - remove: '7'\n")
    assert main(args + ["--out", str(tmp_path / "bad"), "--identity-fixes", str(fixes)]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(fixes) in err and f"{seq}[0].remove" in err and "no track 7" in err
    fixes.write_text("other:\n  - remove: '0'\n")              # a sequence the detections do not have
    assert main(args + ["--out", str(tmp_path / "bad2"), "--identity-fixes", str(fixes)]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(fixes) in err and "'other'" in err and not (tmp_path / "bad2").exists()


def test_the_tracks_digest_follows_who_holds_what_not_where_the_files_lie():
    from pedx_graph.detections.association import DetectedTrack, DetectedTrackFrame
    from pedx_graph.detections.fixes import tracks_digest

    def tracks(folder, swap=False):
        a = _det("L", 0, f"{folder}/s_L_0000000_keypoints.json#people[0]")
        b = _det("L", 0, f"{folder}/s_L_0000000_keypoints.json#people[1]")
        a, b = (b, a) if swap else (a, b)
        return [DetectedTrack("det000001", [DetectedTrackFrame(0, {"L": a})], ("L-R",)),
                DetectedTrack("det000002", [DetectedTrackFrame(0, {"L": b})], ("L-R",))]

    assert tracks_digest(tracks("/data/run1/openpose")) == tracks_digest(tracks("openpose"))
    assert tracks_digest(tracks("openpose")) != tracks_digest(tracks("openpose", swap=True))


def test_checked_stretches_leave_the_order_to_check_and_the_tracks_review(tmp_path):
    from pedx_graph.data.reader import identity_review
    from pedx_graph.detections.fixes import mark_checked

    path = tmp_path / "fixes.yaml"
    path.write_text("s:\n  - checked: [a, b]\n    frames: [0, 10]\n  - checked: c\n")
    fixes = read_fixes(path)["s"].operations
    assert [(f.kind, f.tracks) for f in fixes] == [("checked", ("a", "b")), ("checked", ("c",))]
    groups = _groups({"a": {0: ("L",)}, "b": {1: ("L",)}, "c": {2: ("R",)}})
    fixed, record = apply_fixes(groups, fixes, path, CAMERAS)               # nothing moves
    assert _names(fixed) == _names(groups) and record["detections_moved"] == record["detections_removed"] == 0
    with pytest.raises(DataFormatError, match=r"field 's\[0\]\.checked': no track a"):
        apply_fixes({"b": groups["b"]}, fixes, path, CAMERAS)
    stretches = [{"tracks": ["a", "b"], "first_frame": 2, "last_frame": 8},      # inside [0, 10]: checked
                 {"tracks": ["a", "b"], "first_frame": 8, "last_frame": 12},     # past it: still to check
                 {"tracks": ["c"], "first_frame": 0, "last_frame": 3},           # c beside untracked ones
                 {"tracks": ["b", "c"], "first_frame": 0, "last_frame": 3}]      # b and c: no operation names both
    review = {"stretches": stretches, "check_order": [3, 2, 1, 0]}
    from pedx_graph.detections.association import DetectedTrack, DetectedTrackFrame
    held = [DetectedTrack(tid, [DetectedTrackFrame(f, {}) for f in range(0, 13, 2)], ("L-R",)) for tid in "abc"]
    assert mark_checked(review, fixes, held) == 2
    assert review["check_order"] == [3, 1] and review["checked_stretches"] == 2
    # the track frames still flagged: a's 8, 10, 12; b's 0, 2, 8, 10, 12; c's 0, 2 (the checked stretch of a
    # and b over 2-8 and c's own over 0-3 no longer count)
    assert review["unchecked_flagged_track_frames"] == 10
    assert [bool(s.get("checked")) for s in stretches] == [True, False, True, False]
    # a fit of the imported dataset repeats only the stretches still to check
    (tmp_path / "import_summary.json").write_text(json.dumps({"sequences": {"s": {"identity_review": review}}}))
    assert identity_review(tmp_path, "s") == {
        "a": [{"other": "b", "first_frame": 8, "last_frame": 12}],
        "b": [{"other": "a", "first_frame": 8, "last_frame": 12}, {"other": "c", "first_frame": 0, "last_frame": 3}],
        "c": [{"other": "b", "first_frame": 0, "last_frame": 3}]}


def test_import_adds_a_detection_no_track_holds(tmp_path):
    """A person's second, shifted detection in one image is dropped by the association (a duplicate) and held
    by no track; `remove` then `add` with its index in the file puts it in the track's place there."""
    root = small_scene(tmp_path / "scene", pedestrians=2, frames=8, seed=1)
    raw_calibs = distorted_rig(root)
    files = tmp_path / "openpose"
    write_openpose_truth(root, raw_calibs, files)
    path = sorted(files.rglob("*_keypoints.json"))[len(list(files.rglob("*_keypoints.json"))) // 2]
    doc = json.loads(path.read_text())
    copy = np.array(doc["people"][0]["pose_keypoints_2d"]).reshape(-1, 3)
    copy[:, :2] += 3.0                                   # 3 px off: a duplicate of the same person
    copy[:, 2] = 0.5                                     # scored lower: the one the association drops
    doc["people"].append({"person_id": [-1], "pose_keypoints_2d": copy.ravel().tolist()})
    path.write_text(json.dumps(doc))
    index = len(doc["people"]) - 1
    args = ["import", "openpose", str(files), "--calib", str(root)]
    assert main(args + ["--out", str(tmp_path / "plain")]) == 0
    summary = json.loads((tmp_path / "plain" / "import_summary.json").read_text())
    (seq,) = summary["sequences"]
    stem = path.name.replace("_keypoints.json", "")
    camera, frame = stem.split("_")[1], int(stem.split("_")[2])
    holder = [t for t in read_dataset(tmp_path / "plain") for fr in t.frames if fr.frame == frame
              and any(camera in (name.split("-")[0] if side == "left" else name.split("-")[1])
                      for name, side, _ in fr.labelled_views())]
    assert holder, "the person's own detection is on a track"
    tid = holder[0].tracking_id
    fixes = tmp_path / "fixes.yaml"
    fixes.write_text(f"{seq}:\n  - remove: {tid}\n    frames: {frame}\n    cameras: {camera}\n"
                     f"  - add: {tid}\n    frames: {frame}\n    cameras: {camera}\n    detection: {index}\n")
    out = tmp_path / "fixed"
    assert main(args + ["--out", str(out), "--identity-fixes", str(fixes)]) == 0
    record = json.loads((out / "import_summary.json").read_text())["sequences"][seq]["identity_fixes"]
    assert (record["detections_added"], record["detections_removed"]) == (1, 1)

    def label_uv(dataset):
        for t in read_dataset(dataset):
            if t.tracking_id != tid:
                continue
            for fr in t.frames:
                for name, side, view in fr.labelled_views():
                    if fr.frame == frame and name.split("-")[0 if side == "left" else 1] == camera:
                        return view.keypoints
        raise AssertionError("no label")

    shift = label_uv(out) - label_uv(tmp_path / "plain")
    assert np.all(np.abs(np.nanmedian(shift, axis=0)) > 1.0)         # the shifted copy's keypoints, rectified
