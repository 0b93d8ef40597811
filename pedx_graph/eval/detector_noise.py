"""A simulated 2D detector (paper Table V): turn a dataset's clean 2D labels into detector-like labels.

The paper replaces the annotators' 2D labels with an automatic detector's and refits.  We mimic a detector's
typical failures on a copy of a dataset with the noise model of :mod:`pedx_graph.data.detector_model`
(keypoint noise growing with the person's image height, misses, left/right swaps, outliers, polygon errors),
per labelled instance and image.  ``uv_0``, the keypoints the noise is added to, is the exact projection of
the true 3D keypoint when the dataset carries the simulator's ``truth/`` (so the detector's noise replaces the
annotator's), else the clean label.  The LiDAR segment of each instance is then re-cut from the full sweep
with the noisy left-image polygons (points in front of the camera projecting inside,
:mod:`pedx_graph.data.segment_cut`), as the paper's labelling does.

Every draw comes from one generator seeded by ``(seed, file index)`` in sorted file order, so a run is
reproducible from its seed.  The ``visible`` flags are kept (a detector's confidence threshold).
"""
from __future__ import annotations

import logging
import os
import shutil
from pathlib import Path

import numpy as np

from pedx_graph.data.detector_model import (SWAP_PAIRS, DetectorNoiseConfig,  # noqa: F401  (the model's home)
                                            corrupt_keypoints, corrupt_polygon, instance_height_px)

log = logging.getLogger(__name__)


def _truth_keypoints(root: Path, sequence: str, frame: int, cache: dict) -> dict:
    key = (sequence, frame)
    if key not in cache:
        cache.clear()
        path = root / "truth" / sequence / f"{sequence}_{frame:07d}.npz"
        found = {}
        if path.is_file():
            with np.load(path) as npz:
                found = {name.split("__", 1)[1]: np.asarray(npz[name], dtype=float)
                         for name in npz.files if name.startswith("keypoints__")}
        cache[key] = found
    return cache[key]


def _link_or_copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def make_noisy_dataset(src: str | os.PathLike, dst: str | os.PathLike, config: DetectorNoiseConfig | None = None,
                       seed: int = 0) -> dict:
    """Copy dataset ``src`` to ``dst`` with detector-like 2D labels (and re-cut segments); returns counts.

    Calibration, timestamps, point clouds, SMPL labels and ``truth/`` are linked (or copied) unchanged; every
    2D label file is rewritten.  ``dst`` must not hold labels yet.
    """
    from pedx_graph.data.calib import read_calibrations
    from pedx_graph.data.labels2d import Label2D, iter_label2d_files, read_label2d, write_label2d
    from pedx_graph.data.reader import camera_sides, list_sequences, read_scene_points, resolve_root
    from pedx_graph.data.types import View2D
    from pedx_graph.data.writer import write_segment
    from pedx_graph.data.segment_cut import depth_gate, segment_indices_from_projection

    config = config or DetectorNoiseConfig()
    src, dst = resolve_root(src), Path(dst)
    if (dst / "labels" / "2d").exists():
        raise FileExistsError(f"{dst}: already holds labels/2d")
    for sub in ("calib", "timestamps", "pointclouds", "truth", "labels/3d/smpl"):
        base = src / sub
        if base.is_dir():
            for path in sorted(p for p in base.rglob("*") if p.is_file()):
                _link_or_copy(path, dst / sub / path.relative_to(base))
    calibs = read_calibrations(src / "calib")
    sides = camera_sides(calibs)
    counts = {"labels": 0, "keypoints_in": 0, "keypoints_out": 0, "swapped_pairs": 0, "segments": 0,
              "segment_points": 0, "from_truth": 0}
    truth_cache: dict = {}
    file_index = 0
    for seq in list_sequences(src):
        left_polygons: dict[tuple[int, str], list[tuple[str, np.ndarray]]] = {}
        for path, camera, frame, tid in iter_label2d_files(src, seq):
            rng = np.random.default_rng([int(seed), file_index])
            file_index += 1
            label = read_label2d(path, seq, camera, frame, tid)
            if camera not in sides:
                continue
            pair, side = sides[camera]
            calib = calibs[pair]
            view = label.view
            labelled = view.labelled
            uv0 = np.where(labelled[:, None], view.keypoints, 0.0)
            truth = _truth_keypoints(src, seq, frame, truth_cache) if config.use_truth else {}
            if tid in truth:
                left_uv, right_uv = calib.project(truth[tid])
                uv0 = left_uv if side == "left" else right_uv
                counts["from_truth"] += 1
            height = instance_height_px(view.keypoints, view.polygon)
            pts = view.polygon if view.polygon is not None else view.keypoints[labelled]
            box = (pts.min(axis=0), pts.max(axis=0)) if len(pts) else (np.zeros(2), np.zeros(2))
            uv, vis = corrupt_keypoints(uv0, labelled, view.visible, height, box, config, rng, calib.image_size)
            polygon = None
            if view.polygon is not None:
                polygon = corrupt_polygon(view.polygon, height, config, rng, calib.image_size)
                if side == "left":
                    left_polygons.setdefault((frame, tid), []).append((pair, polygon))
            counts["labels"] += 1
            counts["keypoints_in"] += int(labelled.sum())
            counts["keypoints_out"] += int(np.all(np.isfinite(uv), axis=1).sum())
            write_label2d(dst, Label2D(sequence=seq, camera=camera, frame=frame, tracking_id=tid,
                                       category=label.category, subtype=label.subtype, frame_id=label.frame_id,
                                       view=View2D(keypoints=uv, visible=vis, polygon=polygon)))
        if not config.resegment:
            seg_dir = src / "labels" / "3d" / "segment" / seq
            if seg_dir.is_dir():
                for path in sorted(seg_dir.glob("*.ply")):
                    _link_or_copy(path, dst / "labels" / "3d" / "segment" / seq / path.name)
            continue
        by_frame: dict[int, list] = {}
        for (frame, tid), polys in left_polygons.items():
            by_frame.setdefault(frame, []).append((tid, polys))
        for frame in sorted(by_frame):
            try:
                scene = read_scene_points(src, seq, frame)
            except Exception as exc:  # no sweep: keep the clean segments of this frame
                log.warning("%s frame %d: no full sweep (%s); segments kept", seq, frame, exc)
                continue
            projected = {}
            for tid, polys in sorted(by_frame[frame]):
                index = []
                for pair, polygon in polys:
                    if pair not in projected:
                        calib = calibs[pair]
                        projected[pair] = (calib.project(scene)[0], calib.world_to_rect(scene)[:, 2])
                    uv, depth = projected[pair]
                    index.append(segment_indices_from_projection(uv, depth, polygon))
                idx = np.unique(np.concatenate(index)) if index else np.zeros(0, dtype=np.int64)
                idx = depth_gate(idx, scene, config.segment_depth_gate_m)
                if len(idx):
                    write_segment(dst, seq, frame, tid, scene[idx])
                    counts["segments"] += 1
                    counts["segment_points"] += int(len(idx))
    return counts
