"""Who is who: group id-less detections into tracks — within a stereo pair, over frames and across pairs.

Entry point::

    associate(detections, calibrations, config=None, clouds=None, ground=None, workers=1) -> list[DetectedTrack]

``detections``: :class:`~pedx_graph.detections.types.Detection` of every camera and frame (raw-image pixels,
no ids needed; ids in the files are ignored); ``calibrations``: pair name -> :class:`StereoCalibration`
(with the raw K/D when the detections were made on raw images); ``clouds``: optional ``{frame: (N, 3)}`` full
LiDAR scenes (world frame) — a stereo-matched person's centre then comes from its LiDAR cut
(:mod:`pedx_graph.detections.lidar_cut`) when the cut holds ``lidar_min_points`` and agrees with the stereo
centre (far more precise in depth than stereo at range; for a person cut off by the image's border, the cut
completed past the border around its own median, ``border_centre_steps`` times); ``ground``: the sequence's
:class:`~pedx_graph.data.ground.GroundFrame` (derived from the calibrations when None — and from the clouds
when they are given and it has no ground height, :func:`~pedx_graph.detections.lidar_cut.ground_with_plane`;
distances are measured in its ground plane).  Returns :class:`DetectedTrack` s with ids ``"det000001"``, ... in order of first frame, each holding per frame the detections of every camera
that saw the person (raw pixels as read, ``track_id`` set) and the person's 3D centre — what the import
writer turns into PedX-layout label files.

Steps:

1. **Rectify** every detection (:func:`pedx_graph.detections.undistort.rectified`: K, D, R_rect, P_rect).
2. **Split people joined, duplicates dropped** in one image.  A bottom-up detector (OpenPose) may break one
   person's skeleton in two: an upper body (head, neck, arms) and hips and legs reported as two people
   (:func:`join_split_parts`).  A detection with no hip or leg keypoint and one with nothing else become one
   where they make one standing person: the rows of their keypoints fitted together by a standing body's
   (:func:`~pedx_graph.body.templates.open_standing_keypoints_3d`, scale and offset) leave an RMS within
   ``gate_sigmas`` of ``join_row_sigma``, and the two parts' median columns lie within ``gate_sigmas`` of
   ``join_column_sigma`` (both fractions of the fitted height); the best-fitting pairs first.  Then a
   detector reporting a person twice, or a fragment (legs alone), is dropped:
   two detections sharing at least ``min_shared_keypoints`` keypoints whose median distance is below
   ``duplicate_frac`` of the larger one's height keep only the higher score, unless one is a fragment of the
   other (:func:`_fragment_of`: its keypoints are among the other's, and it lacks the top or the bottom
   third of them): the whole one stays.
3. **Each camera over time first** (:func:`camera_tracklets`): a
   :class:`~pedx_graph.detections.tracker.Tracker` per camera (``tracklet`` config) links its detections into
   2D tracklets — Hungarian matching on constant-velocity predicted keypoints and keypoint-span size, gated;
   identity in one image is decided by motion, before any stereo pairing (with ``backward_birth_frames``,
   off by default, a tracklet's first link, made with no velocity yet, gives way to the link the tracker
   running backwards in time makes with the person's motion known).  With ``clouds`` (and
   ``lidar_identity``), each detection first gets the range of its LiDAR cluster (:func:`detection_ranges`),
   a capped term of the tracker's cost (``tracklet.range_sigma_m``): two people overlapping in one image a
   metre apart in range are told apart where the LiDAR sees both (a cluster at a range where the person's
   feet would leave the ground, ``feet_tolerance_m``, is not its person: a car in front of it).
4. **Tracklets across the pair** (:func:`pair_tracklets`).  Per frame, a left and a right detection of one
   person (:func:`stereo_cost`, over the keypoints present in both with confidence >= ``min_confidence``):

   - row residual ``median(v_l - v_r) / (1.2533 sqrt(2) sigma / sqrt(n))`` over the ``n`` shared keypoints
     (the standard error of a median of differences of two detections), ``sigma = keypoint_sigma_px +
     keypoint_sigma_frac * h``;
   - disparity spread ``1.4826 MAD(u_l - u_r) / (sqrt(2) sigma)`` (a person's points share one depth);
   - size ``log(span_l / span_r) / size_sigma`` (keypoint spans: vertical extents of the shared keypoints whose
     rows agree to ``gate_sigmas`` of ``sqrt(2) sigma`` about the median row offset, when they are most of
     them: a keypoint misplaced in one image does not stretch one span);
   - person height: the nose-to-ankle height the pairing implies (pixel span x baseline / disparity,
     :func:`implied_height_m`) against ``person_height_m``, ``log`` ratio over ``person_height_sigma``
     (a disparity borrowed from someone at another depth implies a giant or a dwarf);

   with LiDAR ranges, the left and right ranges agree and the median disparity matches the range
   (``lidar_range_sigma_m``; capped at ``gate_sigmas``, never gating);
   gated out when a residual exceeds ``gate_sigmas``, the disparity is not positive or the depth lies outside
   ``[min_depth_m, max_depth_m]``.  A left and a right tracklet are scored over all their shared frames
   (:func:`_pair_gains`, :func:`_pair_runs`): the per-frame disparities must follow one smooth depth (a line
   in time whose slope a walker's ``max_speed_mps`` allows, robust, ``disparity_smooth_px`` slack); each
   shared frame passing every gate adds ``gate_sigmas^2 / 2`` minus its cost, each failing one subtracts
   ``gate_sigmas^2 / 2``,
   summed over the runs of consecutive shared frames that support the pairing most (a tracklet the
   per-camera tracker carried on with someone else midway is paired over the part before the change; one
   failing frame between two passing ones, a detector's glitch, does not break a run; where no run holds
   ``pair_min_run_frames`` passing frames, the whole overlap counts when its sum is positive and that many
   of its frames pass).  A passing frame counts only for its detections' best pairing: where the left
   detection pairs better with another right tracklet's detection at that frame, or the right one with
   another left tracklet's, and that rival pairing stands on its own there (the frame lies in one of its
   supported runs), it adds nothing to this pairing and stays unpaired in it (:func:`contest_frames`: a
   tracklet carried on with a neighbour a few pixels of disparity off does not take the frames of the
   person's own shorter tracklet).
   Pairings with positive evidence are accepted greedily, strongest first, frame by frame (a tracklet frame
   already paired is not paired again: a tracklet is split where its pairing evidence changes); pairings
   sharing a tracklet make one person unless that would put two detections of one image in one frame.
   A pairing left with fewer than ``pair_min_run_frames`` frames to pair does not bring a tracklet to a
   person when that tracklet is seen beside one of the person's own in its image (both hold a detection at
   a frame inside the stretch the person holds of its own): one or two agreeing frames do not make two
   people seen side by side one.
   A tracklet's unpaired frames go to the person whose own detections in that image, interpolated in time
   (past the ends carried on at the body's velocity, the median keypoint step), agree best in keypoints and
   size (``tracklet_switch_cost`` added for a person not holding that tracklet), else form a person of their
   own; a detection with a LiDAR range also weighs how far that range lies from the person's depth (its
   paired frames' disparities), without gating on it.  A detection seen in one image at a frame then moves
   to another person holding only the other image's detection there when the two pair in stereo at that
   person's depth better than its own person's detections in its image explain it (:func:`complete_frames`:
   a neighbour's tracklet carried through the one frame where the person was seen in that image; one stereo
   frame is too short to pair tracklets).  Paired frames are triangulated at their median
   disparity (:func:`triangulate_centre`); with ``clouds``, a LiDAR centre replaces the stereo one where it
   agrees (at its detection's own range only where that range's cluster ends at the hulls, not a car or a
   wall seen through someone the LiDAR misses: :func:`detection_ranges`' ``past``); a frame seen in one
   image gets one from its detection's own LiDAR cluster (:func:`_range_centre`) where that cluster ends at
   the silhouettes (not a wall seen through someone the LiDAR misses,
   ``lidar_min_support``) and the track's nearest stereo centre in time allows that depth
   (:func:`_agrees_with_stereo`); once
   the pair's tracks are final (below), every centre is checked against the track's straight walk
   (:func:`settle_centres`): a LiDAR centre off it goes back to its stereo one, a one-image centre off it,
   or one a stereo centre on it does not allow, is taken back (the cluster of someone in front).  A
   paired frame whose disparity
   leaves the person's smooth disparity line by more than ``gate_sigmas`` loses the detection of its
   shorter-held tracklet (:func:`drop_disparity_outliers`: a tracklet of someone else paired for a frame or
   two).  A track whose image velocity changes across frames it missed by more than a walker's velocity can
   (:func:`split_reversals`: the tracker carried it on with someone walking the other way) is split there.
   Where two of the pair's tracks pass each other in the image, tails exchanged at some frame are
   tried, at their ends a head or tail moved from one to the other, and stretches exchanged where they met and
   given back where they met again (:func:`repair_swaps`): a walker moves
   on a straight line at constant speed, which the image column (projected: curved near the camera), the
   frames' centre depths and the image height (:func:`standing_height_px`: a person keeps their height)
   follow, so the exchange is made when it fits the two tracks to such walks clearly
   better (a tracker carrying each on with the other while they were missed in turns); after it, a
   detection whose image height is off its track's walk and on the walk of another track near it in that
   image, or in a frame without a centre far off it (``lone_height_gate_sigmas``), is dropped, with its
   frame unless the frame is unpaired and seen in the other image too
   (:func:`drop_other_heights`).  Last, a piece of at most 3 frames at a track's end that a gap of at least
   ``end_gap_frames`` frames parts from the rest is left out where the rest's walk misses every frame of it
   (column and image height, in each image the frame is seen in) by more than ``gate_sigmas^2``
   (:func:`off_walk_pieces`: the per-camera trackers may have coasted across the gap onto someone else), and
   a frame seen in one image only at a track's end (before its first frame seen in both images or after its
   last) is left out where the track's own walk in that image misses its detection (column and image
   height) by more than ``gate_sigmas^2`` (:func:`off_walk_ends`, with or without a centre: a one-image
   centre is the LiDAR cluster along that detection's ray, whoever it is), and any frame seen in one image
   only, at an end or between frames seen in both, without a centre, where another of the pair's tracks,
   spanning it and without a detection in that image there, explains it by its walk in that image at least
   as well as the track's own walk does (:func:`drop_ambiguous_frames`: one image cannot tell two people on
   one ray apart, and a tracklet born from one detection has no velocity yet).  Before that, a person the
   pair lost and found again (hidden, or missed in both images, for up to ``stitch_max_gap_frames``) is
   made one track when one straight walk explains both pieces, each with its stereo depths
   (:func:`stitch_tracks`).  A person with fewer than ``tracker.min_track_frames`` frames or a mean score
   below ``tracker.min_mean_score`` is dropped (clutter, flickering bystanders).
5. **Across pairs** (:func:`merge_pair_tracks`): tracks of different pairs whose 3D centres agree are one
   person: over at least ``merge_min_shared_frames`` shared frames (a track's centre between two of its 3D
   frames is interpolated), the median of the horizontal distance, each centre uncertain by its depth sigma
   along its viewing ray and by ``centre_lateral_sigma_m`` across it (:func:`_ray_distance`), is within
   ``gate_sigmas`` (without calibrations: divided by ``sqrt(sigma_a^2 + sigma_b^2 + merge_distance_m^2)``,
   at most 1).  A track with fewer than ``merge_min_shared_frames`` 3D centres shared with the other (seen in
   one image of its pair) is compared in its own images instead (:func:`_image_agreement`): the other
   track's centres, projected, must lie under its detections within ``merge_distance_m`` (plus the
   centre's depth uncertainty seen from that camera), and its keypoint span must match the span the
   centre's depth predicts.  Merged greedily, best agreement first, never two tracks of one pair at one
   frame (one pair's tracks of one person at different times — lost and found again — do join).  At a frame
   where two merged pairs' centres disagree beyond ``gate_sigmas``, the pair whose centre the person's walk
   over its other frames does not explain loses that frame's detections (:func:`drop_conflicting_pairs`:
   one pair's track went on with a neighbour for a frame).  A stretch of one pair's track that the other
   pairs' walk of its person does not explain and another person's walk does, where that person lacks
   this pair, moves to that person (:func:`move_to_neighbours`: the pair's track went on with the walker
   alongside for a few frames, that walker's own track in this pair lost there).
6. Tracks left with fewer than ``tracker.min_track_frames`` frames are dropped, as a pair's were in step 4:
   the repairs since cut tracks, and a head, a tail or a remnant of two or three frames on its own is most
   often a piece of someone held by a longer track, or of two people, too short to tell which.  Tracks whose
   median horizontal distance from the rig lies outside ``[min_distance_m, max_distance_m]``
   are dropped (the labelled range of the data set; people beyond it are bystanders).
7. **Smoothed centres** (:func:`smooth_centres`): each frame's centre (what the LiDAR cut's depth gate uses)
   becomes the weighted line fit, in the ground plane, of the ``2 smooth_window_frames + 1`` centres of the
   track that tell most about it (weights: each centre's depth uncertainty, ``smooth_motion_m`` and how far
   a walker leaves its line in the time between, half of ``tracker.accel_sigma_mps`` times that time
   squared, in quadrature: the nearest centres where every frame has a precise one, a LiDAR centre a second
   away rather than a few noisy stereo depths close by; the line's velocity drawn to the person's velocity over
   a wider stretch, so that a track's end is not extrapolated from two noisy centres, and that velocity
   drawn toward standing by ``walking_speed_mps``, so that a few noisy centres do not set it), started from the
   centres the best-supported line explains (:func:`_consensus`: most
   centres within ``gate_sigmas``, not the weighted least squares a single confident outlier would
   steer), centres beyond ``gate_sigmas`` left out, the line's speed at most ``tracker.max_speed_mps`` —
   one frame's noisy stereo depth or a cut that caught a passing car no longer sets the gate, and frames
   seen in one image get a depth too.  Each smoothed centre's uncertainty is its line's at that frame
   (:func:`_offset_sigma`, the walking velocity's own uncertainty included): it grows where the line is
   carried past the centres (a track's ends, a stretch seen in one image), and the cut's gate with it.  A
   centre taken from the LiDAR that lies within ``min_separation_m`` of another person's smoothed centre
   (that person's track runs on between its frames), nearer to it than to its own person's, is taken back
   and the person smoothed again, the clearest such centre first (:func:`separate_people`).
"""
from __future__ import annotations

import dataclasses
import functools
import hashlib
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np
from scipy.optimize import linear_sum_assignment

from pedx_graph.body.keypoint_defs import load_keypoint_set
from pedx_graph.body.templates import open_standing_keypoints_3d
from pedx_graph.data.ground import GroundFrame, ground_from_calibrations
from pedx_graph.data.types import StereoCalibration
from pedx_graph.detections.lidar_cut import LidarCutConfig, ground_with_plane
from pedx_graph.detections.tracker import (Observation, Tracker, TrackerConfig, box_cover, frames_for,
                                          image_sigma_px, keypoint_box)
from pedx_graph.detections.types import Detection
from pedx_graph.detections.undistort import find_camera, rectified
from pedx_graph.keypoints import lower_body_mask
from pedx_graph.small_arrays import median

_GATED = 1e9


@dataclass
class AssociationConfig:
    """Stereo matching, duplicates, merging across pairs and the distance range (pixels, metres)."""

    min_confidence: float = 0.1
    """Keypoints with a lower confidence are ignored by the association."""
    min_shared_keypoints: int = 3
    """Two detections are compared only on at least this many keypoints present in both."""
    join_split_parts: bool = True
    """Join the two parts of a person a bottom-up detector reported as two people (module docstring, step 2)."""
    join_row_sigma: float = 0.05
    """How far a split person's keypoint rows leave a standing person's (RMS, fraction of the height): the
    walking limbs' rise and fall, the head's tilt.  Default: about the median over one person's two parts
    split by the simulated detector from CMU walking (benchmarks/results/bench_split_parts.md)."""
    join_column_sigma: float = 0.075
    """How far the median column of a split person's upper part lies from its hips and legs' (fraction of the
    height): lean, swinging arms, the view.  Default: measured as above (its 99th percentile lies within
    ``gate_sigmas`` of it)."""
    duplicate_frac: float = 0.1
    """Two detections in one image whose shared keypoints lie within this fraction of the larger one's
    height (median distance) are one person: the lower score is dropped, unless one is a fragment of the
    other (its keypoints are among the other's, and it lacks the top or the bottom third of them): then the
    fragment is."""
    keypoint_sigma_px: float = 3.0
    """Size-independent part of one detected keypoint's noise per axis, pixels (the rectification error of a
    real pair adds a little)."""
    keypoint_sigma_frac: float = 0.015
    """Size-dependent part: this fraction of the person's image height (detector noise grows with size)."""
    size_sigma: float = 0.12
    """Expected spread of ``log(span_left / span_right)`` for one person (noise, a keypoint missing in one
    image)."""
    gate_sigmas: float = 3.5
    """A stereo pair whose normalised residual (any term) exceeds this is never matched."""
    min_depth_m: float = 1.5
    """Nearest depth a matched pair may have (the rig's range), metres."""
    max_depth_m: float = 80.0
    """Farthest depth a matched pair may have, metres."""
    person_height_m: float = 1.45
    """Typical nose-to-ankle height of a walking adult, metres: a stereo pairing implying a person far
    taller or shorter (its disparity belongs to someone at another depth) is unlikely ..."""
    person_height_sigma: float = 0.2
    """... by ``log(implied / person_height_m) / person_height_sigma`` (adults and children, pose)."""
    merge_distance_m: float = 0.5
    """Without calibrations: tracks of two pairs are one person when their centres agree to this, metres,
    beyond their depth uncertainties (step 5); with them, ``centre_lateral_sigma_m`` is used."""
    centre_lateral_sigma_m: float = 0.15
    """Uncertainty of a track's centre across its viewing ray (which body point the median of the keypoints or
    of the LiDAR points lands on, a walker's sway), metres: with calibrations, two pairs' tracks are one person
    when the median over shared frames of their centres' distance, each centre uncertain by its depth sigma
    along its ray and by this across it, is within ``gate_sigmas`` (people walking side by side half a metre
    apart are told apart; ``merge_distance_m`` is the isotropic test used without calibrations)."""
    merge_min_shared_frames: int = 3
    """... over at least this many shared frames."""
    min_distance_m: float = 0.0
    """Tracks whose median horizontal distance from the rig is below this are dropped, metres."""
    max_distance_m: float = 60.0
    """Tracks whose median horizontal distance from the rig is above this are dropped, metres (bystanders
    beyond the labelled range)."""
    lidar_min_points: int = 8
    """A LiDAR cut with at least this many points replaces the stereo centre (when clouds are given) ..."""
    lidar_agreement_m: float = 0.3
    """... when its median lies within ``gate_sigmas`` stereo depth sigmas plus this of the stereo centre, in
    the ground plane, metres."""
    lidar_sigma_m: float = 0.1
    """Uncertainty of a LiDAR centre along the ray (the median of a person's points vs its centre), metres."""
    border_centre_steps: int = 3
    """A person cut off by the image's border: its LiDAR cut is completed past the border around the median of
    the cut so far, up to this many times (:func:`_lidar_centre`; each median nearer the whole body's)."""
    disparity_smooth_px: float = 1.0
    """How far a person's per-frame disparity may leave a straight line over the frames two tracklets share
    (depth is smooth, disparity ~ 1/depth is not exactly linear), pixels; added to the disparity's standard
    error in quadrature."""
    lidar_identity: bool = True
    """With clouds: each detection gets the range of the LiDAR points under its keypoints
    (:func:`detection_ranges`), used by the per-camera tracker (``tracklet.range_sigma_m``) and by the stereo
    pairing (left and right ranges agree, the disparity matches the range): two people overlapping in the
    image a metre apart in range are told apart.  The range terms weigh in the costs but never gate (capped
    at ``gate_sigmas``): a detection's range can lie on a neighbour."""
    lidar_cluster_gap_m: float = 0.3
    """LiDAR points inside the detections' hulls closer than this in the ground plane are one cluster
    (:func:`detection_ranges`), metres."""
    lidar_identity_min_points: int = 3
    """A cluster is a candidate person of a detection with at least this many points in its hull (a person
    mostly hidden from the LiDAR by another a metre in front keeps only a few points at 20 m)."""
    lidar_support_margin: float = 0.2
    """A detection whose two best clusters' supports (fraction of the cluster inside its hull) differ by less
    than this gets no LiDAR range."""
    lidar_body_width_frac: float = 0.3
    """A person's LiDAR points lie within its keypoints' columns widened to this fraction of its image height
    (~0.5 m: a walker seen from the side has its keypoints on one line, its chest and arms around it) ..."""
    lidar_context_frac: float = 0.5
    """... its surroundings reach this fraction of its image height further on both sides (~0.8 m at its
    depth; inside the image) ..."""
    lidar_min_support: float = 0.5
    """... a detection's LiDAR cluster that, clustered again with the surroundings' scene points, is less than
    this fraction of its component goes on past the silhouettes (:func:`ends_at_silhouette` for a person seen
    in one image; its hull's points against those of every detection's surroundings in
    :func:`detection_ranges`): its range still tells people apart but places no one (a wall behind someone
    the LiDAR does not see passes the feet test a few metres too far at 20 m; a car in front of someone at
    30 m a few metres too near)."""
    feet_tolerance_m: float = 0.4
    """People stand on the ground: a LiDAR cluster is a detection's person, and a left and a right detection
    are one person, only at a depth (the cluster's range; the pairing's median disparity) where the
    detection's feet (the median pixel of its ankles, heels and toes) lie within this of a standing foot's
    height above the ground plane, metres (plus ``gate_sigmas`` times the foot height error of the
    disparity's standard error: the camera's own height above the plane over the depth).
    A car 15 m away inside the silhouette of someone at 22 m puts that person's feet 0.6 m up in the air, a
    left detection paired with someone else's right one at 13 m instead of 22 m 0.8 m; slopes, kerbs and a
    running stride stay within it.  Not tested when no foot is seen or the ground is unknown."""
    lidar_range_sigma_m: float = 0.2
    """Spread of a detection's LiDAR range about the person's (a few keypoints on a neighbour or the
    background), metres: the left/right agreement term is ``(r_l - r_r) / (sqrt(2) sigma)`` and the
    disparity term ``(d - f b / r) / sqrt(se^2 + (f b sigma / r^2)^2)``."""
    tracklet: TrackerConfig = field(default_factory=lambda: TrackerConfig(
        confirm_hits=1, min_track_frames=1, min_mean_score=0.0, max_misses=4, size_sigma=0.25,
        range_sigma_m=0.25))
    """The per-camera 2D tracker (constant velocity in the image, keypoints, size; every detection above
    ``birth_min_score`` ends in a tracklet: the people are judged after pairing)."""
    pair_min_run_frames: int = 3
    """Two tracklets agreeing in stereo over only part of their shared frames (one of them carried on with
    someone else midway) are paired over that part when it holds at least this many paired frames; a pairing
    with fewer frames to pair does not join a tracklet to a person it is seen beside in its image
    (:func:`pair_tracklets`)."""
    tracklet_switch_cost: float = 1.0
    """Added to the normalised distance when an unpaired frame of a tracklet goes to a person not holding
    that tracklet (a tracklet is trusted unless another person explains the frame clearly better)."""
    backward_birth_frames: int = 0
    """A per-camera tracklet's first link is made with no velocity, a guess where two people overlap in the
    image; with this > 0 the tracker also runs backwards in time and a link it makes there with at least this
    many of the person's detections behind it replaces such a guess (:func:`camera_tracklets`); 0 = the
    forward pass alone."""
    end_gap_frames: int = 2
    """A piece of at most 3 frames at a pair track's end that a gap of at least this many frames the track
    does not hold parts from the rest is judged by the rest's walk (:func:`off_walk_pieces`): across such a
    gap the per-camera tracker coasted on a prediction, which whoever walks into it can take up.  A single
    missed frame is common (a detector's miss) and is not a gap here."""
    swap_motion_m: float = 0.05
    """How far a walker's position leaves a straight walk at constant speed over a track (sway, gentle curves,
    pace), metres: the slack of :func:`repair_swaps`' straight-walk test, added to the keypoint noise of the
    image column (at the track's depth) and to the uncertainty of each frame's centre depth."""
    min_height_frames: int = 5
    """A track's frames are checked against the walk of its image heights (:func:`drop_other_heights`) when
    at least this many of them have a height in one image (a walk through fewer fits the frame it should
    judge)."""
    lone_height_gate_sigmas: float = 7.0
    """A frame without a centre (seen in one image, or in both but unpaired) whose image height in an image lies
    more than this many of its sigmas off its track's walk there loses that image's detection even where no
    other track's walk allows that height (:func:`drop_other_heights`): a person keeps their height, and a
    detection that far off it is someone the pair does not track there (seen in that image alone, or hidden
    behind the track's person in the other).  Twice ``gate_sigmas``: at ``gate_sigmas`` itself, 23 of the 25
    detections so dropped over 264 simulated inputs were the track's own person's (scratch count, 2026-12-07;
    docs/detections.md).  ``inf``: never without another track."""
    swap_size_frac: float = 0.03
    """How far a walker's image height leaves the straight walk's (``s0 / (1 + c tau)``, :func:`_walk_cost`)
    beyond its fit error (:func:`standing_height_px`), as a fraction of the height (gait, posture): added to
    that error in quadrature.  On the simulator's detections (seeds 0-2, every format) one person's height
    changes from frame to frame by a robust 0.031-0.043 in log, ~0.03 per frame; two people walking together
    differ by a few to 20 %."""
    min_separation_m: float = 0.35
    """Two bodies' centres are never closer than this in the ground plane, metres: a centre taken from the
    LiDAR that lies closer than this to another person's smoothed centre, and nearer to it than to its own
    person's, is the neighbour's and is taken back (:func:`separate_people`)."""
    separate_max_rounds: int = 8
    """:func:`separate_people` takes back at most this many LiDAR centres (one per round, the clearest
    first)."""
    move_max_runs: int = 16
    """:func:`move_to_neighbours` moves at most this many stretches of a pair's track to the person alongside
    (one per round, the clearest first)."""
    smooth_window_frames: int = 5
    """Each frame's centre is a line in time fitted to as many of the track's centres as a window of this many
    frames on each side holds (``2 W + 1``): those that tell most about the frame, each centre's uncertainty
    grown by how far a walker leaves its line in the time between (half of ``tracker.accel_sigma_mps`` times
    that time squared) — the nearest ones where every frame has a precise centre (step 7), frames."""
    smooth_min_centres: int = 4
    """The walking velocity a track's lines are drawn to is fitted to its centres within four
    ``smooth_window_frames``, but at least this many of them, the nearest in time (at a track's end or after a
    stretch seen in one image, a line through two noisy centres would carry their noise frames beyond
    them)."""
    smooth_motion_m: float = 0.15
    """How far a walker leaves a straight line within that window (added to each centre's uncertainty in
    quadrature), metres."""
    walking_speed_mps: float = 1.4
    """Spread of a person's velocity along each ground-plane axis before its centres are seen, m/s: a track's
    walking velocity (:func:`_trend`) is drawn toward standing with this sigma, so a short track whose few
    centres are noisy (a person mostly hidden: stereo depth from a handful of keypoints) is not given the
    speed its noise suggests, while a walk seen over many frames follows its centres.  Default: adults'
    typical walking speed (about 1.2-1.5 m/s in pedestrian studies); 0 = no prior."""
    stitch_max_gap_frames: int = 10
    """A pair's track of a person lost and found again up to this many frames later is joined to the track
    that found it when one straight walk explains both (:func:`stitch_tracks`), frames; 0 = off.  Given for
    0.1 s between frames: at a higher rate as many frames as cover the same time
    (:func:`~pedx_graph.detections.tracker.frames_for`)."""
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    """What makes a pair's person a track: ``min_track_frames`` (checked again on the output's tracks after
    every repair), ``min_mean_score``, and the speed limits
    (``max_speed_mps``, ``frame_interval_s``) bounding how fast a person's disparity may change."""
    lidar_cut: LidarCutConfig = field(default_factory=LidarCutConfig)
    """How a person's LiDAR points are cut from a scene cloud (when clouds are given)."""

    def __post_init__(self) -> None:
        if isinstance(self.tracker, TrackerConfig) and isinstance(self.tracklet, TrackerConfig) and \
                self.tracker.frame_interval_s != self.tracklet.frame_interval_s:
            raise ValueError(f"association.tracker.frame_interval_s ({self.tracker.frame_interval_s:g}) and "
                             f"association.tracklet.frame_interval_s ({self.tracklet.frame_interval_s:g}) differ: "
                             "both trackers step the same frames; set both")

    @property
    def frame_interval_s(self) -> float:
        """Seconds between consecutive frame numbers, as both trackers use it."""
        return self.tracker.frame_interval_s

    def with_frame_interval(self, seconds: float) -> "AssociationConfig":
        """A copy whose two trackers (``tracker``, ``tracklet``) step ``seconds`` per frame."""
        return dataclasses.replace(self, tracker=dataclasses.replace(self.tracker, frame_interval_s=float(seconds)),
                                   tracklet=dataclasses.replace(self.tracklet, frame_interval_s=float(seconds)))


