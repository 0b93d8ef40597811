"""The sequence's up axis, ground plane and viewpoint, derived from the data (never assumed).

Nothing in pedx-graph may assume which axis of the LiDAR (world) frame points up: the real PedX range frame
has z pointing *down*, the default simulated one +z, a user's rig anything.  Every quantity that means "up",
"ground", "heading", "height" or "horizontal" is computed through a :class:`GroundFrame`:

* ``world_up`` (3,): unit vector against gravity, in the world (LiDAR) frame;
* ``ground_offset_m``: the ground plane is ``{p : world_up . p = ground_offset_m}`` (None when unknown), so
  a point's height above the ground is ``world_up . p - ground_offset_m``;
* ``world_p_sensor`` (3,): the viewpoint of the rig (rays from the sensors to a pedestrian start here);
* ``world_R_level`` (3, 3): the *level frame* — columns ``[forward, left, up]``: ``forward`` is a horizontal
  reference direction (the reference camera's optical axis laid flat), ``left = up x forward``.  Headings
  (yaw angles) are measured in it: yaw 0 along ``forward``, positive towards ``left``.  Level coordinates are
  ``level_p = world_R_level^T (world_p - world_p_sensor)``.

How it is derived (:func:`estimate_ground`), per sequence:

1. **Calibration**: each camera's image-down axis (the rectified frame's +y) mapped into the world; their
   normalised mean, negated, is the calibration's up.  Cameras that disagree with the mean by more than
   ``GroundConfig.max_camera_disagreement_deg`` get a warning naming the sequence.
2. **Ground plane**: a robust (seeded RANSAC + least-squares) plane fit of the scene point clouds, its normal
   within ``max_ground_tilt_deg`` of the calibration's up; else of the pedestrians' lowest segment points
   (their feet).  With too few points: a warning naming the sequence, and the calibration's up with an
   unknown ground height.
3. A config override (``GroundConfig.world_up`` / ``ground_offset_m`` / ``sensor_xyz``) replaces either.

Every step is equivariant: rotate and shift the whole data set (calibration and points) and the derived frame
moves with it, so the estimator's results do too (tested).
"""
from __future__ import annotations

import functools
import logging
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger(__name__)


@dataclass
class GroundConfig:
    """How a sequence's up axis, ground plane and viewpoint are found (overrides and robust-fit settings)."""

    world_up: tuple[float, float, float] | None = None
    """Override: the up direction in the LiDAR frame (normalised); None = derived from the data."""
    ground_offset_m: float | None = None
    """Override: the ground plane ``world_up . p = ground_offset_m``, metres; None = fitted from the points."""
    sensor_xyz: tuple[float, float, float] | None = None
    """Override: the rig's viewpoint in the LiDAR frame, metres; None = the mean of the camera centres."""
    source: str = "auto"
    """Ground plane from ``auto`` (scene point clouds, else the segments' lowest points), ``pointclouds``,
    ``segments`` or ``calibration`` (no plane fit: the calibration's up, unknown ground height)."""
    max_camera_disagreement_deg: float = 5.0
    """A camera whose image-down axis is farther than this from the cameras' mean is warned about, degrees."""
    max_ground_tilt_deg: float = 12.0
    """The fitted ground normal may differ from the calibration's up by at most this, degrees (walls and
    steep surfaces are never taken for the ground)."""
    inlier_threshold_m: float = 0.06
    """Point-to-plane distance of a ground inlier in the RANSAC fit, metres (range noise + road camber)."""
    min_ground_points: int = 200
    """At least this many scene-cloud inliers make a ground fit; fewer: the segments, then the calibration."""
    min_segment_feet: int = 12
    """At least this many pedestrian instances' lowest points make a ground fit from the segments."""
    max_pointcloud_frames: int = 6
    """Scene clouds read for the fit (evenly spaced over the sequence's frames)."""
    max_fit_points: int = 60000
    """At most this many scene points enter the plane fit (seeded subsample)."""
    ransac_iterations: int = 300
    """RANSAC hypotheses of the plane fit (seeded: the same data gives the same plane)."""


