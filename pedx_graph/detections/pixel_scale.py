"""What a sequence's detector coordinates are — the calibrated images' pixels, those of resized copies, or
coordinates normalised by the image size — brought to the calibration's pixels and checked against the LiDAR.

Nothing in an OpenPose file says which image size its pixels belong to, and a detector run on copies of
12 MP images shrunk to save time writes pixels of the copies.  Read as the calibration's pixels they put
every person at the wrong bearing and, the disparity shrunk alike, at a multiple of its distance, with a
plausible height (image height and disparity scale together): nothing downstream fails loudly.  The
simulator and the import had shared the convention that the pixels are the calibration's.  Now:

* **units** (``units: auto``; one for the sequence, every camera's coordinates together): coordinates that
  all lie within [-1, 1] (at least ``min_keypoints`` of them) are normalised by the image size — [0, 1]
  (OpenPose's ``--keypoint_scale 3``), or [-1, 1] when more than ``signed_fraction`` of them are negative
  (``--keypoint_scale 4``) — and become pixels with the calibration's image size (a resize cancels in them).
  Where a camera's raw image has a size of its own (``S_0x``: a sensor's, larger than the rectified image
  rectification cropped), they are read at the rectified size and the raw model is given for that size
  (:func:`seen_calibrations`), so either reading of the pair (:mod:`.image_frame`) lands on the right points;
* **scale** of pixels, per camera: ``scale`` > 0 in the config says it for every camera; else the files'
  image sizes (a COCO image list's ``width`` and ``height``) against the calibration's: the rectified size
  ``S_rect_00``, or the raw ``S_0x`` when given (detections on raw images), equal, or resized (per axis; one
  size per camera; a size that is a resize of both is taken as the rectified one's, and the LiDAR check
  catches the other; a size that is none of them resized — its aspect off by more than the rounding of a
  resize — is refused: a crop, or another camera); else 1;
* **inside the image**, per camera: more than ``max_outside_fraction`` of the keypoints beyond the
  calibrated image by a tenth of its size (the larger of the rectified and the raw image: ``S_0x``, or
  twice the raw principal point) is refused (pixels of a larger image, a resize given twice);
* **the LiDAR check** (with point clouds, ``check``): a person matched between a pair's two images
  (:func:`pedx_graph.detections.image_frame.match_people`) has, at a trial scale (its pixels divided by it,
  read as rectified, or undistorted with the raw model when the pair has one: either reading counts), a
  box of keypoints in the left image and a depth from its median disparity; at the right scale the LiDAR's
  returns from the person, the ground left out, fall inside that box at that depth (at least
  ``min_hit_points``, within the depth gate).  Over trial scales from 0.2 to 2 and every pair's people
  together, the best scale putting at least ``min_ratio`` times as many people on the LiDAR's returns as
  the scale used does, beyond ``tolerance`` of it, with at least ``min_people`` people matched, refuses
  the sequence: the error names the factor the LiDAR prefers and how to give the resize
  (``--detector-image-scale``, ``import.pixel_scale.scale``).  The import does not apply that factor
  itself: its peak is a few percent wide, and a few percent of a 3,600 px image is tens of pixels.

The decisions are in ``import_summary.json`` (``sequences.<seq>.pixel_scale``).
"""
from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np

from pedx_graph.data.types import DataFormatError, RawCamera, StereoCalibration
from pedx_graph.detections.image_frame import match_people
from pedx_graph.detections.pixel_units import PIXEL_UNITS, from_detector_units
from pedx_graph.detections.types import Detection
from pedx_graph.detections.undistort import find_camera, raw_camera, undistort_rectify

log = logging.getLogger(__name__)

#: Values of :attr:`PixelScaleConfig.units`.
UNITS = ("auto",) + PIXEL_UNITS

#: Trial scales of the LiDAR check (log-spaced, 1 among them).
TRIAL_SCALES = np.unique(np.concatenate([np.exp(np.linspace(np.log(0.2), np.log(2.0), 79)), [1.0]]))


