"""The whole export of one results folder: meshes, overlays, top views and animations (``export.json``).

``export_results(results, out, dataset)`` reads the fitted SMPL labels (``labels/3d/smpl``), the sequences'
derived ground (``summary.json`` ``ground``; else the dataset's) and, when the dataset is found (``dataset``,
else the ``dataset`` path ``summary.json`` names), its calibration, 2D labels and ``images/``, and writes::

    meshes/<seq>/<seq>_<frame:07d>_<tid>.{ply,obj}       every fitted frame (LiDAR frame by default)
    overlays/<seq>/<cam>/<seq>_<cam>_<frame:07d>.jpg     each camera image a fitted person is in
    topview/<seq>/<seq>_<tid>.png                        each track from above (level frame)
    animation/<seq>/<seq>_<tid>.gif                      each track: overlay crop + top view per frame
    export.json                                          what was written, and why anything was not

Without the dataset there are no overlays and the animations show the top view alone.  Every file is written
atomically; the same inputs give the same bytes.
"""
from __future__ import annotations

import json
import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pedx_graph.data.ground import GroundFrame
from pedx_graph.data.images import image_path, read_image
from pedx_graph.export import animation, meshes, overlays, topview
from pedx_graph.export.camera import Camera, dataset_cameras
from pedx_graph.export.raster import outward_faces
from pedx_graph.utils import atomic_write_bytes, atomic_write_json, encode_image

log = logging.getLogger(__name__)

#: Track colours (BGR), assigned in sorted (sequence, tracking id) order.
PALETTE = ((48, 96, 230), (200, 120, 40), (60, 170, 60), (40, 160, 220), (170, 70, 170), (160, 160, 40),
           (90, 60, 200), (30, 120, 120), (200, 90, 120), (120, 120, 120))
#: Padding around a person's box in the animation crop, as a fraction of the box height.
CROP_PAD = 0.35


@dataclass
class ExportConfig:
    """What ``pedx-graph export`` writes."""

    frame: str = "lidar"
    """Frame of the meshes: ``lidar`` (as the results) or ``world`` (the level frame of the derived ground:
    its z is the up axis derived from the data, ground at z = 0)."""
    formats: tuple[str, ...] = ("ply", "obj")
    """Mesh file formats."""
    meshes: bool = True
    """Write the per-frame meshes."""
    overlays: bool = True
    """Write the overlays on the camera images (needs the dataset)."""
    overlay_every: int = 1
    """Overlay every n-th fitted frame of a sequence (the animations still use every frame)."""
    overlay_scale: float = 1.0
    """Size of the overlays relative to the calibration's image size (images are resized)."""
    top_views: bool = True
    """Write a top view per track."""
    animations: bool = True
    """Write a GIF (MP4 without a GIF encoder) per track."""
    fps: float = 5.0
    """Frames per second of the animations."""
    tracks: tuple[str, ...] = ()
    """Export only these tracking ids (a prefix is enough); empty: every track."""


def resolve_dataset(results: Path, dataset: str | os.PathLike | None, summary: dict) -> Path | None:
    """The dataset folder: ``dataset`` when given (must exist), else the ``dataset`` path recorded in
    ``summary.json`` (as given, or relative to the results' parent) when it exists, else None."""
    if dataset is not None:
        path = Path(dataset)
        if not path.is_dir():
            raise FileNotFoundError(f"{path}: dataset folder not found")
        return path
    recorded = summary.get("dataset")
    if recorded:
        for candidate in (Path(recorded), results.parent / Path(recorded).name):
            if (candidate / "calib").is_dir() or (candidate / "data" / "calib").is_dir():
                return candidate
    return None


def _model(results: Path, model):
    from pedx_graph.body import BodyModel

    if model is not None:
        return model if not isinstance(model, (str, os.PathLike)) else BodyModel.load(model)
    config_path = results / "fit_config.yaml"
    if config_path.is_file():
        import yaml

        name = (yaml.safe_load(config_path.read_text()) or {}).get("body_model") or None
        return BodyModel.load(name)
    return BodyModel.load()


def _matrix(value, shape) -> np.ndarray | None:
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
    return array if array.shape == shape else None