@dataclass(frozen=True)
class GroundFrame:
    """One sequence's up axis, ground plane, viewpoint and level frame (see the module docstring)."""

    world_up: np.ndarray
    """(3,) unit up vector in the world (LiDAR) frame."""
    world_forward: np.ndarray
    """(3,) unit horizontal reference direction (yaw 0), perpendicular to ``world_up``."""
    world_p_sensor: np.ndarray
    """(3,) the rig's viewpoint in the world frame, metres."""
    ground_offset_m: float | None = None
    """The ground plane is ``world_up . p = ground_offset_m``; None when it could not be fitted."""
    source: str = "calibration"
    """Where ``world_up`` came from: ``pointclouds``, ``segments``, ``calibration`` or ``config``."""
    details: dict = field(default_factory=dict, compare=False)
    """What the derivation measured (camera disagreement, inlier counts, tilt), JSON-serialisable."""

    @functools.cached_property
    def world_R_level(self) -> np.ndarray:
        """(3, 3) columns ``[forward, left, up]`` of the level frame in the world frame (a rotation; made
        once per frame object, read-only: the association maps points to the level frame many thousand
        times)."""
        left = np.cross(self.world_up, self.world_forward)
        world_R_level = np.stack([self.world_forward, left, self.world_up], axis=1)
        world_R_level.flags.writeable = False
        return world_R_level

    def to_level(self, world_p: np.ndarray) -> np.ndarray:
        """(..., 3) world points -> level coordinates (x forward, y left, z along ``world_up``; origin at the
        sensor)."""
        return (np.asarray(world_p, dtype=float) - self.world_p_sensor) @ self.world_R_level

    def level_directions(self, world_d: np.ndarray) -> np.ndarray:
        """(..., 3) world directions -> level-frame directions (no translation)."""
        return np.asarray(world_d, dtype=float) @ self.world_R_level

    def horizontal_distance(self, world_p: np.ndarray) -> np.ndarray:
        """(...,) distance from the sensor measured in the ground plane, metres."""
        level = self.to_level(world_p)
        return np.hypot(level[..., 0], level[..., 1])

    def height(self, world_p: np.ndarray) -> np.ndarray:
        """(...,) height above the ground plane, metres (NaN when the ground is unknown)."""
        up = np.asarray(world_p, dtype=float) @ self.world_up
        return up - (np.nan if self.ground_offset_m is None else self.ground_offset_m)

    def median_point(self, world_p: np.ndarray) -> np.ndarray:
        """(3,) per-axis median of (N, 3) points taken in the level frame, mapped back to the world: a robust
        centre that moves rigidly with the data (a per-axis median in the world frame would not: it depends
        on how the world's axes are turned)."""
        level = np.median(self.to_level(world_p), axis=0)
        return self.world_p_sensor + self.world_R_level @ level

    def world_R_body_from_yaw(self, yaw: float | np.ndarray) -> np.ndarray:
        """(..., 3, 3) upright SMPL body orientations: body +Y -> ``world_up``, body +Z (forward) -> the level
        direction of heading ``yaw`` (radians); body +X (the body's left) completes the right-handed frame."""
        yaw = np.asarray(yaw, dtype=float)
        c, s = np.cos(yaw), np.sin(yaw)
        zero, one = np.zeros_like(c), np.ones_like(c)
        level_R_body = np.stack([np.stack([-s, c, zero], axis=-1), np.stack([zero, zero, one], axis=-1),
                                 np.stack([c, s, zero], axis=-1)], axis=-1)
        return self.world_R_level @ level_R_body

    def yaw_of(self, world_R_body: np.ndarray) -> np.ndarray:
        """(...,) heading (radians, level frame) of the body's forward axis (+Z) laid on the ground plane."""
        fwd = self.level_directions(np.asarray(world_R_body, dtype=float)[..., :, 2])
        return np.arctan2(fwd[..., 1], fwd[..., 0])

    def to_dict(self) -> dict:
        """JSON-ready record (what ``summary.json`` keeps per sequence)."""
        return {"world_up": [float(v) for v in self.world_up],
                "world_forward": [float(v) for v in self.world_forward],
                "world_p_sensor": [float(v) for v in self.world_p_sensor],
                "ground_offset_m": None if self.ground_offset_m is None else float(self.ground_offset_m),
                "source": self.source, **self.details}

    @staticmethod
    def from_dict(record: dict) -> "GroundFrame":
        """Inverse of :meth:`to_dict` (details kept)."""
        known = ("world_up", "world_forward", "world_p_sensor", "ground_offset_m", "source")
        return make_ground_frame(np.asarray(record["world_up"], float), np.asarray(record["world_forward"], float),
                                 np.asarray(record["world_p_sensor"], float), record.get("ground_offset_m"),
                                 record.get("source", "config"),
                                 {k: v for k, v in record.items() if k not in known})


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    n = float(np.linalg.norm(v))
    if not np.isfinite(n) or n < 1e-12:
        raise ValueError(f"not a finite non-zero vector: {v}")
    return v / n


