"""Association of id-less detections: stereo on rectified rows, tracks over frames (crossing pedestrians keep
their ids), false detections and flickering bystanders never become tracks, tracks of two pairs merge."""
from __future__ import annotations

import dataclasses
from collections import defaultdict

import numpy as np
import pytest

from pedx_graph.data.ground import make_ground_frame
from pedx_graph.detections.association import AssociationConfig, associate, match_stereo, stereo_cost
from pedx_graph.detections.tracker import Observation, Tracker, TrackerConfig
from pedx_graph.detections.types import Detection
from pedx_graph.sim.cameras import make_calibration
from pedx_graph.sim.config import SimConfig

#: A standing person's 17 COCO points in its own frame (x right, y forward, z up), metres.
STICK = np.array([
    [0.0, 0.08, 1.62], [-0.03, 0.07, 1.65], [0.03, 0.07, 1.65], [-0.07, 0.0, 1.63], [0.07, 0.0, 1.63],
    [-0.19, 0.0, 1.42], [0.19, 0.0, 1.42], [-0.24, 0.0, 1.12], [0.24, 0.0, 1.12], [-0.26, 0.02, 0.84],
    [0.26, 0.02, 0.84], [-0.11, 0.0, 0.93], [0.11, 0.0, 0.93], [-0.11, 0.03, 0.5], [0.11, 0.03, 0.5],
    [-0.11, -0.02, 0.08], [0.11, -0.02, 0.08]])
#: Ground of the default rig's sim frame (z up, LiDAR 1.95 m above the ground).
GROUND_Z = -1.95


def _rig():
    cfg = SimConfig()
    return {pair.name: make_calibration(pair) for pair in cfg.cameras.pairs()}


def _ground(calibs):
    return make_ground_frame((0.0, 0.0, 1.0), (1.0, 0.0, 0.0), np.zeros(3), GROUND_Z, source="config")


def _person_points(xy, heading: float, phase: float) -> np.ndarray:
    """(17, 3) world points of a walker at ``xy`` (sim frame) facing ``heading``, limbs swung by ``phase``."""
    local = STICK.copy()
    swing = 0.25 * np.sin(phase)
    local[[9, 16], 1] += swing            # right wrist / ankle forward, left back
    local[[10, 15], 1] -= swing
    c, s = np.cos(heading - np.pi / 2), np.sin(heading - np.pi / 2)
    world = local @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return world + [xy[0], xy[1], GROUND_Z]


def _detections(calib, world_p, frame, rng, noise_px=2.0, score=0.8, drop=None, side_filter=None):
    """Detections of one person in the pair's two images (rectified = raw: no raw model)."""
    out = []
    left_uv, right_uv = calib.project(world_p)
    for camera, uv, side in zip(calib.name.split("-"), (left_uv, right_uv), ("left", "right")):
        if side_filter is not None and side != side_filter:
            continue
        uv = uv + noise_px * rng.normal(size=uv.shape)
        conf = np.full(len(uv), score)
        if drop is not None:
            uv[drop] = np.nan
            conf[drop] = 0.0
        out.append(Detection(camera=camera, frame=frame, keypoint_set="coco17", image_uv=uv, confidence=conf,
                             score=score, source=f"test#{camera}/{frame}/{len(out)}"))
    return out


def _who(track, owners):
    return {owners[d.source] for fr in track.frames for d in fr.detections.values()}


def test_crossing_pedestrians_keep_their_ids():
    """Two walkers cross in front of the forward pair at 9.5 and 11 m (their images overlap, the far one is
    half hidden then): two tracks, each holding one person's detections only."""
    calibs = _rig()
    calib = calibs["ylw79D0-red707B"]
    rng = np.random.default_rng(0)
    dets, owners = [], {}
    n = 24
    for k in range(n):
        t = (k - n / 2) * 0.1
        a = _person_points((9.5, 1.3 * t), np.pi / 2, 5 * t)          # walks to +y (leftwards in the image)
        b = _person_points((11.0, -1.3 * t), -np.pi / 2, 5 * t + 1)    # walks to -y
        hidden = np.arange(0, 17, 2) if abs(t) < 0.25 else None        # the far one is half occluded
        for name, points, drop in (("a", a, None), ("b", b, hidden)):
            for det in _detections(calib, points, k, rng, drop=drop):
                owners[det.source + name] = name
                det.source += name
                dets.append(det)
    tracks = associate(dets, calibs, ground=_ground(calibs))
    assert len(tracks) == 2
    assert sorted(_who(tr, owners) for tr in tracks) == [{"a"}, {"b"}]
    assert all(len(tr) == n for tr in tracks)


def test_a_person_the_repairs_leave_with_few_frames_is_not_a_track(monkeypatch):
    """The two crossing walkers, with the merge's last repair (:func:`move_to_neighbours`) made to leave one of
    them ``tracker.min_track_frames - 1`` frames (as a repair that moves a stretch to a neighbour can leave
    a remnant): that remnant is not output; with exactly ``min_track_frames`` frames left it is, and each track
    output holds one walker's detections."""
    from pedx_graph.detections import association

    calibs = _rig()
    calib = calibs["ylw79D0-red707B"]
    rng = np.random.default_rng(0)
    dets, owners = [], {}
    for k in range(24):
        t = (k - 12) * 0.1
        for name, points in (("a", _person_points((9.5, 1.3 * t), np.pi / 2, 5 * t)),
                             ("b", _person_points((11.0, -1.3 * t), -np.pi / 2, 5 * t + 1))):
            for det in _detections(calib, points, k, rng):
                det.source += name
                owners[det.source] = name
                dets.append(det)
    config = AssociationConfig()
    keep = config.tracker.min_track_frames
    original = association.move_to_neighbours

    def leaving(count):
        def leave_few(people, *args):
            moved = original(people, *args)
            frames, sources = people[0]
            for frame in sorted(frames)[count:]:
                del frames[frame]
                sources.pop(frame, None)
            return moved
        return leave_few

    for leave, expected in ((keep - 1, 1), (keep, 2)):
        monkeypatch.setattr(association, "move_to_neighbours", leaving(leave))
        tracks = associate(dets, calibs, config, ground=_ground(calibs))
        assert len(tracks) == expected
        assert sorted(len(track) for track in tracks) == sorted([24, keep][:expected])
        assert all(len(_who(track, owners)) == 1 for track in tracks)


def test_false_detections_and_bystanders_never_become_tracks():
    """Random clutter in every image and a flickering far bystander (one frame in three, low score) give no
    track; a steady person beyond ``max_distance_m`` is dropped; the walker is the one track."""
    calibs = _rig()
    calib = calibs["ylw79D0-red707B"]
    rng = np.random.default_rng(1)
    dets, owners = [], {}
    width, height = calib.image_size
    for k in range(20):
        t = k * 0.1
        walker = _person_points((14.0, -2.0 + 1.3 * t), np.pi / 2, 5 * t)
        far = _person_points((70.0, 3.0), np.pi, 0.0)
        flicker = _person_points((30.0, -4.0 + 0.4 * t), np.pi / 2, 0.0)
        groups = [("walker", _detections(calib, walker, k, rng)), ("far", _detections(calib, far, k, rng))]
        if k % 3 == 0:
            groups.append(("flicker", _detections(calib, flicker, k, rng, score=0.25)))
        for camera in calib.name.split("-"):
            for c in range(3):
                uv = np.column_stack([rng.uniform(0, width, 17), rng.uniform(0, height, 17)])
                conf = rng.uniform(0.05, 0.5, 17)
                groups.append(("clutter", [Detection(camera=camera, frame=k, keypoint_set="coco17", image_uv=uv,
                                                     confidence=conf, score=float(conf.mean()),
                                                     source=f"clutter#{camera}/{k}/{c}")]))
        for name, group in groups:
            for det in group:
                det.source += name
                owners[det.source] = name
                dets.append(det)
    config = AssociationConfig(max_distance_m=50.0)
    tracks = associate(dets, calibs, config, ground=_ground(calibs))
    assert [_who(tr, owners) for tr in tracks] == [{"walker"}]
    # without the distance limit the far person is a (correct) track of its own, never mixed with clutter
    tracks = associate(dets, calibs, AssociationConfig(max_distance_m=100.0), ground=_ground(calibs))
    assert sorted(map(sorted, (_who(tr, owners) for tr in tracks))) == [["far"], ["walker"]]


def test_stereo_matches_on_rectified_rows():
    """Two people side by side at one depth: each left detection pairs with its own right detection; a right
    detection moved 40 px off the rows, or to a negative disparity, is never matched."""
    calibs = _rig()
    calib = calibs["ylw79D0-red707B"]
    rng = np.random.default_rng(2)
    config = AssociationConfig()
    a = _detections(calib, _person_points((15.0, 0.4), np.pi / 2, 0.0), 0, rng)
    b = _detections(calib, _person_points((15.0, -0.4), np.pi / 2, 1.0), 0, rng)
    left = [(d, d.image_uv) for d in (a[0], b[0])]
    right = [(d, d.image_uv) for d in (b[1], a[1])]
    assert sorted(match_stereo(left, right, calib, config)) == [(0, 1), (1, 0)]
    assert stereo_cost(a[0].image_uv, a[1].image_uv, calib, config) < 3.0
    off_rows = a[1].image_uv + [0.0, 40.0]
    assert stereo_cost(a[0].image_uv, off_rows, calib, config) >= 1e9
    assert match_stereo(left[:1], [(a[1], off_rows)], calib, config) == [(0, None), (None, 0)]
    behind = a[0].image_uv + [30.0, 0.0]                # right image point left of ... : negative disparity
    assert stereo_cost(a[1].image_uv, behind, calib, config) >= 1e9


def test_two_pairs_seeing_one_person_give_one_track():
    """The default rig's pairs look 90 degrees apart; a person at 45 degrees between them, seen by both,
    becomes one track holding all four cameras."""
    cfg = SimConfig()
    cfg.cameras.left.yaw_deg = 40.0               # turn the second pair so both see the diagonal
    cfg.cameras.forward.yaw_deg = 10.0
    calibs = {pair.name: make_calibration(pair) for pair in cfg.cameras.pairs()}
    rng = np.random.default_rng(3)
    dets = []
    for k in range(12):
        points = _person_points((12.0 + 0.09 * k, 6.0 + 0.09 * k), np.pi / 4, 0.5 * k)
        for calib in calibs.values():
            dets += _detections(calib, points, k, rng)
    tracks = associate(dets, calibs, ground=_ground(calibs))
    assert len(tracks) == 1
    assert set(tracks[0].pairs) == set(calibs)
    assert all(len(fr.detections) == 4 for fr in tracks[0].frames)
    assert all(d.track_id == tracks[0].track_id for fr in tracks[0].frames for d in fr.detections.values())


def test_a_range_that_is_the_missed_person_in_front_s_does_not_pull_the_detection_to_that_person():
    """Two people overlap in one image, the near one (17 m, 300 px tall) in front of the far one (21 m, 250 px):
    while both are detected each keeps its own tracklet.  Then the detector misses the near one, and the far
    one's detection gets the only LiDAR cluster its hull holds, the near one's (17.1 m).  With the range as
    evidence the near person's tracklet takes the detection; with ``range_claims`` the range is the near
    person's, whom the tracker follows over the detection, and the far person's own tracklet keeps it."""
    def person(px_per_m, column, feet_row):
        return np.stack([column + px_per_m * STICK[:, 0], feet_row - px_per_m * (STICK[:, 2] - STICK[:, 2].min())],
                        axis=1)

    near, far = person(175.0, 1000.0, 1200.0), person(146.0, 1010.0, 1150.0)
    for claims, owner in ((False, 0), (True, 1)):
        tracker = Tracker(TrackerConfig(confirm_hits=1, min_track_frames=1, min_mean_score=0.0, max_misses=4,
                                        size_sigma=0.25, range_sigma_m=0.25, range_claims=claims))
        for frame in range(4):
            assert tracker.step(frame, [Observation(frame=frame, uv={"left": near}, score=0.8, lidar_range_m=17.0),
                                        Observation(frame=frame, uv={"left": far}, score=0.8, lidar_range_m=21.0)]) \
                == [0, 1]
        assert tracker.step(4, [Observation(frame=4, uv={"left": far}, score=0.8, lidar_range_m=17.1)]) == [owner]


def test_tracker_birth_and_death():
    """A track is output only after ``confirm_hits`` observations and ``min_track_frames`` frames; a confirmed
    track survives ``max_misses - 1`` missing frames and dies at ``max_misses``."""
    config = TrackerConfig(confirm_hits=3, min_track_frames=3, max_misses=3, min_mean_score=0.3)
    uv = np.column_stack([np.linspace(1000, 1040, 17), np.linspace(800, 1200, 17)])

    def obs(frame, du=0.0):
        return Observation(frame=frame, uv={"left": uv + [du, 0.0]}, score=0.8)

    tracker = Tracker(config)
    for frame in (0, 1):
        tracker.step(frame, [obs(frame, 5.0 * frame)])
    assert tracker.tracks() == []                       # two hits: tentative
    tracker.step(2, [obs(2, 10.0)])
    tracker.step(4, [obs(4, 20.0)])                     # one frame missed: same track
    assert [len(t) for t in tracker.tracks()] == [4]
    tracker.step(7, [obs(7, 35.0)])                     # two frames missed: same track
    assert [len(t) for t in tracker.tracks()] == [5]
    tracker.step(11, [obs(11, 55.0)])                   # three frames missed: dead, a new tentative track
    assert [len(t) for t in tracker.tracks()] == [5]


def test_scoring_counts_switches_fragments_and_false_tracks():
    """:func:`score_tracks`: a track going on with another person is a switch charged to both, a person in two
    tracks a fragmentation, a track of clutter a false track, a track of an unlabelled person a bystander's;
    the frames of someone other than a track's owner are its wrong frames, and its detections of others
    (as are a false track's detections of people) others' detections."""
    from pedx_graph.detections.association import DetectedTrack, DetectedTrackFrame
    from pedx_graph.detections.evaluate import score_tracks

    records = []

    def det(frame, kind, tid=None):
        records.append({"camera": "cam", "frame": frame, "index": len(records), "kind": kind,
                        **({"tracking_id": tid} if tid else {})})
        return Detection(camera="cam", frame=frame, keypoint_set="coco17", image_uv=np.zeros((17, 2)),
                         confidence=np.ones(17), score=1.0, source=f"x.json#[{len(records) - 1}]")

    def track(name, items):
        return DetectedTrack(track_id=name, pairs=("cam-other",), frames=[
            DetectedTrackFrame(frame=f, detections={"cam": det(f, kind, tid)}) for f, kind, tid in items])

    tracks = [track("t1", [(0, "person", "a"), (1, "person", "a"), (2, "person", "b"), (3, "person", "b"),
                           (4, "person", "b")]),
              track("t2", [(0, "person", "b"), (1, "person", "b")]),
              track("t3", [(0, "clutter", None), (1, "clutter", None), (2, "person", "a")]),
              track("t4", [(0, "person", "c"), (1, "person", "c")])]
    labelled = {"a": {0: 10.0, 1: 10.0, 2: 10.0}, "b": {f: 12.0 for f in range(5)}}
    score = score_tracks(tracks, records, labelled)
    assert score["id_switches"] == 1                      # t1: a -> b (t3's clutter frames are nobody's)
    assert score["switches_by_person"] == {"a": 1, "b": 1}
    assert score["false_tracks"] == 1 and score["bystander_tracks"] == 1
    assert score["recovered"] == 1 and score["labelled_people"] == 2      # only b owns a track
    assert score["fragmentations"] == 2                   # a in t1 and t3, b in t1 and t2
    assert score["wrong_frames"] == 2                     # t1's two frames of a (t3 is no one's track)
    # people's detections on their own person's track (t1's three of b, t2's two, t4's two) and on someone
    # else's or a false one (t1's two of a, t3's one); clutter counts for neither
    assert score["own_detections"] == 7 and score["others_detections"] == 3
    # a neighbour's one frame inside a track: two switches (in and out), one wrong frame
    score = score_tracks([track("t5", [(0, "person", "a"), (1, "person", "b"), (2, "person", "a")])], records,
                         labelled)
    assert score["id_switches"] == 2 and score["wrong_frames"] == 1
    assert score["own_detections"] == 2 and score["others_detections"] == 1


def test_switch_geometry_sorts_switches_by_where_the_two_people_stood():
    """:func:`switch_geometry`: a switch between walkers one behind the other as seen from the rig (the
    farther within 0.4 m of the nearer one's ray) is in line, between walkers whose directions differ by more
    than 60 degrees paths crossing, else beside; a standing person has no direction; a person without a true
    centre at the frame is unplaced.  Measured on the ground plane of a z-down world (the real PedX LiDAR
    frame), heights ignored."""
    from pedx_graph.data.ground import GroundFrame
    from pedx_graph.detections.evaluate import switch_geometry

    ground = GroundFrame(world_up=np.array([0.0, 0.0, -1.0]), world_forward=np.array([0.0, 1.0, 0.0]),
                         world_p_sensor=np.zeros(3))

    def walk(start, step_per_frame, height=-0.9):
        """Level (x forward, y left) start and step -> world centres over frames 0-4 (world x = level y,
        world y = level x, z down)."""
        return {f: np.array([start[1] + f * step_per_frame[1], start[0] + f * step_per_frame[0], height])
                for f in range(5)}

    people = {"near": walk((10.0, 0.0), (0.12, 0.0)),
              "behind": walk((11.0, 0.25), (0.12, 0.0), height=-1.5),     # 0.25 m off the near one's ray
              "beside": walk((10.0, 0.6), (0.12, 0.0)),
              "across": walk((10.5, -0.5), (0.0, 0.13)),
              "standing": walk((12.0, -0.1), (0.0, 0.01)),
              "far_off": walk((20.0, 0.5), (0.12, 0.0))}                 # 0.5 m off the near one's ray
    centres = {(tid, f): p for tid, path in people.items() for f, p in path.items()}
    switches = [("t1", 2, "near", "behind"), ("t1", 4, "behind", "near"),     # in line (at the track's end too)
                ("t2", 2, "near", "across"),                                   # paths crossing
                ("t3", 2, "beside", "near"),                                   # beside
                ("t4", 2, "near", "standing"),                                 # standing: in line, no direction
                ("t5", 2, "far_off", "near"),                                  # beyond 0.4 m of the ray: beside
                ("t6", 2, "near", "nobody")]                                   # unplaced
    assert switch_geometry(switches, centres, ground, frame_interval_s=0.1) == {
        "switches_in_line": 3, "switches_paths_crossing": 1, "switches_beside": 2, "switches_unplaced": 1}
    # slower frames: the same steps are a standing person's, so no direction crosses
    assert switch_geometry(switches[2:3], centres, ground, frame_interval_s=1.0)["switches_paths_crossing"] == 0


