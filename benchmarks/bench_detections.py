"""Benchmark: manual labels vs detector keypoints (OpenPose BODY_25 / BODY_25B, COCO) on the same simulated scenes.

Each scene is simulated once with detector output (``SimConfig.detections``, :mod:`pedx_graph.sim.detections`:
OpenPose and COCO files on distorted raw images, detector noise growing with size, confidences falling with
error and occlusion, missed people, fragments and clutter, no ids; 15 % of the pedestrians are bystanders
that are never labelled but detected).  Inputs compared on it:

* ``manual``: the simulated annotators' PedX labels and polygon-cut LiDAR segments (the paper's input);
* ``openpose_body25``, ``openpose_body25b``, ``coco``: the detector files through ``pedx-graph import``
  (:func:`pedx_graph.detections.importer.import_detections`: undistort + rectify, association into tracks,
  confidence -> pixel noise, LiDAR cut from the scene clouds), each keypoint set projected by its own body-model
  definition in the fit.

Every track is fitted with batch LM (``fit_track``, covariances on).  Accuracy per frame against the
simulator's SMPL truth: manual tracks by their tracking id; detector tracks against the person most of the
frame's detections belong to (``truth/detections``; a tie, e.g. one image each of two people, goes to the track's
person of the frame before, as in the switch count; frames of a bystander's or an unlabelled instance's
detections, of clutter or fragments, are not scored; a frame fitted farther than 1 m from that person in the
ground plane is counted as *misplaced*, without an MPJPE).  A body placed on a neighbour is the error of the
person whose detections it was fitted to, not a good fit of the neighbour.  Reported per input and distance bin
(horizontal distance of the true pelvis from the LiDAR): global MPJPE and root-relative MPJPE (13 evaluation joints,
after similarity alignment for the latter; the global one also per joint), mean keypoint NEES / 3 dof and the 95 %
ellipsoid coverage of the 18 fitted keypoints (covariance status ``ok``).  The limb joints' (knees, ankles,
shoulders, elbows, wrists: points of every keypoint set) error at 5-25 m is also split by how many images'
keypoints held the joint at the frame (0, 1, 2, 3+): where a detector input's excess comes from — joints it
missed (the manual labels hardly miss any) rather than its pixel noise.

Each format's detections are also imported with the simulator's ids as the files' ids (``<format>_true_ids``:
people's detections only, ``ImportConfig.use_file_ids``), fitted alike and scored on the person-frames the
association's tracks were scored on: the error a perfect association would leave there (keypoint noise and
misses, the centres' placement, which :func:`~pedx_graph.detections.association.tracks_from_ids` does as the
association does), beside the goals' ratio.

Association (per detector format, run as the import runs it, scored against ``truth/detections``,
:mod:`pedx_graph.detections.evaluate`): tracks, false tracks (made of clutter / fragments or of several
people), bystander tracks (a real unlabelled person), labelled people recovered, frames of a track mixing two
people's detections (mostly a left image paired with the wrong right image), identity switches (a track going
on with another person; all, and those involving a person in a crossing: two labelled people at 5-25 m who
pass each other in one image — keypoint boxes overlapping at some frame, their left-right order changed),
wrong frames (frames of a track that are someone else's than its owner's: a neighbour's stretch counts its
frames once, where the switches count it twice), fragmentations (a person split over several tracks).

Scenes: ``crossing`` (default rig, everyone on the crosswalks, no groups, labelled at 5-25 m: people cross in
front of the forward pair at ~6.5 and ~21.5 m) and ``mixed`` (the second pair turned 20 degrees and placed
0.93 m beside the first as on the real rig, the simulator's walkway mix with groups, labelled at 5-45 m).
With ``--rig pedx`` both scenes are on the simulator's ``pedx`` preset instead
(:func:`pedx_graph.sim.config.pedx_rig_config`: the real PedX cameras, the z-down LiDAR frame with its
tilted ground, and the real labels' quirks in the manual labels: every keypoint
flagged visible, integer clicks with the measured per-keypoint noise, polygon-only files, a fifth of the
tracks labelled in one camera): ``crossing`` as above, ``mixed`` the preset's own scene (walkway mix with
groups, half of them where both pairs see them, labelled at 5-50 m).  Nothing in the import or the fit is
told the frame: the up axis and the ground come from the data as for any rig.

    python benchmarks/bench_detections.py [--seed 0] [--pedestrians 10] [--frames 20] [--workers 2]
                                          [--out benchmarks/results] [--detector-noise-scale 1]
                                          [--no-stereo-noise-check] [--detector-shared-noise 0]
                                          [--detector-split-prob 0] [--no-join-split-parts]
                                          [--detector-flip-prob 0] [--unflip]
                                          [--detector-swap-prob P] [--detector-swap-keeps-confidence]
                                          [--no-mirror-screen] [--rig default|pedx]

``--detector-noise-scale F`` makes the simulated detector F times as noisy as the one the shipped
confidence -> noise curves were measured on (a real detector is not ours); ``--no-stereo-noise-check``
imports without the import's check of those curves against the stereo rows
(``ImportConfig.stereo_noise_check``), to measure what that check does; ``--detector-shared-noise R``
makes R of the detector's noise variance one offset in every camera, which that check cannot see;
``--detector-split-prob P`` has the simulated OpenPose detector break a person's skeleton in two (upper body,
hips and legs: two people in the file) with probability P per detection, as bottom-up grouping does, and
``--no-join-split-parts`` associates without joining such parts again
(``AssociationConfig.join_split_parts``), to measure what the joining does; ``--detector-flip-prob P`` has
the simulated detector take a person's left for its right on the whole body, in every camera alike, with
probability P per person and frame (``DetectorOutputConfig.flip_prob``), and ``--unflip`` imports with the
check that swaps such detections back (``ImportConfig.flips``, off by default);
``--detector-swap-prob P`` sets the simulated detector's rate of exchanging one left/right pair of one person
in one image (``keypoint_noise.swap_prob``, 0.05 by default), ``--detector-swap-keeps-confidence`` scores
such keypoints as confidently as well-placed ones (``DetectorOutputConfig.swap_keeps_confidence``: nothing in
the file gives them away), and ``--no-mirror-screen`` fits without the left/right label screen
(``NoiseConfig.detector_left_right_swap_prob`` 0), to measure what the screen does; the screen's exchanges
are counted per scene and format (``label_screen``).

Writes ``bench_detections.json`` and ``bench_detections.md`` into ``--out``.  Goals (issue 15): detector input
within 1.5x the manual-label MPJPE at 5-25 m, no identity switch on crossing pedestrians at that range, no
track made of bystander noise (false tracks = 0).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import cell, hardware, public_args  # noqa: E402
from pedx_graph.data.calib import read_calibrations  # noqa: E402
from pedx_graph.data.ground import ground_from_calibrations  # noqa: E402
from pedx_graph.data.ply import read_ply_points  # noqa: E402
from pedx_graph.data.reader import read_dataset  # noqa: E402
from pedx_graph.detections.association import associate  # noqa: E402
from pedx_graph.detections.coco import read_coco  # noqa: E402
from pedx_graph.detections.evaluate import (detection_records, read_detection_truth, score_tracks,  # noqa: E402
                                          frame_owners as track_frame_owners)
from pedx_graph.detections.flips import unflip_tracks  # noqa: E402
from pedx_graph.detections.importer import ImportConfig, import_detections  # noqa: E402
from pedx_graph.detections.openpose import read_openpose  # noqa: E402
from pedx_graph.detections.tracker import box_iou, keypoint_box  # noqa: E402
from pedx_graph.eval.benchmark_tables import TRUE_IDS  # noqa: E402
from pedx_graph.eval.metrics import DISTANCE_BINS, distance_bin, eval_joints, joint_errors  # noqa: E402
from pedx_graph.keypoints import EVAL_JOINTS, load_keypoint_set  # noqa: E402
from pedx_graph.graph.config import FitConfig  # noqa: E402
from pedx_graph.sim.config import DETECTOR_FORMATS, SimConfig, pedx_rig_config  # noqa: E402
from pedx_graph.sim.detections import coco_paths  # noqa: E402
from pedx_graph.sim.simulate import read_truth_frame, simulate  # noqa: E402
from pedx_graph.solvers.fit import _context, fit_tracks  # noqa: E402
from pedx_graph.utils import atomic_write_json, atomic_write_text  # noqa: E402

SHARED_CMU = ROOT.parent / "shared" / "mocap" / "cmu"
FORMATS = ("openpose_body25", "openpose_body25b", "coco")
INPUTS = ("manual",) + FORMATS + tuple(fmt + TRUE_IDS for fmt in FORMATS)
#: chi2 with 3 dof at 95 %.
CHI2_3_95 = 7.815
#: A detector track's frame is scored against the labelled person whose pelvis is this near, metres.
MATCH_RADIUS_M = 1.0
#: The range of the goals, metres.
GOAL_RANGE_M = (5.0, 25.0)
#: The evaluation joints every keypoint set holds as a point of its own (``pedx_equivalent``): the limbs'.  The
#: head, neck and mid-hip are other points in COCO and OpenPose, so no image "holds" them alike.
LIMB_JOINTS = tuple(j for j in EVAL_JOINTS if j not in ("head", "neck", "hip"))
#: Bins of :func:`joint_views`: the number of images whose keypoints held a limb joint at a frame.
VIEW_BINS = ("0", "1", "2", "3+")
#: ``--rig`` choices: the simulator's default rig, or its ``pedx`` preset (the real cameras, z-down LiDAR frame,
#: tilted ground, real-label quirks).
RIGS = ("default", "pedx")
#: How the markdown names each rig.
RIG_NAMES = {"default": "simulator's default rig",
             "pedx": "real PedX rig (z-down LiDAR frame, real-label quirks in the manual labels)"}


def scene_configs(pedestrians: int, frames: int, detector_noise_scale: float = 1.0,
                  detector_shared_noise: float = 0.0, detector_split_prob: float = 0.0,
                  detector_flip_prob: float = 0.0, swap_keeps_confidence: bool = False,
                  detector_swap_prob: float | None = None, rig: str = "default",
                  car_clearance_m: float = 0.0, detector_definition_shift_m: float = 0.0) -> dict[str, SimConfig]:
    """The two scenes (module docstring) on ``rig`` (``default`` or ``pedx``), detector output on; the simulated
    detector's keypoint noise
    (``sigma_px`` and ``sigma_height_frac``) times ``detector_noise_scale``, ``detector_shared_noise`` of its
    variance the same in every camera (``DetectorOutputConfig.stereo_shared_noise``), OpenPose skeletons split
    in two with probability ``detector_split_prob`` (``DetectorOutputConfig.split_prob``), people's left and
    right swapped with probability ``detector_flip_prob`` (``DetectorOutputConfig.flip_prob``), left/right
    exchanged keypoints scored as confidently as well-placed ones with ``swap_keeps_confidence``
    (``DetectorOutputConfig.swap_keeps_confidence``), each pair exchanged with probability
    ``detector_swap_prob`` (``keypoint_noise.swap_prob``; None: the simulator's default), moving cars kept
    ``car_clearance_m`` from the pedestrians (``SceneConfig.car_clearance_m``; 0: they drive through them), the
    detector's keypoints off the fit's definitions by about ``detector_definition_shift_m``
    (``DetectorOutputConfig.definition_shift_m``; 0: its points are the fit's definitions)."""
    if rig not in RIGS:
        raise ValueError(f"rig must be one of {RIGS}, got {rig!r}")
    out = {}
    crossing = SimConfig() if rig == "default" else pedx_rig_config()
    crossing.scene.crosswalk_prob = 1.0
    crossing.scene.group_prob = 0.0
    crossing.labels.max_distance_m = GOAL_RANGE_M[1]
    out["crossing"] = crossing
    if rig == "default":
        mixed = SimConfig()
        fwd, side = mixed.cameras.forward, mixed.cameras.left
        fwd.focal_px, fwd.baseline_m = 3266.7, 0.329
        side.focal_px, side.baseline_m = 3332.5, 0.274
        side.yaw_deg = 20.0
        side.left_camera_xyz = (0.0, -0.9, -0.08)
    else:                                    # the preset's own scene: walkway mix with groups, labelled 5-50 m
        mixed = pedx_rig_config()
    out["mixed"] = mixed
    for cfg in out.values():
        cfg.scene.n_pedestrians = pedestrians
        cfg.scene.n_frames = frames
        cfg.labels.unlabelled_prob = 0.15
        cfg.detections.formats = FORMATS
        cfg.detections.keypoint_noise.sigma_px *= detector_noise_scale
        cfg.detections.keypoint_noise.sigma_height_frac *= detector_noise_scale
        cfg.detections.stereo_shared_noise = detector_shared_noise
        cfg.detections.split_prob = detector_split_prob
        cfg.detections.flip_prob = detector_flip_prob
        cfg.detections.swap_keeps_confidence = swap_keeps_confidence
        if detector_swap_prob is not None:
            cfg.detections.keypoint_noise.swap_prob = detector_swap_prob
        cfg.scene.car_clearance_m = car_clearance_m
        cfg.detections.definition_shift_m = detector_definition_shift_m
        if SHARED_CMU.is_dir():
            cfg.motion.motion_dir = str(SHARED_CMU)
            cfg.motion.split = "holdout"
    return out


def read_format(scene: Path, fmt: str, sequence: str) -> list:
    """The detections of one format as the import reads them."""
    if fmt == "coco":
        images, results = coco_paths(scene, sequence)
        return read_coco(results, images=images)
    return read_openpose(scene / "detections" / fmt / sequence, keypoint_set=DETECTOR_FORMATS[fmt])


def scene_clouds(scene: Path, sequence: str) -> dict[int, np.ndarray]:
    """Frame -> the scene's LiDAR cloud (``pointclouds/<seq>/``), every frame read up front (the association
    is timed without the reading)."""
    return {int(p.stem.rsplit("_", 1)[1]): read_ply_points(p)
            for p in sorted((scene / "pointclouds" / sequence).glob(f"{sequence}_*.ply"))}


def labelled_instances(scene: Path, sequence: str) -> dict[str, dict[int, float]]:
    """Tracking id -> {frame: horizontal distance (m)} of every labelled instance (``truth/<seq>/*.json``)."""
    out: dict[str, dict[int, float]] = defaultdict(dict)
    for path in sorted((scene / "truth" / sequence).glob("*.json")):
        record = json.loads(path.read_text())
        for tid, person in record["people"].items():
            if person.get("labelled"):
                out[tid][int(record["frame"])] = float(person["distance_m"])
    return dict(out)


def crossing_people(manual_tracks, labelled: dict) -> tuple[set, int]:
    """Labelled people who cross at 5-25 m, and the number of crossings: two labelled people seen in one image
    whose keypoint boxes overlap at some frame and whose left-right order in that image changes between the
    first and the last frame both are labelled there (they pass each other in the image, as in the module
    docstring's crossing; people walking side by side never change order)."""
    boxes = defaultdict(dict)                # (pair, side) -> {(tid, frame): box}
    for track in manual_tracks:
        for fr in track.frames:
            distance = labelled.get(track.tracking_id, {}).get(fr.frame)
            if distance is None or not GOAL_RANGE_M[0] <= distance < GOAL_RANGE_M[1]:
                continue
            for pair, side, view in fr.labelled_views():
                box = keypoint_box(view.keypoints)
                if box is not None:
                    boxes[(pair, side)][(track.tracking_id, fr.frame)] = box
    people, events = set(), set()
    for image_boxes in boxes.values():
        tids = sorted({tid for tid, _ in image_boxes})
        for i, a in enumerate(tids):
            for b in tids[i + 1:]:
                shared = sorted(f for t, f in image_boxes if t == a and (b, f) in image_boxes)
                if len(shared) < 2:
                    continue
                overlap = any(box_iou(image_boxes[(a, f)], image_boxes[(b, f)]) > 0 for f in shared)
                order = [np.sign((image_boxes[(a, f)][0] + image_boxes[(a, f)][2])
                                 - (image_boxes[(b, f)][0] + image_boxes[(b, f)][2])) for f in (shared[0], shared[-1])]
                if overlap and order[0] != order[1]:
                    people |= {a, b}
                    events.add((a, b))
    return people, len(events)


def _truth_frames(scene: Path, frames: list[int]) -> dict[int, list]:
    """frame -> [(tid, (18, 3) true keypoints, labelled)] of every person present (bystanders too)."""
    out = {}
    for frame in frames:
        people = read_truth_frame(scene, frame)["people"]
        out[frame] = [(tid, np.asarray(p["keypoints"], dtype=float), bool(p.get("labelled")))
                      for tid, p in sorted(people.items())]
    return out


def frame_owners(tracks, records: list[dict]) -> dict[tuple[str, int], str]:
    """``(track id, frame) -> the person most of that frame's detections belong to`` (truth records), for the
    detector tracks of :func:`~pedx_graph.detections.association.associate` (the ids the import writes); a
    tie is resolved as the association's scoring does, and fragments and clutter are nobody's
    (:func:`pedx_graph.detections.evaluate.frame_owners`)."""
    index = {(r["camera"], r["frame"], r["index"]): r for r in records}
    return {(track.track_id, frame): owner for track in tracks
            for frame, owner in track_frame_owners(track, records, index).items()}


def with_true_ids(detections: list, records: list[dict]) -> list:
    """The detections of people (whole or a split part; labelled or bystanders), each with the simulator's
    tracking id of its person as the file's id (``track_id``): the import's ``use_file_ids`` path then groups
    them as a perfect association would.  Clutter and fragments (nobody's) are left out."""
    index = {(r["camera"], r["frame"], r["index"]): r for r in records}
    out = []
    for det in detections:
        record = detection_records(det, records, index)[0]
        if record["kind"] in ("person", "part") and record.get("tracking_id"):
            out.append(dataclasses.replace(det, track_id=record["tracking_id"]))
    return out


def joint_views(frame) -> np.ndarray:
    """(len(LIMB_JOINTS),) how many of a track frame's images hold each limb joint as a keypoint of their own
    set (labelled: a detection's keypoint above the import's confidence threshold, an annotator's click)."""
    counts = np.zeros(len(LIMB_JOINTS), dtype=int)
    for _, _, view in frame.labelled_views():
        kps = load_keypoint_set(view.keypoint_set)
        for j, name in enumerate(LIMB_JOINTS):
            k = kps.index_of(name)
            counts[j] += int(k is not None and k < len(view.keypoints) and np.all(np.isfinite(view.keypoints[k])))
    return counts


def fit_rows(tracks, config: FitConfig, workers: int, truth: dict, labelled: dict, ground, by_id: bool,
             owners: dict | None = None) -> tuple:
    """Per scored frame: distance, global / root-relative MPJPE (mm), keypoint NEES (18,); plus failures and
    the left/right label screen's exchanges (``{"pairs", "whole_images"}``, the fits' ``mirrored_labels``).
    Detector tracks (``by_id`` False) are scored against the person most of the frame's detections belong to
    (``owners``, :func:`frame_owners`; frames of a bystander's, clutter or fragments are not scored); a frame
    fitted farther than ``MATCH_RADIUS_M`` from that person is a row with ``misplaced`` set (counted, no
    MPJPE: its error is that of a body placed at the wrong spot)."""
    if not by_id and owners is None:
        raise ValueError("fit_rows: detector tracks are scored against their frames' owners (frame_owners)")
    rows, failures = [], 0
    exchanges = {"pairs": 0, "whole_images": 0}
    for track, (result, error) in zip(tracks, fit_tracks(tracks, config, workers=workers)):
        if result is None:
            failures += 1
            continue
        track_frames = {f.frame: f for f in track.frames}
        for record in (result.extra_track or {}).get("mirrored_labels", []):
            exchanges["whole_images" if record["keypoints"] == "all" else "pairs"] += 1
        for i, frame in enumerate(result.frames):
            candidates = truth.get(frame, [])
            pelvis_fit = np.asarray(result.world_keypoints[i])[[12, 13]].mean(axis=0)
            if by_id:
                chosen = [c for c in candidates if c[0] == track.tracking_id]
            else:
                # the person whose detections the frame holds: a body placed on a neighbour is that
                # person's error, not a good fit of the neighbour's
                owner = owners.get((track.tracking_id, frame))
                chosen = [c for c in candidates if c[0] == owner]
                if chosen and chosen[0][2] and frame in labelled.get(owner, {}):
                    gap = np.linalg.norm(ground.to_level(chosen[0][1][[12, 13]].mean(axis=0))[:2]
                                         - ground.to_level(pelvis_fit)[:2])
                    if gap > MATCH_RADIUS_M:
                        rows.append({"distance_m": labelled[owner][frame], "misplaced": True, "key": (owner, frame)})
                        continue
            if not chosen or not chosen[0][2]:
                continue
            tid, true_kp, _ = chosen[0]
            fitted = np.asarray(result.world_keypoints[i])
            glob, rel = joint_errors(eval_joints(fitted[None]), eval_joints(true_kp[None]))
            extra = result.extra_per_frame[i] if result.extra_per_frame else {}
            nees = None
            if extra.get("covariance_status") == "ok" and extra.get("cov_keypoints_3d") is not None:
                err = fitted - true_kp
                cov = np.asarray(extra["cov_keypoints_3d"], dtype=float)
                nees = np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[..., None])[..., 0])
            rows.append({"key": (tid, frame), "distance_m": labelled[tid][frame], "mpjpe_mm": 1000 * float(np.mean(glob)),
                         "rel_mpjpe_mm": 1000 * float(np.mean(rel)), "nees": nees,
                         "joint_mm": 1000 * np.asarray(glob, dtype=float).reshape(-1),
                         "limb_views": joint_views(track_frames[frame])})
    return rows, failures, exchanges