def make_ground_frame(world_up, world_forward_hint, world_p_sensor, ground_offset_m=None,
                      source: str = "config", details: dict | None = None) -> GroundFrame:
    """A :class:`GroundFrame` with ``world_forward`` = ``world_forward_hint`` laid flat (made perpendicular to
    ``world_up``); when the hint is (nearly) vertical, the world axis most perpendicular to up is used."""
    up = _unit(world_up)
    hint = np.asarray(world_forward_hint, dtype=float)
    flat = hint - (hint @ up) * up
    if not np.isfinite(flat).all() or np.linalg.norm(flat) < 1e-6:
        axis = np.eye(3)[int(np.argmin(np.abs(up)))]
        flat = axis - (axis @ up) * up
    sensor = np.array(world_p_sensor, dtype=float).reshape(3)
    forward = _unit(flat)
    for arr in (up, forward, sensor):
        arr.setflags(write=False)
    return GroundFrame(world_up=up, world_forward=forward, world_p_sensor=sensor,
                       ground_offset_m=None if ground_offset_m is None else float(ground_offset_m),
                       source=source, details=dict(details or {}))


# ------------------------------------------------------------------------------------------ calibration

def camera_up_vectors(calibrations: dict) -> dict[str, np.ndarray]:
    """Pair name -> (3,) up vector of its rectified cameras (minus the image-down axis) in the world frame."""
    out = {}
    for name in sorted(calibrations):
        calib = calibrations[name]
        out[name] = _unit(-calib.world_R_rect[:, 1])
    return out


def camera_centres(calibrations: dict) -> np.ndarray:
    """(2 P, 3) optical centres of both cameras of every pair (sorted by pair name), world frame."""
    centres = []
    for name in sorted(calibrations):
        calib = calibrations[name]
        centres += [calib.camera_centre("left"), calib.camera_centre("right")]
    return np.asarray(centres, dtype=float).reshape(-1, 3)


def reference_forward(calibrations: dict) -> np.ndarray:
    """(3,) optical axis of the reference camera (the left camera of the first pair by name)."""
    calib = calibrations[sorted(calibrations)[0]]
    return calib.world_R_rect[:, 2].copy()


def calibration_up(calibrations: dict, sequence: str = "", max_disagreement_deg: float = 5.0
                   ) -> tuple[np.ndarray, dict]:
    """The calibration's up (3,) and a record: per-pair angle to the mean (degrees), and whether any exceeds
    ``max_disagreement_deg`` (then a warning names the sequence)."""
    if not calibrations:
        raise ValueError(f"{sequence}: no calibration to derive the up axis from")
    ups = camera_up_vectors(calibrations)
    mean = _unit(np.sum(list(ups.values()), axis=0))
    angles = {name: float(np.degrees(np.arccos(np.clip(u @ mean, -1.0, 1.0)))) for name, u in ups.items()}
    worst = max(angles.values())
    record = {"camera_up_disagreement_deg": round(worst, 4)}
    if worst > max_disagreement_deg:
        log.warning("%s: the cameras disagree about up by up to %.1f degrees (> %.1f: %s); check the "
                    "calibration's cam_to_range rotations", sequence or "sequence", worst, max_disagreement_deg,
                    ", ".join(f"{n} {a:.1f}" for n, a in sorted(angles.items())))
        record["camera_up_warning"] = True
    return mean, record


