"""``pedx-graph import openpose|coco``: detector files -> a dataset in the PedX release layout, ready to fit.

Steps: read the files (:mod:`.openpose`, :mod:`.coco`; camera and frame from the file / image names,
:mod:`.naming`) -> bring their coordinates to the calibration's pixels (resized images, normalised
coordinates; checked against the LiDAR: :mod:`.pixel_scale`; a pair's cameras named the wrong way round
refused: :mod:`.pair_order`) -> group them into people: the file's own
ids with ``use_file_ids`` (OpenPose ``person_id``, COCO ``track_id``; every detection must have one), else
:func:`pedx_graph.detections.association.associate` (stereo, over frames, across pairs; with file ids each
frame is placed as the association places its people — triangulated, centred on the LiDAR — without its
identity steps,
:func:`~pedx_graph.detections.association.tracks_from_ids`)
-> with a reviewer's identity fixes file, the tracks fixed (:mod:`pedx_graph.detections.fixes`)
-> per person, frame and camera, undistort + rectify the keypoints
(:func:`pedx_graph.detections.undistort.rectified`; for the pairs whose detections were made on
rectified images, told from their stereo rows by :mod:`pedx_graph.detections.image_frame`, the pixels as
they are), drop those below the confidence threshold and turn the
confidences into pixel noise (:class:`pedx_graph.detections.noise.DetectionNoiseConfig`) -> write
``labels/2d/<seq>/<cam>/<seq>_<cam>_<frame:07d>_<tid>.json`` with ``keypoint_set`` and per-keypoint
``confidence`` and ``sigma_px`` (:mod:`pedx_graph.data.labels2d`), copy ``calib/`` (and ``timestamps/``),
link ``pointclouds/`` and cut each person's LiDAR points from the scene clouds
(:func:`pedx_graph.detections.lidar_cut.write_track_segments`, with the cut of ``association.lidar_cut``)
when the source dataset has them.  A summary goes to ``<out>/import_summary.json`` (with the stretches of
frames where two tracks came close, to check who is who there: :mod:`pedx_graph.detections.review`; given
the images the detections were made on, each stretch drawn on them in ``<out>/review/<seq>/``:
:mod:`pedx_graph.detections.review_sheets`; and those images rectified into ``<out>/images/``:
:mod:`pedx_graph.detections.rectified_images`), the resolved config to ``<out>/import_config.yaml``.
"""
from __future__ import annotations

import dataclasses
import logging
import os
import shutil
from collections import OrderedDict, defaultdict
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pedx_graph.config import save_config
from pedx_graph.data.calib import read_calibrations
from pedx_graph.data.labels2d import Label2D, write_label2d
from pedx_graph.data.types import DataFormatError, View2D
from pedx_graph.detections.association import AssociationConfig
from pedx_graph.detections.flips import FlipConfig, unflip_tracks
from pedx_graph.detections.frame_interval import WalkingCheckConfig, sequence_frame_interval, walking_check
from pedx_graph.detections.image_frame import ImageFrameConfig, image_frames, pixel_calibrations
from pedx_graph.detections.noise import DetectionNoiseConfig, detection_height_px, stereo_row_scale
from pedx_graph.detections.pair_order import pair_order
from pedx_graph.detections.pixel_scale import (PixelScaleConfig, detector_pixels, resized_cameras,
                                              seen_calibrations)
from pedx_graph.detections.review import ReviewConfig, review_summary, untracked_detections
from pedx_graph.detections.types import Detection
from pedx_graph.detections.undistort import find_camera, rectified
from pedx_graph.utils import atomic_write_bytes, atomic_write_json, atomic_write_text

log = logging.getLogger(__name__)

DEFAULT_SEQUENCE = "detections"
"""Sequence name of detections whose file names give none and no ``--sequence`` is passed."""