def _stats(rows: list[dict]) -> dict:
    misplaced = sum(1 for r in rows if r.get("misplaced"))
    rows = [r for r in rows if not r.get("misplaced")]
    if not rows:
        return {"frames": 0, "misplaced_frames": misplaced}
    nees = np.concatenate([r["nees"] for r in rows if r["nees"] is not None] or [np.zeros(0)])
    return {"frames": len(rows), "misplaced_frames": misplaced,
            "mpjpe_mm": float(np.mean([r["mpjpe_mm"] for r in rows])),
            "rel_mpjpe_mm": float(np.mean([r["rel_mpjpe_mm"] for r in rows])),
            "keypoint_nees_over_dof": float(nees.mean() / 3) if len(nees) else None,
            "keypoint_coverage95": float(np.mean(nees <= CHI2_3_95)) if len(nees) else None,
            "joint_mpjpe_mm": dict(zip(EVAL_JOINTS, np.mean([r["joint_mm"] for r in rows], axis=0).tolist())),
            "limbs_by_views": _limbs_by_views(rows)}


def _limbs_by_views(rows: list[dict]) -> dict:
    """Limb joints' global error by how many images held them (VIEW_BINS): share of the limb joint-frames,
    mean error (mm) and that bin's part of the summed limb error — where the error comes from: joints the
    fit saw in two images, in one (depth from the body alone), or in none (the priors')."""
    limb = [EVAL_JOINTS.index(j) for j in LIMB_JOINTS]
    err = np.concatenate([r["joint_mm"][limb] for r in rows])
    views = np.minimum(np.concatenate([r["limb_views"] for r in rows]), len(VIEW_BINS) - 1)
    out = {}
    for k, label in enumerate(VIEW_BINS):
        sel = views == k
        out[label] = {"joint_frames": int(sel.sum()), "share": float(sel.mean()),
                      "mpjpe_mm": float(err[sel].mean()) if sel.any() else None,
                      "error_share": float(err[sel].sum() / max(err.sum(), 1e-12))}
    return out


