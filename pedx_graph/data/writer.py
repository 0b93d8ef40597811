"""Write the release layout: results (SMPL labels), and the inputs the simulator produces.

Every file is written atomically (temporary file + rename).  ``root`` is the dataset folder that holds
(or will hold) ``labels/`` and ``calib/``; when ``root/data/labels`` exists and ``root/labels`` does not,
``root/data`` is used, mirroring :func:`pedx_graph.data.reader.resolve_root`.
"""
from __future__ import annotations

import os
from collections import defaultdict
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from pedx_graph.data.calib import split_pair, write_stereo_calibration
from pedx_graph.data.labels2d import Label2D, write_label2d
from pedx_graph.data.ply import pointcloud_path, segment_path, write_ply_points
from pedx_graph.data.reader import timestamps_path
from pedx_graph.data.smpl_labels import N_BETAS, write_smpl_label
from pedx_graph.data.types import SmplLabel, StereoCalibration, Track
from pedx_graph.utils import atomic_write_text

__all__ = [
    "output_root", "write_results", "write_label2d", "write_segment", "write_scene_points",
    "write_calibration", "write_timestamps", "write_tracks",
]


def output_root(root: str | os.PathLike) -> Path:
    """The folder to write ``labels/`` into: ``root``, or ``root/data`` when only that holds ``labels/``."""
    root = Path(root)
    if not (root / "labels").is_dir() and (root / "data" / "labels").is_dir():
        return root / "data"
    return root


def write_results(root: str | os.PathLike, labels: Iterable[SmplLabel],
                  n_betas: int | None = N_BETAS) -> list[Path]:
    """Write SMPL labels to ``labels/3d/smpl/<seq>/<seq>_<frame:07d>_<tid>.json``; returns the paths.

    ``extra`` fields go to top-level keys.  Each label is validated (lengths, finite) before writing.
    """
    root = output_root(root)
    return [write_smpl_label(root, label, n_betas=n_betas) for label in labels]


def write_segment(root: str | os.PathLike, sequence: str, frame: int, tracking_id: str,
                  world_points: np.ndarray, dtype: str = "float64") -> Path:
    """Write one instance's (N, 3) LiDAR points (world frame, metres) as a binary segment PLY."""
    return write_ply_points(segment_path(output_root(root), sequence, frame, tracking_id), world_points,
                            binary=True, dtype=dtype)


def write_scene_points(root: str | os.PathLike, sequence: str, frame: int, world_points: np.ndarray,
                       dtype: str = "float32") -> Path:
    """Write a frame's full (N, 3) LiDAR scene to ``pointclouds/<seq>/<seq>_<frame:07d>.ply``."""
    return write_ply_points(pointcloud_path(output_root(root), sequence, frame), world_points,
                            binary=True, dtype=dtype)


def write_calibration(root: str | os.PathLike, calib: StereoCalibration,
                      right_rect_R_cam: np.ndarray | None = None) -> tuple[Path, Path]:
    """Write ``calib/calib_cam_to_cam_<pair>.txt`` and ``calib/calib_cam_to_range_<left>.txt``."""
    return write_stereo_calibration(output_root(root) / "calib", calib, right_rect_R_cam)


def write_timestamps(root: str | os.PathLike, sequence: str, frame_seconds: dict[int, float],
                     kind: str = "pointclouds") -> Path:
    """Write ``timestamps/timestamps-<kind>-<seq>.txt`` as ``frame seconds`` lines, sorted by frame."""
    lines = []
    for frame in sorted(frame_seconds):
        value = float(frame_seconds[frame])
        if not np.isfinite(value):
            raise ValueError(f"timestamp of frame {frame} is not finite")
        lines.append(f"{int(frame)} {value!r}")
    return atomic_write_text(timestamps_path(output_root(root), sequence, kind), "\n".join(lines) + "\n")


def write_tracks(root: str | os.PathLike, tracks: Iterable[Track], flat: bool = False,
                 timestamps: bool = True, category: str = "pedestrian") -> list[Path]:
    """Write tracks in the release layout: calibration, 2D labels, segments and (optionally) timestamps.

    Each view of every pair (``TrackFrame.labelled_views``) becomes a 2D label of its pair's left or right
    camera (``flat``: no camera folder); a frame's LiDAR points become its segment PLY (none written when
    empty).  Timestamps of all tracks of
    a sequence are merged into one file; two tracks disagreeing on a frame's time raise ``ValueError``.
    Returns the written paths.
    """
    root = output_root(root)
    written: list[Path] = []
    calibrations: dict[str, StereoCalibration] = {}
    times: dict[str, dict[int, float]] = defaultdict(dict)
    for track in tracks:
        for name, calib in track.calibrations.items():
            if name not in calibrations:
                calibrations[name] = calib
                written.extend(write_calibration(root, calib))
        for tf in track.frames:
            for pair in tf.pairs:
                if pair not in track.calibrations:
                    raise ValueError(f"track {track.tracking_id} frame {tf.frame}: pair {pair!r} has no calibration")
            for pair, side, view in tf.labelled_views():
                camera = split_pair(pair)[0 if side == "left" else 1]
                label = Label2D(sequence=track.sequence, camera=camera, frame=tf.frame,
                                tracking_id=track.tracking_id, category=category, view=view)
                written.append(write_label2d(root, label, flat=flat))
            if len(tf.world_lidar_points):
                written.append(write_segment(root, track.sequence, tf.frame, track.tracking_id,
                                             tf.world_lidar_points))
            seq_times = times[track.sequence]
            previous = seq_times.setdefault(tf.frame, float(tf.timestamp))
            if not np.isclose(previous, tf.timestamp, rtol=0.0, atol=1e-9):
                raise ValueError(f"sequence {track.sequence} frame {tf.frame}: tracks disagree on the "
                                 f"timestamp ({previous} vs {tf.timestamp})")
    if timestamps:
        for sequence, frame_seconds in times.items():
            written.append(write_timestamps(root, sequence, frame_seconds))
    return written
