"""LiDAR cuts of detections: the hull frustum and the depth gate keep the person's points and drop the wall
behind, the car in front and the ground at the feet; segments land in the release layout."""
from __future__ import annotations

import numpy as np

from pedx_graph.data.ground import make_ground_frame
from pedx_graph.data.ply import read_ply_points
from pedx_graph.data.reader import segment_path
from pedx_graph.detections.association import DetectedTrack, DetectedTrackFrame
from pedx_graph.detections.lidar_cut import LidarCutConfig, cut_indices, hull_polygon, write_track_segments
from pedx_graph.detections.types import Detection
from pedx_graph.sim.cameras import make_calibration
from pedx_graph.sim.config import SimConfig
from test_association import GROUND_Z, _person_points

UP = np.array([0.0, 0.0, 1.0])


def _scene(rng):
    """A person at 12 m, a wall at 15 m behind it, a low box 3 m in front of it, the ground (sim frame)."""
    stick = _person_points((12.0, 0.0), np.pi / 2, 0.0)
    limbs = [(5, 7), (7, 9), (6, 8), (8, 10), (11, 13), (13, 15), (12, 14), (14, 16), (5, 11), (6, 12), (5, 12),
             (6, 11), (0, 5), (0, 6)]
    pick = rng.integers(len(limbs), size=400)
    along = rng.random((400, 1))
    person = (stick[[limbs[i][0] for i in pick]] * (1 - along) + stick[[limbs[i][1] for i in pick]] * along
              + 0.03 * rng.normal(size=(400, 3)))
    wall = np.column_stack([np.full(600, 15.0), rng.uniform(-3, 3, 600), rng.uniform(GROUND_Z, GROUND_Z + 4, 600)])
    car = np.column_stack([rng.uniform(8.8, 9.2, 200), rng.uniform(-0.5, 0.5, 200),
                           rng.uniform(GROUND_Z, GROUND_Z + 0.6, 200)])
    ground = np.column_stack([rng.uniform(10, 14, 800), rng.uniform(-1, 1, 800), np.full(800, GROUND_Z)])
    inf = np.full((5, 3), np.inf)
    cloud = np.concatenate([person, wall, car, ground, inf])
    labels = np.repeat(["person", "wall", "car", "ground", "inf"], [400, 600, 200, 800, 5])
    return cloud, labels


def _detection(calib):
    uv = calib.project(_person_points((12.0, 0.0), np.pi / 2, 0.0))[0]
    return uv, Detection(camera=calib.name.split("-")[0], frame=3, keypoint_set="coco17", image_uv=uv,
                         confidence=np.full(17, 0.9), score=0.9, source="test#0")


def test_cut_keeps_the_person_only():
    calib = make_calibration(SimConfig().cameras.forward)
    rng = np.random.default_rng(0)
    cloud, labels = _scene(rng)
    uv, _ = _detection(calib)
    ground = make_ground_frame(UP, (1, 0, 0), np.zeros(3), GROUND_Z, source="config")
    config = LidarCutConfig()
    depth = float(calib.world_to_rect(np.array([12.0, 0.0, GROUND_Z + 1.0]))[2])
    with_depth = labels[cut_indices(uv, calib, "left", cloud, ground, config, depth_m=depth)]
    assert (with_depth == "person").mean() > 0.97 and (with_depth == "person").sum() > 250
    # without a depth: the nearest dense cluster of the frustum (never the wall behind, never the ground)
    nearest = labels[cut_indices(uv, calib, "left", cloud, ground, config)]
    assert not np.isin(nearest, ["wall", "ground", "inf"]).any()
    # the ground height unknown: ground points at the feet stay in (nothing to remove them by)
    unknown = make_ground_frame(UP, (1, 0, 0), np.zeros(3), None, source="calibration")
    kept = labels[cut_indices(uv, calib, "left", cloud, unknown, config, depth_m=depth)]
    assert (kept == "ground").sum() > 0 and (with_depth == "ground").sum() == 0