@dataclass
class DetectedTrackFrame:
    """One person at one frame: the detections of every camera that saw it and its 3D centre."""

    frame: int
    """Frame number."""
    detections: dict[str, Detection]
    """Camera name -> the detection (raw pixels as read, ``track_id`` set to the track's id)."""
    world_p: np.ndarray | None = None
    """(3,) centre of the person in the world (LiDAR) frame, metres (stereo or LiDAR), or None."""
    depth_sigma_m: float = float("inf")
    """Uncertainty of ``world_p`` along the viewing ray, metres."""


@dataclass
class DetectedTrack:
    """One person found in id-less detections: a track id and its frames in increasing order."""

    track_id: str
    """``det000001``, ... in order of first frame (deterministic)."""
    frames: list[DetectedTrackFrame]
    """The frames the person was observed in."""
    pairs: tuple[str, ...]
    """Stereo pairs that saw the person (sorted)."""

    @property
    def mean_score(self) -> float:
        """Mean detection score over every detection of the track."""
        scores = [d.score for fr in self.frames for d in fr.detections.values()]
        return float(np.mean(scores)) if scores else 0.0

    def __len__(self) -> int:
        return len(self.frames)


# ---------------------------------------------------------------------------------------------- helpers

def _usable(uv: np.ndarray, confidence: np.ndarray, min_confidence: float) -> np.ndarray:
    uv = np.where((np.asarray(confidence) >= min_confidence)[:, None], uv, np.nan)
    return uv


def _height(uv: np.ndarray) -> float:
    v = uv[np.all(np.isfinite(uv), axis=1), 1]
    return float(np.ptp(v)) if len(v) >= 2 else 0.0


def drop_duplicates(items: list[tuple[Detection, np.ndarray]], config: AssociationConfig
                    ) -> list[tuple[Detection, np.ndarray]]:
    """The (detection, rectified uv) of one image without duplicates (module docstring, step 2); order kept.

    Detections are taken by score, highest first.  One sharing at least ``min_shared_keypoints`` keypoints
    with a detection already kept, their median distance below ``duplicate_frac`` of the larger one's height,
    is a duplicate: it is dropped, unless the kept one is a fragment of it (:func:`_fragment_of`: a
    detector's partial duplicate, legs or upper body alone, scored above the whole person), which then gives
    way to it."""
    order = sorted(range(len(items)), key=lambda i: -items[i][0].score)
    kept: list[int] = []
    for i in order:
        uv = items[i][1]
        near = [j for j in kept if _within_duplicate_distance(uv, items[j][1], config)]
        if any(not _fragment_of(items[j][1], uv) for j in near):
            continue
        kept = [j for j in kept if j not in near] + [i]
    return [items[i] for i in sorted(kept)]


def _within_duplicate_distance(uv: np.ndarray, other_uv: np.ndarray, config: AssociationConfig) -> bool:
    """Whether two detections of one image (``(K, 2)`` rectified px, NaN where absent) share at least
    ``min_shared_keypoints`` keypoints whose median distance is below ``duplicate_frac`` of the larger one's
    height."""
    both = np.all(np.isfinite(uv), axis=1) & np.all(np.isfinite(other_uv), axis=1)
    if both.sum() < config.min_shared_keypoints:
        return False
    scale = max(_height(uv), _height(other_uv), 1.0)
    return bool(median(np.linalg.norm(uv[both] - other_uv[both], axis=1)) < config.duplicate_frac * scale)


def _fragment_of(uv: np.ndarray, other_uv: np.ndarray) -> bool:
    """Whether a detection (``uv`` (K, 2), NaN where absent) is a fragment of ``other_uv``: a part of that body
    beside the whole of it — each of its present keypoints is present in ``other_uv``, and it lacks every
    keypoint of the top third, or every one of the bottom third, of ``other_uv``'s present keypoints ordered
    by row (at least one keypoint a third).  Two people overlapping in the image, one with its legs hidden,
    hold keypoints the other lacks: neither is a fragment of the other."""
    has, other_has = np.all(np.isfinite(uv), axis=1), np.all(np.isfinite(other_uv), axis=1)
    present = np.flatnonzero(other_has)
    if len(present) < 3 or np.any(has & ~other_has):
        return False
    by_row = present[np.argsort(other_uv[present, 1], kind="stable")]
    third = len(by_row) // 3
    return not has[by_row[:third]].any() or not has[by_row[-third:]].any()


@functools.lru_cache(maxsize=None)
def _standing_rows(keypoint_set: str) -> np.ndarray:
    """(K,) rows of a standing person's keypoints of the set, 0 at the top keypoint to 1 at the bottom one
    (the open body model's mean shape, :func:`~pedx_graph.body.templates.open_standing_keypoints_3d`)."""
    up = open_standing_keypoints_3d(keypoint_set)[:, 1]
    return (up.max() - up) / max(np.ptp(up), 1e-6)


def standing_height_px(uv: np.ndarray, keypoint_set: str, gate: float, floor_px: float) -> tuple[float, float] | None:
    """A detection's height in the image, top keypoint to bottom one of a standing person, pixels, with its
    standard error: ``(height, se)``, or None with fewer than four present keypoints or where they span less
    than a third of the body.

    The present keypoints' rows (``uv`` (K, 2) rectified px, NaN where absent) fitted by least squares with
    :func:`_standing_rows` (``v = top + height * row``), refitted twice without the rows beyond ``gate`` times
    the residuals' robust spread (at least ``floor_px``: a swinging wrist, a lifted foot).  Unlike the present
    keypoints' vertical span it does not shrink when the ankles or the head are missed.  The standard error is
    the fit's own (``s / sqrt(sum (row - mean)^2)``, ``s`` the residuals' RMS): on the simulator's detections
    the frame-to-frame change of one person's height is about that (normalised, robust spread 0.9-1.04, all
    formats; 2-3 % of the height per frame).  Kept per distinct input (:func:`_standing_height`): the
    association asks again for one detection's height each time a track holding it is judged."""
    uv = np.ascontiguousarray(uv, dtype=float)
    return _standing_height(uv.tobytes(), uv.shape, keypoint_set, float(gate), float(floor_px))


@functools.lru_cache(maxsize=1 << 15)
def _standing_height(uv_bytes: bytes, shape: tuple, keypoint_set: str, gate: float,
                     floor_px: float) -> tuple[float, float] | None:
    """:func:`standing_height_px` of the (K, 2) float rows ``uv_bytes`` of ``shape``."""
    uv = np.frombuffer(uv_bytes).reshape(shape)
    rows = _standing_rows(keypoint_set)
    present = np.flatnonzero(np.all(np.isfinite(uv), axis=1))
    if len(present) < 4:
        return None
    keep = np.ones(len(present), dtype=bool)
    for iteration in range(3):
        r = rows[present[keep]]
        if np.ptp(r) < 1.0 / 3.0:
            return None
        design = np.stack([r, np.ones(len(r))], axis=1)
        (height, top), *_ = np.linalg.lstsq(design, uv[present[keep], 1], rcond=None)
        residual = uv[present, 1] - (top + height * rows[present])
        spread = max(1.4826 * float(median(np.abs(residual[keep]))), floor_px)
        new_keep = np.abs(residual) <= gate * spread
        if iteration == 2 or new_keep.sum() < 4 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    if not height > 0:
        return None
    s = float(np.sqrt(np.sum(residual[keep] ** 2) / max(len(r) - 2, 1)))
    return float(height), s / float(np.sqrt(np.sum((r - r.mean()) ** 2)))


def join_misfit(uv_upper: np.ndarray, uv_lower: np.ndarray, keypoint_set: str) -> tuple[float, float] | None:
    """How far two parts of one image, an upper body (K, 2) and hips and legs (K, 2) (rectified px, NaN where
    absent), are from one standing person: ``(RMS row residual, |median column difference|)``, both over the
    height of the standing person fitted to their rows together (scale and offset by least squares against
    :func:`_standing_rows`); None when the fit has no positive height."""
    up = np.all(np.isfinite(uv_upper), axis=1)
    low = np.all(np.isfinite(uv_lower), axis=1)
    rows = _standing_rows(keypoint_set)
    present = np.flatnonzero(up | low)
    v = np.where(up[:, None], uv_upper, uv_lower)[present, 1]
    design = np.stack([rows[present], np.ones(len(present))], axis=1)
    (height, top), *_ = np.linalg.lstsq(design, v, rcond=None)
    if not height > 0:
        return None
    rms = float(np.sqrt(np.mean((v - design @ np.array([height, top])) ** 2)))
    column = abs(float(median(uv_upper[up, 0])) - float(median(uv_lower[low, 0])))
    return rms / height, column / height


def join_split_parts(items: list[tuple[Detection, np.ndarray]], config: AssociationConfig
                     ) -> list[tuple[Detection, np.ndarray]]:
    """The (detection, rectified uv) of one image with each person a bottom-up detector split in two joined
    into one detection (module docstring, step 2): the upper part's detection with the lower part's
    keypoints added, its score the mean confidence of the present keypoints, its source both sources
    (``"<upper> + <lower>"``); the joined ones in the upper part's place, the lower part gone."""
    if not config.join_split_parts or len(items) < 2:
        return items
    by_set: dict[str, list[int]] = defaultdict(list)
    for i, (det, _) in enumerate(items):
        by_set[det.keypoint_set].append(i)
    options = []
    for keypoint_set, indices in by_set.items():
        lower = lower_body_mask(keypoint_set)
        if not lower.any() or lower.all():
            continue
        present = {i: np.all(np.isfinite(items[i][1]), axis=1) for i in indices}
        uppers = [i for i in indices if present[i][~lower].sum() >= 2 and not present[i][lower].any()]
        lowers = [i for i in indices if present[i][lower].sum() >= 2 and not present[i][~lower].any()]
        for i in uppers:
            for j in lowers:
                misfit = join_misfit(items[i][1], items[j][1], keypoint_set)
                if misfit is None:
                    continue
                rows, columns = misfit[0] / config.join_row_sigma, misfit[1] / config.join_column_sigma
                if rows <= config.gate_sigmas and columns <= config.gate_sigmas:
                    options.append((rows ** 2 + columns ** 2, i, j))
    joined: dict[int, tuple[Detection, np.ndarray]] = {}
    gone: set[int] = set()
    for _, i, j in sorted(options):
        if i in joined or i in gone or j in joined or j in gone:
            continue
        (upper, uv_upper), (lower_det, uv_lower) = items[i], items[j]
        take = lower_det.present & lower_body_mask(upper.keypoint_set)
        confidence = np.where(take, lower_det.confidence, upper.confidence)
        occluded = None
        if upper.occluded is not None or lower_det.occluded is not None:
            occluded = np.where(take, lower_det.occluded if lower_det.occluded is not None else False,
                                upper.occluded if upper.occluded is not None else False)
        det = dataclasses.replace(upper, image_uv=np.where(take[:, None], lower_det.image_uv, upper.image_uv),
                                  confidence=confidence, occluded=occluded, bbox=None,
                                  score=float(np.mean(confidence[confidence > 0])),
                                  source=f"{upper.source} + {lower_det.source}")
        joined[i] = (det, np.where(np.all(np.isfinite(uv_upper), axis=1)[:, None], uv_upper, uv_lower))
        gone.add(j)
    return [joined.get(i, item) for i, item in enumerate(items) if i not in gone]


@functools.lru_cache(maxsize=None)
def _nose_and_ankles(keypoint_set: str) -> tuple[int, tuple[int, ...]]:
    """Index of a set's nose (its first keypoint in every shipped set) and of its ankles."""
    names = load_keypoint_set(keypoint_set).keypoints
    return 0, tuple(i for i, name in enumerate(names) if "ankl" in name.lower())


def implied_height_m(uv_left: np.ndarray, uv_right: np.ndarray, calib: StereoCalibration,
                     keypoint_set: str | None) -> float | None:
    """Nose-to-ankle height in metres a left/right pairing implies (pixel span times the depth of the median
    disparity over the focal length), or None when the nose or both ankles are missing in either image."""
    if keypoint_set is None:
        return None
    nose, ankles = _nose_and_ankles(keypoint_set)
    if uv_left.shape[0] <= max((nose,) + ankles, default=0):
        return None
    both = np.all(np.isfinite(uv_left), axis=1) & np.all(np.isfinite(uv_right), axis=1)
    feet = [a for a in ankles if both[a]]
    if not both[nose] or not feet or both.sum() < 3:
        return None
    d_med = float(median(uv_left[both, 0] - uv_right[both, 0]))
    if d_med <= 0:
        return None
    span = float(np.mean([uv_left[a, 1] - uv_left[nose, 1] for a in feet]))
    return span * calib.baseline_m / d_med


def stereo_cost(uv_left: np.ndarray, uv_right: np.ndarray, calib: StereoCalibration,
                config: AssociationConfig, keypoint_set: str | None = None,
                ranges_m: tuple[float | None, float | None] = (None, None),
                ground: GroundFrame | None = None) -> float:
    """Cost of matching a left and a right detection (rectified (K, 2) pixels, unusable keypoints NaN); a
    value >= 1e9 means gated out (module docstring, step 4).  With ``keypoint_set`` given, the person height
    the pairing implies (:func:`implied_height_m`) is a fourth term where the nose and an ankle are seen.
    ``ranges_m``: the detections' LiDAR ranges (:func:`detection_ranges`): where both are known they must
    agree, and the median disparity must match the range (``lidar_range_sigma_m``).  With ``ground`` (and
    ``keypoint_set``), the person at the pairing's depth must stand on the ground (``feet_tolerance_m``)."""
    both = np.all(np.isfinite(uv_left), axis=1) & np.all(np.isfinite(uv_right), axis=1)
    if both.sum() < config.min_shared_keypoints:
        return _GATED
    left, right = uv_left[both], uv_right[both]
    sigma = _keypoint_sigma_px(left, right, config)
    row = float(median(left[:, 1] - right[:, 1])) / (1.2533 * np.sqrt(2.0) * sigma / np.sqrt(len(left)))
    disparity = left[:, 0] - right[:, 0]
    d_med = float(median(disparity))
    if d_med <= 0:
        return _GATED
    depth = calib.focal_px * calib.baseline_m / d_med
    if not config.min_depth_m <= depth <= config.max_depth_m:
        return _GATED
    if ground is not None and keypoint_set is not None:
        # the depth's standard error, seen as a foot height: the ray to the foot descends to the ground
        se_depth = depth / d_med * 1.2533 * np.sqrt(2.0) * sigma / np.sqrt(len(left))
        camera_height = float(ground.height(calib.camera_centre("left")[None])[0])
        slack = config.gate_sigmas * se_depth * abs(camera_height - _FOOT_HEIGHT_M) / depth
        if not _feet_on_ground(keypoint_set, uv_left, calib, "left", depth, ground, config, slack):
            return _GATED
    spread = 1.4826 * float(median(np.abs(disparity - d_med))) / (np.sqrt(2.0) * sigma)
    # the spans over the keypoints whose rows agree: one keypoint misplaced in one image (a wrist put on
    # the hip) stretches one span, not the person's size
    offset = left[:, 1] - right[:, 1]
    agree = np.abs(offset - median(offset)) <= config.gate_sigmas * np.sqrt(2.0) * sigma
    if agree.sum() < max(config.min_shared_keypoints, 0.5 * len(left) + 0.5):
        agree[:] = True
    span_l, span_r = np.ptp(left[agree, 1]), np.ptp(right[agree, 1])
    size = float(np.log(max(span_l, 1.0) / max(span_r, 1.0))) / config.size_sigma if min(span_l, span_r) > 4 else 0.0
    terms = [row, spread, size]
    height_m = implied_height_m(uv_left, uv_right, calib, keypoint_set)
    if height_m is not None:
        terms.append(float(np.log(max(height_m, 1e-3) / config.person_height_m)) / config.person_height_sigma)
    terms = np.array(terms)
    if np.any(np.abs(terms) > config.gate_sigmas):
        return _GATED
    # the LiDAR range terms weigh but never gate (a detection's range can lie on a neighbour): capped at the gate
    known = [r for r in ranges_m if r is not None]
    if known:
        lidar_terms = []
        if len(known) == 2:
            lidar_terms.append((known[0] - known[1]) / (np.sqrt(2.0) * config.lidar_range_sigma_m))
        range_m = float(np.mean(known))
        fb = calib.focal_px * calib.baseline_m
        se = 1.2533 * np.sqrt(2.0) * sigma / np.sqrt(len(left))
        lidar_terms.append((d_med - fb / range_m) / float(np.hypot(se, fb * config.lidar_range_sigma_m / range_m ** 2)))
        terms = np.concatenate([terms, np.minimum(np.abs(lidar_terms), config.gate_sigmas)])
    return float(np.mean(terms ** 2))


def triangulate_centre(uv_left: np.ndarray, uv_right: np.ndarray, calib: StereoCalibration,
                       ground: GroundFrame, config: AssociationConfig) -> tuple[np.ndarray, float]:
    """(3,) world centre of a matched person (median in the level frame of its keypoints triangulated at the
    median disparity) and its depth uncertainty ``Z^2 / (f b) * 1.2533 s / sqrt(n)`` (the standard error of a
    median of ``n`` disparities), metres; ``s`` = the disparities' robust spread ``1.4826 MAD``, at least
    the detector noise of a disparity, ``sqrt(2)`` times one keypoint's (:func:`_keypoint_sigma_px`: a few
    keypoints that happen to agree do not make a depth precise)."""
    both = np.all(np.isfinite(uv_left), axis=1) & np.all(np.isfinite(uv_right), axis=1)
    left, right = uv_left[both], uv_right[both]
    d_med = float(median(left[:, 0] - right[:, 0]))
    P = calib.left_P_rect
    f_u, f_v, c_u, c_v = P[0, 0], P[1, 1], P[0, 2], P[1, 2]
    depth = calib.focal_px * calib.baseline_m / d_med
    rect_p = np.stack([(left[:, 0] - c_u) * depth / f_u, (left[:, 1] - c_v) * depth / f_v,
                       np.full(len(left), depth)], axis=1)
    world_p = calib.rect_to_world(rect_p)
    disparity = left[:, 0] - right[:, 0]
    spread = max(1.4826 * float(median(np.abs(disparity - d_med))),
                 np.sqrt(2.0) * _keypoint_sigma_px(left, right, config))
    sigma = depth ** 2 / (calib.focal_px * calib.baseline_m) * 1.2533 * spread / np.sqrt(max(len(left), 1))
    return ground.median_point(world_p), float(sigma)


def match_stereo(left: list[tuple[Detection, np.ndarray]], right: list[tuple[Detection, np.ndarray]],
                 calib: StereoCalibration, config: AssociationConfig) -> list[tuple[int | None, int | None]]:
    """Pairs ``(left index, right index)`` of one frame's detections of one pair; unmatched detections appear
    with None on the other side.  Gated Hungarian matching on :func:`stereo_cost`."""
    pairs: list[tuple[int | None, int | None]] = []
    used_l, used_r = set(), set()
    if left and right:
        cost = np.array([[stereo_cost(l_uv, r_uv, calib, config,
                                      l_det.keypoint_set if l_det.keypoint_set == r_det.keypoint_set else None)
                          for r_det, r_uv in right] for l_det, l_uv in left])
        rows, cols = linear_sum_assignment(cost)
        for r, c in zip(rows, cols):
            if cost[r, c] < _GATED:
                pairs.append((int(r), int(c)))
                used_l.add(int(r))
                used_r.add(int(c))
    pairs += [(i, None) for i in range(len(left)) if i not in used_l]
    pairs += [(None, j) for j in range(len(right)) if j not in used_r]
    return sorted(pairs, key=lambda p: (p[0] is None, p[0] if p[0] is not None else p[1]))


# ---------------------------------------------------------------------------------------------- LiDAR ranges

def detection_ranges(items: list[tuple[Detection, np.ndarray]], calib: StereoCalibration, side: str,
                     cloud: np.ndarray, ground: GroundFrame, config: AssociationConfig,
                     past: set[int] | None = None) -> dict[int, float]:
    """Id of a detection -> the range of the LiDAR cluster that is its person, metres (median depth along the
    pair's rectified optical axis, the same in both images), for one image's ``(detection, rectified uv)``.

    The scene's non-ground points (higher than ``lidar_cut.ground_clearance_m`` above the ground plane, when
    known) inside any detection's dilated keypoint hull (:func:`~pedx_graph.detections.lidar_cut.hull_polygon`)
    are grouped into clusters: connected components of their ground-plane positions at
    ``lidar_cluster_gap_m`` (a person's scan rings stack vertically; two people a metre apart separate).  A
    cluster is a candidate of a detection when at least ``lidar_identity_min_points`` of its points lie in that
    detection's hull; its *support* is the fraction of the cluster's points that do.  Where two people
    overlap, the near one's hull holds all its own cluster and little of the far one (the far person's
    points the LiDAR sees lie outside the near silhouette), the far one's hull all its own cluster and the
    overlap of the near one: detections and clusters are matched one to one maximising the summed support
    (Hungarian); a detection gets no range when its cluster's support is within ``lidar_support_margin`` of
    its next candidate's or of another detection's support for the same cluster (nothing tells which is its
    person: e.g. the far person fully hidden, one cluster in two overlapping hulls).

    ``past``, when given, gathers the ids of the detections whose cluster goes on past the hulls: clustered
    alike with the scene points of every detection's silhouette and surroundings (:func:`_surroundings_box`),
    the cluster is less than ``lidar_min_support`` of its component — a wall or a car seen through the
    silhouette of someone the LiDAR misses (a person's points end at its silhouette).  Such a range still
    tells people apart but places no one (:func:`lidar_centres`)."""
    from pedx_graph.detections.lidar_cut import hull_polygon, project_cloud
    from pedx_graph.data.segment_cut import segment_indices_from_projection

    cloud = np.asarray(cloud, dtype=float).reshape(-1, 3)
    cloud = cloud[np.all(np.isfinite(cloud), axis=1)]
    if ground.ground_offset_m is not None and len(cloud):
        cloud = cloud[ground.height(cloud) >= config.lidar_cut.ground_clearance_m]
    if not len(cloud) or not items:
        return {}
    uv, depth = project_cloud(calib, side, cloud)
    uv = np.where(np.isfinite(uv), uv, -1e9)
    depth = np.where(np.isfinite(depth), depth, -1.0)
    inside = []
    for _, rect_uv in items:
        polygon = hull_polygon(rect_uv, config.lidar_cut)
        inside.append(np.zeros(0, dtype=np.int64) if polygon is None else
                      segment_indices_from_projection(uv, depth, polygon, config.lidar_cut.min_depth_m))
    used = np.unique(np.concatenate(inside)) if inside else np.zeros(0, dtype=np.int64)
    if not len(used):
        return {}
    label_of = _ground_clusters(ground.to_level(cloud[used])[:, :2], config.lidar_cluster_gap_m)
    n_clusters = int(label_of.max()) + 1
    label = np.full(len(cloud), -1)
    label[used] = label_of
    cluster_size = np.bincount(label_of, minlength=n_clusters)
    support = np.zeros((len(items), n_clusters))
    for i, index in enumerate(inside):
        counts = np.bincount(label[index], minlength=n_clusters) if len(index) else np.zeros(n_clusters)
        support[i] = np.where(counts >= config.lidar_identity_min_points, counts / np.maximum(cluster_size, 1), 0.0)
    candidates = np.flatnonzero(support.max(axis=0, initial=0.0) > 0)
    cluster_range = {int(c): float(median(depth[used[label_of == c]])) for c in candidates}
    going_on = set()
    if past is not None and len(candidates):
        around = np.zeros(len(cloud), dtype=bool)
        around[used] = True
        for _, rect_uv in items:
            box = _surroundings_box(rect_uv, config)
            if box is not None:
                around |= _in_surroundings(uv, depth, box, calib, config)
        wide = np.flatnonzero(around)
        wide_label = _ground_clusters(ground.to_level(cloud[wide])[:, :2], config.lidar_cluster_gap_m)
        component_size = np.bincount(wide_label)[wide_label[np.searchsorted(wide, used)]]
        going_on = {int(c) for c in candidates
                    if cluster_size[c] < config.lidar_min_support * component_size[int(np.argmax(label_of == c))]}
    for i, (det, rect_uv) in enumerate(items):
        for c in np.flatnonzero(support[i] > 0):
            # a cluster at a range where the person would float above the ground or sink into it is not its
            # person (a car or a pole between the camera and someone farther, inside the silhouette)
            if not _feet_on_ground(det.keypoint_set, rect_uv, calib, side, cluster_range[int(c)], ground, config):
                support[i, c] = 0.0
    rows, cols = linear_sum_assignment(-support)
    out = {}
    for i, c in zip(rows, cols):
        if support[i, c] <= 0:
            continue
        others = np.delete(support[i], c)                  # the detection's other clusters
        rivals = np.delete(support[:, c], i)               # the cluster's other detections
        if any(len(x) and x.max() > 0 and support[i, c] - x.max() < config.lidar_support_margin
               for x in (others, rivals)):
            continue
        out[id(items[i][0])] = cluster_range[int(c)]
        if int(c) in going_on:
            past.add(id(items[i][0]))
    return out