@dataclass
class ImportConfig:
    """How detections become 2D labels."""

    noise: DetectionNoiseConfig = field(default_factory=DetectionNoiseConfig)
    """Confidence -> pixel noise and the drop threshold."""
    use_file_ids: bool = False
    """Group detections by the ids in the files (every detection must have one) instead of associating them."""
    min_keypoints: int = 3
    """A detection with fewer kept keypoints (after the threshold) is not written."""
    association: AssociationConfig = field(default_factory=AssociationConfig)
    """Who is who when the files carry no ids (stereo matching, tracking, merging across pairs).  Its
    ``lidar_cut`` is the one definition of how a person's LiDAR points are cut from a scene cloud: the
    association's LiDAR centres and the segments written for the fit use the same cut."""
    flips: FlipConfig = field(default_factory=FlipConfig)
    """A detection whose left and right the detector confused (the whole body), swapped back where the
    person's walking direction shows it (:mod:`pedx_graph.detections.flips`; off by default)."""
    stereo_noise_check: bool = True
    """Check the noise model against the data's own stereo rows (keypoints seen in both images of a pair
    lie on one rectified row; :func:`pedx_graph.detections.noise.stereo_row_scale`) and, where the data show
    more noise than the model (a detector noisier than the simulated one the curves were measured on),
    multiply every sigma of the sequence by that factor.  Never lowers them: the rows only bound the noise
    from below.  The factor goes to ``import_summary.json`` (``sequences.<seq>.stereo_noise_check``)."""
    min_stereo_samples: int = 200
    """Fewer keypoints seen in both images of a pair than this: no check (the model's sigmas as they are)."""
    cloud_cache_mb: float = 512.0
    """Scene clouds kept in memory while importing, megabytes, the least recently used dropped first (the
    association and the segments read each frame's cloud many times; 0 = one frame at a time)."""
    review: ReviewConfig = field(default_factory=ReviewConfig)
    """Which stretches of frames ``import_summary.json`` lists for a second look at who is who
    (``sequences.<seq>.identity_review``: two tracks close in an image or on the ground, or a track beside a
    detection no track holds, :mod:`pedx_graph.detections.review`)."""
    walking_check: WalkingCheckConfig = field(default_factory=WalkingCheckConfig)
    """The association's frame interval (the sequence's timestamps when the dataset has them, else
    ``association.tracker.frame_interval_s``) checked against how fast the tracked people walk
    (:mod:`pedx_graph.detections.frame_interval`; ``import_summary.json``, ``sequences.<seq>.frame_interval``)."""
    image_frame: ImageFrameConfig = field(default_factory=ImageFrameConfig)
    """Which images the detections' pixels are in, raw or rectified: by default told per pair from the
    detections' own stereo rows (:mod:`pedx_graph.detections.image_frame`; a calibration with raw keys does
    not say the detector saw raw images).  The decision goes to ``import_summary.json``
    (``sequences.<seq>.image_frame``)."""
    pixel_scale: PixelScaleConfig = field(default_factory=PixelScaleConfig)
    """Which coordinates the detections are in: the calibrated images' pixels, pixels of resized copies (a
    COCO image list's sizes, or ``scale``), or coordinates normalised by the image size; checked against the
    LiDAR (:mod:`pedx_graph.detections.pixel_scale`; ``import_summary.json``, ``sequences.<seq>.pixel_scale``)."""
    check_pair_order: bool = True
    """Stop the import where a stereo pair's two cameras look named the wrong way round (the people of the
    image named left lie to the right of the other's: :mod:`pedx_graph.detections.pair_order`); False: only
    count (``sequences.<seq>.pair_order``)."""
    write_images: bool = True
    """Given the raw images the detections were made on (``raw_images``): write them rectified into the
    dataset's ``images/`` (:mod:`pedx_graph.detections.rectified_images`), so ``pedx-graph export`` draws its
    overlays on them; False: only the review sheets are drawn on them."""


def calibration_dir(source: str | os.PathLike) -> Path:
    """``<source>/calib`` when ``source`` is a dataset root holding one, else ``source`` itself."""
    source = Path(source)
    return source / "calib" if (source / "calib").is_dir() else source


