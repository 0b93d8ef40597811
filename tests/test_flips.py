"""A detection whose left and right the detector took for each other (the whole body) is swapped back where
the person's walking direction shows which side faces the camera; side views and people standing still are
left as they are."""
from __future__ import annotations

import numpy as np

from pedx_graph.body import BodyModel
from pedx_graph.body.keypoint_defs import standing_keypoints_3d
from pedx_graph.data.ground import make_ground_frame
from pedx_graph.detections.association import DetectedTrack, DetectedTrackFrame
from pedx_graph.detections.flips import FlipConfig, flip_log_odds, unflip_tracks
from pedx_graph.detections.types import Detection
from pedx_graph.keypoints import mirror_order
from pedx_graph.sim.cameras import make_calibration
from pedx_graph.sim.config import SimConfig

SET = "coco17"
#: Ground of the default rig's sim frame (z up, LiDAR 1.95 m above the ground).
GROUND_Z = -1.95
UP = np.array([0.0, 0.0, 1.0])


def _rig():
    return {pair.name: make_calibration(pair) for pair in SimConfig().cameras.pairs()}


def _ground():
    return make_ground_frame(UP, (1.0, 0.0, 0.0), np.zeros(3), GROUND_Z, source="config")


def _body(xy, forward) -> tuple[np.ndarray, np.ndarray]:
    """(17, 3) world keypoints of someone standing at ground point ``xy`` facing ``forward`` (level), and
    its torso centre."""
    local = standing_keypoints_3d(BodyModel.load(), SET)
    forward = np.asarray(forward, dtype=float) / np.linalg.norm(forward)
    left = np.cross(UP, forward)
    world = (np.array([xy[0], xy[1], GROUND_Z - local[:, 1].min()]) + local[:, :1] * left + local[:, 1:2] * UP
             + local[:, 2:3] * forward)
    return world, world[5:13].mean(axis=0)


def _detections(calib, world_p, frame, rng, flipped=False):
    out = []
    for camera, uv in zip(calib.name.split("-"), calib.project(world_p)):
        uv = uv + 2.0 * rng.normal(size=uv.shape)
        if flipped:
            uv = uv[mirror_order(SET)]
        out.append(Detection(camera=camera, frame=frame, keypoint_set=SET, image_uv=uv,
                             confidence=np.full(len(uv), 0.8), score=0.8, source=f"t#{camera}/{frame}"))
    return out


def test_log_odds_tell_a_swapped_back_view_and_say_nothing_of_a_side_view():
    calib = _rig()["ylw79D0-red707B"]
    rng = np.random.default_rng(0)
    for forward, clear in (((1.0, 0.0, 0.0), True), ((-1.0, 0.0, 0.0), True), ((0.0, 1.0, 0.0), False)):
        world, centre = _body((15.0, 0.5), forward)           # walking away, toward the camera, across
        for flipped in (False, True):
            det = _detections(calib, world, 0, rng, flipped)[0]
            odds = flip_log_odds(det.image_uv, SET, calib, "left", centre, np.asarray(forward), UP, 4.0, 0.05)
            if clear:
                assert (odds > 30) if flipped else (odds < -30)
            else:
                assert abs(odds) < FlipConfig().min_log_odds


def test_swapped_detections_of_a_walker_are_swapped_back_the_others_left_alone():
    calibs = _rig()
    calib = calibs["ylw79D0-red707B"]
    rng = np.random.default_rng(1)
    swapped_at = {3, 7}
    frames = []
    for k in range(10):
        world, centre = _body((12.0 + 0.14 * k, -1.0), (1.0, 0.1, 0.0))      # walks away, 1.4 m/s
        dets = _detections(calib, world, k, rng, flipped=k in swapped_at)
        frames.append(DetectedTrackFrame(frame=k, detections={d.camera: d for d in dets}, world_p=centre,
                                         depth_sigma_m=0.1))
    track = DetectedTrack(track_id="det000001", frames=frames, pairs=(calib.name,))
    config = FlipConfig(enabled=True)
    [fixed], count = unflip_tracks([track], calibs, _ground(), config, 3.0, 0.015, 0.1)
    assert count == 2 * len(swapped_at)                       # both images of each swapped frame
    order = mirror_order(SET)
    for before, after in zip(track.frames, fixed.frames):
        for camera, det in after.detections.items():
            original = before.detections[camera]
            expected = original.image_uv[order] if before.frame in swapped_at else original.image_uv
            np.testing.assert_array_equal(det.image_uv, expected)
    # standing still: the facing is unknown, nothing is swapped
    still = DetectedTrack(track_id="det000002", pairs=track.pairs, frames=[
        DetectedTrackFrame(frame=fr.frame, detections=fr.detections, world_p=track.frames[0].world_p)
        for fr in track.frames])
    assert unflip_tracks([still], calibs, _ground(), config, 3.0, 0.015, 0.1)[1] == 0
    # switched off (the default)
    assert unflip_tracks([track], calibs, _ground(), FlipConfig(), 3.0, 0.015, 0.1)[1] == 0
