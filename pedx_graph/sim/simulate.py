"""Run the simulator: build the scene, move the people, sweep the LiDAR, label the images, write the release.

Output layout (``out_dir``; the PedX release layout, see the pedx-format notes, plus ``truth/``)::

    calib/calib_cam_to_cam_<left>-<right>.txt, calib/calib_cam_to_range_<left>.txt
    labels/2d/<seq>/<cam>/<seq>_<cam>_<frame:07d>_<tid>.json    one per labelled instance per image
    labels/3d/segment/<seq>/<seq>_<frame:07d>_<tid>.ply        polygon-assigned LiDAR points (left images)
    labels/3d/smpl/<seq>/<seq>_<frame:07d>_<tid>.json          ground-truth SMPL, output (LiDAR) frame
    pointclouds/<seq>/<seq>_<frame:07d>.ply                    full sweep (lost returns as inf points)
    timestamps/timestamps-{pointclouds,images}-<seq>.txt       ``frame seconds`` lines
    truth/meta.json                                            objects, walkways, people, seed, frames, ground
    truth/<seq>/<seq>_<frame:07d>.npz                          per-frame exact quantities (below)
    truth/<seq>/<seq>_<frame:07d>.json                         per-frame, per-person visibility summary
    detections/..., truth/detections/<seq>/<format>.json     detector files on raw images, when
                                                               ``detections.formats`` is set (:mod:`pedx_graph.sim.detections`)
    sim_config.yaml                                            resolved config (``# seed: S`` first line)
    summary.json                                               counts (no wall-clock times: byte-stable)

Frames: the simulation runs in the sim frame (+z against gravity, LiDAR at the origin); every written 3D quantity (calib
``world_T_cam``, clouds, segments, SMPL labels, truth points, keypoints and joints) is in the output frame,
``output_p = output_T_sim @ sim_p`` (:class:`~pedx_graph.sim.config.OutputFrameConfig`; identity for the
default rig).  ``truth/meta.json`` records ``output_T_sim`` (4x4), ``world_p_lidar`` (the LiDAR's centre) and
``ground`` = ``{"world_up", "ground_offset_m"}`` (the ground plane ``world_up . p = ground_offset_m``), all in
the output frame; ``ground_z`` and ``walkways`` are in the sim frame.  SMPL labels are moved as in
:func:`pedx_graph.data.transform.transform_smpl`.

Per-frame truth NPZ keys (``<tid>`` = tracking id): ``scene_points`` (N, 3) float32 = the finite points of
the scene PLY in order, ``scene_object_id`` (N,) int32 = object id hit by each point (``truth/meta.json``
maps ids to objects), ``scene_true_range`` (N,) float32 (noise-free range);
``segment_index__<tid>`` (M,) int32 = rows of ``scene_points`` written to that instance's segment PLY (same
order), ``segment_is_person__<tid>`` (M,) bool = the point really comes from that person (exact
membership); ``keypoints__<tid>`` (18, 3) and ``joints__<tid>`` (24, 3) world positions of every present
pedestrian.

Per-frame truth JSON: ``people.<tid>`` = ``distance_m`` (horizontal, LiDAR to pelvis),
``n_lidar_points_on_person`` (sweep points whose ray hit the person), ``labelled``, ``n_segment_points``,
``n_segment_points_on_person``, and ``views.<camera>`` = ``in_image`` (keypoints projecting into the
image), ``visible_area_px`` (visible silhouette area), ``n_visible``, ``labelled`` and ``visible`` (18
characters ``0``/``1``: true visibility of each PEDX_KEYPOINTS joint) for the images where it was labelled,
``quirk`` (``polygon_only`` / ``missing_keypoint``) where a file quirk was applied, ``suppressed: true`` where
a labelable view was left out because the track is labelled in one camera only.

Same seed and config -> byte-identical files (NPZ members carry a fixed timestamp).
"""
from __future__ import annotations