class _Clouds(Mapping):
    """Frame -> the sequence's scene cloud, read on demand (``pointclouds/<seq>/``), the most recently used
    ones kept up to ``cache_mb`` megabytes (the last one always).  The association visits a frame's cloud
    once per track and step, track after track: a person is seen for a stretch of frames, so a cache holding
    such a stretch reads each file about once.  Pickled (for worker processes) without the cache."""

    def __init__(self, root: Path, sequence: str, cache_mb: float = 0.0):
        from pedx_graph.data.ply import pointcloud_path
        self._paths = {}
        folder = root / "pointclouds" / sequence
        if folder.is_dir():
            for path in folder.glob(f"{sequence}_*.ply"):
                token = path.stem.rsplit("_", 1)[-1]
                if token.isdigit() and pointcloud_path(root, sequence, int(token)) == path:
                    self._paths[int(token)] = path
        self._budget = float(cache_mb) * 1e6
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()

    def __getstate__(self) -> dict:
        return {**self.__dict__, "_cache": OrderedDict()}

    def __getitem__(self, frame: int) -> np.ndarray:
        from pedx_graph.data.ply import read_ply_points
        if frame in self._cache:
            self._cache.move_to_end(frame)
            return self._cache[frame]
        points = read_ply_points(self._paths[frame])
        self._cache[frame] = points
        held = sum(cloud.nbytes for cloud in self._cache.values())
        while len(self._cache) > 1 and held > self._budget:
            held -= self._cache.popitem(last=False)[1].nbytes
        return points

    def __iter__(self):
        return iter(sorted(self._paths))

    def __len__(self) -> int:
        return len(self._paths)


def detection_view(det: Detection, calibrations, noise: DetectionNoiseConfig) -> View2D:
    """The :class:`View2D` of one detection: rectified pixels, keypoints below the threshold dropped,
    per-keypoint confidence and sigma_px from the confidence and the person's height measured on the detection
    (annotations: :attr:`DetectionNoiseConfig.annotation_sigma_px`)."""
    uv = rectified(det, calibrations)
    annotation = det.occluded is not None
    height = detection_height_px(np.where(det.present[:, None], uv, np.nan))
    sigma = noise.sigma(det.keypoint_set, det.confidence, det.occluded, annotation=annotation, height_px=height)
    keep = np.all(np.isfinite(uv), axis=1) & np.isfinite(sigma)
    uv[~keep] = np.nan
    visible = keep & (~det.occluded if det.occluded is not None else True)
    return View2D(keypoints=uv, visible=visible, keypoint_set=det.keypoint_set,
                  sigma_px=np.where(keep, sigma, np.nan), confidence=np.where(keep, det.confidence, np.nan))


def stereo_rows(views: Mapping[tuple, View2D], calibrations) -> dict[str, tuple[np.ndarray, ...]]:
    """Pair name -> ``(d, sd, confidence)`` over every person and frame seen in both images of a pair: for
    each keypoint kept in both, the rectified row difference ``d = v_left - v_right`` (pixels), its predicted
    standard deviation ``sqrt(sigma_left^2 + sigma_right^2)`` from the views' ``sigma_px`` and the lower of
    the two confidences (:func:`pedx_graph.detections.noise.stereo_row_scale`).  ``views``: ``(person, frame,
    camera) ->`` :func:`detection_view`."""
    sides: dict[tuple, dict[str, View2D]] = defaultdict(dict)
    for (person, frame, camera), view in views.items():
        calib, side = find_camera(calibrations, camera)
        sides[(calib.name, person, frame)][side] = view
    rows: dict[str, tuple[list, list, list]] = defaultdict(lambda: ([], [], []))
    for (pair, _, _), both in sorted(sides.items(), key=lambda kv: tuple(map(str, kv[0]))):
        left, right = both.get("left"), both.get("right")
        if left is None or right is None or left.sigma_px is None or right.sigma_px is None:
            continue
        keep = left.labelled & right.labelled
        rows[pair][0].append(left.keypoints[keep, 1] - right.keypoints[keep, 1])
        rows[pair][1].append(np.hypot(left.sigma_px[keep], right.sigma_px[keep]))
        confidence = [np.ones(len(keep)) if v.confidence is None else v.confidence for v in (left, right)]
        rows[pair][2].append(np.minimum(confidence[0][keep], confidence[1][keep]))
    return {pair: tuple(np.concatenate(part) for part in parts) for pair, parts in rows.items()}