@dataclass
class PixelScaleConfig:
    """Which coordinates the detections are in (module docstring)."""

    scale: float = 0.0
    """The detector saw every camera's images resized by this factor (its pixels per calibration pixel: 0.5
    for images shrunk to half their width and height); 0 = from the files' image sizes where they give them,
    else 1 (pixels of the calibrated images), checked against the LiDAR."""
    units: str = "auto"
    """``pixels``, ``unit`` ([0, 1] of the image's width and height), ``signed_unit`` ([-1, 1]), or ``auto``
    (told per camera from the coordinates' range)."""
    check: bool = True
    """With point clouds, check the scale against the LiDAR and refuse a sequence it contradicts."""
    min_keypoints: int = 10
    """``units: auto`` takes a sequence's coordinates as normalised only with at least this many keypoints."""
    signed_fraction: float = 0.05
    """... and as [-1, 1] rather than [0, 1] when more than this fraction of the coordinates are negative
    (a [0, 1] file's points just outside the image are slightly negative)."""
    max_outside_fraction: float = 0.01
    """At most this fraction of a camera's keypoints may lie beyond its calibrated image by more than a tenth
    of its width or height (a distorted raw image reaches a little past the rectified one)."""
    min_hit_points: int = 3
    """A person triangulated at a trial scale lies among the LiDAR's returns when at least this many of them
    fall inside its keypoints' box in the left image at its stereo depth (within the depth gate) ..."""
    depth_gate_m: float = 0.6
    """... within this of it, metres (a body's depth, a walker's stride) ..."""
    disparity_sigma_px: float = 0.5
    """... plus three times the depth error of this much disparity error, pixels (the median over a person's
    keypoints; at 30 m with PedX's 0.27 m baseline, 0.5 px is about 0.5 m)."""
    ground_cell_m: float = 1.0
    """The LiDAR check leaves out the ground: points within ``ground_band_m`` of the lowest point of their
    square of this side on the ground plane (along the sequence's up axis), metres ..."""
    ground_band_m: float = 0.3
    """... metres (a curb, the ground's slope within a cell, a person's shoes)."""
    min_people: int = 20
    """The LiDAR check judges a sequence with at least this many people matched between the two images of its
    pairs (all pairs together; each pair's own verdict, in the record, alike)."""
    min_ratio: float = 2.0
    """A trial scale contradicts the one used when it puts at least this many times as many people on the
    LiDAR's returns ..."""
    tolerance: float = 0.1
    """... and differs from it by more than this fraction."""
    max_frames: int = 40
    """At most this many frames per pair (with a point cloud, evenly spread) enter the LiDAR check."""
    min_confidence: float = 0.2
    """Keypoints with a lower confidence are left out of the LiDAR check's matching and triangulation."""

    def __post_init__(self) -> None:
        if self.units not in UNITS:
            raise ValueError(f"pixel_scale.units must be one of {', '.join(UNITS)}, got {self.units!r}")
        if not (self.scale == 0 or 0.05 <= self.scale <= 4):
            raise ValueError(f"pixel_scale.scale must be 0 (from the files) or within 0.05-4, got {self.scale!r}")


def coordinate_units(uv: np.ndarray, config: PixelScaleConfig) -> str:
    """The units of a sequence's (N, 2) present coordinates, every camera's together (one detector run writes
    one kind; a camera seeing a few people in one corner of its image could not tell), under
    ``config.units`` (module docstring)."""
    if config.units != "auto":
        return config.units
    if len(uv) < config.min_keypoints or np.abs(uv).max() > 1.0 + 1e-6:
        return "pixels"
    return "signed_unit" if np.mean(uv < 0) > config.signed_fraction else "unit"


def raw_image_size(raw: RawCamera | None) -> tuple[int, int] | None:
    """The raw image's (width, height): ``S_0x`` when the calibration gives it, else twice the raw principal
    point (a lens centred in its image, to within the sensor's offset), None without a raw model."""
    if raw is None:
        return None
    if raw.image_size is not None:
        return tuple(raw.image_size)
    return int(round(2 * raw.raw_K[0, 2])), int(round(2 * raw.raw_K[1, 2]))


def _file_scale(dets: list[Detection], sizes: dict[str, tuple[int, int]], camera: str) -> tuple[float, float] | None:
    """(sx, sy) from the detections' image sizes against the calibrated image sizes of ``camera`` (``sizes``:
    ``"S_rect_00"`` -> rectified, and ``"S_0x"`` -> raw when the calibration gives it), or None when no
    detection gives one; :class:`DataFormatError` for two sizes, or a size that is none of them resized.  A size
    equal to one is scale 1; else the first whose aspect it has (the rectified size first)."""
    given = {}
    for det in dets:
        if det.image_size is not None:
            given.setdefault(tuple(det.image_size), det)
    if not given:
        return None
    if len(given) > 1:
        (a, det_a), (b, _) = sorted(given.items())[:2]
        raise DataFormatError(det_a.source.split("#")[0], "images (width, height)",
                              f"camera {det_a.camera} has images of two sizes, {a[0]}x{a[1]} and {b[0]}x{b[1]}")
    (width, height), det = next(iter(given.items()))
    for size in sizes.values():
        if (width, height) == tuple(size):
            return 1.0, 1.0
    for size in sizes.values():
        sx, sy = width / size[0], height / size[1]
        if abs(sx - sy) <= 1.0 / min(width, height) + 1e-9:
            return sx, sy
    known = ", ".join(f"{w}x{h} ({key})" for key, (w, h) in sizes.items())
    raise DataFormatError(det.source.split("#")[0], "images (width, height)",
                          f"camera {camera}'s images are {width}x{height}, none of its calibrated sizes {known} "
                          f"resized: cropped, or another camera?")


