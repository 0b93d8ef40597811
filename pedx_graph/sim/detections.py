"""The simulator's detector output: OpenPose / COCO keypoint files on distorted raw images, without ids.

Enabled by ``SimConfig.detections.formats`` (``pedx-graph simulate OUT --detections openpose_body25,coco``).
Then every camera gets a raw image model (:func:`raw_cameras`): intrinsics ``K`` near the rectified ones and
radial-tangential distortion ``D = (k1, k2, p1, p2, 0)`` drawn per camera from the config's ranges, written as
the KITTI raw keys ``K_0x`` / ``D_0x`` of the calibration files (with ``right_rect_rotation_deg`` the raw
right camera is also turned against the left one: ``R_rect_01`` differs from ``R_rect_00``).  Detections are
made on those raw images (with ``detected_on: rectified``, on the rectified images instead, the calibration
keeping its raw keys: what a user gets running a detector on a release's rectified images):

* every person present (labelled or not: people outside the labelled distance range, too occluded to be
  labelled, or skipped by the annotators — ``labels.unlabelled_prob`` — are *bystanders*, detected all the
  same) whose keypoints span at least ``min_height_px`` and
  with ``min_visible_keypoints`` visible in-image keypoints is a candidate; it is missed with probability
  ``person_miss_prob + occluded_miss_prob * (occluded fraction)``;
* its keypoints are the format's own points on the body model (:meth:`BodyModel.for_keypoint_set`, never a
  renamed PedX point), projected exactly into the rectified image, distorted into the raw image
  (:func:`pedx_graph.detections.undistort.distort`), then corrupted by the detector model of
  :mod:`pedx_graph.eval.detector_noise` (:func:`~pedx_graph.eval.detector_noise.corrupt_keypoints`: noise
  growing with the person's image height, per-keypoint factors, misses, left/right swaps, outliers; with
  ``stereo_shared_noise`` part of the noise is one offset in every camera, as an error a real detector makes
  alike from several viewpoints); points outside the raw image are absent (with ``raw_margin_px`` the raw
  image is larger than the rectified one, ``S_0x`` written, and people it sees beyond the rectified image are
  detected: :func:`detector_image_size`);
* confidence per keypoint: ``c = c0 * h / (h + h_half) * exp(-e^2 / 2) + N(0, s^2)`` clipped to [0.02, 1],
  ``c0`` = ``confidence_visible`` or ``confidence_occluded``, ``e`` = the keypoint's pixel error divided by
  ``confidence_error_sigmas`` times its noise sigma — confidence falls with the error and with occlusion
  (with ``swap_keeps_confidence``, a left/right exchanged keypoint's error is measured from the nearer of
  its own and its mirror point: confident of the wrong side);
* false positives: a Poisson number (mean ``clutter_per_image``) of skeletons at random places and sizes, and
  with probability ``fragment_prob`` per detected person a partial duplicate of it (legs or upper body);
* with ``duplicate_prob`` > 0, a person reported twice in one image, the second time whole with its own
  noise draw (a top-down detector's second box past non-maximum suppression; truth kind ``person``,
  ``"duplicate": true``);
* with ``flip_prob`` > 0, a person's left taken for its right on the whole body at a frame, in every camera
  alike (truth kind stays ``person``, with ``"flipped": true``);
* OpenPose formats, with ``split_prob`` > 0: a person's skeleton broken in two by the bottom-up grouping, its
  upper body and its hips and legs written as two people (no whole detection of it in that image);
* the detection score is the mean confidence of its present keypoints;
* with ``image_scale`` != 1 every written pixel is that of the image resized by it (and the COCO image list
  gives the resized size), and with ``pixel_units`` other than ``pixels`` the coordinates are normalised by
  the image's size (:func:`pedx_graph.detections.pixel_units.to_detector_units`): what a detector run on
  resized images, or told to write normalised coordinates, gives.

Written files (``<image>`` = ``<seq>_<cam>_<frame:07d>``, the release's image name)::

    detections/openpose_<set>/<seq>/<cam>/<image>_keypoints.json   OpenPose JSON, person_id [-1]
    detections/coco/<seq>/image_list.json                           {"images": [...], "categories": [...]}
    detections/coco/<seq>/keypoint_results.json                     [{"image_id", "category_id", "keypoints", "score"}]
    truth/detections/<seq>/<format>.json                            per image, per written person: what it is

The truth record of each written detection: ``{"camera", "frame", "index", "kind"}`` with kind ``person``
(plus ``tracking_id`` and ``labelled``: the person has 2D labels at that frame), ``part`` (one of the two
pieces of a split person: the same fields), ``fragment`` (plus the
``tracking_id`` it came from) or ``clutter``.  Every draw comes from a generator seeded by ``(seed, frame,
format)`` (distortion: ``(seed, camera)``): files are byte-identical for a seed, whatever the worker count.
"""
from __future__ import annotations