def export_results(results: str | os.PathLike, out: str | os.PathLike | None = None,
                   dataset: str | os.PathLike | None = None, config: ExportConfig | None = None, model=None,
                   progress: bool = False) -> dict:
    """Export a results folder (module docstring) into ``out`` (default ``<results>/export``); returns the
    ``export.json`` record."""
    from pedx_graph.data.reader import read_dataset, read_smpl_labels

    t0 = time.perf_counter()
    config = config or ExportConfig()
    results = Path(results)
    out = Path(out) if out is not None else results / "export"
    summary_path = results / "summary.json"
    summary = json.loads(summary_path.read_text()) if summary_path.is_file() else {}
    labels = read_smpl_labels(results)
    if config.tracks:
        labels = {k: v for k, v in labels.items() if any(k[1].startswith(t) for t in config.tracks)}
        if not labels:
            raise ValueError(f"{results}: no fitted track matches {list(config.tracks)}")
    keys = sorted(labels)
    colours = {key: PALETTE[i % len(PALETTE)] for i, key in enumerate(keys)}
    model = _model(results, model)
    faces = outward_faces(model.forward(np.zeros(72), np.zeros(model.num_betas)).vertices, model.faces)
    grounds = {seq: GroundFrame.from_dict(g) for seq, g in (summary.get("ground") or {}).items()}
    root = resolve_dataset(results, dataset, summary)
    record = {"results": str(results), "dataset": None if root is None else str(root), "frame": config.frame,
              "tracks": [], "files": {"meshes": 0, "overlays": 0, "top_views": 0, "animations": 0}, "notes": []}
    views, cameras = {}, {}
    if root is not None:
        for track in read_dataset(root, sequences=sorted({k[0] for k in keys})):
            grounds.setdefault(track.sequence, track.ground)
            cameras.setdefault(track.sequence, {}).update(dataset_cameras(track.calibrations))
            for fr in track.frames:
                for pair, side, view in fr.labelled_views():
                    cam = next(c.name for c in dataset_cameras({pair: track.calibrations[pair]}).values()
                               if c.side == side)
                    views[(track.sequence, track.tracking_id, fr.frame, cam)] = view
    else:
        record["notes"].append("no dataset found (--dataset): no overlays; animations show the top view only")

    # --- meshes and per-track data -------------------------------------------------------------------
    tracks = {}
    iterator = keys
    if progress:
        from tqdm import tqdm
        iterator = tqdm(keys, desc="export meshes", unit="track")
    for key in iterator:
        labs = labels[key]
        ground = grounds.get(key[0])
        if config.meshes:
            if config.frame == "world" and ground is None:
                raise ValueError(f"{results}: sequence {key[0]} has no derived ground (summary.json 'ground' or "
                                 "--dataset): meshes cannot be written in the level world frame")
            written = meshes.write_track_meshes(out, model, labs, ground, config.frame, config.formats)
            record["files"]["meshes"] += len(written)
        trans = np.stack([np.asarray(lab.trans, float) for lab in labs])
        cov = np.full((len(labs), 3, 3), np.nan)
        for i, lab in enumerate(labs):
            c = _matrix(lab.extra.get("cov_trans"), (3, 3))
            if c is not None:
                cov[i] = c
        tracks[key] = topview.TrackPath(key[0], key[1], [lab.frame for lab in labs], trans, cov, colours[key])
        record["tracks"].append({"sequence": key[0], "tracking_id": key[1], "frames": len(labs)})

    # --- overlays (and the animation crops) ------------------------------------------------------------
    crops: dict[tuple[str, str], dict[int, np.ndarray]] = {key: {} for key in keys}
    anim_camera = {}
    if root is not None and (config.overlays or config.animations):
        anim_camera = _animation_cameras(tracks, cameras, views, model, labels)
        by_frame: dict[tuple[str, int], list[tuple[str, str]]] = {}
        for key in keys:
            for lab in labels[key]:
                by_frame.setdefault((key[0], lab.frame), []).append(key)
        written_frames = {}
        for seq in sorted({k[0] for k in keys}):
            frames = sorted(f for s, f in by_frame if s == seq)
            written_frames[seq] = set(frames[::max(1, int(config.overlay_every))]) if config.overlays else set()
        items = sorted(by_frame.items())
        if progress:
            from tqdm import tqdm
            items = tqdm(items, desc="export overlays", unit="frame")
        for (seq, frame), frame_keys in items:
            people_labels = [(key, next(lab for lab in labels[key] if lab.frame == frame)) for key in frame_keys]
            verts = meshes.track_vertices(model, [lab for _, lab in people_labels])
            for cam_name, camera in sorted(cameras.get(seq, {}).items()):
                wanted = [key for key, _ in people_labels if anim_camera.get(key, (None,))[0] == cam_name]
                write = frame in written_frames[seq]
                if not write and not wanted:
                    continue
                people = []
                for (key, lab), v in zip(people_labels, verts):
                    uv, depth = camera.project(np.asarray(lab.trans, float)[None])
                    label = views.get((seq, key[1], frame, cam_name))
                    inside = depth[0] > 0.5 and 0 <= uv[0, 0] < camera.image_size[0] and \
                        0 <= uv[0, 1] < camera.image_size[1]
                    if not inside and label is None:
                        continue
                    people.append(overlays.PersonInView(
                        key[1], colours[key], v, faces, _matrix(lab.extra.get("keypoints_3d"), (18, 3)),
                        _matrix(lab.extra.get("cov_keypoints_3d"), (18, 3, 3)), label))
                if not people:
                    continue
                image, scale = _image(root, seq, cam_name, frame, camera, config.overlay_scale)
                title = f"{seq} {cam_name} frame {frame}" + ("" if image[1] else " (no image: blank canvas)")
                drawn = overlays.draw_overlay(image[0], camera, people, scale, title)
                if write:
                    atomic_write_bytes(out / "overlays" / seq / cam_name / f"{seq}_{cam_name}_{frame:07d}.jpg",
                                       encode_image(drawn, ".jpg"))
                    record["files"]["overlays"] += 1
                for key in wanted:
                    box = anim_camera[key][1] * scale
                    lo, hi = np.floor(box[0]).astype(int), np.ceil(box[1]).astype(int)
                    lo = np.clip(lo, 0, [drawn.shape[1] - 1, drawn.shape[0] - 1])
                    hi = np.clip(hi, lo + 1, [drawn.shape[1], drawn.shape[0]])
                    crops[key][frame] = animation.fit_height(drawn[lo[1]:hi[1], lo[0]:hi[0]],
                                                             animation.FRAME_HEIGHT_PX)

    # --- top views and animations ----------------------------------------------------------------------
    for key in keys:
        ground = grounds.get(key[0])
        if ground is None:
            record["notes"].append(f"{key[0]}: no derived ground (summary.json 'ground' or --dataset): "
                                   "no top view or animation")
            continue
        path = tracks[key]
        mid = len(path.frames) // 2
        if config.top_views:
            foot = meshes.track_vertices(model, [labels[key][mid]])[0]
            image = topview.render_top_view(path, ground, mid, foot)
            atomic_write_bytes(out / "topview" / key[0] / f"{key[0]}_{key[1]}.png", encode_image(image, ".png"))
            record["files"]["top_views"] += 1
        if config.animations:
            frames = []
            verts = meshes.track_vertices(model, labels[key])
            for i, frame in enumerate(path.frames):
                top = topview.render_top_view(path, ground, i, verts[i], size_px=animation.FRAME_HEIGHT_PX)
                crop = crops[key].get(frame)
                frames.append(animation.compose([crop, top] if crop is not None else [top]))
            written = animation.write_animation(out / "animation" / key[0] / f"{key[0]}_{key[1]}.gif", frames,
                                                config.fps)
            record["files"]["animations"] += 1
            record.setdefault("animation_format", written.suffix[1:])
    record["seconds"] = round(time.perf_counter() - t0, 3)
    atomic_write_json(out / "export.json", {k: v for k, v in record.items() if k != "seconds"})
    return record


