"""The seconds between a sequence's frames for the association's motion model: from the dataset's timestamps
when it has them, else the config's — and a check of that figure against how fast the tracked people walk.

The association turns speeds (m/s) into metres per frame with ``tracker.frame_interval_s``; the fit reads
the same sequence's timestamps (``timestamps/timestamps-<kind>-<seq>.txt``) or ``frame / fps``.  A frame rate
assumed rather than read is a convention the simulator and the code would share (both at 10 Hz); a real
recording may be sampled at 5, 6 (PedX's labelled frames, by the walking speed of its own fits) or 30 Hz.  So:

* :func:`sequence_frame_interval`: with a timestamps file for the sequence (the point clouds', as the fit
  reads by default, else the images'), the median over the frames the
  detections span of the seconds per frame step (frames missing from the file are skipped); without one,
  the config's value;
* :func:`walking_check`: people walk at about 1.2-1.5 m/s.  Each track's velocity is the least-squares
  slope of its centres on the ground plane over its frames; the tracks that walk (carried at least
  ``min_walk_m`` by that slope, over at least ``min_frames`` placed frames) move a median ``m`` metres per
  frame, so the data imply an interval ``m / walking_speed_mps``; the import warns when that
  differs from the interval it used by more than ``max_ratio`` (and records it either way), since the fit
  will assume the same wrong rate when the dataset has no timestamps.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pedx_graph.data.reader import read_timestamps, timestamps_path
from pedx_graph.data.types import DataFormatError

log = logging.getLogger(__name__)


#: Timestamps files tried in order (the fit's reader reads ``pointclouds`` by default:
#: ``ReaderConfig.timestamps_kind``).
TIMESTAMP_KINDS = ("pointclouds", "images")


def sequence_frame_interval(root: Path | None, sequence: str, frames, default_s: float) -> tuple[float, str]:
    """``(seconds per frame step, where it came from)``: the median step of the timestamps of ``root``'s
    sequence (the first of :data:`TIMESTAMP_KINDS` present) over the span of ``frames`` when the file exists and
    gives a positive one, else ``default_s``."""
    if root is None:
        return float(default_s), "config"
    path = next((p for p in (timestamps_path(root, sequence, kind) for kind in TIMESTAMP_KINDS) if p.is_file()),
                None)
    if path is None:
        return float(default_s), "config"
    try:
        table = read_timestamps(path)
    except DataFormatError as exc:
        log.warning("%s; the association uses frame_interval_s = %g s", exc, default_s)
        return float(default_s), "config"
    frames = sorted(int(f) for f in frames)
    listed = np.array(sorted(f for f in table if (not frames) or frames[0] <= f <= frames[-1]), dtype=float)
    if len(listed) < 2:
        return float(default_s), "config"
    times = np.array([table[int(f)] for f in listed])
    steps = np.diff(times) / np.diff(listed)
    steps = steps[np.isfinite(steps) & (steps > 0)]
    if not len(steps):
        log.warning("%s: no increasing timestamps; the association uses frame_interval_s = %g s", path, default_s)
        return float(default_s), "config"
    # to the microsecond: a file of 0.1 s steps gives 0.1, not the float noise of its differences
    return round(float(np.median(steps)), 6), f"timestamps/{path.name}"


@dataclass
class WalkingCheckConfig:
    """How the frame interval is checked against the tracked people's walking (module docstring)."""

    walking_speed_mps: float = 1.35
    """A walking adult's typical speed, m/s (pedestrian studies: about 1.2-1.5 m/s)."""
    min_walk_m: float = 0.75
    """A track walks when its straight-line fit carries it at least this far over its frames, metres (its
    centres' own noise is a few decimetres; a low bar keeps the slow walkers of a short stretch in)."""
    min_frames: int = 6
    """Tracks placed on fewer frames are not used."""
    min_tracks: int = 4
    """Fewer walking tracks: no check."""
    max_ratio: float = 1.5
    """Warn when the interval the walks imply differs from the one used by more than this factor (frame
    rates differ by 2x and more: 5, 10, 20, 30 Hz; PedX's labelled frames by about 1.7x from 10 Hz; walkers
    vary: the simulator's CMU-driven ones move 1.5-1.9 m/s, which reads as 1.00-1.35x on the association
    benchmark's 10 Hz inputs)."""


def walking_check(tracks, ground, frame_interval_s: float, config: WalkingCheckConfig | None = None) -> dict:
    """The record of the check (module docstring): ``walking_tracks``, their median ``m_per_frame``, the
    ``implied_interval_s`` and its ``ratio`` to ``frame_interval_s`` (None without enough walking tracks),
    and ``agrees``.  ``tracks``: the association's (``frames[i].world_p`` the centres, None where unplaced);
    ``ground``: the sequence's :class:`~pedx_graph.data.types.GroundFrame` (centres are compared on its
    plane)."""
    config = config or WalkingCheckConfig()
    up = np.asarray(ground.world_up, dtype=float)
    per_frame = []
    for track in tracks:
        placed = [(fr.frame, np.asarray(fr.world_p, dtype=float)) for fr in track.frames if fr.world_p is not None]
        if len(placed) < config.min_frames:
            continue
        frames = np.array([f for f, _ in placed], dtype=float)
        points = np.stack([p for _, p in placed])
        points = points - np.outer(points @ up, up)                  # on the ground plane
        centred = frames - frames.mean()
        velocity = centred @ (points - points.mean(axis=0)) / float(centred @ centred)   # metres per frame
        speed = float(np.linalg.norm(velocity))
        if speed * (frames[-1] - frames[0]) >= config.min_walk_m:
            per_frame.append(speed)
    record = {"frame_interval_s": float(frame_interval_s), "walking_tracks": len(per_frame),
              "m_per_frame": None, "implied_interval_s": None, "ratio": None, "agrees": True}
    if len(per_frame) < config.min_tracks:
        return record
    m_per_frame = float(np.median(per_frame))
    implied = m_per_frame / config.walking_speed_mps
    ratio = implied / frame_interval_s
    record.update(m_per_frame=round(m_per_frame, 4), implied_interval_s=round(implied, 4), ratio=round(ratio, 3),
                  agrees=bool(1 / config.max_ratio <= ratio <= config.max_ratio))
    return record
