"""Read COCO keypoint files (annotation files and detector results files) into
:class:`~pedx_graph.detections.types.Detection` (keypoint set ``coco17``).

* Annotation file: ``{"images": [{id, file_name, [width, height], ...}], "annotations": [{image_id,
  category_id, bbox, keypoints [x, y, v]*17, ...}], "categories": [...]}``.  Visibility ``v``: 0 not labelled (absent),
  1 labelled but not visible (confidence 1, ``occluded``), 2 visible (confidence 1).  A ``track_id`` key
  (PoseTrack-style files) becomes the track id; a ``score`` key the detection score (else 1).
* Results file (what top-down detectors write): a list of ``{image_id, category_id, keypoints [x, y, s]*17,
  score}``; the per-keypoint score (clipped to [0, 1]) is the confidence, 0 = absent.  Image ids resolve to
  file names through an image list: a COCO annotation file or a bare ``{"images": [...]}`` / ``[{id,
  file_name}]`` file.  Without one, the image id is the frame and ``camera`` names the camera.

An image's ``width`` and ``height``, when given, become its detections'
:attr:`~pedx_graph.detections.types.Detection.image_size` (the import compares it with the calibration's:
detections made on resized images).  Camera and frame of an image come from its ``file_name``
(:mod:`pedx_graph.detections.naming`).  Only the person category (``category_id`` of the category named
``person``; 1 when there is no category list) is read.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from pedx_graph.data.types import DataFormatError
from pedx_graph.detections.naming import ImageName, compile_patterns, parse_name
from pedx_graph.detections.types import Detection

NUM_COCO_KEYPOINTS = 17


def _load(path: Path):
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(path, None, f"cannot read ({exc})") from exc
    except json.JSONDecodeError as exc:
        raise DataFormatError(path, None, f"not JSON ({exc.msg} at line {exc.lineno})") from exc


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _integer(value) -> bool:
    """A finite number with an integral value (an id)."""
    return _number(value) and math.isfinite(value) and float(value).is_integer()


def image_table(doc, path: Path, name_pattern: str | None = None,
                camera_names: dict[str, str] | None = None) -> dict[int, ImageName]:
    """``image id -> ImageName`` from a COCO ``images`` list (a dict holding one, or the list itself)."""
    images = doc.get("images") if isinstance(doc, dict) else doc
    if not isinstance(images, list):
        raise DataFormatError(path, "images", "missing (expected a list of {id, file_name})")
    patterns = compile_patterns(name_pattern)
    table = {}
    for index, image in enumerate(images):
        if not isinstance(image, dict) or not _integer(image.get("id")) or not isinstance(image.get("file_name"), str):
            raise DataFormatError(path, f"images[{index}]", "needs an integer 'id' and a string 'file_name'")
        table[int(image["id"])] = parse_name(image["file_name"], patterns, f"{path}: images[{index}].file_name",
                                             camera_names)
    return table


def image_sizes(doc, path: Path) -> dict[int, tuple[int, int]]:
    """``image id -> (width, height)`` of the images of a COCO ``images`` list that give both (positive
    integers; :func:`image_table` has checked the list itself)."""
    images = doc.get("images") if isinstance(doc, dict) else doc
    sizes = {}
    for index, image in enumerate(images):
        if "width" not in image and "height" not in image:
            continue
        for key in ("width", "height"):
            if not (_integer(image.get(key)) and image[key] > 0):
                raise DataFormatError(path, f"images[{index}].{key}",
                                      f"must be a positive integer (pixels), got {image.get(key)!r}")
        sizes[int(image["id"])] = (int(image["width"]), int(image["height"]))
    return sizes


def _person_category(doc) -> int:
    for cat in (doc.get("categories") or []) if isinstance(doc, dict) else []:
        if isinstance(cat, dict) and cat.get("name") == "person" and _number(cat.get("id")):
            return int(cat["id"])
    return 1


def _keypoints(item: dict, path: Path, field: str) -> np.ndarray:
    flat = item.get("keypoints")
    if not isinstance(flat, list) or not all(_number(v) for v in flat):
        raise DataFormatError(path, field, "missing or not a list of numbers")
    if len(flat) != 3 * NUM_COCO_KEYPOINTS:
        raise DataFormatError(path, field, f"length {len(flat)}, expected {3 * NUM_COCO_KEYPOINTS} "
                                           f"(x, y, v or score for 17 keypoints)")
    arr = np.asarray(flat, dtype=np.float64).reshape(NUM_COCO_KEYPOINTS, 3)
    if not np.all(np.isfinite(arr)):
        raise DataFormatError(path, field, "non-finite value")
    return arr


def _bbox(item: dict, path: Path, field: str) -> np.ndarray | None:
    box = item.get("bbox")
    if box is None:
        return None
    if (not isinstance(box, list) or len(box) != 4 or not all(_number(v) and math.isfinite(v) for v in box)
            or box[2] < 0 or box[3] < 0):
        raise DataFormatError(path, field, f"must be [x, y, w, h] with w, h >= 0, got {box!r}")
    return np.asarray(box, dtype=np.float64)


def _track_id(item: dict) -> str | None:
    tid = item.get("track_id")
    return None if tid is None or (_number(tid) and tid < 0) else str(tid)


def read_coco_annotations(path: str | os.PathLike, name_pattern: str | None = None,
                          camera_names: dict[str, str] | None = None) -> list[Detection]:
    """The person annotations of a COCO keypoint annotation file (module docstring)."""
    path = Path(path)
    doc = _load(path)
    if not isinstance(doc, dict) or not isinstance(doc.get("annotations"), list):
        raise DataFormatError(path, "annotations", "missing (an annotation file has 'images' and 'annotations')")
    images = image_table(doc, path, name_pattern, camera_names)
    sizes = image_sizes(doc, path)
    person = _person_category(doc)
    out = []
    for index, ann in enumerate(doc["annotations"]):
        field = f"annotations[{index}]"
        if not isinstance(ann, dict):
            raise DataFormatError(path, field, "must be an object")
        if ann.get("category_id", person) != person or "keypoints" not in ann:
            continue
        image = images.get(int(ann["image_id"])) if _integer(ann.get("image_id")) else None
        if image is None:
            raise DataFormatError(path, f"{field}.image_id", f"{ann.get('image_id')!r} is not in 'images'")
        arr = _keypoints(ann, path, f"{field}.keypoints")
        vis = arr[:, 2]
        if not np.all(np.isin(vis, (0, 1, 2))):
            raise DataFormatError(path, f"{field}.keypoints", "visibility flags must be 0, 1 or 2")
        present = vis > 0
        if not present.any():
            continue
        uv = arr[:, :2].copy()
        uv[~present] = np.nan
        score = ann.get("score", 1.0)
        if not (_number(score) and math.isfinite(score)):
            raise DataFormatError(path, f"{field}.score", f"must be a finite number, got {score!r}")
        out.append(Detection(camera=image.camera, frame=image.frame, keypoint_set="coco17", image_uv=uv,
                             confidence=present.astype(float), score=float(score), source=f"{path}#{field}",
                             track_id=_track_id(ann), bbox=_bbox(ann, path, f"{field}.bbox"),
                             occluded=vis == 1, sequence=image.sequence, image=image.stem,
                             image_size=sizes.get(int(ann["image_id"]))))
    return out


def read_coco_results(path: str | os.PathLike, images: str | os.PathLike | None = None,
                      name_pattern: str | None = None, camera_names: dict[str, str] | None = None,
                      camera: str | None = None) -> list[Detection]:
    """The person detections of a COCO keypoint results file (module docstring).

    ``images``: a file whose ``images`` list resolves the image ids; without it the image id is the frame and
    ``camera`` the camera (:class:`DataFormatError` when neither is given).
    """
    path = Path(path)
    doc = _load(path)
    if not isinstance(doc, list):
        raise DataFormatError(path, None, "a results file is a list of {image_id, keypoints, score}")
    table, sizes = None, {}
    if images is not None:
        images = Path(images)
        listing = _load(images)
        table = image_table(listing, images, name_pattern, camera_names)
        sizes = image_sizes(listing, images)
    elif camera is None:
        raise DataFormatError(path, "image_id", "image ids need an image list (the annotation file) or a camera name")
    out = []
    for index, item in enumerate(doc):
        field = f"[{index}]"
        if not isinstance(item, dict):
            raise DataFormatError(path, field, "must be an object")
        if item.get("category_id", 1) != 1:
            continue
        image_id = item.get("image_id")
        if not _integer(image_id):
            raise DataFormatError(path, f"{field}.image_id", f"must be an integer, got {image_id!r}")
        if table is not None:
            if int(image_id) not in table:
                raise DataFormatError(path, f"{field}.image_id", f"{image_id} is not in {images}")
            image = table[int(image_id)]
        else:
            image = ImageName(sequence=None, camera=camera, frame=int(image_id))
        arr = _keypoints(item, path, f"{field}.keypoints")
        conf = np.clip(arr[:, 2], 0.0, 1.0)
        present = conf > 0
        if not present.any():
            continue
        uv = arr[:, :2].copy()
        uv[~present] = np.nan
        score = item.get("score")
        if score is not None and not (_number(score) and math.isfinite(score)):
            raise DataFormatError(path, f"{field}.score", f"must be a finite number, got {score!r}")
        out.append(Detection(camera=image.camera, frame=image.frame, keypoint_set="coco17", image_uv=uv,
                             confidence=np.where(present, conf, 0.0),
                             score=float(conf[present].mean() if score is None else score),
                             source=f"{path}#{field}", track_id=_track_id(item),
                             bbox=_bbox(item, path, f"{field}.bbox"), sequence=image.sequence,
                             image=image.stem, image_size=sizes.get(int(image_id))))
    return out


def read_coco(path: str | os.PathLike, images: str | os.PathLike | None = None, name_pattern: str | None = None,
              camera_names: dict[str, str] | None = None, camera: str | None = None) -> list[Detection]:
    """An annotation file (a dict with ``annotations``) or a results file (a list), told apart by content."""
    path = Path(path)
    doc = _load(path)
    if isinstance(doc, dict):
        return read_coco_annotations(path, name_pattern, camera_names)
    return read_coco_results(path, images, name_pattern, camera_names, camera)