def detector_pixels(detections: list[Detection], calibrations: dict[str, StereoCalibration],
                    config: PixelScaleConfig, clouds=None, where: str = "", world_up: np.ndarray | None = None
                    ) -> tuple[list[Detection], dict]:
    """``detections`` with their coordinates (and boxes) in the calibration's pixels, and the record
    ``{"cameras": {camera: {"units", "scale", "from"}}, "lidar_check": {pair: ...}}`` (module docstring).
    ``clouds``: frame -> (N, 3) world points (a mapping), or None; ``world_up``: the sequence's up axis
    (the LiDAR check leaves the ground out with it).  Raises :class:`DataFormatError` where
    the files or the LiDAR contradict the scale."""
    by_camera: dict[str, list[Detection]] = {}
    for det in detections:
        by_camera.setdefault(det.camera, []).append(det)
    index = {"left": "00", "right": "01"}
    converted: dict[int, Detection] = {}
    cameras = {}
    units = coordinate_units(np.concatenate([d.image_uv[d.present] for d in detections] + [np.zeros((0, 2))]),
                             config)
    for camera, dets in sorted(by_camera.items()):
        calib, side = find_camera(calibrations, camera)
        size, raw = calib.image_size, raw_camera(calib, side)
        calibrated = {f"S_rect_{index[side]}": size}
        if raw is not None and raw.image_size is not None:
            calibrated[f"S_{index[side]}"] = tuple(raw.image_size)
        if units != "pixels":
            scale, source = (1.0, 1.0), "normalised coordinates"
        elif config.scale > 0:
            scale, source = (config.scale, config.scale), "config"
            from_files = _file_scale(dets, calibrated, camera)
            if from_files is not None and max(abs(np.log(np.asarray(from_files) / config.scale))) > 0.01:
                log.warning("%s: camera %s: the files' image sizes say the pixels are %.4g x the calibration's; "
                            "pixel_scale.scale %.4g is used", where or "detections", camera, from_files[0],
                            config.scale)
        else:
            from_files = _file_scale(dets, calibrated, camera)
            scale, source = (from_files, "image sizes in the files") if from_files is not None else (
                (1.0, 1.0), "the calibration's image size")
        for det in dets:
            if units == "pixels" and tuple(scale) == (1.0, 1.0):
                converted[id(det)] = det           # the calibration's pixels already: untouched
                continue
            uv = from_detector_units(det.image_uv, size, scale, units)
            bbox = det.bbox
            if bbox is not None:
                corners = from_detector_units(np.reshape(bbox, (2, 2)) + [[0.0, 0.0], bbox[:2]], size, scale, units)
                bbox = np.concatenate([corners[0], corners[1] - corners[0]])
            converted[id(det)] = dataclasses.replace(det, image_uv=uv, bbox=bbox)
        raw_size = raw_image_size(raw)
        if raw_size is not None and tuple(raw_size) != tuple(size):
            bounds = tuple(int(v) for v in np.maximum(size, raw_size))
            label = f"the larger of its rectified and raw images, {calib.name}"
        else:
            bounds, label = tuple(size), f"S_rect_00 of {calib.name}"
        _check_inside([converted[id(d)] for d in dets], bounds, config, label)
        cameras[camera] = {"units": units, "scale": [round(float(v), 6) for v in scale], "from": source}
    out = [converted[id(d)] for d in detections]
    record = {"cameras": cameras, "lidar_check": {}}
    if clouds is None or not config.check:
        return out, record
    totals = np.zeros(len(TRIAL_SCALES), dtype=int)
    people = 0
    frames_with_cloud, off_ground = set(clouds), _OffGround(clouds, world_up, config)
    for name, calib in sorted(seen_calibrations(calibrations, cameras).items()):
        left, right = name.split("-")
        if left not in cameras or right not in cameras:
            continue
        check, hits = lidar_check(calib, [d for d in out if d.camera in (left, right)], off_ground,
                                  frames_with_cloud, config)
        record["lidar_check"][name] = check
        if hits is not None:
            totals += hits
            people += check["people"]
    verdict = {"people": people, **judge(totals, people, config)}
    record["lidar_check"]["all pairs"] = verdict
    if verdict["contradicts"]:
        first = min((d for d in detections if d.camera in cameras), key=lambda d: (d.frame, d.camera, d.source))
        used = sorted({c["scale"][0] for c in cameras.values()})
        used_text = " / ".join(f"{sx:.3g}" for sx in used)
        hint = f"; about {used[0] * verdict['best_scale']:.2f} here" if len(used) == 1 else ""
        raise DataFormatError(
            first.source.split("#")[0], "keypoints",
            f"{where or 'detections'}: the detections lie on the LiDAR's people only if their pixels are "
            f"{verdict['best_scale']:.2f} x those read ({verdict['people_on_lidar_at_best']} of {people} people "
            f"matched in stereo against {verdict['people_on_lidar']} as read, at {used_text} x the calibration's "
            f"image size, S_rect_00): were they made on resized images?  Give the resize with "
            f"--detector-image-scale (import.pixel_scale.scale{hint}), or turn the check off "
            f"(import.pixel_scale.check)")
    return out, record