import json
import logging
import shutil
import time
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from pedx_graph.config import to_dict
from pedx_graph.data.labels2d import Label2D, label2d_path, label2d_to_json
from pedx_graph.data.npzfile import npz_bytes
from pedx_graph.data.smpl_labels import smpl_label_path, smpl_label_to_json
from pedx_graph.data.types import SmplLabel, StereoCalibration
from pedx_graph.data.transform import transform_points, transform_smpl
from pedx_graph.data.writer import write_calibration, write_scene_points, write_segment, write_timestamps
from pedx_graph.sim import cameras, labels, lidar
from pedx_graph.sim.config import SimConfig
from pedx_graph.sim.pedestrians import Pedestrian, plan_pedestrians
from pedx_graph.sim.scene import RayScene, StaticScene, build_scene, outward_faces, retime_moving_cars
from pedx_graph.utils import atomic_write_bytes, atomic_write_json, atomic_write_text

logger = logging.getLogger(__name__)


def write_json_compact(path: Path, obj) -> Path:
    """Atomic compact JSON (C encoder; ``obj`` must hold only plain Python types)."""
    return atomic_write_bytes(path, (json.dumps(obj, separators=(",", ":")) + "\n").encode("utf-8"))


def write_label2d(root: Path, label: Label2D) -> Path:
    """A 2D label file in the release layout (the data package's JSON object, written compact)."""
    path = label2d_path(root, label.sequence, label.camera, label.frame, label.tracking_id)
    return write_json_compact(path, label2d_to_json(label))


def write_smpl(root: Path, label: SmplLabel) -> Path:
    """An SMPL label file in the release layout (the data package's JSON object, written compact)."""
    return write_json_compact(smpl_label_path(root, label.sequence, label.frame, label.tracking_id),
                              smpl_label_to_json(label))


@dataclass
class _ViewLabel:
    camera: str
    side: str
    uv: np.ndarray
    visible: np.ndarray
    polygon: np.ndarray
    n_visible_true: int
    area_px: float


def _label_person_in_view(ray_scene: RayScene, view: cameras.CameraView, person: Pedestrian,
                          vertices: np.ndarray, keypoints: np.ndarray, config: SimConfig,
                          rng: np.random.Generator, v_shift_px: float = 0.0) -> tuple[_ViewLabel | None, dict]:
    """Label one person in one image, or None when it is not labelable there; plus a truth record.

    ``v_shift_px``: added to the v of every click and polygon vertex (a right image's rectification error)."""
    lab = config.labels
    uv_true, depth = view.project(keypoints)
    in_image = view.in_image(uv_true) & (depth > 0.5)
    record = {"in_image": int(in_image.sum())}
    if not in_image.any():
        return None, record
    sil = cameras.visible_silhouette(ray_scene, view, person.object_id, vertices, lab.id_buffer_max_cells)
    area = 0.0 if sil is None else sil.area_px
    record["visible_area_px"] = round(area, 1)
    if sil is None or area < lab.min_visible_pixels:
        return None, record
    visible = cameras.point_visibility(ray_scene, view, keypoints, lab.visibility_tolerance_m) & in_image
    record["n_visible"] = int(visible.sum())
    if visible.sum() < lab.min_visible_keypoints:
        return None, record
    polygon = cameras.silhouette_polygon(sil, lab.polygon_epsilon_px)
    if polygon is None:
        return None, record
    uv, vis = labels.keypoint_labels(uv_true, visible, in_image, lab, rng, view.calib.image_size, v_shift_px)
    polygon = labels.noisy_polygon(polygon, lab, rng, view.calib.image_size, v_shift_px)
    record.update(labelled=True, visible="".join("1" if v else "0" for v in visible))
    return _ViewLabel(view.camera, view.side, uv, vis, polygon, int(visible.sum()), area), record


#: Counters of a run (summed over frames).
COUNT_KEYS = ("labels_2d", "segments", "smpl_labels", "segment_points", "segment_points_on_person",
              "lidar_points", "person_lidar_points", "polygon_only_files", "missing_keypoint_files")