def summarise(rows: list[dict]) -> dict:
    out = {"all": _stats(rows)}
    lo, hi = GOAL_RANGE_M
    out[f"{lo:g}-{hi:g}"] = _stats([r for r in rows if lo <= r["distance_m"] < hi])
    for b_lo, b_hi in DISTANCE_BINS:
        label = distance_bin(0.5 * (b_lo + b_hi))
        out[label] = _stats([r for r in rows if distance_bin(r["distance_m"]) == label])
    return out


def flip_counts(tracks, calibs, ground, import_config: ImportConfig | None, records: list[dict]) -> dict:
    """How the import's left/right check (``ImportConfig.flips``, run on the association's ``tracks`` as the
    import runs it) stands to the simulator's whole-body flips (truth records ``"flipped": true``): person
    detections flipped and swapped back or left so, and not flipped but swapped."""
    config = import_config or ImportConfig()
    fixed, _ = unflip_tracks(tracks, calibs, ground, config.flips, config.association.keypoint_sigma_px,
                             config.association.keypoint_sigma_frac, config.association.tracker.frame_interval_s)
    index = {(r["camera"], r["frame"], r["index"]): r for r in records}
    out = {"flipped_swapped_back": 0, "flipped_left": 0, "not_flipped_swapped": 0, "not_flipped_left": 0}
    for before, after in zip(tracks, fixed):
        for fr_before, fr_after in zip(before.frames, after.frames):
            for camera, det in fr_before.detections.items():
                record = detection_records(det, records, index)[0]
                if record["kind"] != "person":
                    continue
                swapped = fr_after.detections[camera] is not det
                key = ("flipped_" + ("swapped_back" if swapped else "left")) if record.get("flipped") else \
                    ("not_flipped_" + ("swapped" if swapped else "left"))
                out[key] += 1
    return out


