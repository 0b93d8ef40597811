"""The raw images the detections were made on, written rectified into the imported dataset's ``images/``.

A detector sees the raw (distorted) images; the release and everything that draws on it (``pedx-graph
export``'s overlays) use the rectified ones.  Given the folder of raw images (``pedx-graph import ...
--raw-images FOLDER``), each image a detection names (:attr:`~pedx_graph.detections.types.Detection.image`,
found by its stem: :func:`~pedx_graph.detections.review_sheets.index_images`) is rectified with its
camera's raw model (:func:`pedx_graph.data.images.rectify_image`, the model the keypoints are rectified
with) and written as ``images/<seq>/<cam>/<seq>_<cam>_<frame:07d>.jpg`` (atomically).  A camera whose
calibration has no raw model (``K_0x`` / ``D_0x``), or whose pair's detections the import found made on
rectified images (:mod:`pedx_graph.detections.image_frame`: the pair is handed over without its raw
models), had rectified images to begin with: they are copied (re-encoded when not JPEG).  A frame in which a camera detected nobody names no image; its image is found
by the name the camera's other images follow (:func:`complete_stems`), so the export can show a person
the detector missed there.

A raw image must have the size the raw ``K`` was calibrated on; the calibration does not say which, so a
camera whose principal point lies outside the middle half of its image (a downscaled copy, or the wrong
camera's file) is skipped with a warning and the reason in the summary.
"""
from __future__ import annotations

import logging
import os
import re
from collections import defaultdict
from pathlib import Path

from pedx_graph.data.images import image_path, read_image, rectification_maps, rectify_image
from pedx_graph.data.types import RawCamera
from pedx_graph.detections.pixel_units import calibration_sized
from pedx_graph.detections.undistort import find_camera, raw_camera
from pedx_graph.execution.executors import map_ordered
from pedx_graph.utils import atomic_write_bytes, encode_image

log = logging.getLogger(__name__)


def principal_point_fits(raw: RawCamera, image_shape: tuple[int, ...]) -> bool:
    """Whether the raw ``K``'s principal point lies in the middle half of an image of ``image_shape``
    (H, W, ...): the image is then of the size ``K`` was calibrated on, as far as can be told."""
    height, width = image_shape[:2]
    cu, cv = float(raw.raw_K[0, 2]), float(raw.raw_K[1, 2])
    return 0.25 * width <= cu <= 0.75 * width and 0.25 * height <= cv <= 0.75 * height


def _stem_template(known: dict[int, str]) -> str | None:
    """A name template ``prefix{frame:0Nd}suffix`` every one of ``known`` (frame -> stem) follows, or None:
    taken from one stem's run of digits that reads as its frame (the last such run first), checked against
    all the others."""
    frame, stem = next(iter(sorted(known.items())))
    for match in reversed(list(re.finditer(r"\d+", stem))):
        if int(match.group()) != frame:
            continue
        width = len(match.group()) if match.group().startswith("0") else 1
        template = stem[:match.start()].replace("{", "{{").replace("}", "}}") + "{:0%dd}" % width \
            + stem[match.end():].replace("{", "{{").replace("}", "}}")
        if all(template.format(f) == s for f, s in known.items()):
            return template
    return None


def complete_stems(stems: dict[tuple[str, int], str], images: dict[str, Path]) -> dict[tuple[str, int], str]:
    """``stems`` (``(camera, frame)`` -> image stem, from the detections) with the frames a camera detected
    nobody in, between the first and the last frame of any detection: their stems follow the name every
    image the camera's detections name follows (:func:`_stem_template`: ``seq_cam_0000012`` ->
    ``seq_cam_{:07d}``), where that image is in ``images``.  A camera whose names follow no such template
    (e.g. COCO ``file_name`` hashes) keeps its own."""
    if not stems:
        return {}
    frames = [frame for _, frame in stems]
    span = range(min(frames), max(frames) + 1)
    by_camera: dict[str, dict[int, str]] = defaultdict(dict)
    for (camera, frame), stem in stems.items():
        by_camera[camera][int(frame)] = stem
    out = dict(stems)
    for camera, known in sorted(by_camera.items()):
        template = _stem_template(known)
        if template is None:
            continue
        for frame in span:
            if frame not in known and template.format(frame) in images:
                out[(camera, frame)] = template.format(frame)
    return out