def test_placement_counts_judge_each_frame_s_centre_against_its_own_person():
    """:func:`placement_counts`: a frame's centre is judged against the true centre of the person its
    detections belong to (a neighbour's frame inside a track against the neighbour), on the ground plane
    (height does not count); off by more than 0.5 m it is misplaced, and overconfident when that is also
    more than three of its own depth sigmas; frames without a centre, or whose person has no true centre
    there, are not placed."""
    from pedx_graph.data.ground import GroundFrame
    from pedx_graph.detections.association import DetectedTrack, DetectedTrackFrame
    from pedx_graph.detections.evaluate import placement_counts

    # z-down world (the real PedX LiDAR frame), level x along world y
    ground = GroundFrame(world_up=np.array([0.0, 0.0, -1.0]), world_forward=np.array([0.0, 1.0, 0.0]),
                         world_p_sensor=np.zeros(3))
    records = []

    def frame(f, tid, world_p, sigma):
        records.append({"camera": "cam", "frame": f, "index": len(records), "kind": "person", "tracking_id": tid})
        det = Detection(camera="cam", frame=f, keypoint_set="coco17", image_uv=np.zeros((17, 2)),
                        confidence=np.ones(17), score=1.0, source=f"x.json#[{len(records) - 1}]")
        return DetectedTrackFrame(frame=f, detections={"cam": det},
                                  world_p=None if world_p is None else np.asarray(world_p, dtype=float),
                                  depth_sigma_m=sigma)

    centres = {("a", f): np.array([0.0, 10.0 + f, 0.0]) for f in range(6)}
    centres.update({("b", f): np.array([3.0, 10.0 + f, 0.0]) for f in range(6)})
    track = DetectedTrack(track_id="t1", pairs=("cam-other",), frames=[
        frame(0, "a", [0.1, 10.0, -1.5], 0.1),       # 0.1 m off on the ground (1.5 m up does not count)
        frame(1, "a", [0.0, 11.9, 0.0], 0.1),        # 0.9 m off, claiming 0.1 m: overconfident
        frame(2, "a", [0.0, 12.9, 0.0], 0.5),        # 0.9 m off, claiming 0.5 m: misplaced, honest
        frame(3, "b", [3.0, 13.2, 0.0], 0.1),        # the neighbour's frame, on the neighbour
        frame(4, "a", None, np.inf),                 # no centre
        frame(5, "c", [0.0, 15.0, 0.0], 0.1)])       # a person without a true centre
    assert placement_counts([track], records, centres, ground) == {
        "placed_frames": 4, "misplaced_centres": 2, "overconfident_centres": 1}


def test_a_tied_frame_belongs_to_the_track_s_person_in_switches_and_owners():
    """A frame holding one detection of the track's person and one of a neighbour (two images, a tie) is the
    track's person's — the same for :func:`score_tracks`' switches and for :func:`frame_owners`, which a
    benchmark scores the frame's fit against — whatever the ids' sorted order; a tie at the first frame
    goes to the first id in sorted order; a frame holding only fragments (a detector's partial second
    reading of someone) belongs to nobody."""
    from pedx_graph.detections.association import DetectedTrack, DetectedTrackFrame
    from pedx_graph.detections.evaluate import frame_owners, score_tracks

    records = []

    def det(frame, camera, tid, kind="person"):
        records.append({"camera": camera, "frame": frame, "index": len(records), "kind": kind,
                        "tracking_id": tid})
        return Detection(camera=camera, frame=frame, keypoint_set="coco17", image_uv=np.zeros((17, 2)),
                         confidence=np.ones(17), score=1.0, source=f"x.json#[{len(records) - 1}]")

    def frame(f, left, right):
        return DetectedTrackFrame(frame=f, detections={"left": det(f, "left", left), "right": det(f, "right", right)})

    track = DetectedTrack(track_id="t1", pairs=("left-right",), frames=[
        frame(0, "z", "a"), frame(1, "z", "z"), frame(2, "z", "a"), frame(3, "z", "z"),
        DetectedTrackFrame(frame=4, detections={"left": det(4, "left", "a", kind="fragment")})])
    assert frame_owners(track, records) == {0: "a", 1: "z", 2: "z", 3: "z"}
    score = score_tracks([track], records, {"z": {f: 10.0 for f in range(4)}})
    assert score["id_switches"] == 1 and score["switches"] == [("t1", 1, "a", "z")]
    assert score["mixed_frames"] == 2
    assert score["wrong_frames"] == 1                     # frame 0, a's, in z's track


def test_two_people_crossing_at_20_m_on_the_pedx_rig_keep_their_ids():
    """The real rig's forward pair (0.33 m baseline: ~53 px disparity at 20 m, a 0.6 m depth step is ~1.6 px):
    two walkers cross each other at 20 and 20.6 m with detector-like noise (1.5 % of their height); while they
    overlap, the detector misses the one in the left image and the other in the right image.  Per-frame
    stereo pairs what is left (one person's left image with the other's right image: same rows, same size,
    a plausible disparity); tracking each camera first and pairing tracklets by their shared frames' evidence
    does not: two tracks, each one person's detections only, both images paired wherever both saw it."""
    from pedx_graph.data.ground import ground_from_calibrations
    from pedx_graph.sim import pedx_rig_config
    from pedx_graph.sim.cameras import rig_calibrations

    cfg = pedx_rig_config()
    calibs = rig_calibrations(cfg)
    calib = calibs[cfg.cameras.forward.name]
    up = ground_from_calibrations(calibs).world_up        # the simulator's frame, derived from the cameras
    world_T_cam = np.asarray(calib.world_T_cam, dtype=float)
    axis = calib.world_R_rect[:, 2]                                        # the rectified viewing direction
    forward = axis - (axis @ up) * up
    forward /= np.linalg.norm(forward)
    lateral = np.cross(up, forward)
    ground_offset = -cfg.lidar.height_m                     # the LiDAR (origin) this high above the ground
    ground = make_ground_frame(up, forward, np.zeros(3), ground_offset, source="config")
    origin = world_T_cam[:3, 3] - (world_T_cam[:3, 3] @ up - ground_offset) * up   # ground below the camera
    rng = np.random.default_rng(4)
    dets, owners = [], {}
    n = 24
    for k in range(n):
        t = (k - n / 2 + 0.5) * 0.1                          # they pass each other between frames 11 and 12
        for name, depth, side, phase in (("a", 20.0, 1.0, 0.0), ("b", 20.6, -1.0, 1.0)):
            centre = origin + depth * forward + side * 1.3 * t * lateral
            heading = side * lateral
            right = np.cross(heading, up)
            swing = 0.25 * np.sin(5 * t + phase)
            local = STICK.copy()
            local[[9, 16], 1] += swing
            local[[10, 15], 1] -= swing
            world = centre + local[:, :1] * right + local[:, 1:2] * heading + local[:, 2:3] * up
            missed_in = ("left" if name == "a" else "right") if abs(t) < 0.1 else None
            left_uv, right_uv = calib.project(world)
            height = float(np.ptp(left_uv[:, 1]))
            for camera, uv, side in zip(calib.name.split("-"), (left_uv, right_uv), ("left", "right")):
                if side == missed_in:
                    continue
                uv = uv + 0.015 * height * rng.normal(size=uv.shape)
                conf = np.full(len(uv), 0.7)
                det = Detection(camera=camera, frame=k, keypoint_set="coco17", image_uv=uv, confidence=conf,
                                score=0.7, source=f"{camera}/{k}/{name}")
                owners[det.source] = name
                dets.append(det)
    tracks = associate(dets, calibs, ground=ground)
    assert sorted(map(sorted, (_who(tr, owners) for tr in tracks))) == [["a"], ["b"]]
    assert all(len(tr) == n for tr in tracks)
    assert sum(len(fr.detections) == 2 for tr in tracks for fr in tr.frames) == 2 * (n - 2)


def _walkers_together(with_clouds: bool, seed: int):
    """Two walkers crossing the PedX rig's forward view together, one behind the other: at 21 and 22 m along
    the viewing direction, 0.25 m apart sideways (their images overlap; ~2.5 px of disparity apart), the far
    one's stride out of phase.  Returns (tracks, owners)."""
    from pedx_graph.data.ground import ground_from_calibrations
    from pedx_graph.sim import pedx_rig_config
    from pedx_graph.sim.cameras import rig_calibrations

    cfg = pedx_rig_config()
    calibs = rig_calibrations(cfg)
    calib = calibs[cfg.cameras.forward.name]
    up = ground_from_calibrations(calibs).world_up
    world_T_cam = np.asarray(calib.world_T_cam, dtype=float)
    axis = calib.world_R_rect[:, 2]
    forward = axis - (axis @ up) * up
    forward /= np.linalg.norm(forward)
    lateral = np.cross(up, forward)
    ground_offset = -cfg.lidar.height_m
    ground = make_ground_frame(up, forward, np.zeros(3), ground_offset, source="config")
    origin = world_T_cam[:3, 3] - (world_T_cam[:3, 3] @ up - ground_offset) * up
    lidar_foot = -(0.0 - ground_offset) * up * 0.0        # the LiDAR is the world origin
    rng = np.random.default_rng(seed)
    dets, owners, clouds = [], {}, {}
    n = 20
    angles = np.linspace(-np.pi / 2, np.pi / 2, 9)
    for k in range(n):
        t = (k - n / 2) * 0.1
        people = {}
        for name, depth, offset, phase in (("a", 21.0, 0.0, 0.0), ("b", 22.0, 0.25, 2.0)):
            centre = origin + depth * forward + (1.3 * t + offset) * lateral
            heading, right = lateral, np.cross(lateral, up)
            swing = 0.25 * np.sin(5 * t + phase)
            local = STICK.copy()
            local[[9, 16], 1] += swing
            local[[10, 15], 1] -= swing
            people[name] = (centre, centre + local[:, :1] * right + local[:, 1:2] * heading + local[:, 2:3] * up)
        points = []
        for name, (centre, _) in people.items():       # a scan of each body's near half: 0.2 m cylinders
            towards = -(centre - lidar_foot) / np.linalg.norm(centre - lidar_foot)
            towards -= (towards @ up) * up
            towards /= np.linalg.norm(towards)
            side = np.cross(up, towards)
            for h in np.arange(0.2, 1.7, 0.35):          # scan rings ~0.35 m apart at this range
                ring = centre + h * up + 0.2 * (np.cos(angles)[:, None] * towards + np.sin(angles)[:, None] * side)
                if name == "b":                          # hidden behind a where the ray passes within 0.25 m
                    near = people["a"][0] + h * up
                    ray = ring / np.linalg.norm(ring, axis=1, keepdims=True)
                    closest = np.linalg.norm(near - (ring @ np.zeros(3))[:, None] - (ray @ near)[:, None] * ray,
                                             axis=1)
                    ring = ring[closest > 0.25]
                points.append(ring)
        clouds[k] = np.concatenate(points)
        for name, (_, world) in people.items():
            left_uv, right_uv = calib.project(world)
            height = float(np.ptp(left_uv[:, 1]))
            for camera, uv in zip(calib.name.split("-"), (left_uv, right_uv)):
                uv = uv + 0.015 * height * rng.normal(size=uv.shape)
                det = Detection(camera=camera, frame=k, keypoint_set="coco17", image_uv=uv,
                                confidence=np.full(len(uv), 0.7), score=0.7, source=f"{camera}/{k}/{name}")
                owners[det.source] = name
                dets.append(det)
    tracks = associate(dets, calibs, clouds=clouds if with_clouds else None, ground=ground)
    return tracks, owners


def test_two_people_walking_together_at_21_m_keep_their_ids_with_lidar():
    """Two people walk together one metre apart in range at ~21 m on the PedX rig (overlapping images, ~2.5 px
    of disparity apart): with the scene's LiDAR (the far one partly hidden by the near one) every track holds
    one person's detections only, over seeds of the detector noise."""
    for seed in range(3):
        tracks, owners = _walkers_together(True, seed)
        assert all(len(_who(tr, owners)) == 1 for tr in tracks), seed
        assert sorted(set.union(*(_who(tr, owners) for tr in tracks))) == ["a", "b"]


def test_a_person_seen_in_one_image_of_a_pair_joins_the_other_pairs_track():
    """A person the first pair sees in both images and the second pair only in its left image (the right one
    occluded) is one track: the first pair's 3D centres explain the second pair's detections.  Someone else,
    seen only in that left image 2 m to the side, stays a track of its own."""
    cfg = SimConfig()
    cfg.cameras.left.yaw_deg = 40.0
    cfg.cameras.forward.yaw_deg = 10.0
    calibs = {pair.name: make_calibration(pair) for pair in cfg.cameras.pairs()}
    first, second = sorted(calibs)
    rng = np.random.default_rng(5)
    dets, owners = [], {}
    for k in range(12):
        walker = _person_points((12.0 + 0.09 * k, 6.0 + 0.09 * k), np.pi / 4, 0.5 * k)
        other = _person_points((10.5 + 0.09 * k, 8.0 - 0.05 * k), np.pi / 4, 0.5 * k)
        for d in _detections(calibs[first], walker, k, rng) + _detections(calibs[second], walker, k, rng,
                                                                          side_filter="left"):
            owners[d.source] = "walker"
            dets.append(d)
        for d in _detections(calibs[second], other, k, rng, side_filter="left"):
            d.source += "/other"
            owners[d.source] = "other"
            dets.append(d)
    tracks = associate(dets, calibs, ground=_ground(calibs))
    people = [_who(t, owners) for t in tracks]
    assert all(len(p) == 1 for p in people), people              # nobody mixed
    walker = [t for t, p in zip(tracks, people) if p == {"walker"}]
    assert len(walker) == 1 and set(walker[0].pairs) == set(calibs)
    assert sum(len(fr.detections) for fr in walker[0].frames) == 36
    assert sum(p == {"other"} for p in people) == 1


def test_smoothed_centres_follow_the_majority_not_one_confident_outlier():
    """A walker's centres along a line (0.5 m uncertain) with one frame's centre 10 m off and claiming 5 cm
    (a cut on an occluder): the smoothed centres stay on the walker's line, frame by frame."""
    from pedx_graph.detections.association import DetectedTrackFrame, smooth_centres

    calibs = _rig()
    ground = _ground(calibs)
    rng = np.random.default_rng(2)
    truth = [np.array([20.0 + 0.12 * k, -5.0, GROUND_Z + 0.9]) for k in range(12)]
    frames = [DetectedTrackFrame(frame=k, detections={}, world_p=p + [0.3 * rng.normal(), 0.3 * rng.normal(), 0.0],
                                 depth_sigma_m=0.5) for k, p in enumerate(truth)]
    frames[9].world_p, frames[9].depth_sigma_m = truth[9] + [-10.0, 2.0, 0.0], 0.05
    smooth_centres(frames, ground, AssociationConfig())
    gaps = [np.linalg.norm((fr.world_p - p)[:2]) for fr, p in zip(frames, truth)]
    assert max(gaps) < 0.6, np.round(gaps, 2)


def test_smoothed_centres_weigh_precise_centres_a_second_away_over_noisy_ones_close_by():
    """Walks at 1.4 m/s at 22 m: LiDAR centres (0.1 m) at frames 0-6, none at 7-13 (hidden), stereo centres
    (0.8-1.8 m) at 14-19.  The late frames' smoothed centres use the early LiDAR centres too, each weighed
    by how far a walker leaves its line in that time: over 200 walks their RMS error is 0.44 m at this seed
    (0.67 m fitted to the noisy centres near them alone), and their claimed sigmas cover the error."""
    from pedx_graph.detections.association import DetectedTrackFrame, smooth_centres

    ground = _ground(_rig())
    rng = np.random.default_rng(7)
    errors, covered = [], []
    for _ in range(200):
        heading = rng.uniform(0, 2 * np.pi)
        velocity = 0.14 * np.array([np.cos(heading), np.sin(heading), 0.0])           # metres per frame
        start = np.array([22.0, -2.0, GROUND_Z + 0.9])
        frames = [DetectedTrackFrame(frame=k, detections={}) for k in range(20)]
        for fr in frames[:7] + frames[14:]:
            sigma = 0.1 if fr.frame < 7 else rng.uniform(0.8, 1.8)
            fr.world_p = start + fr.frame * velocity + np.r_[sigma * rng.normal(size=2), 0.0]
            fr.depth_sigma_m = sigma
        smooth_centres(frames, ground, AssociationConfig())
        for fr in frames[14:]:
            error = (fr.world_p - start - fr.frame * velocity)[:2]
            errors.append(np.linalg.norm(error))
            covered.append(bool(np.all(np.abs(error) <= 2 * fr.depth_sigma_m)))
    assert np.sqrt(np.mean(np.square(errors))) < 0.6, np.sqrt(np.mean(np.square(errors)))
    assert np.mean(covered) > 0.9, np.mean(covered)


def test_a_track_that_turns_back_across_a_gap_is_split_there():
    """A one-image track whose first two frames are a walker going one way at 21 m and whose frames after a
    three-frame gap are another walker going the other way (the tracker carried it across the gap while the
    two crossed): split at the gap.  A walker at constant velocity with the same gap stays one track."""
    from pedx_graph.detections.association import split_reversals

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(13)

    def observation(k, xy):
        uv = calib.project(_person_points(xy, np.pi / 2, 0.5 * k))[0] + 2.0 * rng.normal(size=(17, 2))
        return Observation(frame=k, uv={"left": uv}, score=0.8, payload={"left": f"{xy}/{k}"})

    swapped = [observation(k, (21.6, -0.6 + 0.16 * k)) for k in (7, 8)] + \
        [observation(k, (20.6, 1.8 - 0.16 * k)) for k in (11, 12, 15, 16, 17, 19)]
    parts = split_reversals([swapped], calib, AssociationConfig())
    assert [[o.frame for o in part] for part in parts] == [[7, 8], [11, 12, 15, 16, 17, 19]]
    steady = [observation(k, (21.6, -0.6 + 0.16 * k)) for k in (7, 8, 11, 12, 15, 16, 17, 19)]
    assert len(split_reversals([steady], calib, AssociationConfig())) == 1


def test_smoothed_centres_do_not_carry_two_noisy_centres_beyond_a_track_end():
    """A walker crossing the view at a constant depth: stereo centres (0.3 m uncertain) up to frame 12, the
    last two off in depth in opposite directions, then four frames seen in one image (no centre).  Those
    frames' smoothed centres follow the walker's line, not the line through the last two centres."""
    from pedx_graph.detections.association import DetectedTrackFrame, smooth_centres

    ground = _ground(_rig())
    rng = np.random.default_rng(3)
    truth = [np.array([7.4, -3.0 + 0.18 * k, GROUND_Z + 0.9]) for k in range(17)]
    frames = []
    for k, p in enumerate(truth):
        if k > 12:
            frames.append(DetectedTrackFrame(frame=k, detections={}))
            continue
        offset = [0.05 * rng.normal(), 0.05 * rng.normal(), 0.0]
        if k in (11, 12):
            offset = [0.35 if k == 11 else -0.05, 0.0, 0.0]
        frames.append(DetectedTrackFrame(frame=k, detections={}, world_p=p + offset, depth_sigma_m=0.3))
    smooth_centres(frames, ground, AssociationConfig())
    gaps = [np.linalg.norm((fr.world_p - p)[:2]) for fr, p in zip(frames, truth)]
    assert max(gaps[13:]) < 0.25, np.round(gaps, 2)


