"""Read a PedX release (or a simulated one in the same layout) into :class:`Track` objects.

``root`` is the dataset folder holding ``labels/`` and ``calib/`` (the release's ``data/``), or its
parent.  Needed: ``calib/`` and ``labels/2d/``; optional: ``labels/3d/segment/``, ``timestamps/``,
``labels/3d/smpl/`` (ground truth, :func:`read_smpl_labels`).  Images and scene point clouds are not
needed.

Assembly rules
--------------
* One :class:`Track` per (sequence, tracking id) having at least one readable 2D label of a category in
  :attr:`ReaderConfig.categories` (default ``pedestrian``).  Frames are sorted by frame number.
* Stereo pairs are discovered from the ``calib_cam_to_cam_<left>-<right>.txt`` names; a label of camera
  ``<left>`` fills :attr:`TrackFrame.left`, of ``<right>`` :attr:`TrackFrame.right`.  Labels of a camera
  in no readable pair are skipped (one warning per camera).
* When an instance is labelled in several pairs at one frame, every pair's labels are kept: the pair with
  more labelled keypoints (left + right views; ties: the name that sorts first) is the frame's primary
  :attr:`TrackFrame.pair` / ``left`` / ``right``, the others go to :attr:`TrackFrame.other_views`.
  :attr:`Track.calibrations` holds every pair a frame of the track uses.
* LiDAR points come from the instance's segment PLY (empty when absent).  Frames that have a segment
  but no 2D label are not assembled (their pair is unknown).
* Timestamps come from ``timestamps/timestamps-pointclouds-<seq>.txt`` when present
  (:func:`read_timestamps`), else ``frame / fps`` (an info log note names the fps).
* Robustness: a malformed file logs a warning naming the file and the field and only that file is
  skipped (a bad segment leaves the frame without LiDAR points).  :class:`DataFormatError` is raised only
  when nothing at all can be read (no calibration, no label files, no track).
"""
from __future__ import annotations

import logging
import os
import re
from collections import defaultdict
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pedx_graph.data.calib import CalibrationLimits, cam_to_cam_path, read_calibrations, split_pair
from pedx_graph.data.ground import GroundConfig, GroundFrame, estimate_ground
from pedx_graph.data.labels2d import Label2D, iter_label2d_files, read_label2d, screen_label
from pedx_graph.data.ply import pointcloud_path, read_ply_points, segment_path
from pedx_graph.data.smpl_labels import N_BETAS, parse_smpl_label_name, read_smpl_label
from pedx_graph.data.types import UNTRACKED, DataFormatError, SmplLabel, StereoCalibration, Track, TrackFrame

logger = logging.getLogger(__name__)


@dataclass
class ReaderConfig:
    """How a release folder is turned into tracks."""

    fps: float = 10.0
    """Frame rate (Hz) giving ``timestamp = frame / fps`` when a sequence has no timestamps file."""
    categories: tuple[str, ...] = ("pedestrian",)
    """2D label categories assembled into tracks (others are skipped silently)."""
    read_segments: bool = True
    """Read the LiDAR segment PLY of every instance (False: empty point arrays)."""
    timestamps_kind: str = "pointclouds"
    """Which timestamps file gives frame times: ``timestamps-<kind>-<seq>.txt``."""
    ground: GroundConfig = field(default_factory=GroundConfig)
    """How each sequence's up axis, ground plane and viewpoint are derived (:mod:`pedx_graph.data.ground`)."""
    calibration_limits: CalibrationLimits = field(default_factory=CalibrationLimits)
    """Sanity limits of the calibration files (:class:`~pedx_graph.data.calib.CalibrationLimits`)."""
    keypoint_margin: float = 0.05
    """A 2D keypoint more than this fraction of the image width / height outside the image is dropped with a
    warning; a label with more than half of its keypoints outside is skipped (:func:`screen_label`).  Clicks
    just past the border are kept: annotators click a foot or hand cut by the image edge where they guess it."""