def run_scene(name: str, cfg: SimConfig, seed: int, work: Path, workers: int, fit_config: FitConfig, ctx,
              import_config: ImportConfig | None = None) -> dict:
    scene = work / name
    t0 = time.perf_counter()
    sim_summary = simulate(scene, cfg, seed=seed, workers=workers)
    seconds = {"simulate": time.perf_counter() - t0}
    seq = cfg.scene.sequence
    labelled = labelled_instances(scene, seq)
    truth = _truth_frames(scene, [cfg.scene.first_frame + k for k in range(cfg.scene.n_frames)])
    calibs = read_calibrations(scene / "calib")
    manual = read_dataset(scene)
    ground = manual[0].ground if manual else ground_from_calibrations(calibs, seq)
    crossing, events = crossing_people(manual, labelled)
    clouds = scene_clouds(scene, seq)
    result = {"simulated": {k: sim_summary[k] for k in ("pedestrians", "labelled_tracks", "labelled_instances",
                                                       "detections")},
              "crossing_people": len(crossing), "crossing_events": events, "association": {}, "accuracy": {},
              "tracks_fitted": {}, "fit_failures": {}, "label_screen": {}}
    t0 = time.perf_counter()
    rows, failures, result["label_screen"]["manual"] = fit_rows(manual, fit_config, workers, truth, labelled,
                                                                ground, by_id=True)
    seconds["fit_manual"] = time.perf_counter() - t0
    result["accuracy"]["manual"], result["tracks_fitted"]["manual"] = rows, len(manual)
    result["fit_failures"]["manual"] = failures
    for fmt in FORMATS:
        detections = read_format(scene, fmt, seq)
        records = read_detection_truth(scene, seq, fmt)
        t0 = time.perf_counter()
        tracks = associate(detections, calibs, config=import_config.association if import_config else None,
                           clouds=clouds, ground=ground_from_calibrations(calibs, seq))
        seconds[f"associate_{fmt}"] = time.perf_counter() - t0
        score = score_tracks(tracks, records, labelled)
        score["crossing_id_switches"] = sum(1 for _, _, a, b in score["switches"] if a in crossing or b in crossing)
        score.pop("owners")
        result["association"][fmt] = score
        imported = work / f"{name}_{fmt}"
        summary = import_detections(detections, scene, imported, config=import_config)
        score["import_tracks"] = summary["sequences"][seq]["tracks"]
        score["left_right_swapped_back"] = summary["sequences"][seq].get("left_right_swapped_back")
        score["flips"] = flip_counts(tracks, calibs, ground_from_calibrations(calibs, seq), import_config, records)
        score["stereo_noise_check"] = summary["sequences"][seq].get("stereo_noise_check")
        dataset = read_dataset(imported) if (imported / "labels").is_dir() else []      # no track found
        t0 = time.perf_counter()
        rows, failures, result["label_screen"][fmt] = fit_rows(dataset, fit_config, workers, truth, labelled,
                                                               ground, by_id=False,
                                                               owners=frame_owners(tracks, records))
        seconds[f"fit_{fmt}"] = time.perf_counter() - t0
        result["accuracy"][fmt], result["tracks_fitted"][fmt] = rows, len(dataset)
        result["fit_failures"][fmt] = failures
        # the same detections grouped by the simulator's ids, scored on the same people's frames: the error
        # left without the association's identity errors (keypoint noise and misses, the centres' placement)
        t0 = time.perf_counter()
        known = work / f"{name}_{fmt}_true_ids"
        import_detections(with_true_ids(detections, records), scene, known,
                          config=dataclasses.replace(import_config or ImportConfig(), use_file_ids=True))
        dataset = read_dataset(known) if (known / "labels").is_dir() else []
        own = {(track.tracking_id, fr.frame): track.tracking_id for track in dataset for fr in track.frames}
        scored = {r["key"] for r in result["accuracy"][fmt]}
        rows, failures, _ = fit_rows(dataset, fit_config, workers, truth, labelled, ground, by_id=False, owners=own)
        rows = [r for r in rows if r["key"] in scored]        # the frames the association's tracks were scored on
        seconds[f"fit_{fmt}_true_ids"] = time.perf_counter() - t0
        source = f"{fmt}{TRUE_IDS}"
        result["accuracy"][source], result["tracks_fitted"][source] = rows, len(dataset)
        result["fit_failures"][source] = failures
    result["seconds"] = seconds
    return result


