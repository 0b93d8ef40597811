"""Whole-dataset round trip (write_tracks -> read_dataset) and robustness of the reader."""
from __future__ import annotations

import json
import logging
import shutil

import numpy as np
import pytest

from pedx_graph.data import (
    DataFormatError,
    ReaderConfig,
    SmplLabel,
    Track,
    TrackFrame,
    View2D,
    iter_tracks,
    read_dataset,
    read_smpl_labels,
    read_timestamps,
    write_results,
    write_segment,
    write_tracks,
)
from pedx_graph.data.labels2d import label2d_path
from pedx_graph.data.ply import segment_path
from pedx_graph.data.reader import timestamps_path

from pedx_graph.data.types import StereoCalibration

SEQ = "20171207T2024"
TID_A = "a" * 32
TID_B = "b" * 32


def make_calib(name: str, yaw: float = 0.0, focal: float = 2000.0, baseline: float = 0.5) -> StereoCalibration:
    """A roof-rig pair: camera z forward = world x rotated by ``yaw`` about z, 1.8 m up."""
    c, s = np.cos(yaw), np.sin(yaw)
    world_T_cam = np.eye(4)
    world_T_cam[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    world_T_cam[:3, 3] = [0.3, -0.1, 1.8]
    left = np.array([[focal, 0, 1800, 0], [0, focal, 1300, 0], [0, 0, 1, 0]], dtype=float)
    right = left.copy()
    right[0, 3] = -focal * baseline
    return StereoCalibration(name=name, left_P_rect=left, right_P_rect=right, rect_R_cam=np.eye(3),
                             world_T_cam=world_T_cam, image_size=(3678, 2668))


def view(rng, n_labelled: int = 14, polygon: bool = True) -> View2D:
    inside = ([100, 100], [3000, 2500])            # pixels inside the 3678x2668 image (the reader drops others)
    keypoints = rng.uniform(*inside, size=(18, 2))
    keypoints[n_labelled:] = np.nan
    visible = np.arange(18) < n_labelled - 1
    return View2D(keypoints=keypoints, visible=visible,
                  polygon=rng.uniform(*inside, size=(6, 2)) if polygon else None)


def build_tracks(seed: int = 0) -> list[Track]:
    """Two tracks, three frames each, one per stereo pair; one frame without a right view."""
    rng = np.random.default_rng(seed)
    calibs = {"ylw79D0-red707B": make_calib("ylw79D0-red707B"),
              "blu79CF-grn43E3": make_calib("blu79CF-grn43E3", yaw=np.pi / 2)}
    tracks = []
    for tid, pair, frames in ((TID_A, "ylw79D0-red707B", (0, 2, 4)), (TID_B, "blu79CF-grn43E3", (1, 2, 5))):
        track_frames = []
        for k, frame in enumerate(frames):
            points = rng.normal(size=(20 + k, 3)) * 0.3 + [15.0, 2.0, 0.0]
            track_frames.append(TrackFrame(
                frame=frame, timestamp=1512690000.0 + 0.1 * frame, pair=pair,
                left=view(rng), right=None if (tid == TID_B and k == 1) else view(rng, polygon=k != 0),
                world_lidar_points=points))
        tracks.append(Track(sequence=SEQ, tracking_id=tid, frames=track_frames,
                            calibrations={pair: calibs[pair]}))
    return tracks


def assert_views_equal(a: View2D | None, b: View2D | None) -> None:
    assert (a is None) == (b is None)
    if a is None:
        return
    np.testing.assert_array_equal(a.keypoints, b.keypoints)
    np.testing.assert_array_equal(a.visible, b.visible)
    assert (a.polygon is None) == (b.polygon is None)
    if a.polygon is not None:
        np.testing.assert_array_equal(a.polygon, b.polygon)


def assert_tracks_equal(expected: list[Track], got: list[Track]) -> None:
    assert [(t.sequence, t.tracking_id) for t in got] == [(t.sequence, t.tracking_id) for t in expected]
    for te, tg in zip(expected, got):
        assert list(tg.calibrations) == list(te.calibrations)
        for name, calib in te.calibrations.items():
            np.testing.assert_allclose(tg.calibrations[name].world_T_cam, calib.world_T_cam, atol=1e-12)
            np.testing.assert_allclose(tg.calibrations[name].right_P_rect, calib.right_P_rect, atol=1e-12)
        assert [f.frame for f in tg.frames] == [f.frame for f in te.frames]
        for fe, fg in zip(te.frames, tg.frames):
            assert fg.pair == fe.pair
            assert fg.timestamp == pytest.approx(fe.timestamp, abs=1e-6)
            assert_views_equal(fe.left, fg.left)
            assert_views_equal(fe.right, fg.right)
            assert sorted(fg.other_views) == sorted(fe.other_views)
            for name, (left, right) in fe.other_views.items():
                assert_views_equal(left, fg.other_views[name][0])
                assert_views_equal(right, fg.other_views[name][1])
            np.testing.assert_array_equal(fg.world_lidar_points, fe.world_lidar_points)


@pytest.mark.parametrize("flat", [False, True])
def test_round_trip_whole_dataset(tmp_path, flat):
    tracks = build_tracks()
    write_tracks(tmp_path / "data", tracks, flat=flat)
    assert_tracks_equal(tracks, read_dataset(tmp_path))  # the parent of data/ is accepted
    assert_tracks_equal(tracks, read_dataset(tmp_path / "data"))


def test_mixed_folder_layouts_in_one_sequence(tmp_path):
    tracks = build_tracks()
    write_tracks(tmp_path, tracks[:1], flat=False)
    write_tracks(tmp_path, tracks[1:], flat=True)
    assert (tmp_path / "labels/2d" / SEQ / "ylw79D0").is_dir()
    assert list((tmp_path / "labels/2d" / SEQ).glob(f"{SEQ}_blu79CF_*.json"))
    assert_tracks_equal(tracks, read_dataset(tmp_path))


def test_lazy_iterator_and_sequence_filter(tmp_path, caplog):
    tracks = build_tracks()
    write_tracks(tmp_path, tracks)
    iterator = iter_tracks(tmp_path, sequences=[SEQ])
    assert next(iterator).tracking_id == TID_A
    assert next(iterator).tracking_id == TID_B
    with pytest.raises(DataFormatError, match="no track could be read"):
        with caplog.at_level(logging.WARNING):
            read_dataset(tmp_path, sequences=["20171130T2000"])
    assert "20171130T2000 not found" in caplog.text


def test_timestamps_absent_use_fps(tmp_path, caplog):
    write_tracks(tmp_path, build_tracks(), timestamps=False)
    with caplog.at_level(logging.INFO):
        got = read_dataset(tmp_path, config=ReaderConfig(fps=20.0))
    assert [f.timestamp for f in got[0].frames] == [0.0, 0.1, 0.2]
    assert "fps = 20" in caplog.text


def test_timestamp_file_formats(tmp_path):
    path = tmp_path / "t.txt"
    path.write_text("# comment\n1512690000.5\n1512690000.6\n\n1512690000.7\n")
    assert read_timestamps(path) == pytest.approx({0: 1512690000.5, 1: 1512690000.6, 2: 1512690000.7})
    path.write_text("0000010, 1512690000000000\n0000012, 1512690000200000\n")  # microseconds
    assert read_timestamps(path) == pytest.approx({10: 1512690000.0, 12: 1512690000.2})
    path.write_text(f"{SEQ}_0000003.ply 1512690000300000000\n")  # nanoseconds, file-name frames
    assert read_timestamps(path) == pytest.approx({3: 1512690000.3})
    for bad in ("1 2 3\n", "1 2\n3\n", "0 abc\n", "x 1.0\n", ""):
        path.write_text(bad)
        with pytest.raises(DataFormatError, match="t.txt"):
            read_timestamps(path)


def test_bad_timestamps_fall_back_and_missing_frames_interpolate(tmp_path, caplog):
    tracks = build_tracks()
    write_tracks(tmp_path, tracks)
    path = timestamps_path(tmp_path, SEQ)
    path.write_text("0 100.0\n4 100.4\n")  # frames 1, 2 interpolated, 5 extrapolated at 1 / fps
    with caplog.at_level(logging.WARNING):
        got = read_dataset(tmp_path)
    assert [f.timestamp for f in got[1].frames] == pytest.approx([100.1, 100.2, 100.5])
    assert "missing from the timestamps" in caplog.text
    path.write_text("0 nope\n")
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        got = read_dataset(tmp_path)
    assert [f.timestamp for f in got[0].frames] == pytest.approx([0.0, 0.2, 0.4])
    assert path.name in caplog.text and "line 1" in caplog.text


def test_instance_in_both_pairs_keeps_both_pairs(tmp_path):
    """An instance labelled by both pairs at a frame: the pair with more labelled keypoints is the primary
    ``pair``/``left``/``right``, the other pair's labels are kept in ``other_views``, and both pairs'
    calibrations are in the track."""
    tracks = build_tracks()
    write_tracks(tmp_path, tracks)
    rng = np.random.default_rng(5)
    # Track A at frame 2 also labelled by the other pair: with fewer keypoints, then with more.
    other = Track(SEQ, TID_A, [TrackFrame(2, 0.0, "blu79CF-grn43E3", view(rng, 3), view(rng, 3))],
                  {"blu79CF-grn43E3": tracks[1].calibrations["blu79CF-grn43E3"]})
    write_tracks(tmp_path, [other], timestamps=False)
    got = read_dataset(tmp_path)
    frame = got[0].frames[1]
    assert frame.pair == "ylw79D0-red707B"
    assert_views_equal(frame.left, tracks[0].frames[1].left)
    assert list(frame.other_views) == ["blu79CF-grn43E3"]
    assert_views_equal(frame.other_views["blu79CF-grn43E3"][0], other.frames[0].left)
    assert_views_equal(frame.other_views["blu79CF-grn43E3"][1], other.frames[0].right)
    assert [(p, s) for p, s, _ in frame.labelled_views()] == [
        ("ylw79D0-red707B", "left"), ("ylw79D0-red707B", "right"), ("blu79CF-grn43E3", "left"),
        ("blu79CF-grn43E3", "right")]
    assert [(p, s) for p, s, _ in frame.labelled_views(all_pairs=False)] == [
        ("ylw79D0-red707B", "left"), ("ylw79D0-red707B", "right")]
    assert sorted(got[0].calibrations) == ["blu79CF-grn43E3", "ylw79D0-red707B"]
    assert got[0].frames[0].other_views == {}                  # frames seen by one pair: nothing else
    other.frames[0].left = view(rng, 18)
    other.frames[0].right = None                               # the other pair's left camera only
    write_tracks(tmp_path, [other], timestamps=False)
    label2d_path(tmp_path, SEQ, "grn43E3", 2, TID_A).unlink()          # the earlier right label
    frame = read_dataset(tmp_path)[0].frames[1]
    assert frame.pair == "ylw79D0-red707B"                              # 14 + 14 labelled vs 18
    assert frame.other_views["blu79CF-grn43E3"][1] is None
    assert_views_equal(frame.other_views["blu79CF-grn43E3"][0], other.frames[0].left)
    other.frames[0].right = view(rng, 18)
    write_tracks(tmp_path, [other], timestamps=False)
    got = read_dataset(tmp_path)
    frame = got[0].frames[1]
    assert frame.pair == "blu79CF-grn43E3"
    assert_views_equal(frame.left, other.frames[0].left)
    assert_views_equal(frame.other_views["ylw79D0-red707B"][0], tracks[0].frames[1].left)
    assert_views_equal(frame.other_views["ylw79D0-red707B"][1], tracks[0].frames[1].right)
    assert len(frame.labelled_views()) == 4
    # the round trip keeps every pair's labels
    write_tracks(tmp_path / "again", got)
    again = read_dataset(tmp_path / "again")
    assert_tracks_equal(got, again)


def corrupt(path, data) -> None:
    path.write_text(data if isinstance(data, str) else json.dumps(data))


@pytest.mark.parametrize("content, field", [
    ("{bad json", "<json>"),
    ({"category": "pedestrian", "keypoint": {"nose": {"y": 1.0, "visible": True}}}, "keypoint.nose.x"),
    ({"category": "pedestrian", "keypoint": {"neck": {"x": "12,5", "y": 1.0}}}, "keypoint.neck.x"),
    ({"category": "pedestrian", "keypoint": None, "polygon": [[1, 2], [3, 4]]}, "polygon"),
])
def test_bad_label_skips_only_that_instance(tmp_path, caplog, content, field):
    tracks = build_tracks()
    write_tracks(tmp_path, tracks)
    bad = label2d_path(tmp_path, SEQ, "ylw79D0", 2, TID_A)
    corrupt(bad, content)
    with caplog.at_level(logging.WARNING):
        got = read_dataset(tmp_path)
    assert bad.name in caplog.text and f"'{field}'" in caplog.text
    frame = got[0].frames[1]
    assert frame.left is None  # the corrupted view is gone ...
    assert_views_equal(frame.right, tracks[0].frames[1].right)  # ... its partner and the rest are intact
    tracks[0].frames[1].left = None
    assert_tracks_equal(tracks, got)


def test_null_fields_and_other_categories(tmp_path):
    tracks = build_tracks()
    write_tracks(tmp_path, tracks)
    corrupt(label2d_path(tmp_path, SEQ, "ylw79D0", 0, TID_A),
            {"tracking_id": TID_A, "category": "pedestrian", "keypoint": None, "polygon": None})
    for camera in ("blu79CF", "grn43E3"):
        for frame in (1, 2, 5):
            path = label2d_path(tmp_path, SEQ, camera, frame, TID_B)
            if path.exists():
                data = json.loads(path.read_text())
                corrupt(path, dict(data, category="vehicle"))
    got = read_dataset(tmp_path)
    assert [t.tracking_id for t in got] == [TID_A]
    assert got[0].frames[0].left.labelled.sum() == 0 and got[0].frames[0].left.polygon is None


def test_segments_inf_masked_and_bad_segment_skipped(tmp_path, caplog):
    tracks = build_tracks()
    write_tracks(tmp_path, tracks)
    points = np.vstack([tracks[0].frames[0].world_lidar_points, [[np.inf] * 3, [np.nan, 1.0, 2.0]]])
    write_segment(tmp_path, SEQ, 0, TID_A, points)
    segment_path(tmp_path, SEQ, 2, TID_A).write_bytes(b"ply\nformat ascii 1.0\nend_header\n")
    segment_path(tmp_path, SEQ, 5, TID_B).unlink()
    with caplog.at_level(logging.WARNING):
        got = read_dataset(tmp_path)
    np.testing.assert_array_equal(got[0].frames[0].world_lidar_points, tracks[0].frames[0].world_lidar_points)
    assert got[0].frames[1].world_lidar_points.shape == (0, 3)
    assert got[1].frames[2].world_lidar_points.shape == (0, 3)
    assert f"{SEQ}_0000002_{TID_A}.ply" in caplog.text and "'vertex'" in caplog.text
    assert len(got[0].frames) == 3


def test_uncalibrated_camera_warned(tmp_path, caplog):
    write_tracks(tmp_path, build_tracks())
    shutil.copytree(tmp_path / "labels/2d" / SEQ / "ylw79D0", tmp_path / "labels/2d" / SEQ / "other00")
    for path in (tmp_path / "labels/2d" / SEQ / "other00").iterdir():
        path.rename(path.with_name(path.name.replace("ylw79D0", "other00")))
    with caplog.at_level(logging.WARNING):
        got = read_dataset(tmp_path)
    assert len(got) == 2 and "camera other00 is in no calibrated stereo pair" in caplog.text


def test_nothing_readable_raises(tmp_path):
    with pytest.raises(DataFormatError, match="neither 'labels/'"):
        read_dataset(tmp_path)
    write_tracks(tmp_path, build_tracks())
    shutil.rmtree(tmp_path / "calib")
    with pytest.raises(DataFormatError, match="calib_cam_to_cam"):
        read_dataset(tmp_path)
    write_tracks(tmp_path, build_tracks())
    for path in (tmp_path / "labels/2d").rglob("*.json"):
        path.write_text("{")
    with pytest.raises(DataFormatError, match="no track could be read"):
        read_dataset(tmp_path)


def test_smpl_results_round_trip_and_bad_file(tmp_path, caplog):
    rng = np.random.default_rng(3)
    labels = [SmplLabel(SEQ, frame, tid, rng.normal(size=10), rng.normal(size=72), rng.normal(size=3),
                        extra={"keypoints_3d": rng.normal(size=(18, 3))})
              for tid in (TID_A, TID_B) for frame in (4, 0, 2)]
    (tmp_path / "data" / "labels").mkdir(parents=True)
    paths = write_results(tmp_path, labels)  # parent given: written under data/
    assert all("data/labels/3d/smpl" in p.as_posix() for p in paths)
    truth = read_smpl_labels(tmp_path)
    assert list(truth) == [(SEQ, TID_A), (SEQ, TID_B)]
    assert [lab.frame for lab in truth[(SEQ, TID_A)]] == [0, 2, 4]
    np.testing.assert_array_equal(truth[(SEQ, TID_B)][2].pose, labels[3].pose)
    np.testing.assert_array_equal(truth[(SEQ, TID_B)][2].extra["keypoints_3d"], labels[3].extra["keypoints_3d"])
    data = json.loads(paths[0].read_text())
    paths[0].write_text(json.dumps(dict(data, betas=[0.0] * 9)))
    with caplog.at_level(logging.WARNING):
        truth = read_smpl_labels(tmp_path)
    assert [lab.frame for lab in truth[(SEQ, TID_A)]] == [0, 2]
    assert paths[0].name in caplog.text and "'betas'" in caplog.text
    with pytest.raises(DataFormatError, match="no SMPL label"):
        read_smpl_labels(tmp_path, sequences=["20171130T2000"])
