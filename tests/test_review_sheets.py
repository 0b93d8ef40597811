"""Review sheets: the identity review's stretches drawn on the images the detector saw (synthetic detections and
images: what is drawn where, which cells find their image), the limbs of every keypoint set, and the import's
``--review-images`` on a simulated scene."""
import json

import cv2
import numpy as np
import pytest

from pedx_graph.cli import main
from pedx_graph.detections.openpose import read_openpose
from pedx_graph.detections.review_sheets import (BLANK_GREY, TRACK_COLOURS, UNTRACKED_COLOUR, index_images,
                                                 review_sheet, write_review_sheets)
from pedx_graph.detections.types import Detection
from pedx_graph.keypoints import keypoint_set_names, limb_edges, load_keypoint_set
from scene_fixtures import small_scene

#: Colour (BGR) of the synthetic images: far from the track colours and from the blank grey.
IMAGE_BGR = (40, 200, 40)


def standing(column: float, keypoint_set: str = "body25") -> np.ndarray:
    """(K, 2) raw pixels of a person drawn upright around ``column``: every keypoint present, spread over a
    200 x 400 px box from row 300."""
    k = len(load_keypoint_set(keypoint_set).keypoints)
    rng = np.random.default_rng(int(column))
    return np.c_[column + rng.uniform(-100, 100, k), rng.uniform(300, 700, k)]


def detection(camera: str, frame: int, column: float, image: str | None) -> Detection:
    uv = standing(column)
    return Detection(camera=camera, frame=frame, keypoint_set="body25", image_uv=uv, confidence=np.full(len(uv), 0.8),
                     score=0.8, source="test", image=image)


def test_every_shipped_keypoint_set_has_its_limbs_on_the_right_sides():
    for name in keypoint_set_names():
        names = load_keypoint_set(name).keypoints
        edges = limb_edges(name)
        assert len(edges) == 12, name                      # 5 limbs a side, shoulders and hips across
        for i, j, side in edges:
            marks = {names[i].lower()[0], names[j].lower()[0]}
            if side == "left":
                assert marks == {"l"}, (name, names[i], names[j])
            elif side == "right":
                assert marks == {"r"}, (name, names[i], names[j])
            else:
                assert marks == {"l", "r"}, (name, names[i], names[j])


def test_a_sheet_draws_both_tracks_on_their_images_and_grey_where_an_image_is_missing(tmp_path):
    folder = tmp_path / "raw" / "nested"
    folder.mkdir(parents=True)
    for frame in (3, 4):                             # frame 5's image is missing
        cv2.imwrite(str(folder / f"seq_camA_{frame:07d}.png"), np.full((900, 1200, 3), IMAGE_BGR, np.uint8))
    images = index_images(tmp_path / "raw")
    assert sorted(images) == ["seq_camA_0000003", "seq_camA_0000004"]
    tracks = {"det000001": {f: {"camA": detection("camA", f, 400 + 10 * f, f"seq_camA_{f:07d}")} for f in (3, 4, 5)},
              "det000002": {f: {"camA": detection("camA", f, 800 - 10 * f, f"seq_camA_{f:07d}")} for f in (3, 5)},
              "det000009": {4: {"camB": detection("camB", 4, 300, None)}}}      # not in the stretch: not drawn
    stretch = {"tracks": ["det000001", "det000002"], "first_frame": 3, "last_frame": 5, "close_frames": [4]}
    sheet, held = review_sheet(tracks, stretch, images, cell_height_px=200)
    assert held == {"frames": [3, 4, 5], "cameras": ["camA"], "cells": 3, "cells_with_image": 2,
                    "without_image": [["camA", 5]]}
    colours = {tuple(int(c) for c in px) for px in sheet.reshape(-1, 3)}
    assert IMAGE_BGR in colours and (BLANK_GREY,) * 3 in colours
    for colour in TRACK_COLOURS:                     # each track's keypoints, in its own colour
        assert colour in colours
    # the grey cell (frame 5) is the third column and holds both tracks' keypoints
    grey = np.all(sheet == BLANK_GREY, axis=2)
    columns = np.flatnonzero(grey.sum(axis=0) > 100)   # (anti-aliased text holds a few such pixels too)
    assert len(columns) and columns.min() > sheet.shape[1] * 0.6
    index = write_review_sheets([], [stretch], images, tmp_path / "out")      # no tracks: nothing to draw
    assert index[0]["sheet"] is None and not (tmp_path / "out").exists()