@dataclass
class _FrameContext:
    """What every frame needs (built once by :func:`simulate`; pickled once to each worker process)."""

    out: Path
    config: SimConfig
    seed: int
    scene: object
    calibs: dict
    people: list
    body_model: object
    faces: np.ndarray
    directions: np.ndarray
    views: list
    viewpoints: np.ndarray
    output_T_sim: np.ndarray
    """(4, 4) sim frame -> output frame (every written 3D quantity goes through it)."""
    v_shift_px: dict
    """Camera name -> shift added to the v of its clicks (right cameras: ``-vertical_disparity_px``)."""
    label_cameras: dict
    """Tracking id -> the one camera a one-camera track is labelled in (absent: every camera)."""
    bystanders: frozenset = frozenset()
    """Tracking ids never labelled (``labels.unlabelled_prob``)."""


_WORKER_CONTEXT: _FrameContext | None = None


_UNGUARDED = ("simulate(workers={workers}): {what}; spawned workers import the calling script again, which "
              "cannot start them without an 'if __name__ == \"__main__\":' guard (or use workers=1)")


def _importing_main_in_worker() -> bool:
    """True in a spawned worker while it imports the parent's main script (what multiprocessing itself checks
    before it starts a process: the script was run again without a ``__main__`` guard)."""
    import multiprocessing
    return bool(getattr(multiprocessing.current_process(), "_inheriting", False))


def _init_worker(ctx_path: str) -> None:
    """A worker's start: the frame context from the file the parent pickled it to (a large argument written
    down the spawn pipe would leave the parent blocked for ever if the worker died before reading it)."""
    import pickle
    global _WORKER_CONTEXT
    with open(ctx_path, "rb") as f:
        _WORKER_CONTEXT = pickle.load(f)


def _frame_in_worker(k: int) -> dict:
    return _simulate_frame(_WORKER_CONTEXT, k)


def frame_rngs(seed: int, k: int) -> tuple[np.random.Generator, np.random.Generator]:
    """The (LiDAR, labelling) random generators of frame index ``k``: independent of the worker count."""
    return np.random.default_rng([int(seed), 1, int(k)]), np.random.default_rng([int(seed), 2, int(k)])


def quirk_rng(seed: int, k: int) -> np.random.Generator:
    """The generator of frame index ``k``'s file quirks (separate: quirks never change the other draws)."""
    return np.random.default_rng([int(seed), 4, int(k)])


def _pair_of_camera(calibs: dict) -> dict[str, tuple[str, str]]:
    """Camera name -> (pair name, side)."""
    out = {}
    for name in calibs:
        left, right = name.split("-")
        out[left], out[right] = (name, "left"), (name, "right")
    return out


