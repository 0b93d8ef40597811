"""A simulated 2D detector (paper Table V): turn a dataset's clean 2D labels into detector-like labels.

The paper replaces the annotators' 2D labels with an automatic detector's and refits.  We mimic a detector's
typical failures on a copy of a dataset, per labelled instance and image (pixels; ``h`` = the instance's
image height, the vertical extent of its polygon, else of its keypoints):

* keypoint noise grows with the person's size: ``uv = uv_0 + n``, ``n ~ N(0, s^2 I2)``,
  ``s = sqrt(sigma_px^2 + (sigma_height_frac * h)^2)``, times ``occluded_sigma_factor`` for joints labelled
  not visible.  ``uv_0`` is the exact projection of the true 3D keypoint when the dataset carries the
  simulator's ``truth/`` (so the detector's noise replaces the annotator's), else the clean label;
* missed joints: a visible joint is dropped with probability ``miss_prob_visible``, an occluded one with
  ``miss_prob_occluded``;
* left/right swaps: each left/right pair (eyes, shoulders, elbows, wrists, hips, knees, ankles) is swapped
  with probability ``swap_prob`` (the classic detector confusion on people seen from behind or the side);
* gross outliers: with probability ``outlier_prob`` a joint lands uniformly inside the instance's box;
* polygon errors: the silhouette polygon is scaled about its centroid by ``1 + N(0, polygon_scale_sigma^2)``,
  shifted by ``N(0, (polygon_shift_frac * h)^2)`` per axis and its vertices jittered by
  ``polygon_vertex_noise_px``; the LiDAR segment of the instance is then re-cut from the full sweep with the
  noisy left-image polygons (points in front of the camera projecting inside), as the paper's labelling does.

Every draw comes from one generator seeded by ``(seed, file index)`` in sorted file order, so a run is
reproducible from its seed.  The ``visible`` flags are kept (a detector's confidence threshold).
"""
from __future__ import annotations

import logging
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pedx_graph.keypoints import PEDX_KEYPOINTS

log = logging.getLogger(__name__)

#: Left/right keypoint pairs a detector can swap.
SWAP_PAIRS: tuple[tuple[str, str], ...] = (("leye", "reye"), ("lsho", "rsho"), ("lelb", "relb"),
                                           ("lwri", "rwri"), ("lhip", "rhip"), ("lknee", "rknee"),
                                           ("lankl", "rankl"))


@dataclass
class DetectorNoiseConfig:
    """How the simulated detector corrupts clean 2D labels (pixels unless stated)."""

    sigma_px: float = 3.0
    """Size-independent part of the keypoint noise (per axis), pixels."""
    sigma_height_frac: float = 0.015
    """Size-dependent part: this fraction of the instance's image height (per axis)."""
    occluded_sigma_factor: float = 2.5
    """Joints labelled not visible get this many times the noise."""
    miss_prob_visible: float = 0.05
    """Probability that a visible joint is not detected."""
    miss_prob_occluded: float = 0.4
    """Probability that an occluded (labelled, not visible) joint is not detected."""
    swap_prob: float = 0.05
    """Probability that a left/right pair is swapped (per pair, per instance and image)."""
    outlier_prob: float = 0.02
    """Probability that a joint is a gross outlier (uniform inside the instance's box)."""
    polygon_scale_sigma: float = 0.06
    """Std. dev. of the relative scale error of the polygon about its centroid."""
    polygon_shift_frac: float = 0.03
    """Std. dev. of the polygon's shift (per axis), fraction of the instance's image height."""
    polygon_vertex_noise_px: float = 3.0
    """Std. dev. of the extra noise on every polygon vertex, pixels."""
    use_truth: bool = True
    """Start from the exact projections of the simulator's true keypoints when ``truth/`` exists."""
    resegment: bool = True
    """Re-cut the LiDAR segments from the full sweeps (``pointclouds/``) with the noisy left polygons."""
    segment_depth_gate_m: float = 1.5
    """Far-side depth gate applied to the re-cut segments (as the simulator's
    ``labels.segment_depth_gate_m``), metres; 0 disables it."""