import dataclasses
import json
import zlib
from pathlib import Path

import cv2
import numpy as np

from pedx_graph.body.keypoint_defs import KeypointMap, load_keypoint_set, standing_keypoints_2d
from pedx_graph.keypoints import lower_body_mask, mirror_index, mirror_order
from pedx_graph.data.detector_model import corrupt_keypoints
from pedx_graph.data.types import RawCamera, StereoCalibration
from pedx_graph.detections.pixel_units import to_detector_units
from pedx_graph.sim import cameras
from pedx_graph.sim.config import DETECTOR_FORMATS, PEDX_VERTICAL_DISPARITY_SD_PX, DetectorOutputConfig
from pedx_graph.utils import atomic_write_bytes

#: Noise factor of keypoints without a PedX counterpart, by a part of their name (relative to a median
#: click; PedX's measured per-keypoint click noise gives the factors of the others): surface hips are as
#: ambiguous under clothing as PedX's hips, ears and toes are small sharp features, the head top is hidden
#: in hair.
EXTRA_SIGMA_SCALE: dict[str, float] = {"hip": 5.9 / 3.0, "neck": 1.0, "ear": 0.7, "toe": 1.0, "heel": 1.0,
                                       "head": 1.3}


def image_name(sequence: str, camera: str, frame: int) -> str:
    """The release's image name ``<seq>_<cam>_<frame:07d>`` (no extension)."""
    return f"{sequence}_{camera}_{int(frame):07d}"


def openpose_path(root: Path, fmt: str, sequence: str, camera: str, frame: int) -> Path:
    """``detections/<fmt>/<seq>/<cam>/<seq>_<cam>_<frame:07d>_keypoints.json`` under ``root``."""
    return Path(root) / "detections" / fmt / sequence / camera / f"{image_name(sequence, camera, frame)}_keypoints.json"


def coco_paths(root: Path, sequence: str) -> tuple[Path, Path]:
    """(image list, results) of the COCO output of one sequence."""
    base = Path(root) / "detections" / "coco" / sequence
    return base / "image_list.json", base / "keypoint_results.json"


# ---------------------------------------------------------------------------------------------- raw cameras

