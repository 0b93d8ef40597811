"""Review sheets: each stretch of the identity review drawn on the images the detector saw, one JPEG per stretch.

The import lists where two tracks came close (:mod:`pedx_graph.detections.review`); a team building a dataset
checks those stretches by eye.  A sheet shows one stretch: a row per camera that saw either track there, a
column per frame (at most ``max_frames``, evenly spaced over the stretch's frames that hold a detection of the
two), each cell the same crop of that camera's image — the box of both tracks' detections over the stretch,
widened by ``pad_frac`` of its size — so that who walks where reads left to right.  Each track's detection is
drawn as the detector wrote it (raw-image pixels, no rectification: what the image shows): its keypoints,
its limbs (:func:`pedx_graph.keypoints.limb_edges`; the person's left side in the track's colour, the right
side in a darker shade, so a left/right swap shows too) and its id.  The first track of the stretch is
orange, the second blue; the other tracks are not drawn.  A stretch of one track close to detections no track
holds draws those detections in green, labelled ``untracked`` (a true duplicate of the track's person, or
the other of two people on one ray whom the association left out).

Images are found by the stem of the image each detection was made on (:attr:`Detection.image`: an OpenPose
file's name, a COCO image's ``file_name``) among the files of a folder (searched recursively,
:func:`index_images`).  A cell whose image is missing, or a detection whose file named none, is drawn on a
grey canvas (the keypoints alone still tell who is where); the sheet's index says how many cells had their
image.  The files are named so that they sort in the order to check them (the stretches whose tracks missed
the largest share of their frames first: :func:`pedx_graph.detections.review.check_order`).
"""
from __future__ import annotations

import os
from collections import defaultdict
from pathlib import Path

import numpy as np

from pedx_graph.data.types import UNTRACKED
from pedx_graph.detections.naming import strip_name
from pedx_graph.detections.pixel_units import calibration_sized
from pedx_graph.keypoints import limb_edges
from pedx_graph.utils import atomic_write_bytes, encode_image

#: Image files looked for, by extension (lower case).
IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png")
#: Colours (BGR) of the stretch's first and second track; the right side of each body in ``RIGHT_SHADE`` of it.
TRACK_COLOURS = ((0, 140, 255), (255, 160, 0))
#: Colour (BGR) of a detection no track holds, drawn on a stretch that lists it.
UNTRACKED_COLOUR = (60, 200, 60)
RIGHT_SHADE = 0.55
#: Grey of a cell without its image.
BLANK_GREY = 96
#: Heights of the sheet's title strip and of a cell's frame caption, and the width of the camera column, px.
TITLE_PX, CAPTION_PX, LABEL_PX = 30, 18, 110