_IDX = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}


def instance_height_px(keypoints: np.ndarray, polygon: np.ndarray | None) -> float:
    """Vertical image extent of an instance, pixels: of its polygon, else of its labelled keypoints."""
    pts = polygon if polygon is not None and len(polygon) >= 3 else keypoints[np.all(np.isfinite(keypoints), 1)]
    if len(pts) < 2:
        return 0.0
    return float(np.ptp(pts[:, 1]))


def corrupt_keypoints(uv0: np.ndarray, labelled: np.ndarray, visible: np.ndarray, height_px: float,
                      box: tuple[np.ndarray, np.ndarray], config: DetectorNoiseConfig,
                      rng: np.random.Generator, image_size: tuple[int, int],
                      swap_index: tuple[tuple[int, int], ...] | None = None,
                      sigma_scale: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Detector keypoints of one instance in one image.

    ``uv0`` (K, 2) noise-free (or clean) pixels, ``labelled`` / ``visible`` (K,) bool, ``box`` (lo, hi)
    the instance's pixel box.  Returns ((K, 2) pixels with NaN = not detected, (K,) visible flags).
    K = 18 (PEDX_KEYPOINTS) unless another keypoint set is given by ``swap_index`` (its left/right index
    pairs) and ``sigma_scale`` ((K,) factor on each keypoint's noise; None = 1).
    Draws are made for every joint in a fixed order whatever the flags (reproducible from the seed).
    """
    n = len(uv0)
    if swap_index is None:
        swap_index = tuple((_IDX[a], _IDX[b]) for a, b in SWAP_PAIRS)
    unit = rng.normal(size=(n, 2))
    miss_draw = rng.random(n)
    swap_draw = rng.random(len(swap_index))
    outlier_draw = rng.random(n)
    outlier_pos = rng.random((n, 2))
    sigma = np.hypot(config.sigma_px, config.sigma_height_frac * height_px)
    sigmas = np.where(visible, sigma, sigma * config.occluded_sigma_factor)
    if sigma_scale is not None:
        sigmas = sigmas * np.asarray(sigma_scale, dtype=float)
    uv = np.asarray(uv0, dtype=float) + sigmas[:, None] * unit
    lo, hi = box
    outlier = outlier_draw < config.outlier_prob
    uv[outlier] = lo + outlier_pos[outlier] * (hi - lo)
    vis = np.asarray(visible, dtype=bool).copy()
    lab = np.asarray(labelled, dtype=bool).copy()
    for (ia, ib), draw in zip(swap_index, swap_draw):
        if draw < config.swap_prob:
            uv[[ia, ib]] = uv[[ib, ia]]
            vis[[ia, ib]] = vis[[ib, ia]]
            lab[[ia, ib]] = lab[[ib, ia]]
    missed = miss_draw < np.where(vis, config.miss_prob_visible, config.miss_prob_occluded)
    lab &= ~missed
    width, height = image_size
    uv[:, 0] = np.clip(uv[:, 0], 0.0, width - 1e-3)
    uv[:, 1] = np.clip(uv[:, 1], 0.0, height - 1e-3)
    uv[~lab] = np.nan
    return uv, vis & lab


def corrupt_polygon(polygon: np.ndarray, height_px: float, config: DetectorNoiseConfig,
                    rng: np.random.Generator, image_size: tuple[int, int]) -> np.ndarray:
    """(K, 2) polygon scaled about its centroid, shifted and jittered (see the module docstring)."""
    polygon = np.asarray(polygon, dtype=float)
    scale = 1.0 + config.polygon_scale_sigma * rng.normal()
    shift = config.polygon_shift_frac * height_px * rng.normal(size=2)
    jitter = config.polygon_vertex_noise_px * rng.normal(size=polygon.shape)
    centre = polygon.mean(axis=0)
    out = centre + max(scale, 0.2) * (polygon - centre) + shift + jitter
    width, height = image_size
    out[:, 0] = np.clip(out[:, 0], 0.0, float(width))
    out[:, 1] = np.clip(out[:, 1], 0.0, float(height))
    return out


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