def _camera_job(job: tuple) -> dict:
    """Write one camera's images (a module-level function for the worker processes): ``job = (out, seq,
    camera, raw model or None, image size, [(frame, raw image path)], resize)`` (``resize``: ``(size, scale)``
    of :func:`~pedx_graph.detections.pixel_scale.resized_cameras` for a camera whose images the detector saw
    at another size, else None); returns what it wrote."""
    out, seq, camera, raw, image_size, items, resize = job
    maps = None
    written, unreadable = 0, []
    for frame, source in items:
        target = image_path(out, seq, camera, frame)
        if raw is None and resize is None and Path(source).suffix.lower() in (".jpg", ".jpeg"):
            atomic_write_bytes(target, Path(source).read_bytes())          # already rectified: as it is
            written += 1
            continue
        image = read_image(source)
        if image is None:
            unreadable.append(str(source))
            continue
        if resize is not None:
            image = calibration_sized(image, *resize)
        if raw is not None:
            if not principal_point_fits(raw, image.shape):
                return {"camera": camera, "written": written, "unreadable": unreadable,
                        "skipped": f"{source}: image {image.shape[1]}x{image.shape[0]} does not hold the raw K's "
                                   f"principal point ({raw.raw_K[0, 2]:.0f}, {raw.raw_K[1, 2]:.0f}) in its middle "
                                   f"half: not the size K was calibrated on"}
            if maps is None:
                maps = rectification_maps(raw, image_size)
            image = rectify_image(image, maps)
        atomic_write_bytes(target, encode_image(image, ".jpg"))
        written += 1
    return {"camera": camera, "written": written, "unreadable": unreadable, "skipped": None}


def write_rectified_images(out: str | os.PathLike, sequence: str, stems: dict[tuple[str, int], str],
                           images: dict[str, Path], calibrations, workers: int = 1, resized: dict | None = None
                           ) -> dict:
    """Write the images named by ``stems`` (``(camera, frame)`` -> image stem,
    :func:`~pedx_graph.detections.review_sheets.image_stems`) from ``images`` (stem -> raw image path)
    rectified under ``out`` (module docstring), with the frames :func:`complete_stems` finds by name;
    ``workers`` processes, one camera each; ``resized``:
    :func:`~pedx_graph.detections.pixel_scale.resized_cameras` (those cameras' images are brought to the
    calibration's size first, where the detections' pixels now are).  Returns the record for the import
    summary: ``folder``, ``written``, ``without_image`` (frames named by a detection whose image is not in the
    folder), ``found_by_name`` (frames without a detection whose image was found by name), ``rectified_cameras``,
    ``copied_cameras`` (no raw model: rectified already), ``skipped_cameras`` (camera -> reason) and
    ``unreadable`` (files OpenCV could not decode)."""
    by_camera: dict[str, list] = defaultdict(list)
    missing = 0
    named = len(stems)
    stems = complete_stems(stems, images)
    for (camera, frame), stem in sorted(stems.items()):
        path = images.get(stem)
        if path is None:
            missing += 1
        else:
            by_camera[camera].append((int(frame), path))
    jobs = []
    for camera in sorted(by_camera):
        calib, side = find_camera(calibrations, camera)
        jobs.append((Path(out), sequence, camera, raw_camera(calib, side), tuple(calib.image_size), by_camera[camera],
                     (resized or {}).get(camera)))
    record = {"folder": f"images/{sequence}", "written": 0, "without_image": missing,
              "found_by_name": len(stems) - named, "rectified_cameras": [], "copied_cameras": [],
              "skipped_cameras": {}, "unreadable": []}
    for job, done in zip(jobs, map_ordered(_camera_job, jobs, workers)):
        record["written"] += done["written"]
        record["unreadable"] += done["unreadable"]
        if done["skipped"]:
            record["skipped_cameras"][done["camera"]] = done["skipped"]
            log.warning("%s: camera %s's raw images not rectified: %s", sequence, done["camera"], done["skipped"])
        else:
            record["rectified_cameras" if job[3] is not None else "copied_cameras"].append(done["camera"])
    if record["unreadable"]:
        log.warning("%s: %d raw images could not be decoded (first: %s)", sequence, len(record["unreadable"]),
                    record["unreadable"][0])
    return record