def run(seed: int, pedestrians: int, frames: int, workers: int, work: Path, detector_noise_scale: float = 1.0,
        stereo_noise_check: bool = True, detector_shared_noise: float = 0.0, detector_split_prob: float = 0.0,
        join_split_parts: bool = True, detector_flip_prob: float = 0.0, unflip: bool = False,
        swap_keeps_confidence: bool = False, mirror_screen: bool = True,
        detector_swap_prob: float | None = None, rig: str = "default", car_clearance_m: float = 0.0,
        detector_definition_shift_m: float = 0.0, definition_sigma_m: float = 0.0) -> dict:
    fit_config = FitConfig()
    if not mirror_screen:
        fit_config.noise.detector_left_right_swap_prob = 0.0
    fit_config.diagnostics = False
    fit_config.covariances = True
    ctx = _context(fit_config)
    scenes = {}
    import_config = ImportConfig(stereo_noise_check=stereo_noise_check)
    import_config.association.join_split_parts = join_split_parts
    import_config.flips.enabled = unflip
    import_config.noise.definition_sigma_m = definition_sigma_m
    configs = scene_configs(pedestrians, frames, detector_noise_scale, detector_shared_noise, detector_split_prob,
                            detector_flip_prob, swap_keeps_confidence, detector_swap_prob, rig, car_clearance_m,
                            detector_definition_shift_m)
    for s, (name, cfg) in enumerate(configs.items()):
        scenes[name] = run_scene(name, cfg, seed + s, work, workers, fit_config, ctx, import_config)
    accuracy = {}
    for source in INPUTS:
        rows = [r for sc in scenes.values() for r in sc["accuracy"][source]]
        accuracy[source] = summarise(rows)
    for sc in scenes.values():
        sc["accuracy"] = {source: summarise(rows) for source, rows in sc["accuracy"].items()}
    key = f"{GOAL_RANGE_M[0]:g}-{GOAL_RANGE_M[1]:g}"
    manual = accuracy["manual"][key].get("mpjpe_mm")
    goals = {}
    for fmt in FORMATS:
        det = accuracy[fmt][key].get("mpjpe_mm")
        ratio = det / manual if det is not None and manual else None
        known = accuracy[fmt + TRUE_IDS][key].get("mpjpe_mm")
        goals[fmt] = {"mpjpe_ratio_5_25": ratio, "within_1.5x": ratio is not None and ratio <= 1.5,
                      "mpjpe_ratio_5_25_true_ids": known / manual if known is not None and manual else None,
                      "crossing_id_switches": sum(sc["association"][fmt]["crossing_id_switches"]
                                                  for sc in scenes.values()),
                      "false_tracks": sum(sc["association"][fmt]["false_tracks"] for sc in scenes.values()),
                      "misplaced_frames_5_25": accuracy[fmt][key].get("misplaced_frames", 0)}
    return {"scenes": scenes, "accuracy": accuracy, "goals": goals,
            "motion": "CMU hold-out clips" if SHARED_CMU.is_dir() else "procedural gait"}