def resolve_root(root: str | os.PathLike) -> Path:
    """The folder holding ``labels/``: ``root`` itself or ``root/data``; :class:`DataFormatError` otherwise."""
    root = Path(root)
    if (root / "labels").is_dir():
        return root
    if (root / "data" / "labels").is_dir():
        return root / "data"
    raise DataFormatError(root, None, "not a PedX dataset folder: neither 'labels/' nor 'data/labels/' exists")


def list_sequences(root: str | os.PathLike, kind: str = "2d") -> list[str]:
    """Sorted sequence names with a folder in ``labels/2d`` (``kind="2d"``) or ``labels/3d/<kind>``."""
    root = resolve_root(root)
    base = root / "labels" / "2d" if kind == "2d" else root / "labels" / "3d" / kind
    if not base.is_dir():
        return []
    return sorted(p.name for p in base.iterdir() if p.is_dir() and not p.name.startswith("."))


def _select_sequences(available: list[str], sequences: Iterable[str] | None, where: Path) -> list[str]:
    if sequences is None:
        return available
    if isinstance(sequences, str):
        sequences = [sequences]
    chosen = []
    for seq in sequences:
        if seq in available:
            chosen.append(seq)
        else:
            logger.warning("%s: sequence %s not found (available: %s); skipped", where, seq, available)
    return chosen


# --------------------------------------------------------------------------------------------- timestamps

def timestamps_path(root: str | os.PathLike, sequence: str, kind: str = "pointclouds") -> Path:
    """``<root>/timestamps/timestamps-<kind>-<seq>.txt`` (kind ``pointclouds`` or ``images``)."""
    return Path(root) / "timestamps" / f"timestamps-{kind}-{sequence}.txt"


_DIGITS_RE = re.compile(r"([0-9]+)(?!.*[0-9])")