def _ground_clusters(level_xy: np.ndarray, gap_m: float) -> np.ndarray:
    """(N,) cluster label of each of N ground-plane positions (N, 2): connected components of the points closer
    than ``gap_m``, labels 0, 1, ..."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = cKDTree(level_xy).query_pairs(gap_m, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(level_xy), len(level_xy)))
    return connected_components(graph, directed=False)[1]


def _surroundings_box(rect_uv: np.ndarray, config: AssociationConfig) -> tuple[float, ...] | None:
    """``(centre, half, reach, v_min, v_max)``, rectified pixels: a detection's silhouette is the columns
    within ``half`` of ``centre`` (its keypoints' columns grown by the cut's hull's dilation, widened to at
    least ``lidar_body_width_frac`` of their image height: a walker seen from the side has its keypoints on
    one line, its body's points a chest's depth across) and the rows from ``v_min`` to ``v_max`` (its
    keypoints' rows grown alike); its surroundings, the same rows out to ``reach`` of ``centre``
    (``lidar_context_frac`` of that height further on both sides).  None with fewer than
    ``lidar_cut.min_keypoints`` (and three) keypoints."""
    from pedx_graph.detections.lidar_cut import border_margin_px

    rect_uv = np.asarray(rect_uv, dtype=float)
    present = rect_uv[np.all(np.isfinite(rect_uv), axis=1)]
    if len(present) < max(config.lidar_cut.min_keypoints, 3):
        return None
    lo, hi = present.min(axis=0), present.max(axis=0)
    height = float(hi[1] - lo[1])
    grow = border_margin_px(rect_uv, config.lidar_cut)             # the cut's hull's dilation
    half = max(0.5 * float(hi[0] - lo[0]) + grow, 0.5 * config.lidar_body_width_frac * height)
    return (0.5 * float(lo[0] + hi[0]), half, half + config.lidar_context_frac * height,
            float(lo[1]) - grow, float(hi[1]) + grow)


def _in_surroundings(uv: np.ndarray, depth: np.ndarray, box: tuple, calib: StereoCalibration,
                     config: AssociationConfig) -> np.ndarray:
    """(N,) bool: which of N projected points (``uv`` (N, 2) rectified pixels, ``depth`` (N,) metres along
    the optical axis) lie in front of the camera (``lidar_cut.min_depth_m``), inside the image, in a
    detection's silhouette or surroundings (``box``: :func:`_surroundings_box`)."""
    centre, _, reach, v_min, v_max = box
    width, height = calib.image_size
    with np.errstate(invalid="ignore"):
        return (uv[:, 1] >= max(v_min, 0.0)) & (uv[:, 1] < min(v_max, float(height))) & \
            (depth > config.lidar_cut.min_depth_m) & (np.abs(uv[:, 0] - centre) <= reach) & \
            (uv[:, 0] >= 0.0) & (uv[:, 0] < width)


def ends_at_silhouette(rect_uv: np.ndarray, calib: StereoCalibration, side: str, cloud: np.ndarray,
                       ground: GroundFrame, range_m: float, config: AssociationConfig,
                       projection: tuple[np.ndarray, np.ndarray] | None = None) -> bool:
    """Whether the LiDAR cluster a detection's range comes from (:func:`detection_ranges`) ends at the
    person's silhouette (:func:`_surroundings_box`, as its surroundings).  The scene points above the ground
    in the silhouette are clustered in the ground plane (``lidar_cluster_gap_m``), the cluster
    whose median depth is nearest ``range_m`` taken; clustered again with the surroundings' points, it must be
    at least ``lidar_min_support`` of its component.  A person's points end at its silhouette; a wall's or a
    parked car's, seen through the silhouette of someone the LiDAR misses, go on past it (as do a person's
    merged with someone undetected beside it: the range is right, but nothing tells).  True when nothing can
    be judged (too few keypoints, no points).  ``rect_uv``: (K, 2) rectified pixels in the pair's ``side``
    image; ``cloud``: (N, 3) world points; ``projection``: ``cloud`` projected into that image
    (:func:`~pedx_graph.detections.lidar_cut.project_cloud`), when already done."""
    from pedx_graph.detections.lidar_cut import project_cloud

    cloud = np.asarray(cloud, dtype=float).reshape(-1, 3)
    box = _surroundings_box(rect_uv, config)
    if box is None or not len(cloud):
        return True
    uv, depth = projection if projection is not None else project_cloud(calib, side, cloud)
    near = np.flatnonzero(_in_surroundings(uv, depth, box, calib, config))
    offset = np.abs(uv[:, 0] - box[0])
    half = box[1]
    if ground.ground_offset_m is not None and len(near):
        near = near[ground.height(cloud[near]) >= config.lidar_cut.ground_clearance_m]
    inside = near[offset[near] <= half]
    if not len(inside):
        return True
    own = _ground_clusters(ground.to_level(cloud[inside])[:, :2], config.lidar_cluster_gap_m)
    medians = [float(median(depth[inside[own == c]])) for c in range(int(own.max()) + 1)]
    cluster = inside[own == int(np.argmin(np.abs(np.asarray(medians) - range_m)))]
    grown = _ground_clusters(ground.to_level(cloud[near])[:, :2], config.lidar_cluster_gap_m)
    component = grown[np.searchsorted(near, cluster[0])]
    return len(cluster) >= config.lidar_min_support * int(np.sum(grown == component))


# ---------------------------------------------------------------------------------------------- tracklets

def _tracklet_links(per_frame: Mapping[int, list[tuple[Detection, np.ndarray]]], config: AssociationConfig,
                    ranges: Mapping[int, float], backward: bool) -> tuple[dict[tuple[int, int], int], set[int]]:
    """One pass of the per-camera tracker over ``per_frame``, forwards or backwards in time: its links as (id
    of the earlier detection, id of the later one) -> how many of the tracklet's detections lie behind the
    link in the pass's direction (1: the tracklet's first link, made with no velocity), and the ids of the
    detections its tracklets hold (every one scored at least ``tracklet.birth_min_score``, in either pass)."""
    sign = -1 if backward else 1
    tracker = Tracker(config.tracklet)
    for frame in sorted(per_frame, key=lambda f: sign * f):
        tracker.step(sign * frame, [Observation(frame=sign * frame, uv={"left": uv}, score=float(det.score),
                                                payload=(det, uv), lidar_range_m=ranges.get(id(det)))
                                    for det, uv in per_frame[frame]])
    links, held = {}, set()
    for observations in tracker.tracks():
        held.update(id(o.payload[0]) for o in observations)
        for k in range(1, len(observations)):
            earlier, later = id(observations[k - 1].payload[0]), id(observations[k].payload[0])
            links[(later, earlier) if backward else (earlier, later)] = k
    return links, held


def _birth_links_checked(forward: dict[tuple[int, int], int], backward: dict[tuple[int, int], int],
                         min_frames: int) -> dict[int, int]:
    """Id of a detection -> id of the next one in its tracklet: the forward pass's links, except its
    tracklets' first links (made with no velocity) that the backward pass does not make, where a backward
    link made with at least ``min_frames`` of the person behind it (its velocity known) and sharing a
    detection with one of them takes its place first (the more it knew, the earlier; then in the backward
    pass's order).  ``forward`` / ``backward``: :func:`_tracklet_links`' links; each detection keeps at most one
    link to the past and one to the future."""
    guesses = {link for link, known in forward.items() if known == 1 and link not in backward}
    earlier, later = {a for a, _ in guesses}, {b for _, b in guesses}
    options = [(0, 0, link) for link in forward if link not in guesses]
    options += [(1, -known, link) for link, known in backward.items()
                if link not in forward and known >= min_frames and (link[0] in earlier or link[1] in later)]
    options += [(2, 0, link) for link in guesses]
    links: dict[int, int] = {}
    linked_to: set[int] = set()
    for _, _, (a, b) in sorted(options, key=lambda option: option[:2]):   # stable: the passes' own order
        if a in links or b in linked_to:
            continue
        links[a] = b
        linked_to.add(b)
    return links


def camera_tracklets(per_frame: Mapping[int, list[tuple[Detection, np.ndarray]]], config: AssociationConfig,
                     ranges: Mapping[int, float] | None = None) -> list[list[tuple[int, Detection, np.ndarray]]]:
    """One camera's detections linked over frames (module docstring, step 3): ``per_frame`` maps a frame to its
    de-duplicated ``(detection, rectified uv)``; returns tracklets, each a list of ``(frame, detection, uv)`` in
    frame order, in order of their first detection (a detection in exactly one tracklet; the low-score ones
    alone, last); ``ranges``: id of a detection -> its LiDAR range (:func:`detection_ranges`), a term of the
    tracker's cost.

    A tracklet just born has no velocity and takes its next detection by position alone: where two people
    overlap in the image at a person's first frames (a sequence's start, or one person emerging from behind
    the other) that is a guess.  With ``backward_birth_frames`` > 0 the tracker also runs backwards in time,
    reaching those frames with the people's motion known, and its links replace the forward pass's guesses
    (:func:`_birth_links_checked`)."""
    ranges = ranges or {}
    frames = sorted(per_frame)
    position = {id(det): (frame, k) for frame in frames for k, (det, _) in enumerate(per_frame[frame])}
    item = {id(det): (frame, det, uv) for frame in frames for det, uv in per_frame[frame]}
    forward, held = _tracklet_links(per_frame, config, ranges, backward=False)
    if config.backward_birth_frames > 0:
        backward, _ = _tracklet_links(per_frame, config, ranges, backward=True)
        links = _birth_links_checked(forward, backward, config.backward_birth_frames)
    else:
        links = {a: b for a, b in forward}
    linked_to = set(links.values())
    out = []
    for start in sorted(held - linked_to, key=position.__getitem__):
        tracklet, key = [item[start]], start
        while key in links:
            key = links[key]
            tracklet.append(item[key])
        out.append(tracklet)
    for frame in frames:                                   # below the birth score: one-frame tracklets
        out += [[(frame, det, uv)] for det, uv in per_frame[frame] if id(det) not in held]
    return out


def _frame_terms(uv_left: np.ndarray, uv_right: np.ndarray, calib: StereoCalibration,
                 config: AssociationConfig, keypoint_set: str | None = None,
                 ranges_m: tuple[float | None, float | None] = (None, None),
                 ground: GroundFrame | None = None) -> tuple[float, float, float] | None:
    """One frame's stereo evidence of a left and a right detection: ``(cost, disparity px, its standard error
    px)``; None when gated (:func:`stereo_cost`)."""
    cost = stereo_cost(uv_left, uv_right, calib, config, keypoint_set, ranges_m, ground)
    if cost >= _GATED:
        return None
    disparity, se = _disparity_of(uv_left, uv_right, config)      # stereo_cost passed: enough shared keypoints
    return cost, disparity, se


def _detection_pair_terms(det_left: Detection, uv_left: np.ndarray, det_right: Detection, uv_right: np.ndarray,
                          calib: StereoCalibration, config: AssociationConfig,
                          ranges: Mapping[int, float] | None = None,
                          ground: GroundFrame | None = None) -> tuple[float, float, float] | None:
    """:func:`_frame_terms` of a left and a right detection: the height term where both have one keypoint
    set, their LiDAR ranges where ``ranges`` (id of a detection -> range) holds them."""
    kset = det_left.keypoint_set if det_left.keypoint_set == det_right.keypoint_set else None
    pair_ranges = (ranges.get(id(det_left)), ranges.get(id(det_right))) if ranges else (None, None)
    return _frame_terms(uv_left, uv_right, calib, config, kset, pair_ranges, ground)


def _smooth_disparity(frames: np.ndarray, disparity: np.ndarray, se: np.ndarray, calib: StereoCalibration,
                      config: AssociationConfig) -> np.ndarray:
    """Normalised residuals of per-frame disparities about the best line ``d(f) = a + b f`` whose slope a
    walker's depth change allows (``|b| <= d^2 / (f_px B) * max_speed * dt``); robust (iterated, outliers
    down-weighted)."""
    if len(frames) < 2:
        return np.zeros(len(frames))
    sigma = np.hypot(se, config.disparity_smooth_px)
    d_med = float(median(disparity))
    max_slope = d_med ** 2 / (calib.focal_px * calib.baseline_m) * config.tracker.max_speed_mps \
        * config.tracker.frame_interval_s
    f0 = float(median(frames))
    weight = 1.0 / sigma ** 2
    a, b = d_med, 0.0
    for _ in range(4):
        x = frames - f0
        wsum = weight.sum()
        xm, ym = (weight * x).sum() / wsum, (weight * disparity).sum() / wsum
        var = (weight * (x - xm) ** 2).sum()
        b = float(np.clip((weight * (x - xm) * (disparity - ym)).sum() / var if var > 0 else 0.0,
                          -max_slope, max_slope))
        a = ym - b * xm
        z = (disparity - a - b * x) / sigma
        weight = np.where(np.abs(z) > config.gate_sigmas, 1e-6, 1.0) / sigma ** 2
    return (disparity - a - b * (frames - f0)) / sigma


def _pair_gains(left: list, right: list, calib: StereoCalibration, config: AssociationConfig,
                ranges: Mapping[int, float] | None = None,
                ground: GroundFrame | None = None) -> tuple[list[int], np.ndarray]:
    """Per shared frame of a left and a right tracklet, in frame order: the frames and their pairing gains.
    A frame whose stereo terms pass the gates and whose disparity lies within ``gate_sigmas`` of the
    tracklets' smooth disparity gains ``gate_sigmas^2 / 2`` minus its cost (the stereo terms and the
    disparity residual); every other shared frame ``-gate_sigmas^2 / 2``."""
    by_frame = {frame: (det, uv) for frame, det, uv in right}
    items = []
    for frame, det, uv_left in left:
        if frame in by_frame:
            items.append((frame, _detection_pair_terms(det, uv_left, *by_frame[frame], calib, config, ranges,
                                                       ground)))
    items.sort(key=lambda item: item[0])
    c0 = 0.5 * config.gate_sigmas ** 2
    gain = np.full(len(items), -c0)
    good = [k for k, (_, terms) in enumerate(items) if terms is not None]
    if good:
        frames = np.array([items[k][0] for k in good], dtype=float)
        z = _smooth_disparity(frames, np.array([items[k][1][1] for k in good]),
                              np.array([items[k][1][2] for k in good]), calib, config)
        for k, zf in zip(good, z):
            if abs(zf) <= config.gate_sigmas:
                gain[k] = c0 - 0.5 * (items[k][1][0] + zf ** 2)   # the stereo terms and the disparity residual
    return [frame for frame, _ in items], gain


def _pair_runs(frames: list[int], gain: np.ndarray, config: AssociationConfig) -> list[tuple[float, list[int]]]:
    """Evidence that a left and a right tracklet are one person, as ``(evidence, paired frames)`` per stretch of
    their shared ``frames`` (in order, with their pairing ``gain``, :func:`_pair_gains`).  A passing frame adds
    its gain; every failing one subtracts ``gate_sigmas^2 / 2`` (the pairing evidence changes there: those
    frames stay unpaired); a contested one (NaN, :func:`contest_frames`) adds nothing and stays unpaired.  The
    stretches are the runs of consecutive shared frames with the largest summed evidence, found in turn
    (:func:`_supported_runs`): a per-camera tracker that carried one of the two tracklets on
    with someone else midway leaves the part before the switch paired, where a sum over the whole overlap
    would reject both parts.  A single failing frame between two passing ones counts zero instead (a
    detector's one-frame glitch is no change of person; it stays unpaired).  A run shorter than the whole
    overlap counts only with at least ``pair_min_run_frames`` paired frames.  When no run counts, the whole
    overlap does where its summed evidence is positive and at least ``pair_min_run_frames`` of its frames
    pass: the two agree in most frames, the failing ones scattered among them (a detector that reports, in
    one image, now the person and now someone beside it), not a tracklet gone on with someone else."""
    if not frames:
        return []
    c0 = 0.5 * config.gate_sigmas ** 2
    # one failing frame between two passing ones is a detector's glitch, not a change of person: it does not
    # break the run (it adds nothing and stays unpaired)
    contested = np.isnan(gain)
    passing = gain > -c0
    failing = ~passing & ~contested
    glitch = failing & np.r_[False, passing[:-1]] & np.r_[passing[1:], False]
    runs_gain = np.where(glitch | contested, 0.0, gain)
    out = []
    for lo, hi in _supported_runs(runs_gain):
        paired = [frames[k] for k in range(lo, hi) if passing[k]]
        whole = lo == 0 and hi == len(frames)
        if paired and (whole or len(paired) >= config.pair_min_run_frames):
            out.append((float(runs_gain[lo:hi].sum()), paired))
    passed = [frames[k] for k in range(len(frames)) if passing[k]]
    if not out and runs_gain.sum() > 0 and len(passed) >= config.pair_min_run_frames:
        out.append((float(runs_gain.sum()), passed))
    return out


def _supported_runs(gain: np.ndarray) -> list[tuple[int, int]]:
    """Disjoint index ranges ``[lo, hi)`` of ``gain`` with a positive sum: the maximum-sum run, then the same
    on what lies left and right of it (Kadane's scan, recursively)."""
    if len(gain) == 0:
        return []
    best, best_lo, best_hi = -np.inf, 0, 0
    total, start = 0.0, 0
    for k, value in enumerate(gain):
        if total <= 0.0:
            total, start = 0.0, k
        total += float(value)
        if total > best:
            best, best_lo, best_hi = total, start, k + 1
    if best <= 0.0:
        return []
    return _supported_runs(gain[:best_lo]) + [(best_lo, best_hi)] + \
        [(best_hi + lo, best_hi + hi) for lo, hi in _supported_runs(gain[best_hi:])]


def _interpolation_cost(observed: dict, frame: int, uv: np.ndarray, config: AssociationConfig) -> float | None:
    """How far ``uv`` lies from a person's keypoints in the same image at ``frame``, in sigmas: the median
    keypoint distance from the person's keypoints linearly interpolated between its nearest observations
    before and after (extrapolated at the body's velocity between its two nearest observations on one side,
    the median keypoint step, when only one side exists; held with a single one), over
    :func:`~pedx_graph.detections.tracker.image_sigma_px` of ``tracklet`` at ``h`` and the gap, and the log
    ratio of the
    keypoints' vertical spans over ``tracklet.size_sigma`` (capped at ``tracklet.gate_sigmas``), added in
    quadrature.  ``observed``: frame -> (tracklet, detection, uv).  None when the person has no observation
    of that image within ``tracklet.max_misses`` frames."""
    frames = np.array(sorted(observed))
    if len(frames) == 0 or frame in observed:
        return None
    before, after = frames[frames < frame], frames[frames > frame]
    f0 = int(before[-1]) if len(before) else None
    f1 = int(after[0]) if len(after) else None
    gaps = [abs(frame - g) for g in (f0, f1) if g is not None]
    if min(gaps) > frames_for(config.tracklet, config.tracklet.max_misses):
        return None
    if f0 is not None and f1 is not None:
        w = (frame - f0) / (f1 - f0)
        predicted = (1 - w) * observed[f0][2] + w * observed[f1][2]
        gap = min(gaps)
    else:
        # one side only: the two nearest observations' velocity carries the keypoints on (held with one)
        near = before[-2:] if f0 is not None else after[:2]
        anchor = f0 if f0 is not None else f1
        predicted = observed[anchor][2]
        if len(near) == 2:
            # the body's velocity (the median keypoint step, as the tracker's): swinging limbs' own steps would
            # be carried on too
            step = (observed[int(near[1])][2] - observed[int(near[0])][2]) / float(near[1] - near[0])
            shared = np.all(np.isfinite(step), axis=1)
            if shared.sum() >= 2:
                predicted = predicted + median(step[shared], axis=0) * (frame - anchor)
        gap = gaps[0] * 2                          # extrapolated: the velocity itself is uncertain
    both = np.all(np.isfinite(predicted), axis=1) & np.all(np.isfinite(uv), axis=1)
    if both.sum() < config.min_shared_keypoints:
        return None
    height = max(np.ptp(predicted[both, 1]), np.ptp(uv[both, 1]), 1.0)
    sigma = image_sigma_px(config.tracklet, height, gap)
    distance = float(median(np.linalg.norm(predicted[both] - uv[both], axis=1))) / sigma
    size = 0.0
    span_pred, span_obs = np.ptp(predicted[both, 1]), np.ptp(uv[both, 1])
    if config.tracklet.size_sigma > 0 and min(span_pred, span_obs) > 4 * config.tracklet.keypoint_sigma_px:
        size = min(abs(float(np.log(span_obs / span_pred))) / config.tracklet.size_sigma, config.tracklet.gate_sigmas)
    return float(np.hypot(distance, size))


def _keypoint_sigma_px(left: np.ndarray, right: np.ndarray, config: AssociationConfig) -> float:
    """One detected keypoint's noise per axis, pixels, for a left and a right detection's shared keypoints
    (``(n, 2)`` each): ``keypoint_sigma_px + keypoint_sigma_frac * h``, ``h`` the larger of their vertical
    spans (the person's image height)."""
    return config.keypoint_sigma_px + config.keypoint_sigma_frac * max(float(np.ptp(left[:, 1])),
                                                                       float(np.ptp(right[:, 1])))


def _disparity_of(uv_left: np.ndarray, uv_right: np.ndarray, config: AssociationConfig) -> tuple[float, float] | None:
    """A left and a right detection's median disparity over their shared keypoints and its standard error,
    pixels (``1.2533 sqrt(2) sigma / sqrt(n)``, ``sigma = keypoint_sigma_px + keypoint_sigma_frac * h``); None
    with fewer than ``min_shared_keypoints`` shared."""
    both = np.all(np.isfinite(uv_left), axis=1) & np.all(np.isfinite(uv_right), axis=1)
    if both.sum() < config.min_shared_keypoints:
        return None
    sigma = _keypoint_sigma_px(uv_left[both], uv_right[both], config)
    return (float(median(uv_left[both, 0] - uv_right[both, 0])),
            float(1.2533 * np.sqrt(2.0) * sigma / np.sqrt(both.sum())))


def _paired_disparities(person: "_Person", config: AssociationConfig) -> list[tuple[int, float, float]]:
    """``(frame, disparity px, its standard error px)`` of a person's paired frames (:func:`_disparity_of`),
    in frame order."""
    out = []
    for frame in sorted(f for f in person.paired if f in person.sides["left"] and f in person.sides["right"]):
        item = _disparity_of(person.sides["left"][frame][2], person.sides["right"][frame][2], config)
        if item is not None:
            out.append((frame, *item))
    return out


def _person_depths(person: "_Person", calib: StereoCalibration, config: AssociationConfig,
                   ranges: Mapping[int, float] | None) -> dict[int, tuple[float, float]]:
    """frame -> (depth along the pair's rectified optical axis m, its standard error m) of a person under
    construction: from the median disparity of its paired frames (``f B / d``; the disparity's standard error
    of :func:`_disparity_of`), else from the mean LiDAR range of its detections (``lidar_range_sigma_m``)."""
    fb = calib.focal_px * calib.baseline_m
    out = {frame: (fb / d_med, fb / d_med ** 2 * se_px) for frame, d_med, se_px in _paired_disparities(person, config)
           if d_med > 0}
    for frame in (set(person.sides["left"]) | set(person.sides["right"])) - set(out):
        held = [person.sides[s][frame] for s in ("left", "right") if frame in person.sides[s]]
        known = [ranges[id(item[1])] for item in held if ranges and id(item[1]) in ranges]
        if known:
            out[frame] = (float(np.mean(known)), config.lidar_range_sigma_m)
    return out


def _depth_residual(depths: dict[int, tuple[float, float]], frame: int, range_m: float,
                    config: AssociationConfig, range_sigma_m: float | None = None) -> float:
    """How far a detection's LiDAR range lies from a person's depth at ``frame`` (:func:`_person_depths`,
    linearly interpolated between its nearest known frames before and after, else held from the nearest), in
    sigmas: the range's ``lidar_range_sigma_m`` (or ``range_sigma_m``, for a depth measured otherwise), the
    depth's standard error and a walker's depth change over the gap (``tracker.max_speed_mps`` for a held
    depth, ``tracklet.accel_sigma_mps`` for an interpolated one) in quadrature; capped at
    ``tracklet.gate_sigmas`` (a range can lie on a neighbour); 0 without depths."""
    if not depths:
        return 0.0
    frames = np.array(sorted(depths))
    before, after = frames[frames <= frame], frames[frames >= frame]
    dt = config.tracker.frame_interval_s
    if len(before) and len(after):
        f0, f1 = int(before[-1]), int(after[0])
        w = 0.0 if f1 == f0 else (frame - f0) / (f1 - f0)
        depth = (1 - w) * depths[f0][0] + w * depths[f1][0]
        se = float(np.hypot(depths[f0][1], depths[f1][1]))
        motion = config.tracklet.accel_sigma_mps * min(frame - f0, f1 - frame) * dt
    else:
        near = int(before[-1]) if len(before) else int(after[0])
        depth, se = depths[near]
        motion = config.tracker.max_speed_mps * abs(frame - near) * dt
    range_sigma_m = config.lidar_range_sigma_m if range_sigma_m is None else range_sigma_m
    sigma = float(np.sqrt(range_sigma_m ** 2 + se ** 2 + motion ** 2))
    return min(abs(range_m - depth) / sigma, config.tracklet.gate_sigmas)


@dataclass
class _Person:
    """A pair track under construction: per side, frame -> (tracklet index, detection, uv)."""

    sides: dict = field(default_factory=lambda: {"left": {}, "right": {}})
    tracklets: set = field(default_factory=set)
    paired: set = field(default_factory=set)
    """Frames whose left and right detections were paired by tracklet evidence (the ones triangulated)."""

    def conflicts(self, side: str, frames) -> bool:
        return any(f in self.sides[side] for f in frames)

    def beside(self, side: str, index: int, tracklets: list[list]) -> bool:
        """Whether ``side``'s tracklet ``index`` (of ``tracklets``, that image's) holds a detection at a frame
        where another of that image's tracklets this person holds has one too, inside the stretch of frames
        the person holds of it: two people seen side by side in that image."""
        mine = {f for f, _, _ in tracklets[index]}
        for other_side, other in self.tracklets:
            if other_side != side or other == index:
                continue
            held = [f for f, (tracklet, _, _) in self.sides[side].items() if tracklet == other]
            if held and any(min(held) <= f <= max(held) and f in mine for f, _, _ in tracklets[other]):
                return True
        return False


def contest_frames(gains: dict, config: AssociationConfig) -> None:
    """Keep each passing frame only for its detections' best pairing, in place.  ``gains``: (left tracklet,
    right tracklet) -> (shared frames, their pairing gains, :func:`_pair_gains`).  At a frame where the left
    detection pairs better (a higher gain) with another right tracklet's detection, or the right detection
    with another left tracklet's, the pairing's frame is contested: NaN, which :func:`_pair_runs` counts as
    zero evidence and leaves unpaired.  Only a rival pairing that stands on its own at that frame contests
    (the frame lies in one of its own supported runs, :func:`_pair_runs`): a chance agreement for a frame or
    two, with a neighbour's or a fragment's tracklet, takes nothing away.  The case: one image's tracker
    carried a tracklet on with a neighbour beside the person (a few pixels of disparity off) while the
    person's own detection at that frame is in another, shorter tracklet; summed over the whole run, the
    carried-on tracklet outweighs the person's own, though at those frames the person's own detection is the
    better match."""
    c0 = 0.5 * config.gate_sigmas ** 2
    best = {"left": defaultdict(lambda: -np.inf), "right": defaultdict(lambda: -np.inf)}
    for (i, j), (frames, gain) in gains.items():
        supported = {f for _, paired in _pair_runs(frames, gain, config) for f in paired}
        for f, g in zip(frames, gain):
            if f in supported:
                best["left"][(i, f)] = max(best["left"][(i, f)], g)
                best["right"][(j, f)] = max(best["right"][(j, f)], g)
    for (i, j), (frames, gain) in gains.items():
        for k, (f, g) in enumerate(zip(frames, gain)):
            if g > -c0 and (g < best["left"][(i, f)] or g < best["right"][(j, f)]):
                gain[k] = np.nan


def pair_tracklets(left: list[list], right: list[list], calib: StereoCalibration, config: AssociationConfig,
                   ranges: Mapping[int, float] | None = None, ground: GroundFrame | None = None) -> list[_Person]:
    """Group one pair's left and right tracklets into people (module docstring, step 4); ``ranges``: id of a
    detection -> its LiDAR range (:func:`detection_ranges`); ``ground``: people stand on it
    (``feet_tolerance_m``)."""
    gains = {}
    for i, lt in enumerate(left):
        l_frames = {f for f, _, _ in lt}
        for j, rt in enumerate(right):
            if l_frames & {f for f, _, _ in rt}:
                gains[(i, j)] = _pair_gains(lt, rt, calib, config, ranges, ground)
    contest_frames(gains, config)
    edges = []
    for (i, j), (frames, gain) in gains.items():
        for evidence, paired in _pair_runs(frames, gain, config):
            edges.append((-evidence, i, j, paired))
    edges.sort(key=lambda e: e[:3])
    people: list[_Person] = []
    used = {"left": defaultdict(set), "right": defaultdict(set)}      # tracklet -> frames already paired
    for _, i, j, paired in edges:
        frames = [f for f in paired if f not in used["left"][i] and f not in used["right"][j]]
        if not frames:
            continue
        l_items = {f: (i, d, uv) for f, d, uv in left[i] if f in frames}
        r_items = {f: (j, d, uv) for f, d, uv in right[j] if f in frames}
        candidates = [p for p in people if ("left", i) in p.tracklets or ("right", j) in p.tracklets]
        joined = [p for p in candidates if not p.conflicts("left", l_items) and not p.conflicts("right", r_items)]
        if len(frames) < config.pair_min_run_frames and any(
                (side, index) not in p.tracklets and p.beside(side, index, tracklets)
                for p in joined for side, index, tracklets in (("left", i, left), ("right", j, right))):
            continue              # too short to join a tracklet to a person it is seen beside
        if joined:
            target = joined[0]
            for other in joined[1:]:                # the edge links two people: one person if they never clash
                if not any(target.conflicts(s, other.sides[s]) for s in ("left", "right")):
                    for s in ("left", "right"):
                        target.sides[s].update(other.sides[s])
                    target.tracklets |= other.tracklets
                    target.paired |= other.paired
                    people.remove(other)
        else:
            target = _Person()
            people.append(target)
        target.sides["left"].update(l_items)
        target.sides["right"].update(r_items)
        target.tracklets |= {("left", i), ("right", j)}
        target.paired.update(frames)
        used["left"][i].update(frames)
        used["right"][j].update(frames)
    # the tracklets' unpaired frames go to the person whose own observations of that image, interpolated in
    # time, agree best (a tracklet that took another person's detection for a frame gives it back)
    leftovers = [(side, index, f, d, uv) for side, tracklets in (("left", left), ("right", right))
                 for index, tracklet in enumerate(tracklets) for f, d, uv in tracklet if f not in used[side][index]]
    snapshot = [{s: dict(p.sides[s]) for s in ("left", "right")} for p in people]
    depths = [_person_depths(p, calib, config, ranges) for p in people]
    options = []
    for n, (side, index, f, det, uv) in enumerate(leftovers):
        range_m = ranges.get(id(det)) if ranges else None
        for k, person in enumerate(people):
            cost = _interpolation_cost(snapshot[k][side], f, uv, config)
            if cost is None:
                continue
            if (side, index) not in person.tracklets:
                cost += config.tracklet_switch_cost
            if cost > config.tracklet.gate_sigmas:
                continue
            if range_m is not None:       # the range weighs in the choice but never gates (it can lie on a neighbour)
                cost = float(np.hypot(cost, _depth_residual(depths[k], f, range_m, config)))
            options.append((cost, n, k))
    placed = set()
    for _, n, k in sorted(options):
        side, index, f, d, uv = leftovers[n]
        if n in placed or f in people[k].sides[side]:
            continue
        people[k].sides[side][f] = (index, d, uv)
        people[k].tracklets.add((side, index))
        placed.add(n)
    alone: dict[tuple[str, int], _Person] = {}
    for n, (side, index, f, d, uv) in enumerate(leftovers):
        if n not in placed:
            alone.setdefault((side, index), _Person(tracklets={(side, index)})).sides[side][f] = (index, d, uv)
    people += list(alone.values())
    return complete_frames(people, calib, config, ranges, ground)


def complete_frames(people: list[_Person], calib: StereoCalibration, config: AssociationConfig,
                    ranges: Mapping[int, float] | None = None, ground: GroundFrame | None = None) -> list[_Person]:
    """Move a detection seen in one image of a person's frame to another person that holds only the other
    image's detection at that frame, where the two pair in stereo (:func:`_completion_cost`) and that explains
    the detection better than its own person's neighbouring detections in its image do
    (:func:`_interpolation_cost`; a detection with a LiDAR range also weighs how far it lies from each
    person's depth, :func:`_depth_residual`); ``tracklet_switch_cost`` is added for a person not holding the
    detection's tracklet, and a move costs at most ``tracklet.gate_sigmas``.  The frame becomes a paired one
    of the receiving person.  The case: a person missed in one image for a few frames while the tracker of
    that image carried a neighbour's tracklet through the one frame where the person was seen there; the
    detection's single stereo frame is too short for tracklet pairing (``pair_min_run_frames``) and
    stays with the tracklet it was tracked in.  Clearest moves first (the largest margin); people left
    empty are dropped.  A detection alone in its image (no other of its person's within
    ``tracklet.max_misses`` frames) counts ``tracklet.gate_sigmas`` to stay; one whose neighbours in time
    share too few keypoints with it to interpolate stays (no evidence either way).  Only a person with at
    least ``tracker.min_track_frames`` frames receives: a shorter one is dropped unless stitched, and the
    detection with it."""
    depths = [_person_depths(p, calib, config, ranges) for p in people]
    min_frames = config.tracker.min_track_frames
    moves = []
    for k, person in enumerate(people):
        for side, other in (("left", "right"), ("right", "left")):
            for f, (index, det, uv) in person.sides[side].items():
                if f in person.sides[other]:
                    continue
                receivers = [m for m, q in enumerate(people)
                             if m != k and f in q.sides[other] and f not in q.sides[side]
                             and len(q.sides["left"].keys() | q.sides["right"].keys()) >= min_frames]
                if not receivers:
                    continue
                own = {g: item for g, item in person.sides[side].items() if g != f}
                stay = _interpolation_cost(own, f, uv, config)
                if stay is None:
                    if any(abs(g - f) <= frames_for(config.tracklet, config.tracklet.max_misses) for g in own):
                        continue           # its neighbours in time share too few keypoints with it to judge
                    stay = config.tracklet.gate_sigmas         # alone in its image: nothing holds it there
                range_m = ranges.get(id(det)) if ranges else None
                if range_m is not None:
                    stay = float(np.hypot(stay, _depth_residual(depths[k], f, range_m, config)))
                for m in receivers:
                    cost = _completion_cost(people[m].sides, side, f, det, uv, depths[m], calib, config, ranges,
                                            ground)
                    if cost is None:
                        continue
                    if (side, index) not in people[m].tracklets:
                        cost += config.tracklet_switch_cost
                    if cost <= config.tracklet.gate_sigmas and cost < stay:
                        moves.append((cost - stay, k, m, side, f))
    for _, k, m, side, f in sorted(moves):
        other = "right" if side == "left" else "left"
        if f not in people[k].sides[side] or f in people[k].sides[other] or f in people[m].sides[side] \
                or f not in people[m].sides[other]:
            continue               # an earlier move paired this detection where it is, or took one of the two
        index, det, uv = people[k].sides[side].pop(f)
        people[m].sides[side][f] = (index, det, uv)
        people[m].tracklets.add((side, index))
        people[m].paired.add(f)
    return [p for p in people if p.sides["left"] or p.sides["right"]]


def _completion_cost(sides: Mapping[str, dict], side: str, frame: int, det: Detection, uv: np.ndarray,
                     depths: dict[int, tuple[float, float]], calib: StereoCalibration, config: AssociationConfig,
                     ranges: Mapping[int, float] | None, ground: GroundFrame | None) -> float | None:
    """How well an unpaired detection (``side`` image, ``frame``) completes a person that holds only the other
    image's detection at that frame, in sigmas: the root mean square of the pair's stereo terms
    (:func:`stereo_cost`) and, in quadrature, how far the pairing's depth ``f B / d`` (its standard error
    ``f B / d^2`` times the disparity's) lies from the person's depth at that frame (:func:`_depth_residual`,
    its paired frames' disparities or LiDAR ranges).  None when the pairing is gated out.  ``sides``: the
    person's side -> frame -> (tracklet, detection, uv)."""
    other = "right" if side == "left" else "left"
    _, other_det, other_uv = sides[other][frame]
    pair = (det, uv, other_det, other_uv) if side == "left" else (other_det, other_uv, det, uv)
    terms = _detection_pair_terms(*pair, calib, config, ranges, ground)
    if terms is None:
        return None
    cost, disparity_px, se_px = terms
    depth_m = calib.focal_px * calib.baseline_m / disparity_px
    depth_se_m = depth_m / disparity_px * se_px
    return float(np.hypot(np.sqrt(cost), _depth_residual(depths, frame, depth_m, config, depth_se_m)))


def drop_disparity_outliers(person: _Person, calib: StereoCalibration, config: AssociationConfig) -> None:
    """Unpair the frames of a person whose disparity leaves the person's smooth disparity line by more than
    ``gate_sigmas`` (:func:`_smooth_disparity` over all its paired frames), in place.  Tracklet evidence is
    judged per pair of tracklets: a short tracklet of someone else, paired for a frame or two with one of the
    person's tracklets, passes on its own and joins the person.  At such a frame the side whose tracklet holds
    fewer of the person's frames is taken out (the intruder); the frame stays with its other side, unpaired."""
    items = _paired_disparities(person, config)
    if len(items) < 3:
        return
    z = _smooth_disparity(np.array([i[0] for i in items], dtype=float), np.array([i[1] for i in items]),
                          np.array([i[2] for i in items]), calib, config)
    held = {side: defaultdict(int) for side in ("left", "right")}
    for side in ("left", "right"):
        for index, _, _ in person.sides[side].values():
            held[side][index] += 1
    for (frame, _, _), zf in zip(items, z):
        if abs(zf) <= config.gate_sigmas:
            continue
        counts = {side: held[side][person.sides[side][frame][0]] for side in ("left", "right")}
        intruder = "right" if counts["right"] < counts["left"] else "left"
        del person.sides[intruder][frame]
        person.paired.discard(frame)


# ---------------------------------------------------------------------------------------------- observations

def pair_tracks(detections: list[Detection], calib: StereoCalibration, config: AssociationConfig,
                ground: GroundFrame, clouds: Mapping[int, np.ndarray] | None = None) -> list[list[Observation]]:
    """The people one pair saw, each a list of per-frame :class:`Observation` in frame order (module
    docstring, steps 1-4): rectified, de-duplicated, tracked per camera, tracklets paired by their shared
    frames' evidence, paired frames triangulated (or centred on their LiDAR cut when ``clouds`` holds the
    frame); people with fewer than ``tracker.min_track_frames`` frames or a mean score below
    ``tracker.min_mean_score`` are dropped."""
    left_name, right_name = calib.name.split("-")
    per_image: dict[str, dict[int, list]] = {"left": defaultdict(list), "right": defaultdict(list)}
    for det in detections:
        if det.camera not in (left_name, right_name):
            continue
        uv = _usable(rectified(det, calib), det.confidence, config.min_confidence)
        per_image["left" if det.camera == left_name else "right"][det.frame].append((det, uv))
    for frames in per_image.values():
        for frame, items in frames.items():
            frames[frame] = join_split_parts(items, config)
    tracklets = {}
    ranges: dict[int, float] = {}
    past: set[int] = set()                               # ranges whose cluster goes on past the hulls
    for side, frames in per_image.items():
        deduplicated = {frame: drop_duplicates(items, config) for frame, items in sorted(frames.items())}
        if clouds is not None and config.lidar_identity:
            for frame, items in deduplicated.items():
                if frame in clouds and items:
                    ranges.update(detection_ranges(items, calib, side, clouds[frame], ground, config, past))
        tracklets[side] = camera_tracklets(deduplicated, config, ranges)
    candidates = []
    for person in pair_tracklets(tracklets["left"], tracklets["right"], calib, config, ranges, ground):
        drop_disparity_outliers(person, calib, config)
        frames = sorted(set(person.sides["left"]) | set(person.sides["right"]))
        track = []
        for frame in frames:
            uv, payload = {}, {}
            for side in ("left", "right"):
                if frame in person.sides[side]:
                    _, det, side_uv = person.sides[side][frame]
                    uv[side], payload[side] = side_uv, det
            obs = Observation(frame=frame, uv=uv, score=float(max(d.score for d in payload.values())),
                              payload=payload)
            if frame in person.paired:
                _stereo_centre(obs, calib, ground, config)
            track.append(obs)
        candidates.append(track)
    out = []
    projections: dict[tuple[int, str], tuple[np.ndarray, np.ndarray]] = {}   # scene cloud per image, once
    placing = _placing(ranges, past)
    for track in stitch_tracks(candidates, calib, config):
        if len(track) < config.tracker.min_track_frames:
            continue
        if float(np.mean([o.score for o in track])) < config.tracker.min_mean_score:
            continue
        if clouds is not None:
            lidar_centres(track, calib, per_image, placing, clouds, ground, config, projections)
        out.append(track)
    out = drop_other_heights(repair_swaps(split_reversals(out, calib, config), calib, config), calib, config)
    if clouds is not None and config.lidar_identity:
        settle_centres(out, calib, config)
    return drop_ambiguous_frames(out, calib, config)


def _stereo_centre(obs: Observation, calib: StereoCalibration, ground: GroundFrame,
                   config: AssociationConfig) -> None:
    """Centre an observation seen in both images of the pair by stereo, in place: ``world_p`` and
    ``depth_sigma_m`` from :func:`triangulate_centre`, seen from the left camera, and ``disparity_px`` the
    median disparity of the keypoints both images hold (the caller has checked they pair)."""
    uv_l, uv_r = obs.uv["left"], obs.uv["right"]
    obs.world_p, obs.depth_sigma_m = triangulate_centre(uv_l, uv_r, calib, ground, config)
    obs.world_p_camera = calib.camera_centre("left")
    both = np.all(np.isfinite(uv_l), axis=1) & np.all(np.isfinite(uv_r), axis=1)
    obs.disparity_px = float(median(uv_l[both, 0] - uv_r[both, 0]))


def _placing(ranges: Mapping[int, float], past: set[int]) -> dict[int, float]:
    """The LiDAR ranges (:func:`detection_ranges`) that may place their detection's person: those whose
    cluster ends at the hulls (not in ``past``)."""
    return {key: value for key, value in ranges.items() if key not in past}


def lidar_centres(track: list[Observation], calib: StereoCalibration, per_image: Mapping[str, Mapping[int, list]],
                  ranges: Mapping[int, float], clouds: Mapping[int, np.ndarray], ground: GroundFrame,
                  config: AssociationConfig, projections: dict | None = None) -> None:
    """Centre one pair's track on the LiDAR where the scene ``clouds`` allow (module docstring, step 4), in
    place: a frame seen in one image at its detection's own cluster (:func:`_range_centre`) where the
    track's stereo centre nearest in time allows that depth (:func:`_agrees_with_stereo`), then every frame
    with a centre on its cut (:func:`_lidar_centre`).  ``per_image``: side -> frame -> that image's
    ``(detection, rectified uv)`` (whose ranges other detections claim, whose hulls they cover); ``ranges``:
    :func:`detection_ranges` of those images, those that may place a person (:func:`_placing`);
    ``projections``: ``(frame, side)`` -> the cloud projected into that image, filled on first use (shared by
    the tracks of one pair)."""
    projections = {} if projections is None else projections
    stereo = [obs for obs in track if obs.world_p is not None]
    for obs in stereo + [obs for obs in track if obs.world_p is None]:     # stereo frames first
        if obs.world_p is None and config.lidar_identity:
            seen = next(iter(obs.uv))
            _range_centre(obs, calib, ranges, clouds[obs.frame] if obs.frame in clouds else None, ground,
                          config, projections.get((obs.frame, seen)))
            if obs.world_p is not None and stereo and \
                    not _agrees_with_stereo(obs, [_nearest_in_time(stereo, obs.frame)], calib, config):
                obs.world_p, obs.world_p_camera, obs.depth_sigma_m = None, None, np.inf
                obs.fallback = None
        if obs.world_p is not None and obs.frame in clouds:
            views = {side: projections.setdefault((obs.frame, side), None) for side in ("left", "right")}
            claimed = {side: [ranges[id(d)] for d, _ in per_image[side].get(obs.frame, [])
                              if id(d) in ranges] for side in ("left", "right")}
            others = {side: [uv for d, uv in per_image[side].get(obs.frame, [])
                             if d is not obs.payload.get(side)] for side in ("left", "right")}
            _lidar_centre(obs, calib, clouds[obs.frame], ground, config, views,
                          ranges if config.lidar_identity else None, claimed, others)
            projections.update({(obs.frame, side): v for side, v in views.items()})


def _image_track(track: list[Observation], calib: StereoCalibration, config: AssociationConfig,
                 side: str = "left", stereo_frames: frozenset = frozenset(), memo: dict | None = None) -> tuple:
    """A pair track as positions over time seen from one camera (``side``): ``(frames (n,), u (n,) px,
    sigma (n,) px, depth (n,) m, depth_sigma (n,) m, size (n,) px, size_sigma (n,) px, px_per_m)``.

    ``u`` is the median column of the detection's keypoints in that image, measured from the image's
    principal column; for a frame seen only in the other image, that image's column shifted by the disparity
    of the frame's centre depth (else by the track's median disparity; left out when the track has none).
    ``sigma`` is the keypoint noise of that median plus how far a walker leaves a straight walk
    (``swap_motion_m`` at the track's depth).  ``depth`` is the depth of the frame's centre (``world_p``) in
    the pair's rectified frame, ``depth_sigma`` its uncertainty (``depth_sigma_m``) plus ``swap_motion_m``;
    NaN for a frame without a centre.  In ``stereo_frames`` a centre the LiDAR replaced gives way to the one
    it replaced (``fallback``).  ``size`` is the frame's standing height in the image seen
    (:func:`standing_height_px`; the other image's for a frame seen there only: rectified, the same),
    ``size_sigma`` its fit error and ``swap_size_frac`` of it; NaN without a detection to fit.
    ``px_per_m`` is the track's scale (``f / depth``: from its median
    disparity, else from its median image height and ``person_height_m``), None when it has no frame.
    ``memo`` keeps each observation's own numbers across calls (the observations must not change)."""
    disparities = [o.disparity_px for o in track if o.disparity_px is not None and o.disparity_px > 0]
    disparity = float(median(disparities)) if disparities else None
    principal = {"left": float(calib.left_P_rect[0, 2]), "right": float(calib.right_P_rect[0, 2])}
    toward = 1.0 if side == "left" else -1.0             # the other image's columns + this * disparity
    frames, u, sigma, heights, depth, depth_sigma, size, size_sigma = [], [], [], [], [], [], [], []
    for obs in track:
        seen = side if side in obs.uv else next(iter(obs.uv))
        if seen != side and disparity is None:
            continue
        key = (id(obs), seen, obs.frame in stereo_frames)
        if memo is not None and key in memo:
            entry = memo[key]
        else:
            entry = _seen_column(obs, seen, calib, config, obs.frame in stereo_frames)
            if memo is not None:
                memo[key] = entry
        if entry is None:
            continue
        column, height, noise, frame_depth, frame_depth_sigma, frame_size, frame_size_sigma = entry
        if seen != side:         # the disparity at the frame's centre depth, else the track's median
            column += toward * (calib.focal_px * calib.baseline_m / frame_depth if frame_depth > 0
                                else disparity - (principal["left"] - principal["right"]))
        frames.append(obs.frame)
        u.append(column)
        sigma.append(noise)
        heights.append(height)
        depth.append(frame_depth)
        depth_sigma.append(frame_depth_sigma)
        size.append(frame_size)
        size_sigma.append(frame_size_sigma)
    px_per_m = None
    if disparity is not None:
        px_per_m = disparity / calib.baseline_m
    elif heights:
        px_per_m = float(median(heights)) / config.person_height_m
    slack = config.swap_motion_m * (px_per_m or 0.0)
    return (np.array(frames, dtype=float), np.array(u), np.hypot(np.array(sigma), slack), np.array(depth),
            np.array(depth_sigma), np.array(size, dtype=float), np.array(size_sigma, dtype=float), px_per_m)


def _seen_column(obs: Observation, seen: str, calib: StereoCalibration, config: AssociationConfig,
                 stereo: bool) -> tuple | None:
    """One observation's numbers for :func:`_image_track`, seen in image ``seen``: ``(median keypoint column
    from that image's principal column px, keypoint height px, the median's noise px, centre depth m, its
    uncertainty m, standing height px, its uncertainty px)`` (depth NaN without a centre; with ``stereo``, a
    LiDAR centre gives way to its fallback; the standing height, :func:`standing_height_px`, uncertain by
    its fit error and ``swap_size_frac`` of it, NaN without a detection to fit); None with fewer than
    ``min_shared_keypoints`` keypoints."""
    present = obs.uv[seen][np.all(np.isfinite(obs.uv[seen]), axis=1)]
    if len(present) < config.min_shared_keypoints:
        return None
    detection = obs.payload.get(seen) if isinstance(obs.payload, dict) else None
    size = None if getattr(detection, "keypoint_set", None) is None else \
        standing_height_px(obs.uv[seen], detection.keypoint_set, config.gate_sigmas, config.keypoint_sigma_px)
    size, size_sigma = size if size is not None else (np.nan, np.nan)
    size_sigma = float(np.hypot(size_sigma, config.swap_size_frac * size))
    centre_p, centre_sigma = obs.world_p, obs.depth_sigma_m
    if stereo and obs.fallback is not None:
        centre_p, _, centre_sigma = obs.fallback
    known = centre_p is not None and np.isfinite(centre_sigma)
    principal = float((calib.left_P_rect if seen == "left" else calib.right_P_rect)[0, 2])
    height = float(np.ptp(present[:, 1]))
    noise = (config.keypoint_sigma_px + config.keypoint_sigma_frac * height) * 1.2533 / np.sqrt(len(present))
    if not known:
        return float(median(present[:, 0])) - principal, height, noise, np.nan, np.nan, size, size_sigma
    depth = float(calib.world_to_rect(np.asarray(centre_p, dtype=float))[2])
    return (float(median(present[:, 0])) - principal, height, noise, depth,
            float(np.hypot(centre_sigma, config.swap_motion_m)), size, size_sigma)


def _normal_solve(columns: list[np.ndarray], b: np.ndarray) -> list[np.ndarray]:
    """Least-squares coefficients of ``b`` (n,) by ``columns`` (k arrays (m, n): the columns of m models),
    from the normal equations (regularised by 1e-12): k arrays (m,).  Written out for one and two columns
    (the walk's fits), which is where the association spends its time."""
    if len(columns) == 1:
        a0 = columns[0]
        return [np.add.reduce(a0 * b, axis=1) / (np.add.reduce(a0 ** 2, axis=1) + 1e-12)]
    if len(columns) == 2:
        a0, a1 = columns
        s00 = np.add.reduce(a0 * a0, axis=1) + 1e-12
        s01 = np.add.reduce(a0 * a1, axis=1)
        s11 = np.add.reduce(a1 * a1, axis=1) + 1e-12
        r0, r1 = a0 @ b, a1 @ b
        det = s00 * s11 - s01 * s01
        return [(s11 * r0 - s01 * r1) / det, (s00 * r1 - s01 * r0) / det]
    a = np.stack(columns, axis=2)
    normal = np.einsum("mni,mnj->mij", a, a) + 1e-12 * np.eye(len(columns))
    return list(np.linalg.solve(normal, np.einsum("mni,n->mi", a, b)[:, :, None])[:, :, 0].T)


def _robust_fit(design: np.ndarray, y: np.ndarray, sigma: np.ndarray, gate: float,
                coefficients: bool = False) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Sums of ``min(z^2, gate^2)`` of the normalised residuals of weighted least-squares fits of ``y`` (n,)
    with standard deviations ``sigma`` (n,) by the columns of each of ``design`` (m, n, k) (one fit per model),
    each fit iterated three times with the residuals beyond ``gate`` left out (as long as ``k`` remain): (m,);
    with ``coefficients``, also the fits' coefficients (m, k).  A one-coefficient fit starts from the median
    of the ratios ``y / design`` (the first fit then leaves out what lies beyond ``gate`` of it); started from
    every point, two precise points off the rest pull the first fit toward them until they lie inside the
    gate and stay.  The iterations stop early where the points kept no longer change (the rest would repeat
    the last one; the walk's fits call this tens of thousands of times)."""
    weight = 1.0 / sigma
    k = design.shape[2]
    a = design * weight[None, :, None]
    columns = [a[:, :, i] for i in range(k)]
    b = y * weight
    keep = np.ones(design.shape[:2], dtype=bool)
    if k == 1:                             # one coefficient: start from the median ratio, not from every point
        with np.errstate(divide="ignore", invalid="ignore"):
            start = median(y[None, :] / design[:, :, 0], axis=1)
            keep = np.abs(b[None, :] - columns[0] * start[:, None]) <= gate
        keep[keep.sum(axis=1) == 0] = True     # no finite start (a zero design): from every point
    for _ in range(3):
        ak = a * keep[:, :, None]
        coef = _normal_solve([ak[:, :, i] for i in range(k)], b)
        fitted = columns[0] * coef[0][:, None]
        for column, c in zip(columns[1:], coef[1:]):
            fitted = fitted + column * c[:, None]
        z = b[None, :] - fitted
        new_keep = np.abs(z) <= gate
        enough = np.count_nonzero(new_keep, axis=1) >= k
        new_keep = new_keep if enough.all() else np.where(enough[:, None], new_keep, keep)
        if np.array_equal(new_keep, keep):  # the next iterations would repeat this one
            break
        keep = new_keep
    total = np.add.reduce(np.minimum(z ** 2, gate ** 2), axis=1)
    return (total, np.stack(coef, axis=1)) if coefficients else total


def _walk_cost(frames: np.ndarray, u: np.ndarray, sigma: np.ndarray, gate: float, max_rate: float = 0.0,
               depth: np.ndarray | None = None, depth_sigma: np.ndarray | None = None,
               size: np.ndarray | None = None, size_sigma: np.ndarray | None = None) -> float:
    """Robust misfit of a track's image columns and depths to one straight walk at constant velocity.

    A point moving on a straight line at constant velocity, seen by a rectified camera, has the depth
    ``Z(f) = Z0 (1 + c tau)`` and the column (from the principal column) ``u(f) = (a + b tau) / (1 + c tau)``,
    ``tau = f - f0`` (the track's middle frame; ``c`` the depth's relative rate per frame, shared by both).
    ``|c| <= max_rate`` (the walker's top speed over its depth; 0: the straight line ``u = a + b f`` of a walker
    far away, whose depth hardly changes).  A person keeps their height, so their image height (``size``,
    :func:`standing_height_px`) is ``s(f) = s0 / (1 + c tau)``.  The misfit is the smallest, over ``c``, of the
    summed ``min(z^2, gate^2)`` of the normalised residuals of the columns, of the depths and of the sizes
    (NaN = unknown; depths and sizes used from three known) (:func:`_robust_fit`): ``c`` searched on a grid of
    33 rates, then on a grid 16 times finer around the best; 0 for < 3 frames."""
    return _walk_fit(frames, u, sigma, gate, max_rate, depth, depth_sigma, size, size_sigma)[0]


def _walk_costs(frames: np.ndarray, u: np.ndarray, sigma: np.ndarray, gate: float,
                depth: np.ndarray | None = None, depth_sigma: np.ndarray | None = None,
                size: np.ndarray | None = None, size_sigma: np.ndarray | None = None
                ) -> Callable[[np.ndarray], np.ndarray]:
    """``rates (m,) -> misfits (m,)``: :func:`_walk_cost`'s robust misfit of the straight walk at each relative
    depth rate ``c`` (columns, and depths and sizes where at least three are known; ``frames`` at least 3)."""
    tau = frames - 0.5 * (frames.min() + frames.max())
    known = np.isfinite(depth) if depth is not None else np.zeros(len(frames), dtype=bool)
    sized = np.isfinite(size) & np.isfinite(size_sigma) if size is not None else np.zeros(len(frames), dtype=bool)

    def costs(rates: np.ndarray) -> np.ndarray:
        stretch = 1.0 + rates[:, None] * tau[None, :]                  # Z / Z0, (m, n)
        total = _robust_fit(np.stack([1.0 / stretch, tau / stretch], axis=2), u, sigma, gate)
        if known.sum() >= 3:
            total = total + _robust_fit(stretch[:, known, None], depth[known], depth_sigma[known], gate)
        if sized.sum() >= 3:
            total = total + _robust_fit(1.0 / stretch[:, sized, None], size[sized], size_sigma[sized], gate)
        return total

    return costs


def _walk_fit(frames: np.ndarray, u: np.ndarray, sigma: np.ndarray, gate: float, max_rate: float = 0.0,
              depth: np.ndarray | None = None, depth_sigma: np.ndarray | None = None,
              size: np.ndarray | None = None, size_sigma: np.ndarray | None = None) -> tuple[float, float]:
    """:func:`_walk_cost`'s misfit and the rate ``c`` it was found at (0 for < 3 frames)."""
    if len(frames) < 3:
        return 0.0, 0.0
    tau = frames - 0.5 * (frames.min() + frames.max())
    costs = _walk_costs(frames, u, sigma, gate, depth, depth_sigma, size, size_sigma)
    if max_rate * float(np.max(np.abs(tau))) <= 1e-3:
        return float(costs(np.zeros(1))[0]), 0.0
    coarse = np.linspace(-max_rate, max_rate, 33)
    coarse_costs = costs(coarse)
    best = coarse[int(np.argmin(coarse_costs))]
    step = coarse[1] - coarse[0]
    fine = np.clip(best + np.linspace(-step, step, 33), -max_rate, max_rate)
    fine_costs = costs(fine)
    if fine_costs.min() < coarse_costs.min():
        return float(fine_costs.min()), float(fine[int(np.argmin(fine_costs))])
    return float(coarse_costs.min()), float(best)


def _walk_lines(fit: tuple, rate: float, gate: float) -> tuple:
    """The straight walk fitted once at ``rate`` (:func:`_walk_fit`) to ``fit`` = ``(frames, u, sigma, depth,
    depth_sigma, size, size_sigma)`` as :func:`_image_track` gives them, robustly at ``gate``: ``(column,
    depth, size)``, each a function of the frame (column px from the principal column, depth m, image
    height px), depth and size None with fewer than three known; all None with fewer than 3 frames."""
    frames, u, sigma, depth, depth_sigma, size, size_sigma = fit
    if len(frames) < 3:
        return None, None, None
    centre = 0.5 * (frames.min() + frames.max())
    tau = frames - centre
    stretch = 1.0 + rate * tau
    _, u_coef = _robust_fit(np.stack([1.0 / stretch, tau / stretch], axis=1)[None], u, sigma, gate, coefficients=True)
    u0, u1 = float(u_coef[0, 0]), float(u_coef[0, 1])
    out = [lambda f: (u0 + u1 * (f - centre)) / (1.0 + rate * (f - centre)), None, None]
    known = np.isfinite(depth)
    if known.sum() >= 3:
        _, depth_coef = _robust_fit(stretch[None, known, None], depth[known], depth_sigma[known], gate,
                                    coefficients=True)
        depth0 = float(depth_coef[0, 0])
        out[1] = lambda f: depth0 * (1.0 + rate * (f - centre))
    sized = np.isfinite(size) & np.isfinite(size_sigma)
    if sized.sum() >= 3:
        _, size_coef = _robust_fit(1.0 / stretch[None, sized, None], size[sized], size_sigma[sized], gate,
                                   coefficients=True)
        size0 = float(size_coef[0, 0])
        out[2] = lambda f: size0 / (1.0 + rate * (f - centre))
    return tuple(out)


def _walk_misfits(fit: tuple, rate: float, gate: float, seen: list[tuple]) -> list[np.ndarray]:
    """Per series of ``seen``, per observation its ``min(z^2, gate^2)`` (column plus depth and size where
    known) against the straight walk fitted once at ``rate`` to ``fit`` (:func:`_walk_lines`); all
    ``(frames, u, sigma, depth, depth_sigma, size, size_sigma)`` as :func:`_image_track` gives them, each of
    ``seen`` with its own noise.  Zeros when ``fit`` has fewer than 3 frames."""
    out = [np.zeros(len(series[0])) for series in seen]
    column, depth, size = _walk_lines(fit, rate, gate)
    if column is None:
        return out
    for misfit, (s_frames, s_u, s_sigma, s_depth, s_depth_sigma, s_size, s_size_sigma) in zip(out, seen):
        misfit += np.minimum(((s_u - column(s_frames)) / s_sigma) ** 2, gate ** 2)
        if depth is not None:
            s_known = np.isfinite(s_depth)
            z = (s_depth[s_known] - depth(s_frames[s_known])) / s_depth_sigma[s_known]
            misfit[s_known] += np.minimum(z ** 2, gate ** 2)
        if size is not None:
            s_sized = np.isfinite(s_size) & np.isfinite(s_size_sigma)
            z = (s_size[s_sized] - size(s_frames[s_sized])) / s_size_sigma[s_sized]
            misfit[s_sized] += np.minimum(z ** 2, gate ** 2)
    return out


def _depth_rate(px_per_m: float | None, calib: StereoCalibration, config: AssociationConfig) -> float:
    """The largest relative rate of change of a walker's depth per frame, ``v_max dt / Z`` with ``v_max`` =
    ``tracker.max_speed_mps`` and ``Z = f / px_per_m``: the bound of :func:`_walk_cost`'s ``c``; 0 without
    a scale."""
    if not px_per_m:
        return 0.0
    return config.tracker.max_speed_mps * config.tracker.frame_interval_s * px_per_m / calib.focal_px


def _track_walk(seen: tuple, calib: StereoCalibration, config: AssociationConfig,
                with_size: bool = True, memo: dict | None = None) -> tuple[float, float]:
    """:func:`_walk_fit` (misfit, rate) of a track as :func:`_image_track` gives it, at ``gate_sigmas``, its
    depth rate bounded by a walker's top speed at the track's scale (:func:`_depth_rate`); without
    ``with_size``, on columns and depths only.  ``memo`` keeps the fits by the series' values (a dict held
    while ``calib`` and ``config`` stay the same: the swap repair judges one track against many)."""
    if memo is not None:
        values = hashlib.blake2b(digest_size=16)         # a digest: long tracks' series stay out of memory
        for series in seen[:7]:
            values.update(np.ascontiguousarray(series, dtype=float).tobytes())
        key = (with_size, seen[7], len(seen[0]), values.digest())
        if key in memo:
            return memo[key]
    frames, u, sigma, depth, depth_sigma, size, size_sigma, px_per_m = seen
    if not with_size:
        size = size_sigma = None
    walk = _walk_fit(frames, u, sigma, config.gate_sigmas, _depth_rate(px_per_m, calib, config), depth, depth_sigma,
                     size, size_sigma)
    if memo is not None:
        memo[key] = walk
    return walk


def _overlapping_frames(track_a: list[Observation], track_b: list[Observation], cover: float = 0.5) -> frozenset:
    """Frames where, in an image both tracks' detections are in, one detection's box covers at least ``cover``
    of the other's: one person (partly) in front of the other, whose LiDAR cuts cannot be told apart."""
    by_frame = {o.frame: o for o in track_b}
    out = set()
    for obs in track_a:
        other = by_frame.get(obs.frame)
        if other is None:
            continue
        for side in set(obs.uv) & set(other.uv):
            box_a, box_b = keypoint_box(obs.uv[side]), keypoint_box(other.uv[side])
            if box_a is not None and box_b is not None and box_cover(box_a, box_b) >= cover:
                out.add(obs.frame)
    return frozenset(out)


def repair_swaps(tracks: list[list[Observation]], calib: StereoCalibration,
                 config: AssociationConfig) -> list[list[Observation]]:
    """Undo identity swaps between one pair's tracks where two people pass each other in the image.

    The per-camera tracker decides frame by frame; when the two are missed in turns while they overlap it can
    carry each track on with the other person.  Over the whole track, a walker's image column follows the
    projection of a straight walk at constant velocity (:func:`_image_track`, :func:`_walk_cost`: a line
    far away, curved by perspective near the camera), and so does its image height (a person keeps their
    height); a swap shows as kinks or steps.  For two tracks that
    come within half a person's height of each other in the image at frames at most 2 apart, split times
    ``tau`` from the later start to just after the earlier end are tried: heads kept, tails exchanged.  The
    tracker can only have carried a track on with the other person where the two were that near, between
    ``tau`` and the frame before it (across a gap where both were missed), so such a frame lies within 2
    frames of that interval; or ``tau`` is the first or the last split time (there one track's head moves
    to the other, or one track's tail: a track begun with, or carried on to, the other person; never all
    of one track).  So are stretches ``[t1, t2)`` exchanged, both ends within 2 frames of a frame where
    the two are that near (people walking together
    or meeting twice: the tracker carried each on with the other and back again where they met next): those
    around the runs of frames whose observations fit the other track's walk better than their own
    (:func:`_walk_misfits`, each walk fitted robustly as the track is; a stretch holding all of one track is
    not tried, that would join them; nor is one of a single frame, unless only one track holds that frame:
    then it is a move of one observation to the other track, from a track left with three frames at least,
    whose walk still judges it).  Past the span the two share (when they share one), a frame at most 2
    frames beyond it, within 2 frames of one where the two are near, held by one track and not by the
    other, may move to the other too (a track carried on one frame with the other person where that one's
    own track begins or ends).  The frames' centre depths weigh in
    too, except LiDAR centres of frames where one's detection hides half of the other's
    (:func:`_overlapping_frames`: either cut may hold the person in front; their stereo centres are used).
    The exchange with the lowest summed cost is made when it beats the tracks as they are by more than
    ``gate_sigmas^2``; repeated until no exchange helps (a pair's best exchange depends on its two tracks
    only: it is searched again only when one of them changed).  Returns the tracks (each in frame order)."""
    gate = config.gate_sigmas
    tracks = [list(t) for t in tracks]
    memo: dict = {}
    walks_memo: dict = {}                               # the walk fits by their series' values
    series: dict[str, dict[int, tuple]] = {"left": {}, "right": {}}
    spans: dict[int, list[float]] = {}                  # track -> its detections' keypoint spans, px
    offers: dict[tuple[int, int], tuple | None] = {}    # (a, b) -> the pair's best exchange, while both are unchanged

    def best_exchange(a: int, b: int) -> tuple | None:
        """The exchange of tracks ``a`` and ``b`` with the largest gain above ``gate^2`` (the first such
        ``tau`` on ties), as ``(gain, new_a, new_b)``, or None: depends on the two tracks only."""
        # compared in the image where both are seen most
        side = max(("left", "right"), key=lambda sd: min(len(series[sd][a][0]), len(series[sd][b][0])))
        fa, ua = series[side][a][:2]
        fb, ub = series[side][b][:2]
        if len(fa) < 2 or len(fb) < 2:
            return None
        heights = spans[a] + spans[b]
        near = (np.abs(fa[:, None] - fb[None, :]) <= 2) & \
            (np.abs(ua[:, None] - ub[None, :]) <= 0.5 * max(median(heights), 1.0))
        if not near.any():
            return None
        lo, hi = max(fa.min(), fb.min()), min(fa.max(), fb.max())
        hidden = _overlapping_frames(tracks[a], tracks[b])

        def consider(new_a, new_b):
            nonlocal found
            bar = gate ** 2 if found is None else max(gate ** 2, found[0])
            cost_a = _track_walk(_image_track(new_a, calib, config, side, hidden, memo), calib, config,
                                 memo=walks_memo)[0]
            if now - cost_a <= bar:           # a misfit is never negative: new_b's cannot make up for it
                return
            gain = now - (cost_a + _track_walk(_image_track(new_b, calib, config, side, hidden, memo), calib,
                                               config, memo=walks_memo)[0])
            if gain > bar:
                found = (gain, new_a, new_b)

        seen = {k: _image_track(tracks[k], calib, config, side, hidden, memo) for k in (a, b)}
        walks = {k: _track_walk(seen[k], calib, config, memo=walks_memo) for k in (a, b)}
        now = walks[a][0] + walks[b][0]
        found = None
        taus = sorted({o.frame for o in tracks[a] + tracks[b] if lo <= o.frame <= hi} | {hi + 1})
        near_frames = np.union1d(fa[near.any(axis=1)], fb[near.any(axis=0)])
        switches = [t for t in taus if t <= hi and np.min(np.abs(near_frames - t)) <= 2]
        # a tracker's switch at tau happened between tau and the frame before it (across a gap where both
        # were missed), so the two were near each other there, give or take 2 frames; and the ends
        previous = dict(zip(taus[1:], taus[:-1]))
        splits = [t for t in taus if t in (lo, hi + 1)
                  or np.any((near_frames >= previous.get(t, t) - 2) & (near_frames <= t + 2))]
        for tau in splits:
            new_a = [o for o in tracks[a] if o.frame < tau] + [o for o in tracks[b] if o.frame >= tau]
            new_b = [o for o in tracks[b] if o.frame < tau] + [o for o in tracks[a] if o.frame >= tau]
            if new_a and new_b:               # else the tracks lie apart in time: that would join them
                consider(new_a, new_b)
        # one frame just past the span the two share (within 2 frames of it and of a frame where the two are
        # near), held by the track going on there, moved to the other one: a track carried on one frame with
        # the other person where that one's own track begins or ends (the move beats the gate on that one
        # observation; a whole head or tail is the split times' case above).  Only for tracks sharing a span
        # (else a move would begin to join them), from a track left with three frames at least (a walk
        # through fewer costs nothing: any move out of it would look like a gain)
        for k, m in ((a, b), (b, a)):
            if lo > hi or len(tracks[k]) <= 3:
                continue
            have = {o.frame for o in tracks[m]}     # lo, hi are of one image's series: m may hold more frames
            for o in tracks[k]:
                if (lo - 2 <= o.frame < lo or hi < o.frame <= hi + 2) and o.frame not in have \
                        and np.min(np.abs(near_frames - o.frame)) <= 2:
                    moved_k = [x for x in tracks[k] if x is not o]
                    moved_m = sorted(tracks[m] + [o], key=lambda x: x.frame)
                    consider(*((moved_k, moved_m) if k == a else (moved_m, moved_k)))
        # a stretch exchanged and exchanged back: the tracker can only have switched where the two were near
        # each other in the image, so both ends lie within 2 frames of such a frame; at least two frames long
        # (one frame's exchange is two noisy observations against two walks: the straight-walk test cannot
        # tell it from noise, and among the many stretches tried one such frame beats the gate by chance),
        # except one frame moved from a track to the other where that one has no observation (the move must
        # beat the gate on that one observation alone), from a track left with three frames at least.
        # Which stretches: per frame, how much better its observations fit the other track's walk than their
        # own (each track's walk fitted as it is, robustly: a stretch of the other person is its outliers);
        # the runs where that sum is positive (:func:`_supported_runs`), their ends give or take 2 frames,
        # are then tried exactly.
        if len(switches) < 2:
            return found
        shared = {m: tuple(x[(seen[m][0] >= lo) & (seen[m][0] <= hi)] for x in seen[m][:7]) for m in (a, b)}
        misfit = {}                         # (walk of k, observations of m): frame -> misfit, on frames both span
        for k in (a, b):
            for m, values in zip((a, b), _walk_misfits(seen[k][:7], walks[k][1], gate, [shared[a], shared[b]])):
                misfit[(k, m)] = dict(zip(shared[m][0].astype(int), values))
        span = sorted(set(misfit[(a, a)]) | set(misfit[(b, b)]))
        better = np.array([misfit[(a, a)].get(f, 0.0) + misfit[(b, b)].get(f, 0.0)
                           - misfit[(a, b)].get(f, 0.0) - misfit[(b, a)].get(f, 0.0) for f in span])
        tried = set()
        for first, last in _supported_runs(better):
            starts = [t for t in switches if abs(t - span[first]) <= 2]
            ends = [t for t in switches if span[last - 1] - 2 < t <= span[last - 1] + 3]
            for t1 in starts:
                for t2 in ends:
                    if t2 <= t1 or (t1, t2) in tried:
                        continue
                    tried.add((t1, t2))
                    inside_a = [o for o in tracks[a] if t1 <= o.frame < t2]
                    inside_b = [o for o in tracks[b] if t1 <= o.frame < t2]
                    if t2 - t1 < 2:                 # one frame: only a move, never an exchange
                        donor = tracks[a] if inside_a else tracks[b]
                        if bool(inside_a) == bool(inside_b) or len(donor) <= 3:
                            continue
                    if len(inside_a) == len(tracks[a]) or len(inside_b) == len(tracks[b]):
                        continue                    # all of one track: not an exchange but a join
                    consider(sorted([o for o in tracks[a] if not t1 <= o.frame < t2] + inside_b, key=lambda o: o.frame),
                             sorted([o for o in tracks[b] if not t1 <= o.frame < t2] + inside_a, key=lambda o: o.frame))
        return found

    changed = set(range(len(tracks)))
    for _ in range(2 * len(tracks)):
        for side in ("left", "right"):
            for k in changed:
                series[side][k] = _image_track(tracks[k], calib, config, side, memo=memo)
        for k in changed:
            spans[k] = [o.height_px(seen) for o in tracks[k] for seen in o.uv]
        for a in range(len(tracks)):
            for b in range(a + 1, len(tracks)):
                if a in changed or b in changed:
                    offers[(a, b)] = best_exchange(a, b)
        best = None                         # the largest gain; the first pair in (a, b) order on ties
        for key in sorted(offers):
            offer = offers[key]
            if offer is not None and (best is None or offer[0] > best[0][0]):
                best = (offer, key)
        if best is None:
            break
        (_, new_a, new_b), (a, b) = best
        tracks[a], tracks[b] = new_a, new_b
        changed = {a, b}
    return tracks


def _height_walks(track: list[Observation], calib: StereoCalibration, config: AssociationConfig) -> dict:
    """Per image side in which at least ``min_height_frames`` of the track's frames have an image height: the
    track's straight walk there (:func:`_track_walk`, column and height fitted robustly at its rate) as
    ``(frames -> (column px, height px, its sigma px), column at frame, height at frame)``.  The rate comes
    from the columns and the centres' depths alone: the heights are what is judged, and a few frames of
    someone else's height (a smaller person behind, at a track's end) would bend it their way."""
    out = {}
    for side in ("left", "right"):
        seen = _image_track(track, calib, config, side)
        frames, u, sigma, _, _, size, size_sigma, _ = seen
        sized = np.isfinite(size) & np.isfinite(size_sigma)
        if sized.sum() < config.min_height_frames:
            continue
        _, rate = _track_walk(seen, calib, config, with_size=False)
        column_at, _, height_at = _walk_lines(seen[:7], rate, config.gate_sigmas)
        if height_at is None:                      # fewer than three heights: no walk to judge by
            continue
        out[side] = (dict(zip(frames.astype(int), zip(u, size, size_sigma))), column_at, height_at)
    return out


def drop_other_heights(tracks: list[list[Observation]], calib: StereoCalibration,
                       config: AssociationConfig) -> list[list[Observation]]:
    """Take out of one pair's final tracks the frames that are someone else's by their image height.

    A person keeps their height, so over a track its image height follows the straight walk
    (:func:`_walk_cost`).  A frame whose height (:func:`standing_height_px`) in one image lies more than
    ``gate_sigmas`` of its uncertainty off its track's walk in that image, while another of the pair's
    tracks' walk there passes within half that height of its column at that frame and allows its height, is
    that other person's in that image (the per-camera tracker gave it to the wrong track where the two
    met).  A frame without a centre whose height lies more than ``lone_height_gate_sigmas`` (twice as far)
    off the walk is someone else's in that image even where no track's walk allows it: someone the pair
    does not track there.  Every image the frame is seen in and the track has ``min_height_frames`` heights
    in is judged.  An unpaired frame (no centre) seen in both images loses only that image's detection; any
    other such frame is dropped (a stereo or LiDAR centre made with the other person's detection is not the track's).
    Not moved: among the many frames of a scene one frame now and then fits another walk better by chance
    (:func:`repair_swaps` exchanges two frames at least); a dropped frame costs a frame, a kept one mixes
    two people.  A track left empty is removed.  Returns the tracks."""
    gate = config.gate_sigmas
    walks = [_height_walks(track, calib, config) for track in tracks]
    out = []
    for k, track in enumerate(tracks):
        kept = []
        for obs in track:
            off = {side for side in obs.uv if side in walks[k]
                   and (_someone_elses_height(obs.frame, side, k, walks, gate)
                        or obs.world_p is None and _far_off_height(obs.frame, walks[k][side],
                                                                    config.lone_height_gate_sigmas))}
            if not off:
                kept.append(obs)
            elif obs.world_p is None and set(obs.uv) - off:    # unpaired: the other image's detection stays
                keep = [side for side in obs.uv if side not in off]
                kept.append(dataclasses.replace(obs, uv={side: obs.uv[side] for side in keep},
                                                payload={side: obs.payload[side] for side in keep}))
        if kept:
            out.append(kept)
    return out


def drop_ambiguous_frames(tracks: list[list[Observation]], calib: StereoCalibration,
                          config: AssociationConfig) -> list[list[Observation]]:
    """Leave out of one pair's final tracks the short pieces a gap parts from their ends, the one-image
    frames at their ends that their own walk refuses, and the one-image frames another track explains as
    well.

    A frame seen in one image only has no depth of its own where the LiDAR gave it no centre: two people on
    one ray of that image cannot be told apart by it, and the per-camera tracker may have begun the track
    with the other person, carried it on to them, or given it the other person's detection where its own
    person was missed in that image (a tracklet born from one detection has no velocity yet; a near short
    person and a far tall one are of one image height).  First, a piece of at most 3
    frames at an end that a gap of at least ``end_gap_frames`` frames parts from the rest, seen in one image
    or both, is left out where the rest's walk misses every frame of it by more than ``gate_sigmas^2``
    (:func:`off_walk_pieces`: across a gap the trackers coasted on a prediction).  Then a one-image end
    frame whose detection the track's own straight walk in that image, fitted without it
    (:func:`_walk_misfits`), misses by more than ``gate_sigmas^2`` is left out, with or without a centre,
    from the outermost frame inwards while they are refused (:func:`off_walk_ends`: a one-image centre is
    the LiDAR cluster along that detection's ray, which does not tell whose detection it is).  Last, a
    one-image frame without a centre, at an end or between two frames seen in both images, is left out
    when another of the pair's tracks spans it give or take 2 frames (its first frame at most 2 after it,
    its last at most 2 before), has no detection of its own in that image there, and its straight walk in
    that image (:func:`_walk_misfits`: column and image height, fitted as :func:`repair_swaps` fits them)
    explains the frame's detection at least as well as the track's own walk without that frame.  Not
    moved: the two explain it alike.  Its pieces apart, a track with no frame seen in both images is left
    as it is.  Each frame is judged against the tracks as they come in.  A track left empty is removed.
    Returns the tracks."""
    gate = config.gate_sigmas
    tracks = [off_walk_ends(off_walk_pieces(t, calib, config), calib, config) for t in tracks]
    spans = [(min(o.frame for o in t), max(o.frame for o in t)) if t else (0, -1) for t in tracks]
    held = [{(o.frame, side) for o in t for side in o.uv} for t in tracks]
    walks: dict[tuple[int, str], tuple | None] = {}

    def walk(k: int, side: str, left_out: Observation | None = None) -> tuple | None:
        """Track ``k``'s walk in ``side`` as ``(series, rate)``, without ``left_out``; None below 3 frames."""
        key = (k, side)
        if left_out is None and key in walks:
            return walks[key]
        rest = [o for o in tracks[k] if o is not left_out]
        seen = _image_track(rest, calib, config, side) if len(rest) >= 3 else None
        found = None if seen is None or len(seen[0]) < 3 else (seen, _track_walk(seen, calib, config)[1])
        if left_out is None:
            walks[key] = found
        return found

    def misfit(found: tuple, mine: tuple) -> float:
        """The frame's misfit (``mine``: its :func:`_image_track` series) against the walk ``found``."""
        seen, rate = found
        return float(_walk_misfits(seen[:7], rate, gate, [mine[:7]])[0][0])

    out = []
    for k, track in enumerate(tracks):
        both = [o.frame for o in track if len(o.uv) == 2]
        kept = []
        for obs in track:
            if not both or len(obs.uv) != 1 or obs.world_p is not None:
                kept.append(obs)
                continue
            side = next(iter(obs.uv))
            mine = _image_track([obs], calib, config, side)
            own = walk(k, side, obs)
            if not len(mine[0]) or own is None:
                kept.append(obs)
                continue
            own_misfit = misfit(own, mine)
            rivals = [j for j in range(len(tracks)) if j != k and spans[j][0] - 2 <= obs.frame <= spans[j][1] + 2
                      and (obs.frame, side) not in held[j]]
            other = [misfit(found, mine) for j in rivals for found in [walk(j, side)] if found is not None]
            if not other or min(other) > own_misfit:
                kept.append(obs)
        if kept:
            out.append(kept)
    return out


def _off_walk_misfit(obs: Observation, rest: list[Observation], calib: StereoCalibration,
                     config: AssociationConfig) -> float | None:
    """How far the straight walk of ``rest`` misses ``obs``' detections: per image ``obs`` is seen in, the
    walk of ``rest`` in that image (:func:`_image_track`, :func:`_track_walk`) against the detection's column
    and image height (:func:`_walk_misfits`; the depth of a one-image centre is not judged), the mean over
    those images; None where no image has a detection to judge and a walk of 3 frames."""
    gate = config.gate_sigmas
    misfits = []
    for side in obs.uv:
        mine = list(_image_track([obs], calib, config, side))
        seen = _image_track(rest, calib, config, side)
        if not len(mine[0]) or len(seen[0]) < 3:
            continue
        mine[3] = np.full(len(mine[0]), np.nan)        # its detection judged, not its one-image centre
        rate = _track_walk(seen, calib, config)[1]
        misfits.append(float(_walk_misfits(seen[:7], rate, gate, [mine[:7]])[0][0]))
    return float(np.mean(misfits)) if misfits else None


def off_walk_pieces(track: list[Observation], calib: StereoCalibration, config: AssociationConfig
                    ) -> list[Observation]:
    """``track`` in frame order without the short pieces at its ends that a gap parts from the rest and the
    rest's walk refuses.

    A track's first frames up to a gap of at least ``end_gap_frames`` frames it does not hold, when they are
    at most 3 (a walk of their own would have no frame to spare), are a piece the per-camera trackers may
    have carried across the gap from someone else; likewise its last frames after such a gap.  The piece
    is left out when the straight walk of the rest of the track misses every one of its frames that can be
    judged by more than ``gate_sigmas^2`` (:func:`_off_walk_misfit`: column and image height in each image
    the frame is seen in, stereo frames too; at least one frame judged), and the next piece is judged; else
    that end stays.  The rest must keep at least 3 frames."""
    gate = config.gate_sigmas
    track = sorted(track, key=lambda o: o.frame)
    frames = [o.frame for o in track]
    gaps = [k for k in range(1, len(track)) if frames[k] - frames[k - 1] - 1 >= config.end_gap_frames]
    first, last = 0, len(track)

    def refused(piece: list[Observation], rest: list[Observation]) -> bool:
        if len(piece) > 3 or len(rest) < 3:
            return False
        misfits = [m for m in (_off_walk_misfit(o, rest, calib, config) for o in piece) if m is not None]
        return bool(misfits) and min(misfits) > gate ** 2

    while True:
        cut = next((k for k in gaps if first < k < last), None)
        if cut is None or not refused(track[first:cut], track[cut:last]):
            break
        first = cut
    while True:
        cut = next((k for k in reversed(gaps) if first < k < last), None)
        if cut is None or not refused(track[cut:last], track[first:cut]):
            break
        last = cut
    return track[first:last]


def off_walk_ends(track: list[Observation], calib: StereoCalibration, config: AssociationConfig
                  ) -> list[Observation]:
    """``track`` in frame order without the one-image frames at its ends that its own walk refuses.

    From each end inwards, while the frame there is seen in one image only and lies outside the track's
    frames seen in both images: the track's straight walk in that image (:func:`_image_track`,
    :func:`_track_walk`: column and image height), fitted over the rest of the track as it stands, is
    compared with the frame's detection (:func:`_walk_misfits`: its column and image height; the depth of its
    one-image centre is not judged, as the walk's own depth at a pair's end rests on few, loose stereo
    depths); a misfit above ``gate_sigmas^2`` leaves the frame out and the next one is judged, else the end
    stays.  A track with no frame seen in both images, or whose rest holds fewer than 3 frames in that image,
    keeps its ends."""
    gate = config.gate_sigmas
    track = sorted(track, key=lambda o: o.frame)
    both = [o.frame for o in track if len(o.uv) == 2]
    if not both:
        return track
    first, last = 0, len(track)

    def refused(k: int) -> bool:
        obs = track[k]
        if len(obs.uv) != 1 or min(both) <= obs.frame <= max(both):
            return False
        misfit = _off_walk_misfit(obs, [o for o in track[first:last] if o is not obs], calib, config)
        return misfit is not None and misfit > gate ** 2

    while last - first > 1 and refused(first):
        first += 1
    while last - first > 1 and refused(last - 1):
        last -= 1
    return track[first:last]


def _far_off_height(frame: int, walk: tuple, gate: float) -> bool:
    """Whether a track's image height at ``frame`` lies more than ``gate`` of its sigmas off the track's walk in
    that image (``walk``: one side of :func:`_height_walks`); False without a height there."""
    values, _, height_at = walk
    _, height, height_sigma = values.get(frame, (np.nan, np.nan, np.nan))
    return bool(abs(height - height_at(frame)) > gate * height_sigma)         # NaN: no height, False


def _someone_elses_height(frame: int, side: str, k: int, walks: list[dict], gate: float) -> bool:
    """Whether track ``k``'s height in image ``side`` at ``frame`` is off its own walk there and allowed by
    another track's walk passing near it (:func:`drop_other_heights`; ``walks``: :func:`_height_walks` of
    every track)."""
    if not _far_off_height(frame, walks[k][side], gate):
        return False
    column, height, height_sigma = walks[k][side][0][frame]
    return any(abs(column - column_at(frame)) <= 0.5 * height
               and abs(height - other_height_at(frame)) <= gate * height_sigma
               for j, walk in enumerate(walks) if j != k and side in walk
               for _, column_at, other_height_at in [walk[side]])


def _velocity(frames: np.ndarray, u: np.ndarray, sigma: np.ndarray) -> tuple[float, float]:
    """Slope of the weighted line through ``(frames, u)`` (``sigma`` (n,) each) and its standard error."""
    w = 1.0 / sigma ** 2
    fm = float((w * frames).sum() / w.sum())
    sxx = float((w * (frames - fm) ** 2).sum())
    slope = float((w * (frames - fm) * (u - (w * u).sum() / w.sum())).sum() / sxx)
    return slope, float(1.0 / np.sqrt(sxx))


def split_reversals(tracks: list[list[Observation]], calib: StereoCalibration,
                    config: AssociationConfig) -> list[list[Observation]]:
    """Split a pair's track where, across frames it missed, its image velocity changes more than a walker can
    (the tracker carried it on with someone walking the other way, the two crossing while missed).

    Per gap of a track (consecutive frames more than one apart), in the image that saw it most
    (:func:`_image_track`): the velocities of the line through its last up to four columns before the gap and
    of the line through its first up to four after it (at least two each), each with its standard error; the
    track is split there when they differ by more than ``gate_sigmas`` times those errors and a walker's
    velocity change over the gap (``tracker.accel_sigma_mps`` over the gap's time, at the track's scale) in
    quadrature.  Checked again on the part after a split.  Both parts are kept, however short (the track
    passed ``tracker.min_track_frames`` whole: its detections are a person's, not clutter)."""
    gate = config.gate_sigmas
    dt = config.tracker.frame_interval_s
    out = []
    pending = [list(t) for t in tracks]
    while pending:
        track = pending.pop(0)
        series = {sd: _image_track(track, calib, config, sd) for sd in ("left", "right")}
        frames, u, sigma, *_, px_per_m = max(series.values(), key=lambda item: len(item[0]))
        split_at = None
        for i in range(1, len(frames) - 2):
            gap = frames[i + 1] - frames[i]
            if gap <= 1:
                continue
            head = slice(max(i - 3, 0), i + 1)
            tail = slice(i + 1, min(i + 5, len(frames)))
            v_head, se_head = _velocity(frames[head], u[head], sigma[head])
            v_tail, se_tail = _velocity(frames[tail], u[tail], sigma[tail])
            change = config.tracker.accel_sigma_mps * gap * dt * dt * (px_per_m or 0.0)
            if abs(v_tail - v_head) > gate * float(np.sqrt(se_head ** 2 + se_tail ** 2 + change ** 2)):
                split_at = frames[i + 1]
                break
        if split_at is None:
            out.append(track)
            continue
        out.append([o for o in track if o.frame < split_at])
        pending.insert(0, [o for o in track if o.frame >= split_at])
    return out


def stitch_tracks(tracks: list[list[Observation]], calib: StereoCalibration,
                  config: AssociationConfig) -> list[list[Observation]]:
    """Join one pair's tracks of a person lost and found again: hidden for a few frames (a passing car, a
    neighbour in front) or missed in both images, the per-camera tracker gives up (``tracklet.max_misses``) or
    no longer recognises its keypoints (limbs swing over a gap), and the person goes on as a new track.  A
    piece may be too short to be kept (``tracker.min_track_frames``), and a piece fitted alone gets no shape
    or walk from the frames where the person was seen well.

    A track ending at frame ``e`` and one starting at ``s``, ``e < s <= e + 1 + stitch_max_gap_frames``, are one
    person when one straight walk at constant velocity explains both: the misfit of the joined track
    (:func:`_walk_fit`: image column, centre depths and image heights, robust, in the image where both are
    seen most, :func:`_image_track`) exceeds the two tracks' own misfits by at most ``gate_sigmas^2`` (joining
    one walker's pieces leaves an increase about chi-square distributed with four degrees of freedom, one
    walk's column line, depth and rate fewer, five with the heights; a piece of someone elsewhere adds up to
    ``gate_sigmas^2`` per frame).
    Each track must hold at least three frames (its own walk is measured; through two frames any walk
    passes) of which at least two have a stereo centre: seen in one image, a person cannot be told from
    someone behind it in the same image column.  A join is made only where it is the one that passes both for
    the first track's end and for the second's start (two people one behind the other on a ray, hidden
    together, leave two pieces that the found one fits; the far one's noisy depths fit it best, and the walk
    cannot tell which); chains of joins make one track.  Returns the tracks, each joined chain in the place
    of its first track, the others as they were."""
    max_gap = frames_for(config.tracker, config.stitch_max_gap_frames) if config.stitch_max_gap_frames > 0 else 0
    if max_gap <= 0 or len(tracks) < 2:
        return tracks
    gate = config.gate_sigmas
    memo: dict = {}
    sides = ("left", "right")
    placed = [len(t) >= 3 and sum(o.world_p is not None for o in t) >= 2 for t in tracks]
    series = {sd: [_image_track(t, calib, config, sd, memo=memo) if ok else None for t, ok in zip(tracks, placed)]
              for sd in sides}
    own: dict[tuple[str, int], float] = {}        # (image, track) -> the track's own walk misfit
    joins = []
    for a, head in enumerate(tracks):
        if not placed[a]:
            continue
        for b, tail in enumerate(tracks):
            if b == a or not placed[b] or not 0 < tail[0].frame - head[-1].frame <= max_gap + 1:
                continue
            side = max(sides, key=lambda sd: min(len(series[sd][a][0]), len(series[sd][b][0])))
            if min(len(series[side][a][0]), len(series[side][b][0])) < 3:
                continue
            for k in (a, b):
                if (side, k) not in own:
                    own[(side, k)] = _track_walk(series[side][k], calib, config)[0]
            increase = _track_walk(_image_track(head + tail, calib, config, side, memo=memo), calib, config)[0] \
                - own[(side, a)] - own[(side, b)]
            if increase <= gate ** 2:
                joins.append((a, b))
    # a join is made only where it is the one that passes for its track's end and for the other's start
    heads = Counter(a for a, _ in joins)
    tails = Counter(b for _, b in joins)
    successor = {a: b for a, b in joins if heads[a] == 1 and tails[b] == 1}
    followers = set(successor.values())
    out = []
    for k, track in enumerate(tracks):
        if k in followers:
            continue
        chain = list(track)
        while k in successor:
            k = successor[k]
            chain += tracks[k]
        out.append(chain)
    return out


def _agrees_with_stereo(obs: Observation, stereo: list[Observation], calib: StereoCalibration,
                        config: AssociationConfig) -> bool:
    """Whether a one-image frame's range centre (:func:`_range_centre`) lies at a depth each of the track's
    stereo (or LiDAR) centres ``stereo`` allows: within ``gate_sigmas`` of that centre's depth uncertainty
    plus how far a walker gets in the frames between (``tracker.max_speed_mps``); true when there are none
    (a detection's cluster can be a neighbour's or the background behind it)."""
    depth = float(calib.world_to_rect(np.asarray(obs.world_p, dtype=float))[2])
    step = config.tracker.max_speed_mps * config.tracker.frame_interval_s
    for known in stereo:
        reach = step * abs(known.frame - obs.frame)
        known_depth = float(calib.world_to_rect(np.asarray(known.world_p, dtype=float))[2])
        if abs(depth - known_depth) > config.gate_sigmas * min(float(known.depth_sigma_m), 5.0) + reach:
            return False
    return True


def _nearest_in_time(observations: list[Observation], frame: int) -> Observation:
    """The observation nearest to ``frame`` in time (the earlier one of two as near)."""
    return min(observations, key=lambda o: (abs(o.frame - frame), o.frame))


#: Relative depth rates tried per side of a walk's best one when bracketing it (:func:`_depth_walk`).
_RATE_STEPS = 32


def _depth_walk(stereo: list[Observation], calib: StereoCalibration,
                config: AssociationConfig) -> tuple[Callable[[float], float], Callable[[float], float]] | None:
    """The depth over frames of the straight walk fitted to the track ``stereo`` make (:func:`_track_walk`:
    image columns and centre depths, robust, depths uncertain as :func:`_image_track` gives them; not the
    image heights, which tell one person from another but whose 3 % per frame would bend the depth rate of a
    track holding one frame of someone taller), and how uncertain it is: ``(frame -> depth, frame -> sigma)``
    along the pair's rectified optical axis, metres; None when fewer than three of them have a centre.

    The sigma is how far the walk's rate can carry it: half the spread of the walk's depth at that frame
    over the rates whose misfit lies within 1 of the best one's (a profile of the one rate, each rate's
    walk refitted to the depths).  Near the centres that fix the walk it is small; a walk carried to a
    frame far from them by a rate that loose stereo depths leave open is uncertain there.  The walk's
    level, where its stereo frames lie, is the reference as it is: a LiDAR centre is one measurement that
    can hold a neighbour, the stereo frames together are the person."""
    seen = _image_track(stereo, calib, config)
    if np.isfinite(seen[3]).sum() < 3:
        return None
    _, rate = _track_walk(seen, calib, config, with_size=False)
    depth = _walk_lines(seen[:7], rate, config.gate_sigmas)[1]
    frames, u, sigma, depths, depth_sigma = seen[:5]
    max_rate = _depth_rate(seen[7], calib, config)
    rates = np.unique(np.clip(rate + max_rate * np.linspace(-1.0, 1.0, 2 * _RATE_STEPS + 1), -max_rate, max_rate))
    costs = _walk_costs(frames, u, sigma, config.gate_sigmas, depths, depth_sigma)(rates)
    near = rates[costs <= costs.min() + 1.0]
    lines = [line for line in (_walk_lines(seen[:7], float(r), config.gate_sigmas)[1] for r in near)
             if line is not None]

    def spread(frame: float) -> float:
        values = [line(frame) for line in lines] + [depth(frame)]
        return 0.5 * (max(values) - min(values))

    return depth, spread


def _off_walk(obs: Observation, walk: tuple[Callable[[float], float], Callable[[float], float]],
              calib: StereoCalibration, config: AssociationConfig) -> bool:
    """Whether an observation's centre depth lies more than ``gate_sigmas`` from the walk's
    (:func:`_depth_walk`: its depth and sigma), uncertain by its depth sigma, how far a walker leaves a
    straight walk (``swap_motion_m``, as :func:`_image_track` has it) and the walk's own sigma there."""
    depth = float(calib.world_to_rect(np.asarray(obs.world_p, dtype=float))[2])
    walk_depth, walk_sigma = walk
    sigma = float(np.sqrt(float(obs.depth_sigma_m) ** 2 + config.swap_motion_m ** 2 + walk_sigma(obs.frame) ** 2))
    return abs(depth - walk_depth(obs.frame)) > config.gate_sigmas * sigma


def settle_centres(tracks: list[list[Observation]], calib: StereoCalibration, config: AssociationConfig) -> None:
    """Check every centre against its final track (after :func:`repair_swaps`), in place.

    The track's straight walk is fitted to its stereo frames (:func:`_depth_walk`: frames seen in both
    images, their centres stereo or LiDAR).  A stereo frame's LiDAR centre off that walk
    (:func:`_off_walk`) goes back to the centre it replaced (:attr:`Observation.fallback`: a cut that held
    someone in front).  A frame seen in one image loses its centre (its detection's LiDAR cluster,
    :func:`_range_centre`) when it lies off the walk, or when a stereo centre on the walk does not allow its
    depth (:func:`_agrees_with_stereo`).

    Each range centre was checked against the nearest stereo centre in time only, while the tracks could
    still hold each other's tails; once they are final every centre counts: the cluster of someone in
    front that a loose stereo depth (1 m) next to it allowed is refused by a sharp one (0.1 m) a few
    frames away, and by the walk the track's other frames follow."""
    for track in tracks:
        stereo = [o for o in track if o.disparity_px is not None and o.world_p is not None]
        walk = _depth_walk(stereo, calib, config)
        if walk is not None:
            on_walk = [not _off_walk(o, walk, calib, config) for o in stereo]
            for obs, on in zip(stereo, on_walk):
                if not on and obs.fallback is not None:
                    obs.world_p, obs.world_p_camera, obs.depth_sigma_m = obs.fallback
                    obs.fallback = None
            stereo = [o for o, on in zip(stereo, on_walk) if on]
        for obs in track:
            if obs.disparity_px is None and obs.world_p is not None and \
                    ((walk is not None and _off_walk(obs, walk, calib, config))
                     or not _agrees_with_stereo(obs, stereo, calib, config)):
                obs.world_p, obs.world_p_camera, obs.depth_sigma_m = None, None, np.inf
                obs.fallback = None


def pixel_at_depth(calib: StereoCalibration, side: str, uv: np.ndarray, depth_m: float) -> np.ndarray:
    """(3,) world point of the rectified pixel ``uv`` of the pair's ``side`` image at ``depth_m`` along the
    rectified optical axis."""
    P = calib.left_P_rect if side == "left" else calib.right_P_rect
    u, v = float(uv[0]), float(uv[1])
    rect_p = np.array([((u - P[0, 2]) * depth_m - P[0, 3]) / P[0, 0], ((v - P[1, 2]) * depth_m - P[1, 3]) / P[1, 1],
                       depth_m])
    return calib.rect_to_world(rect_p)


#: Height of a foot keypoint above the ground when standing (ankle ~0.08 m, heel and toe lower), metres.
_FOOT_HEIGHT_M = 0.06


def _feet_on_ground(keypoint_set: str, rect_uv: np.ndarray, calib: StereoCalibration, side: str, depth_m: float,
                    ground: GroundFrame, config: AssociationConfig, slack_m: float = 0.0) -> bool:
    """Whether the detected person (``keypoint_set``, rectified ``rect_uv`` in the pair's ``side`` image), put
    at ``depth_m``, stands on the ground: the median pixel of its foot keypoints (ankles, heels, toes) lies
    within ``feet_tolerance_m`` plus ``slack_m`` of a foot's height above the ground plane.  True when the
    ground height is unknown or no foot is seen (nothing to test)."""
    if ground.ground_offset_m is None:
        return True
    feet = _foot_rows(keypoint_set)
    present = [k for k in feet if k < len(rect_uv) and np.all(np.isfinite(rect_uv[k]))]
    if not present:
        return True
    foot_uv = median(rect_uv[present], axis=0)         # one stray toe does not lift the person
    height = float(ground.height(pixel_at_depth(calib, side, foot_uv, depth_m)[None])[0])
    return abs(height - _FOOT_HEIGHT_M) <= config.feet_tolerance_m + slack_m


@functools.lru_cache(maxsize=None)
def _foot_rows(keypoint_set: str) -> tuple[int, ...]:
    """Rows of a keypoint set's ankles, heels and toes."""
    names = load_keypoint_set(keypoint_set).keypoints
    return tuple(i for i, name in enumerate(names) if any(part in name.lower() for part in ("ankl", "heel", "toe")))


def _range_centre(obs: Observation, calib: StereoCalibration, ranges: Mapping[int, float],
                  cloud: np.ndarray | None = None, ground: GroundFrame | None = None,
                  config: AssociationConfig | None = None,
                  projection: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """Give an observation seen in one image only a centre where its detection has its own LiDAR cluster
    (:func:`detection_ranges`), in place: the median keypoint pixel's viewing ray at that cluster's range,
    with a loose 1 m uncertainty (a median pixel is not the body's centre); :func:`_lidar_centre` then
    replaces it by the cut's median, or slides it to the range, as for a stereo centre.  With the frame's
    scene ``cloud`` (and ``ground``, ``config``; ``projection``: the cloud projected into the observation's
    image, when done), not where the cluster goes on past the silhouette (:func:`ends_at_silhouette`: a wall
    behind someone the LiDAR misses)."""
    side = next(iter(obs.uv))
    if not isinstance(obs.payload, dict) or id(obs.payload.get(side)) not in ranges:
        return
    range_m = ranges[id(obs.payload[side])]
    if cloud is not None and not ends_at_silhouette(obs.uv[side], calib, side, cloud, ground, range_m,
                                                    config or AssociationConfig(), projection):
        return
    present = obs.uv[side][np.all(np.isfinite(obs.uv[side]), axis=1)]
    if len(present) == 0:
        return
    obs.fallback = (obs.world_p, obs.world_p_camera, obs.depth_sigma_m)
    obs.world_p = pixel_at_depth(calib, side, median(present, axis=0), range_m)
    obs.world_p_camera = calib.camera_centre(side)
    obs.depth_sigma_m = 1.0


def _lidar_centre(obs: Observation, calib: StereoCalibration, cloud: np.ndarray, ground: GroundFrame,
                  config: AssociationConfig, projections: dict, ranges: Mapping[int, float] | None = None,
                  claimed: Mapping[str, list[float]] | None = None,
                  others: Mapping[str, list[np.ndarray]] | None = None) -> None:
    """Replace the observation's centre by the median of its LiDAR cut when the cut is large enough
    (``projections``: side -> the cloud projected into that image, filled on first use).  Where both images
    saw the person, the cut's keypoints are the left ones completed by the right ones at the observation's
    disparity (:func:`~pedx_graph.detections.lidar_cut.completed_keypoints`, as for the segments); a person
    cut off by the image's border has its cut completed past it (``border_centre_steps``).  With ``ranges``
    (:func:`detection_ranges`: each image's clusters given one to one to its detections), the cut must lie
    at the range of the detection's own cluster (within ``lidar_range_sigma_m``) when it has one; a detection
    without one keeps its stereo centre when the cut lies at a range another detection of that image holds
    (``claimed``: side -> those ranges): a far person's cut that caught the near person in front is not taken
    for the far person's centre.  A detection whose cut misses its own cluster gets its stereo centre slid
    along the viewing ray to that cluster's range (uncertain by ``lidar_range_sigma_m``).  A detection without
    its own cluster keeps its stereo centre too when most of its cut lies inside another detection's hull
    of that image (``others``: side -> those detections' rectified keypoints): a cut of someone hidden
    behind a neighbour holds the neighbour."""
    from pedx_graph.data.segment_cut import points_in_polygon
    from pedx_graph.detections.lidar_cut import (completed_keypoints, cut_indices, hull_polygon, project_cloud,
                                                 reaches_border)

    side = "left" if "left" in obs.uv else "right"
    seen_uv = obs.uv[side]
    if side == "left" and "right" in obs.uv and obs.disparity_px is not None:
        # one silhouette, as for the segments: the left keypoints, the missing ones from the right image
        seen_uv = completed_keypoints(obs.uv["left"], obs.uv["right"] + np.array([obs.disparity_px, 0.0]))
    own_range = None
    if ranges is not None and isinstance(obs.payload, dict):
        own_range = ranges.get(id(obs.payload[side]))
    depth = None
    if obs.world_p is not None:
        depth = float(calib.world_to_rect(obs.world_p)[2])
    cloud = np.asarray(cloud, dtype=float).reshape(-1, 3)
    if projections.get(side) is None:
        projections[side] = project_cloud(calib, side, cloud)
    index = cut_indices(seen_uv, calib, side, cloud, ground, config.lidar_cut, depth_m=depth,
                        projection=projections[side])
    if reaches_border(seen_uv, calib, config.lidar_cut):
        # cut off by the image's border: the seen part's median lies off the body's centre; the cut goes on
        # past the border around that median, then around the new one (each nearer the whole body's centre)
        for _ in range(config.border_centre_steps):
            if len(index) < config.lidar_min_points:
                break
            grown = cut_indices(seen_uv, calib, side, cloud, ground, config.lidar_cut, depth_m=depth,
                                projection=projections[side], world_centre=ground.median_point(cloud[index]))
            if np.array_equal(grown, index):
                break
            index = grown
    points = cloud[index]
    centre, sigma = None, config.lidar_sigma_m
    if own_range is None and others and len(index):
        cut_uv = projections[side][0][index]              # the cut's pixels (finite: they lie in its hull)
        shared = np.zeros(len(index), dtype=bool)
        for other_uv in others.get(side, []):
            polygon = hull_polygon(np.asarray(other_uv, dtype=float), config.lidar_cut)
            if polygon is not None:
                shared |= points_in_polygon(cut_uv, polygon)
        if shared.mean() >= 0.5:
            points = points[:0]
    if len(points) >= config.lidar_min_points:
        centre = ground.median_point(points)
        centre_range = float(calib.world_to_rect(centre)[2])
        if own_range is not None and abs(centre_range - own_range) > config.lidar_range_sigma_m:
            centre = None
        elif own_range is None and claimed and any(abs(centre_range - r) <= config.lidar_range_sigma_m
                                                   for r in claimed.get(side, [])):
            centre = None
    if centre is None and own_range is not None and depth is not None and depth > 0:
        # the cut missed the detection's own cluster: the stereo centre slid along its ray to that range
        camera = calib.camera_centre("left")           # the rectified frame's origin
        centre = camera + (own_range / depth) * (np.asarray(obs.world_p, dtype=float) - camera)
        sigma = config.lidar_range_sigma_m
    if centre is None:
        return
    # accepted only where it agrees with the stereo centre (a cut that caught an occluder does not)
    offset = np.linalg.norm(ground.to_level(centre)[:2] - ground.to_level(obs.world_p)[:2])
    if offset <= config.gate_sigmas * obs.depth_sigma_m + config.lidar_agreement_m:
        obs.fallback = (obs.world_p, obs.world_p_camera, obs.depth_sigma_m)
        obs.world_p = centre
        obs.world_p_camera = calib.camera_centre(side)
        obs.depth_sigma_m = sigma


# ---------------------------------------------------------------------------------------------- across pairs

def _centres(track: list[Observation]) -> dict[int, tuple[np.ndarray, float]]:
    """Frame -> (3D centre, depth sigma) of every frame of the track between its first and last 3D centre:
    observed, or interpolated linearly in time between the neighbouring ones (with the larger sigma)."""
    known = [(o.frame, o.world_p, min(float(o.depth_sigma_m), 1e3)) for o in track if o.world_p is not None]
    if not known:
        return {}
    frames = np.array([k[0] for k in known], dtype=float)
    points = np.array([k[1] for k in known], dtype=float)
    sigmas = np.array([k[2] for k in known], dtype=float)
    out = {}
    for o in track:
        if not frames[0] <= o.frame <= frames[-1]:
            continue
        j = int(np.searchsorted(frames, o.frame))
        if frames[min(j, len(frames) - 1)] == o.frame:
            out[o.frame] = (points[j], float(sigmas[j]))
            continue
        w = (o.frame - frames[j - 1]) / (frames[j] - frames[j - 1])
        out[o.frame] = ((1 - w) * points[j - 1] + w * points[j], float(max(sigmas[j - 1], sigmas[j])))
    return out


def _image_agreement(seen: list[Observation], centres: dict, camera_p: np.ndarray, calib_seen: StereoCalibration,
                     config: AssociationConfig) -> float | None:
    """How well one track's 3D centres explain another track's detections in its own images: the median over
    the shared frames of the normalised horizontal pixel offset between the centre projected into each image
    of ``seen`` and that detection's median keypoint (tolerance: ``merge_distance_m`` at the centre's depth,
    and the centre's depth uncertainty moved along its viewing ray and seen from this camera), with the
    keypoint span the centre's depth predicts (from the centre's own track) as a second term (log ratio over
    twice ``size_sigma``).  ``centres``: frame -> (world centre, its depth sigma along the ray from
    ``camera_p``, the known track's keypoint span in metres or None).  None when fewer than
    ``merge_min_shared_frames`` frames are comparable."""
    from pedx_graph.detections.lidar_cut import project_cloud

    scores = []
    for obs in seen:
        if obs.frame not in centres:
            continue
        world_p, sigma, span_m = centres[obs.frame]
        terms = []
        for side, uv in obs.uv.items():
            present = uv[np.all(np.isfinite(uv), axis=1)]
            if len(present) < config.min_shared_keypoints:
                continue
            ray = world_p - camera_p
            points = np.array([world_p])
            if np.isfinite(sigma):
                unit = ray / max(float(np.linalg.norm(ray)), 1e-9)
                points = np.array([world_p, world_p + min(sigma, 5.0) * unit])
            uv_c, depth = project_cloud(calib_seen, side, points)
            if not np.all(np.isfinite(uv_c)) or depth[0] <= config.min_depth_m:
                continue
            f_px = calib_seen.focal_px
            spread = abs(uv_c[1, 0] - uv_c[0, 0]) if len(points) == 2 else 0.0
            tol = float(np.hypot(config.merge_distance_m * f_px / depth[0], spread))
            offset = abs(float(median(present[:, 0])) - uv_c[0, 0]) / tol
            size = 0.0
            if span_m is not None and np.ptp(present[:, 1]) > 4:
                size = abs(np.log(np.ptp(present[:, 1]) * depth[0] / f_px / span_m)) / (2 * config.size_sigma)
            terms.append(max(offset, size))
        if terms:
            scores.append(min(terms))
    if len(scores) < config.merge_min_shared_frames:
        return None
    return float(median(scores))


def _span_m(track: list[Observation], calib: StereoCalibration) -> float | None:
    """Median vertical keypoint span of a track's 3D frames in metres (pixels x depth / focal length)."""
    spans = []
    for obs in track:
        if obs.world_p is None:
            continue
        for side, uv in obs.uv.items():
            v = uv[np.all(np.isfinite(uv), axis=1), 1]
            if len(v) >= 2 and np.ptp(v) > 4:
                depth = float(calib.world_to_rect(np.asarray(obs.world_p, dtype=float))[2])
                spans.append(np.ptp(v) * depth / calib.focal_px)
    return float(median(spans)) if spans else None


def _ray_distances(pa: np.ndarray, pb: np.ndarray, cameras: list[np.ndarray], sigmas: list[np.ndarray],
                   lateral_sigma_m: float) -> np.ndarray:
    """(n,) Mahalanobis distances between two tracks' ground-plane centres ``pa``, ``pb`` (n, 2): each centre
    uncertain by its depth sigma (``sigmas``, (n,) each) along the ray from its camera (``cameras``,
    ground-plane positions, (2,) or (n, 2)) and by ``lateral_sigma_m`` across it.  Two people walking side by
    side half a metre apart, whose centres are a metre uncertain in depth, are told apart where an isotropic
    distance is not."""
    cov = np.zeros((len(pa), 2, 2))
    for points, camera, sigma in zip((pa, pb), cameras, sigmas):
        ray = points - camera
        ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-9)
        along = np.minimum(sigma, 5.0) ** 2 - lateral_sigma_m ** 2
        cov += lateral_sigma_m ** 2 * np.eye(2) + np.maximum(along, 0.0)[:, None, None] * ray[:, :, None] * ray[:, None, :]
    diff = pa - pb
    return np.sqrt(np.einsum("ni,ni->n", diff, np.linalg.solve(cov, diff[..., None])[..., 0]))


def _ray_distance(pa: np.ndarray, pb: np.ndarray, cameras: list[np.ndarray], sigmas: list[np.ndarray],
                  lateral_sigma_m: float) -> float:
    """Median of :func:`_ray_distances` over the shared frames."""
    return float(median(_ray_distances(pa, pb, cameras, sigmas, lateral_sigma_m)))


def merge_pair_tracks(pair_tracks: list[tuple[str, list[Observation]]], ground: GroundFrame,
                      config: AssociationConfig,
                      calibrations: Mapping[str, StereoCalibration] | None = None) -> list[list[int]]:
    """Groups of indices into ``pair_tracks`` (``(pair name, observations)``) that are one person (module
    docstring, step 5); every index is in exactly one group.  With ``calibrations``, a track with too few 3D
    centres of its own (seen in one image of its pair) is compared in its images with the other pair's 3D
    centres (:func:`_image_agreement`)."""
    centres = [_centres(obs) for _, obs in pair_tracks]
    spans = [(_span_m(obs, calibrations[pair]) if calibrations else None) for pair, obs in pair_tracks]
    candidates = []
    for a in range(len(pair_tracks)):
        for b in range(a + 1, len(pair_tracks)):
            if pair_tracks[a][0] == pair_tracks[b][0]:
                continue
            shared = sorted(set(centres[a]) & set(centres[b]))
            if len(shared) >= config.merge_min_shared_frames:
                pa = ground.to_level(np.array([centres[a][f][0] for f in shared]))[:, :2]
                pb = ground.to_level(np.array([centres[b][f][0] for f in shared]))[:, :2]
                sigma = np.sqrt(np.array([centres[a][f][1] ** 2 + centres[b][f][1] ** 2 for f in shared])
                                + config.merge_distance_m ** 2)
                score = float(median(np.linalg.norm(pa - pb, axis=1) / sigma))
                if calibrations is not None:
                    # a centre is uncertain along its viewing ray, hardly across it: gated and ordered so
                    cameras = [ground.to_level(calibrations[pair_tracks[i][0]].camera_centre("left"))[:2]
                               for i in (a, b)]
                    distance = _ray_distance(pa, pb, cameras,
                                             [np.array([centres[i][f][1] for f in shared]) for i in (a, b)],
                                             config.centre_lateral_sigma_m)
                    if distance <= config.gate_sigmas:
                        candidates.append((distance / config.gate_sigmas, a, b))
                    continue
            elif calibrations is not None:
                # one of them is (mostly) seen in one image: the other's centres must explain its detections
                options = []
                for known, seen in ((a, b), (b, a)):
                    if len(centres[known]) < config.merge_min_shared_frames:
                        continue
                    known_centres = {f: (c, s, spans[known]) for f, (c, s) in centres[known].items()}
                    value = _image_agreement(pair_tracks[seen][1], known_centres,
                                             calibrations[pair_tracks[known][0]].camera_centre("left"),
                                             calibrations[pair_tracks[seen][0]], config)
                    if value is not None:
                        options.append(value)
                if not options:
                    continue
                score = min(options)
            else:
                continue
            if score <= 1.0:
                candidates.append((score, a, b))
    frames_of = [{o.frame for o in obs} for _, obs in pair_tracks]
    group_of = list(range(len(pair_tracks)))
    members = {i: {i} for i in range(len(pair_tracks))}
    for _, a, b in sorted(candidates):
        ga, gb = group_of[a], group_of[b]
        if ga == gb:
            continue
        # never two tracks of one pair at one frame in one person (one pair's tracks of one person at
        # different times — the person lost and found again — are one)
        if any(pair_tracks[i][0] == pair_tracks[j][0] and frames_of[i] & frames_of[j]
               for i in members[ga] for j in members[gb]):
            continue
        for i in members[gb]:
            group_of[i] = ga
        members[ga] |= members.pop(gb)
    return [sorted(m) for _, m in sorted(members.items())]


# ---------------------------------------------------------------------------------------------- smoothing

def _consensus(x: np.ndarray, y: np.ndarray, sigma: np.ndarray, gate: float, max_step: float) -> np.ndarray:
    """The centres (times ``x`` (n,), ground-plane positions ``y`` (n, 2), uncertainties ``sigma`` (n,)) that
    the best-supported walking line explains within ``gate`` sigmas: of the lines through each centre
    (standing) and through each two centres (speed clipped to ``max_step`` per frame), the one with most
    such centres, ties to the smaller sum of squared normalised residuals.  A single centre with a small
    uncertainty that lies on someone else (a wrong pairing, a cut on an occluder) no longer outweighs the
    others, as it would in a weighted least-squares start."""
    n = len(x)
    i, j = np.triu_indices(n, k=1)
    moving = x[i] != x[j]
    i, j = i[moving], j[moving]
    slope = (y[j] - y[i]) / (x[j] - x[i])[:, None]
    speed = np.linalg.norm(slope, axis=1)
    slope = slope * np.minimum(1.0, max_step / np.maximum(speed, 1e-300))[:, None]
    offsets = np.concatenate([y, y[i] - x[i, None] * slope])           # standing lines first, then pairs
    slopes = np.concatenate([np.zeros((n, 2)), slope])
    z = np.linalg.norm(y[None] - (offsets[:, None] + x[None, :, None] * slopes[:, None]), axis=2) / sigma
    inside = z <= gate
    counts = inside.sum(axis=1)
    sums = np.where(inside, z ** 2, 0.0).sum(axis=1)
    best = inside[np.lexsort((sums, -counts))[0]]
    return best if best.any() else np.ones(n, dtype=bool)


def _walking_line(x: np.ndarray, y: np.ndarray, w: np.ndarray, max_step: float,
                  slope_prior: tuple[np.ndarray, float] | None = None) -> np.ndarray:
    """Weighted least-squares line ``y = a + b x`` per ground-plane axis (``x`` (n,) frames, ``y`` (n, 2),
    weights ``w`` (n,)), its speed clipped to ``max_step`` per frame (the offset refitted); ``slope_prior``
    ``(b0 (2,), weight)`` adds ``weight * |b - b0|^2`` (a walker's velocity changes slowly: a few close
    centres do not decide it alone).  Returns ``[[a], [b]]`` (2, 2); a constant (b = 0, or ``b0``) with one
    distinct frame."""
    if len(np.unique(x)) < 2 and slope_prior is None:
        return np.stack([np.average(y, axis=0, weights=w), np.zeros(2)])
    normal = np.array([[w.sum(), (w * x).sum()], [(w * x).sum(), (w * x * x).sum()]])
    rhs = np.stack([(w[:, None] * y).sum(axis=0), (w[:, None] * x[:, None] * y).sum(axis=0)])
    if slope_prior is not None:
        normal[1, 1] += slope_prior[1]
        rhs[1] += slope_prior[1] * slope_prior[0]
    coef = np.linalg.solve(normal + 1e-12 * np.eye(2), rhs)
    speed = float(np.linalg.norm(coef[1]))
    if speed > max_step:                        # no walker moves faster: the slope clipped, the offset refitted
        coef[1] *= max_step / speed
        coef[0] = np.average(y - x[:, None] * coef[1], axis=0, weights=w)
    return coef


def _offset_sigma(x: np.ndarray, w: np.ndarray, slope_weight: float, slope_variance: float = 0.0) -> float:
    """Standard deviation, metres, of the offset ``a`` (the line's value at ``x = 0``) of :func:`_walking_line`'s
    fit to centres at frames ``x`` (n,) from the frame with weights ``w`` (n,) (inverse variances per axis),
    its slope drawn with weight ``slope_weight`` to a velocity that is itself uncertain by ``slope_variance``
    (per axis): with ``C = N^-1``, ``N = [[sum w, sum w x], [sum w x, sum w x^2 + slope_weight]]``, the
    variance ``C_00 + (C_01 slope_weight)^2 slope_variance``.  ``1 / sqrt(sum w)`` where the centres lie
    around the frame; larger where the line is carried past them (a track's ends, a stretch without a
    centre)."""
    s0, s1, s2 = float(w.sum()), float((w * x).sum()), float((w * x * x).sum()) + slope_weight
    det = s0 * s2 - s1 * s1
    if det <= 0:
        return float(1.0 / np.sqrt(s0))
    return float(np.sqrt(s2 / det + (-s1 / det * slope_weight) ** 2 * slope_variance))


def _trend(x: np.ndarray, y: np.ndarray, sigma: np.ndarray, config: AssociationConfig) -> tuple[np.ndarray, float]:
    """A walker's velocity (2,) metres per frame around ``x = 0``: the weighted line (:func:`_walking_line`)
    through the centres (``x`` (n,) frames from it, ``y`` (n, 2), ``sigma`` (n,)) within four
    ``smooth_window_frames`` (at least the ``smooth_min_centres`` nearest), started from the centres the
    best-supported line explains (:func:`_consensus`) and refitted three times without the centres beyond
    ``gate_sigmas``; the slope drawn toward zero by ``walking_speed_mps`` (per axis: a walker's speed is that
    of a prior, not of the noise of a few centres); zero with fewer than two distinct frames.  Returns the
    velocity and its variance per axis ((metres per frame)^2; for a zero, the walking prior's, or a walker's
    top speed squared without one)."""
    near = np.abs(x) <= 4 * config.smooth_window_frames
    if near.sum() < config.smooth_min_centres:
        near = np.zeros(len(x), dtype=bool)
        near[np.lexsort((x, np.abs(x)))[:config.smooth_min_centres]] = True
    x, y, w = x[near], y[near], 1.0 / sigma[near] ** 2
    max_step = config.tracker.max_speed_mps * config.tracker.frame_interval_s
    walking_step = config.walking_speed_mps * config.tracker.frame_interval_s
    standing = (np.zeros(2), 1.0 / walking_step ** 2) if walking_step > 0 else None
    prior_weight = standing[1] if standing is not None else 0.0
    keep = _consensus(x, y, sigma[near], config.gate_sigmas, max_step)
    coef = np.zeros((2, 2))
    for _ in range(3):
        if len(np.unique(x[keep])) < 2:
            return np.zeros(2), (walking_step ** 2 if walking_step > 0 else max_step ** 2)
        coef = _walking_line(x[keep], y[keep], w[keep], max_step, standing)
        fitted = keep
        new_keep = np.linalg.norm(y - (coef[0] + x[:, None] * coef[1]), axis=1) * np.sqrt(w) <= config.gate_sigmas
        if new_keep.sum() < 2 or np.array_equal(new_keep, keep):
            break
        keep = new_keep
    s0, s1 = float(w[fitted].sum()), float((w[fitted] * x[fitted]).sum())     # the centres the line was fitted to
    s2 = float((w[fitted] * x[fitted] ** 2).sum()) + prior_weight
    return coef[1], s0 / max(s0 * s2 - s1 * s1, 1e-300)


def smooth_centres(frames: list[DetectedTrackFrame], ground: GroundFrame, config: AssociationConfig,
                   only: frozenset | None = None) -> None:
    """Replace every frame's centre and its uncertainty by the track's smoothed ones (module docstring, step 7;
    :func:`_offset_sigma`), in place; with ``only``, just those frames' (every frame's centre still counts).

    Each frame's line is fitted to the ``2 smooth_window_frames + 1`` centres that tell most about it, each
    weighed by its uncertainty, ``smooth_motion_m`` and a walker's drift off its line over the time between
    (``0.5 tracker.accel_sigma_mps t^2``) in quadrature (where a person was hidden for a while and is seen
    again by stereo only, the precise LiDAR centres before count as well as the noisy ones after), its
    velocity drawn to the person's walking velocity over four windows
    (:func:`_trend`) with the weight of a walker's velocity change over one window
    (``tracker.accel_sigma_mps``): at a track's end or after a stretch seen in one image, a line through two
    noisy centres is not carried frames beyond them."""
    known = [(fr.frame, ground.to_level(fr.world_p), min(float(fr.depth_sigma_m), 5.0))
             for fr in frames if fr.world_p is not None]
    if not known:
        return
    t = np.array([k[0] for k in known], dtype=float)
    level = np.array([k[1] for k in known], dtype=float)
    sigma = np.hypot(np.array([k[2] for k in known]), config.smooth_motion_m)
    height = float(median(level[:, 2]))
    world_R_level = ground.world_R_level
    dt = config.tracker.frame_interval_s
    max_step = config.tracker.max_speed_mps * dt
    velocity_sigma = max(config.tracker.accel_sigma_mps * dt * max(config.smooth_window_frames, 1) * dt, 1e-6)
    count = max(2 * config.smooth_window_frames + 1, config.smooth_min_centres)
    for fr in frames:
        if only is not None and fr.frame not in only:
            continue
        # each centre as evidence of this frame's: its own uncertainty and how far a walker leaves its line
        # over the time between them (a velocity change of accel_sigma_mps per second), the ``count`` most
        # telling kept (the nearest ones where every frame has a precise centre; a LiDAR centre a second
        # away rather than a few noisy stereo depths close by)
        seconds = np.abs(t - fr.frame) * dt
        telling = np.hypot(sigma, 0.5 * config.tracker.accel_sigma_mps * seconds ** 2)
        near = np.zeros(len(t), dtype=bool)
        near[np.lexsort((t, seconds, telling))[:count]] = True
        x, y, w = t[near] - fr.frame, level[near, :2], 1.0 / telling[near] ** 2
        trend, trend_variance = _trend(t - fr.frame, level[:, :2], sigma, config)
        prior = (trend, 1.0 / velocity_sigma ** 2)
        keep = _consensus(x, y, telling[near], config.gate_sigmas, max_step)
        for _ in range(3):                       # weighted line per axis; outlying centres left out
            coef = _walking_line(x[keep], y[keep], w[keep], max_step, prior)
            fitted = keep                        # the centres this line was fitted to
            residual = np.linalg.norm(y - (coef[0] + x[:, None] * coef[1]), axis=1) / telling[near]
            new_keep = residual <= config.gate_sigmas
            if not new_keep.any() or np.array_equal(new_keep, keep):
                break
            keep = new_keep
        fit_sigma = _offset_sigma(x[fitted], w[fitted], prior[1], trend_variance)
        level_p = np.array([coef[0][0], coef[0][1], height])
        fr.world_p = ground.world_p_sensor + world_R_level @ level_p
        fr.depth_sigma_m = min(float(fr.depth_sigma_m), fit_sigma) if fr.frame in set(t[near][fitted]) \
            else fit_sigma


def _frame_centre(entry: DetectedTrackFrame, sources: list[Observation]) -> None:
    """Set a merged frame's centre to that of its pairs' observations with the smallest depth sigma."""
    entry.world_p, entry.depth_sigma_m = None, float("inf")
    for obs in sources:
        if obs.world_p is not None and obs.depth_sigma_m < entry.depth_sigma_m:
            entry.world_p, entry.depth_sigma_m = obs.world_p, obs.depth_sigma_m


def _smoothed_without(frames: list[DetectedTrackFrame], sources: dict[int, list[Observation]], left_out: Observation,
                      ground: GroundFrame, config: AssociationConfig) -> np.ndarray | None:
    """The person's smoothed centre (3,) at ``left_out``'s frame with that observation's LiDAR centre replaced
    by what it was before (:attr:`Observation.fallback`), or None; ``frames`` are left as they are."""
    copies = []
    for entry in frames:
        copy = DetectedTrackFrame(frame=entry.frame, detections={})
        kept = [obs for obs in sources.get(entry.frame, []) if obs is not left_out]
        _frame_centre(copy, kept)
        if entry.frame == left_out.frame and left_out.fallback[0] is not None and \
                left_out.fallback[2] < copy.depth_sigma_m:
            copy.world_p, copy.depth_sigma_m = left_out.fallback[0], left_out.fallback[2]
        copies.append(copy)
    smooth_centres(copies, ground, config, only=frozenset({left_out.frame}))
    return next((c.world_p for c in copies if c.frame == left_out.frame), None)


def drop_conflicting_pairs(frames: dict[int, DetectedTrackFrame], sources: dict[int, list[Observation]],
                           pair_of: Mapping[int, str], ground: GroundFrame, config: AssociationConfig,
                           calibrations: Mapping[str, StereoCalibration]) -> None:
    """Take out, in place, a pair's detections at a frame where its centre contradicts another pair's centre
    of the same merged person and the person's walk (module docstring, step 5): tracks of two pairs are merged
    on the median agreement of their shared frames, so one frame where a pair's own track went on with
    someone else (a neighbour a metre behind, overlapping in its images) joins the person with both people's
    detections, and a fit to both is confidently wrong.

    ``frames``: frame -> the merged person's :class:`DetectedTrackFrame`; ``sources``: frame -> the pairs'
    observations behind it; ``pair_of``: id of an observation -> its pair.  An observation's centre is its
    own, else, seen in both images of its pair but left unpaired, the one its median disparity gives
    (:func:`triangulate_centre`).  At a frame where two pairs' centres lie more than ``gate_sigmas`` apart
    (:func:`_ray_distance`: each uncertain by its depth sigma along its ray and ``centre_lateral_sigma_m``
    across it), the person's smoothed centre from its other
    frames (:func:`smooth_centres`) decides: the observation nearest it (same distance, the smoothed centre's
    own uncertainty and ``smooth_motion_m`` added) stays, an observation beyond ``gate_sigmas`` of it leaves
    the frame with its pair's detections.  Nothing changes where no observation lies within the gate."""
    def level_xy(world_p) -> np.ndarray:
        return _level_xy(ground, world_p)

    def camera_xy(obs: Observation) -> np.ndarray:
        return _camera_xy(obs, ground, calibrations, pair_of)

    def distance(a_xy, a_camera, a_sigma, b_xy, b_camera, b_sigma) -> float:
        return _ray_distance(a_xy[None], b_xy[None], [a_camera, b_camera], [np.array([a_sigma]), np.array([b_sigma])],
                             config.centre_lateral_sigma_m)

    def centre(obs: Observation) -> tuple[np.ndarray, float] | None:
        # its own centre, else (both images seen, left unpaired) the one its median disparity gives
        if obs.world_p is not None:
            return level_xy(obs.world_p), float(obs.depth_sigma_m)
        if set(obs.uv) != {"left", "right"}:
            return None
        disparity = _disparity_of(obs.uv["left"], obs.uv["right"], config)
        if disparity is None or disparity[0] <= 0:
            return None
        world_p, sigma = triangulate_centre(obs.uv["left"], obs.uv["right"], calibrations[pair_of[id(obs)]],
                                            ground, config)
        return level_xy(world_p), sigma

    for frame in sorted(frames):
        placed = []
        for obs in sources.get(frame, []):
            known = centre(obs) if id(obs) in pair_of else None
            if known is not None:
                placed.append((obs, *known))
        if len({pair_of[id(o)] for o, _, _ in placed}) < 2:
            continue
        conflict = any(pair_of[id(a)] != pair_of[id(b)] and
                       distance(a_xy, camera_xy(a), a_sigma, b_xy, camera_xy(b), b_sigma) > config.gate_sigmas
                       for i, (a, a_xy, a_sigma) in enumerate(placed) for b, b_xy, b_sigma in placed[i + 1:])
        if not conflict:
            continue
        others = []
        for f, entry in frames.items():
            copy = DetectedTrackFrame(frame=f, detections={})
            if f != frame:
                _frame_centre(copy, sources.get(f, []))
            others.append(copy)
        if sum(c.world_p is not None for c in others) < 2:
            continue
        smooth_centres(others, ground, config, only=frozenset({frame}))
        walk = next(c for c in others if c.frame == frame)
        if walk.world_p is None:
            continue
        walk_sigma = float(np.hypot(min(walk.depth_sigma_m, 5.0), config.smooth_motion_m))
        scores = [distance(xy, camera_xy(o), sigma, level_xy(walk.world_p), camera_xy(o), walk_sigma)
                  for o, xy, sigma in placed]
        best = int(np.argmin(scores))
        if scores[best] > config.gate_sigmas:
            continue
        for (obs, _, _), score in zip(placed, scores):
            if score <= config.gate_sigmas or pair_of[id(obs)] == pair_of[id(placed[best][0])]:
                continue
            sources[frame] = [o for o in sources[frame] if o is not obs]
            left_name, right_name = pair_of[id(obs)].split("-")
            for side in obs.payload:
                frames[frame].detections.pop(left_name if side == "left" else right_name, None)
        if not frames[frame].detections:
            del frames[frame]
            sources.pop(frame, None)


def _level_xy(ground: GroundFrame, world_p) -> np.ndarray:
    """(2,) ground-plane position of a world point (3,), metres."""
    return ground.to_level(np.asarray(world_p, dtype=float))[:2]


def _camera_xy(obs: Observation, ground: GroundFrame, calibrations: Mapping[str, StereoCalibration],
               pair_of: Mapping[int, str]) -> np.ndarray:
    """(2,) ground-plane position of the camera an observation's centre was seen from (its pair's left camera
    where the observation does not say)."""
    camera = obs.world_p_camera if obs.world_p_camera is not None \
        else calibrations[pair_of[id(obs)]].camera_centre("left")
    return _level_xy(ground, camera)


def _between_frames(held: list[tuple[int, np.ndarray, float]]) -> dict[int, tuple[np.ndarray, float]]:
    """A track's ground-plane positions ``held`` (frame, (2,), sigma; in frame order) at every frame from its
    first to its last: a frame it lacks (its detection dropped, or taken by a neighbour's track) on the line
    between the neighbouring two, with the larger of their sigmas."""
    out = {}
    for (f0, p0, s0), (f1, p1, s1) in zip(held, held[1:]):
        for frame in range(f0, f1):
            out[frame] = (p0 + (frame - f0) / (f1 - f0) * (p1 - p0), s0 if frame == f0 else max(s0, s1))
    if held:
        out[held[-1][0]] = (held[-1][1], held[-1][2])
    return out


def _walk_of(frames: Mapping[int, DetectedTrackFrame], sources: Mapping[int, list[Observation]],
             ground: GroundFrame, config: AssociationConfig,
             left_out: str | None = None, pair_of: Mapping[int, str] | None = None
             ) -> dict[int, tuple[np.ndarray, float]]:
    """A person's smoothed walk in the ground plane: frame -> (level (x, y), its sigma) at every frame from
    its first to its last centre (between two held frames on the line joining them, with the larger sigma),
    from its pairs' observations (``left_out`` not counted), :func:`smooth_centres`."""
    copies = []
    for frame in sorted(frames):
        copy = DetectedTrackFrame(frame=frame, detections={})
        _frame_centre(copy, [obs for obs in sources.get(frame, [])
                             if left_out is None or pair_of[id(obs)] != left_out])
        copies.append(copy)
    placed = [c.frame for c in copies if c.world_p is not None]
    if len(placed) < 2:
        return {}
    smooth_centres(copies, ground, config)
    # between its first and last centre only: smoothing carries the line past them too
    held = [(c.frame, _level_xy(ground, c.world_p), min(float(c.depth_sigma_m), 5.0))
            for c in copies if c.world_p is not None and placed[0] <= c.frame <= placed[-1]]
    return _between_frames(held)


def move_to_neighbours(people: list[tuple[dict[int, DetectedTrackFrame], dict[int, list[Observation]]]],
                       pair_of: Mapping[int, str], track_of: Mapping[int, int], ground: GroundFrame,
                       config: AssociationConfig, calibrations: Mapping[str, StereoCalibration]) -> int:
    """Move, in place, a stretch of one pair track's observations from the merged person it is in to another
    person whose walk explains them (module docstring, step 5); returns how many stretches moved.

    Tracks of two pairs are merged on the median agreement of their shared frames, so a pair's track that went
    on with the walker alongside for a few frames (that walker's own track in the pair lost there) brings
    that walker's detections into the person.  Frame by frame the evidence is weak — two people walking side
    by side half a metre apart along the rays, their centres 0.1-0.2 m uncertain, lie two to three sigmas
    apart — but over a stretch it adds up.

    ``people``: per person, frame -> its :class:`DetectedTrackFrame` and frame -> the pairs' observations
    behind it; ``pair_of`` / ``track_of``: id of an observation -> its pair / the index of its pair track.
    For each pair track in a person, its person's walk from the other pairs' observations only
    (:func:`_walk_of`) and every other person's walk are compared with each of its observations' centres
    (:func:`_ray_distances`: the centre uncertain by its depth sigma along its ray and by
    ``centre_lateral_sigma_m`` across it, the walk by its own sigma and ``smooth_motion_m``).  Where the
    other person holds no observation of this pair at that frame and its walk explains the centre within
    ``gate_sigmas``, the observation's evidence for the move is half the difference of the squared
    distances (a log likelihood ratio); the consecutive observations, two at least, with the largest sum
    move when that sum reaches ``gate_sigmas^2 / 2`` (what one frame passing every gate adds to a pairing,
    step 4).  Never one alone: a single centre off its person's walk and on another's is more often a
    centre gone wrong (a cut or a cluster on the neighbour, a stereo mismatch; :func:`separate_people`) than
    a track gone on with someone else, which lasts.  The
    clearest stretch moves first and the walks are recomputed, at most ``move_max_runs`` stretches; a
    person left without frames is empty.  Without another pair's observations near a frame there is no
    walk to judge it by, and nothing moves."""
    seen: dict[int, tuple[np.ndarray, np.ndarray, float]] = {}     # id -> (centre, camera) (2,), depth sigma

    def distances(placed: list[Observation], walk: dict) -> np.ndarray:
        # each placed centre against the walk at its frame (the walk's sigma with smooth_motion_m)
        for obs in placed:
            if id(obs) not in seen:
                seen[id(obs)] = (_level_xy(ground, obs.world_p), _camera_xy(obs, ground, calibrations, pair_of),
                                 float(obs.depth_sigma_m))
        walk_xy = np.array([walk[obs.frame][0] for obs in placed])
        walk_sigma = np.hypot([walk[obs.frame][1] for obs in placed], config.smooth_motion_m)
        cameras = np.array([seen[id(obs)][1] for obs in placed])
        return _ray_distances(np.array([seen[id(obs)][0] for obs in placed]), walk_xy, [cameras, cameras],
                              [np.array([seen[id(obs)][2] for obs in placed]), walk_sigma],
                              config.centre_lateral_sigma_m)

    walks = [_walk_of(frames, sources, ground, config) for frames, sources in people]
    own_walks: dict[tuple[int, str], dict] = {}         # (person, pair) -> its walk without that pair
    moved = 0
    for _ in range(config.move_max_runs):
        clearest = None                # (evidence, person, other, observations)
        for person, (frames, sources) in enumerate(people):
            by_track: dict[int, list[Observation]] = defaultdict(list)
            for frame in sorted(sources):
                for obs in sources[frame]:
                    by_track[track_of[id(obs)]].append(obs)
            for observations in by_track.values():
                pair = pair_of[id(observations[0])]
                if (person, pair) not in own_walks:
                    own_walks[person, pair] = _walk_of(frames, sources, ground, config, left_out=pair, pair_of=pair_of)
                own = own_walks[person, pair]
                placed = [obs for obs in observations if obs.world_p is not None and obs.frame in own]
                if not placed:
                    continue
                d_own = dict(zip(map(id, placed), distances(placed, own)))
                for other, (_, other_sources) in enumerate(people):
                    if other == person:
                        continue
                    candidates = [obs for obs in placed if obs.frame in walks[other] and
                                  not any(pair_of[id(o)] == pair for o in other_sources.get(obs.frame, []))]
                    if not candidates:
                        continue
                    d_other = dict(zip(map(id, candidates), distances(candidates, walks[other])))
                    # the best run of consecutive observations the other's walk explains better than the
                    # own person's walk without this pair: evidence adds over the run
                    run, total, best = [], 0.0, (0.0, [])
                    for obs in observations:
                        gain = None
                        if d_other.get(id(obs), np.inf) <= config.gate_sigmas:
                            gain = 0.5 * (d_own[id(obs)] ** 2 - d_other[id(obs)] ** 2)
                        if gain is None or total + gain <= 0:
                            run, total = [], 0.0
                            continue
                        run, total = run + [obs], total + gain
                        if total > best[0] and len(run) >= 2:
                            best = (total, list(run))
                    if best[0] >= 0.5 * config.gate_sigmas ** 2 and (clearest is None or best[0] > clearest[0]):
                        clearest = (best[0], person, other, best[1])
        if clearest is None:
            break
        _, person, other, observations = clearest
        frames, sources = people[person]
        other_frames, other_sources = people[other]
        left_name, right_name = pair_of[id(observations[0])].split("-")
        for obs in observations:
            frame = obs.frame
            names = {side: left_name if side == "left" else right_name for side in obs.payload}
            sources[frame] = [o for o in sources[frame] if o is not obs]
            for name in names.values():
                frames[frame].detections.pop(name, None)
            if not frames[frame].detections:
                del frames[frame]
                sources.pop(frame, None)
            entry = other_frames.setdefault(frame, DetectedTrackFrame(frame=frame, detections={}))
            for side, det in obs.payload.items():
                entry.detections[names[side]] = det
            other_sources.setdefault(frame, []).append(obs)
        walks[person] = _walk_of(frames, sources, ground, config)
        walks[other] = _walk_of(other_frames, other_sources, ground, config)
        own_walks = {key: walk for key, walk in own_walks.items() if key[0] not in (person, other)}
        moved += 1
    return moved


def separate_people(people: list[tuple[list[DetectedTrackFrame], dict[int, list[Observation]]]],
                    ground: GroundFrame, config: AssociationConfig) -> None:
    """Smooth every person's centres (:func:`smooth_centres`; ``people``: per person its frames and, per
    frame, the pairs' observations behind it), in place; then a centre an observation took from the LiDAR
    (:attr:`Observation.fallback` set) that lies within ``min_separation_m`` of another person's smoothed
    centre at its frame (between two of that person's frames, on the line joining their centres: a frame
    the neighbour's track lacks, its detection dropped or taken by this track, still has the neighbour
    there), and nearer to it than to its own person's smoothed centre without it
    (:func:`_smoothed_without`), goes back to what it was before (its stereo centre, or none) and the person
    is smoothed again.  One centre per round, the one nearer the neighbour by the most, up to
    ``separate_max_rounds``: a centre taken back moves its own track, and a neighbour's centre that track
    drew near it before lies on its own person's after all.  Someone hidden behind a neighbour in an image
    where the neighbour was not detected gets the neighbour's points, as a cut or as "its own" cluster: one
    such confident centre would draw the smoothed track onto the neighbour, whose own track the other frames
    place there; a person's own LiDAR centre lies nearest its own track."""
    for frames, sources in people:
        for entry in frames:
            _frame_centre(entry, sources.get(entry.frame, []))
        smooth_centres(frames, ground, config)
    for _ in range(config.separate_max_rounds):
        smoothed: dict[int, dict[int, np.ndarray]] = defaultdict(dict)      # frame -> person -> (2,)
        for person, (frames, _) in enumerate(people):
            # a person's smoothed track runs on between its frames: a frame it lacks (its detection dropped,
            # or taken by the neighbour's track) is placed on the line between its neighbours
            held = sorted(((entry.frame, _level_xy(ground, entry.world_p), 0.0) for entry in frames
                           if entry.world_p is not None), key=lambda item: item[0])
            for frame, (xy, _) in _between_frames(held).items():
                smoothed[frame][person] = xy
        clearest = None                     # (how much nearer the neighbour than its own track, person, obs)
        for person, (_, sources) in enumerate(people):
            for frame, observations in sources.items():
                others = [xy for other, xy in smoothed[frame].items() if other != person]
                if not others:
                    continue
                for obs in observations:
                    if obs.fallback is None or obs.world_p is None:
                        continue
                    xy = _level_xy(ground, obs.world_p)
                    nearest = min(float(np.linalg.norm(xy - q)) for q in others)
                    if nearest >= config.min_separation_m:
                        continue
                    own = _smoothed_without(people[person][0], sources, obs, ground, config)
                    mine = float(np.linalg.norm(xy - _level_xy(ground, own))) if own is not None else np.inf
                    if nearest < mine and (clearest is None or mine - nearest > clearest[0]):
                        clearest = (mine - nearest, person, obs)
        if clearest is None:
            return
        # the clearest case only, then every track as it now is: a centre taken back moves its own track,
        # and a neighbour's centre judged against that track before may be its person's after all
        _, person, obs = clearest
        obs.world_p, obs.world_p_camera, obs.depth_sigma_m = obs.fallback
        obs.fallback = None
        frames, sources = people[person]
        for entry in frames:
            _frame_centre(entry, sources.get(entry.frame, []))
        smooth_centres(frames, ground, config)


def tracks_from_ids(groups: Mapping[str, Mapping[int, Mapping[str, Detection]]],
                    calibrations: Mapping[str, StereoCalibration], config: AssociationConfig | None = None,
                    ground: GroundFrame | None = None,
                    clouds: Mapping[int, np.ndarray] | None = None) -> list[DetectedTrack]:
    """:class:`DetectedTrack` s of detections grouped by ids the files carry (``groups``: id -> frame -> camera
    -> detection), placed as the association places its own people — what the LiDAR cut's depth gate needs
    when the ids come from the files.  Per pair, each id's frames are observations as :func:`pair_tracks`
    makes them: a frame seen in both images triangulated (:func:`triangulate_centre`); with the scene
    ``clouds``, centred on the LiDAR (:func:`lidar_centres`: a one-image frame at its detection's own cluster
    among those of every detection of that image, :func:`detection_ranges`; every centre on its cut) and
    checked against the id's straight walk in that pair (:func:`settle_centres`).  A frame takes the centre of
    the pair that places it best (:func:`_frame_centre`) and the centres are smoothed, a LiDAR centre on
    another id's track taken back (:func:`separate_people`).  The association's identity steps (stereo
    matching, tracking, repairs) are not run: the ids are the files'."""
    config = config or AssociationConfig()
    ground = ground or ground_from_calibrations(dict(calibrations))
    if clouds is not None:
        ground = ground_with_plane(ground, calibrations, clouds)
    sources: dict[str, dict[int, list[Observation]]] = {track_id: defaultdict(list) for track_id in groups}
    for name, calib in sorted(calibrations.items()):
        left_name, right_name = name.split("-")
        per_image: dict[str, dict[int, list]] = {"left": defaultdict(list), "right": defaultdict(list)}
        tracks = []
        for track_id in groups:
            track = []
            for frame in sorted(groups[track_id]):
                uv, payload = {}, {}
                for side, camera in (("left", left_name), ("right", right_name)):
                    det = groups[track_id][frame].get(camera)
                    if det is not None:
                        uv[side] = _usable(rectified(det, calib), det.confidence, config.min_confidence)
                        payload[side] = det
                        per_image[side][frame].append((det, uv[side]))
                if not uv:
                    continue
                obs = Observation(frame=frame, uv=uv, score=float(max(d.score for d in payload.values())),
                                  payload=payload)
                if len(uv) == 2:
                    both = np.all(np.isfinite(uv["left"]), axis=1) & np.all(np.isfinite(uv["right"]), axis=1)
                    if both.sum() >= config.min_shared_keypoints and \
                            median(uv["left"][both, 0] - uv["right"][both, 0]) > 0:
                        _stereo_centre(obs, calib, ground, config)
                track.append(obs)
                sources[track_id][frame].append(obs)
            tracks.append(track)
        if clouds is not None:
            ranges: dict[int, float] = {}                 # each image's clusters given to its detections
            past: set[int] = set()
            if config.lidar_identity:
                for side, frames in per_image.items():
                    for frame, items in frames.items():
                        if frame in clouds:
                            ranges.update(detection_ranges(items, calib, side, clouds[frame], ground, config,
                                                           past))
            ranges = _placing(ranges, past)
            projections: dict[tuple[int, str], tuple[np.ndarray, np.ndarray]] = {}
            for track in tracks:
                lidar_centres(track, calib, per_image, ranges, clouds, ground, config, projections)
            if config.lidar_identity:
                settle_centres(tracks, calib, config)
    out, smoothing = [], []
    for track_id in sorted(groups):
        frames = []
        for frame in sorted(groups[track_id]):
            entry = DetectedTrackFrame(frame=frame, detections=dict(groups[track_id][frame]))
            _frame_centre(entry, sources[track_id][frame])
            frames.append(entry)
        smoothing.append((frames, sources[track_id]))
        pairs = tuple(sorted({name for name, calib in calibrations.items()
                              if any(cam in name.split("-") for fr in frames for cam in fr.detections)}))
        out.append(DetectedTrack(track_id=track_id, frames=frames, pairs=pairs))
    separate_people(smoothing, ground, config)
    return out


# ---------------------------------------------------------------------------------------------- entry point

def _pair_job(job: tuple) -> list[list[Observation]]:
    """:func:`pair_tracks` of one pair, for :func:`associate`'s workers: ``job`` is its arguments."""
    return pair_tracks(*job)


def associate(detections: list[Detection], calibrations: Mapping[str, StereoCalibration],
              config: AssociationConfig | None = None, clouds: Mapping[int, np.ndarray] | None = None,
              ground: GroundFrame | None = None, workers: int = 1) -> list[DetectedTrack]:
    """Tracks with ids from id-less detections (module docstring).  ``workers`` > 1 runs the pairs' own
    steps (:func:`pair_tracks`, each pair on its own: most of the time) in that many local processes, the
    same tracks as in this process; ``clouds`` must then pickle (a dict of arrays, or a mapping that reads
    its frames on demand)."""
    from pedx_graph.execution.executors import map_ordered

    config = config or AssociationConfig()
    ground = ground or ground_from_calibrations(dict(calibrations))
    if clouds is not None:
        ground = ground_with_plane(ground, calibrations, clouds)
    by_pair: dict[str, list[Detection]] = defaultdict(list)
    for det in detections:
        try:
            calib, _ = find_camera(calibrations, det.camera)
        except KeyError:
            continue
        by_pair[calib.name].append(det)
    pairs = sorted(by_pair)
    jobs = [(by_pair[pair], calibrations[pair], config, ground, clouds) for pair in pairs]
    tracks: list[tuple[str, list[Observation]]] = []
    for pair, found in zip(pairs, map_ordered(_pair_job, jobs, workers)):
        tracks += [(pair, track) for track in found]
    pair_of = {id(obs): pair for pair, track in tracks for obs in track}
    track_of = {id(obs): index for index, (_, track) in enumerate(tracks) for obs in track}
    groups = []
    for group in merge_pair_tracks(tracks, ground, config, calibrations):
        frames: dict[int, DetectedTrackFrame] = {}
        sources: dict[int, list[Observation]] = defaultdict(list)
        for index in group:
            pair, track = tracks[index]
            left_name, right_name = pair.split("-")
            for obs in track:
                entry = frames.setdefault(obs.frame, DetectedTrackFrame(frame=obs.frame, detections={}))
                for side, det in obs.payload.items():
                    entry.detections[left_name if side == "left" else right_name] = det
                sources[obs.frame].append(obs)
        drop_conflicting_pairs(frames, sources, {id(obs): tracks[i][0] for i in group for obs in tracks[i][1]},
                               ground, config, calibrations)
        groups.append((frames, sources))
    move_to_neighbours(groups, pair_of, track_of, ground, config, calibrations)
    people, smoothing = [], []
    for frames, sources in groups:
        if len(frames) < max(config.tracker.min_track_frames, 1):
            continue
        for frame, entry in frames.items():
            _frame_centre(entry, sources[frame])
        centres = np.array([fr.world_p for fr in frames.values() if fr.world_p is not None]).reshape(-1, 3)
        if len(centres):
            distance = float(median(ground.horizontal_distance(centres)))
            if not config.min_distance_m <= distance <= config.max_distance_m:
                continue
        pairs = tuple(sorted({pair_of[id(obs)] for observations in sources.values() for obs in observations}))
        people.append((min(frames), pairs, [frames[f] for f in sorted(frames)]))
        smoothing.append((people[-1][2], sources))
    separate_people(smoothing, ground, config)
    people.sort(key=lambda item: (item[0], item[1], sorted(item[2][0].detections)))
    out = []
    for number, (_, pairs, frames) in enumerate(people, start=1):
        track_id = f"det{number:06d}"
        for fr in frames:
            fr.detections = {cam: dataclasses.replace(det, track_id=track_id)
                             for cam, det in sorted(fr.detections.items())}
        out.append(DetectedTrack(track_id=track_id, frames=frames, pairs=pairs))
    return out