def test_a_short_tracks_velocity_is_a_walkers_not_its_noise():
    """A person mostly hidden, tracked over six frames walking away at 1.6 m/s: one LiDAR centre (0.2 m) and two
    stereo centres from a handful of keypoints (1.2 and 1.7 m uncertain) that happen to lie nearer each frame.
    Fitted freely, the centres give it a runner's speed toward the rig and the track's ends land ~1 m off;
    drawn toward standing by a walker's speed (``walking_speed_mps``), every frame stays within 0.7 m.  A walk
    seen over twenty frames at 1.5 m/s keeps its speed."""
    from pedx_graph.detections.association import DetectedTrackFrame, smooth_centres

    ground = _ground(_rig())
    truth = [np.array([20.62 + 0.16 * k, -4.7, GROUND_Z + 0.9]) for k in range(6)]
    measured = {2: ([20.90, -4.61], 0.2), 3: ([20.51, -4.64], 1.2), 4: ([19.73, -4.38], 1.66)}

    def gaps(config):
        frames = [DetectedTrackFrame(frame=k, detections={}) for k in range(6)]
        for k, (xy, sigma) in measured.items():
            frames[k].world_p, frames[k].depth_sigma_m = np.array(xy + [GROUND_Z + 0.9]), sigma
        smooth_centres(frames, ground, config)
        return np.array([np.linalg.norm((fr.world_p - p)[:2]) for fr, p in zip(frames, truth)])

    assert gaps(AssociationConfig(walking_speed_mps=0.0)).max() > 0.9
    assert gaps(AssociationConfig()).max() < 0.7, np.round(gaps(AssociationConfig()), 2)
    rng = np.random.default_rng(5)
    walk = [np.array([12.0 + 0.15 * k, -3.0, GROUND_Z + 0.9]) for k in range(20)]
    frames = [DetectedTrackFrame(frame=k, detections={}, world_p=p + [0.2 * rng.normal(), 0.2 * rng.normal(), 0.0],
                                 depth_sigma_m=0.2) for k, p in enumerate(walk)]
    smooth_centres(frames, ground, AssociationConfig())
    speed = (frames[-3].world_p[0] - frames[2].world_p[0]) / (15 * 0.1)
    assert 1.35 < speed < 1.65, speed


def test_a_smoothed_centres_sigma_grows_where_the_line_is_carried_past_its_centres():
    """Walks at 1.4 m/s seen at frames 0-9 with 0.3 m centre noise, smoothed over frames 0-15: past the track's
    end the claimed sigma grows frame by frame, and it is honest there and among the centres — over 200 random
    walks each frame's error stays within 2 claimed sigmas per axis about 95 % of the time (96-97 % at this
    seed; the fit's
    ``1 / sqrt(sum w)``, the same past the end, covered 76 % there; without the walking velocity's own
    uncertainty, 88 %)."""
    from pedx_graph.detections.association import DetectedTrackFrame, smooth_centres

    ground = _ground(_rig())
    rng = np.random.default_rng(11)
    inside, total, claimed = defaultdict(int), defaultdict(int), defaultdict(list)
    for _ in range(200):
        heading = rng.uniform(0, 2 * np.pi)
        velocity = 0.14 * np.array([np.cos(heading), np.sin(heading), 0.0])           # metres per frame
        start = np.array([15.0, -2.0, GROUND_Z + 0.9])
        frames = [DetectedTrackFrame(frame=k, detections={}) for k in range(16)]
        for fr in frames[:10]:
            fr.world_p = start + fr.frame * velocity + np.r_[0.3 * rng.normal(size=2), 0.0]
            fr.depth_sigma_m = 0.3
        smooth_centres(frames, ground, AssociationConfig())
        for fr in frames:
            part = "seen" if fr.frame < 10 else "past"
            error = np.abs((fr.world_p - start - fr.frame * velocity)[:2])
            inside[part] += int(np.sum(error <= 2 * fr.depth_sigma_m))
            total[part] += 2
            claimed[fr.frame].append(fr.depth_sigma_m)
    sigma = [float(np.median(claimed[k])) for k in range(16)]
    assert all(b > a for a, b in zip(sigma[9:], sigma[10:])), np.round(sigma, 3)
    assert sigma[15] > 2 * sigma[9], np.round(sigma, 3)
    for part in ("seen", "past"):
        assert 0.935 < inside[part] / total[part] < 0.99, (part, inside[part] / total[part])


def test_a_smoothed_centres_sigma_is_that_of_the_line_it_returns(monkeypatch):
    """Each frame's claimed sigma comes from the centres its line was fitted to, also where the refits that
    leave outlying centres out stop before they settle (random walks with gross outliers: a few in a
    thousand tracks end so; their last refit's keep set is not the fitted one)."""
    import pedx_graph.detections.association as association

    fitted_x, sigma_x = [], []
    walking_line, offset_sigma = association._walking_line, association._offset_sigma

    def recording_line(x, *args):
        fitted_x.append(np.array(x))
        return walking_line(x, *args)

    def recording_sigma(x, *args):
        sigma_x.append((len(fitted_x), np.array(x)))
        return offset_sigma(x, *args)

    monkeypatch.setattr(association, "_walking_line", recording_line)
    monkeypatch.setattr(association, "_offset_sigma", recording_sigma)
    ground = _ground(_rig())
    rng = np.random.default_rng(0)
    for _ in range(700):
        n = int(rng.integers(3, 12))
        heading = rng.uniform(0, 2 * np.pi)
        velocity = 0.14 * np.array([np.cos(heading), np.sin(heading), 0.0])
        start = np.array([15.0, -2.0, GROUND_Z + 0.9])
        frames = [association.DetectedTrackFrame(frame=k, detections={}) for k in range(n)]
        for fr in frames:
            sigma = float(rng.choice([0.05, 0.2, 0.5]))
            noise = rng.normal(size=2) * sigma
            if rng.random() < 0.3:
                noise += rng.normal(size=2) * 1.5                # a gross outlier
            fr.world_p, fr.depth_sigma_m = start + fr.frame * velocity + np.r_[noise, 0.0], sigma
        fitted_x.clear()
        sigma_x.clear()
        association.smooth_centres(frames, ground, AssociationConfig())
        assert len(sigma_x) == n
        for calls, x in sigma_x:                                   # the line fitted last before the sigma
            np.testing.assert_array_equal(x, fitted_x[calls - 1])


def test_a_frame_borrowed_from_someone_else_is_unpaired():
    """A person's left tracklet paired over 8 frames with its right tracklet, plus one frame with a right
    detection of someone 15 m nearer (another tracklet, one frame): that right detection leaves the person."""
    from pedx_graph.detections.association import _Person, drop_disparity_outliers

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(4)
    person = _Person()
    for k in range(9):
        far = _person_points((21.0 + 0.1 * k, -1.0), 0.0, 0.5 * k)
        near = _person_points((6.0, -0.2), 0.0, 0.5 * k)
        uv_l, uv_r = calib.project(far)
        person.sides["left"][k] = (0, None, uv_l + rng.normal(size=uv_l.shape))
        if k < 8:
            person.sides["right"][k] = (0, None, uv_r + rng.normal(size=uv_r.shape))
        else:
            person.sides["right"][k] = (1, None, calib.project(near)[1])
        person.paired.add(k)
    drop_disparity_outliers(person, calib, AssociationConfig())
    assert 8 not in person.sides["right"] and 8 in person.sides["left"] and 8 not in person.paired
    assert all(k in person.sides["right"] and k in person.paired for k in range(8))