def _frame_token(token: str) -> int | None:
    digits = token if token.isascii() and token.isdigit() else None    # ASCII only: '²'.isdigit() too
    if digits is None:
        match = _DIGITS_RE.search(token)  # e.g. a file name "<seq>_0000123.ply": its last digit run
        digits = match.group(1) if match and not _is_float(token) else None
    return int(digits) if digits is not None and len(digits.lstrip("0")) <= 15 else None


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def read_timestamps(path: str | os.PathLike) -> dict[int, float]:
    """Frame number -> seconds from a timestamps file (the release does not document the format).

    Accepted: one number per line (line ``i`` of the data lines is frame ``i``, counting from 0), or
    two columns ``frame value`` (separated by whitespace or a comma; the frame may be zero padded or a
    file name ending in the frame number).  Blank lines and ``#`` comments are skipped.  Units are
    inferred from the median magnitude: > 1e17 nanoseconds, > 1e14 microseconds, > 1e11 milliseconds,
    else seconds.  Raises :class:`DataFormatError` naming the file and line on malformed content.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise DataFormatError(path, None, f"cannot read file ({exc.strerror or exc})") from exc
    frames: list[int] = []
    values: list[float] = []
    columns = None
    for lineno, line in enumerate(text.splitlines(), start=1):
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            continue
        tokens = [t for t in re.split(r"[,\s]+", stripped) if t]
        if columns is None:
            columns = len(tokens)
            if columns not in (1, 2):
                raise DataFormatError(path, f"line {lineno}", f"expected 1 or 2 columns, found {columns}")
        if len(tokens) != columns:
            raise DataFormatError(path, f"line {lineno}", f"expected {columns} columns, found {len(tokens)}")
        try:
            value = float(tokens[-1])
        except ValueError:
            raise DataFormatError(path, f"line {lineno}", f"non-numeric timestamp {tokens[-1]!r}") from None
        if not np.isfinite(value):
            raise DataFormatError(path, f"line {lineno}", f"non-finite timestamp {tokens[-1]!r}")
        if columns == 1:
            frame = len(frames)
        else:
            frame = _frame_token(tokens[0])
            if frame is None:
                raise DataFormatError(path, f"line {lineno}", f"frame {tokens[0]!r} is not an integer")
        frames.append(frame)
        values.append(value)
    if not frames:
        raise DataFormatError(path, None, "no timestamps in file")
    if len(set(frames)) != len(frames):
        raise DataFormatError(path, "frame", "a frame number appears twice")
    times = np.asarray(values, dtype=np.float64)
    magnitude = float(np.median(np.abs(times)))
    scale = 1e-9 if magnitude > 1e17 else 1e-6 if magnitude > 1e14 else 1e-3 if magnitude > 1e11 else 1.0
    return {f: float(t * scale) for f, t in zip(frames, times)}


def frame_times(frames: Iterable[int], table: dict[int, float] | None, fps: float,
                where: str = "") -> dict[int, float]:
    """Seconds of each frame: from ``table`` where listed, else ``frame / fps`` when ``table`` is None.

    Frames missing from a table are interpolated linearly between listed frames and extrapolated at
    ``1 / fps`` seconds per frame beyond its ends (one warning naming ``where`` and the count).
    """
    frames = sorted(set(int(f) for f in frames))
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if table is None:
        return {f: f / fps for f in frames}
    known = np.array(sorted(table), dtype=np.float64)
    known_t = np.array([table[int(f)] for f in known])
    out: dict[int, float] = {}
    missing = 0
    for f in frames:
        if f in table:
            out[f] = table[f]
            continue
        missing += 1
        if f < known[0]:
            out[f] = float(known_t[0] - (known[0] - f) / fps)
        elif f > known[-1]:
            out[f] = float(known_t[-1] + (f - known[-1]) / fps)
        else:
            out[f] = float(np.interp(f, known, known_t))
    if missing:
        logger.warning("%s: %d labelled frame(s) missing from the timestamps; interpolated", where, missing)
    return out


def _sequence_timestamps(root: Path, sequence: str, config: ReaderConfig) -> dict[int, float] | None:
    path = timestamps_path(root, sequence, config.timestamps_kind)
    if not path.is_file():
        logger.info("%s: no timestamps file %s; using frame / fps with fps = %g", sequence, path.name, config.fps)
        return None
    try:
        return read_timestamps(path)
    except DataFormatError as exc:
        logger.warning("%s; using frame / fps with fps = %g instead", exc, config.fps)
        return None


# ------------------------------------------------------------------------------------------------ tracks

def camera_sides(calibrations: dict[str, StereoCalibration]) -> dict[str, tuple[str, str]]:
    """Camera name -> (pair name, ``"left"`` or ``"right"``) of the given stereo pairs."""
    sides: dict[str, tuple[str, str]] = {}
    for pair in calibrations:
        left, right = split_pair(pair)
        for camera, side in ((left, "left"), (right, "right")):
            if camera in sides:
                raise DataFormatError(pair, None, f"camera {camera} belongs to two stereo pairs "
                                                  f"({sides[camera][0]} and {pair})")
            sides[camera] = (pair, side)
    return sides


def uncalibrated_reason(calib_dir: Path, camera: str, calib_errors: dict[str, str]) -> str:
    """Why ``camera`` has no usable calibration: its pair's error (a missing or malformed file, named), or the
    ``calib_cam_to_cam`` file names that would have given it one."""
    for pair, message in sorted(calib_errors.items()):
        if camera in split_pair(pair):
            return message
    return (f"{calib_dir}: no calibration of camera {camera} (missing: "
            f"{cam_to_cam_path(calib_dir, f'{camera}-<right>').name} or "
            f"{cam_to_cam_path(calib_dir, f'<left>-{camera}').name})")


def _index_sequence(root: Path, sequence: str, sides: dict[str, tuple[str, str]],
                    uncalibrated: dict[str, str], calib_errors: dict[str, str] | None = None
                    ) -> dict[str, list[tuple[int, str, Path]]]:
    """tracking id -> [(frame, camera, path)] of a sequence's 2D label files (names only, nothing read).
    Labels of a camera in no readable stereo pair are skipped: one warning per camera naming the calibration
    file that is missing or malformed, recorded in ``uncalibrated`` (camera -> reason)."""
    index: dict[str, list[tuple[int, str, Path]]] = defaultdict(list)
    seen: dict[tuple[int, str, str], Path] = {}
    for path, camera, frame, tid in iter_label2d_files(root, sequence):
        if camera not in sides:
            if camera not in uncalibrated:
                uncalibrated[camera] = uncalibrated_reason(root / "calib", camera, calib_errors or {})
                logger.warning("%s: camera %s is in no calibrated stereo pair (%s); its labels are skipped",
                               path.parent, camera, uncalibrated[camera])
            continue
        key = (frame, camera, tid)
        if key in seen:
            logger.warning("%s: duplicate of %s (same camera, frame and tracking id); skipped", path, seen[key])
            continue
        seen[key] = path
        index[tid].append((frame, camera, path))
    return index


def _choose_pair(frame_views: dict[str, dict[str, Label2D]]) -> str:
    """The pair with the most labelled keypoints over its two views (ties: first name)."""
    def score(pair: str) -> int:
        return sum(label.n_labelled for label in frame_views[pair].values())
    return max(sorted(frame_views), key=score)


def _assemble_track(root: Path, sequence: str, tracking_id: str, entries: list[tuple[int, str, Path]],
                    calibrations: dict[str, StereoCalibration], sides: dict[str, tuple[str, str]],
                    times: dict[int, float], config: ReaderConfig, ground: GroundFrame | None = None,
                    skipped: dict[str, int] | None = None) -> Track | None:
    skipped = skipped if skipped is not None else {"labels": 0}
    by_frame: dict[int, dict[str, dict[str, Label2D]]] = defaultdict(lambda: defaultdict(dict))
    track_set = None
    for frame, camera, path in sorted(entries):
        try:
            label = read_label2d(path, sequence, camera, frame, tracking_id)
        except DataFormatError as exc:
            logger.warning("%s; instance skipped", exc)
            skipped["labels"] += 1
            continue
        if label.category not in config.categories:
            continue
        pair, side = sides[camera]
        track_set = label.view.keypoint_set if track_set is None else track_set
        if label.view.keypoint_set != track_set:      # one keypoint set per track (the fit's body map)
            logger.warning("%s: field 'keypoint_set' %r differs from the track's %r; instance skipped", path,
                           label.view.keypoint_set, track_set)
            skipped["labels"] += 1
            continue
        label = screen_label(label, calibrations[pair].image_size, config.keypoint_margin, path)
        if label is None:
            skipped["labels"] += 1
            continue
        by_frame[frame][pair][side] = label
    frames: list[TrackFrame] = []
    for frame in sorted(by_frame):
        views = by_frame[frame]
        pair = _choose_pair(views)
        if len(views) > 1:
            logger.debug("%s %s frame %d: labelled in pairs %s; primary %s (more labelled keypoints)",
                         sequence, tracking_id, frame, sorted(views), pair)
        points = np.zeros((0, 3))
        if config.read_segments:
            seg = segment_path(root, sequence, frame, tracking_id)
            if seg.is_file():
                try:
                    points = read_ply_points(seg)
                except DataFormatError as exc:
                    logger.warning("%s; LiDAR points of this instance skipped", exc)
        def side_views(name: str) -> tuple:
            return tuple(None if views[name].get(side) is None else views[name][side].view
                         for side in ("left", "right"))
        left, right = side_views(pair)
        frames.append(TrackFrame(frame=frame, timestamp=times[frame], pair=pair, left=left, right=right,
                                 world_lidar_points=points,
                                 other_views={name: side_views(name) for name in sorted(views) if name != pair}))
    if not frames:
        return None
    used = sorted({name for f in frames for name in f.pairs})
    return Track(sequence=sequence, tracking_id=tracking_id, frames=frames,
                 calibrations={pair: calibrations[pair] for pair in used}, ground=ground)


def iter_tracks(root: str | os.PathLike, sequences: Iterable[str] | None = None,
                config: ReaderConfig | None = None) -> Iterator[Track]:
    """Yield tracks one at a time (sequence by sequence, tracks by first frame then id); lazy variant of
    :func:`read_dataset`: only the current track's files are held in memory.

    Raises :class:`DataFormatError` when the calibration cannot be read, or (at the end) when no track
    at all was produced.
    """
    config = config or ReaderConfig()
    root = resolve_root(root)
    calib_errors: dict[str, str] = {}
    calibrations = read_calibrations(root / "calib", config.calibration_limits, calib_errors)
    sides = camera_sides(calibrations)
    available = list_sequences(root, "2d")
    chosen = _select_sequences(available, sequences, root / "labels" / "2d")
    uncalibrated: dict[str, str] = {}
    skipped = {"labels": 0}
    n_tracks = 0
    n_files = 0
    for sequence in chosen:
        index = _index_sequence(root, sequence, sides, uncalibrated, calib_errors)
        n_files += sum(len(v) for v in index.values())
        if not index:
            logger.warning("%s: no 2D label file of a calibrated camera", root / "labels" / "2d" / sequence)
            continue
        table = _sequence_timestamps(root, sequence, config)
        all_frames = {frame for entries in index.values() for frame, _, _ in entries}
        times = frame_times(all_frames, table, config.fps, where=sequence)
        ground = sequence_ground(root, sequence, calibrations, config.ground)
        review = identity_review(root, sequence)
        order = sorted(index, key=lambda tid: (min(f for f, _, _ in index[tid]), tid))
        for tid in order:
            track = _assemble_track(root, sequence, tid, index[tid], calibrations, sides, times, config, ground,
                                    skipped)
            if track is not None:
                track.identity_review = review.get(tid, [])
                n_tracks += 1
                yield track
    if n_tracks == 0:
        by_reason: dict[str, list[str]] = defaultdict(list)
        for camera, reason in sorted(uncalibrated.items()):
            by_reason[reason].append(camera)
        why = "".join(f"; labels of {', '.join(cams)} skipped: {reason}" for reason, cams in by_reason.items())
        if skipped["labels"]:
            why += f"; {skipped['labels']} label files skipped as unreadable or outside the image (see the warnings)"
        raise DataFormatError(root / "labels" / "2d", None,
                              f"no track could be read (sequences {chosen or available or 'none'}, "
                              f"{n_files} label files of calibrated cameras, categories {list(config.categories)})"
                              + why)


def identity_review(root: str | os.PathLike, sequence: str) -> dict[str, list[dict]]:
    """Track id -> the stretches ``pedx-graph import`` listed for it in ``<root>/import_summary.json``
    (``sequences.<seq>.identity_review.stretches``, :mod:`pedx_graph.detections.review`), each as
    ``{"other", "first_frame", "last_frame"}`` (``other``: :data:`~pedx_graph.data.types.UNTRACKED` for a
    stretch naming one track); empty without the file (hand labels).  A malformed file or
    entry logs a warning naming the file and field and gives no review (the labels are read all the same)."""
    path = Path(root) / "import_summary.json"
    if not path.is_file():
        return {}
    from pedx_graph.data.jsonfile import read_json_file

    field_name = f"sequences.{sequence}.identity_review.stretches"
    try:
        record = read_json_file(path).get("sequences", {}).get(sequence)
        stretches = [] if record is None else record.get("identity_review", {}).get("stretches", [])
        out: dict[str, list[dict]] = defaultdict(list)
        for stretch in stretches:
            if stretch.get("checked"):      # a reviewer looked and found it right (identity fixes file)
                continue
            names = [str(t) for t in stretch["tracks"]]
            if len(names) not in (1, 2):
                raise ValueError(f"{len(names)} tracks in a stretch")
            first, last = int(stretch["first_frame"]), int(stretch["last_frame"])
            if len(names) == 1:             # close to detections no track holds
                out[names[0]].append({"other": UNTRACKED, "first_frame": first, "last_frame": last})
                continue
            a, b = names
            for tid, other in ((a, b), (b, a)):
                out[tid].append({"other": other, "first_frame": first, "last_frame": last})
    except DataFormatError as exc:
        logger.warning("%s; no identity review read", exc)
        return {}
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        logger.warning("%s: field %s: malformed (%s); no identity review read", path, field_name, exc)
        return {}
    return dict(out)


def _evenly(items: list, count: int) -> list:
    """At most ``count`` of ``items``, evenly spaced (first and last included)."""
    if len(items) <= count:
        return list(items)
    return [items[int(round(i))] for i in np.linspace(0, len(items) - 1, count)]


def sequence_ground(root: str | os.PathLike, sequence: str, calibrations: dict[str, StereoCalibration],
                    config: GroundConfig | None = None) -> GroundFrame:
    """The :class:`~pedx_graph.data.ground.GroundFrame` of one sequence: the calibration's up, refined by a
    ground-plane fit of up to ``config.max_pointcloud_frames`` scene clouds (``pointclouds/<seq>/``, evenly
    spaced), else of the lowest points of up to 400 pedestrian segments (``labels/3d/segment/<seq>/``).
    Unreadable files are skipped with a warning naming them; too few points: a warning naming the
    sequence and the calibration's up (:func:`~pedx_graph.data.ground.estimate_ground`)."""
    config = config or GroundConfig()
    root = resolve_root(root)

    def read_some(paths: list[Path]) -> list[np.ndarray]:
        out = []
        for path in paths:
            try:
                out.append(read_ply_points(path))
            except DataFormatError as exc:
                logger.warning("%s; not used for the ground fit", exc)
        return out

    clouds = segments = None
    if config.source in ("auto", "pointclouds"):
        paths = sorted((root / "pointclouds" / sequence).glob(f"{sequence}_*.ply"))
        if paths:
            clouds = read_some(_evenly(paths, config.max_pointcloud_frames))
    if config.source in ("auto", "segments"):
        paths = sorted((root / "labels" / "3d" / "segment" / sequence).glob(f"{sequence}_*.ply"))
        if paths:
            segments = read_some(_evenly(paths, 400))
    return estimate_ground(calibrations, clouds, segments, sequence=sequence, config=config)