# ------------------------------------------------------------------------------------------ plane fits

def _refine_plane(points: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane through ``points`` (total least squares), normal oriented like ``normal``."""
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    n = vt[-1]
    if n @ normal < 0:
        n = -n
    return n, float(n @ centre)


def fit_ground_plane(world_points: np.ndarray, up_hint: np.ndarray, *, max_tilt_deg: float = 12.0,
                     inlier_threshold_m: float = 0.06, iterations: int = 300, seed: int = 0,
                     min_inliers: int = 3) -> tuple[np.ndarray, float, int] | None:
    """Robust ground plane of (N, 3) points: ``(normal (3,), offset, n_inliers)`` with ``normal . p = offset``
    on the plane and ``normal`` within ``max_tilt_deg`` of ``up_hint``; None when no such plane has
    ``min_inliers`` inliers.

    Seeded RANSAC over point triples; a hypothesis scores its inlier count, ties broken towards the *lowest*
    plane (the road, not a car roof or a sidewalk above it); the winner is refined by total least squares on
    its inliers, twice.  Equivariant: the same points in another rigid frame give the same plane moved along.
    """
    pts = np.asarray(world_points, dtype=float).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) < max(3, min_inliers):
        return None
    up = _unit(up_hint)
    cos_tilt = np.cos(np.radians(max_tilt_deg))
    rng = np.random.default_rng(seed)
    triples = rng.integers(0, len(pts), size=(iterations, 3))
    a, b, c = pts[triples[:, 0]], pts[triples[:, 1]], pts[triples[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    ok = norms > 1e-9
    normals[ok] /= norms[ok, None]
    normals *= np.sign(normals @ up)[:, None]
    ok &= (normals @ up) >= cos_tilt
    if not ok.any():
        return None
    normals, offsets = normals[ok], np.einsum("ij,ij->i", normals[ok], a[ok])
    heights = pts @ up
    best = None
    for n, d in zip(normals, offsets):
        inl = np.abs(pts @ n - d) <= inlier_threshold_m
        count = int(inl.sum())
        level = float(np.median(heights[inl])) if count else np.inf
        key = (count, -level)
        if best is None or key > best[0]:
            best = (key, n, d)
    _, n, d = best
    for _ in range(2):
        inl = np.abs(pts @ n - d) <= inlier_threshold_m
        if inl.sum() < 3:
            break
        n, d = _refine_plane(pts[inl], up)
    count = int((np.abs(pts @ n - d) <= inlier_threshold_m).sum())
    if count < min_inliers or (n @ up) < cos_tilt:
        return None
    return n, d, count


def lowest_points(segments: Iterable[np.ndarray], up: np.ndarray, quantile: float = 0.02,
                  min_points: int = 10) -> np.ndarray:
    """(K, 3) the lowest point (the ``quantile`` of height along ``up``) of each segment with at least
    ``min_points`` finite points: a pedestrian's feet, where the LiDAR sees them."""
    out = []
    for seg in segments:
        pts = np.asarray(seg, dtype=float).reshape(-1, 3)
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if len(pts) < min_points:
            continue
        h = pts @ up
        out.append(pts[int(np.argmin(np.abs(h - np.quantile(h, quantile))))])
    return np.asarray(out, dtype=float).reshape(-1, 3)


# ------------------------------------------------------------------------------------------ the estimate

def ground_from_calibrations(calibrations: dict, sequence: str = "", config: GroundConfig | None = None
                             ) -> GroundFrame:
    """A :class:`GroundFrame` from the calibration alone (up from the cameras, unknown ground height)."""
    return estimate_ground(calibrations, sequence=sequence,
                           config=config if config is not None else GroundConfig(source="calibration"))


def estimate_ground(calibrations: dict, scene_points: Iterable[np.ndarray] | None = None,
                    segments: Iterable[np.ndarray] | None = None, sequence: str = "",
                    config: GroundConfig | None = None) -> GroundFrame:
    """Derive one sequence's :class:`GroundFrame` (see the module docstring for the steps).

    ``calibrations``: the sequence's stereo pairs (name -> :class:`~pedx_graph.data.types.StereoCalibration`);
    ``scene_points``: full-scene clouds (each (N, 3), world frame) or None; ``segments``: pedestrian instance
    points (each (M, 3)) or None.  Warnings name ``sequence``.
    """
    config = config or GroundConfig()
    if config.source not in ("auto", "pointclouds", "segments", "calibration"):
        raise ValueError(f"ground.source must be auto, pointclouds, segments or calibration, got {config.source!r}")
    cam_up, details = calibration_up(calibrations, sequence, config.max_camera_disagreement_deg)
    sensor = (np.asarray(config.sensor_xyz, dtype=float) if config.sensor_xyz is not None
              else camera_centres(calibrations).mean(axis=0))
    details["sensor_source"] = "config" if config.sensor_xyz is not None else "camera_centres"
    up, offset, source = cam_up, None, "calibration"
    if config.world_up is not None:
        up, source = _unit(config.world_up), "config"
    plane = None
    if config.source in ("auto", "pointclouds") and scene_points is not None:
        clouds = [np.asarray(c, dtype=float).reshape(-1, 3) for c in scene_points]
        pts = np.concatenate(clouds) if clouds else np.zeros((0, 3))
        pts = pts[np.all(np.isfinite(pts), axis=1)]
        if len(pts) > config.max_fit_points:
            pts = pts[np.sort(np.random.default_rng(0).choice(len(pts), config.max_fit_points, replace=False))]
        plane = fit_ground_plane(pts, up, max_tilt_deg=config.max_ground_tilt_deg,
                                 inlier_threshold_m=config.inlier_threshold_m,
                                 iterations=config.ransac_iterations, min_inliers=config.min_ground_points)
        details["ground_points"] = int(len(pts))
        if plane is not None:
            details["ground_inliers"] = plane[2]
            plane = (plane[0], plane[1], "pointclouds")
        else:
            log.warning("%s: no ground plane with >= %d inliers in the scene point clouds (%d points)",
                        sequence or "sequence", config.min_ground_points, len(pts))
    if plane is None and config.source in ("auto", "segments") and segments is not None:
        feet = lowest_points(segments, up)
        details["segment_feet"] = int(len(feet))
        if len(feet) >= config.min_segment_feet:
            fit = fit_ground_plane(feet, up, max_tilt_deg=config.max_ground_tilt_deg,
                                   inlier_threshold_m=max(config.inlier_threshold_m, 0.08),
                                   iterations=config.ransac_iterations,
                                   min_inliers=max(3, config.min_segment_feet // 2))
            if fit is not None:
                details["ground_inliers"] = fit[2]
                plane = (fit[0], fit[1], "segments")
        if plane is None:
            log.warning("%s: too few pedestrian feet (%d instances, need %d) for a ground fit from the segments",
                        sequence or "sequence", len(feet), config.min_segment_feet)
    if plane is not None and config.world_up is None:
        up, offset, source = plane[0], plane[1], plane[2]
        details["ground_tilt_from_cameras_deg"] = round(float(np.degrees(np.arccos(np.clip(up @ cam_up, -1, 1)))), 4)
    elif plane is not None:
        offset = float(plane[1])           # the fitted plane's offset along its own (nearly equal) normal
        details["ground_from"] = plane[2]
    if plane is None and config.source != "calibration" and config.world_up is None:
        details["ground_fallback"] = "calibration"
    if config.ground_offset_m is not None:
        offset = float(config.ground_offset_m)
        details["ground_offset_source"] = "config"
    return make_ground_frame(up, reference_forward(calibrations), sensor, offset, source, details)