def _group_by_file_ids(detections: list[Detection]) -> dict[str, list[Detection]]:
    groups: dict[str, list[Detection]] = defaultdict(list)
    for det in detections:
        if det.track_id is None:
            raise DataFormatError(det.source, "person_id/track_id", "no id in the file (needed with --use-file-ids)")
        groups[det.track_id].append(det)
    return groups


def _copy_support(source_root: Path | None, calib_dir: Path, out: Path) -> dict:
    """Copy the calibration (and timestamps), link the scene clouds; returns what was done."""
    done = {"calib_files": 0, "pointclouds": None, "timestamps": False}
    (out / "calib").mkdir(parents=True, exist_ok=True)
    for path in sorted(calib_dir.glob("calib_*.txt")):
        shutil.copyfile(path, out / "calib" / path.name)
        done["calib_files"] += 1
    if source_root is None:
        return done
    if (source_root / "timestamps").is_dir() and not (out / "timestamps").exists():
        shutil.copytree(source_root / "timestamps", out / "timestamps")
        done["timestamps"] = True
    clouds = source_root / "pointclouds"
    target = out / "pointclouds"
    if clouds.is_dir() and not target.exists():
        try:
            target.symlink_to(os.path.relpath(clouds.resolve(), out.resolve()), target_is_directory=True)
            done["pointclouds"] = "linked"
        except OSError:
            shutil.copytree(clouds, target)
            done["pointclouds"] = "copied"
    return done


def import_detections(detections: list[Detection], calib: str | os.PathLike, out: str | os.PathLike,
                      config: ImportConfig | None = None, sequence: str | None = None, workers: int = 1,
                      raw_images: str | os.PathLike | None = None,
                      identity_fixes: str | os.PathLike | None = None) -> dict:
    """Write ``detections`` as a dataset under ``out`` (module docstring); returns the summary (also written).
    ``workers``: local processes for the association's per-pair steps (the same tracks with any number) and
    for rectifying images.  ``raw_images``: the folder of the images the detections were made on; each
    stretch of the identity review is then drawn on them, one JPEG per stretch under ``out/review/<seq>/``
    (:mod:`pedx_graph.detections.review_sheets`), and with ``config.write_images`` they are written
    rectified into ``out/images/`` (:mod:`pedx_graph.detections.rectified_images`).  ``identity_fixes``: a
    reviewer's fixes file (:mod:`pedx_graph.detections.fixes`), applied to each sequence's tracks before
    anything is written from them, and copied to ``out/identity_fixes.yaml``.  ``out/identity_fixes_template.yaml``
    lists the stretches still to check as commented fixes (:func:`~pedx_graph.detections.fixes.fixes_template`)."""
    from pedx_graph.detections.fixes import fixes_template, read_fixes
    from pedx_graph.detections.review_sheets import index_images

    config = config or ImportConfig()
    fixes = read_fixes(identity_fixes) if identity_fixes is not None else {}
    images = index_images(raw_images) if raw_images is not None else None
    calib = Path(calib)
    calib_dir = calibration_dir(calib)
    calibrations = read_calibrations(calib_dir)
    source_root = calib if calib_dir != calib else None
    by_sequence: dict[str, list[Detection]] = defaultdict(list)
    for det in detections:
        by_sequence[det.sequence or sequence or DEFAULT_SEQUENCE].append(det)
    unknown = sorted(set(fixes) - set(by_sequence))
    if unknown:
        raise DataFormatError(identity_fixes, unknown[0], f"no such sequence among the detections "
                                                          f"({', '.join(sorted(by_sequence))})")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    support = _copy_support(source_root, calib_dir, out)
    summary = {"detections": len(detections), "sequences": {}, "support": support,
               "keypoint_sets": sorted({d.keypoint_set for d in detections})}
    if identity_fixes is not None:
        atomic_write_bytes(out / "identity_fixes.yaml", Path(identity_fixes).read_bytes())
    for seq in sorted(by_sequence):
        if "_" in seq:
            raise ValueError(f"sequence name {seq!r} must not contain '_' (release file names); pass --sequence")
        summary["sequences"][seq] = _import_sequence(seq, by_sequence[seq], calibrations, out, source_root, config,
                                                      workers, images, fixes.get(seq), identity_fixes)
    atomic_write_text(out / "identity_fixes_template.yaml", fixes_template(summary["sequences"]))
    save_config(config, out / "import_config.yaml")          # the resolved config beside what it made
    atomic_write_json(out / "import_summary.json", summary)
    return summary