def test_an_uncertain_depth_widens_the_gate():
    """A stereo centre 1.6 m in front of the person (a far person's disparity is a few pixels of noise away),
    uncertain by 0.7 m: the fixed gates hold none of the person's points; widened to ``depth_gate_sigmas``
    of that uncertainty they hold the person and nothing else (the wall 3 m behind stays out).  A precise
    depth keeps the fixed gates."""
    calib = make_calibration(SimConfig().cameras.forward)
    cloud, labels = _scene(np.random.default_rng(2))
    uv, _ = _detection(calib)
    ground = make_ground_frame(UP, (1, 0, 0), np.zeros(3), GROUND_Z, source="config")
    config = LidarCutConfig()
    depth = float(calib.world_to_rect(np.array([12.0, 0.0, GROUND_Z + 1.0]))[2])
    assert len(cut_indices(uv, calib, "left", cloud, ground, config, depth_m=depth - 1.6)) == 0
    widened = labels[cut_indices(uv, calib, "left", cloud, ground, config, depth_m=depth - 1.6,
                                 depth_sigma_m=0.7)]
    assert (widened == "person").mean() > 0.97 and (widened == "person").sum() > 250
    precise = cut_indices(uv, calib, "left", cloud, ground, config, depth_m=depth - 0.3, depth_sigma_m=0.05)
    np.testing.assert_array_equal(precise, cut_indices(uv, calib, "left", cloud, ground, config,
                                                       depth_m=depth - 0.3))


def test_hull_grows_with_the_person():
    config = LidarCutConfig(dilate_frac=0.1, dilate_px=0.0)
    uv = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 100.0], [0.0, 100.0], [np.nan, np.nan]])
    hull = hull_polygon(uv, config)
    assert hull.min(axis=0)[1] < -5 and hull.max(axis=0)[1] > 105
    assert hull_polygon(uv[:2], config) is None            # two keypoints: no hull


def test_segments_in_the_release_layout(tmp_path):
    calib = make_calibration(SimConfig().cameras.forward)
    rng = np.random.default_rng(1)
    cloud, labels = _scene(rng)
    _, det = _detection(calib)
    frame = DetectedTrackFrame(frame=3, detections={det.camera: det}, world_p=np.array([12.0, 0.0, GROUND_Z + 0.9]))
    track = DetectedTrack(track_id="det000001", frames=[frame], pairs=(calib.name,))
    ground = make_ground_frame(UP, (1, 0, 0), np.zeros(3), GROUND_Z, source="config")
    counts = write_track_segments(tmp_path, "20991231T1200", [track], {calib.name: calib}, ground,
                                  lambda f: cloud)
    assert counts["segments"] == 1
    points = read_ply_points(segment_path(tmp_path, "20991231T1200", 3, "det000001"))
    person = cloud[labels == "person"]
    assert len(points) > 250
    assert np.all((points[:, 0] > 11.5) & (points[:, 0] < 12.5))      # none from the wall or the car
    assert np.all(points[:, 2] > GROUND_Z + 0.05)                       # none from the ground
    assert len(points) <= len(person)
    # a frame whose cloud cannot be read costs its segments only
    counts = write_track_segments(tmp_path / "b", "20991231T1200", [track], {calib.name: calib}, ground,
                                  lambda f: (_ for _ in ()).throw(OSError("missing")))
    assert counts == {"segments": 0, "points": 0, "frames_without_cloud": 1}


def test_a_frame_the_association_could_not_place_gets_no_points(tmp_path):
    """A track frame without a centre (seen in one image, no LiDAR cluster of its own) writes no segment:
    the nearest cluster in its hull is a guess the association refused (a wall behind a person the LiDAR
    misses).  The same frame with its centre gets the person's points."""
    from pedx_graph.detections.lidar_cut import track_frame_indices

    calib = make_calibration(SimConfig().cameras.forward)
    cloud, labels = _scene(np.random.default_rng(1))
    _, det = _detection(calib)
    ground = make_ground_frame(UP, (1, 0, 0), np.zeros(3), GROUND_Z, source="config")
    unplaced = DetectedTrackFrame(frame=3, detections={det.camera: det})
    assert unplaced.world_p is None
    assert len(track_frame_indices(unplaced, {calib.name: calib}, cloud, ground)) == 0
    track = DetectedTrack(track_id="det000001", frames=[unplaced], pairs=(calib.name,))
    counts = write_track_segments(tmp_path, "20991231T1200", [track], {calib.name: calib}, ground, lambda f: cloud)
    assert counts["segments"] == 0
    placed = DetectedTrackFrame(frame=3, detections={det.camera: det}, world_p=np.array([12.0, 0.0, GROUND_Z + 0.9]))
    kept = labels[track_frame_indices(placed, {calib.name: calib}, cloud, ground)]
    assert (kept == "person").sum() > 250 and (kept == "person").mean() > 0.97