def _normalised_raw_size(raw: RawCamera | None, size: tuple[int, int], used: dict | None) -> tuple | None:
    """(raw width / rectified width, raw height / rectified height) for a camera whose coordinates were
    normalised (``used``: its entry of :func:`detector_pixels`' record) and whose raw image has a size of its
    own (``S_0x``, not the rectified ``size``); else None."""
    if used is None or used["units"] == "pixels" or raw is None or raw.image_size is None:
        return None
    if tuple(int(v) for v in raw.image_size) == tuple(int(v) for v in size):
        return None
    return raw.image_size[0] / size[0], raw.image_size[1] / size[1]


def seen_calibrations(calibrations: dict[str, StereoCalibration], cameras: dict) -> dict[str, StereoCalibration]:
    """The pairs as the read coordinates need them (``cameras``: the ``"cameras"`` of :func:`detector_pixels`'
    record).  Normalised coordinates say nothing of the image's size and are read at the rectified size
    (``S_rect_00``); where the raw image has a size of its own (``S_0x``) and the detector saw the raw image,
    its pixels are those read times raw / rectified size, per axis.  Such a camera's raw model is given for
    the pixels as read: ``K_0x``'s rows scaled by rectified / raw size (the raw image resized to the
    rectified size), so that reading the pixels as raw (:mod:`.image_frame`) undistorts the right points.
    Other cameras keep their models."""
    out = {}
    for name, calib in calibrations.items():
        raws = {}
        for side, camera in zip(("left", "right"), name.split("-")):
            raw = raw_camera(calib, side)
            ratio = _normalised_raw_size(raw, calib.image_size, cameras.get(camera))
            if ratio is not None:
                raw_K = np.array(raw.raw_K, dtype=float)
                raw_K[0] /= ratio[0]
                raw_K[1] /= ratio[1]
                raws[f"{side}_raw"] = dataclasses.replace(raw, raw_K=raw_K, image_size=tuple(calib.image_size))
        out[name] = dataclasses.replace(calib, **raws) if raws else calib
    return out


def resized_cameras(record: dict, calibrations: dict[str, StereoCalibration]) -> dict:
    """Camera -> ``(calibration image size, scale or None)`` for the cameras of :func:`detector_pixels`'
    ``record`` whose images the detector saw at another size (``scale``: its pixels per calibration pixel;
    None: normalised coordinates, any size; raw / rectified size for normalised coordinates of a raw image
    with a size of its own, whose model :func:`seen_calibrations` gives for the rectified size), for
    :func:`~pedx_graph.detections.pixel_units.calibration_sized` (the review sheets and the rectified images
    drawn from the images the detector saw).  ``calibrations``: as read from the files."""
    sizes, ratios = {}, {}
    for calib in calibrations.values():
        for side, camera in zip(("left", "right"), calib.name.split("-")):
            sizes[camera] = calib.image_size
            ratios[camera] = _normalised_raw_size(raw_camera(calib, side), calib.image_size,
                                                  record["cameras"].get(camera))
    return {camera: (sizes[camera], tuple(used["scale"]) if used["units"] == "pixels" else ratios[camera])
            for camera, used in record["cameras"].items()
            if used["units"] != "pixels" or tuple(used["scale"]) != (1.0, 1.0)}