def raw_cameras(calibs: dict[str, StereoCalibration], config: DetectorOutputConfig, seed: int
                ) -> dict[str, StereoCalibration]:
    """The pairs with a raw image model per camera (module docstring); draws from ``(seed, 6, camera index)``."""
    out = {}
    for p, (name, calib) in enumerate(calibs.items()):
        raws = []
        for s, (P_rect, side) in enumerate(((calib.left_P_rect, "left"), (calib.right_P_rect, "right"))):
            rng = np.random.default_rng([int(seed), 6, 2 * p + s])
            fx_j, fy_j, cx_j, cy_j, k1, k2, t1, t2 = rng.random(8)
            raw_K = np.array(P_rect[:, :3], dtype=float)
            raw_K[0, 0] *= 1 + config.raw_focal_jitter * (2 * fx_j - 1)
            raw_K[1, 1] *= 1 + config.raw_focal_jitter * (2 * fy_j - 1)
            raw_K[0, 2] += config.raw_principal_jitter_px * (2 * cx_j - 1)
            raw_K[1, 2] += config.raw_principal_jitter_px * (2 * cy_j - 1)
            raw_K[:2, 2] += np.asarray(config.raw_margin_px, dtype=float)
            raw_size = None
            if any(config.raw_margin_px):
                raw_size = tuple(int(round(v + 2 * m)) for v, m in zip(calib.image_size, config.raw_margin_px))
            lo1, hi1 = config.distortion_k1
            lo2, hi2 = config.distortion_k2
            raw_D = np.array([lo1 + (hi1 - lo1) * k1, lo2 + (hi2 - lo2) * k2,
                              config.distortion_tangential * (2 * t1 - 1),
                              config.distortion_tangential * (2 * t2 - 1), 0.0])
            rect_R_cam = np.asarray(calib.rect_R_cam, dtype=float)
            if side == "right" and config.right_rect_rotation_deg > 0:
                # the raw right camera turned against the left: R_rect_01 = R_rect_00 @ R (own generator, so
                # that the other draws are those of a parallel pair)
                axis = np.random.default_rng([int(seed), 11, p]).normal(size=3)
                rotvec = np.deg2rad(config.right_rect_rotation_deg) * axis / np.linalg.norm(axis)
                rect_R_cam = rect_R_cam @ cv2.Rodrigues(rotvec)[0]
            raws.append(RawCamera(raw_K=raw_K, raw_D=raw_D, rect_R_cam=rect_R_cam,
                                  P_rect=np.asarray(P_rect, dtype=float), image_size=raw_size))
        out[name] = dataclasses.replace(calib, left_raw=raws[0], right_raw=raws[1])
    return out


def detector_image_size(calib: StereoCalibration, raw: RawCamera | None, config: DetectorOutputConfig
                        ) -> tuple[int, int]:
    """(width, height) of the images the detector ran on, before ``image_scale``: the raw image's (``S_0x``)
    when detected on raw images that have a size of their own, else the rectified one's."""
    if config.detected_on == "raw" and raw is not None and raw.image_size is not None:
        return tuple(int(v) for v in raw.image_size)
    return tuple(int(v) for v in calib.image_size)


def _detector_sees(rect_uv: np.ndarray, view, raw: RawCamera | None, size: tuple[int, int],
                   config: DetectorOutputConfig) -> np.ndarray:
    """(K,) which keypoints (rectified ``rect_uv`` (K, 2)) the image the detector ran on holds (``size``:
    :func:`detector_image_size`): a raw image of a size of its own (``raw_margin_px``) the points whose
    distorted pixels lie inside it, within twice the margin of the rectified image (beyond it the distortion
    polynomial folds far points back in); else the rectified image's (no distortion computed)."""
    rect_size = tuple(view.calib.image_size)
    if tuple(size) == rect_size:
        return view.in_image(rect_uv)
    margin = 2.0 * np.asarray(config.raw_margin_px, dtype=float)
    near = _inside(np.asarray(rect_uv, dtype=float) + margin, tuple(np.asarray(rect_size) + 2 * margin))
    return near & _inside(_distort(rect_uv, raw), size)