def _simulate_frame(ctx: _FrameContext, k: int) -> dict:
    """Simulate and write frame index ``k`` (scene PLY, labels, segments, SMPL, truth); returns its counts and
    its labelled instances (``instances``: ``[tid, distance_m, [cameras]]``)."""
    config, out, calibs = ctx.config, ctx.out, ctx.calibs
    sc = config.scene
    seq = sc.sequence
    lidar_rng, label_rng = frame_rngs(ctx.seed, k)
    file_rng = quirk_rng(ctx.seed, k)
    camera_pair = _pair_of_camera(calibs)
    counts = dict.fromkeys(COUNT_KEYS, 0)
    instances = []
    time_s = k / sc.fps
    frame = sc.first_frame + k
    meshes = ctx.scene.meshes_at(time_s)
    present = [p for p in ctx.people if p.present[k]]
    bodies = {}
    for person in present:
        body = ctx.body_model.forward(person.pose[k], person.betas, person.trans[k])
        bodies[person.tracking_id] = body
        meshes.append((person.object_id, body.vertices, ctx.faces))
    ray_scene = RayScene(meshes, ctx.viewpoints)
    sweep = lidar.sweep(ray_scene, config.lidar, lidar_rng, ctx.directions)
    scene_points = sweep.world_points
    out_points = transform_points(ctx.output_T_sim, scene_points)
    ply_points = out_points
    if config.lidar.write_dropouts_as_inf and sweep.n_dropped:
        ply_points = np.concatenate([out_points, np.full((sweep.n_dropped, 3), np.inf)])
    lidar_frame = k % config.lidar.every_n_frames == 0
    if lidar_frame:
        write_scene_points(out, seq, frame, ply_points)
        counts["lidar_points"] += len(scene_points)

    truth_arrays = {"scene_points": out_points.astype(np.float32),
                    "scene_object_id": sweep.object_id.astype(np.int32),
                    "scene_true_range": sweep.true_range_m.astype(np.float32)}
    truth_people = {}
    projection = {}
    labelled_tids: set[str] = set()
    for person in present:
        tid = person.tracking_id
        body = bodies[tid]
        pelvis_xy = person.world_pelvis_xy[k]
        distance = float(np.hypot(*pelvis_xy))
        n_person_points = int((sweep.object_id == person.object_id).sum())
        counts["person_lidar_points"] += n_person_points
        record = {"distance_m": round(distance, 3), "n_lidar_points_on_person": n_person_points,
                  "views": {}}
        truth_arrays[f"keypoints__{tid}"] = transform_points(ctx.output_T_sim, body.keypoints)
        truth_arrays[f"joints__{tid}"] = transform_points(ctx.output_T_sim, body.joints)
        labelled_views: list[_ViewLabel] = []
        only_camera = ctx.label_cameras.get(tid)
        if config.labels.min_distance_m <= distance <= config.labels.max_distance_m and tid not in ctx.bystanders:
            for view in ctx.views:
                vl, vrec = _label_person_in_view(ray_scene, view, person, body.vertices, body.keypoints,
                                                 config, label_rng, ctx.v_shift_px.get(view.camera, 0.0))
                record["views"][view.camera] = vrec
                if vl is None:
                    continue
                if only_camera is not None and view.camera != only_camera:
                    vrec.pop("labelled", None)
                    vrec.pop("visible", None)
                    vrec["suppressed"] = True
                    continue
                uv, flags, quirk = labels.file_quirks(vl.uv, vl.visible, config.labels, file_rng)
                if quirk is not None:
                    vrec["quirk"] = quirk
                    counts[f"{quirk}_files"] += 1
                labelled_views.append(vl)
                write_label2d(out, Label2D(sequence=seq, camera=vl.camera, frame=frame, tracking_id=tid,
                                           category="pedestrian", subtype="adult",
                                           view=labels.make_view(uv, flags, vl.polygon), frame_id=frame))
                counts["labels_2d"] += 1
        record["labelled"] = bool(labelled_views)
        if labelled_views:
            labelled_tids.add(tid)
        if labelled_views:
            # Segment: points inside the polygon of every left image the person is labelled in (with
            # segment_cameras == "any" and no left image: of every right image).
            cut_views = [vl for vl in labelled_views if vl.side == "left"]
            if not cut_views and config.labels.segment_cameras == "any":
                cut_views = labelled_views
            seg = []
            for vl in cut_views:
                pair_name, side = camera_pair[vl.camera]
                if (pair_name, side) not in projection:
                    cut_view = cameras.CameraView(calibs[pair_name], side, vl.camera)
                    projection[(pair_name, side)] = cut_view.project(scene_points)
                uv, depth = projection[(pair_name, side)]
                seg.append(labels.segment_indices_from_projection(uv, depth, vl.polygon))
            index = np.unique(np.concatenate(seg)) if seg else np.zeros(0, dtype=np.int64)
            index = labels.depth_gate(index, scene_points, config.labels.segment_depth_gate_m)
            is_person = sweep.object_id[index] == person.object_id
            truth_arrays[f"segment_index__{tid}"] = index.astype(np.int32)
            truth_arrays[f"segment_is_person__{tid}"] = is_person
            record["n_segment_points"] = int(len(index))
            record["n_segment_points_on_person"] = int(is_person.sum())
            if len(index) and lidar_frame:
                write_segment(out, seq, frame, tid, out_points[index])
                counts["segments"] += 1
                counts["segment_points"] += int(len(index))
                counts["segment_points_on_person"] += int(is_person.sum())
            pose, trans = transform_smpl(ctx.output_T_sim, person.pose[k], person.trans[k], person.rest_pelvis)
            write_smpl(out, SmplLabel(sequence=seq, frame=frame, tracking_id=tid, betas=person.betas,
                                      pose=pose, trans=trans))
            counts["smpl_labels"] += 1
            instances.append([tid, distance, sorted(vl.camera for vl in labelled_views)])
        truth_people[tid] = record
    if config.images.enabled:                         # rendered camera images of this frame (sim/render.py)
        from pedx_graph.sim.render import write_frame_images
        write_frame_images(out, seq, frame, [v for c in calibs.values() for v in cameras.camera_views(c)],
                           ctx.scene.ground_z, meshes, {o.object_id: o.kind for o in ctx.scene.objects},
                           config.images)
    detections = None
    if config.detections.formats:
        from pedx_graph.sim.detections import frame_detections

        detections = frame_detections(ctx, k, ray_scene, bodies, present, labelled_tids)
    truth_dir = out / "truth" / seq
    atomic_write_bytes(truth_dir / f"{seq}_{frame:07d}.npz", npz_bytes(truth_arrays))
    write_json_compact(truth_dir / f"{seq}_{frame:07d}.json",
                       {"frame": frame, "time_s": time_s, "n_lidar_points": len(scene_points),
                        "n_dropped": sweep.n_dropped, "people": truth_people})
    return {**counts, "instances": instances, "detections": detections}