def test_a_walkers_own_detection_past_its_last_observation_stays_close_to_the_extrapolation():
    """A walker 7 m away crossing the view, its keypoints 10 px noisy (a detector's at that size): two frames
    past its last observation, its own detection lies near the prediction carried on at the body's velocity
    (the median keypoint step); each keypoint's own noisy step carried on would double the distance.  Mean
    over 30 draws, bound about 1.5x what it measures (0.45)."""
    from pedx_graph.detections.association import _interpolation_cost

    ahead = _person_points((7.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(5)
    costs = []
    for _ in range(30):
        def uv(k):
            points = _person_points((7.0, -1.0 + 0.14 * k), np.pi / 2, 1.2 * k)
            return calib.project(points)[0] + 10.0 * rng.normal(size=(17, 2))

        observed = {k: (0, None, uv(k)) for k in range(6)}
        costs.append(_interpolation_cost(observed, 7, uv(7), AssociationConfig()))
    assert np.mean(costs) < 0.65, np.mean(costs)


def test_a_frame_a_tracklet_took_from_a_nearer_person_goes_to_that_person_by_its_lidar_range():
    """Two walkers one behind the other on one line of sight (6.6 and 7.4 m away): at the last frame the far
    one is hidden and the left image's tracker carried its tracklet on with the near one's detection, which
    the far walker's own keypoints explain about as well.  That detection's LiDAR range (the near walker's
    depth) sends it to the near walker, whose right image holds that frame; without ranges it stays with
    the tracklet it was linked to."""
    from pedx_graph.detections.association import pair_tracklets

    ahead = _person_points((7.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(12)
    frames = range(11)
    dets, ranges = {}, {}
    for name, distance in (("near", 6.6), ("far", 7.4)):
        for k in frames:
            points = _person_points((distance, (-0.9 + 0.14 * k) * distance / 6.6), np.pi / 2, 0.5 * k)
            depth = float(calib.world_to_rect(points.mean(axis=0))[2])      # along the pair's optical axis
            for side, uv in zip(("left", "right"), calib.project(points)):
                uv = uv + rng.normal(size=uv.shape)
                det = Detection(camera=side, frame=k, keypoint_set="coco17", image_uv=uv,
                                confidence=np.full(17, 0.8), score=0.8, source=f"{name}/{side}/{k}")
                dets[name, side, k] = (det, uv)
                ranges[id(det)] = depth

    def tracklet(items):
        return [(k, *dets[key]) for k, key in items]

    left = [tracklet([(k, ("far", "left", k)) for k in range(10)] + [(10, ("near", "left", 10))]),
            tracklet([(k, ("near", "left", k)) for k in range(10)])]
    right = [tracklet([(k, ("far", "right", k)) for k in range(10)]),
             tracklet([(k, ("near", "right", k)) for k in frames])]

    def holder_of_the_taken_detection(with_ranges):
        people = pair_tracklets(left, right, calib, AssociationConfig(), ranges if with_ranges else None)
        taken = dets["near", "left", 10][0]
        holder = next(p for p in people if 10 in p.sides["left"] and p.sides["left"][10][1] is taken)
        return {d.source.split("/")[0] for side in ("left", "right") for _, d, _ in holder.sides[side].values()}

    assert holder_of_the_taken_detection(True) == {"near"}
    assert holder_of_the_taken_detection(False) == {"near", "far"}


def test_a_one_frame_detection_a_neighbours_tracklet_took_completes_its_own_persons_frame():
    """Two walkers crossing the view 8 and 10 m away.  The far one is seen in the right image only, but at
    frame 4 also in the left, where the near one is missed in both images and the left image's tracker
    carried the near one's tracklet through the far one's detection.  One stereo frame is too short to pair
    tracklets, and the near walker's left detections explain that detection well enough to keep it; it
    pairs with the far walker's right detection at that frame (rows agree, the disparity at the far walker's
    depth), so it moves there and the frame is paired; the far walker's right detections stay where they
    are.  Seen in the right image for four frames only (fewer than ``tracker.min_track_frames``: a person
    dropped later, with what it received), the far walker receives nothing and the detection stays."""
    from pedx_graph.detections.association import pair_tracklets

    ahead = _person_points((8.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(7)
    views = {}
    for name, x, y0 in (("near", 8.0, -1.2), ("far", 10.0, -1.3)):
        for k in range(8):
            points = _person_points((x, y0 + 0.15 * k), np.pi / 2, 0.6 * k)
            for side, uv in zip(("left", "right"), calib.project(points)):
                uv = uv + rng.normal(size=uv.shape)
                det = Detection(camera=side, frame=k, keypoint_set="coco17", image_uv=uv,
                                confidence=np.full(len(uv), 0.8), score=0.8, source=f"{name}/{side}/{k}")
                views[name, side, k] = (k, det, uv)
    left = [[views["far" if k == 4 else "near", "left", k] for k in range(8)]]

    def owners(far_frames):
        right = [[views["near", "right", k] for k in range(8) if k != 4],
                 [views["far", "right", k] for k in far_frames]]
        people = pair_tracklets(left, right, calib, AssociationConfig())
        return people, {d.source: n for n, p in enumerate(people) for s in ("left", "right")
                        for _, d, _ in p.sides[s].values()}

    people, owner = owners(range(8))
    far = owner["far/right/0"]
    assert owner["far/left/4"] == far and 4 in people[far].paired
    assert all(owner[f"far/right/{k}"] == far for k in range(8))
    assert all(owner[f"near/left/{k}"] != far for k in range(8) if k != 4)
    _, owner = owners(range(2, 6))
    assert owner["far/left/4"] == owner["near/left/0"] != owner["far/right/4"]


def test_a_tracklet_seen_beside_the_persons_own_does_not_join_it_by_one_paired_frame():
    """Two walkers 20 and 21.6 m away on nearly one ray, the far one 0.2 m to the side.  The left image's
    tracker holds each in a tracklet of its own: the near one missed at frames 3, 4 and 8, the far one seen
    at frames 3, 4, 7 and 8 only (at frame 7 beside the near one).  The right image sees only the near one
    (not at frames 3, 4 and 7), so the far walker's left tracklet shares a single frame (8) with the near
    walker's right tracklet, and passes the stereo gates there.  That one frame is too short to make the
    far walker's tracklet the near one's, which it is seen beside at frame 7: the far walker's detections
    stay together, apart from the near walker's person."""
    from pedx_graph.detections.association import pair_tracklets

    x0, gap, lateral = 20.0, 1.6, 0.2
    ahead = _person_points((x0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(1)
    views = {}
    for name, x, side_m in (("near", x0, 0.0), ("far", x0 + gap, lateral)):
        for k in range(12):
            y = (-1.0 + 0.13 * k) * x / x0 + side_m                     # on the near walker's ray, then aside
            points = _person_points((x, y), np.pi / 2, 0.6 * k)
            for side, uv in zip(("left", "right"), calib.project(points)):
                uv = uv + rng.normal(size=uv.shape)
                det = Detection(camera=side, frame=k, keypoint_set="coco17", image_uv=uv,
                                confidence=np.full(len(uv), 0.8), score=0.8, source=f"{name}/{side}/{k}")
                views[name, side, k] = (k, det, uv)
    left = [[views["near", "left", k] for k in (0, 1, 2, 5, 6, 7, 9, 10, 11)],
            [views["far", "left", k] for k in (3, 4, 7, 8)]]
    right = [[views["near", "right", k] for k in (0, 1, 2, 5, 6, 8, 9, 10, 11)]]
    people = pair_tracklets(left, right, calib, AssociationConfig())
    owner = {d.source: n for n, p in enumerate(people) for s in ("left", "right") for _, d, _ in p.sides[s].values()}
    near = owner["near/left/0"]
    assert all(owner[d.source] == near for _, d, _ in left[0] + right[0])
    assert len({owner[f"far/left/{k}"] for k in (3, 4, 7, 8)}) == 1
    assert owner["far/left/3"] != near


def test_a_tracklet_that_changed_person_midway_stays_paired_before_the_change():
    """The right image's tracker swapped two people 8 m apart in depth at frame 8 (each right tracklet holds
    one person for frames 0-7 and the other for 8-19); the left image's tracklets are clean.  Each left
    tracklet agrees in stereo with each right one over part of their overlap only: both parts are paired,
    so each person is one track paired at every frame, with its own right detections."""
    from pedx_graph.detections.association import pair_tracklets

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(11)
    views = {}
    for name, start, step in (("near", (21.0, -1.5), (0.0, 0.15)), ("far", (29.0, 1.2), (0.0, -0.12))):
        for k in range(20):
            points = _person_points((start[0] + step[0] * k, start[1] + step[1] * k), 0.0, 0.5 * k)
            for side, uv in zip(("left", "right"), calib.project(points)):
                uv = uv + rng.normal(size=uv.shape)
                det = Detection(camera=side, frame=k, keypoint_set="coco17", image_uv=uv,
                                confidence=np.full(len(uv), 0.8), score=0.8, source=f"{name}/{side}/{k}")
                views[name, side, k] = (k, det, uv)
    left = [[views["near", "left", k] for k in range(20)], [views["far", "left", k] for k in range(20)]]
    right = [[views["near" if k < 8 else "far", "right", k] for k in range(20)],
             [views["far" if k < 8 else "near", "right", k] for k in range(20)]]
    people = pair_tracklets(left, right, calib, AssociationConfig())
    found = {}
    for person in people:
        names = {d.source.split("/")[0] for side in ("left", "right") for _, d, _ in person.sides[side].values()}
        assert len(names) == 1, names
        found[names.pop()] = person
    assert sorted(found) == ["far", "near"]
    for person in found.values():
        assert sorted(person.paired) == list(range(20))


def test_a_frame_goes_to_the_persons_own_detection_not_a_neighbours_a_carried_on_tracklet_holds():
    """A walker at 19 m, clean in the left image.  The right image's tracker lost it after frame 2 and carried a
    neighbour's tracklet on with it from frame 3; at frames 1-2 that tracklet holds the neighbour, 4 px of
    disparity off the walker's (1 m deeper), close enough to pass the stereo gates with the walker's left
    detection.  Summed over its run, the long tracklet outweighs the walker's own short right tracklet
    (frames 0-2), yet at frames 1-2 the walker's own right detection pairs better: the walker keeps its own
    right detections at every frame, and the neighbour's stay out."""
    from pedx_graph.detections.association import pair_tracklets

    ahead = _person_points((19.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(21)
    views = {}
    for k in range(12):
        walker = calib.project(_person_points((19.0, -1.0 + 0.12 * k), 0.0, 0.5 * k))
        neighbour = calib.project(_person_points((19.0, -1.0 + 0.12 * k), 0.0, 0.5 * k + 2.0))[1] + [4.0, 0.0]
        for name, side, uv in (("walker", "left", walker[0]), ("walker", "right", walker[1]),
                               ("neighbour", "right", neighbour)):
            uv = uv + rng.normal(size=uv.shape)
            det = Detection(camera=side, frame=k, keypoint_set="coco17", image_uv=uv,
                            confidence=np.full(len(uv), 0.8), score=0.8, source=f"{name}/{side}/{k}")
            views[name, side, k] = (k, det, uv)
    left = [[views["walker", "left", k] for k in range(12)]]
    right = [[views["walker", "right", k] for k in range(3)],
             [views["neighbour", "right", k] for k in (1, 2)] + [views["walker", "right", k] for k in range(3, 12)]]
    people = pair_tracklets(left, right, calib, AssociationConfig())
    walker = next(p for p in people if p.sides["left"])
    assert sorted(walker.sides["right"]) == list(range(12))
    assert {d.source.split("/")[0] for _, d, _ in walker.sides["right"].values()} == {"walker"}
    assert sorted(walker.paired) == list(range(12))


def test_a_one_frame_agreement_with_another_tracklet_takes_no_frame_from_a_pairing():
    """A walker at 19 m, its left and right tracklets agreeing at frames 0-9.  A two-frame right tracklet of
    someone else matches the walker's left detection a little better at frame 5 (0.2 px noise against the
    walker's 1.5 px) and fails the stereo gates at frame 6: that pairing stands on no run of its own, so it
    contests nothing, and the walker stays paired with its own right detection at every frame."""
    from pedx_graph.detections.association import pair_tracklets

    ahead = _person_points((19.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(22)

    def view(name, side, k, uv):
        return (k, Detection(camera=side, frame=k, keypoint_set="coco17", image_uv=uv,
                             confidence=np.full(len(uv), 0.8), score=0.8, source=f"{name}/{side}/{k}"), uv)

    left, right, other = [], [], []
    for k in range(10):
        uv_l, uv_r = calib.project(_person_points((19.0, -1.0 + 0.12 * k), 0.0, 0.5 * k))
        left.append(view("walker", "left", k, uv_l + 1.5 * rng.normal(size=uv_l.shape)))
        right.append(view("walker", "right", k, uv_r + 1.5 * rng.normal(size=uv_r.shape)))
        if k == 5:
            other.append(view("other", "right", k, uv_r + 0.2 * rng.normal(size=uv_r.shape)))
        elif k == 6:
            other.append(view("other", "right", k, uv_r + [0.0, 60.0]))
    people = pair_tracklets([left], [right, other], calib, AssociationConfig())
    walker = next(p for p in people if p.sides["left"])
    assert sorted(walker.paired) == list(range(10))
    assert {d.source.split("/")[0] for _, d, _ in walker.sides["right"].values()} == {"walker"}


def test_single_frame_glitches_do_not_break_a_pairing():
    """A person's left and right tracklets share 7 frames; in every other one (1, 3, 5) the right detection is
    off by 60 px in rows (a detector's glitch: that frame fails the stereo gates).  No run of passing frames
    is long enough on its own, yet the tracklets are one person: paired at the passing frames."""
    from pedx_graph.detections.association import pair_tracklets

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(12)
    left, right = [], []
    for k in range(7):
        uv_l, uv_r = calib.project(_person_points((21.0, -1.0 + 0.12 * k), 0.0, 0.5 * k))
        uv_l, uv_r = uv_l + rng.normal(size=uv_l.shape), uv_r + rng.normal(size=uv_r.shape)
        if k % 2:
            uv_r = uv_r + [0.0, 60.0]
        for side, uv, out in (("left", uv_l, left), ("right", uv_r, right)):
            det = Detection(camera=side, frame=k, keypoint_set="coco17", image_uv=uv,
                            confidence=np.full(len(uv), 0.8), score=0.8, source=f"{side}/{k}")
            out.append((k, det, uv))
    people = pair_tracklets([left], [right], calib, AssociationConfig())
    paired = [p for p in people if p.paired]
    assert len(paired) == 1
    assert sorted(paired[0].paired) == [0, 2, 4, 6]
    assert sorted(paired[0].sides["left"]) == list(range(7))


def _pair_with_failing_frames(failing, frames):
    """One walker's left and right tracklets at 21 m over ``frames``, the right detection off by 60 px in rows
    (failing the stereo gates) at the ``failing`` frames."""
    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(15)
    left, right = [], []
    for k in frames:
        uv_l, uv_r = calib.project(_person_points((21.0, -1.0 + 0.12 * k), 0.0, 0.5 * k))
        uv_l, uv_r = uv_l + rng.normal(size=uv_l.shape), uv_r + rng.normal(size=uv_r.shape)
        if k in failing:
            uv_r = uv_r + [0.0, 60.0]
        for side, uv, out in (("left", uv_l, left), ("right", uv_r, right)):
            det = Detection(camera=side, frame=k, keypoint_set="coco17", image_uv=uv,
                            confidence=np.full(len(uv), 0.8), score=0.8, source=f"{side}/{k}")
            out.append((k, det, uv))
    return calib, left, right


def test_tracklets_agreeing_in_most_frames_with_failures_scattered_are_paired():
    """Shared frames 0-5, the right detection failing at 1 (a glitch), 3 and 4: no run of passing frames is
    long enough (0-2 holds two), but over the whole overlap the evidence is positive and three frames pass —
    paired there.  With only two frames passing (0 and 2, failing at 1 and 3) they stay apart: two frames
    could be two people's."""
    from pedx_graph.detections.association import pair_tracklets

    calib, left, right = _pair_with_failing_frames({1, 3, 4}, range(6))
    paired = [p for p in pair_tracklets([left], [right], calib, AssociationConfig()) if p.paired]
    assert len(paired) == 1 and sorted(paired[0].paired) == [0, 2, 5]
    calib, left, right = _pair_with_failing_frames({1, 3}, range(4))
    assert not [p for p in pair_tracklets([left], [right], calib, AssociationConfig()) if p.paired]


def _walker_observations(calib, start_xy, step_xy, frames, rng):
    """Pair-track observations (both images, rectified) of a stick walker, one per frame."""
    out = []
    for k in frames:
        points = _person_points((start_xy[0] + step_xy[0] * k, start_xy[1] + step_xy[1] * k), 0.0, 0.5 * k)
        uv_l, uv_r = calib.project(points)
        uv = {"left": uv_l + rng.normal(size=uv_l.shape), "right": uv_r + rng.normal(size=uv_r.shape)}
        both = np.median(uv["left"][:, 0] - uv["right"][:, 0])
        out.append(Observation(frame=k, uv=uv, score=0.8, disparity_px=float(both), payload=k))
    return out


def test_tracks_swapped_where_two_people_cross_are_repaired():
    """Two people crossing at ~21 m in opposite directions (1 m apart in depth); their tracks were carried on
    with each other after the crossing (frame 10).  The straight-walk test gives each its own tail back;
    two people walking side by side keep their tracks as they are."""
    from pedx_graph.detections.association import repair_swaps

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(6)
    frames = range(20)
    a = _walker_observations(calib, (21.0, -1.6), (0.0, 0.16), frames, rng)
    b = _walker_observations(calib, (22.0, 1.6), (0.0, -0.16), frames, rng)
    swapped = [a[:12] + b[12:], b[:12] + a[12:]]
    repaired = repair_swaps(swapped, calib, AssociationConfig())
    # where both stand in the same image column (frame 10) either assignment explains the images
    apart = [k for k in frames if abs(np.median(a[k].uv["left"][:, 0]) - np.median(b[k].uv["left"][:, 0])) > 30]
    assert len(apart) >= 17
    for track, person in zip(repaired, (a, b)):
        ids = {o.frame: id(o) for o in track}
        assert sorted(ids) == list(frames)
        assert all(ids[k] == id(person[k]) for k in apart)
    c = _walker_observations(calib, (21.0, -1.0), (0.12, 0.1), frames, rng)
    d = _walker_observations(calib, (21.3, -0.3), (0.12, 0.1), frames, rng)
    kept = repair_swaps([c, d], calib, AssociationConfig())
    assert [id(o) for o in kept[0]] == [id(o) for o in c] and [id(o) for o in kept[1]] == [id(o) for o in d]


def _walkers_in_step(calib, rng, frames):
    """Two people walking side by side in step along +y (sim frame), 1.5 m apart in depth at ~20 m, placed so
    that they stand in the same image column at frame 10: pair-track observations of each with LiDAR-like
    centres (0.1 m), and a function giving the true centre of a walker (depth, start) at a frame."""
    def position(depth_x, start_y, k):
        return np.array([depth_x, start_y + 0.14 * k, GROUND_Z + 1.0])

    def walker(depth_x, start_y):
        observations = _walker_observations(calib, (depth_x, start_y), (0.0, 0.14), frames, rng)
        for obs in observations:
            obs.world_p = position(depth_x, start_y, obs.frame)
            obs.world_p[:2] += rng.normal(scale=0.1, size=2)
            obs.depth_sigma_m = 0.1
        return observations

    far_y = -1.6 + 0.2 * (1.0 - 21.5 / 20.0)
    return walker(20.0, -1.6), walker(21.5, far_y), position, far_y


def test_swap_between_people_walking_in_step_at_different_depths_is_repaired_by_their_depths():
    """Two people walking side by side in step, 1.5 m apart in depth at ~20 m, placed so that they stand in
    the same image column at frame 10: their columns stay within ~16 px of each other, so the image alone
    cannot tell them apart.  Their tracks were carried on with each other after frame 12.  The frames'
    centre depths (LiDAR-like, 0.1 m) give each its own tail back."""
    from pedx_graph.detections.association import repair_swaps

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    frames = range(20)
    near, far, _, _ = _walkers_in_step(calib, np.random.default_rng(3), frames)
    columns = [abs(np.median(near[k].uv["left"][:, 0]) - np.median(far[k].uv["left"][:, 0])) for k in frames]
    assert max(columns) < 25.0
    repaired = repair_swaps([near[:12] + far[12:], far[:12] + near[12:]], calib, AssociationConfig())
    for track, person in zip(repaired, (near, far)):
        assert [id(o) for o in track] == [id(o) for o in person]


def test_lidar_centre_on_the_person_in_front_does_not_decide_the_swap():
    """As above, with the tracks swapped at frame 10, where the two stand in the same image column: the near
    one is seen there in one image only (no centre), the far one's LiDAR cut caught the near one in front
    (its centre on the near one, 0.1 m; its stereo centre, 1 m, kept as the fallback).  Where one detection
    hides the other, that LiDAR depth is not used: each track gets its own frame 10 back, not the one whose
    depth lies on the other."""
    from pedx_graph.detections.association import repair_swaps

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))
    near, far, position, far_y = _walkers_in_step(calib, np.random.default_rng(4), range(20))
    near[10] = Observation(frame=10, uv={"left": near[10].uv["left"]}, score=0.8, payload=10)
    far[10].fallback = (position(21.5, far_y, 10), calib.camera_centre("left"), 1.0)
    far[10].world_p, far[10].depth_sigma_m = position(20.0, -1.6, 10), 0.1
    repaired = repair_swaps([near[:10] + far[10:], far[:10] + near[10:]], calib, AssociationConfig())
    for track, person in zip(repaired, (near, far)):
        assert [id(o) for o in track] == [id(o) for o in person]


def test_track_head_or_tail_holding_the_other_walker_goes_back_to_it():
    """The walkers in step again.  One track begins with the far walker's frame 0 and goes on with the near
    one from frame 2, while the far one's own track starts at frame 2 (the tracker took the far walker's first
    detection for the near one); another time, the far walker's track goes on with the near one after frame
    15, where the near one's track ends.  Moving that head or tail to the other track is tried too: each
    track ends up with one walker."""
    from pedx_graph.detections.association import repair_swaps

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))
    near, far, _, _ = _walkers_in_step(calib, np.random.default_rng(5), range(20))
    head = repair_swaps([[far[0]] + near[2:], far[2:]], calib, AssociationConfig())
    assert sorted([id(o) for o in t] for t in head) == sorted([[id(o) for o in near[2:]],
                                                               [id(o) for o in [far[0]] + far[2:]]])
    tail = repair_swaps([near[:16], far[:16] + near[16:]], calib, AssociationConfig())
    assert sorted([id(o) for o in t] for t in tail) == sorted([[id(o) for o in near], [id(o) for o in far[:16]]])
    apart = repair_swaps([near[:6], near[8:]], calib, AssociationConfig())     # one walker lost for two frames
    assert [[id(o) for o in t] for t in apart] == [[id(o) for o in near[:6]], [id(o) for o in near[8:]]]


def test_stretch_exchanged_between_walkers_in_step_and_given_back_is_repaired():
    """The walkers in step again, their tracks carried on with each other from frame 8 and back again from
    frame 14 (they met twice while missed in turns).  No single exchange of tails helps: either tail leaves
    six frames on the wrong walker.  Exchanging the stretch gives each track its own walker back."""
    from pedx_graph.detections.association import repair_swaps

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))
    near, far, _, _ = _walkers_in_step(calib, np.random.default_rng(7), range(20))
    swapped = [near[:8] + far[8:14] + near[14:], far[:8] + near[8:14] + far[14:]]
    repaired = repair_swaps(swapped, calib, AssociationConfig())
    assert sorted([id(o) for o in t] for t in repaired) == sorted([[id(o) for o in near], [id(o) for o in far]])


def test_one_frame_of_a_walker_in_the_other_track_moves_back_where_that_track_has_none():
    """The walkers in step again.  The far walker was missed at frame 14 and its track took the near walker's
    detection there, while the near walker's track has no frame 14.  One frame is not exchanged, but it is
    moved: the near walker's frame 14 goes back to its track (its depth is 1.5 m off the far walk, its column
    and height a little off too: together beyond the gate); the far walker's track is left without it."""
    from pedx_graph.detections.association import repair_swaps

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))
    near, far, _, _ = _walkers_in_step(calib, np.random.default_rng(8), range(20))
    misplaced = [near[:14] + near[15:], far[:14] + [near[14]] + far[15:]]
    repaired = repair_swaps(misplaced, calib, AssociationConfig())
    assert sorted([id(o) for o in t] for t in repaired) == sorted([[id(o) for o in near],
                                                                   [id(o) for o in far[:14] + far[15:]]])


def test_one_frame_of_a_walker_just_past_its_track_moves_back_to_it():
    """The walkers in step again.  The near walker's track ends at frame 15 (it was lost there) while the far
    walker's track took the near walker's detection of frame 16 (its own walker just missed); another time
    the near walker's track begins at frame 17 and that frame 16 is again in the far walker's track.  That
    one frame, just past the span the two tracks share, moves to the near walker's track."""
    from pedx_graph.detections.association import repair_swaps

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))
    near, far, _, _ = _walkers_in_step(calib, np.random.default_rng(8), range(20))
    far_track = far[:16] + [near[16]] + far[17:]
    for near_track in (near[:16], near[17:]):
        repaired = repair_swaps([near_track, far_track], calib, AssociationConfig())
        assert sorted([id(o) for o in t] for t in repaired) == sorted(
            [[id(o) for o in sorted(near_track + [near[16]], key=lambda o: o.frame)],
             [id(o) for o in far[:16] + far[17:]]])


def test_no_frame_moves_out_of_a_short_track_or_between_tracks_apart_in_time():
    """One walker's two tracks, frames 5-7 and 8-19 (lost for a moment, not stitched); the short one's middle
    frame is off (30 px in the image, 2 m in depth), so its three frames fit no straight walk.  Moving its
    frame 7 to the long track would leave two frames, whose walk costs nothing: a gain that says nothing of
    who frame 7 is.  Nor do the two share a span: a move between them would begin to join them.  They are
    left as they are."""
    from pedx_graph.detections.association import repair_swaps

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))
    near, _, _, _ = _walkers_in_step(calib, np.random.default_rng(8), range(20))
    near[6].uv = {side: uv + [30.0, 0.0] for side, uv in near[6].uv.items()}
    near[6].world_p = near[6].world_p + [2.0, 0.0, 0.0]
    repaired = repair_swaps([near[5:8], near[8:]], calib, AssociationConfig())
    assert [[id(o) for o in t] for t in repaired] == [[id(o) for o in near[5:8]], [id(o) for o in near[8:]]]


def _walker_of_height(calib, start_xy, step_xy, frames, rng, scale):
    """Pair-track observations of a stick walker ``scale`` times the stick's height, each holding its two
    detections (coco17), so their image heights are known to :func:`repair_swaps`' walk."""
    out = []
    for k in frames:
        points = _person_points((start_xy[0] + step_xy[0] * k, start_xy[1] + step_xy[1] * k), 0.0, 0.5 * k)
        points[:, 2] = GROUND_Z + scale * (points[:, 2] - GROUND_Z)
        uv = dict(zip(("left", "right"), calib.project(points)))
        uv = {side: value + rng.normal(size=value.shape) for side, value in uv.items()}
        payload = {side: Detection(camera=camera, frame=k, keypoint_set="coco17", image_uv=uv[side],
                                   confidence=np.full(len(uv[side]), 0.8), score=0.8, source=f"{side}{k}")
                   for side, camera in zip(("left", "right"), calib.name.split("-"))}
        disparity = float(np.median(uv["left"][:, 0] - uv["right"][:, 0]))
        out.append(Observation(frame=k, uv=uv, score=0.8, disparity_px=disparity, payload=payload))
    return out


def _short_and_tall(rng):
    """A short (1.45 m) and a tall (1.85 m) person walking together at ~20 m, the tall one 0.4 m behind on
    nearly the same ray, over frames 0-19: the forward pair, and each one's observations."""
    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    frames = range(20)
    short = _walker_of_height(calib, (20.0, -1.4), (0.0, 0.14), frames, rng, 1.45 / 1.7)
    tall = _walker_of_height(calib, (20.4, -1.4 * 20.4 / 20.0), (0.0, 0.14 * 20.4 / 20.0), frames, rng, 1.85 / 1.7)
    return calib, short, tall


def test_standing_height_holds_when_the_feet_or_the_head_are_missed():
    """A detection's standing-template height (:func:`standing_height_px`) stays where it was when the ankles
    or the face are not detected, where the present keypoints' vertical span shrinks; an upper body alone
    gives none."""
    from pedx_graph.detections.association import standing_height_px

    calib = next(iter(_rig().values()))
    rng = np.random.default_rng(21)
    uv, _ = calib.project(_person_points((12.0, 0.0), np.pi / 2, 0.3))
    noisy = uv + rng.normal(size=uv.shape)
    full, full_se = standing_height_px(noisy, "coco17", 3.0, 4.0)
    assert 0.0 < full_se < 0.03 * full
    for missing in ([15, 16], [0, 1, 2, 3, 4]):             # ankles; nose, eyes and ears
        cut = noisy.copy()
        cut[missing] = np.nan
        height, se = standing_height_px(cut, "coco17", 3.0, 4.0)
        span = np.ptp(cut[np.all(np.isfinite(cut), axis=1), 1])
        assert abs(height - full) < 3.0 * np.hypot(se, full_se)
        assert span < 0.9 * np.ptp(noisy[:, 1])
    assert standing_height_px(np.where(np.arange(17)[:, None] < 7, noisy, np.nan), "coco17", 3.0, 4.0) is None


def test_swap_between_two_people_of_different_heights_walking_together_is_repaired_by_their_heights():
    """A short (1.45 m) and a tall (1.85 m) person walking together at ~20 m, the tall one 0.4 m behind on
    nearly the same ray: their image columns stay within a few pixels and their stereo depths cannot tell
    0.4 m apart.  Their tracks were carried on with each other after frame 10.  A person keeps their height,
    so their image heights follow the walk: each track gets its own walker back.  Without the heights (no
    detections to measure them on) the walk sees nothing to repair."""
    from pedx_graph.detections.association import repair_swaps

    calib, short, tall = _short_and_tall(np.random.default_rng(8))
    frames = range(20)
    columns = [abs(np.median(short[k].uv["left"][:, 0]) - np.median(tall[k].uv["left"][:, 0])) for k in frames]
    assert max(columns) < 10.0
    swapped = [short[:10] + tall[10:], tall[:10] + short[10:]]
    repaired = repair_swaps(swapped, calib, AssociationConfig())
    for track, person in zip(repaired, (short, tall)):
        assert [id(o) for o in track] == [id(o) for o in person]
    blind = [[dataclasses.replace(o, payload=o.frame) for o in track] for track in swapped]
    kept = repair_swaps(blind, calib, AssociationConfig())
    assert [[id(o) for o in t] for t in kept] == [[id(o) for o in t] for t in blind]