def _inside(uv: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """(K,) whether each pixel (``uv`` (K, 2)) lies inside an image of ``size`` (width, height)."""
    uv = np.asarray(uv, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= 0) & (uv[:, 0] < size[0]) & (uv[:, 1] >= 0) \
            & (uv[:, 1] < size[1])


# ---------------------------------------------------------------------------------------------- keypoint sets

def sigma_scale(set_name: str) -> np.ndarray:
    """(K,) noise factor per keypoint of a set: PedX's measured per-keypoint click noise relative to its
    median for points PedX has, :data:`EXTRA_SIGMA_SCALE` by name for the others (1 when none applies)."""
    kset = load_keypoint_set(set_name)
    median = float(np.median(list(PEDX_VERTICAL_DISPARITY_SD_PX.values())))
    out = []
    for name in kset.keypoints:
        pedx = kset.pedx_equivalent.get(name)
        if pedx is None and name in PEDX_VERTICAL_DISPARITY_SD_PX:
            pedx = name
        if pedx is not None:
            out.append(PEDX_VERTICAL_DISPARITY_SD_PX[pedx] / median)
            continue
        lower = name.lower()
        out.append(next((v for part, v in EXTRA_SIGMA_SCALE.items() if part in lower), 1.0))
    return np.asarray(out, dtype=float)


def shifted_definitions(model, shift_m: float, seed: tuple) -> KeypointMap:
    """``model``'s keypoint map with every keypoint moved by about ``shift_m`` metres
    (``DetectorOutputConfig.definition_shift_m``): plus the vertex ``b`` minus the vertex ``a``, ``a`` the rest
    mesh's vertex nearest the keypoint, ``b`` one drawn (from ``seed``) among those between 0.75 and 1.25
    ``shift_m`` from ``a`` (the nearest to ``shift_m`` when there is none).  Still a linear map of the posed
    vertices and joints; the offset turns and stretches with the skin around the point."""
    kmap = model.keypoint_map
    rest_v = np.asarray(model.v_template, dtype=float)
    rest_kp = kmap.apply(rest_v[kmap.vertex_ids], model.rest_joints(np.zeros(model.num_betas)))
    rng = np.random.default_rng(list(seed))
    moves = []
    for point in rest_kp:
        anchor = int(np.argmin(np.linalg.norm(rest_v - point, axis=1)))
        distance = np.linalg.norm(rest_v - rest_v[anchor], axis=1)
        ring = np.flatnonzero(np.abs(distance - shift_m) <= 0.25 * shift_m)
        other = int(rng.choice(ring)) if len(ring) else int(np.argmin(np.abs(distance - shift_m)))
        moves.append((anchor, other))
    ids = np.unique(np.concatenate([kmap.vertex_ids, np.array(moves, dtype=np.int64).ravel()]))
    coeffs = np.zeros((kmap.num_keypoints, len(ids)))
    coeffs[:, np.searchsorted(ids, kmap.vertex_ids)] = kmap.vertex_coeffs
    for k, (anchor, other) in enumerate(moves):
        coeffs[k, np.searchsorted(ids, anchor)] -= 1.0
        coeffs[k, np.searchsorted(ids, other)] += 1.0
    return dataclasses.replace(kmap, vertex_ids=ids, vertex_coeffs=coeffs,
                               source=f"{kmap.source}+shift{shift_m:g}")


def clutter_template(body_model, set_name: str) -> np.ndarray:
    """(K, 2) a standing person's keypoints of the set, front view, unit height (v down, u centred):
    :func:`~pedx_graph.body.keypoint_defs.standing_keypoints_2d`."""
    return standing_keypoints_2d(body_model, set_name)


# ---------------------------------------------------------------------------------------------- one frame

@dataclasses.dataclass
class _Candidate:
    tracking_id: str
    labelled: bool
    rect_uv: np.ndarray
    visible: np.ndarray
    in_image: np.ndarray


def _confidence(error_px: np.ndarray, sigma_px: np.ndarray, visible: np.ndarray, height_px: float,
                config: DetectorOutputConfig, rng: np.random.Generator) -> np.ndarray:
    base = np.where(visible, config.confidence_visible, config.confidence_occluded)
    base = base * height_px / (height_px + config.confidence_half_height_px)
    e = error_px / (config.confidence_error_sigmas * np.maximum(sigma_px, 1e-6))
    noise = config.confidence_noise * rng.normal(size=len(error_px))
    return np.clip(base * np.exp(-0.5 * e ** 2) + noise, 0.02, 1.0)


def _person_detection(raw_uv: np.ndarray, visible: np.ndarray, present: np.ndarray, raw: RawCamera,
                      image_size: tuple[int, int], set_name: str, config: DetectorOutputConfig,
                      rng: np.random.Generator, shared_unit: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(K, 2) raw pixels (NaN = absent) and (K,) confidences of one detected person; ``shared_unit``: the
    person's draws common to every camera (``DetectorOutputConfig.stereo_shared_noise``)."""
    noise = config.keypoint_noise
    ok = present & np.all(np.isfinite(raw_uv), axis=1)
    pts = raw_uv[ok]
    height = float(np.ptp(pts[:, 1])) if len(pts) >= 2 else 0.0
    box = (pts.min(axis=0), pts.max(axis=0)) if len(pts) else (np.zeros(2), np.zeros(2))
    scale = sigma_scale(set_name)
    uv0 = np.where(ok[:, None], raw_uv, 0.0)
    uv, _ = corrupt_keypoints(uv0, ok, visible & ok, height, box, noise, rng, image_size,
                              swap_index=mirror_index(load_keypoint_set(set_name).keypoints), sigma_scale=scale,
                              shared_unit=shared_unit, shared_fraction=config.stereo_shared_noise)
    sigma = np.hypot(noise.sigma_px, noise.sigma_height_frac * height) * scale
    sigma = np.where(visible, sigma, sigma * noise.occluded_sigma_factor)
    error = np.linalg.norm(np.where(np.isfinite(uv), uv - uv0, 0.0), axis=1)
    if config.swap_keeps_confidence:          # an exchanged keypoint localises its mirror point well
        order = mirror_order(set_name)
        mirror_error = np.linalg.norm(np.where(np.isfinite(uv), uv - uv0[order], 0.0), axis=1)
        error = np.where(ok[order], np.minimum(error, mirror_error), error)
    conf = _confidence(error, sigma, visible, height, config, rng)
    width, height_img = image_size
    inside = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] > 0) & (uv[:, 0] < width - 1) & (uv[:, 1] > 0) \
        & (uv[:, 1] < height_img - 1)
    uv[~inside] = np.nan
    conf[~inside] = 0.0
    return uv, conf