def test_a_hidden_person_leaves_the_neighbours_points_to_the_neighbour(tmp_path):
    """A person hidden from the LiDAR 0.8 m behind a near one: its hull holds the near one's points, and its
    uncertain depth (0.3 m) gates them in.  Each point goes to one person, the one whose centre is nearest
    on the ground: the near one (whose detection here shows only its head and shoulders, its centre known
    to 0.1 m, so it claims the rest of its body by ``body_radius_m``); the hidden one gets no segment."""
    calib = make_calibration(SimConfig().cameras.forward)
    rng = np.random.default_rng(3)
    near_xy, far_xy = (12.0, 0.0), (12.8, 0.1)
    stick = _person_points(near_xy, 0.0, 0.0)
    limbs = [(5, 7), (7, 9), (6, 8), (8, 10), (11, 13), (13, 15), (12, 14), (14, 16), (5, 11), (6, 12)]
    pick = rng.integers(len(limbs), size=300)
    along = rng.random((300, 1))
    cloud = (stick[[limbs[i][0] for i in pick]] * (1 - along) + stick[[limbs[i][1] for i in pick]] * along
             + 0.02 * rng.normal(size=(300, 3)))
    ground = make_ground_frame(UP, (1, 0, 0), np.zeros(3), GROUND_Z, source="config")

    def detection(xy, keep):
        uv = calib.project(_person_points(xy, 0.0, 0.0))[0]
        conf = np.where(np.isin(np.arange(17), keep), 0.9, 0.0)
        return Detection(camera=calib.name.split("-")[0], frame=3, keypoint_set="coco17", image_uv=uv,
                         confidence=conf, score=0.9, source=f"test{xy}")

    near = DetectedTrackFrame(frame=3, detections={"l": detection(near_xy, np.arange(7))},
                              world_p=np.array([*near_xy, GROUND_Z + 0.9]), depth_sigma_m=0.1)
    far = DetectedTrackFrame(frame=3, detections={"l": detection(far_xy, np.arange(17))},
                             world_p=np.array([*far_xy, GROUND_Z + 0.9]), depth_sigma_m=0.3)
    for fr in (near, far):
        fr.detections = {fr.detections["l"].camera: fr.detections["l"]}
    tracks = [DetectedTrack(track_id="det000001", frames=[near], pairs=(calib.name,)),
              DetectedTrack(track_id="det000002", frames=[far], pairs=(calib.name,))]
    alone = write_track_segments(tmp_path / "alone", "20991231T1200", tracks[1:], {calib.name: calib}, ground,
                                 lambda f: cloud)
    assert alone["points"] > 200                        # by itself, the hidden one's cut is the neighbour
    write_track_segments(tmp_path, "20991231T1200", tracks, {calib.name: calib}, ground, lambda f: cloud)
    assert not segment_path(tmp_path, "20991231T1200", 3, "det000002").exists()
    # every point the hidden one's cut held is the near one's now (its own hull held a few)
    assert len(read_ply_points(segment_path(tmp_path, "20991231T1200", 3, "det000001"))) >= alone["points"]