def _check_inside(dets: list[Detection], size: tuple[int, int], config: PixelScaleConfig, label: str) -> None:
    """Refuse a camera whose converted keypoints lie beyond its image of ``size`` (``label`` says which)
    (:attr:`PixelScaleConfig.max_outside_fraction`)."""
    uv = np.concatenate([d.image_uv[d.present] for d in dets]) if dets else np.zeros((0, 2))
    if len(uv) == 0:
        return
    margin = 0.1 * np.asarray(size, dtype=float)
    outside = np.any((uv < -margin) | (uv > np.asarray(size) + margin), axis=1)
    if outside.mean() > config.max_outside_fraction:
        det = next(d for d in dets if np.any(np.any((d.image_uv[d.present] < -margin)
                                                    | (d.image_uv[d.present] > np.asarray(size) + margin), axis=1)))
        raise DataFormatError(det.source.split("#")[0], "keypoints",
                              f"{outside.mean():.0%} of camera {det.camera}'s keypoints lie beyond its image "
                              f"({size[0]}x{size[1]}, {label}) as read: made on larger images, "
                              f"or a resize given that the pixels do not have?")


def _rectified(calib: StereoCalibration, uv: np.ndarray, side: str, raw: bool) -> np.ndarray:
    """(N, 2) calibration pixels of ``side`` as rectified pixels: undistorted and rectified first when ``raw``."""
    if not raw:
        return uv
    return undistort_rectify(uv, calib.left_raw if side == "left" else calib.right_raw)


def above_ground(world_p: np.ndarray, world_up: np.ndarray, cell_m: float, band_m: float) -> np.ndarray:
    """(N,) bool: the points more than ``band_m`` above the lowest point of their ``cell_m`` square of the
    ground plane (the ground, and a person's feet, left out; a slope or a tilted plane changes little
    within a cell)."""
    up = np.asarray(world_up, dtype=float) / np.linalg.norm(world_up)
    across = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    across /= np.linalg.norm(across)
    along = np.cross(up, across)
    height = world_p @ up
    cells = np.floor(np.c_[world_p @ across, world_p @ along] / cell_m).astype(np.int64)
    _, index = np.unique(cells[:, 0] * (1 << 32) + cells[:, 1], return_inverse=True)
    index = index.reshape(-1)
    lowest = np.full(index.max() + 1 if len(index) else 0, np.inf)
    np.minimum.at(lowest, index, height)
    return height > lowest[index] + band_m


class _OffGround(dict):
    """Frame -> the finite points of its scene cloud, those above the ground only when an up axis is known
    (:func:`above_ground`); each frame made once, for every pair."""

    def __init__(self, clouds, world_up: np.ndarray | None, config: PixelScaleConfig):
        super().__init__()
        self._clouds, self._up, self._config = clouds, world_up, config

    def __missing__(self, frame: int) -> np.ndarray:
        cloud = np.asarray(self._clouds[frame], dtype=float).reshape(-1, 3)
        cloud = cloud[np.all(np.isfinite(cloud), axis=1)]
        if self._up is not None and len(cloud):
            cloud = cloud[above_ground(cloud, self._up, self._config.ground_cell_m, self._config.ground_band_m)]
        self[frame] = cloud
        return cloud


def _frame_points(calib: StereoCalibration, cloud: np.ndarray) -> np.ndarray:
    """(N, 3) ``u, v, depth`` of a cloud's points in front of the pair's rectified left camera, sorted by ``u``."""
    rect = calib.world_to_rect(cloud)
    rect = rect[rect[:, 2] > 1.0]
    hom = np.c_[rect, np.ones(len(rect))] @ calib.left_P_rect.T
    uvz = np.c_[hom[:, :2] / hom[:, 2:], rect[:, 2]]
    return uvz[np.argsort(uvz[:, 0], kind="stable")]