def read_truth_frame(out_dir: str | Path, frame: int, sequence: str | None = None) -> dict:
    """The exact quantities of one simulated frame, regrouped per pedestrian.

    Returns ``{"scene_points" (N, 3), "scene_object_id" (N,), "scene_true_range" (N,), "people": {tid: {...}}}``
    where each person has ``keypoints`` (18, 3), ``joints`` (24, 3), ``object_id``, and when labelled
    ``segment_index`` (M,) / ``segment_is_person`` (M,) plus the per-frame JSON record (distance, views...).
    ``sequence`` defaults to the one in ``truth/meta.json``.
    """
    out = Path(out_dir)
    meta = json.loads((out / "truth" / "meta.json").read_text())
    seq = sequence or meta["sequence"]
    stem = out / "truth" / seq / f"{seq}_{int(frame):07d}"
    with np.load(stem.with_suffix(".npz")) as npz:
        arrays = {key: npz[key] for key in npz.files}
    records = json.loads(stem.with_suffix(".json").read_text())["people"]
    object_ids = {p["tracking_id"]: p["object_id"] for p in meta["pedestrians"]}
    people = {}
    for tid, record in records.items():
        person = {"object_id": object_ids[tid], "keypoints": arrays[f"keypoints__{tid}"],
                  "joints": arrays[f"joints__{tid}"], **record}
        if f"segment_index__{tid}" in arrays:
            person["segment_index"] = arrays[f"segment_index__{tid}"]
            person["segment_is_person"] = arrays[f"segment_is_person__{tid}"]
        people[tid] = person
    return {"scene_points": arrays["scene_points"], "scene_object_id": arrays["scene_object_id"],
            "scene_true_range": arrays["scene_true_range"], "people": people}