def test_a_frame_of_a_taller_person_walking_alongside_is_taken_out_of_the_shorter_ones_track():
    """The short and the tall walker on nearly one ray again: the short one's track holds the tall one's
    frame 10 (the tracker gave it the wrong detection where they met), the tall one's track misses it.  Its
    height is far off the short one's walk and on the tall one's: the frame is dropped from the short one's
    track (not moved: one frame can fit another walk by chance).  Without the tall one's track nothing
    allows that height elsewhere and the frame stays."""
    from pedx_graph.detections.association import drop_other_heights

    calib, short, tall = _short_and_tall(np.random.default_rng(9))
    mixed = short[:10] + [tall[10]] + short[11:]
    rest = tall[:10] + tall[11:]
    kept = drop_other_heights([mixed, rest], calib, AssociationConfig())
    assert [[id(o) for o in t] for t in kept] == [[id(o) for o in short[:10] + short[11:]], [id(o) for o in rest]]
    alone = drop_other_heights([mixed], calib, AssociationConfig())
    assert [[id(o) for o in t] for t in alone] == [[id(o) for o in mixed]]
    assert [[id(o) for o in t] for t in drop_other_heights([short, tall], calib, AssociationConfig())] == \
        [[id(o) for o in short], [id(o) for o in tall]]


def test_a_one_image_detection_far_off_its_tracks_height_is_dropped_though_no_other_track_explains_it():
    """At frame 10 the short walker's track holds, in its left image only, the detection of someone 5 m
    nearer on nearly the same ray whom the pair does not track (seen in that image alone): about 1.6 times
    the walk's image height, more than ``lone_height_gate_sigmas`` of its sigma off it.  The detection goes
    with its frame.  The tall walker 0.4 m behind (some 6 sigmas off) stays without a track of its own to
    explain it; so do the walker's own one-image detection, and the near one's with the rule off."""
    from pedx_graph.detections.association import drop_other_heights

    calib, short, tall = _short_and_tall(np.random.default_rng(9))
    near = _walker_of_height(calib, (15.0, -1.4 * 15.0 / 20.0), (0.0, 0.14 * 15.0 / 20.0), range(20),
                             np.random.default_rng(10), 1.0)

    def with_left_of(person: list) -> list:
        lone = Observation(frame=10, uv={"left": person[10].uv["left"]}, score=0.8,
                           payload={"left": person[10].payload["left"]})
        return short[:10] + [lone] + short[11:]

    (kept,) = drop_other_heights([with_left_of(near)], calib, AssociationConfig())
    assert [o.frame for o in kept] == [f for f in range(20) if f != 10]
    assert [id(o) for o in kept] == [id(o) for o in short[:10] + short[11:]]
    for person, config in ((tall, AssociationConfig()), (short, AssociationConfig()),
                           (near, AssociationConfig(lone_height_gate_sigmas=float("inf")))):
        track = with_left_of(person)
        (kept,) = drop_other_heights([track], calib, config)
        assert [id(o) for o in kept] == [id(o) for o in track]


def test_the_taller_ones_detection_in_one_image_of_an_unpaired_frame_is_taken_out_and_the_other_image_kept():
    """The short and the tall walker again; at frame 10 the short one's track holds its own left detection
    and the tall one's right detection, unpaired (the stereo pairing refused them).  The right image's
    height is off the short one's walk there and on the tall one's: that detection is dropped, the frame
    stays with its left one.  Every image with a walk is judged, not only the one with the most heights
    (here the left: it holds the frame's own detection).  A paired frame loses both, its centre being
    theirs."""
    from pedx_graph.detections.association import drop_other_heights

    calib, short, tall = _short_and_tall(np.random.default_rng(9))
    own, other = short[10], tall[10]
    unpaired = Observation(frame=10, uv={"left": own.uv["left"], "right": other.uv["right"]}, score=0.8,
                           payload={"left": own.payload["left"], "right": other.payload["right"]})
    rest = tall[:10] + tall[11:]
    kept, kept_rest = drop_other_heights([short[:10] + [unpaired] + short[11:], rest], calib, AssociationConfig())
    assert [id(o) for o in kept_rest] == [id(o) for o in rest]
    assert [o.frame for o in kept] == list(range(20))
    assert set(kept[10].uv) == {"left"} and kept[10].payload == {"left": own.payload["left"]}
    assert kept[10].uv["left"] is own.uv["left"]
    assert [id(o) for o in kept[:10] + kept[11:]] == [id(o) for o in short[:10] + short[11:]]
    paired = dataclasses.replace(unpaired, disparity_px=own.disparity_px, world_p=np.zeros(3), depth_sigma_m=1.0)
    kept, _ = drop_other_heights([short[:10] + [paired] + short[11:], rest], calib, AssociationConfig())
    assert [o.frame for o in kept] == [f for f in range(20) if f != 10]


def test_a_one_coefficient_robust_fit_leaves_out_two_precise_points_off_the_rest():
    """Eight points at 0 (sigma 1) and two at 3 (sigma 0.5): fitted from all ten, the mean lies at 1.5 and
    every residual within the 3.5-sigma gate, so trimming from there keeps the two.  Started from the
    median instead, the two lie 6 sigma off, are left out, and the fit is the eight's mean."""
    from pedx_graph.detections.association import _robust_fit

    rng = np.random.default_rng(3)
    y = np.concatenate([rng.normal(scale=0.1, size=8), [3.0, 3.0]])
    sigma = np.concatenate([np.ones(8), [0.5, 0.5]])
    total, coef = _robust_fit(np.ones((1, 10, 1)), y, sigma, 3.5, coefficients=True)
    assert abs(coef[0, 0] - np.mean(y[:8])) < 1e-9
    assert total[0] == pytest.approx(np.sum((y[:8] - np.mean(y[:8])) ** 2) + 2 * 3.5 ** 2)


def _robust_fit_three_times(design, y, sigma, gate):
    """The walk's robust fit written plainly (every fit iterated three times, np.median, einsum): what
    :func:`_robust_fit` must give bit for bit."""
    weight = 1.0 / sigma
    a = design * weight[None, :, None]
    b = y * weight
    k = design.shape[2]
    keep = np.ones(design.shape[:2], dtype=bool)
    if k == 1:
        with np.errstate(divide="ignore", invalid="ignore"):
            start = np.median(y[None, :] / design[:, :, 0], axis=1)
            keep = np.abs(b[None, :] - a[:, :, 0] * start[:, None]) <= gate
        keep[keep.sum(axis=1) == 0] = True
    for _ in range(3):
        ak = a * keep[:, :, None]
        if k == 1:
            coef = (np.sum(ak[:, :, 0] * b, axis=1) / (np.sum(ak[:, :, 0] ** 2, axis=1) + 1e-12))[:, None]
        else:
            a0, a1 = ak[:, :, 0], ak[:, :, 1]
            s00, s01, s11 = np.sum(a0 * a0, axis=1) + 1e-12, np.sum(a0 * a1, axis=1), np.sum(a1 * a1, axis=1) + 1e-12
            r0, r1 = a0 @ b, a1 @ b
            det = s00 * s11 - s01 * s01
            coef = np.stack([(s11 * r0 - s01 * r1) / det, (s00 * r1 - s01 * r0) / det], axis=1)
        z = b[None, :] - np.einsum("mni,mi->mn", a, coef)
        new_keep = np.abs(z) <= gate
        enough = new_keep.sum(axis=1) >= k
        keep = np.where(enough[:, None], new_keep, keep)
    return np.sum(np.minimum(z ** 2, gate ** 2), axis=1), coef


def test_the_robust_fit_stopping_early_gives_the_three_iterations_bit_for_bit():
    """:func:`_robust_fit` stops once the points it keeps no longer change: on walk-like designs (columns
    over 33 depth rates, depths, sizes, with outliers and a zero design column) its sums and coefficients
    are those of three full iterations, bit for bit."""
    from pedx_graph.detections.association import _robust_fit

    rng = np.random.default_rng(11)
    for _ in range(400):
        m, n = int(rng.integers(1, 34)), int(rng.integers(3, 60))
        tau = np.arange(n) - 0.5 * (n - 1)
        stretch = 1.0 + rng.uniform(-0.02, 0.02, m)[:, None] * tau[None, :]
        design = (np.stack([1.0 / stretch, tau / stretch], axis=2), stretch[:, :, None],
                  1.0 / stretch[:, :, None])[int(rng.integers(3))]
        if rng.random() < 0.1:
            design = design.copy()
            design[:, rng.integers(n)] = 0.0
        y = 100.0 * rng.normal() + 30.0 * rng.normal(size=n)
        if rng.random() < 0.5:
            y[rng.integers(n, size=3)] += 200.0
        sigma = rng.uniform(0.5, 5.0, n)
        total, coef = _robust_fit(design, y, sigma, 3.0, coefficients=True)
        want_total, want_coef = _robust_fit_three_times(design, y, sigma, 3.0)
        assert np.array_equal(total, want_total) and np.array_equal(coef, want_coef)


def test_a_walk_fit_kept_by_its_series_values_is_the_one_fitted_anew():
    """:func:`_track_walk` with a memo gives what it gives without one, fits a series once however often it
    is asked (equal values in other arrays included), and fits a changed series anew."""
    from pedx_graph.detections.association import _track_walk

    calib = _rig()["ylw79D0-red707B"]
    config = AssociationConfig()
    rng = np.random.default_rng(8)
    frames = np.arange(12.0)
    seen = (frames, 40.0 + 3.0 * frames + rng.normal(0, 1, 12), np.full(12, 1.5), 14.0 - 0.1 * frames,
            np.full(12, 0.3), 180.0 + rng.normal(0, 2, 12), np.full(12, 4.0), 60.0)
    memo: dict = {}
    fresh = _track_walk(seen, calib, config)
    assert _track_walk(seen, calib, config, memo=memo) == fresh
    assert _track_walk(tuple(np.array(x) if isinstance(x, np.ndarray) else x for x in seen), calib, config,
                       memo=memo) == fresh and len(memo) == 1
    moved = (seen[0], seen[1] + np.where(frames >= 6, 25.0, 0.0)) + seen[2:]
    assert _track_walk(moved, calib, config, memo=memo) == _track_walk(moved, calib, config) != fresh
    assert _track_walk(seen, calib, config, with_size=False, memo=memo) == _track_walk(seen, calib, config,
                                                                                      with_size=False)
    assert len(memo) == 3


def test_a_standing_height_is_kept_by_the_keypoints_it_was_measured_on():
    """:func:`standing_height_px` keeps its answers by the keypoints' values: the same keypoints in
    another array give the same height, and keypoints changed in place give a new one."""
    from pedx_graph.detections.association import _standing_rows, standing_height_px

    rng = np.random.default_rng(4)
    uv = np.stack([rng.uniform(600, 620, 17), 300.0 + 180.0 * _standing_rows("coco17")], axis=1)
    first = standing_height_px(uv, "coco17", 3.0, 4.0)
    assert standing_height_px(uv.copy(), "coco17", 3.0, 4.0) == first
    assert standing_height_px(uv[:, [0, 1]].T.copy().T, "coco17", 3.0, 4.0) == first     # not contiguous
    uv[:, 1] = 300.0 + 2.0 * (uv[:, 1] - 300.0)
    assert standing_height_px(uv, "coco17", 3.0, 4.0)[0] == pytest.approx(2.0 * first[0])


def _walker_and_the_one_behind(seed: int):
    """A walker going away from the forward pair from 7 m (0.12 m a frame, frames 0-11) and a person of the
    same height standing 1.2 m behind it on nearly the same ray, each observation with a centre 0.15 m
    uncertain in depth: the forward pair, the walker's and the standing one's observations."""
    rng = np.random.default_rng(seed)
    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    frames = range(12)
    end = (7.0 + 0.12 * 11 + 1.2, -0.6 * (7.0 + 0.12 * 11 + 1.2) / (7.0 + 0.12 * 11))

    def centred(obs, xy):
        world_p = np.array([xy[0], xy[1], GROUND_Z + 0.9]) + rng.normal(scale=[0.15, 0.03, 0.03])
        return dataclasses.replace(obs, world_p=world_p, depth_sigma_m=0.15)

    walker = [centred(o, (7.0 + 0.12 * o.frame, -0.6))
              for o in _walker_of_height(calib, (7.0, -0.6), (0.12, 0.0), frames, rng, 1.0)]
    behind = [centred(o, end) for o in _walker_of_height(calib, end, (0.0, 0.0), frames, rng, 1.0)]
    return calib, walker, behind


def test_a_track_tail_in_one_image_of_the_person_behind_is_dropped_though_it_would_bend_the_walk():
    """The walker's track ends with two frames holding, in the left image only, the detections of the person
    standing 1.2 m behind (the tracker carried it on with them; about 13 % smaller in the image), while that
    person's own track misses them.  The walker's image heights shrink as it walks away, so a walk whose
    depth rate followed the heights could take the tail for more of the same; its rate comes from its
    columns and centres, and the tail's heights lie off it: both frames are dropped (on 9 of 10 seeds at
    least; a rate fitted to the heights as well kept the tail on 4 of these 10)."""
    from pedx_graph.detections.association import drop_other_heights

    dropped = 0
    for seed in range(10):
        calib, walker, behind = _walker_and_the_one_behind(seed)
        tail = [Observation(frame=o.frame, uv={"left": o.uv["left"]}, score=0.8, payload={"left": o.payload["left"]})
                for o in behind[10:]]
        kept = drop_other_heights([walker[:10] + tail, behind[:10]], calib, AssociationConfig())
        assert [id(o) for o in kept[1]] == [id(o) for o in behind[:10]]
        assert [id(o) for o in kept[0][:10]] == [id(o) for o in walker[:10]]
        dropped += len(kept[0]) == 10
    assert dropped >= 9


def test_a_walker_lost_and_found_again_is_one_track_not_the_neighbour_found_beside_it():
    """The walkers in step: the near one's track ends at frame 3 and a new one starts at frame 8 (hidden for
    four frames); the far one, unseen before, is found at frame 8 too, in the same image column.  The walk
    joins the near one's two pieces (its centre depths; the far one is 1.5 m deeper).  A piece of someone
    standing still, or of a walker coming back the other way, is not joined; nor is the near one's second
    piece seen in one image only, without depths, nor any piece when another one fits as well."""
    from pedx_graph.detections.association import stitch_tracks

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    near, far, position, _ = _walkers_in_step(calib, np.random.default_rng(11), range(20))
    pieces = [near[:4], far[8:], near[8:]]
    joined = stitch_tracks(pieces, calib, AssociationConfig())
    assert [[id(o) for o in t] for t in joined] == [[id(o) for o in near[:4] + near[8:]], [id(o) for o in far[8:]]]
    # each piece alone is what it was without a join (0 = off)
    assert stitch_tracks(pieces, calib, AssociationConfig(stitch_max_gap_frames=0)) == pieces
    # beyond the allowed gap: not joined
    assert len(stitch_tracks([near[:4], near[16:]], calib, AssociationConfig(stitch_max_gap_frames=10))) == 2
    # the far walker's first piece, its depths known to 1.5 m only (stereo at range), fits the near one's
    # second piece too: two pieces pass for it, the walk cannot tell which, and none is joined
    vague = [dataclasses.replace(o, depth_sigma_m=1.5) for o in far[:4]]
    assert len(stitch_tracks([near[:4], vague, near[8:]], calib, AssociationConfig())) == 3
    # found again in one image only (no centre): it could as well be the one behind in that column
    one_image = [Observation(frame=o.frame, uv={"left": o.uv["left"]}, score=0.8, payload=o.payload) for o in near[8:]]
    assert len(stitch_tracks([near[:4], one_image], calib, AssociationConfig())) == 2
    rng = np.random.default_rng(12)
    start = (20.0, -1.6 + 0.14 * 8)            # where the near walker is at frame 8
    standing = _walker_observations(calib, start, (0.0, 0.0), range(8, 14), rng)
    back = _walker_observations(calib, (start[0], start[1] + 0.14 * 8), (0.0, -0.14), range(8, 14), rng)
    for other, step in ((standing, 0.0), (back, -0.14)):
        for obs in other:
            obs.world_p = np.array([start[0], start[1] + step * (obs.frame - 8), GROUND_Z + 1.0])
            obs.depth_sigma_m = 0.1
        assert len(stitch_tracks([near[:4], other], calib, AssociationConfig())) == 2


def test_a_person_hidden_for_four_frames_is_one_track_with_both_pieces():
    """A walker at 20 m seen in both images at frames 0-3, hidden from 4 to 7, seen again from 8 to 15: the
    per-camera tracker gives up after the gap (``tracklet.max_misses``), and the first piece alone (4 frames)
    is shorter than ``tracker.min_track_frames``; the two pieces make one track of all 12 frames."""
    calibs = _rig()
    ahead = _person_points((20.0, 0.0), 0.0, 0.0)
    calib = next(c for c in calibs.values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))
    rng = np.random.default_rng(14)
    dets = []
    seen = [k for k in range(16) if not 4 <= k <= 7]
    for k in seen:
        dets += _detections(calib, _person_points((20.0, -1.0 + 0.14 * k), np.pi / 2, 0.6 * k), k, rng)
    tracks = associate(dets, calibs, ground=_ground(calibs))
    assert [[fr.frame for fr in tr.frames] for tr in tracks] == [seen]
    parted = associate(dets, calibs, AssociationConfig(stitch_max_gap_frames=0), ground=_ground(calibs))
    assert [[fr.frame for fr in tr.frames] for tr in parted] == [seen[4:]]


def test_walk_cost_follows_perspective_near_the_camera():
    """A walker 4-7 m away walking diagonally away from the camera: its image speed halves over 20 frames
    (perspective), which no straight line in time fits; the projected straight walk fits it to the noise."""
    from pedx_graph.detections.association import _depth_rate, _image_track, _walk_cost

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))
    config = AssociationConfig()
    track = _walker_observations(calib, (4.0, -2.0), (0.15, 0.12), range(20), np.random.default_rng(2))
    frames, u, sigma, depth, depth_sigma, _, _, px_per_m = _image_track(track, calib, config, "left")
    speed = np.abs(np.diff(u))
    assert speed[:3].mean() > 2.0 * speed[-3:].mean()
    rate = _depth_rate(px_per_m, calib, config)
    assert _walk_cost(frames, u, sigma, config.gate_sigmas, rate) < 0.5 * len(frames)
    assert _walk_cost(frames, u, sigma, config.gate_sigmas, 0.0) > 2.0 * len(frames)