def test_exclusive_cuts_give_each_point_to_one_person():
    """A point two people's cuts share goes to the nearer centre; a point claimed by a confident centre's
    body radius leaves a farther person's cut; a point shared by two people without a centre goes to no one;
    a point only one person claims stays with it, centre or not."""
    from pedx_graph.detections.lidar_cut import exclusive_cuts

    ground = make_ground_frame(UP, (1, 0, 0), np.zeros(3), GROUND_Z, source="config")
    points = np.array([[10.0, 0.0, -1.0], [10.9, 0.0, -1.0], [10.1, 0.1, -1.0], [30.0, 5.0, -1.0],
                       [31.0, 5.0, -1.0]])
    config = LidarCutConfig()
    cuts = [np.array([0, 1]), np.array([0, 1, 2]), np.array([3]), np.array([3, 4])]
    centres = [np.array([10.0, 0.0, -1.0]), np.array([11.0, 0.0, -1.0]), None, None]
    out = exclusive_cuts(cuts, points, centres, [0.1, 0.5, np.inf, np.inf], ground, config)
    # 0 nearer person 0; 1 nearer person 1; 2 only in person 1's cut but within person 0's body radius
    np.testing.assert_array_equal(out[0], [0, 2])
    np.testing.assert_array_equal(out[1], [1])
    np.testing.assert_array_equal(out[2], [])                 # shared by two without a centre
    np.testing.assert_array_equal(out[3], [4])                # its own point
    # a wide centre (sigma above claim_sigma_m) claims nothing by radius
    out = exclusive_cuts(cuts, points, centres, [0.5, 0.5, np.inf, np.inf], ground, config)
    np.testing.assert_array_equal(out[1], [1, 2])


def test_a_placed_centre_keeps_its_points_against_a_guessed_one_on_top_of_it():
    """A walker's LiDAR points about its centre, known to 0.1 m; a second person's smoothed stereo centre
    (0.5 m uncertain: someone hidden behind, at range) lies 0.05 m from the points' middle, nearer than the
    walker's 0.12 m, and its cut holds them too.  The points stay the walker's.  Two equally sure centres
    still split shared points by distance."""
    from pedx_graph.detections.lidar_cut import exclusive_cuts

    ground = make_ground_frame(UP, (1, 0, 0), np.zeros(3), GROUND_Z, source="config")
    rng = np.random.default_rng(4)
    points = np.c_[[21.3, 0.0] + 0.12 * rng.normal(size=(40, 2)), rng.uniform(-1.8, -0.4, 40)]
    centres = [np.array([21.42, 0.0, -1.0]), np.array([21.35, 0.0, -1.0])]
    cuts = [np.arange(40), np.arange(40)]
    out = exclusive_cuts(cuts, points, centres, [0.1, 0.5], ground, LidarCutConfig())
    assert len(out[0]) == 40 and len(out[1]) == 0, (len(out[0]), len(out[1]))
    out = exclusive_cuts(cuts, points, centres, [0.1, 0.1], ground, LidarCutConfig())
    nearer = np.linalg.norm(points[:, :2] - [21.35, 0.0], axis=1) < np.linalg.norm(points[:, :2] - [21.42, 0.0], axis=1)
    assert 0 < nearer.sum() < 40
    np.testing.assert_array_equal(out[1], np.flatnonzero(nearer))


def _limb_cloud(rng, xy, n=300):
    """(n, 3) LiDAR points along the limbs and torso of a stick walker at ``xy`` facing the rig's rays' side."""
    stick = _person_points(xy, 0.0, 0.0)
    limbs = [(5, 7), (7, 9), (6, 8), (8, 10), (11, 13), (13, 15), (12, 14), (14, 16), (5, 11), (6, 12), (5, 6),
             (11, 12)]
    pick = rng.integers(len(limbs), size=n)
    along = rng.random((n, 1))
    return (stick[[limbs[i][0] for i in pick]] * (1 - along) + stick[[limbs[i][1] for i in pick]] * along
            + 0.02 * rng.normal(size=(n, 3)))


def _walker_on_the_border(depth_axis_m: float = 6.0):
    """The forward rig, its ground, the left image's width and the lateral position (m) of a walker at
    ``depth_axis_m`` whose centre projects onto the left image's right border."""
    calib = make_calibration(SimConfig().cameras.forward)
    ground = make_ground_frame(UP, (1, 0, 0), np.zeros(3), GROUND_Z, source="config")
    width = calib.image_size[0]
    ys = np.linspace(-4.0, 0.0, 401)
    centre_u = np.array([calib.project(np.array([[depth_axis_m, y, GROUND_Z + 1.0]]))[0][0, 0] for y in ys])
    return calib, ground, width, float(ys[np.argmin(np.abs(centre_u - width))])