def index_images(folder: str | os.PathLike) -> dict[str, Path]:
    """Stem (:func:`~pedx_graph.detections.naming.strip_name`) -> path of every image file under ``folder``
    (searched recursively; the first in sorted order where two share a stem).  ``ValueError`` naming the
    folder when it is not one."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: the images folder does not exist")
    out: dict[str, Path] = {}
    for path in sorted(folder.rglob("*")):
        if path.suffix.lower() in IMAGE_EXTENSIONS and path.is_file():
            out.setdefault(strip_name(path.name), path)
    return out


def _chosen_frames(frames: list[int], max_frames: int) -> list[int]:
    """At most ``max_frames`` of the sorted ``frames``, evenly spaced, the first and the last kept."""
    if len(frames) <= max_frames:
        return frames
    picks = np.unique(np.round(np.linspace(0, len(frames) - 1, max_frames)).astype(int))
    return [frames[i] for i in picks]


def _crop_box(detections: list, pad_frac: float) -> tuple[int, int, int, int]:
    """``(x0, y0, x1, y1)`` integer pixels: the box of the detections' keypoint boxes widened by ``pad_frac``
    of its larger side on every side (at least 8 px)."""
    boxes = np.array([det.box() for det in detections], dtype=float)
    lo = boxes[:, :2].min(axis=0)
    hi = (boxes[:, :2] + boxes[:, 2:]).max(axis=0)
    pad = max(pad_frac * float(np.max(hi - lo)), 8.0)
    lo, hi = np.floor(lo - pad), np.ceil(hi + pad)
    return int(lo[0]), int(lo[1]), int(hi[0]), int(hi[1])


def _cut(image: np.ndarray | None, box: tuple[int, int, int, int]) -> np.ndarray:
    """The ``box`` of ``image`` (BGR), grey where the box leaves the image or there is no image."""
    x0, y0, x1, y1 = box
    out = np.full((y1 - y0, x1 - x0, 3), BLANK_GREY, dtype=np.uint8)
    if image is None:
        return out
    h, w = image.shape[:2]
    sx0, sy0, sx1, sy1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if sx1 > sx0 and sy1 > sy0:
        out[sy0 - y0:sy1 - y0, sx0 - x0:sx1 - x0] = image[sy0:sy1, sx0:sx1]
    return out


def _draw_detection(cell: np.ndarray, det, origin: np.ndarray, scale: float, colour: tuple, label: str) -> None:
    """One detection on a cell (in place): limbs, keypoints and the track's id at its top keypoint."""
    import cv2

    uv = (np.asarray(det.image_uv, dtype=float) - origin) * scale
    present = det.present
    shade = tuple(int(c * RIGHT_SHADE) for c in colour)
    width = max(1, int(round(cell.shape[0] / 160)))
    for i, j, side in limb_edges(det.keypoint_set):
        if present[i] and present[j]:
            cv2.line(cell, tuple(np.round(uv[i]).astype(int)), tuple(np.round(uv[j]).astype(int)),
                     shade if side == "right" else colour, width + 1, cv2.LINE_AA)
    for k in np.flatnonzero(present):
        cv2.circle(cell, tuple(np.round(uv[k]).astype(int)), width + 2, (0, 0, 0), -1, cv2.LINE_AA)
        cv2.circle(cell, tuple(np.round(uv[k]).astype(int)), width + 1, colour, -1, cv2.LINE_AA)
    if present.any():
        top = uv[present][np.argmin(uv[present, 1])]
        anchor = (int(top[0]) - 4 * len(label), max(int(top[1]) - 8, 12))
        cv2.putText(cell, label, anchor, cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(cell, label, anchor, cv2.FONT_HERSHEY_SIMPLEX, 0.45, colour, 1, cv2.LINE_AA)


def image_stems(detections: list) -> dict[tuple[str, int], str]:
    """``(camera, frame)`` -> the stem of the image the detections of that camera and frame were made on
    (:attr:`Detection.image`; frames whose files name no image are left out)."""
    return {(det.camera, det.frame): det.image for det in detections if det.image}


def review_sheet(tracks: dict, stretch: dict, images: dict[str, Path], max_frames: int = 10,
                 cell_height_px: int = 240, pad_frac: float = 0.15,
                 stems: dict[tuple[str, int], str] | None = None,
                 untracked: dict | None = None, resized: dict | None = None) -> tuple[np.ndarray, dict] | None:
    """The sheet of one stretch (module docstring) as a BGR image, and what it holds (``frames``, ``cameras``,
    ``cells``, ``cells_with_image`` and the ``[camera, frame]`` of the others, ``without_image``); None when
    neither track has a detection in it.  A cell is ``cell_height_px`` high, or less where its crop is more
    than three times as wide as high (the two far apart in that image).  ``tracks``: track id -> frame ->
    camera -> :class:`~pedx_graph.detections.types.Detection`; ``stretch``: one of
    :func:`~pedx_graph.detections.review.review_stretches`; ``images``: :func:`index_images`; ``stems``:
    :func:`image_stems` of every detection read (a cell where neither track was detected finds its image
    by another person's detection there; without, by the two tracks' only); ``untracked``: ``(camera, frame,
    source)`` -> :class:`~pedx_graph.detections.types.Detection` of the detections no track holds, for the
    ones the stretch lists (``"untracked"``; left out without it; their frames are drawn too, a frame before
    or after the stretch where one lies there: it was close to the track's frame next to it); ``resized``:
    :func:`~pedx_graph.detections.pixel_scale.resized_cameras` (their images are brought to the calibration's
    size, where the detections' pixels now are)."""
    import cv2

    names = list(stretch["tracks"])
    first, last = int(stretch["first_frame"]), int(stretch["last_frame"])
    lone: dict[int, dict[str, list]] = defaultdict(lambda: defaultdict(list))   # frame -> camera -> untracked
    for entry in stretch.get("untracked", []):
        det = (untracked or {}).get((entry["camera"], int(entry["frame"]), entry["source"]))
        if det is not None:
            lone[det.frame][det.camera].append(det)
    held = sorted({f for tid in names for f in tracks.get(tid, {}) if first <= f <= last} | set(lone))
    frames = _chosen_frames(held, max_frames)
    by_camera: dict[str, list] = defaultdict(list)
    for tid in names:
        for frame in frames:
            for camera, det in tracks.get(tid, {}).get(frame, {}).items():
                by_camera[camera].append(det)
    for frame in frames:
        for camera, dets in lone.get(frame, {}).items():
            by_camera[camera].extend(dets)
    if not by_camera:
        return None
    cameras = sorted(by_camera)
    boxes = {camera: _crop_box(by_camera[camera], pad_frac) for camera in cameras}
    scales = {camera: min(cell_height_px / (b[3] - b[1]), 3 * cell_height_px / (b[2] - b[0]))
              for camera, b in boxes.items()}
    sizes = {camera: (max(int(round((b[2] - b[0]) * scales[camera])), 1),
                      max(int(round((b[3] - b[1]) * scales[camera])), 1)) for camera, b in boxes.items()}
    column_px = max(w for w, _ in sizes.values())
    row_px = cell_height_px + CAPTION_PX
    font = cv2.FONT_HERSHEY_SIMPLEX
    title = (f"tracks {names[0]} (orange) and {names[-1]} (blue), frames {first}-{last}" if len(names) > 1 else
             f"track {names[0]} (orange) and detections no track holds (green), frames {first}-{last}")
    title_px = cv2.getTextSize(title, font, 0.55, 1)[0][0] + 16
    sheet = np.full((TITLE_PX + row_px * len(cameras), max(LABEL_PX + column_px * len(frames), title_px), 3), 255,
                    dtype=np.uint8)
    cv2.putText(sheet, title, (8, 20), font, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    found = cells = 0
    missing = []
    for r, camera in enumerate(cameras):
        y = TITLE_PX + r * row_px
        cv2.putText(sheet, camera, (6, y + CAPTION_PX + cell_height_px // 2), font, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        box, scale, size = boxes[camera], scales[camera], sizes[camera]
        for c, frame in enumerate(frames):
            x = LABEL_PX + c * column_px
            cv2.putText(sheet, f"frame {frame}", (x + 4, y + 13), font, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
            dets = [(k, tracks.get(tid, {}).get(frame, {}).get(camera)) for k, tid in enumerate(names)]
            dets = [(k, det) for k, det in dets if det is not None]
            extra = lone.get(frame, {}).get(camera, [])
            stem = next((det.image for det in [d for _, d in dets] + extra if det.image), None) \
                or (stems or {}).get((camera, frame))
            image = cv2.imread(str(images[stem]), cv2.IMREAD_COLOR) if stem in images else None
            if image is not None and camera in (resized or {}):
                image = calibration_sized(image, *resized[camera])
            cells += 1
            found += image is not None
            if image is None:
                missing.append([camera, frame])
            cell = cv2.resize(_cut(image, box), size, interpolation=cv2.INTER_AREA)
            for det in extra:
                _draw_detection(cell, det, np.array(box[:2], dtype=float), scale, UNTRACKED_COLOUR, UNTRACKED)
            for k, det in dets:
                _draw_detection(cell, det, np.array(box[:2], dtype=float), scale, TRACK_COLOURS[k % 2], names[k])
            sheet[y + CAPTION_PX:y + CAPTION_PX + size[1], x:x + size[0]] = cell
    return sheet, {"frames": frames, "cameras": cameras, "cells": cells, "cells_with_image": found,
                   "without_image": missing}


def write_review_sheets(tracks: list, stretches: list[dict], images: dict[str, Path], out: str | os.PathLike,
                        stems: dict[tuple[str, int], str] | None = None, order: list[int] | None = None,
                        max_frames: int = 10, cell_height_px: int = 240, untracked: list | None = None,
                        resized: dict | None = None) -> list[dict]:
    """One JPEG per stretch under ``out`` (``<n>_<a>_<b>_<first>-<last>.jpg``, ``<n>_<a>_untracked_...`` for a
    stretch of one track, ``n`` its place in ``order``, :func:`~pedx_graph.detections.review.check_order`,
    from 1: the files sort in the order to check them; written atomically); returns the index: per stretch
    (in the list's order) its place, tracks, frames, the sheet's file name (None when nothing was drawn) and
    how many of its cells had their image.  ``tracks``:
    :class:`~pedx_graph.detections.association.DetectedTrack`; ``stems``: :func:`image_stems`; ``untracked``:
    the detections no track holds (:func:`~pedx_graph.detections.review.untracked_detections`), drawn where a
    stretch lists them; ``resized``: as in :func:`review_sheet`."""
    by_id = {t.track_id: {fr.frame: dict(fr.detections) for fr in t.frames} for t in tracks}
    loose = {(det.camera, det.frame, det.source): det for det in untracked or []}
    out = Path(out)
    place = {i: n for n, i in enumerate(order if order is not None else range(len(stretches)), start=1)}
    width = len(str(len(stretches)))
    index = []
    for k, stretch in enumerate(stretches):
        drawn = review_sheet(by_id, stretch, images, max_frames, cell_height_px, stems=stems, untracked=loose,
                             resized=resized)
        names = list(stretch["tracks"])
        entry = {"check": place[k], "tracks": names, "first_frame": stretch["first_frame"],
                 "last_frame": stretch["last_frame"], "sheet": None}
        if drawn is not None:
            sheet, held = drawn
            pair = "_".join(names if len(names) > 1 else names + [UNTRACKED])
            name = f"{place[k]:0{width}d}_{pair}_{stretch['first_frame']}-{stretch['last_frame']}.jpg"
            atomic_write_bytes(out / name, encode_image(sheet, ".jpg"))
            entry.update(sheet=name, **held)
        index.append(entry)
    return index