def test_two_pairs_pair_up_people_walking_side_by_side_by_their_rays():
    """Two people walking side by side 0.7 m apart at ~20 m, seen by both pairs of the real rig's layout (the
    second 0.9 m to the side, turned 20 degrees).  Each pair's centres are 1 m uncertain in depth (an error
    that persists over the frames, as smoothed stereo centres' does), so both
    pairings pass the isotropic gate; with the uncertainty along each viewing ray only, the right pairing
    agrees far better and is the one merged."""
    from pedx_graph.detections.association import merge_pair_tracks
    from pedx_graph.detections.tracker import Observation

    cfg = SimConfig()
    cfg.cameras.left.yaw_deg = 20.0
    cfg.cameras.left.left_camera_xyz = (0.0, -0.9, -0.08)
    cfg.cameras.forward.yaw_deg = 0.0
    calibs = {pair.name: make_calibration(pair) for pair in cfg.cameras.pairs()}
    ground = _ground(calibs)
    rng = np.random.default_rng(8)
    people = {"left": np.array([20.0, 0.7, GROUND_Z + 0.9]), "right": np.array([20.2, 0.0, GROUND_Z + 0.9])}
    tracks, owner = [], []
    for name, calib in sorted(calibs.items()):
        camera = calib.world_T_cam[:3, 3]
        for who, centre in people.items():
            ray = (centre - camera) / np.linalg.norm(centre - camera)
            bias = rng.normal(0.0, 1.0)                   # smoothed stereo centres: errors persist over frames
            obs = []
            for k in range(10):
                truth = centre + [0.1 * k, 0.0, 0.0]
                depth_error = bias + rng.normal(0.0, 0.3)
                obs.append(Observation(frame=k, uv={}, score=0.8, world_p=truth + depth_error * ray
                                       + rng.normal(0.0, 0.03, 3), depth_sigma_m=1.0))
            tracks.append((name, obs))
            owner.append(who)
    groups = merge_pair_tracks(tracks, ground, AssociationConfig(), calibs)
    merged = [g for g in groups if len(g) == 2]
    assert len(merged) == 2 and all(owner[g[0]] == owner[g[1]] for g in merged), [[owner[i] for i in g] for g in groups]


def test_the_far_walker_keeps_its_own_depth_behind_the_near_one():
    """The two walkers one behind the other (21 and 22 m): the far one's LiDAR cut also holds the near one's
    points in front of it.  Its centre comes from its own LiDAR cluster or from stereo, never from the near
    one: over the track the far person's centres lie about a metre beyond the near person's."""
    for seed in range(3):
        tracks, owners = _walkers_together(True, seed)
        ranges = {}
        for track in tracks:
            who = _who(track, owners)
            assert len(who) == 1, seed
            ranges[who.pop()] = np.median([np.linalg.norm(fr.world_p) for fr in track.frames
                                           if fr.world_p is not None])
        assert 0.5 < ranges["b"] - ranges["a"] < 1.5, (seed, ranges)