def lidar_check(calib: StereoCalibration, detections: list[Detection], clouds, frames_with_cloud: set,
                config: PixelScaleConfig) -> tuple[dict, np.ndarray | None]:
    """One pair's LiDAR check (module docstring): its record (``frames``, ``people`` matched in stereo and
    :func:`judge`'s verdict on them alone) and the people on the LiDAR's returns per trial scale
    (:data:`TRIAL_SCALES`, relative to the pixels as given; None without people).  ``clouds``: frame -> (N, 3)
    world points off the ground, for the frames of ``frames_with_cloud``."""
    left_name, right_name = calib.name.split("-")
    by_frame: dict[int, tuple[list, list]] = {}
    for det in detections:
        uv = np.where((det.confidence >= config.min_confidence)[:, None] & det.present[:, None], det.image_uv, np.nan)
        by_frame.setdefault(det.frame, ([], []))[0 if det.camera == left_name else 1].append((uv,))
    frames = sorted(f for f, (lf, rt) in by_frame.items() if lf and rt and f in frames_with_cloud)
    if len(frames) > config.max_frames:
        frames = [frames[i] for i in np.linspace(0, len(frames) - 1, config.max_frames).round().astype(int)]
    people = []                                   # (frame, left keypoints, right keypoints), shared ones only
    for frame in frames:
        lf, rt = by_frame[frame]
        for a, b in match_people(lf, rt):
            both = np.all(np.isfinite(lf[a][0]) & np.isfinite(rt[b][0]), axis=1)
            people.append((frame, lf[a][0][both], rt[b][0][both]))
    record = {"frames": len(frames), "people": len(people)}
    if not people:
        return record, None
    points = {frame: _frame_points(calib, clouds[frame]) for frame in frames}
    readings = [False] + ([True] if calib.left_raw is not None and calib.right_raw is not None else [])
    focal, baseline = calib.focal_px, calib.baseline_m
    cx_shift = calib.right_P_rect[0, 2] - calib.left_P_rect[0, 2]
    left_all = np.concatenate([p[1] for p in people])
    right_all = np.concatenate([p[2] for p in people])
    starts = np.cumsum([0] + [len(p[1]) for p in people])
    hits = np.zeros((len(TRIAL_SCALES), len(people)), dtype=bool)
    for t, scale in enumerate(TRIAL_SCALES):
        for raw in readings:
            left = _rectified(calib, left_all / scale, "left", raw)
            right = _rectified(calib, right_all / scale, "right", raw)
            lo_uv = np.minimum.reduceat(left, starts[:-1], axis=0)
            hi_uv = np.maximum.reduceat(left, starts[:-1], axis=0)
            gap = left[:, 0] - right[:, 0] + cx_shift
            for i, (frame, _, _) in enumerate(people):
                if hits[t, i]:
                    continue
                disparity = float(np.median(gap[starts[i]:starts[i + 1]]))
                if not disparity > 0:
                    continue
                depth = focal * baseline / disparity
                gate = config.depth_gate_m + 3.0 * config.disparity_sigma_px * depth ** 2 / (focal * baseline)
                uvz = points[frame]
                first, last = np.searchsorted(uvz[:, 0], [lo_uv[i, 0], hi_uv[i, 0]])
                inside = uvz[first:last]
                inside = inside[(inside[:, 1] >= lo_uv[i, 1]) & (inside[:, 1] <= hi_uv[i, 1])
                                & (np.abs(inside[:, 2] - depth) <= gate)]
                hits[t, i] = len(inside) >= config.min_hit_points
    totals = hits.sum(axis=1)
    record.update(judge(totals, len(people), config))
    return record, totals


def judge(totals: np.ndarray, people: int, config: PixelScaleConfig) -> dict:
    """The LiDAR check's verdict from the number of people on the LiDAR's returns per trial scale
    (:data:`TRIAL_SCALES`) out of ``people`` (module docstring); ``people_on_lidar_elsewhere``: the most any
    trial scale beyond ``tolerance`` of 1 puts there (the margin of pixels read right)."""
    if people < config.min_people:
        return {"judged": False, "contradicts": False}
    at_one = int(totals[np.argmin(np.abs(TRIAL_SCALES - 1.0))])
    best = int(np.argmax(totals))
    best_scale = float(TRIAL_SCALES[best])
    contradicts = bool(totals[best] >= config.min_ratio * max(at_one, 1) and abs(best_scale - 1.0) > config.tolerance
                       and totals[best] >= config.min_people // 2)
    far = np.abs(TRIAL_SCALES - 1.0) > config.tolerance
    return {"judged": True, "people_on_lidar": at_one, "best_scale": round(best_scale, 3),
            "people_on_lidar_at_best": int(totals[best]),
            "people_on_lidar_elsewhere": int(totals[far].max()) if far.any() else 0, "contradicts": contradicts}