def _cars(clearance_m: float) -> str:
    """The markdown's words on the moving cars (``scene.car_clearance_m``): none for the simulator's default
    (they drive through the people on the crosswalks), so the default runs' text is as before."""
    return f", moving cars kept {clearance_m:g} m from every pedestrian (scene.car_clearance_m)" if clearance_m else ""


def _shift(shift_m: float) -> str:
    """The markdown's words on the detector's keypoint definitions (``detections.definition_shift_m``): none
    for the simulator's default (the fit's own definitions), so the default runs' text is as before."""
    return (f", the detector's keypoints about {shift_m:g} m off the fit's definitions "
            "(detections.definition_shift_m)") if shift_m else ""


def _definition(sigma_m: float) -> str:
    """The markdown's words on the import's definition uncertainty (``import.noise.definition_sigma_m``): none
    for the default (0)."""
    return (f", imported with {sigma_m:g} m of uncertainty of the detector's points about the definitions "
            "(import.noise.definition_sigma_m)") if sigma_m else ""


def markdown(result: dict, command: str) -> str:
    key = f"{GOAL_RANGE_M[0]:g}-{GOAL_RANGE_M[1]:g}"
    lines = ["# bench_detections: manual labels vs detector keypoints", "", f"Command: `{command}`", "",
             f"Seed {result['seed']}, {result['pedestrians']} pedestrians x {result['frames']} frames per scene "
             f"on the {RIG_NAMES[result.get('rig', 'default')]}, {result['motion']}; "
             f"simulated detector noise x{result.get('detector_noise_scale', 1.0):g} "
             f"({result.get('detector_shared_noise', 0.0):g} of its variance shared by the cameras), "
             f"OpenPose skeletons split in two with probability {result.get('detector_split_prob', 0.0):g} "
             f"(parts joined: {'yes' if result.get('join_split_parts', True) else 'no'}), left and right "
             f"swapped on the whole body with probability {result.get('detector_flip_prob', 0.0):g} "
             f"(swapped back: {'yes' if result.get('unflip', False) else 'no'}), "
             f"left/right pairs exchanged with probability "
             f"{'the default' if result.get('detector_swap_prob') is None else result['detector_swap_prob']} "
             f"({'as confident as well-placed keypoints' if result.get('swap_keeps_confidence') else 'losing confidence'}), "
             f"left/right label screen {'on' if result.get('mirror_screen', True) else 'off'}, "
             f"stereo-row noise check {'on' if result.get('stereo_noise_check', True) else 'off'}"
             f"{_cars(result.get('car_clearance_m', 0.0))}{_shift(result.get('detector_definition_shift_m', 0.0))}"
             f"{_definition(result.get('definition_sigma_m', 0.0))}.  "
             "Method: see the script's docstring (simulated OpenPose BODY_25 / BODY_25B and COCO files on "
             "distorted raw images, no ids, 15 % unlabelled bystanders, clutter and fragments; "
             "imported with `pedx-graph import` (association, undistortion, confidence -> noise, LiDAR cut) and "
             "fitted with batch LM; manual = the simulated annotators' labels and segments).", "",
             "## Goals (issue 15)", "",
             "| input | MPJPE ratio to manual at 5-25 m | within 1.5x | id switches, crossing people | false tracks "
             "| misplaced frames at 5-25 m | ratio with the simulator's ids |",
             "|---|---|---|---|---|---|---|"]
    for fmt, g in result["goals"].items():
        lines.append(f"| {fmt} | {cell(g['mpjpe_ratio_5_25'], '.2f')} | {'yes' if g['within_1.5x'] else 'no'} | "
                     f"{g['crossing_id_switches']} | {g['false_tracks']} | {g.get('misplaced_frames_5_25', 0)} | "
                     f"{cell(g.get('mpjpe_ratio_5_25_true_ids'), '.2f')} |")
    lines += ["", "The last column: the same detections grouped into tracks by the simulator's ids (`use_file_ids`, "
              f"rows `<format>{TRUE_IDS}` below), imported and fitted alike and scored on the frames of the people "
              "the association's tracks were scored on: the ratio a perfect association would give there; the "
              "difference to the first column is the association's identity errors' part.  Their frames are placed "
              "as the association places its people (`tracks_from_ids`)."]
    lines += ["", "## Association (per scene and format)", "",
              "| scene | format | tracks | false | bystander | recovered / labelled people | id switches "
              "(crossing) | wrong frames | mixed frames | fragmentations | crossing people (events) | "
              "stereo-row noise scale (applied) |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, sc in result["scenes"].items():
        for fmt, a in sc["association"].items():
            check = a.get("stereo_noise_check") or {}
            lines.append(f"| {name} | {fmt} | {a['tracks']} | {a['false_tracks']} | {a['bystander_tracks']} | "
                         f"{a['recovered']} / {a['labelled_people']} | {a['id_switches']} "
                         f"({a['crossing_id_switches']}) | {a['wrong_frames']} | {a['mixed_frames']} | "
                         f"{a['fragmentations']} | "
                         f"{sc['crossing_people']} ({sc['crossing_events']}) | "
                         f"{cell(check.get('scale'), '.2f')} ({cell(check.get('applied'), '.2f')}) |")
    lines += ["", "## Accuracy (both scenes)", "",
              "| input | bin (m) | frames | misplaced frames | MPJPE (mm) | root-rel. MPJPE (mm) | "
              "keypoint NEES / dof | 95 % coverage |", "|---|---|---|---|---|---|---|---|"]
    for source, summary in result["accuracy"].items():
        for label, st in summary.items():
            if not st["frames"]:
                continue
            lines.append(f"| {source} | {label} | {st['frames']} | {st.get('misplaced_frames', 0)} | "
                         f"{st['mpjpe_mm']:.1f} | {st['rel_mpjpe_mm']:.1f} | "
                         f"{cell(st['keypoint_nees_over_dof'], '.2f')} | {cell(st['keypoint_coverage95'], '.3f')} |")
    lines += ["", f"## Global MPJPE per joint at {key} m (mm, both scenes)", "",
              "| input | " + " | ".join(EVAL_JOINTS) + " |", "|---|" + "---:|" * len(EVAL_JOINTS)]
    for source, summary in result["accuracy"].items():
        joints = summary[key].get("joint_mpjpe_mm")
        if joints:
            lines.append(f"| {source} | " + " | ".join(f"{joints[j]:.1f}" for j in EVAL_JOINTS) + " |")
    lines += ["", f"## Limb joints at {key} m by the images that held them (both scenes)", "",
              "How many images' keypoints held each limb joint (" + ", ".join(LIMB_JOINTS) + ") at a scored frame: "
              "the share of the limb joint-frames, their mean global error and that bin's part of the summed "
              "limb error.  A joint held by no image is placed by the pose and motion priors alone, one held by "
              "one image has its depth along that image's ray from the rest of the body only: those two bins are "
              "the detector's misses (of a keypoint, or of the person in an image), not its pixel noise.", "",
              "| input | " + " | ".join(f"{b} images: share, mm (part of error)" for b in VIEW_BINS) + " |",
              "|---|" + "---|" * len(VIEW_BINS)]
    for source, summary in result["accuracy"].items():
        by_views = summary[key].get("limbs_by_views")
        if by_views:
            lines.append(f"| {source} | " + " | ".join(
                f"{v['share']:.2f}, {cell(v['mpjpe_mm'], '.1f')} ({v['error_share']:.2f})"
                for v in by_views.values()) + " |")
    lines += ["", f"Frames are scored against their labelled person (detector tracks: the person most of the frame's "
              f"detections belong to); the {key} m row is the goal's range.  A detector track's frame fitted farther "
              f"than {MATCH_RADIUS_M:g} m from that person is counted as misplaced and left out of the MPJPE (a body "
              f"at the wrong spot).  Per scene:", ""]
    for name, sc in result["scenes"].items():
        fitted = ", ".join(f"{k} {v}" for k, v in sc["tracks_fitted"].items())
        failed = sum(sc["fit_failures"].values())
        lines.append(f"- {name}: tracks fitted {fitted}; failed fits {failed}; seconds "
                     + ", ".join(f"{k} {v:.1f}" for k, v in sc["seconds"].items()))
    flips = [(name, fmt, a["flips"]) for name, sc in result["scenes"].items()
             for fmt, a in sc["association"].items() if a.get("flips")]
    if any(sum(counts.values()) for _, _, counts in flips):
        lines += ["", "Whole-body left/right flips of person detections in the association's tracks (simulator's "
                  "truth) and the import's check (`ImportConfig.flips`): flipped -> swapped back / left flipped; "
                  "not flipped -> swapped:", ""]
        lines += [f"- {name} {fmt}: {c['flipped_swapped_back']} / {c['flipped_left']}; {c['not_flipped_swapped']} "
                  f"of {c['not_flipped_swapped'] + c['not_flipped_left']}" for name, fmt, c in flips]
    screened = [(name, fmt, c) for name, sc in result["scenes"].items()
                for fmt, c in sc.get("label_screen", {}).items()]
    if screened:
        lines += ["", "Left/right labels the fit's screen exchanged back (`mirrored_labels`, "
                  "pedx_graph.solvers.mirror): pairs / whole images:", ""]
        lines += [f"- {name} {fmt}: {c['pairs']} / {c['whole_images']}" for name, fmt, c in screened]
    lines += ["", f"Hardware: {result['hardware']}", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--pedestrians", type=int, default=10)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2, help="processes for simulating and fitting")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    parser.add_argument("--detector-noise-scale", type=float, default=1.0,
                        help="multiply the simulated detector's keypoint noise (a detector unlike the one the "
                             "shipped noise curves were measured on)")
    parser.add_argument("--no-stereo-noise-check", action="store_true",
                        help="import without checking the noise model against the stereo rows")
    parser.add_argument("--detector-shared-noise", type=float, default=0.0,
                        help="fraction of the simulated detector's noise variance that is the same offset in "
                             "every camera (invisible to the stereo-row check)")
    parser.add_argument("--detector-split-prob", type=float, default=0.0,
                        help="probability that the simulated OpenPose detector reports a person as two parts "
                             "(upper body; hips and legs)")
    parser.add_argument("--no-join-split-parts", action="store_true",
                        help="associate without joining a person's two parts")
    parser.add_argument("--detector-flip-prob", type=float, default=0.0,
                        help="probability per person and frame that the simulated detector swaps the person's "
                             "left and right (every camera alike)")
    parser.add_argument("--unflip", action="store_true",
                        help="import with the check that swaps back detections whose left and right the detector "
                             "confused (ImportConfig.flips, off by default)")
    parser.add_argument("--detector-swap-keeps-confidence", action="store_true",
                        help="the simulated detector scores left/right exchanged keypoints as confidently as "
                             "well-placed ones (DetectorOutputConfig.swap_keeps_confidence)")
    parser.add_argument("--detector-swap-prob", type=float, default=None,
                        help="probability that the simulated detector exchanges one left/right pair of one "
                             "person in one image (keypoint_noise.swap_prob; default: the simulator's)")
    parser.add_argument("--rig", choices=RIGS, default="default",
                        help="the simulated rig: the default one, or the real PedX rig (z-down LiDAR frame, "
                             "real-label quirks in the manual labels)")
    parser.add_argument("--car-clearance", type=float, default=0.0,
                        help="moving cars keep this far from the pedestrians, metres (scene.car_clearance_m; "
                             "0: the simulator's default, cars drive through the people on the crosswalks)")
    parser.add_argument("--detector-definition-shift", type=float, default=0.0,
                        help="the simulated detector's keypoints lie about this far from the body model's "
                             "definitions the import fits, metres (detections.definition_shift_m; 0: on them)")
    parser.add_argument("--definition-sigma", type=float, default=0.0,
                        help="import with this uncertainty of the detector's points about the body model's "
                             "definitions, metres (import.noise.definition_sigma_m; 0: none)")
    parser.add_argument("--no-mirror-screen", action="store_true",
                        help="fit without the left/right label screen (noise.detector_left_right_swap_prob 0)")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench_detections_") as tmp:
        result = run(args.seed, args.pedestrians, args.frames, args.workers, Path(tmp), args.detector_noise_scale,
                     not args.no_stereo_noise_check, args.detector_shared_noise, args.detector_split_prob,
                     not args.no_join_split_parts, args.detector_flip_prob, args.unflip,
                     swap_keeps_confidence=args.detector_swap_keeps_confidence,
                     mirror_screen=not args.no_mirror_screen, detector_swap_prob=args.detector_swap_prob,
                     rig=args.rig, car_clearance_m=args.car_clearance,
                     detector_definition_shift_m=args.detector_definition_shift,
                     definition_sigma_m=args.definition_sigma)
    result.update(rig=args.rig, seed=args.seed, pedestrians=args.pedestrians, frames=args.frames,
                  workers=args.workers,
                  detector_noise_scale=args.detector_noise_scale, stereo_noise_check=not args.no_stereo_noise_check,
                  detector_shared_noise=args.detector_shared_noise, detector_split_prob=args.detector_split_prob,
                  join_split_parts=not args.no_join_split_parts, detector_flip_prob=args.detector_flip_prob,
                  unflip=args.unflip, swap_keeps_confidence=args.detector_swap_keeps_confidence,
                  mirror_screen=not args.no_mirror_screen, detector_swap_prob=args.detector_swap_prob,
                  car_clearance_m=args.car_clearance, detector_definition_shift_m=args.detector_definition_shift,
                  definition_sigma_m=args.definition_sigma,
                  total_seconds=time.perf_counter() - t0, hardware=hardware())
    command = " ".join(["python benchmarks/bench_detections.py"] + public_args(argv))
    result["command"] = command
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "bench_detections.json", result)
    atomic_write_text(out / "bench_detections.md", markdown(result, command))
    print(markdown(result, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