def _image(root: Path, seq: str, cam: str, frame: int, camera: Camera, overlay_scale: float):
    """((image, True) read from ``images/`` or (blank canvas, False)), and its scale over the calibration."""
    import cv2

    image = read_image(image_path(root, seq, cam, frame))
    if image is None:
        return (overlays.blank_canvas(camera.image_size, overlay_scale), False), overlay_scale
    if overlay_scale != 1.0:
        size = tuple(max(1, int(round(v * overlay_scale))) for v in (image.shape[1], image.shape[0]))
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    return (image, True), image.shape[1] / camera.image_size[0]


def _animation_cameras(tracks: dict, cameras: dict, views: dict, model, labels: dict) -> dict:
    """Per track: (the camera labelling it in the most frames, else seeing its ``trans`` in the most frames,
    (2, 2) crop box in the calibration's pixels: the union of its keypoints' boxes, padded)."""
    out = {}
    for key, path in tracks.items():
        best, best_count = None, 0
        for cam_name, camera in sorted(cameras.get(key[0], {}).items()):
            labelled = sum((key[0], key[1], f, cam_name) in views for f in path.frames)
            uv, depth = camera.project(path.world_trans)
            w, h = camera.image_size
            seen = int(np.sum((depth > 0.5) & (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)))
            count = 1000 * labelled + seen
            if count > best_count:
                best, best_count = cam_name, count
        if best is None:
            continue
        camera = cameras[key[0]][best]
        kp = np.stack([np.asarray(lab.extra["keypoints_3d"], float) if "keypoints_3d" in lab.extra
                       else np.asarray(model.keypoints(lab.pose, lab.betas, lab.trans)) for lab in labels[key]])
        uv, depth = camera.project(kp.reshape(-1, 3))
        uv = uv[depth > 0.5]
        if not len(uv):
            continue
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        pad = CROP_PAD * max(hi[1] - lo[1], 1.0)
        out[key] = (best, np.stack([lo - pad, hi + pad]))
    return out
