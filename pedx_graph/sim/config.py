"""Configuration of the PedX-like simulator (nested dataclasses, one docstring per field).

Frames: ``world`` is the LiDAR (range) frame of the stopped capture vehicle: origin at the LiDAR's optical
centre, x forward (along the vehicle), y to the vehicle's left, z up, metres.  The ground is the plane
``z = -lidar.height_m``.  Angles in the config are degrees; everything else SI (m, s) or pixels.

PedX does not publish its focal length, baseline or mounting; the defaults below are plausible values
chosen for a 12 MP roof-mounted rig (see docs/simulator.md for the reasoning):

* focal length 3000 px: with 3678 px wide images that is a 63 deg horizontal field of view, so a 1.7 m
  person spans ~1000 px at 5 m and ~115 px at 45 m;
* baseline 0.5 m: a roof-width rig; one pixel of disparity error is 0.27 m of depth at 20 m
  (``Z^2 / (f b)``), 1.1 m at 40 m, which is why the PedX method needs LiDAR at range.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from pedx_graph.config import ConfigError

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
    """Viewing direction about world z: 0 = forward (+x), 90 = left (+y)."""
    pitch_deg: float = -2.0
    """Tilt of the optical axis, negative = looking down."""
    left_camera_xyz: tuple[float, float, float] = (0.27, 0.0, -0.08)
    """Position of the left (reference) camera's centre in the world (LiDAR) frame, metres.  Default as in
    KITTI's rig: 0.27 m ahead of and 0.08 m below the LiDAR, no sideways offset (the LiDAR/camera parallax
    decides how many background points a polygon catches past the silhouette edge)."""
    rectification_deg: tuple[float, float, float] = (0.3, -0.2, 0.1)
    """Rotation vector (degrees) of ``rect_R_cam`` (``R_rect_00``): raw left camera -> rectified frame."""


def _left_pair() -> StereoPairConfig:
    return StereoPairConfig(name=LEFT_PAIR, image_size=(3645, 2687), yaw_deg=90.0,
                            left_camera_xyz=(0.0, 0.27, -0.08), rectification_deg=(-0.2, 0.25, -0.15))


@dataclass
class CamerasConfig:
    """The two stereo pairs (forward and left), named as in PedX."""

    forward: StereoPairConfig = field(default_factory=StereoPairConfig)
    """Forward-facing pair ylw79D0-red707B."""
    left: StereoPairConfig = field(default_factory=_left_pair)
    """Left-facing pair blu79CF-grn43E3."""
    label_right_images: bool = True
    """Also write 2D labels for the right camera of each pair (PedX labels all four cameras)."""

    def pairs(self) -> list[StereoPairConfig]:
        """The pairs in a fixed order (forward, left)."""
        return [self.forward, self.left]


@dataclass
class LidarConfig:
    """A spinning 32-beam LiDAR in the style of the Velodyne HDL-32E, at the world origin."""

    height_m: float = 1.95
    """Height of the LiDAR's optical centre above the ground (roof mount), metres."""
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
class SimConfig:
    """Everything the simulator needs besides the seed and the output folder."""

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
    body_model: str | None = None
    """Body model ``.npz`` path; None = the package's default open model."""

    def validate(self, source: str = "<config>") -> "SimConfig":
        """Check ranges; raise :class:`ConfigError` naming the field. Returns self."""
        checks = [
            ("scene.n_pedestrians", self.scene.n_pedestrians >= 0),
            ("scene.n_frames", self.scene.n_frames >= 1),
            ("scene.fps", self.scene.fps > 0),
            ("scene.sequence", bool(self.scene.sequence) and "_" not in self.scene.sequence),
            ("lidar.n_beams", self.lidar.n_beams >= 1),
            ("lidar.azimuth_step_deg", 0 < self.lidar.azimuth_step_deg <= 90),
            ("lidar.dropout_prob", 0 <= self.lidar.dropout_prob < 1),
            ("lidar.range_noise_m", self.lidar.range_noise_m >= 0),
            ("labels.visible_noise_px", self.labels.visible_noise_px >= 0),
            ("labels.occluded_noise_px", self.labels.occluded_noise_px >= 0),
            ("labels.min_distance_m", 0 <= self.labels.min_distance_m < self.labels.max_distance_m),
            ("labels.id_buffer_max_cells", self.labels.id_buffer_max_cells >= 8),
            ("motion.split", self.motion.split in ("train", "holdout", "all")),
        ]
        for pair in self.cameras.pairs():
            checks.append((f"cameras.{pair.name}.focal_px", pair.focal_px > 0))
            checks.append((f"cameras.{pair.name}.baseline_m", pair.baseline_m > 0))
            checks.append((f"cameras.{pair.name}.name", pair.name.count("-") == 1 and "_" not in pair.name))
        for key, ok in checks:
            if not ok:
                raise ConfigError(f"{source}: config key '{key}' is out of range")
        return self