def test_a_person_cut_off_by_the_image_border_keeps_its_points_beyond_it():
    """A walker at 6 m whose right half lies past the left image's right border: the detector reports the
    keypoints inside the image only, yet the LiDAR sees the whole body.  With the walker's centre known, the
    cut takes the body's points past the border too (they connect to the seen half), not those of a second
    walker standing 1.2 m farther out, nor the far part of a wall the walker passes 0.3 m behind it (which
    touches it); without a centre, or with ``beyond_border_m`` 0, only the seen half is cut."""
    rng = np.random.default_rng(5)
    depth_axis_m = 6.0
    calib, ground, width, y_border = _walker_on_the_border(depth_axis_m)
    person = _limb_cloud(rng, (depth_axis_m, y_border))
    other = _limb_cloud(rng, (depth_axis_m, y_border - 1.2))
    wall = np.column_stack([np.full(400, depth_axis_m + 0.3), y_border + rng.uniform(-2.0, 0.5, 400),
                            rng.uniform(GROUND_Z, GROUND_Z + 1.5, 400)])
    cloud = np.concatenate([person, other, wall])
    labels = np.repeat(["person", "other", "wall"], [len(person), len(other), len(wall)])
    centre = np.array([depth_axis_m, y_border, GROUND_Z + 1.0])
    uv = calib.project(_person_points((depth_axis_m, y_border), 0.0, 0.0))[0]
    seen = uv[:, 0] < width - 1
    assert 4 <= seen.sum() <= 13                               # the border cuts the walker
    uv[~seen] = np.nan
    depth = float(calib.world_to_rect(np.array([depth_axis_m, y_border, GROUND_Z + 1.0]))[2])
    person_u = calib.project(person)[0][:, 0]
    config = LidarCutConfig()
    index = cut_indices(uv, calib, "left", cloud, ground, config, depth_m=depth, world_centre=centre)
    cut = labels[index]
    above = (person[:, 2] >= GROUND_Z + config.ground_clearance_m).sum()      # the feet's points are ground
    assert (cut == "person").sum() > 0.95 * above and (cut == "other").sum() == 0
    assert (person_u > width).sum() > 0.3 * len(person)      # a good share of the body lies past the border
    wall_u = calib.project(cloud[index][cut == "wall"])[0][:, 0]
    far_wall = np.abs(cloud[index][cut == "wall"][:, 1] - y_border) > config.body_radius_m
    assert not np.any(far_wall & (wall_u > width))           # past the border: only within the body's radius
    for seen_only in (cut_indices(uv, calib, "left", cloud, ground, config, depth_m=depth),
                      cut_indices(uv, calib, "left", cloud, ground, LidarCutConfig(beyond_border_m=0.0),
                                  depth_m=depth, world_centre=centre)):
        assert (labels[seen_only] == "person").sum() <= (person_u <= width + 40).sum()


def test_a_frame_cut_completes_one_image_with_the_other(tmp_path):
    """The left image's detector saw only the walker's head and shoulders, the right one the whole body: the
    frame's segment holds the legs' points too (the left keypoints completed by the right ones at the
    walker's disparity)."""
    calib = make_calibration(SimConfig().cameras.forward)
    rng = np.random.default_rng(6)
    xy = (10.0, 0.5)
    cloud = _limb_cloud(rng, xy)
    world_kp = _person_points(xy, 0.0, 0.0)
    left_uv, right_uv = calib.project(world_kp)
    left_name, right_name = calib.name.split("-")
    head_only = np.where(np.arange(17) < 7, 0.9, 0.0)
    left = Detection(camera=left_name, frame=3, keypoint_set="coco17", image_uv=left_uv, confidence=head_only,
                     score=0.9, source="test#l")
    right = Detection(camera=right_name, frame=3, keypoint_set="coco17", image_uv=right_uv,
                      confidence=np.full(17, 0.9), score=0.9, source="test#r")
    frame = DetectedTrackFrame(frame=3, detections={left_name: left, right_name: right},
                               world_p=np.array([*xy, GROUND_Z + 0.9]), depth_sigma_m=0.1)
    track = DetectedTrack(track_id="det000001", frames=[frame], pairs=(calib.name,))
    ground = make_ground_frame(UP, (1, 0, 0), np.zeros(3), GROUND_Z, source="config")
    write_track_segments(tmp_path, "20991231T1200", [track], {calib.name: calib}, ground, lambda f: cloud)
    points = read_ply_points(segment_path(tmp_path, "20991231T1200", 3, "det000001"))
    legs = (cloud[:, 2] < GROUND_Z + 0.8) & (cloud[:, 2] >= GROUND_Z + LidarCutConfig().ground_clearance_m)
    assert (points[:, 2] < GROUND_Z + 0.8).sum() > 0.9 * legs.sum()