def one_camera_tracks(people: list[Pedestrian], views: list, config: SimConfig,
                      rng: np.random.Generator) -> dict[str, str]:
    """Tracking id -> the one camera of each track labelled in one camera only.

    Per pedestrian (in order, always two draws from ``rng``): with probability
    ``labels.one_camera_track_prob`` the track gets one camera, drawn among ``views`` with probability
    proportional to the frames (present, within the labelled distance range) in which its pelvis projects
    into that image (uniformly when it never does).
    """
    lab = config.labels
    out = {}
    for person in people:
        u_track, u_camera = rng.random(2)
        if not u_track < lab.one_camera_track_prob or not views:
            continue
        pelvis = person.trans + person.rest_pelvis
        distance = np.hypot(pelvis[:, 0], pelvis[:, 1])
        frames = person.present & (distance >= lab.min_distance_m) & (distance <= lab.max_distance_m)
        weights = []
        for view in views:
            uv, depth = view.project(pelvis[frames])
            weights.append(float(np.sum(view.in_image(uv) & (depth > 0.5))))
        weights = np.asarray(weights) if sum(weights) > 0 else np.ones(len(views))
        index = int(np.searchsorted(np.cumsum(weights) / weights.sum(), u_camera, side="right"))
        out[person.tracking_id] = views[min(index, len(views) - 1)].camera
    return out


def instance_summary(instances: list, calibs: dict, label_cameras: dict) -> dict:
    """Counts of labelled instances (``[tid, distance_m, cameras]`` per instance and frame): per pair (labelled
    in at least one of its images), in both pairs, in one image only; labelled tracks, one-camera tracks
    among them, and the distance range (horizontal, LiDAR to pelvis, metres)."""
    camera_pair = _pair_of_camera(calibs)
    per_pair = dict.fromkeys(calibs, 0)
    both = one_image = 0
    for _, _, cams in instances:
        pairs = {camera_pair[c][0] for c in cams}
        for pair in pairs:
            per_pair[pair] += 1
        both += len(pairs) >= 2
        one_image += len(cams) == 1
    tracks = {tid for tid, _, _ in instances}
    distances = np.array([d for _, d, _ in instances])
    return {
        "labelled_instances": len(instances), "labelled_instances_per_pair": per_pair,
        "labelled_instances_both_pairs": both, "labelled_instances_one_image": one_image,
        "labelled_tracks": len(tracks), "one_camera_tracks": sum(tid in tracks for tid in label_cameras),
        "labelled_distance_m": None if not len(distances) else {
            "min": round(float(distances.min()), 3), "median": round(float(np.median(distances)), 3),
            "max": round(float(distances.max()), 3)},
    }


#: What :func:`simulate` writes directly under ``out_dir`` (removed first with ``overwrite=True``).
OUTPUT_ENTRIES = ("calib", "labels", "pointclouds", "timestamps", "truth", "sim_config.yaml", "summary.json",
                  "detections")


def plan_scene(config: SimConfig, seed: int, body_model, clip_source=None) -> tuple[StaticScene, list[Pedestrian]]:
    """The intersection and its pedestrians that :func:`simulate` draws for ``seed`` (the same random streams),
    the moving cars retimed to keep ``scene.car_clearance_m`` from the pedestrians
    (:func:`~pedx_graph.sim.scene.retime_moving_cars`); nothing is rendered or written.  ``body_model`` and
    ``clip_source`` as in :func:`simulate` (the body model is needed: ``BodyModel.load(config.body_model)``)."""
    scene_rng, ped_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(2))
    scene = build_scene(config, scene_rng)
    people = plan_pedestrians(config, scene, body_model, ped_rng, clip_source)
    if people:
        retime_moving_cars(scene, np.stack([person.world_pelvis_xy for person in people]),
                           np.stack([person.present for person in people]), config.scene.fps,
                           config.scene.car_clearance_m)
    return scene, people


