"""The seconds between frames for the import's association: the dataset's timestamps when it has them, else the
config's, checked against how fast the tracked people walk (a frame rate assumed rather than read is a convention
the simulator and the code would share)."""
import json
import shutil
from types import SimpleNamespace

import numpy as np

from pedx_graph.cli import main
from pedx_graph.detections.frame_interval import WalkingCheckConfig, sequence_frame_interval, walking_check
from scene_fixtures import small_scene

UP = np.array([0.0, 0.0, -1.0])            # a z-down frame, as the real rig's
GROUND = SimpleNamespace(world_up=UP)


def test_the_interval_comes_from_the_timestamps_the_fit_reads(tmp_path, caplog):
    folder = tmp_path / "timestamps"
    folder.mkdir()
    # two columns, epoch milliseconds, frame 3 missing: 0.2 s per frame step all the same
    (folder / "timestamps-images-seqA.txt").write_text(
        "\n".join(f"{f} {1512680000000 + 200 * f}" for f in range(10) if f != 3))
    assert sequence_frame_interval(tmp_path, "seqA", range(2, 8), 0.1) == (0.2,
                                                                            "timestamps/timestamps-images-seqA.txt")
    # the point clouds' file, which the fit reads by default, comes first
    (folder / "timestamps-pointclouds-seqA.txt").write_text("\n".join(f"{0.05 * f:.2f}" for f in range(10)))
    assert sequence_frame_interval(tmp_path, "seqA", range(10), 0.1) == (0.05,
                                                                          "timestamps/timestamps-pointclouds-seqA.txt")
    assert sequence_frame_interval(tmp_path, "seqB", range(10), 0.1) == (0.1, "config")
    assert sequence_frame_interval(None, "seqA", range(10), 0.1) == (0.1, "config")
    (folder / "timestamps-pointclouds-seqA.txt").write_text("0 1 2\n")
    assert sequence_frame_interval(tmp_path, "seqA", range(10), 0.1) == (0.1, "config")
    assert "timestamps-pointclouds-seqA.txt" in caplog.text


def walker(speed_m_per_frame: float, frames: int, heading: float, rng, noise_m: float = 0.1):
    direction = np.array([np.cos(heading), np.sin(heading), 0.0])
    start = np.array([rng.uniform(-10, 10), rng.uniform(5, 30), 1.5])
    return SimpleNamespace(frames=[SimpleNamespace(frame=f, world_p=start + f * speed_m_per_frame * direction
                                                   + rng.normal(scale=noise_m, size=3))
                                   for f in range(frames)])


def test_walking_tracks_tell_a_wrong_frame_interval():
    rng = np.random.default_rng(0)
    # people at 1.2-1.5 m/s filmed every 0.2 s; two standing, one seen on too few frames
    tracks = [walker(rng.uniform(1.2, 1.5) * 0.2, 20, rng.uniform(0, 6.3), rng) for _ in range(6)]
    tracks += [walker(0.0, 20, 0.0, rng) for _ in range(2)] + [walker(0.3, 3, 0.0, rng)]
    wrong = walking_check(tracks, GROUND, 0.1)
    assert wrong["walking_tracks"] == 6 and not wrong["agrees"]
    assert 0.18 < wrong["implied_interval_s"] < 0.23 and wrong["ratio"] > 1.4
    right = walking_check(tracks, GROUND, 0.2)
    assert right["agrees"] and 0.9 < right["ratio"] < 1.15
    # too few walkers: no verdict
    few = walking_check(tracks[:3], GROUND, 0.1, WalkingCheckConfig(min_tracks=4))
    assert few["implied_interval_s"] is None and few["agrees"]


def test_import_uses_the_timestamps_and_warns_without_them(tmp_path, capsys, caplog):
    """A scene filmed at 5 Hz: with its timestamps the association steps 0.2 s per frame and the walks agree;
    without them it falls back to the config's 0.1 s and the walks give it away."""
    from pedx_graph.sim.config import SimConfig

    config = SimConfig()
    config.scene.fps = 5.0
    config.detections.formats = ("openpose_body25",)
    root = small_scene(tmp_path / "scene", pedestrians=8, frames=20, seed=0, config=config)
    args = ["import", "openpose", str(root / "detections" / "openpose_body25"), "--keypoint-set", "body25",
            "--calib", str(root)]
    assert main([*args, "--out", str(tmp_path / "timed")]) == 0
    (timed,) = json.loads((tmp_path / "timed" / "import_summary.json").read_text())["sequences"].values()
    interval = timed["frame_interval"]
    assert interval["frame_interval_s"] == 0.2 and interval["from"].startswith("timestamps/")
    assert interval["agrees"] and interval["walking_tracks"] >= 4
    shutil.rmtree(root / "timestamps")
    capsys.readouterr()
    assert main([*args, "--out", str(tmp_path / "untimed")]) == 0
    (untimed,) = json.loads((tmp_path / "untimed" / "import_summary.json").read_text())["sequences"].values()
    interval = untimed["frame_interval"]
    assert interval["frame_interval_s"] == 0.1 and interval["from"] == "config"
    assert not interval["agrees"] and interval["ratio"] > 1.4
    captured = capsys.readouterr()
    assert "check the frame rate" in captured.out
    assert "a frame every" in caplog.text and "association.tracker.frame_interval_s" in caplog.text