def test_a_centre_comes_from_the_detections_own_lidar_cluster():
    """A far person (21 m) whose stereo centre came out a metre short, on the near person (20 m) standing
    in front: the cut around that depth holds the near person's points, not the cluster the detection was
    given (its range, 21 m).  The centre is not taken from the near person: it slides along its viewing
    ray to the detection's own range."""
    from pedx_graph.detections.association import _lidar_centre

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calibs = _rig()
    calib = next(c for c in calibs.values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    ground = _ground(calibs)
    far, near = np.array([21.0, 0.0]), np.array([20.0, 0.25])
    rings = []
    for centre in (far, near):
        for h in np.arange(0.2, 1.7, 0.3):
            angles = np.linspace(np.pi / 2, 3 * np.pi / 2, 9)       # the side facing the sensor
            rings.append(np.c_[centre[0] + 0.2 * np.cos(angles), centre[1] + 0.2 * np.sin(angles),
                               np.full(9, GROUND_Z + h)])
    cloud = np.concatenate(rings)
    uv_left, uv_right = calib.project(ahead)
    det = Detection(camera=calib.name.split("-")[0], frame=0, keypoint_set="coco17", image_uv=uv_left,
                    confidence=np.full(len(uv_left), 0.9), score=0.9, source="test")
    truth_centre = np.array([far[0], far[1], GROUND_Z + 0.9])
    short = truth_centre - [1.0, 0.0, 0.0]
    obs = Observation(frame=0, uv={"left": uv_left}, score=0.9, world_p=short, depth_sigma_m=0.8,
                      payload={"left": det})
    own_range = float(calib.world_to_rect(truth_centre)[2])
    _lidar_centre(obs, calib, cloud, ground, AssociationConfig(), {}, {id(det): own_range},
                  {"left": [own_range, float(calib.world_to_rect(np.r_[near, GROUND_Z + 0.9])[2])]})
    assert abs(float(calib.world_to_rect(obs.world_p)[2]) - own_range) < 0.25
    assert np.linalg.norm(obs.world_p[:2] - far) < 0.3


def _someone_at_22m():
    """A standing person 22 m ahead (+x) of the rig's forward pair: ``(calibs, calib, ground, uv, det)`` with
    its left-image detection (COCO, every keypoint)."""
    ahead = _person_points((22.0, 0.0), 0.0, 0.0)
    calibs = _rig()
    calib = next(c for c in calibs.values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    uv = calib.project(ahead)[0]
    det = Detection(camera=calib.name.split("-")[0], frame=0, keypoint_set="coco17", image_uv=uv,
                    confidence=np.full(len(uv), 0.9), score=0.9, source="test")
    return calibs, calib, _ground(calibs), uv, det


def _lidar_person(x: float = 22.0) -> np.ndarray:
    """(45, 3) LiDAR points of a person at ``(x, 0)``: the half-cylinder (0.2 m radius) facing the sensor, 5
    scan rings."""
    angles = np.linspace(np.pi / 2, 3 * np.pi / 2, 9)
    return np.concatenate([np.c_[x + 0.2 * np.cos(angles), 0.2 * np.sin(angles), np.full(9, GROUND_Z + h)]
                           for h in np.arange(0.2, 1.7, 0.3)])


def _lidar_on(keypoints: np.ndarray) -> np.ndarray:
    """LiDAR points on a person's body as its keypoints (K, 3) pose it: three points between each keypoint
    and the next (a body seen side-on is as narrow as its limbs; a front-facing cylinder would not be)."""
    steps = np.linspace(0.0, 1.0, 3, endpoint=False)[:, None, None]
    return (keypoints[:-1] + steps * (keypoints[1:] - keypoints[:-1])).reshape(-1, 3)


def _facade(x: float = 24.5) -> np.ndarray:
    """LiDAR points of a building's wall facing the sensor at ``x``: 8 m wide, 4 m high."""
    grid = np.stack(np.meshgrid(np.arange(-4.0, 4.0, 0.1), np.arange(0.1, 4.0, 0.3)), -1).reshape(-1, 2)
    return np.c_[np.full(len(grid), x), grid[:, 0], GROUND_Z + grid[:, 1]]


def test_a_cluster_that_would_lift_the_person_off_the_ground_is_not_its_range():
    """A person at 22 m whose own points the LiDAR does not see, and a box 1.2 m high at 15 m inside its
    silhouette (a car's flank): at 15 m the person's feet would float ~0.6 m above the ground, so the box's
    cluster is not its range.  With the person's own points present, they are."""
    from pedx_graph.detections.association import detection_ranges

    calibs, calib, ground, uv, det = _someone_at_22m()
    grid = np.stack(np.meshgrid(np.linspace(-0.3, 0.3, 7), np.linspace(0.3, 1.2, 6)), -1).reshape(-1, 2)
    box = np.c_[np.full(len(grid), 15.0), grid[:, 0], GROUND_Z + grid[:, 1]]
    person = _lidar_person()
    config = AssociationConfig()
    assert detection_ranges([(det, uv)], calib, "left", box, ground, config) == {}
    ranges = detection_ranges([(det, uv)], calib, "left", np.concatenate([box, person]), ground, config)
    assert abs(ranges[id(det)] - float(calib.world_to_rect(np.array([21.8, 0.0, GROUND_Z + 0.9]))[2])) < 0.3


def test_a_wall_behind_a_person_the_lidar_misses_places_no_one():
    """A person at 22 m whose own points the LiDAR does not see, in front of a building's wall 2.5 m behind
    (a facade 8 m wide, 4 m high): at the wall's range the person's feet sink only ~0.2 m into the ground,
    within the feet test, so the wall's cluster is the detection's range (it still tells people apart) — but
    it goes on past the silhouette (:func:`ends_at_silhouette` False), so a one-image track of that person
    gets no centre from it.  The person's own points in front of the same wall end at its silhouette; alone in
    its hull they place it."""
    from pedx_graph.detections.association import detection_ranges, ends_at_silhouette, pair_tracks

    calibs, calib, ground, uv, det = _someone_at_22m()
    wall = _facade()
    person = _lidar_person()
    config = AssociationConfig()
    past = set()
    ranges = detection_ranges([(det, uv)], calib, "left", wall, ground, config, past)
    wall_range = float(calib.world_to_rect(np.array([24.5, 0.0, GROUND_Z + 0.9]))[2])
    assert abs(ranges[id(det)] - wall_range) < 0.3
    assert past == {id(det)}                    # the wall's range places no one
    assert not ends_at_silhouette(uv, calib, "left", wall, ground, ranges[id(det)], config)
    with_person = np.concatenate([wall, person])
    person_range = float(calib.world_to_rect(np.array([21.8, 0.0, GROUND_Z + 0.9]))[2])
    assert ends_at_silhouette(uv, calib, "left", with_person, ground, person_range, config)
    past = set()
    ranges = detection_ranges([(det, uv)], calib, "left", person, ground, config, past)
    assert abs(ranges[id(det)] - person_range) < 0.3 and past == set()
    # a walker seen in the left image only, over 6 frames, in front of the wall: no centre
    dets, clouds = [], {}
    for k in range(6):
        points = _person_points((22.0, 0.13 * k), np.pi / 2, 0.6 * k)
        dets.append(Detection(camera=calib.name.split("-")[0], frame=k, keypoint_set="coco17",
                              image_uv=calib.project(points)[0], confidence=np.full(17, 0.9), score=0.9,
                              source=f"test#{k}"))
        clouds[k] = wall
    tracks = pair_tracks(dets, calib, config, ground, clouds)
    assert len(tracks) == 1 and all(obs.world_p is None for obs in tracks[0])
    # its own points, alone in the hull (the wall too would leave two clusters, nothing telling which): placed
    tracks = pair_tracks(dets, calib, config, ground, {k: _lidar_on(_person_points((22.0, 0.13 * k), np.pi / 2,
                                                                                   0.6 * k)) for k in range(6)})
    assert len(tracks) == 1 and all(obs.world_p is not None for obs in tracks[0])


def test_ids_from_the_files_place_a_one_image_track_by_its_own_lidar_cluster_only():
    """Detections whose ids come from the files (:func:`tracks_from_ids`), a walker at 22 m seen in the left
    image only: with the scene clouds holding its own points every frame gets a centre on it (as the
    association's one-image frames do); with only a wall behind it (the LiDAR misses the walker) none does,
    so no segment is cut from the wall."""
    from pedx_graph.detections.association import tracks_from_ids

    calibs, calib, ground, _, _ = _someone_at_22m()
    person = _lidar_person()
    wall = _facade()
    camera = calib.name.split("-")[0]
    frames = {k: {camera: Detection(camera=camera, frame=k, keypoint_set="coco17", score=0.9, source=f"t#{k}",
                                    image_uv=calib.project(_person_points((22.0, 0.13 * k), np.pi / 2, 0.6 * k))[0],
                                    confidence=np.full(17, 0.9))} for k in range(6)}
    placed = tracks_from_ids({"7": frames}, calibs, AssociationConfig(), ground,
                             clouds={k: person + [0.0, 0.13 * k, 0.0] for k in range(6)})
    for k, fr in enumerate(placed[0].frames):
        assert fr.world_p is not None and np.linalg.norm(fr.world_p[:2] - [22.0, 0.13 * k]) < 0.4
    walled = tracks_from_ids({"7": frames}, calibs, AssociationConfig(), ground, clouds={k: wall for k in range(6)})
    assert all(fr.world_p is None for fr in walled[0].frames)
    without_clouds = tracks_from_ids({"7": frames}, calibs, AssociationConfig(), ground)
    assert all(fr.world_p is None for fr in without_clouds[0].frames)


def test_ids_from_the_files_centre_a_stereo_frame_on_the_lidar_as_the_association_does():
    """Detections whose ids come from the files (:func:`tracks_from_ids`), a walker at 22 m seen in both
    images whose right-image keypoints lie 3 px to the right (a calibration's or a detector's bias: the
    disparity short by 3 px, the stereo depth metres long): with the scene clouds holding the walker's
    points, every frame's centre lies on them, as the association's paired frames do (:func:`lidar_centres`),
    and is as sharp; without the clouds it is the stereo one, metres off."""
    from pedx_graph.detections.association import tracks_from_ids

    calibs, calib, ground, _, _ = _someone_at_22m()
    left, right = calib.name.split("-")
    frames = {}
    for k in range(6):
        left_uv, right_uv = calib.project(_person_points((22.0, 0.13 * k), np.pi / 2, 0.6 * k))
        frames[k] = {camera: Detection(camera=camera, frame=k, keypoint_set="coco17", score=0.9,
                                       source=f"{camera}#{k}", image_uv=uv, confidence=np.full(17, 0.9))
                     for camera, uv in ((left, left_uv), (right, right_uv + [3.0, 0.0]))}
    clouds = {k: _lidar_person() + [0.0, 0.13 * k, 0.0] for k in range(6)}
    placed = tracks_from_ids({"7": frames}, calibs, AssociationConfig(), ground, clouds=clouds)
    stereo = tracks_from_ids({"7": frames}, calibs, AssociationConfig(), ground)
    for k, (fr, st) in enumerate(zip(placed[0].frames, stereo[0].frames)):
        assert np.linalg.norm(fr.world_p[:2] - [22.0, 0.13 * k]) < 0.35
        assert fr.depth_sigma_m < 0.5 < np.linalg.norm(st.world_p[:2] - [22.0, 0.13 * k])


def test_one_keypoint_misplaced_in_one_image_does_not_gate_a_stereo_match():
    """A person at 19 m of whom the detector found, in both images, only the head, the shoulders and one
    wrist, the right image's wrist put 0.6 m lower (on the hip): the spans of the shared keypoints differ by a
    factor ~2, but the rows of every other keypoint agree, so the size compares the spans over those — the
    match passes.  The same detections with every keypoint's row off by the same factor (someone else, of
    another size) are still gated."""
    ahead = _person_points((19.0, 0.0), 0.0, 0.0)
    calibs = _rig()
    calib = next(c for c in calibs.values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    config = AssociationConfig()
    left, right = calib.project(ahead)
    seen = np.zeros(len(left), dtype=bool)
    seen[[0, 1, 2, 5, 6, 9]] = True                   # nose, eyes, shoulders, left wrist
    left, right = np.where(seen[:, None], left, np.nan), np.where(seen[:, None], right, np.nan)
    assert stereo_cost(left, right, calib, config, "coco17") < 1e9
    wrong = right.copy()
    wrong[9, 1] += 0.6 * calib.focal_px / 19.0        # the wrist 0.6 m lower in the right image
    assert abs(np.log(np.nanmax(wrong[:, 1]) - np.nanmin(wrong[:, 1]))
               - np.log(np.nanmax(left[:, 1]) - np.nanmin(left[:, 1]))) > config.gate_sigmas * config.size_sigma
    assert stereo_cost(left, wrong, calib, config, "coco17") < 1e9
    taller = right.copy()
    taller[:, 1] = np.nanmean(right[:, 1]) + 2.0 * (right[:, 1] - np.nanmean(right[:, 1]))
    assert stereo_cost(left, taller, calib, config, "coco17") >= 1e9


def test_a_pairing_whose_depth_lifts_the_person_off_the_ground_is_gated():
    """A left detection of someone at 22 m and a right detection of someone else 0.35 m to the side: their
    disparity puts the person at ~13 m, where its feet would float ~0.8 m above the ground.  With the ground
    known the pairing is gated out; the true pairing passes."""
    ahead = _person_points((22.0, 0.0), 0.0, 0.0)
    calibs = _rig()
    calib = next(c for c in calibs.values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    ground = _ground(calibs)
    config = AssociationConfig()
    left, right = calib.project(ahead)
    beside = calib.project(_person_points((22.0, 0.0), 0.0, 0.0) + [0.0, 0.35, 0.0])[1]
    depth = calib.focal_px * calib.baseline_m / float(np.median(left[:, 0] - beside[:, 0]))
    assert 12.0 < depth < 14.0
    assert stereo_cost(left, right, calib, config, "coco17", ground=ground) < 1e9
    assert stereo_cost(left, beside, calib, config, "coco17") < 1e9           # every other term passes
    assert stereo_cost(left, beside, calib, config, "coco17", ground=ground) >= 1e9


def test_a_hidden_persons_cut_on_the_neighbour_in_front_is_not_its_centre():
    """A far person (21 m) hidden from the LiDAR by a near one (20.5 m) just in front, neither detection given
    a cluster of its own (one cluster in both hulls): the far person's cut holds the near one's points,
    inside the near one's hull, so its stereo centre stays (uncertain) rather than moving onto the near
    person with a LiDAR sigma.  Without the other detection to compare with, it moved."""
    from pedx_graph.detections.association import _lidar_centre

    far_points, near_points = _person_points((21.0, 0.0), 0.0, 0.0), _person_points((20.5, 0.1), 0.0, 0.0)
    calibs = _rig()
    calib = next(c for c in calibs.values() if np.all(np.subtract(*c.project(far_points))[:, 0] > 0))
    ground = _ground(calibs)
    angles = np.linspace(np.pi / 2, 3 * np.pi / 2, 9)
    cloud = np.concatenate([np.c_[20.5 + 0.2 * np.cos(angles), 0.1 + 0.2 * np.sin(angles), np.full(9, GROUND_Z + h)]
                            for h in np.arange(0.2, 1.7, 0.3)])
    uv_far, uv_near = calib.project(far_points)[0], calib.project(near_points)[0]
    det = Detection(camera=calib.name.split("-")[0], frame=0, keypoint_set="coco17", image_uv=uv_far,
                    confidence=np.full(len(uv_far), 0.9), score=0.9, source="test")
    stereo = np.array([21.0, 0.0, GROUND_Z + 0.9])
    moved = []
    for others in ({"left": [uv_near]}, None):
        obs = Observation(frame=0, uv={"left": uv_far}, score=0.9, world_p=stereo.copy(), depth_sigma_m=0.8,
                          payload={"left": det})
        _lidar_centre(obs, calib, cloud, ground, AssociationConfig(), {}, {}, {"left": []}, others)
        moved.append(float(np.linalg.norm(obs.world_p[:2] - stereo[:2])))
    assert moved[0] == 0.0 and moved[1] > 0.4


def test_a_person_seen_in_one_image_gets_its_centre_from_its_lidar_cluster():
    """Seen in the left image only (no disparity), a detection whose LiDAR cluster is its own gets a centre
    on its viewing ray at that cluster's range: within a few decimetres of the person, in both images' rays."""
    from pedx_graph.detections.association import _range_centre

    calibs = _rig()
    for side in ("left", "right"):
        for xy in ((21.0, 0.0), (12.0, -2.5)):
            points = _person_points(xy, 0.0, 0.0)
            calib = next(c for c in calibs.values() if np.all(np.subtract(*c.project(points))[:, 0] > 0))
            uv = calib.project(points)[0 if side == "left" else 1]
            det = Detection(camera=calib.name.split("-")[0 if side == "left" else 1], frame=0, keypoint_set="coco17",
                            image_uv=uv, confidence=np.full(len(uv), 0.9), score=0.9, source="test")
            obs = Observation(frame=0, uv={side: uv}, score=0.9, payload={side: det})
            centre = np.array([xy[0], xy[1], GROUND_Z + 0.9])
            _range_centre(obs, calib, {id(det): float(calib.world_to_rect(centre)[2])})
            assert obs.world_p is not None and np.linalg.norm(obs.world_p - centre) < 0.4, (side, xy, obs.world_p)
            other = Observation(frame=0, uv={side: uv}, score=0.9, payload={side: det})
            _range_centre(other, calib, {})                       # no cluster of its own: no centre
            assert other.world_p is None


def test_a_one_image_range_centre_must_agree_with_the_tracks_stereo_depth():
    """In a track with stereo frames, a one-image frame's centre from its detection's LiDAR cluster is kept
    only at a depth the nearest stereo centre allows (its uncertainty plus a walker's reach): a cluster 6 m
    behind (a neighbour, the background) is refused, one 0.3 m off three frames later is kept."""
    from pedx_graph.detections.association import _agrees_with_stereo

    calibs = _rig()
    ahead = _person_points((18.0, 0.0), 0.0, 0.0)
    calib = next(c for c in calibs.values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    stereo = [Observation(frame=k, uv={}, score=0.9, world_p=np.array([18.0 + 0.1 * k, 0.0, GROUND_Z + 0.9]),
                          depth_sigma_m=0.3) for k in range(5)]
    far = Observation(frame=7, uv={}, score=0.9, world_p=np.array([24.5, 0.0, GROUND_Z + 0.9]))
    near = Observation(frame=7, uv={}, score=0.9, world_p=np.array([18.8, 0.0, GROUND_Z + 0.9]))
    config = AssociationConfig()
    assert not _agrees_with_stereo(far, stereo, calib, config)
    assert _agrees_with_stereo(near, stereo, calib, config)
    assert _agrees_with_stereo(far, [], calib, config)          # a track with no stereo frame: nothing to check


def test_centres_off_the_final_tracks_walk_are_taken_back():
    """A walker at ~21 m with sharp LiDAR centres (0.1 m), a loose stereo depth at frame 2 (1 m, 1 m short)
    and a frame paired with someone 1.6 m in front at frame 11 (0.1 m, off the walk).  One-image frames whose
    cluster is someone in front lose their centre: 3.5 m at frames 3-5, though frame 3's nearest stereo
    centre (frame 2) allows it, and 0.75 m at frame 12, which every stereo centre on the walk allows (three
    frames from the nearest) but the walk does not.  The walker's own one-image centres (frames 1, 8, 10,
    13, 14) are kept: the centre off the walk at frame 11 does not count.  A LiDAR centre 1.4 m short at
    frame 17 goes back to the stereo centre it replaced."""
    from pedx_graph.detections.association import _agrees_with_stereo, settle_centres

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(3)
    start, step = np.array([21.8, -1.0]), np.array([-0.13, 0.1])
    track = _walker_observations(calib, start, step, range(20), rng)

    def centre(k, short_m=0.0):
        xy = start + k * step
        return np.array([xy[0] - short_m, xy[1], GROUND_Z + 0.9])

    one_image = {1: 0.0, 3: 3.5, 4: 3.5, 5: 3.5, 8: 0.0, 10: 0.0, 12: 0.75, 13: 0.0, 14: 0.0}
    for obs in track:
        k = obs.frame
        if k in one_image:
            obs.uv, obs.disparity_px = {"left": obs.uv["left"]}, None
            obs.world_p, obs.depth_sigma_m = centre(k, one_image[k] + 0.05 * rng.normal()), 0.1
        else:
            obs.world_p, obs.depth_sigma_m = centre(k, 0.05 * rng.normal()), 0.1
    track[2].world_p, track[2].depth_sigma_m = centre(2, 1.0), 1.0
    track[11].world_p = centre(11, 1.6)
    stereo_17 = centre(17, 0.2)
    track[17].world_p, track[17].fallback = centre(17, 1.4), (stereo_17, np.zeros(3), 0.6)
    config = AssociationConfig()
    stereo = [o for o in track if o.disparity_px is not None]
    assert _agrees_with_stereo(track[3], [track[2]], calib, config)           # the nearest one allows it
    assert _agrees_with_stereo(track[12], [o for o in stereo if o.frame != 11], calib, config)
    settle_centres([track], calib, config)
    assert [o.frame for o in track if o.world_p is None] == [3, 4, 5, 12]
    assert all(o.world_p is not None for o in stereo)                          # stereo frames keep a centre
    assert np.isinf(track[3].depth_sigma_m) and track[3].fallback is None
    assert np.array_equal(track[17].world_p, stereo_17) and track[17].depth_sigma_m == 0.6
    assert track[17].fallback is None
    assert np.allclose(track[11].world_p, centre(11, 1.6))                     # no stereo centre to go back to


def test_a_walk_carried_far_from_its_sharp_centres_does_not_refuse_the_persons_own():
    """A walker going away from ~20 to ~23 m over 20 frames, seen in one image at frames 0-4 with its own
    LiDAR clusters (0.1 m), then in both images at frames 10-19: loose stereo depths (1.5 m) that happen to
    lie short early and long late, and one sharp LiDAR centre at frame 18.  Their straight walk carried
    back to frame 0 by a rate they leave open lies ~1 m short of the clusters; before the walk had a
    sigma of its own, it refused them all.  A one-image centre 1.2 m in front at frame 16, among the frames
    that fix the walk, is still taken back."""
    from pedx_graph.detections.association import _depth_walk, settle_centres

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    rng = np.random.default_rng(5)
    start, step = np.array([20.0, -1.0]), np.array([0.16, 0.05])
    track = _walker_observations(calib, start, step, [k for k in range(20) if not 5 <= k <= 9], rng)

    def centre(k, short_m=0.0):
        xy = start + k * step
        return np.array([xy[0] - short_m, xy[1], GROUND_Z + 0.9])

    for obs in track:
        k = obs.frame
        if k <= 4 or k == 16:
            obs.uv, obs.disparity_px = {"left": obs.uv["left"]}, None
            obs.world_p, obs.depth_sigma_m = centre(k, 1.2 if k == 16 else 0.0), 0.1
        elif k == 18:
            obs.world_p, obs.depth_sigma_m = centre(k), 0.1
        else:
            obs.world_p, obs.depth_sigma_m = centre(k, 0.15 * (14.5 - k)), 1.5     # short early, long late
    config = AssociationConfig()
    stereo = [o for o in track if o.disparity_px is not None]
    depth, sigma = _depth_walk(stereo, calib, config)
    own = float(calib.world_to_rect(centre(0))[2])
    assert abs(depth(0) - own) > config.gate_sigmas * np.hypot(0.1, config.swap_motion_m)   # the old test's limit
    assert sigma(0) > sigma(18)
    settle_centres([track], calib, config)
    assert [o.frame for o in track if o.world_p is None] == [16]
    assert all(np.linalg.norm(o.world_p - centre(o.frame)) < 1e-9 for o in track if o.frame <= 4)


def test_a_cut_on_a_neighbour_that_puts_two_people_in_one_place_is_taken_back():
    """A far walker (21.5 m) whose images give only uncertain stereo depths (1 m) and one frame whose LiDAR
    centre held the walker 0.75 m in front (a confident 0.1 m centre on the neighbour): smoothed, the two
    would stand within a few centimetres of each other at that frame.  That centre is taken back and the far
    walker's smoothed centres stay on its own line, while the neighbour keeps every LiDAR centre of its
    own; with the separation test off the confident centre draws the far walker onto the neighbour."""
    from pedx_graph.detections.association import DetectedTrackFrame, separate_people

    ground = _ground(_rig())
    rng = np.random.default_rng(4)
    frames = range(11)

    def people(config):
        far, near = [], []
        far_sources, near_sources = {}, {}
        for k in frames:
            y = -1.0 + 0.15 * k
            stereo = np.array([21.5 + 0.8 * rng.standard_normal(), y, GROUND_Z + 0.9])
            obs = Observation(frame=k, uv={}, score=0.9, world_p=stereo, depth_sigma_m=1.0)
            if k == 5:
                obs.fallback = (obs.world_p, None, obs.depth_sigma_m)
                obs.world_p, obs.depth_sigma_m = np.array([20.8, y - 0.05, GROUND_Z + 0.9]), 0.1
            far_sources[k] = [obs]
            lidar = Observation(frame=k, uv={}, score=0.9, world_p=np.array([20.75, y, GROUND_Z + 0.9]),
                                depth_sigma_m=0.1)
            lidar.fallback = (np.array([21.0, y, GROUND_Z + 0.9]), None, 1.0)
            near_sources[k] = [lidar]                          # the neighbour's centres: from the LiDAR too
            far.append(DetectedTrackFrame(frame=k, detections={}))
            near.append(DetectedTrackFrame(frame=k, detections={}))
        separate_people([(far, far_sources), (near, near_sources)], ground, config)
        gap = np.linalg.norm(far[5].world_p[:2] - near[5].world_p[:2])        # at the frame of the cut
        return far, far_sources, near_sources, gap

    far, sources, near_sources, gap = people(AssociationConfig())
    assert gap > 0.35
    assert sources[5][0].fallback is None and sources[5][0].depth_sigma_m == 1.0
    assert max(abs(fr.world_p[0] - 21.5) for fr in far) < 0.5
    # the neighbour's own LiDAR centres lie on its own track: all kept
    assert all(obs[0].fallback is not None and obs[0].depth_sigma_m == 0.1 for obs in near_sources.values())
    _, _, _, gap_off = people(AssociationConfig(min_separation_m=0.0))
    assert gap_off < 0.35


def test_a_frame_where_one_pair_saw_someone_else_loses_that_pairs_detections():
    """A walker seen by both pairs over 10 frames (centres 0.1 m uncertain in depth); at frame 6 one pair's
    track went on with a neighbour 1.2 m behind.  That pair's detections leave frame 6, the other pair's
    stay, every other frame keeps both pairs; a 0.1 m disagreement (noise) changes nothing."""
    from pedx_graph.detections.association import DetectedTrackFrame, drop_conflicting_pairs

    calibs = _rig()
    ground = _ground(calibs)
    pairs = sorted(calibs)

    def person(offset_m):
        frames, sources, pair_of = {}, {}, {}
        for k in range(10):
            walker = np.array([12.0, -2.0 + 0.14 * k, GROUND_Z + 0.9])
            entry = DetectedTrackFrame(frame=k, detections={})
            sources[k] = []
            for pair in pairs:
                centre = walker + ([offset_m, 0.0, 0.0] if (k == 6 and pair == pairs[1]) else 0.0)
                obs = Observation(frame=k, uv={"left": np.zeros((17, 2)), "right": np.zeros((17, 2))}, score=0.9,
                                  payload={"left": f"{pair}/L/{k}", "right": f"{pair}/R/{k}"}, world_p=centre,
                                  depth_sigma_m=0.1, world_p_camera=calibs[pair].camera_centre("left"))
                for side, camera in zip(("left", "right"), pair.split("-")):
                    entry.detections[camera] = obs.payload[side]
                sources[k].append(obs)
                pair_of[id(obs)] = pair
            frames[k] = entry
        drop_conflicting_pairs(frames, sources, pair_of, ground, AssociationConfig(), calibs)
        return frames, sources

    frames, sources = person(1.2)
    assert sorted(frames[6].detections) == sorted(pairs[0].split("-"))
    assert [pair for pair in pairs if any(o.payload["left"].startswith(pair) for o in sources[6])] == [pairs[0]]
    assert all(len(frames[k].detections) == 4 and len(sources[k]) == 2 for k in range(10) if k != 6)
    frames, sources = person(0.1)
    assert all(len(frames[k].detections) == 4 for k in range(10))


def test_box_cover_and_iou():
    """A box inside another covers it fully (cover 1) while their IoU is the area ratio; disjoint boxes 0;
    a degenerate box 0."""
    from pedx_graph.detections.tracker import box_cover, box_iou

    outer, inner = np.array([0.0, 0.0, 10.0, 20.0]), np.array([2.0, 2.0, 7.0, 12.0])
    assert box_cover(outer, inner) == pytest.approx(1.0)
    assert box_iou(outer, inner) == pytest.approx(50.0 / 200.0)
    half = np.array([5.0, 0.0, 15.0, 20.0])
    assert box_cover(outer, half) == pytest.approx(0.5)
    assert box_cover(outer, np.array([20.0, 0.0, 30.0, 5.0])) == 0.0
    assert box_cover(outer, np.array([3.0, 3.0, 3.0, 9.0])) == 0.0


def test_a_cut_on_a_neighbour_at_a_frame_the_neighbours_track_lacks_is_taken_back_first():
    """Two walkers in line, 1 m apart in depth (20 m and 21 m), seen by stereo only (1 m depth sigmas).
    The near one has one LiDAR centre of its own (frame 2) and no frame 4: there its detection went to the
    far walker's track, whose frame 4 holds a confident LiDAR centre on the near walker.  The near walker's
    track runs on through frame 4 (between its frames 3 and 5), so that centre is the neighbour's and is
    taken back, and the far walker's track stays on its own line.  The near walker keeps its own LiDAR
    centre: judged against the far walker's track as it was before (drawn onto the near walker) it would
    be taken back too, so one centre is taken back per round, the clearest first, and the rest are judged
    against the tracks as they are then.  Compared only at frames both tracks hold, the far walker's wrong
    centre stays and draws its track onto the near walker."""
    from pedx_graph.detections.association import DetectedTrackFrame, separate_people

    ground = _ground(_rig())
    rng = np.random.default_rng(3)
    near_frames, far_frames = [], []
    near_sources, far_sources = {}, {}
    for k in range(9):
        y = -1.0 + 0.15 * k
        far_obs = Observation(frame=k, uv={}, score=0.9, depth_sigma_m=1.0,
                              world_p=np.array([21.0 + 0.5 * rng.standard_normal(), y, GROUND_Z + 0.9]))
        if k == 4:                                  # the near walker's points, as the far walker's centre
            far_obs.fallback = (far_obs.world_p, None, far_obs.depth_sigma_m)
            far_obs.world_p, far_obs.depth_sigma_m = np.array([20.0, y, GROUND_Z + 0.9]), 0.1
        far_sources[k] = [far_obs]
        far_frames.append(DetectedTrackFrame(frame=k, detections={}))
        if k == 4:
            continue
        near_obs = Observation(frame=k, uv={}, score=0.9, depth_sigma_m=1.0,
                               world_p=np.array([20.0 + 0.5 * rng.standard_normal(), y, GROUND_Z + 0.9]))
        if k == 2:                                  # the near walker's own LiDAR centre
            near_obs.fallback = (near_obs.world_p, None, near_obs.depth_sigma_m)
            near_obs.world_p, near_obs.depth_sigma_m = np.array([20.0, y, GROUND_Z + 0.9]), 0.1
        near_sources[k] = [near_obs]
        near_frames.append(DetectedTrackFrame(frame=k, detections={}))
    separate_people([(near_frames, near_sources), (far_frames, far_sources)], ground, AssociationConfig())
    assert far_sources[4][0].fallback is None and far_sources[4][0].depth_sigma_m == 1.0
    assert max(abs(fr.world_p[0] - 21.0) for fr in far_frames) < 0.5
    assert near_sources[2][0].fallback is not None and near_sources[2][0].depth_sigma_m == 0.1


def test_a_stereo_centres_sigma_holds_the_keypoint_noise_at_the_persons_size():
    """A walker at 20 m whose 17 keypoints carry detector noise growing with its image height (per axis and
    image ``3 px + 1.5 %`` of the height, the association's own model): the depth of
    :func:`triangulate_centre` lies within three of its claimed sigmas in every one of 400 draws (at most two
    allowed).  A few disparities that happen to agree (a small robust spread) no longer make a depth
    precise: floored at the size-independent part of the noise alone, 7 of the 400 lay beyond.  Without
    noise (every disparity the same) the sigma is that floor exactly."""
    from pedx_graph.detections.association import triangulate_centre

    calibs = _rig()
    calib = next(iter(calibs.values()))
    ground = _ground(calibs)
    config = AssociationConfig()
    rng = np.random.default_rng(11)
    camera = calib.camera_centre("left")
    # a walker 20 m along the pair's optical axis, a little to the side
    axis = calib.rect_to_world(np.array([[0.0, 0.0, 20.0]]))[0] - camera
    ahead = camera[:2] + axis[:2] / np.linalg.norm(axis[:2]) * 20.0
    left_uv, right_uv = calib.project(_person_points(ahead, 0.0, 0.0))
    _, clean_sigma = triangulate_centre(left_uv, right_uv, calib, ground, config)
    sigma_px = config.keypoint_sigma_px + config.keypoint_sigma_frac * max(np.ptp(left_uv[:, 1]),
                                                                           np.ptp(right_uv[:, 1]))
    depth = calib.focal_px * calib.baseline_m / float(np.median(left_uv[:, 0] - right_uv[:, 0]))
    assert clean_sigma == pytest.approx(depth ** 2 / (calib.focal_px * calib.baseline_m) * 1.2533 * np.sqrt(2.0)
                                        * sigma_px / np.sqrt(len(left_uv)), rel=1e-6)
    outside = 0
    for k in range(400):
        xy = ahead + rng.uniform(-2.0, 2.0, 2)
        world_p = _person_points(xy, rng.uniform(0.0, 2 * np.pi), rng.uniform(0.0, 2 * np.pi))
        left_uv, right_uv = calib.project(world_p)
        height = float(np.ptp(left_uv[:, 1]))
        sigma_px = config.keypoint_sigma_px + config.keypoint_sigma_frac * height
        noisy_l = left_uv + sigma_px * rng.standard_normal(left_uv.shape)
        noisy_r = right_uv + sigma_px * rng.standard_normal(right_uv.shape)
        centre, sigma = triangulate_centre(noisy_l, noisy_r, calib, ground, config)
        true_depth = float(np.median(calib.world_to_rect(world_p)[:, 2]))
        outside += abs(float(calib.world_to_rect(centre)[2]) - true_depth) > 3.0 * sigma
    assert outside <= 2


def _side_by_side_people(stray_frames, pair1_keeps_second, pair0_keeps_first=lambda k: True, apart_m=0.55):
    """Two walkers side by side at 12 m and 12 m + ``apart_m`` (LiDAR centres 0.1 m uncertain, 2 cm noise), both seen
    by both pairs over 15 frames and merged: the first person holds pair 0's and pair 1's tracks of the
    near walker, except that pair 1's track holds the far walker at ``stray_frames``; the second person
    holds pair 0's track of the far walker and pair 1's only where ``pair1_keeps_second`` (its own track
    lost elsewhere); pair 0's track of the near walker holds the frames ``pair0_keeps_first`` keeps."""
    from pedx_graph.detections.association import DetectedTrackFrame

    calibs = _rig()
    pairs = sorted(calibs)
    rng = np.random.default_rng(5)
    people, pair_of, track_of = [], {}, {}
    for person in range(2):
        frames, sources = {}, {}
        for k in range(15):
            entry = DetectedTrackFrame(frame=k, detections={})
            sources[k] = []
            for index, pair in enumerate(pairs):
                if person == 1 and index == 1 and not pair1_keeps_second(k) or \
                        person == 0 and index == 0 and not pair0_keeps_first(k):
                    continue
                walker = person if not (person == 0 and index == 1 and k in stray_frames) else 1
                centre = np.array([12.0 + apart_m * walker, -2.0 + 0.14 * k, GROUND_Z + 0.9])
                obs = Observation(frame=k, uv={}, score=0.9, depth_sigma_m=0.1,
                                  world_p=centre + 0.02 * rng.standard_normal(3),
                                  world_p_camera=calibs[pair].camera_centre("left"),
                                  payload={"left": f"{pair}/{walker}/L/{k}", "right": f"{pair}/{walker}/R/{k}"})
                for side, camera in zip(("left", "right"), pair.split("-")):
                    entry.detections[camera] = obs.payload[side]
                sources[k].append(obs)
                pair_of[id(obs)], track_of[id(obs)] = pair, 2 * person + index
            frames[k] = entry
        people.append((frames, sources))
    return people, pair_of, track_of, calibs


def test_a_stretch_of_one_pairs_track_on_the_walker_alongside_moves_to_that_walker():
    """Two walkers side by side, 0.55 m apart along the rays: pair 1's track of the near one went on with the
    far one for frames 5-10 (the far one's own track in pair 1 lost there) and was merged with the near one
    on its other frames.  Each of those frames lies only about 2.5 sigmas off the near walker's walk, but
    six of them together are clear: they move to the far walker, who had no pair 1 detection there, and the
    near walker keeps pair 0's.  One such frame alone stays (too little evidence), even 1.5 m off (one
    centre gone wrong is not a track gone on with someone else); a stretch where the far
    walker holds its own pair 1 detections does not move (one detection per camera per person); nor does one
    past the last frame pair 0 saw the near walker (no walk to judge it by: the smoothed line carried on is
    not one)."""
    from pedx_graph.detections.association import move_to_neighbours

    stray = set(range(5, 11))
    people, pair_of, track_of, calibs = _side_by_side_people(stray, lambda k: k < 5)
    ground = _ground(calibs)
    moved = move_to_neighbours(people, pair_of, track_of, ground, AssociationConfig(), calibs)
    assert moved == 1
    (near, near_sources), (far, far_sources) = people
    for k in range(15):
        assert sorted({d.split("/")[1] for d in near[k].detections.values()}) == ["0"]
        assert len(near[k].detections) == (2 if k in stray else 4)
        assert len(far[k].detections) == (4 if k in stray or k < 5 else 2)
        assert {d.split("/")[1] for d in far[k].detections.values()} == {"1"}
        assert len(far_sources[k]) == len(far[k].detections) // 2
    for apart_m in (0.55, 1.5):
        people, pair_of, track_of, calibs = _side_by_side_people({7}, lambda k: k < 5, apart_m=apart_m)
        assert move_to_neighbours(people, pair_of, track_of, ground, AssociationConfig(), calibs) == 0
    people, pair_of, track_of, calibs = _side_by_side_people(stray, lambda k: True)
    assert move_to_neighbours(people, pair_of, track_of, ground, AssociationConfig(), calibs) == 0
    people, pair_of, track_of, calibs = _side_by_side_people(set(range(9, 15)), lambda k: k < 9, lambda k: k < 9)
    assert move_to_neighbours(people, pair_of, track_of, ground, AssociationConfig(), calibs) == 0


def _one_image(obs: Observation, side: str = "left") -> Observation:
    """``obs`` as seen in the ``side`` image only (no disparity, no centre)."""
    return Observation(frame=obs.frame, uv={side: obs.uv[side]}, score=obs.score, payload={side: obs.payload[side]})


def _crossing_at_20_and_22_m():
    """The camera looking at +x and, per seed 0-9, two walkers of one height crossing at 20 and 22 m in
    opposite directions, in one image column at frame 10 (pair-track observations of frames 0-19)."""
    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    for seed in range(10):
        rng = np.random.default_rng(seed)
        near = _walker_of_height(calib, (20.0, -1.4), (0.0, 0.14), range(20), rng, 1.0)
        far = _walker_of_height(calib, (22.0, 1.4 * 22.0 / 20.0), (0.0, -0.14 * 22.0 / 20.0), range(20), rng, 1.0)
        yield calib, near, far


def test_a_one_image_track_end_another_track_explains_as_well_is_left_out():
    """Two people of one height crossing at 20 and 22 m in opposite directions, in one image column at frame
    10.  The near one's track ends at frame 9; its tracker carried it on to frame 10 with the far one's
    detection in the left image only (no depth), where the far one's own track holds only the right image's.
    The far one's walk (smaller in the image) explains that detection at least as well as the near one's:
    it is left out.  The near one's own left detection there is kept (its walk explains it better), and so
    is the far one's when the far track holds its own left detection at frame 10 (no rival lacks it)."""
    from pedx_graph.detections.association import drop_ambiguous_frames

    kept_own = left_out = 0
    for calib, near, far in _crossing_at_20_and_22_m():
        far_track = [_one_image(far[10], "right")] + far[11:]
        out = drop_ambiguous_frames([near[:10] + [_one_image(far[10])], far_track], calib, AssociationConfig())
        left_out += [[id(o) for o in t] for t in out] == [[id(o) for o in near[:10]], [id(o) for o in far_track]]
        tail = _one_image(near[10])
        out = drop_ambiguous_frames([near[:10] + [tail], far_track], calib, AssociationConfig())
        kept_own += [[id(o) for o in t] for t in out] == [[id(o) for o in near[:10] + [tail]],
                                                           [id(o) for o in far_track]]
        held = drop_ambiguous_frames([near[:10] + [_one_image(far[10])], far[10:]], calib, AssociationConfig())
        assert [len(t) for t in held] == [11, 10]
    assert left_out >= 9 and kept_own >= 9


def test_a_one_image_frame_between_stereo_frames_another_track_explains_as_well_is_left_out():
    """The same two people crossing at 20 and 22 m, in one image column at frame 10, but the near one's track
    goes on, seen in both images, over frames 11-14: at frame 10, where its own person was missed in the
    left image, the tracker gave it the far one's left detection (no depth).  The far one's track spans the
    frame and lacks that image there, and its walk explains the detection at least as well: the frame is
    left out though it lies between frames seen in both images.  Kept: the near one's own left detection
    there (its walk explains it better), and the far one's when the far track holds its own left detection
    at frame 10 (no rival lacks it)."""
    from pedx_graph.detections.association import drop_ambiguous_frames

    config = AssociationConfig()

    def ids(tracks):
        return [[id(o) for o in t] for t in tracks]

    kept_own = left_out = 0
    for calib, near, far in _crossing_at_20_and_22_m():
        far_track = [_one_image(far[10], "right")] + far[11:]
        taken = near[:10] + [_one_image(far[10])] + near[11:15]
        left_out += ids(drop_ambiguous_frames([taken, far_track], calib, config)) == \
            ids([near[:10] + near[11:15], far_track])
        own = near[:10] + [_one_image(near[10])] + near[11:15]
        kept_own += ids(drop_ambiguous_frames([own, far_track], calib, config)) == ids([own, far_track])
        held = drop_ambiguous_frames([taken, far[10:]], calib, config)
        assert [len(t) for t in held] == [15, 10]
    assert left_out >= 9 and kept_own >= 9


def test_a_one_image_track_end_its_own_walk_refuses_is_left_out_even_with_a_centre():
    """A walker at 20 m crossing the view, seen in both images over frames 0-9.  The track's last frames
    hold, in the left image only, the detections of someone 1.5 m beside it (the tracker carried it on to
    them), each with a centre (a LiDAR cluster along that detection's ray): the track's own walk misses
    them by far more than the gate, so they are left out from the end inwards, with no other track to
    explain them.  The walker's own one-image tail frames are kept (its walk explains them), and so is an
    off-walk one-image frame between two frames seen in both images (not an end), and an own tail frame
    whose one-image centre is far off the walk's depth (its detection is judged, not that centre)."""
    from pedx_graph.detections.association import drop_ambiguous_frames, off_walk_ends

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    config = AssociationConfig()
    left_out = kept_own = kept_middle = kept_deep = 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        walker = _walker_of_height(calib, (20.0, -1.4), (0.0, 0.14), range(14), rng, 1.0)
        beside = _walker_of_height(calib, (20.0, 0.1), (0.0, 0.14), range(14), rng, 1.0)

        def centred(obs):
            obs = _one_image(obs)
            obs.world_p, obs.depth_sigma_m = np.array([20.0, 0.0, 0.0]), 0.2
            return obs

        stray = [centred(beside[10]), centred(beside[12])]            # a gap at 11: ends are judged alike
        out = drop_ambiguous_frames([walker[:10] + stray], calib, config)
        left_out += [[id(o) for o in t] for t in out] == [[id(o) for o in walker[:10]]]
        own = [centred(walker[10]), centred(walker[12])]
        out = off_walk_ends(walker[:10] + own, calib, config)
        kept_own += [id(o) for o in out] == [id(o) for o in walker[:10] + own]
        middle = walker[:5] + [centred(beside[5])] + walker[6:10]
        kept_middle += [id(o) for o in off_walk_ends(middle, calib, config)] == [id(o) for o in middle]
        head = [centred(beside[0])] + walker[1:10]
        assert [id(o) for o in off_walk_ends(head, calib, config)] == [id(o) for o in walker[1:10]]
        # Its detection is judged, not its centre's depth: with a LiDAR centre on every frame seen in both
        # images (the walk has a depth line), the walker's own tail frame whose one-image centre is 3 m
        # too deep (someone behind on that ray) is kept.
        for k, obs in enumerate(walker[:10]):
            obs.world_p, obs.depth_sigma_m = np.array([20.0, -1.4 + 0.14 * k, GROUND_Z + 0.9]), 0.1
        deep = _one_image(walker[10])
        deep.world_p, deep.depth_sigma_m = np.array([23.0, -1.4 + 0.14 * 10, GROUND_Z + 0.9]), 0.1
        kept_deep += [id(o) for o in off_walk_ends(walker[:10] + [deep], calib, config)] == \
            [id(o) for o in walker[:10] + [deep]]
    assert left_out >= 9 and kept_own >= 9 and kept_middle == 10 and kept_deep >= 9


def test_a_short_piece_a_gap_parts_from_a_pair_track_is_left_out_when_the_rest_s_walk_refuses_it():
    """A walker at 20 m crossing the view, seen in both images over frames 4-15.  The track begins with two
    frames, also seen in both images, of someone 1.5 m beside it, then holds nothing for frames 2-3 (the
    per-camera trackers coasted across the gap onto the walker): the walk of the rest misses both frames
    by far more than the gate, so the piece is left out, and so are two such frames after a gap at the
    track's other end (through :func:`drop_ambiguous_frames`).  Kept: the walker's own first frames across
    that gap; someone else's frames across a single missed frame (a detector's miss, not a gap); and a
    piece of four frames (long enough for a walk of its own, not judged here)."""
    from pedx_graph.detections.association import drop_ambiguous_frames, off_walk_pieces

    ahead = _person_points((21.0, 0.0), 0.0, 0.0)
    calib = next(c for c in _rig().values() if np.all(np.subtract(*c.project(ahead))[:, 0] > 0))   # looks at +x
    config = AssociationConfig()

    def ids(track):
        return [id(o) for o in track]

    left_out = tail_left_out = kept_own = 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        walker = _walker_of_height(calib, (20.0, -1.4), (0.0, 0.14), range(20), rng, 1.0)
        beside = _walker_of_height(calib, (20.0, 0.1), (0.0, 0.14), range(20), rng, 1.0)
        left_out += ids(off_walk_pieces(beside[:2] + walker[4:16], calib, config)) == ids(walker[4:16])
        out = drop_ambiguous_frames([walker[4:14] + beside[16:18]], calib, config)
        tail_left_out += [ids(t) for t in out] == [ids(walker[4:14])]
        kept_own += ids(off_walk_pieces(walker[:2] + walker[4:16], calib, config)) == ids(walker[:2] + walker[4:16])
        across_a_miss = beside[:3] + walker[4:16]
        assert ids(off_walk_pieces(across_a_miss, calib, config)) == ids(across_a_miss)
        four = beside[:4] + walker[6:16]
        assert ids(off_walk_pieces(four, calib, config)) == ids(four)
    assert left_out >= 9 and tail_left_out >= 9 and kept_own >= 9


def _image_person(centre_u: float, frame: int, name: str) -> tuple[Detection, np.ndarray]:
    """One detection of a standing person in one rectified image: the stick's 17 points seen from the front,
    120 px per metre, its centre column ``centre_u``; source ``<name><frame>``."""
    uv = np.stack([centre_u + 120.0 * STICK[:, 0], 600.0 - 120.0 * STICK[:, 2]], axis=1)
    det = Detection(camera="ylw79D0", frame=frame, keypoint_set="coco17", image_uv=uv, confidence=np.full(17, 0.8),
                    score=0.8, source=f"{name}{frame}")
    return det, uv


def test_a_tracklet_begun_by_a_guess_takes_the_link_the_backward_pass_makes_with_the_person_known():
    """Two people in one image: A walks right from column 100 (6 px per frame), B appears beside it at frame 1
    and walks left.  The forward tracker's tracklet born on A at frame 0 has no velocity yet and takes B, the
    nearer detection at frame 1 (A's own starts a second tracklet).  With ``backward_birth_frames`` the
    tracker also runs backwards; its A tracklet reaches frame 0 with A's motion known, 7 detections behind
    it, and that link replaces the guess: one tracklet per person.  Asking for more than the 7 the backward
    pass knew leaves the guess."""
    from pedx_graph.detections.association import camera_tracklets

    per_frame = {0: [_image_person(100.0, 0, "a")]}
    for k in range(1, 8):
        per_frame[k] = [_image_person(100.0 + 6 * k, k, "a"), _image_person(98.0 - 6 * (k - 1), k, "b")]

    def people(backward_birth_frames: int) -> list[str]:
        config = dataclasses.replace(AssociationConfig(), backward_birth_frames=backward_birth_frames)
        tracklets = camera_tracklets(per_frame, config)
        held = [det.source for tracklet in tracklets for _, det, _ in tracklet]
        assert sorted(held) == sorted(det.source for items in per_frame.values() for det, _ in items)
        assert all([f for f, _, _ in t] == sorted(f for f, _, _ in t) for t in tracklets)
        return sorted("".join(sorted({det.source[0] for _, det, _ in t})) + str(len(t)) for t in tracklets)

    assert people(0) == ["a7", "ab8"]                    # the guess: A's first detection, then B's
    assert people(3) == people(7) == ["a8", "b7"]
    assert people(8) == ["a7", "ab8"]


def test_a_fragment_scored_above_its_person_gives_way_to_the_whole_detection():
    """One image, a person 400 px tall (240 px per metre): a fragment of it (its hips and legs alone, shifted
    by 4 % of its height) scored above it is dropped and the whole detection kept; a copy of the person with
    3 px of noise, scored above it, is kept in its place (the lower score of two whole detections goes); the
    legs a fifth of a height aside are someone else's and stay.  Two partial detections overlapping, neither
    within the other (an upper body to the knees and the legs; someone with the legs hidden beside someone
    whole but for the head), keep the higher score."""
    from pedx_graph.detections.association import drop_duplicates

    rng = np.random.default_rng(3)
    front = np.stack([240.0 * STICK[:, 0], -240.0 * STICK[:, 2]], axis=1) + [1000.0, 900.0]
    legs = np.where((np.arange(17) >= 11)[:, None], front + [12.0, 10.0], np.nan)
    upper = np.where((np.arange(17) <= 14)[:, None], front + [-8.0, 6.0], np.nan)

    def kept(*named) -> list[str]:
        items = [(Detection(camera="ylw79D0", frame=0, keypoint_set="coco17", image_uv=uv,
                            confidence=np.full(17, score), score=score, source=name), uv)
                 for name, uv, score in named]
        return [det.source for det, _ in drop_duplicates(items, AssociationConfig())]

    assert kept(("front", front, 0.7), ("legs", legs, 0.8)) == ["front"]
    assert kept(("front", front, 0.8), ("legs", legs, 0.7)) == ["front"]
    assert kept(("front", front, 0.8), ("again", front + rng.normal(0.0, 3.0, front.shape), 0.9)) == ["again"]
    assert kept(("front", front, 0.7), ("legs", legs + [80.0, 0.0], 0.8)) == ["front", "legs"]
    assert kept(("upper", upper, 0.7), ("legs", legs, 0.8)) == ["legs"]
    assert kept(("upper", upper, 0.8), ("legs", legs, 0.7)) == ["upper"]
    assert kept(("upper", upper, 0.6), ("front", front, 0.7), ("legs", legs, 0.8)) == ["front"]
    headless = np.where((np.arange(17) >= 5)[:, None], front + [-10.0, 8.0], np.nan)
    assert kept(("upper", upper, 0.8), ("headless", headless, 0.7)) == ["upper"]
    assert kept(("upper", upper, 0.7), ("headless", headless, 0.8)) == ["headless"]


def test_a_wall_seen_through_a_walker_the_lidar_misses_does_not_place_its_stereo_frames():
    """A walker at 22 m seen in both images whose own points the LiDAR misses, in front of a building's wall
    2.5 m behind: the wall's cluster is each detection's range (:func:`detection_ranges`, it still tells
    people apart) but goes on past the hull, so no frame's centre is slid to the wall's range with the
    range's sharp sigma: each keeps its stereo centre (at the walker, within its own uncertainty)."""
    from pedx_graph.detections.association import tracks_from_ids

    calibs, calib, ground, _, _ = _someone_at_22m()
    rng = np.random.default_rng(3)
    frames = {}
    for k in range(6):
        dets = _detections(calib, _person_points((22.0, 0.13 * k), np.pi / 2, 0.6 * k), k, rng, noise_px=0.5,
                           score=0.9)
        frames[k] = {det.camera: det for det in dets}
    config = AssociationConfig()
    walled = tracks_from_ids({"7": frames}, calibs, config, ground, clouds={k: _facade() for k in range(6)})
    for k, fr in enumerate(walled[0].frames):
        error = float(np.linalg.norm(fr.world_p[:2] - [22.0, 0.13 * k]))
        assert error < max(3.0 * fr.depth_sigma_m, 0.5), (k, error, fr.depth_sigma_m)