def read_dataset(root: str | os.PathLike, sequences: Iterable[str] | None = None,
                 config: ReaderConfig | None = None) -> list[Track]:
    """All tracks of the dataset at ``root`` (see the module docstring for the assembly rules)."""
    return list(iter_tracks(root, sequences, config))


# ------------------------------------------------------------------------------------------ ground truth

def read_smpl_labels(root: str | os.PathLike, sequences: Iterable[str] | None = None,
                     n_betas: int | None = N_BETAS) -> dict[tuple[str, str], list[SmplLabel]]:
    """SMPL labels under ``labels/3d/smpl``: ``(sequence, tracking_id) -> labels sorted by frame``.

    Malformed files are skipped with a warning naming file and field; raises :class:`DataFormatError`
    when none can be read.
    """
    root = resolve_root(root)
    base = root / "labels" / "3d" / "smpl"
    chosen = _select_sequences(list_sequences(root, "smpl"), sequences, base)
    out: dict[tuple[str, str], list[SmplLabel]] = defaultdict(list)
    for sequence in chosen:
        for path in sorted((base / sequence).glob("*.json")):
            parsed = parse_smpl_label_name(path, sequence)
            if parsed is None:
                logger.warning("%s: file name does not match '%s_<frame>_<tid>.json'; skipped", path, sequence)
                continue
            try:
                label = read_smpl_label(path, sequence, parsed[0], parsed[1], n_betas=n_betas)
            except DataFormatError as exc:
                logger.warning("%s; label skipped", exc)
                continue
            out[(sequence, parsed[1])].append(label)
    if not out:
        raise DataFormatError(base, None, f"no SMPL label could be read (sequences {chosen})")
    return {key: sorted(labels, key=lambda lab: lab.frame) for key, labels in sorted(out.items())}


def read_scene_points(root: str | os.PathLike, sequence: str, frame: int) -> np.ndarray:
    """(N, 3) finite LiDAR points of a frame's full scene (``pointclouds/``), world frame, metres."""
    return read_ply_points(pointcloud_path(resolve_root(root), sequence, frame))