def test_a_five_hertz_scene_is_tracked_as_a_ten_hertz_one(tmp_path):
    """At 5 Hz people move twice as far between frames, in the image too; told the interval, the association
    widens its image gates in proportion (``tracker.image_sigma_px``) and tracks every labelled person, as at
    10 Hz.  (Before, a walker's first two frames could lie beyond the gate of a track with no velocity yet: this
    scene kept 9 of its 10 labelled people, the association benchmark's seed 0 crossing scene 4 of its 8.)"""
    from pedx_graph.data.calib import read_calibrations
    from pedx_graph.detections.association import AssociationConfig, associate
    from pedx_graph.detections.evaluate import read_detection_truth, score_tracks
    from pedx_graph.detections.openpose import read_openpose
    from pedx_graph.sim.config import SimConfig

    config = SimConfig()
    config.scene.fps = 5.0
    config.scene.crosswalk_prob, config.scene.group_prob = 1.0, 0.0
    config.detections.formats = ("openpose_body25",)
    root = small_scene(tmp_path / "scene", pedestrians=10, frames=20, seed=0, config=config)
    seq = config.scene.sequence
    labelled: dict = {}
    for path in sorted((root / "truth" / seq).glob("*.json")):
        record = json.loads(path.read_text())
        for tid, person in record["people"].items():
            if person.get("labelled"):
                labelled.setdefault(tid, {})[int(record["frame"])] = float(person["distance_m"])
    detections = read_openpose(root / "detections" / "openpose_body25", "body25")
    records = read_detection_truth(root, seq, "openpose_body25")
    calibrations = read_calibrations(root / "calib")
    score = score_tracks(associate(detections, calibrations, AssociationConfig().with_frame_interval(0.2)),
                         records, labelled)
    assert score["labelled_people"] >= 5
    assert score["recovered"] == score["labelled_people"] and score["false_tracks"] == 0


def test_the_two_trackers_step_the_same_frames(tmp_path):
    import pytest

    from pedx_graph.config import load_config
    from pedx_graph.config_ranges import ConfigError
    from pedx_graph.detections.importer import ImportConfig

    from pedx_graph.detections.association import AssociationConfig
    from pedx_graph.detections.tracker import TrackerConfig

    config = AssociationConfig().with_frame_interval(0.25)
    assert config.tracker.frame_interval_s == config.tracklet.frame_interval_s == config.frame_interval_s == 0.25
    assert AssociationConfig().tracklet.min_track_frames == config.tracklet.min_track_frames == 1
    with pytest.raises(ValueError, match="tracklet.frame_interval_s"):
        AssociationConfig(tracker=TrackerConfig(frame_interval_s=0.2))
    # from a file: one line naming the file and the section
    path = tmp_path / "import.yaml"
    path.write_text("association:\n  tracker:\n    frame_interval_s: 0.2\n")
    with pytest.raises(ConfigError, match=r"import.yaml: 'association': .*set both"):
        load_config(ImportConfig, path)
    path.write_text("association:\n  tracker:\n    frame_interval_s: 0.2\n  tracklet:\n    frame_interval_s: 0.2\n")
    assert load_config(ImportConfig, path).association.frame_interval_s == 0.2


def test_how_long_a_track_coasts_is_given_in_time_at_higher_rates():
    """``max_misses`` (and the stitch gap) are frame counts given for 0.1 s between frames: at 20 Hz a track
    coasts as long in time, twice the frames; at 5 Hz it keeps its frames (never fewer than given)."""
    from pedx_graph.detections.tracker import Observation, Tracker, TrackerConfig, frames_for

    assert frames_for(TrackerConfig(frame_interval_s=0.05), 5) == 10
    assert frames_for(TrackerConfig(frame_interval_s=0.1), 5) == 5
    assert frames_for(TrackerConfig(frame_interval_s=0.2), 5) == 5

    def person(frame: int) -> Observation:
        uv = np.c_[np.full(10, 500.0 + 2.0 * frame), np.linspace(300.0, 600.0, 10)]
        return Observation(frame=frame, uv={"left": uv}, score=0.9)

    for interval, kept in ((0.05, True), (0.1, False)):
        tracker = Tracker(TrackerConfig(frame_interval_s=interval))
        first = [tracker.step(f, [person(f)])[0] for f in range(6)]
        assert len(set(first)) == 1
        # unseen for 8 frames: 0.4 s at 20 Hz (within 10 frames' coasting), 0.8 s at 10 Hz (beyond 5)
        again = tracker.step(14, [person(14)])[0]
        assert (again == first[0]) is kept, interval