def test_a_centre_at_the_image_border_is_the_whole_bodys():
    """A walker at 6 m half past the left image's right border: the median of the LiDAR cut of its seen half
    lies ~0.14 m off the body's centre toward the image; completed past the border around that median, and
    again around the new one (``border_centre_steps``), the association's LiDAR centre lands on the body."""
    from pedx_graph.detections.association import AssociationConfig, _lidar_centre, pixel_at_depth
    from pedx_graph.detections.tracker import Observation

    depth_axis_m = 6.0
    calib, ground, width, y_border = _walker_on_the_border(depth_axis_m)
    cloud = _limb_cloud(np.random.default_rng(7), (depth_axis_m, y_border))
    uv = calib.project(_person_points((depth_axis_m, y_border), 0.0, 0.0))[0]
    uv[uv[:, 0] >= width - 1] = np.nan
    depth = float(calib.world_to_rect(np.array([depth_axis_m, y_border, GROUND_Z + 1.0]))[2])

    def lateral_error(config):
        obs = Observation(frame=3, uv={"left": uv}, score=0.9, depth_sigma_m=0.3,
                          world_p=pixel_at_depth(calib, "left", np.nanmedian(uv, axis=0), depth),
                          world_p_camera=calib.camera_centre("left"))
        _lidar_centre(obs, calib, cloud, ground, config, {})
        return abs(float(obs.world_p[1]) - y_border)

    assert lateral_error(AssociationConfig()) < 0.05
    assert lateral_error(AssociationConfig(border_centre_steps=0)) > 0.1


def test_a_centre_takes_the_keypoints_one_image_lacks_from_the_other():
    """A walker at 6 m on the left image's right border, found there with only the three keypoints well inside
    the image (80 px from the border: the hull does not reach it), and whole in the right image: the LiDAR
    centre of the stereo observation (left keypoints completed by the right ones at its disparity) lands on
    the body; from the left keypoints alone it stays ~0.24 m off toward the image."""
    from pedx_graph.detections.association import AssociationConfig, _lidar_centre, pixel_at_depth
    from pedx_graph.detections.tracker import Observation

    depth_axis_m = 6.0
    calib, ground, width, y_border = _walker_on_the_border(depth_axis_m)
    cloud = _limb_cloud(np.random.default_rng(7), (depth_axis_m, y_border))
    left, right = calib.project(_person_points((depth_axis_m, y_border), 0.0, 0.0))
    left[left[:, 0] >= width - 80] = np.nan
    assert np.isfinite(left[:, 0]).sum() == 3 and np.all(right[:, 0] < width)
    depth = float(calib.world_to_rect(np.array([depth_axis_m, y_border, GROUND_Z + 1.0]))[2])

    def lateral_error(uv):
        obs = Observation(frame=3, uv=uv, score=0.9, depth_sigma_m=0.1,
                          world_p=pixel_at_depth(calib, "left", np.nanmedian(left, axis=0), depth),
                          world_p_camera=calib.camera_centre("left"))
        if "right" in uv:
            obs.disparity_px = float(np.nanmedian(left[:, 0] - right[:, 0]))
        _lidar_centre(obs, calib, cloud, ground, AssociationConfig(), {})
        return abs(float(obs.world_p[1]) - y_border)

    assert lateral_error({"left": left, "right": right}) < 0.05
    assert lateral_error({"left": left}) > 0.15
