"""Image or detection-file names -> (sequence, camera, frame), by documented patterns or a user's regex.

A name is first stripped of its folder, of OpenPose's ``_keypoints.json`` suffix and of one image or JSON
extension (``.json``, ``.jpg``, ``.jpeg``, ``.png``); the rest is matched in full against each pattern in turn:

1. PedX image names ``<sequence>_<camera>_<frame>`` (frame = digits, e.g. ``20171207T2024_blu79CF_0000123``);
2. ``<camera><sep><frame>`` with ``<sep>`` one of ``. _ -`` and a numeric frame (e.g. ``cam01.0000``);

or only against a user's regex (``--name-pattern``), whose named groups are ``camera`` and ``frame``
(required) and ``sequence`` (optional), e.g. ``(?P<camera>cam\\d+)\\.(?P<frame>\\d+)``.  ``frame`` must be
digits.  A name no pattern matches is a :class:`DataFormatError` naming the file.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from pedx_graph.data.types import DataFormatError

#: The built-in patterns, tried in this order.
DEFAULT_NAME_PATTERNS: tuple[str, ...] = (
    r"(?P<sequence>[^_/]+)_(?P<camera>[^_/]+)_(?P<frame>\d+)",
    r"(?P<camera>[^/]+?)[._-](?P<frame>\d+)",
)

_SUFFIXES = ("_keypoints.json", ".json", ".jpg", ".jpeg", ".png")


@dataclass(frozen=True)
class ImageName:
    """Where one image sits in a capture."""

    sequence: str | None
    """The sequence named by the file, or None when the pattern has no ``sequence`` group."""
    camera: str
    """Camera name as written in the file name (rename with ``camera_names`` to match the calibration)."""
    frame: int
    """Frame index."""
    stem: str | None = None
    """The name without folder, extension and OpenPose's ``_keypoints.json``: the image's stem, by which
    the image the detector saw is found again (:mod:`pedx_graph.detections.review_sheets`)."""


def strip_name(name: str) -> str:
    """The stem of an image or detection file name: folder, ``_keypoints.json`` and extension removed."""
    base = Path(str(name)).name
    lower = base.lower()
    for suffix in _SUFFIXES:
        if lower.endswith(suffix):
            return base[: -len(suffix)]
    return base


def compile_patterns(pattern: str | None) -> list[re.Pattern]:
    """The user's pattern (checked for its ``camera`` and ``frame`` groups), or the built-in ones."""
    if pattern is None:
        return [re.compile(p) for p in DEFAULT_NAME_PATTERNS]
    try:
        compiled = re.compile(pattern)
    except re.error as exc:
        raise ValueError(f"--name-pattern {pattern!r} is not a regular expression ({exc})") from exc
    missing = {"camera", "frame"} - set(compiled.groupindex)
    if missing:
        raise ValueError(f"--name-pattern {pattern!r} needs the named groups {sorted(missing)} "
                         f"(e.g. '(?P<camera>cam\\d+)\\.(?P<frame>\\d+)')")
    return [compiled]


def parse_name(name: str, patterns: list[re.Pattern] | None = None, source: str | None = None,
               camera_names: dict[str, str] | None = None) -> ImageName:
    """(sequence, camera, frame) of an image / detection file ``name`` (module docstring).

    ``camera_names`` renames cameras (file's name -> calibration's name).  :class:`DataFormatError` naming
    ``source`` (default ``name``) when no pattern matches.
    """
    stem = strip_name(name)
    for pattern in patterns or compile_patterns(None):
        match = pattern.fullmatch(stem)
        if match is None:
            continue
        frame_text = match.group("frame")
        if not frame_text.isdigit():
            raise DataFormatError(source or name, "frame", f"frame {frame_text!r} of name {stem!r} is not a number")
        groups = match.groupdict()
        camera = match.group("camera")
        if camera_names:
            camera = camera_names.get(camera, camera)
        return ImageName(sequence=groups.get("sequence"), camera=camera, frame=int(frame_text), stem=stem)
    raise DataFormatError(source or name, "file name",
                          f"{stem!r} matches no name pattern ({', '.join(p.pattern for p in patterns or [])}"
                          f"{'' if patterns else 'built-in: <sequence>_<camera>_<frame>, <camera>.<frame>'}); "
                          f"give --name-pattern with (?P<camera>...) and (?P<frame>...) groups")
