"""Configuration of the PedX-like simulator (nested dataclasses, one docstring per field) and its rig presets.

Frames: ``sim`` (the simulator's internal frame, called ``world`` inside :mod:`pedx_graph.sim`) has its
origin at the simulated LiDAR's optical centre, x forward (along the vehicle), y to the vehicle's left, +z
against gravity, metres; the ground is the plane ``z = -lidar.height_m``.  ``output`` is the frame every
written 3D quantity is in (the release's LiDAR/range frame): ``output_p = output_T_sim @ sim_p`` with ``output_T_sim`` from
:class:`OutputFrameConfig` (identity for the default rig).  Angles in the config are degrees; everything
else SI (m, s) or pixels.

Two rigs (:data:`RIGS`, :func:`rig_config`, ``rig:`` in YAML, ``--rig`` on the command line):

* ``default``: output = sim frame (+z against gravity).  Focal length, baseline and mounting are plausible values chosen
  for a 12 MP roof-mounted rig (see docs/simulator.md for the reasoning):

* focal length 3000 px: with 3678 px wide images that is a 63 deg horizontal field of view, so a 1.7 m
  person spans ~1000 px at 5 m and ~115 px at 45 m;
* baseline 0.5 m: a roof-width rig; one pixel of disparity error is 0.27 m of depth at 20 m
  (``Z^2 / (f b)``), 1.1 m at 40 m, which is why the PedX method needs LiDAR at range.

* ``pedx``: the real rig of sequence 20171207T2024 (:func:`pedx_rig_config`): both pairs' rectified focal
  lengths, principal points, image sizes, baselines, left-camera positions and optical axes in the real
  LiDAR frame, whose z points *down*; that frame's origin ~0.3 m above the ground near the car and a ~0.8 deg
  tilt between it and the ground; real-label quirks and the measured per-keypoint click noise.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from pedx_graph.config import ConfigError, from_dict, read_yaml, to_dict
from pedx_graph.data.detector_model import DetectorNoiseConfig
from pedx_graph.detections.pixel_units import PIXEL_UNITS
from pedx_graph.sim.render import ImageConfig

#: Stereo pair names of the release: forward and left-facing pairs.
FORWARD_PAIR = "ylw79D0-red707B"
LEFT_PAIR = "blu79CF-grn43E3"


@dataclass
class StereoPairConfig:
    """One rectified stereo pair on the roof."""

    name: str = FORWARD_PAIR
    """Pair name ``"<left>-<right>"`` as in the release (left camera = reference camera)."""
    image_size: tuple[int, int] = (3678, 2668)
    """(width, height) of the rectified images, pixels (PedX: ylw/red 3678x2668, blu/grn 3645x2687)."""
    focal_px: float = 3000.0
    """Focal length of the rectified pair, pixels (not published by PedX; 63 deg horizontal FOV)."""
    principal_point: tuple[float, float] | None = None
    """(cx, cy) pixels; None = image centre."""
    baseline_m: float = 0.5
    """Stereo baseline, metres (not published by PedX; a roof-width rig)."""
    yaw_deg: float = 0.0
    """Viewing direction of the rectified left camera about the sim frame's z: 0 = forward (+x), 90 = left
    (+y).  Used when ``optical_axis`` is None."""
    pitch_deg: float = -2.0
    """Tilt of the rectified optical axis in the sim frame, negative = looking down.  Used when
    ``optical_axis`` is None."""
    left_camera_xyz: tuple[float, float, float] = (0.27, 0.0, -0.08)
    """Position of the left (reference) camera's centre, metres, in the frame named by
    ``CamerasConfig.frame``.  Default as in KITTI's rig: 0.27 m ahead of and 0.08 m below the LiDAR, no
    sideways offset (the LiDAR/camera parallax decides how many background points a polygon catches past the
    silhouette edge)."""
    rectification_deg: tuple[float, float, float] = (0.3, -0.2, 0.1)
    """Rotation vector (degrees) of ``rect_R_cam`` (``R_rect_00``): raw left camera -> rectified frame."""
    optical_axis: tuple[float, float, float] | None = None
    """Optical axis of the raw left camera (its +z, the third column of the calibration's ``R``) in the frame
    named by ``CamerasConfig.frame`` (normalised); None = the rectified axis from ``yaw_deg`` /
    ``pitch_deg``."""
    image_down: tuple[float, float, float] | None = None
    """Direction the raw left camera's image-down axis (its +y) leans to, same frame as ``optical_axis``
    (made perpendicular to it); required with ``optical_axis``."""
    vertical_disparity_px: float = 0.0
    """Systematic vertical disparity ``v_left - v_right`` of the pair's labels (a small rectification error):
    every click and polygon vertex of the right image is shifted by ``-vertical_disparity_px`` in v, pixels
    (real blu79CF-grn43E3: a -1 px median)."""

    def __post_init__(self) -> None:
        # optional vectors read from YAML arrive as lists: keep them tuples (configs compare equal)
        for name in ("principal_point", "optical_axis", "image_down"):
            value = getattr(self, name)
            if isinstance(value, list):
                setattr(self, name, tuple(value))


def _left_pair() -> StereoPairConfig:
    return StereoPairConfig(name=LEFT_PAIR, image_size=(3645, 2687), yaw_deg=90.0,
                            left_camera_xyz=(0.0, 0.27, -0.08), rectification_deg=(-0.2, 0.25, -0.15))


#: Values of ``CamerasConfig.frame``.
CAMERA_FRAMES = ("sim", "output")


@dataclass
class CamerasConfig:
    """The two stereo pairs, named as in PedX (slot names from the default rig's layout)."""

    forward: StereoPairConfig = field(default_factory=StereoPairConfig)
    """Pair ylw79D0-red707B (default rig: facing forward; pedx rig: ~17 deg left of the blu pair)."""
    left: StereoPairConfig = field(default_factory=_left_pair)
    """Pair blu79CF-grn43E3 (default rig: facing left; pedx rig: facing forward)."""
    label_right_images: bool = True
    """Also write 2D labels for the right camera of each pair (PedX labels all four cameras)."""
    frame: str = "sim"
    """Frame of every pair's ``left_camera_xyz``, ``optical_axis`` and ``image_down``: ``sim`` (the
    simulator's frame with +z against gravity, LiDAR at the origin) or ``output`` (the written frame,
    :class:`OutputFrameConfig`; cameras given there are mapped into the sim frame with ``sim_T_output``)."""

    def pairs(self) -> list[StereoPairConfig]:
        """The pairs in a fixed order (forward, left)."""
        return [self.forward, self.left]


@dataclass
class LidarConfig:
    """A spinning 32-beam LiDAR in the style of the Velodyne HDL-32E, at the sim frame's origin."""

    height_m: float = 1.95
    """Height of the LiDAR's optical centre above the ground (roof mount), metres (the sim frame's ground is
    ``z = -height_m``)."""
    n_beams: int = 32
    """Number of lasers (evenly spaced in elevation)."""
    elevation_min_deg: float = -30.67
    """Lowest beam elevation (HDL-32E: -30.67 deg)."""
    elevation_max_deg: float = 10.67
    """Highest beam elevation (HDL-32E: +10.67 deg)."""
    azimuth_step_deg: float = 0.18
    """Horizontal angular step between firings (HDL-32E at 10 Hz: ~0.16-0.18 deg; 2000 per turn)."""
    range_noise_m: float = 0.02
    """Standard deviation of the Gaussian range noise along each ray, metres."""
    dropout_prob: float = 0.02
    """Probability that a return is lost (independent per ray)."""
    min_range_m: float = 1.0
    """Returns closer than this are discarded, metres."""
    max_range_m: float = 100.0
    """Returns farther than this are discarded (HDL-32E: ~100 m), metres."""
    write_dropouts_as_inf: bool = True
    """Write lost returns into the full-scene PLY as ``inf`` points (PedX clouds contain inf points)."""
    every_n_frames: int = 1
    """A scene cloud (and its LiDAR segments, and a line of the point clouds' timestamps) is written every
    this many frames, from the first: a LiDAR sampled less often than the cameras (PedX: about half their
    rate).  The sweep is simulated every frame all the same, so the truth and every other file stay as at 1."""


@dataclass
class LabelConfig:
    """How the simulated annotators label 2D keypoints, polygons and LiDAR segments."""

    visible_noise_px: float = 2.0
    """Std. dev. (per axis) of the click noise of a visible keypoint, pixels."""
    occluded_noise_px: float = 8.0
    """Std. dev. (per axis) of an occluded keypoint's guessed position, pixels."""
    occluded_label_prob: float = 1.0
    """Probability that an occluded (but in-image) keypoint is labelled at all (``visible: false``)."""
    visibility_tolerance_m: float = 0.12
    """A keypoint is visible when the first surface on the ray from the camera lies no more than this
    in front of it (joint centres sit inside limbs: this is about a limb radius plus margin), metres."""
    polygon_epsilon_px: float = 3.0
    """Douglas-Peucker tolerance used to simplify the silhouette polygon, pixels."""
    polygon_noise_px: float = 1.5
    """Std. dev. of the noise added to each polygon vertex, pixels."""
    segment_depth_gate_m: float = 1.5
    """Far-side depth gate of the LiDAR segment: polygon points whose horizontal range exceeds the
    segment's median range by more than this are dropped (background seen past the silhouette), metres;
    0 disables the gate (raw polygon assignment)."""
    id_buffer_max_cells: int = 96
    """The visible-silhouette mask is ray cast on a grid of at most this many cells along the person's
    longer image side (cell size >= 1 px)."""
    min_visible_pixels: float = 150.0
    """An instance is labelled in an image only if its visible silhouette covers this many pixels."""
    min_visible_keypoints: int = 3
    """... and at least this many keypoints are visible."""
    min_distance_m: float = 5.0
    """Pedestrians nearer than this (horizontal distance to the LiDAR) are not labelled (PedX: 5 m)."""
    max_distance_m: float = 45.0
    """Pedestrians farther than this are not labelled (PedX: 45 m)."""
    keypoint_noise_px: tuple[float, ...] | None = None
    """Per-keypoint click noise of a visible keypoint: std. dev. per axis of one click, pixels, for each of
    the 18 PEDX_KEYPOINTS in that order; None = ``visible_noise_px`` for every keypoint (occluded keypoints
    always use ``occluded_noise_px``)."""
    occlusion_flags: bool = True
    """Write each keypoint's true visibility as its ``visible`` flag; False = every labelled keypoint is
    ``visible: true`` (real PedX labels carry no occlusion flag; occluded keypoints are still clicked, with
    ``occluded_noise_px``)."""
    integer_clicks: bool = False
    """Round every click (keypoints and polygon vertices) to whole pixels (real PedX labels are integers)."""
    polygon_only_prob: float = 0.0
    """Probability that a labelled instance's file carries no keypoints (``keypoint: null``, polygon only);
    real sequence 20171207T2024: 301 of 3101 files."""
    missing_keypoint_prob: float = 0.0
    """Probability that a file with keypoints misses one of them (one labelled keypoint, drawn uniformly, is
    dropped: 17 of 18 names); real: 3 of the 2800 files with keypoints."""
    one_camera_track_prob: float = 0.0
    """Probability that a pedestrian is labelled in one camera only over its whole track (no stereo at all);
    the camera is drawn with probability proportional to the labelable frames in which the pelvis projects
    into its image.  Real PedX has such tracks (4 of 19 in the sequence of issue 13)."""
    unlabelled_prob: float = 0.0
    """Probability that a pedestrian is never labelled: a bystander the annotators skipped (detectors still
    see it; ``truth/meta.json`` marks it ``"bystander": true``)."""
    segment_cameras: str = "left"
    """Images whose polygons cut an instance's LiDAR segment: ``left`` (the pairs' left images only, as in
    the paper) or ``any`` (the left images, else the right images when no left image labels the instance)."""

    def __post_init__(self) -> None:
        if isinstance(self.keypoint_noise_px, list):     # from YAML
            self.keypoint_noise_px = tuple(self.keypoint_noise_px)


@dataclass
class SceneConfig:
    """The four-way-stop intersection and its traffic."""

    n_pedestrians: int = 10
    """Number of simulated pedestrians (PedX: up to 15 per image)."""
    n_frames: int = 20
    """Number of synchronised stereo + LiDAR samples."""
    fps: float = 10.0
    """Sample rate of the synchronised stereo + LiDAR frames, Hz."""
    sequence: str = "20991231T1200"
    """Sequence name (PedX style ``YYYYMMDDTHHMM``; no ``_``)."""
    first_frame: int = 0
    """Frame number of the first sample (file names carry it)."""
    road_half_width_m: float = 6.0
    """Half width of each road (kerb to kerb / 2), metres."""
    intersection_x_m: float = 14.0
    """x of the intersection centre (the vehicle waits at the stop line of the -x approach), metres."""
    road_center_y_m: float = 2.0
    """y of the approach road's centre line (the vehicle is in the right-hand lane), metres."""
    crosswalk_width_m: float = 3.0
    """Width of each zebra crossing, metres."""
    sidewalk_width_m: float = 3.0
    """Width of each sidewalk, metres."""
    walkway_extent_m: float = 60.0
    """How far sidewalks extend from the intersection centre, metres."""
    n_parked_cars: int = 6
    """Cars parked along the kerbs (occluders)."""
    n_moving_cars: int = 2
    """Cars crossing the intersection on the cross road."""
    car_clearance_m: float = 0.0
    """Drivers yield: a moving car never comes nearer a pedestrian's pelvis than this, horizontally from the
    car's footprint, metres (:func:`pedx_graph.sim.scene.retime_moving_cars`: a car whose drive would pass
    nearer crosses the intersection earlier or later, by the smallest whole number of frame periods that keeps
    it clear, its path and speed unchanged; no random draw, so scenes without such a car are unchanged).
    0 (the default for now): cars drive through the people on the crosswalks, as in every scene of the
    committed benchmarks: in 12 of 40 seeded default scenes (9 of 40 on the pedx rig) a car's footprint comes
    within 0.3 m of a walker's pelvis; keeping 1.0 m (a yielding driver) retimes a car in 17 (14) of them
    (benchmarks/results/bench_car_clearance.md; docs/simulator.md, "Moving cars")."""
    n_buildings_per_corner: int = 2
    """Building blocks behind the sidewalks at each corner (background for polygon mistakes)."""
    group_prob: float = 0.35
    """Probability that a new pedestrian starts a group (2-3 people walking together)."""
    speed_mean_mps: float = 1.3
    """Mean walking speed, m/s."""
    speed_std_mps: float = 0.15
    """Std. dev. of the walking speed, m/s."""
    beta_clip: float = 2.5
    """Body shapes: betas ~ N(0, I) clipped to +-beta_clip."""
    crosswalk_prob: float = 0.4
    """Probability that a group walks on a crosswalk (else along a sidewalk)."""
    distance_mean_m: float = 20.0
    """Optional soft target of the distance distribution: a group's candidate position at distance d is
    accepted with probability ``exp(-(d - mean)^2 / (2 std^2))``."""
    distance_std_m: float = 0.0
    """Width of that soft target, metres (<= 0: off; the default walkway mix already gives a mean of ~22 m,
    5-95 % of people at 9-41 m, against PedX's 5-45 m with a mean of ~20 m)."""
    all_views_prob: float = 0.0
    """Probability that a group's middle-frame position must lie in the horizontal field of view of every
    pair (else of some pair).  Real PedX (sequence 20171207T2024): 474 of the 1014 instances labelled in a pair
    are labelled in both."""


@dataclass
class MotionConfig:
    """Where pedestrian motions come from."""

    motion_dir: str | None = None
    """Folder of BVH clips (with the CMU ``clips.csv`` index); None = the procedural gait only."""
    split: str = "holdout"
    """Which clips to use from ``motion_dir`` (``holdout`` keeps the priors' training clips out)."""
    categories: tuple[str, ...] = ("walk",)
    """Clip categories to draw from (index column ``category``)."""


@dataclass
class OutputFrameConfig:
    """Where the written (output) frame sits relative to the sim frame.

    ``output_p = output_T_sim @ sim_p`` with ``output_R_sim = [forward | up x forward | up]`` (the sim's x, y,
    z axes in the output frame) and translation ``output_p_lidar``.  Identity by default.
    """

    output_up: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """The sim frame's up (+z, against gravity) in the output frame (normalised)."""
    output_forward: tuple[float, float, float] = (1.0, 0.0, 0.0)
    """The sim frame's forward (+x, the vehicle's heading) in the output frame; its component along
    ``output_up`` is removed."""
    output_p_lidar: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """The simulated LiDAR's optical centre (the sim frame's origin) in the output frame, metres."""

    def output_T_sim(self) -> np.ndarray:
        """(4, 4) rigid transform sim frame -> output frame (exactly the identity for the defaults)."""
        up = np.asarray(self.output_up, dtype=float)
        up = up / np.linalg.norm(up)
        forward = np.asarray(self.output_forward, dtype=float)
        forward = forward - (forward @ up) * up
        forward = forward / np.linalg.norm(forward)
        output_T_sim = np.eye(4)
        output_T_sim[:3, :3] = np.stack([forward, np.cross(up, forward), up], axis=1)
        output_T_sim[:3, 3] = self.output_p_lidar
        return output_T_sim


#: Detector output formats the simulator can write (``DetectorOutputConfig.formats``) -> keypoint set.
DETECTOR_FORMATS: dict[str, str] = {"openpose_body25": "body25", "openpose_body25b": "body25b",
                                    "openpose_coco18": "coco18", "coco": "coco17"}


@dataclass
class DetectorOutputConfig:
    """Detector files written beside the labels (:mod:`pedx_graph.sim.detections`): raw distorted images, no ids."""

    formats: tuple[str, ...] = ()
    """Formats to write (keys of :data:`DETECTOR_FORMATS`); empty = none (and undistorted calibration files)."""
    keypoint_noise: DetectorNoiseConfig = field(default_factory=lambda: DetectorNoiseConfig(use_truth=True))
    """Per-keypoint noise, misses, left/right swaps and outliers (the detector model of
    :mod:`pedx_graph.data.detector_model`; its polygon and segment fields are not used here)."""
    person_miss_prob: float = 0.03
    """Probability that a detectable person is not detected at all in one image."""
    occluded_miss_prob: float = 0.5
    """Extra miss probability times the fraction of the person's in-image keypoints that are occluded."""
    min_height_px: float = 40.0
    """People whose keypoints span fewer pixels vertically are never detected."""
    min_visible_keypoints: int = 4
    """People with fewer visible in-image keypoints are never detected."""
    clutter_per_image: float = 0.3
    """Mean number (Poisson) of false person detections at random places per image."""
    fragment_prob: float = 0.05
    """Probability that a detected person also yields a second, partial detection (its legs or its upper
    body, slightly off): the bystander-like clutter of bottom-up detectors."""
    duplicate_prob: float = 0.0
    """Probability that a detected person is reported twice in one image, the second time whole and with the
    keypoints detected anew (their own noise draw; the part every camera shares, ``stereo_shared_noise``, is
    the person's as in the first): a top-down detector's second box of the person passing non-maximum
    suppression (truth kind ``person``, ``"duplicate": true``); 0 = never."""
    split_prob: float = 0.0
    """OpenPose formats only: probability that a detected person's skeleton is broken in two by the
    bottom-up grouping, written as two people — the upper body (head, neck, arms) and the hips and legs
    (truth kind ``part``); 0 = never (top-down detectors, COCO, crop one box per person and do not split)."""
    flip_prob: float = 0.0
    """Probability per person and frame that the detector takes the person's left for its right on the whole
    body (every left/right pair swapped, the confidences with them), in every camera alike (a back view
    confuses it the same from each viewpoint); 0 = never (per-pair swaps are ``keypoint_noise.swap_prob``)."""
    swap_keeps_confidence: bool = False
    """How a left/right exchanged keypoint (``keypoint_noise.swap_prob``, ``flip_prob``) scores.  False: its
    confidence falls with its distance from its own body point, like any misplaced keypoint (the exchange
    gives itself away and the import's confidence-to-noise curve all but drops it).  True: with its distance
    from the nearer of its own point and its mirror point — a heatmap detector that found the other wrist
    precisely is as confident as if it had found the right one, and nothing in the file tells the exchange
    apart (``flip_prob``'s whole-body exchanges keep their confidences either way)."""
    confidence_visible: float = 0.9
    """Confidence of a visible keypoint detected exactly on a large person."""
    confidence_occluded: float = 0.45
    """Confidence of an occluded keypoint detected exactly on a large person."""
    confidence_error_sigmas: float = 2.0
    """The confidence falls by ``exp(-e^2 / 2)``, ``e`` = the keypoint's error in units of this many of its
    own noise sigmas (a keypoint far off gets a low confidence)."""
    confidence_half_height_px: float = 30.0
    """Confidence is scaled by ``h / (h + this)``, ``h`` the person's image height in pixels."""
    confidence_noise: float = 0.06
    """Std. dev. of the noise added to every confidence."""
    stereo_shared_noise: float = 0.0
    """Fraction of a keypoint's noise variance that is the same offset in every image of the person at that
    frame (a detector placing a point alike from several cameras: its own idea of a hip, a hidden wrist guessed
    the same way); 0 = each image's noise its own.  Such an error cancels in the stereo rows the import checks
    its noise model against (``pedx_graph.detections.noise.stereo_row_scale``)."""
    distortion_k1: tuple[float, float] = (-0.12, -0.03)
    """Range of the first radial coefficient ``k1`` drawn per camera (barrel distortion)."""
    distortion_k2: tuple[float, float] = (0.0, 0.04)
    """Range of ``k2`` drawn per camera."""
    distortion_tangential: float = 5e-4
    """``p1``, ``p2`` drawn uniformly within +- this per camera."""
    raw_focal_jitter: float = 0.02
    """The raw focal lengths differ from the rectified one by up to this fraction (per camera and axis)."""
    raw_principal_jitter_px: float = 12.0
    """The raw principal point differs from the rectified one by up to this many pixels per axis."""
    definition_shift_m: float = 0.0
    """The detector's idea of each keypoint differs from the body model's definition the import fits by about
    this many metres: each keypoint of each format is moved by the difference of two skin vertices this far
    apart near it (drawn once per format from the seed; it moves with the skin), in every image alike — a
    systematic error, not noise (a real detector's "hip" or "ankle" is its training labels' idea, not ours).
    0 = the detector's points are the fit's definitions exactly (a convention the two would share)."""
    raw_margin_px: tuple[float, float] = (0.0, 0.0)
    """The raw images are larger than the rectified ones by this many pixels on each side, (x, y): their
    principal point shifted by it, their size ``S_0x`` (written to the calibration) the rectified size plus
    twice it, and people seen by the raw image beyond the rectified one detected too.  A real camera's raw
    image is its sensor's, which rectification crops (PedX's rectified 3645 x 2687 is no sensor size);
    (0, 0) = the raw images of the rectified size, no ``S_0x`` written."""
    right_rect_rotation_deg: float = 0.0
    """The raw right camera is turned against the raw left one by a rotation of this angle, degrees, about
    an axis drawn per pair (``R_rect_01 = R_rect_00 @ R``; written to the calibration), as a real pair's
    two cameras are never quite parallel before rectification; 0 = parallel (``R_rect_01 = R_rect_00``)."""
    detected_on: str = "raw"
    """The images the detector ran on: ``raw`` (the distorted camera images: keypoints distorted with the
    raw model ``K_0x`` / ``D_0x``) or ``rectified`` (the rectified images, as a user running a detector on a
    release that ships only rectified images, PedX's among them; the calibration still carries the raw
    keys, as PedX's does).  Either way the calibration files get the raw keys."""
    image_scale: float = 1.0
    """The detector saw the images resized by this factor (a 12 MP image shrunk to save time or storage):
    every written pixel is multiplied by it, and the COCO image list gives the resized width and height
    (rounded); 1 = the images at the calibration's size.  Noise, misses and clutter are drawn at full size."""
    pixel_units: str = "pixels"
    """How the written keypoints are expressed: ``pixels``; ``unit``, each coordinate divided by the image's
    width or height, in [0, 1] (OpenPose's ``--keypoint_scale 3``); ``signed_unit``, mapped to [-1, 1]
    (``--keypoint_scale 4``).  Applied after ``image_scale``."""

    def __post_init__(self) -> None:
        for name in ("formats", "distortion_k1", "distortion_k2", "raw_margin_px"):
            value = getattr(self, name)
            if isinstance(value, list):
                setattr(self, name, tuple(value))


#: Named rig presets (:func:`rig_config`).
RIGS = ("default", "pedx")


@dataclass
class SimConfig:
    """Everything the simulator needs besides the seed and the output folder."""

    rig: str = "default"
    """Name of the rig preset this config starts from (``default`` or ``pedx``, :data:`RIGS`); a YAML file
    naming it is read on top of that preset (:func:`load_sim_config`).  Informative once loaded."""
    scene: SceneConfig = field(default_factory=SceneConfig)
    """Intersection geometry, traffic and pedestrian counts."""
    cameras: CamerasConfig = field(default_factory=CamerasConfig)
    """The two stereo pairs."""
    lidar: LidarConfig = field(default_factory=LidarConfig)
    """The spinning LiDAR."""
    labels: LabelConfig = field(default_factory=LabelConfig)
    """Annotator noise and labelling rules."""
    motion: MotionConfig = field(default_factory=MotionConfig)
    """Motion sources."""
    output_frame: OutputFrameConfig = field(default_factory=OutputFrameConfig)
    """The frame every written 3D quantity is in, relative to the sim frame."""
    body_model: str | None = None
    """Body model ``.npz`` path; None = the package's default open model."""
    images: ImageConfig = field(default_factory=ImageConfig)
    """Rendered camera images under ``images/`` (:mod:`pedx_graph.sim.render`), off by default."""
    detections: DetectorOutputConfig = field(default_factory=DetectorOutputConfig)
    """Detector files on distorted raw images (OpenPose / COCO), off by default."""

    def validate(self, source: str = "<config>") -> "SimConfig":
        """Check ranges; raise :class:`ConfigError` naming the field. Returns self."""
        checks = [
            ("scene.n_pedestrians", self.scene.n_pedestrians >= 0),
            ("scene.n_frames", self.scene.n_frames >= 1),
            ("scene.fps", self.scene.fps > 0),
            ("scene.sequence", bool(self.scene.sequence) and "_" not in self.scene.sequence),
            ("lidar.n_beams", self.lidar.n_beams >= 1),
            ("lidar.every_n_frames", self.lidar.every_n_frames >= 1),
            ("lidar.azimuth_step_deg", 0 < self.lidar.azimuth_step_deg <= 90),
            ("lidar.dropout_prob", 0 <= self.lidar.dropout_prob < 1),
            ("lidar.range_noise_m", self.lidar.range_noise_m >= 0),
            ("labels.visible_noise_px", self.labels.visible_noise_px >= 0),
            ("labels.occluded_noise_px", self.labels.occluded_noise_px >= 0),
            ("labels.min_distance_m", 0 <= self.labels.min_distance_m < self.labels.max_distance_m),
            ("labels.id_buffer_max_cells", self.labels.id_buffer_max_cells >= 8),
            ("motion.split", self.motion.split in ("train", "holdout", "all")),
            ("rig", self.rig in RIGS),
            ("cameras.frame", self.cameras.frame in CAMERA_FRAMES),
            ("labels.keypoint_noise_px", self.labels.keypoint_noise_px is None
             or (len(self.labels.keypoint_noise_px) == 18 and min(self.labels.keypoint_noise_px) >= 0)),
            ("scene.all_views_prob", 0 <= self.scene.all_views_prob <= 1),
            ("scene.car_clearance_m", np.isfinite(self.scene.car_clearance_m) and self.scene.car_clearance_m >= 0),
            ("labels.polygon_only_prob", 0 <= self.labels.polygon_only_prob <= 1),
            ("labels.missing_keypoint_prob", 0 <= self.labels.missing_keypoint_prob <= 1),
            ("labels.one_camera_track_prob", 0 <= self.labels.one_camera_track_prob <= 1),
            ("labels.unlabelled_prob", 0 <= self.labels.unlabelled_prob <= 1),
            ("labels.segment_cameras", self.labels.segment_cameras in ("left", "any")),
            ("output_frame.output_up", _unit_ok(self.output_frame.output_up)),
            ("output_frame.output_forward", _unit_ok(self.output_frame.output_forward)
             and _unit_ok(np.cross(self.output_frame.output_up, self.output_frame.output_forward))),
        ]
        det = self.detections
        checks += [
            ("detections.formats", all(f in DETECTOR_FORMATS for f in det.formats)),
            ("detections.person_miss_prob", 0 <= det.person_miss_prob <= 1),
            ("detections.occluded_miss_prob", 0 <= det.occluded_miss_prob <= 1),
            ("detections.min_height_px", det.min_height_px >= 0),
            ("detections.min_visible_keypoints", det.min_visible_keypoints >= 1),
            ("detections.clutter_per_image", 0 <= det.clutter_per_image <= 100),
            ("detections.fragment_prob", 0 <= det.fragment_prob <= 1),
            ("detections.duplicate_prob", 0 <= det.duplicate_prob <= 1),
            ("detections.split_prob", 0 <= det.split_prob <= 1),
            ("detections.flip_prob", 0 <= det.flip_prob <= 1),
            ("detections.confidence_visible", 0 < det.confidence_visible <= 1),
            ("detections.confidence_occluded", 0 < det.confidence_occluded <= 1),
            ("detections.confidence_error_sigmas", det.confidence_error_sigmas > 0),
            ("detections.confidence_half_height_px", det.confidence_half_height_px >= 0),
            ("detections.confidence_noise", 0 <= det.confidence_noise <= 1),
            ("detections.stereo_shared_noise", 0 <= det.stereo_shared_noise <= 1),
            ("detections.distortion_k1", len(det.distortion_k1) == 2 and -0.5 <= min(det.distortion_k1)
             and max(det.distortion_k1) <= 0.5 and det.distortion_k1[0] <= det.distortion_k1[1]),
            ("detections.distortion_k2", len(det.distortion_k2) == 2 and -0.5 <= min(det.distortion_k2)
             and max(det.distortion_k2) <= 0.5 and det.distortion_k2[0] <= det.distortion_k2[1]),
            ("detections.distortion_tangential", 0 <= det.distortion_tangential <= 0.01),
            ("detections.raw_focal_jitter", 0 <= det.raw_focal_jitter <= 0.2),
            ("detections.raw_principal_jitter_px", 0 <= det.raw_principal_jitter_px <= 500),
            ("detections.definition_shift_m", 0 <= det.definition_shift_m <= 0.2),
            ("detections.raw_margin_px", len(det.raw_margin_px) == 2
             and all(0 <= v <= 2000 for v in det.raw_margin_px)),
            ("detections.right_rect_rotation_deg", 0 <= det.right_rect_rotation_deg <= 10),
            ("detections.detected_on", det.detected_on in ("raw", "rectified")),
            ("detections.image_scale", 0.05 <= det.image_scale <= 4),
            ("detections.pixel_units", det.pixel_units in PIXEL_UNITS),
        ]
        for slot, pair in (("forward", self.cameras.forward), ("left", self.cameras.left)):
            checks.append((f"cameras.{slot}.focal_px", pair.focal_px > 0))
            checks.append((f"cameras.{slot}.baseline_m", pair.baseline_m > 0))
            checks.append((f"cameras.{slot}.name", pair.name.count("-") == 1 and "_" not in pair.name))
            axis_ok = pair.optical_axis is None or (
                pair.image_down is not None and _unit_ok(pair.optical_axis)
                and _unit_ok(np.cross(pair.optical_axis, pair.image_down)))
            checks.append((f"cameras.{slot}.optical_axis", axis_ok))
            checks.append((f"cameras.{slot}.optical_axis",
                           self.cameras.frame == "sim" or pair.optical_axis is not None))
        for key, ok in checks:
            if not ok:
                raise ConfigError(f"{source}: config key '{key}' is out of range")
        return self


def _unit_ok(vector) -> bool:
    """A finite 3-vector long enough to normalise."""
    v = np.asarray(vector, dtype=float).reshape(-1)
    return v.shape == (3,) and bool(np.all(np.isfinite(v))) and float(np.linalg.norm(v)) > 1e-6


# ------------------------------------------------------------------------------------ the PedX rig
# Numbers of the real rig (sequence 20171207T2024, pedx-format notes).  Output frame = the real LiDAR (range)
# frame: z points down, the pairs look along -x.

#: Robust SD of the vertical disparity of one keypoint clicked in both images of a rectified pair (the
#: difference of two clicks), pixels, measured on the real labels (pedx-format notes).  Wrists: the note gives
#: 4.4-5.9 px; the middle of that range is used for both.
PEDX_VERTICAL_DISPARITY_SD_PX: dict[str, float] = {
    "nose": 1.5, "leye": 1.5, "reye": 1.5, "mouth": 1.5,
    "head": 3.0, "neck": 3.0, "lsho": 3.0, "rsho": 3.0, "lankl": 3.0, "rankl": 3.0,
    "lknee": 4.4, "rknee": 4.4, "lelb": 4.4, "relb": 4.4,
    "lwri": 5.15, "rwri": 5.15, "lhip": 5.9, "rhip": 5.9,
}
#: Tilt between the real LiDAR frame and the ground, degrees: the ground is at z = +0.3 m near the car and at
#: about -0.2 m 25-45 m ahead (0.5 m over ~35 m).
PEDX_GROUND_TILT_DEG = 0.8
#: The real frame's origin lies this far above the ground (along the ground normal), metres.
PEDX_GROUND_BELOW_ORIGIN_M = 0.3
#: Where the simulated spinning LiDAR sits in the real frame (not given by the release: on the roof ~0.27 m
#: above the left cameras, 0.2 m beside blu79CF; a LiDAR farther from the cameras adds more ground and
#: background to the polygon-cut segments), metres.
PEDX_LIDAR_XYZ = (-2.05, -0.05, -1.45)


def click_noise_from_vertical_disparity(disparity_sd_px: float, integer_clicks: bool = True) -> float:
    """Std. dev. of one click (per axis, pixels) from the SD of the difference of two independent clicks.

    ``sigma = sqrt(sd^2 / 2 - q)`` with ``q = 1/12`` px^2 (the variance of rounding to whole pixels) when the
    clicks are integers, else 0.
    """
    variance = disparity_sd_px ** 2 / 2.0 - (1.0 / 12.0 if integer_clicks else 0.0)
    return float(np.sqrt(max(variance, 0.0)))


def pedx_click_noise_px(integer_clicks: bool = True) -> tuple[float, ...]:
    """The 18 per-keypoint click noises (PEDX_KEYPOINTS order, px per axis) measured on the real labels."""
    from pedx_graph.keypoints import PEDX_KEYPOINTS

    return tuple(click_noise_from_vertical_disparity(PEDX_VERTICAL_DISPARITY_SD_PX[name], integer_clicks)
                 for name in PEDX_KEYPOINTS)


def pedx_rig_config() -> SimConfig:
    """The ``pedx`` rig preset: the real cameras and frame, real-label quirks and click noise.

    Output frame = the real LiDAR frame (z down, pairs looking along -x, ground ~0.8 deg off the frame's
    x-y plane and 0.3 m below its origin); cameras given in it (``cameras.frame = "output"``).  Labels:
    no occlusion flags, integer clicks, the measured per-keypoint noise, 301/3101 polygon-only files,
    3/2800 files with 17 keypoints, 20 % of tracks in one camera only, a -1 px vertical disparity on
    blu79CF-grn43E3; pedestrians labelled at 5-50 m, half of the groups placed where both pairs' fields of
    view overlap.
    """
    cfg = SimConfig(rig="pedx")
    tilt = np.deg2rad(PEDX_GROUND_TILT_DEG)
    # up = -z tilted so that the ground rises (z decreases) ahead, along -x
    output_up = (float(np.sin(tilt)), 0.0, float(-np.cos(tilt)))
    cfg.output_frame = OutputFrameConfig(output_up=output_up, output_forward=(-1.0, 0.0, 0.0),
                                         output_p_lidar=PEDX_LIDAR_XYZ)
    # ground plane {output_up . p = -PEDX_GROUND_BELOW_ORIGIN_M}; the LiDAR's height above it
    cfg.lidar.height_m = float(np.dot(output_up, PEDX_LIDAR_XYZ) + PEDX_GROUND_BELOW_ORIGIN_M)
    cfg.cameras.frame = "output"
    cfg.cameras.forward = StereoPairConfig(
        name=FORWARD_PAIR, image_size=(3678, 2668), focal_px=3266.70, principal_point=(1845.0, 1333.4),
        baseline_m=1074.30 / 3266.70, left_camera_xyz=(-2.243, 0.661, -1.140),
        optical_axis=(-0.9579, 0.2864, -0.0217), image_down=(0.0, 0.0, 1.0),
        rectification_deg=(0.2, -0.1, 0.05))
    cfg.cameras.left = StereoPairConfig(
        name=LEFT_PAIR, image_size=(3645, 2687), focal_px=3332.51, principal_point=(1857.0, 1334.9),
        baseline_m=912.26 / 3332.51, left_camera_xyz=(-1.980, -0.235, -1.188),
        optical_axis=(-0.99986, -0.0090, 0.0142), image_down=(0.0, 0.0, 1.0),
        rectification_deg=(0.45, -0.55, 0.1), vertical_disparity_px=-1.0)
    # more people where the two pairs' fields of view overlap (real: ~47 % of instances in both pairs)
    cfg.scene.all_views_prob = 0.5
    lab = cfg.labels
    lab.integer_clicks = True
    lab.keypoint_noise_px = pedx_click_noise_px(integer_clicks=True)
    lab.visible_noise_px = click_noise_from_vertical_disparity(3.0)
    lab.occlusion_flags = False
    lab.polygon_only_prob = 301 / 3101
    lab.missing_keypoint_prob = 3 / 2800
    lab.one_camera_track_prob = 0.2
    lab.segment_cameras = "any"
    lab.max_distance_m = 50.0
    return cfg


def rig_config(name: str) -> SimConfig:
    """A fresh :class:`SimConfig` of the named rig preset (:data:`RIGS`)."""
    if name == "default":
        return SimConfig()
    if name == "pedx":
        return pedx_rig_config()
    raise ConfigError(f"unknown rig {name!r} (known: {', '.join(RIGS)})")


def _merge(base: dict, update: dict) -> dict:
    out = dict(base)
    for key, value in update.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def load_sim_config(path: str | os.PathLike | None = None, rig: str | None = None) -> SimConfig:
    """A :class:`SimConfig` from the rig preset ``rig`` (else the YAML's ``rig:`` key, else ``default``) with
    the YAML file's keys on top (nested sections merge key by key).  Errors name the file and the key."""
    source = "<command line>" if path is None else str(path)
    data: dict = {}
    if path is not None:
        data = read_yaml(path)
        data = {} if data is None else data
        if not isinstance(data, dict):
            raise ConfigError(f"{path}: '<root>' must be a mapping, got {type(data).__name__}")
    name = rig or data.get("rig") or "default"
    if name not in RIGS:
        raise ConfigError(f"{source}: config key 'rig' must be one of {list(RIGS)}, got {name!r}")
    merged = _merge(to_dict(rig_config(name)), data)
    merged["rig"] = name
    return from_dict(SimConfig, merged, source=source)