def _fragment(uv: np.ndarray, conf: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A partial duplicate: the lower or upper half of the present keypoints, shifted, lower confidence."""
    present = np.flatnonzero(np.all(np.isfinite(uv), axis=1))
    out_uv, out_conf = np.full_like(uv, np.nan), np.zeros_like(conf)
    lower_half, shift, factor = rng.random(), rng.normal(size=2), rng.uniform(0.4, 0.8)
    if len(present) < 4:
        return out_uv, out_conf
    v = uv[present, 1]
    keep = present[v >= np.median(v)] if lower_half < 0.5 else present[v < np.median(v)]
    height = float(np.ptp(v))
    out_uv[keep] = uv[keep] + shift * 0.04 * height
    out_conf[keep] = conf[keep] * factor
    return out_uv, out_conf


def _split(uv: np.ndarray, conf: np.ndarray, set_name: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """A person's detection broken in two by a bottom-up detector's grouping: the upper body (head, neck,
    arms) and the hips and legs (:func:`~pedx_graph.keypoints.lower_body_mask`), each a detection
    of its own; a part with fewer than two keypoints is not written."""
    lower = lower_body_mask(set_name)
    out = []
    for mask in (~lower, lower):
        part_uv, part_conf = np.where(mask[:, None], uv, np.nan), np.where(mask, conf, 0.0)
        if (part_conf > 0).sum() >= 2:
            out.append((part_uv, part_conf))
    return out


def _clutter(template: np.ndarray, image_size: tuple[int, int], rng: np.random.Generator
             ) -> tuple[np.ndarray, np.ndarray]:
    """A false detection: the template at a random place and size, heavily jittered, a random subset kept."""
    width, height = image_size
    k = len(template)
    size, u0, v0 = rng.uniform(40.0, 0.4 * height), rng.uniform(0, width), rng.uniform(0, height)
    jitter, keep_draw, conf = rng.normal(size=(k, 2)), rng.random(k), rng.uniform(0.05, 0.5, size=k)
    keep_frac = rng.uniform(0.3, 0.9)
    uv = np.stack([u0 + template[:, 0] * size, v0 - size + template[:, 1] * size], axis=1) + 0.08 * size * jitter
    keep = (keep_draw < keep_frac) & (uv[:, 0] > 0) & (uv[:, 0] < width - 1) & (uv[:, 1] > 0) & (uv[:, 1] < height - 1)
    uv[~keep] = np.nan
    conf = np.where(keep, conf, 0.0)
    return uv, conf


def frame_detections(ctx, k: int, ray_scene, bodies: dict, present_people: list, labelled: set) -> dict:
    """Simulate and write one frame's detector files (OpenPose formats) and return the COCO entries and the
    truth records: ``{fmt: [(camera, frame, uv (K, 2), conf (K,), truth record)]}``."""
    config = ctx.config
    det_cfg = config.detections
    seq, frame = config.scene.sequence, config.scene.first_frame + k
    vis_tol = config.labels.visibility_tolerance_m
    out: dict[str, list] = {}
    for f_index, fmt in enumerate(det_cfg.formats):
        set_name = DETECTOR_FORMATS[fmt]
        model = ctx.body_model.for_keypoint_set(set_name)
        kmap = model.keypoint_map
        if det_cfg.definition_shift_m > 0:
            kmap = shifted_definitions(model, det_cfg.definition_shift_m, (int(ctx.seed), 12, f_index))
        template = clutter_template(ctx.body_model, set_name)
        rng = np.random.default_rng([int(ctx.seed), 5, int(k), f_index])
        set_points = {tid: kmap.apply(body.vertices[kmap.vertex_ids], body.joints) for tid, body in bodies.items()}
        entries = []
        for calib in ctx.calibs.values():
            for view in cameras.camera_views(calib):
                raw = calib.left_raw if view.side == "left" else calib.right_raw
                size = detector_image_size(calib, raw, det_cfg)
                people_uv = []
                for p_index, person in enumerate(present_people):
                    tid = person.tracking_id
                    rect_uv, depth = view.project(set_points[tid])
                    in_image = _detector_sees(rect_uv, view, raw, size, det_cfg) & (depth > 0.5)
                    draws = rng.random(3)
                    if in_image.sum() < det_cfg.min_visible_keypoints:
                        continue
                    visible = cameras.point_visibility(ray_scene, view, set_points[tid], vis_tol) & in_image
                    span = float(np.ptp(rect_uv[in_image, 1]))
                    if visible.sum() < det_cfg.min_visible_keypoints or span < det_cfg.min_height_px:
                        continue
                    occluded_frac = 1.0 - visible.sum() / in_image.sum()
                    if draws[0] < det_cfg.person_miss_prob + det_cfg.occluded_miss_prob * occluded_frac:
                        continue
                    # the pixels of the image the detector ran on (named raw_uv either way)
                    raw_uv = _distort(rect_uv, raw) if det_cfg.detected_on == "raw" else rect_uv.copy()
                    shared = None
                    if det_cfg.stereo_shared_noise > 0:      # the same draws in every camera (own generator)
                        shared = np.random.default_rng([int(ctx.seed), 7, int(k), f_index, p_index]).normal(
                            size=(len(raw_uv), 2))
                    uv, conf = _person_detection(raw_uv, visible, in_image, raw, size, set_name, det_cfg, rng,
                                                 shared)
                    if not (conf > 0).any():
                        continue
                    order = None
                    if det_cfg.flip_prob > 0 and np.random.default_rng(
                            [int(ctx.seed), 9, int(k), f_index, p_index]).random() < det_cfg.flip_prob:
                        # own generator, one draw per person and frame: every camera flipped alike
                        order = mirror_order(set_name)
                        uv, conf = uv[order], conf[order]
                        record = {"kind": "person", "tracking_id": tid, "labelled": tid in labelled, "flipped": True}
                    else:
                        record = {"kind": "person", "tracking_id": tid, "labelled": tid in labelled}
                    duplicate = None
                    if det_cfg.duplicate_prob > 0:
                        # own generator: the other draws (and so the files at duplicate_prob 0) are unchanged
                        dup_rng = np.random.default_rng([int(ctx.seed), 10, int(k), f_index, p_index,
                                                         zlib.crc32(view.camera.encode())])
                        if dup_rng.random() < det_cfg.duplicate_prob:
                            d_uv, d_conf = _person_detection(raw_uv, visible, in_image, raw, size, set_name, det_cfg,
                                                             dup_rng, shared)
                            if order is not None:
                                d_uv, d_conf = d_uv[order], d_conf[order]
                            if (d_conf > 0).any():
                                duplicate = (d_uv, d_conf, {**record, "duplicate": True})
                    if det_cfg.split_prob > 0 and fmt.startswith("openpose_") and np.random.default_rng(
                            [int(ctx.seed), 8, int(k), f_index, p_index, zlib.crc32(view.camera.encode())]).random() < det_cfg.split_prob:
                        # own generator: the other draws (and so the files at split_prob 0) are unchanged
                        people_uv += [(part_uv, part_conf, {**record, "kind": "part"})
                                      for part_uv, part_conf in _split(uv, conf, set_name)]
                    else:
                        people_uv.append((uv, conf, record))
                    if duplicate is not None:
                        people_uv.append(duplicate)
                    if draws[1] < det_cfg.fragment_prob:
                        f_uv, f_conf = _fragment(uv, conf, rng)
                        if (f_conf > 0).sum() >= 2:
                            people_uv.append((f_uv, f_conf, {"kind": "fragment", "tracking_id": tid}))
                for _ in range(int(rng.poisson(det_cfg.clutter_per_image))):
                    c_uv, c_conf = _clutter(template, size, rng)
                    if (c_conf > 0).sum() >= 2:
                        people_uv.append((c_uv, c_conf, {"kind": "clutter"}))
                if det_cfg.image_scale != 1.0 or det_cfg.pixel_units != "pixels":
                    people_uv = [(to_detector_units(uv, size, (det_cfg.image_scale,) * 2, det_cfg.pixel_units),
                                  conf, record) for uv, conf, record in people_uv]
                for index, (uv, conf, record) in enumerate(people_uv):
                    entries.append((view.camera, frame, uv, conf,
                                    {"camera": view.camera, "frame": frame, "index": index, **record}))
                if fmt.startswith("openpose_"):
                    write_openpose(openpose_path(ctx.out, fmt, seq, view.camera, frame),
                                   [(uv, conf) for uv, conf, _ in people_uv], _digits(det_cfg.pixel_units))
        out[fmt] = entries
    return out


def _distort(rect_uv: np.ndarray, raw: RawCamera) -> np.ndarray:
    from pedx_graph.detections.undistort import distort

    return distort(rect_uv, raw)


# ---------------------------------------------------------------------------------------------- writers

def _triplets(uv: np.ndarray, conf: np.ndarray, digits: int = 3) -> list[float]:
    """``[x0, y0, c0, ...]`` with absent keypoints as ``0, 0, 0`` (coordinates rounded to ``digits`` decimals:
    1/1000 px, or 7 for normalised coordinates)."""
    out = []
    for (u, v), c in zip(uv, conf):
        if np.isfinite(u) and np.isfinite(v) and c > 0:
            out += [round(float(u), digits), round(float(v), digits), round(float(c), 4)]
        else:
            out += [0.0, 0.0, 0.0]
    return out


def _digits(pixel_units: str) -> int:
    """Decimals a written coordinate keeps: 1/1000 px, or 1e-7 of the image for normalised ones."""
    return 3 if pixel_units == "pixels" else 7


def write_openpose(path: Path, people: list[tuple[np.ndarray, np.ndarray]], digits: int = 3) -> Path:
    """One OpenPose JSON file (``version`` 1.3, ``person_id`` [-1], empty face/hand arrays)."""
    doc = {"version": 1.3, "people": [
        {"person_id": [-1], "pose_keypoints_2d": _triplets(uv, conf, digits), "face_keypoints_2d": [],
         "hand_left_keypoints_2d": [], "hand_right_keypoints_2d": [], "pose_keypoints_3d": [],
         "face_keypoints_3d": [], "hand_left_keypoints_3d": [], "hand_right_keypoints_3d": []}
        for uv, conf in people]}
    return atomic_write_bytes(path, (json.dumps(doc, separators=(",", ":")) + "\n").encode("utf-8"))


def write_sequence_files(out: Path, config, calibs: dict[str, StereoCalibration], entries: dict[str, list]) -> dict:
    """After every frame: the COCO image list and results (when ``coco`` is a format) and the truth records;
    ``entries`` = the concatenated per-frame outputs of :func:`frame_detections`.  Returns counts per format."""
    seq = config.scene.sequence
    sc = config.scene
    camera_names = [name for calib in calibs.values() for name in calib.name.split("-")]
    scale = config.detections.image_scale
    sizes = {name: tuple(int(round(v * scale)) for v in detector_image_size(calib, raw, config.detections))
             for calib in calibs.values()
             for name, raw in zip(calib.name.split("-"), (calib.left_raw, calib.right_raw))}
    counts = {}
    for fmt, items in entries.items():
        items = sorted(items, key=lambda e: (e[1], camera_names.index(e[0]), e[4]["index"]))
        if fmt == "coco":
            set_name = DETECTOR_FORMATS[fmt]
            images, image_id = [], {}
            for k in range(sc.n_frames):
                frame = sc.first_frame + k
                for c, cam in enumerate(camera_names):
                    image_id[(cam, frame)] = k * len(camera_names) + c + 1
                    images.append({"id": image_id[(cam, frame)],
                                   "file_name": f"images/{seq}/{cam}/{image_name(seq, cam, frame)}.jpg",
                                   "width": int(sizes[cam][0]), "height": int(sizes[cam][1])})
            categories = [{"id": 1, "name": "person", "supercategory": "person",
                           "keypoints": list(load_keypoint_set(set_name).keypoints), "skeleton": []}]
            results = []
            for cam, frame, uv, conf, _ in items:
                present = conf > 0
                results.append({"image_id": image_id[(cam, frame)], "category_id": 1,
                                "keypoints": _triplets(uv, conf, _digits(config.detections.pixel_units)),
                                "score": round(float(conf[present].mean()) if present.any() else 0.0, 4)})
            list_path, results_path = coco_paths(out, seq)
            atomic_write_bytes(list_path, (json.dumps({"images": images, "categories": categories},
                                                      separators=(",", ":")) + "\n").encode("utf-8"))
            atomic_write_bytes(results_path, (json.dumps(results, separators=(",", ":")) + "\n").encode("utf-8"))
        truth = [record for *_, record in items]
        atomic_write_bytes(Path(out) / "truth" / "detections" / seq / f"{fmt}.json",
                           (json.dumps(truth, separators=(",", ":")) + "\n").encode("utf-8"))
        kinds = [r["kind"] for r in truth]
        counts[fmt] = {kind: kinds.count(kind) for kind in ("person", "fragment", "clutter")}
    return counts