def test_a_one_track_stretch_draws_the_detections_no_track_holds_it_lists(tmp_path):
    """A stretch naming one track and a detection no track holds (``untracked``): the sheet draws the track in
    its colour and the listed detection in green; one not listed is not drawn; the file is named
    ``<n>_<track>_untracked_<first>-<last>.jpg``."""
    from pedx_graph.detections.association import DetectedTrack, DetectedTrackFrame

    own = {f: detection("camA", f, 400 + 10 * f, None) for f in (3, 4, 5)}
    loose = detection("camA", 4, 470, None)
    loose.source = "loose#4"
    unlisted = detection("camA", 5, 1500, None)
    unlisted.source = "unlisted#5"
    stretch = {"tracks": ["det000001"], "first_frame": 3, "last_frame": 5, "close_frames": [4],
               "untracked": [{"camera": "camA", "frame": 4, "source": "loose#4"}]}
    tracks = {"det000001": {f: {"camA": det} for f, det in own.items()}}
    lookup = {(d.camera, d.frame, d.source): d for d in (loose, unlisted)}
    sheet, held = review_sheet(tracks, stretch, {}, cell_height_px=200, untracked=lookup)
    colours = {tuple(int(c) for c in px) for px in sheet.reshape(-1, 3)}
    assert TRACK_COLOURS[0] in colours and UNTRACKED_COLOUR in colours and TRACK_COLOURS[1] not in colours
    assert held["frames"] == [3, 4, 5] and held["cameras"] == ["camA"]
    without = review_sheet(tracks, stretch, {}, cell_height_px=200)[0]        # nothing to look it up in
    assert UNTRACKED_COLOUR not in {tuple(int(c) for c in px) for px in without.reshape(-1, 3)}
    # one listed a frame before the stretch (close to the track's first frame) is drawn in a column of its own
    early = detection("camA", 2, 420, None)
    early.source = "early#2"
    before = dict(stretch, untracked=stretch["untracked"] + [{"camera": "camA", "frame": 2, "source": "early#2"}])
    _, held = review_sheet(tracks, before, {}, cell_height_px=200, untracked={**lookup, ("camA", 2, "early#2"): early})
    assert held["frames"] == [2, 3, 4, 5]
    track = DetectedTrack("det000001", [DetectedTrackFrame(f, {"camA": det}) for f, det in own.items()], ("camA-camB",))
    index = write_review_sheets([track], [stretch], {}, tmp_path / "out", untracked=[loose, unlisted])
    assert index[0]["sheet"] == "1_det000001_untracked_3-5.jpg" and index[0]["tracks"] == ["det000001"]
    assert (tmp_path / "out" / index[0]["sheet"]).is_file()