def _import_sequence(seq: str, detections: list[Detection], calibrations, out: Path, source_root: Path | None,
                     config: ImportConfig, workers: int = 1, images: dict | None = None,
                     fixes=None, fixes_path: str | os.PathLike | None = None) -> dict:
    from pedx_graph.detections.association import associate, tracks_from_ids
    from pedx_graph.detections.fixes import fix_tracks, mark_checked, tracks_digest

    known = [d for d in detections if _calibrated(d.camera, calibrations)]
    uncalibrated = sorted({d.camera for d in detections} - {d.camera for d in known})
    if uncalibrated:
        log.warning("%s: cameras %s are in no calibrated pair; their detections are skipped", seq, uncalibrated)
    clouds = _Clouds(source_root, seq, config.cloud_cache_mb) if source_root is not None else {}
    from pedx_graph.data.ground import ground_from_calibrations
    ground = ground_from_calibrations(dict(calibrations), seq)
    known, scale_record = detector_pixels(known, calibrations, config.pixel_scale, clouds or None, seq,
                                          ground.world_up)
    as_read, calibrations = calibrations, seen_calibrations(calibrations, scale_record["cameras"])
    order_record = pair_order(known, calibrations, config.noise.min_confidence, seq, refuse=config.check_pair_order)
    frames_record = image_frames(known, calibrations, config.image_frame, config.noise.min_confidence, seq)
    calibrations = pixel_calibrations(calibrations, frames_record)
    people: dict[str, dict[int, dict[str, Detection]]] = {}
    interval_s, interval_from = sequence_frame_interval(source_root, seq, {d.frame for d in known},
                                                        config.association.frame_interval_s)
    association = config.association.with_frame_interval(interval_s)
    if config.use_file_ids:
        for tid, dets in sorted(_group_by_file_ids(known).items()):
            frames: dict[int, dict[str, Detection]] = defaultdict(dict)
            for det in sorted(dets, key=lambda d: (d.frame, d.camera, -d.score)):
                frames[det.frame].setdefault(det.camera, det)
            people[tid] = frames
        tracks = tracks_from_ids(people, calibrations, association, ground,     # centres for the cut
                                 clouds=clouds or None)
    else:
        tracks = associate(known, calibrations, association, clouds=clouds or None, ground=ground,
                           workers=workers)
    digest, fixed = tracks_digest(tracks), None
    if fixes is not None:
        tracks, fixed = fix_tracks(tracks, list(fixes.operations), fixes_path, calibrations, association,
                                   ground, clouds=clouds or None, made_for=fixes.made_for,
                                   where=f"{seq}.made_for", untracked=untracked_detections(known, tracks))
        log.debug("%s: %d identity fix operations applied (%d detections moved, %d added, %d removed)", seq,
                  fixed["operations"], fixed["detections_moved"], fixed["detections_added"],
                  fixed["detections_removed"])
    tracks, flipped = unflip_tracks(tracks, calibrations, ground, config.flips, association.keypoint_sigma_px,
                                    association.keypoint_sigma_frac, association.frame_interval_s)
    if flipped:
        log.info("%s: %d detections had their left and right swapped back", seq, flipped)
    walking = walking_check(tracks, ground, interval_s, config.walking_check)
    walking["from"] = interval_from
    if not walking["agrees"]:
        fix = ("check that file's times" if interval_from != "config" else
               f"give the sequence's timestamps (timestamps/timestamps-pointclouds-{seq}.txt) or "
               f"association.tracker.frame_interval_s and tracklet.frame_interval_s in --config, and the fit's fps")
        log.warning("%s: the %d walking tracks move a median %.2f m per frame: at a walking speed of %.2f m/s "
                    "that is a frame every %.3f s, not the %.3f s used (%s); %s", seq, walking["walking_tracks"],
                    walking["m_per_frame"], config.walking_check.walking_speed_mps, walking["implied_interval_s"],
                    interval_s, interval_from, fix)
    untracked = untracked_detections(known, tracks)
    review = review_summary(tracks, ground, config.review, untracked)
    if fixes is not None:
        mark_checked(review, fixes.operations, tracks)
    sheets = written_images = None
    if images is not None:
        from pedx_graph.detections.review_sheets import image_stems, write_review_sheets
        stems = image_stems(known)
        open_stretches = [i for i, s in enumerate(review["stretches"]) if not s.get("checked")]
        place = {i: k for k, i in enumerate(open_stretches)}
        resized = resized_cameras(scale_record, as_read)
        sheets = {"folder": f"review/{seq}", "images_in_folder": len(images),
                  "sheets": write_review_sheets(tracks, [review["stretches"][i] for i in open_stretches], images,
                                                out / "review" / seq, stems,
                                                [place[i] for i in review["check_order"]], untracked=untracked,
                                                resized=resized)}
        if config.write_images:
            from pedx_graph.detections.rectified_images import write_rectified_images
            written_images = write_rectified_images(out, seq, stems, images, calibrations, workers, resized)
    people = {track.track_id: {fr.frame: dict(fr.detections) for fr in track.frames} for track in tracks}
    views = {(tid, frame, camera): detection_view(det, calibrations, config.noise)
             for tid, frames in people.items() for frame, cams in frames.items() for camera, det in cams.items()}
    check = stereo_row_scale(stereo_rows(views, calibrations), config.min_stereo_samples,
                             knots=config.noise.default.confidence_knots) if config.stereo_noise_check else None
    factor = check.applied if check is not None else 1.0
    if factor > 1.0:
        log.warning("%s: the detections' stereo rows show %.2fx the noise model's keypoint noise (%d keypoints); "
                    "every sigma scaled by %.2f", seq, check.scale, check.samples, factor)
    written = 0
    for tid, frames in people.items():
        for frame, cams in sorted(frames.items()):
            for camera in sorted(cams):
                view = views[(tid, frame, camera)]
                if int(view.labelled.sum()) < config.min_keypoints:
                    continue
                if factor != 1.0 or config.noise.definition_sigma_m > 0:
                    definition = config.noise.definition_sigma_px(view.keypoint_set,
                                                                  detection_height_px(view.keypoints))
                    view = dataclasses.replace(view, sigma_px=np.hypot(view.sigma_px * factor, definition))
                write_label2d(out, Label2D(sequence=seq, camera=camera, frame=frame, tracking_id=tid,
                                           category="pedestrian", view=view, subtype="detection"))
                written += 1
    result = {"detections": len(detections), "tracks": len(people), "labels_written": written,
              "left_right_swapped_back": flipped,
              "uncalibrated_cameras": uncalibrated, "pixel_scale": scale_record, "pair_order": order_record,
              "image_frame": frames_record,
              "frame_interval": walking,
              "stereo_noise_check": check.record() if check is not None else None,
              "tracks_digest": digest, "identity_fixes": fixed, "identity_review": review,
              "review_sheets": sheets, "images": written_images}
    if len(clouds):
        from pedx_graph.detections.lidar_cut import write_track_segments
        result["segments"] = write_track_segments(out, seq, tracks, calibrations, ground,
                                                  lambda frame: clouds[frame], association.lidar_cut,
                                                  frames_with_cloud=set(clouds))
    return result


def _calibrated(camera: str, calibrations) -> bool:
    return any(camera in calib.name.split("-") for calib in calibrations.values())