def simulate(out_dir: str | Path, config: SimConfig | None = None, seed: int = 0, body_model=None,
             clip_source=None, progress: bool = False, overwrite: bool = False, workers: int = 1) -> dict:
    """Simulate ``config.scene.n_frames`` frames into ``out_dir`` (layout in the module docstring).

    ``body_model``: a :class:`pedx_graph.body.BodyModel` (default: ``BodyModel.load(config.body_model)``);
    ``clip_source``: an object with ``draw(rng, n_frames, fps, rest_joints, hip_height_m, speed_mps)``
    returning a MotionClip (default from ``config.motion``).  An ``out_dir`` that already holds a simulation
    is refused (FileExistsError) unless ``overwrite`` (then :data:`OUTPUT_ENTRIES` are removed first).
    ``workers`` > 1 simulates frames in worker processes (spawned); every frame has its own random streams
    (:func:`frame_rngs`), so the files are the same for any worker count; spawned workers import the calling
    script again, so a script calling this with ``workers`` > 1 needs an ``if __name__ == "__main__":`` guard
    (without one the workers fail to start and this raises a RuntimeError saying so).  Returns a summary
    dict.
    """
    t_start = time.perf_counter()
    if int(workers) > 1 and _importing_main_in_worker():
        raise RuntimeError(_UNGUARDED.format(workers=int(workers), what="called again by a worker importing the "
                                                                            "calling script"))
    config = (config or SimConfig()).validate()
    out = Path(out_dir)
    existing = [name for name in OUTPUT_ENTRIES if (out / name).exists()]
    if existing:
        if not overwrite:
            raise FileExistsError(f"{out}: already holds {existing[0]} (use overwrite=True / --overwrite)")
        for name in existing:
            path = out / name
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    out.mkdir(parents=True, exist_ok=True)
    if body_model is None:
        from pedx_graph.body import BodyModel
        body_model = BodyModel.load(config.body_model)
    sc = config.scene
    seq = sc.sequence
    scene, people = plan_scene(config, seed, body_model, clip_source)
    output_T_sim = config.output_frame.output_T_sim()
    calibs: dict[str, StereoCalibration] = cameras.rig_calibrations(config)    # sim frame
    if config.detections.formats:              # raw distorted images for the detector files (K_0x, D_0x)
        from pedx_graph.sim.detections import raw_cameras

        calibs = raw_cameras(calibs, config.detections, seed)
    for calib in calibs.values():
        write_calibration(out, cameras.output_calibration(calib, output_T_sim))
    for person in people:
        person.object_id = scene.add_object("pedestrian", person.tracking_id)
    rest_vertices = body_model.forward(np.zeros(72), np.zeros(body_model.num_betas)).vertices
    views = []
    for calib in calibs.values():
        for view in cameras.camera_views(calib):
            if view.side == "left" or config.cameras.label_right_images:
                views.append(view)
    v_shift_px = {pair.name.split("-")[1]: -pair.vertical_disparity_px for pair in config.cameras.pairs()
                  if pair.vertical_disparity_px}
    label_cameras = one_camera_tracks(people, views, config, np.random.default_rng([int(seed), 3]))
    bystanders = frozenset()
    if config.labels.unlabelled_prob > 0:         # no draw when off: the default streams are unchanged
        draws = np.random.default_rng([int(seed), 7]).random(len(people))
        bystanders = frozenset(p.tracking_id for p, u in zip(people, draws) if u < config.labels.unlabelled_prob)
    ctx = _FrameContext(
        out=out, config=config, seed=int(seed), scene=scene, calibs=calibs, people=people,
        body_model=body_model, faces=outward_faces(rest_vertices, body_model.faces),
        directions=lidar.beam_directions(config.lidar), views=views,
        # every ray starts at the LiDAR or at a camera centre: back-facing triangles are culled (RayScene)
        viewpoints=np.stack([np.zeros(3)] + [v.world_center for calib in calibs.values()
                                             for v in cameras.camera_views(calib)]),
        output_T_sim=output_T_sim, v_shift_px=v_shift_px, label_cameras=label_cameras, bystanders=bystanders)

    counts = dict.fromkeys(COUNT_KEYS, 0)
    instances = []
    detections: dict[str, list] = {}
    frame_seconds = {sc.first_frame + k: k / sc.fps for k in range(sc.n_frames)}
    workers = max(1, min(int(workers), sc.n_frames))
    pool, ctx_path = None, None
    try:
        if workers > 1:
            import multiprocessing
            import os
            import pickle
            import tempfile
            from concurrent.futures import ProcessPoolExecutor

            handle, ctx_path = tempfile.mkstemp(prefix="pedx_graph_sim_", suffix=".pkl")
            with os.fdopen(handle, "wb") as f:
                pickle.dump(ctx, f, protocol=pickle.HIGHEST_PROTOCOL)
            # spawned (not forked) workers: Embree's thread pool in this process must not be inherited.  An
            # executor, not a multiprocessing Pool: a worker that dies (the calling script run again without a
            # __main__ guard) breaks it and the call fails, where a Pool starts replacements and waits on.
            pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                       initializer=_init_worker, initargs=(ctx_path,))
            results = pool.map(_frame_in_worker, range(sc.n_frames))
        else:
            results = (_simulate_frame(ctx, k) for k in range(sc.n_frames))
        if progress:
            from tqdm import tqdm
            results = tqdm(results, total=sc.n_frames, desc="simulate", unit="frame", disable=None)  # off unless a TTY
        for frame_counts in results:
            instances.extend(frame_counts.pop("instances"))
            for fmt, items in (frame_counts.pop("detections") or {}).items():
                detections.setdefault(fmt, []).extend(items)
            for key, value in frame_counts.items():
                counts[key] += value
    except BrokenProcessPool as exc:
        raise RuntimeError(_UNGUARDED.format(workers=workers, what="a worker process died (its own error is "
                                                                   "printed above)")) from exc
    finally:
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        if ctx_path is not None:
            Path(ctx_path).unlink(missing_ok=True)

    every = config.lidar.every_n_frames
    write_timestamps(out, seq, {f: t for f, t in frame_seconds.items() if (f - sc.first_frame) % every == 0},
                     kind="pointclouds")
    write_timestamps(out, seq, frame_seconds, kind="images")
    output_up = output_T_sim[:3, 2]
    meta = {
        "seed": int(seed), "sequence": seq, "fps": sc.fps, "first_frame": sc.first_frame,
        "n_frames": sc.n_frames, "rig": config.rig, "output_T_sim": output_T_sim.tolist(),
        "world_p_lidar": output_T_sim[:3, 3].tolist(),
        "ground": {"world_up": output_up.tolist(),
                   "ground_offset_m": float(scene.ground_z + output_up @ output_T_sim[:3, 3])},
        "ground_z": scene.ground_z, "objects": scene.object_table(),
        "walkways": [{"name": w.name, "kind": w.kind, "start_xy": w.start_xy, "end_xy": w.end_xy,
                      "half_width_m": w.half_width_m} for w in scene.walkways],
        "pedestrians": [{"tracking_id": p.tracking_id, "object_id": p.object_id, "betas": p.betas,
                         "walkway": p.walkway, "group": p.group, "motion": p.motion,
                         "present_frames": int(p.present.sum()),
                         "label_camera": label_cameras.get(p.tracking_id),
                         **({"bystander": True} if p.tracking_id in bystanders else {})} for p in people],
        "pairs": {n: {"focal_px": c.focal_px, "baseline_m": c.baseline_m, "image_size": c.image_size}
                  for n, c in calibs.items()},
    }
    atomic_write_json(out / "truth" / "meta.json", meta)
    detection_counts = None
    if config.detections.formats:
        from pedx_graph.sim.detections import write_sequence_files

        detection_counts = write_sequence_files(out, config, calibs, detections)
    atomic_write_text(out / "sim_config.yaml",
                      f"# seed: {int(seed)}\n" + yaml.safe_dump(to_dict(config), sort_keys=False))
    summary = {"seed": int(seed), "sequence": seq, "rig": config.rig, "frames": sc.n_frames,
               "pedestrians": len(people), **counts,
               "segment_precision": (counts["segment_points_on_person"] / counts["segment_points"]
                                     if counts["segment_points"] else None),
               **instance_summary(instances, calibs, label_cameras)}
    if detection_counts is not None:
        summary["detections"] = detection_counts
    atomic_write_json(out / "summary.json", summary)
    summary["seconds"] = time.perf_counter() - t_start
    return summary