def test_import_draws_each_review_stretch_and_refuses_a_missing_images_folder(tmp_path, capsys):
    """``--review-images``: every stretch of the identity review gets a sheet, listed in import_summary.json;
    the simulated detector files name their images (PedX image names), all of them found.  A missing folder
    is a one-line error naming it."""
    from pedx_graph.sim.config import pedx_rig_config

    config = pedx_rig_config()
    config.detections.formats = ("openpose_body25",)
    config.scene.crosswalk_prob = 1.0                # people crossing: seed 0 has three stretches to check
    root = small_scene(tmp_path / "scene", pedestrians=6, frames=8, seed=0, config=config)
    files = root / "detections" / "openpose_body25"
    raw = tmp_path / "raw"
    for path in sorted(files.rglob("*_keypoints.json")):
        target = raw / path.parent.name / path.name.replace("_keypoints.json", ".jpg")
        target.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(target), np.full((64, 64, 3), IMAGE_BGR, np.uint8))
    out = tmp_path / "imported"
    assert main(["import", "openpose", str(files), "--keypoint-set", "body25", "--calib", str(root),
                 "--out", str(out), "--review-images", str(raw)]) == 0
    summary = json.loads((out / "import_summary.json").read_text())
    (record,) = summary["sequences"].values()
    stretches = record["identity_review"]["stretches"]
    sheets = record["review_sheets"]["sheets"]
    assert stretches and len(sheets) == len(stretches)
    # the files sort in the order to check them
    by_name = sorted(sheets, key=lambda entry: entry["sheet"])
    assert [entry["check"] for entry in by_name] == list(range(1, len(sheets) + 1))
    assert [sheets.index(entry) for entry in by_name] == record["identity_review"]["check_order"]
    named = {(d.camera, d.frame) for d in read_openpose(files)}
    assert sum(entry["cells_with_image"] for entry in sheets) > 0
    for entry, stretch in zip(sheets, stretches):
        assert entry["tracks"] == stretch["tracks"] and entry["sheet"]
        assert entry["cells_with_image"] + len(entry["without_image"]) == entry["cells"]
        # an image is missed only where no file of that camera and frame held a detection to name it
        assert not {tuple(cell) for cell in entry["without_image"]} & named
        assert cv2.imread(str(out / record["review_sheets"]["folder"] / entry["sheet"])) is not None
    # the import's fixes template: valid as it is (every operation commented out), the stretches in the order to
    # check them, each naming its sheet; uncommenting the first marks that stretch checked
    from pedx_graph.detections.fixes import read_fixes

    seq = next(iter(summary["sequences"]))
    first = stretches[record["identity_review"]["check_order"][0]]
    template = (out / "identity_fixes_template.yaml").read_text()
    (blank,) = read_fixes(out / "identity_fixes_template.yaml").values()
    assert blank.operations == () and blank.made_for == record["tracks_digest"]
    first_sheet = min(entry["sheet"] for entry in sheets)
    assert template.count("# - checked:") == len(stretches) and first_sheet in template.split("# - checked:")[0]
    lines = template.splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("    # - checked:"))
    lines[k:k + 2] = [line.replace("# ", "", 1) for line in lines[k:k + 2]]
    fixes = tmp_path / "fixes.yaml"
    fixes.write_text("\n".join(lines) + "\n")
    (op,) = read_fixes(fixes)[seq].operations
    assert (op.kind, list(op.tracks), op.first_frame, op.last_frame) == \
        ("checked", first["tracks"], first["first_frame"], first["last_frame"])
    # a stretch a reviewer marked checked (identity fixes file) gets no sheet; the others keep the order to check
    assert main(["import", "openpose", str(files), "--keypoint-set", "body25", "--calib", str(root),
                 "--out", str(tmp_path / "checked"), "--review-images", str(raw), "--identity-fixes", str(fixes)]) == 0
    again = json.loads((tmp_path / "checked" / "import_summary.json").read_text())["sequences"][seq]
    review = again["identity_review"]
    assert review["checked_stretches"] >= 1 and [s["first_frame"] for s in review["stretches"]] == \
        [s["first_frame"] for s in stretches]
    assert review["unchecked_flagged_track_frames"] < review["flagged_track_frames"]
    open_stretches = [s for s in review["stretches"] if not s.get("checked")]
    assert len(again["review_sheets"]["sheets"]) == len(open_stretches) == len(stretches) - review["checked_stretches"]
    by_name = sorted(again["review_sheets"]["sheets"], key=lambda entry: entry["sheet"])
    assert [entry["check"] for entry in by_name] == list(range(1, len(open_stretches) + 1))
    assert [(e["tracks"], e["first_frame"]) for e in by_name] == \
        [(review["stretches"][i]["tracks"], review["stretches"][i]["first_frame"]) for i in review["check_order"]]
    capsys.readouterr()
    assert main(["import", "openpose", str(files), "--calib", str(root), "--out", str(tmp_path / "again"),
                 "--review-images", str(tmp_path / "nowhere")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(tmp_path / "nowhere") in err[0]


@pytest.mark.parametrize("frames, expected", [(list(range(4)), [0, 1, 2, 3]), (list(range(30)), None)])
def test_long_stretches_are_sampled_evenly_with_both_ends(frames, expected):
    from pedx_graph.detections.review_sheets import _chosen_frames

    chosen = _chosen_frames(frames, 10)
    if expected is not None:
        assert chosen == expected
    else:
        assert len(chosen) == 10 and chosen[0] == 0 and chosen[-1] == 29 and chosen == sorted(set(chosen))
