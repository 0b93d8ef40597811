"""Read OpenPose JSON files (BODY_25, BODY_25B, COCO-18) into :class:`~pedx_graph.detections.types.Detection`.

One file per image: ``{"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": [x, y, c, ...]}]}``
(OpenPose names it ``<image name>_keypoints.json``).  A joint written ``0, 0, 0`` (or with confidence 0) is
absent.  The keypoint set follows from the count (18: ``coco18``; 25: ``body25`` unless the caller names
``body25b``, since both have 25 points).  ``person_id`` >= 0 (a tracker filled it) becomes the track id.
Pixels are kept as written: in the raw image the detector saw.
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

#: Keypoint counts -> the set assumed when the caller names none.
SET_BY_COUNT = {18: "coco18", 25: "body25"}
#: Sets an OpenPose file may hold, with their counts.
OPENPOSE_SETS = {"coco18": 18, "body25": 25, "body25b": 25}


def _load_json(path: Path):
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFormatError(path, None, f"cannot read ({exc})") from exc
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise DataFormatError(path, None, f"not JSON ({exc.msg} at line {exc.lineno})") from exc


def parse_openpose(doc, path: str | os.PathLike, image: ImageName, keypoint_set: str | None = None) -> list[Detection]:
    """The detections of one parsed OpenPose document ``doc`` (from file ``path``) seen in ``image``."""
    if not isinstance(doc, dict) or "people" not in doc:
        raise DataFormatError(path, "people", "missing (an OpenPose file is {'version': ..., 'people': [...]})")
    people = doc["people"]
    if not isinstance(people, list):
        raise DataFormatError(path, "people", f"must be a list, got {type(people).__name__}")
    if keypoint_set is not None and keypoint_set not in OPENPOSE_SETS:
        raise ValueError(f"keypoint set {keypoint_set!r} is not an OpenPose set ({', '.join(OPENPOSE_SETS)})")
    out = []
    for index, person in enumerate(people):
        field = f"people[{index}].pose_keypoints_2d"
        if not isinstance(person, dict) or "pose_keypoints_2d" not in person:
            raise DataFormatError(path, field, "missing")
        flat = person["pose_keypoints_2d"]
        if not isinstance(flat, list) or not all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                 for v in flat):
            raise DataFormatError(path, field, "must be a list of numbers")
        if len(flat) == 0:
            continue                                      # a person of the face/hand model only
        if len(flat) % 3:
            raise DataFormatError(path, field, f"length {len(flat)} is not a multiple of 3 (x, y, c per joint)")
        count = len(flat) // 3
        set_name = keypoint_set or SET_BY_COUNT.get(count)
        if set_name is None or OPENPOSE_SETS[set_name] != count:
            raise DataFormatError(path, field, f"{count} keypoints: expected "
                                  + (f"{OPENPOSE_SETS[keypoint_set]} for {keypoint_set}" if keypoint_set else
                                     "18 (COCO-18) or 25 (BODY_25 / BODY_25B)"))
        arr = np.asarray(flat, dtype=np.float64).reshape(count, 3)
        if not np.all(np.isfinite(arr)):
            raise DataFormatError(path, field, "non-finite value")
        conf = arr[:, 2].copy()
        if np.any(conf < 0) or np.any(conf > 1.0 + 1e-6):
            raise DataFormatError(path, field, f"confidence outside [0, 1] (min {conf.min():g}, max {conf.max():g})")
        absent = (conf <= 0) | np.all(arr[:, :2] == 0, axis=1)
        conf[absent] = 0.0
        uv = arr[:, :2].copy()
        uv[absent] = np.nan
        if not np.any(~absent):
            continue
        track_id = None
        pid = person.get("person_id", -1)
        if isinstance(pid, list):
            pid = pid[0] if pid else -1
        if not isinstance(pid, (int, float)) or isinstance(pid, bool) or not math.isfinite(pid):
            raise DataFormatError(path, f"people[{index}].person_id", f"must be a number, got {pid!r}")
        if pid >= 0:
            track_id = str(int(pid))
        out.append(Detection(camera=image.camera, frame=image.frame, keypoint_set=set_name, image_uv=uv,
                             confidence=np.clip(conf, 0.0, 1.0), score=float(conf[~absent].mean()),
                             source=f"{path}#people[{index}]", track_id=track_id, sequence=image.sequence,
                             image=image.stem))
    return out


def read_openpose_file(path: str | os.PathLike, keypoint_set: str | None = None, name_pattern: str | None = None,
                       camera_names: dict[str, str] | None = None, image: ImageName | None = None) -> list[Detection]:
    """The detections of one OpenPose file; camera and frame from its name (:mod:`.naming`) unless ``image``."""
    path = Path(path)
    if image is None:
        image = parse_name(path.name, compile_patterns(name_pattern), str(path), camera_names)
    return parse_openpose(_load_json(path), path, image, keypoint_set)


def read_openpose(inputs: str | os.PathLike | list, keypoint_set: str | None = None, name_pattern: str | None = None,
                  camera_names: dict[str, str] | None = None) -> list[Detection]:
    """Every OpenPose file of ``inputs`` (files, or folders searched recursively for ``*.json``), by path."""
    paths = []
    for item in (inputs if isinstance(inputs, (list, tuple)) else [inputs]):
        item = Path(item)
        if item.is_dir():
            paths.extend(sorted(item.rglob("*.json")))
        elif item.is_file():
            paths.append(item)
        else:
            raise DataFormatError(item, None, "no such file or folder")
    patterns = compile_patterns(name_pattern)
    detections = []
    for path in sorted(paths):
        image = parse_name(path.name, patterns, str(path), camera_names)
        detections.extend(read_openpose_file(path, keypoint_set, image=image))
    return detections
