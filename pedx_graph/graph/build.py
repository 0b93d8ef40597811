"""One nonlinear factor graph per pedestrian track (the paper's energy, Sec. IV, as GTSAM factors).

Variables: per frame ``i`` the root orientation ``r<i>`` (``Rot3``, ``world_R_body``), the translation
``t<i>`` (3) and the body pose ``p<i>`` (69); one shape ``b0`` (10) shared by the whole track — the graph's
shared node replaces the paper's ADMM consensus.

Factors, one per frame per term (few, vectorised callbacks):

* ``stereo_reprojection`` — E_J,l + E_J,r: every image labelling the pedestrian at the frame in one factor
  (both pairs' when both labelled it, ``terms.all_views``; left or right images can be switched off);
* ``lidar_chamfer`` — E_3d, Eq. 4; ``translation_prior`` — E_T, Eq. 2; ``heading_prior`` — E_D, Eq. 3;
* ``pose_prior`` + ``joint_limits`` — E_P; ``temporal_prior`` — E_tp, Eq. 10, between consecutive observed
  frames (a gap of k frame periods weakens it); ``shape_prior`` once (the Gaussian prior and its support hinge,
  two factors of that kind).
"""
from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field

import gtsam
import numpy as np

from factors.common import FrameKeys
from factors.heading_prior import make_heading_prior_factor
from factors.joint_limits import make_joint_limit_factor
from factors.lidar_chamfer import facing_margin, make_lidar_chamfer_factor
from factors.pose_prior import make_pose_prior_factor
from factors.registry import frame_terms
from factors.shape_prior import shape_factors
from factors.stereo_reprojection import images_from_views, make_reprojection_factor
from factors.temporal_prior import make_temporal_prior_factor
from factors.translation_prior import make_translation_prior_factor
from pedx_graph.body.rotation import log_so3
from pedx_graph.data.ground import GroundFrame
from pedx_graph.data.noise_estimate import chamfer_sigma_m, keypoint_row_sigmas_px
from pedx_graph.data.types import StereoCalibration, Track, TrackFrame
from pedx_graph.graph.batch import BatchedBodyModel
from pedx_graph.graph.config import FitConfig
from pedx_graph.graph.context import EstimatorContext
from pedx_graph.graph.layout import ChainLayout
from pedx_graph.graph.init import TrackInit, initialise_track, world_R_body_from_yaw
from pedx_graph.keypoints import PEDX_KEYPOINTS

log = logging.getLogger(__name__)

_ROBUST_NAMES = {"geman_mcclure": "gemanmcclure", "gemanmcclure": "gemanmcclure", "huber": "huber",
                 "cauchy": "cauchy", "none": "none"}


def _robust(name: str) -> str:
    try:
        return _ROBUST_NAMES[name.lower()]
    except KeyError:
        raise ValueError(f"unknown robust loss {name!r}; choose one of {sorted(_ROBUST_NAMES)}") from None


@dataclass
class TrackProblem:
    """A track's graph, its initial values and the bookkeeping to read the estimate back."""

    graph: gtsam.NonlinearFactorGraph
    initial: gtsam.Values
    keys: list[FrameKeys]
    init: TrackInit
    factor_kinds: list[str] = field(default_factory=list)
    """Kind of each factor of ``graph`` (same order), e.g. ``"stereo_reprojection"``."""
    factor_frames: list[int] = field(default_factory=list)
    """Frame index (into the track) of each factor; -1 for track-level factors."""
    body: BatchedBodyModel | None = None
    """The batched body model the factors of this graph evaluate."""
    _layout: object = field(default=None, repr=False)

    active_kinds: frozenset | None = None
    """The factor kinds this graph holds when it is a :meth:`without` view (None: all registered)."""
    ground: GroundFrame | None = None
    """The track's up axis, level frame and viewpoint (``Track.ground``), for diagnostics along them."""

    def prefetch(self, values: gtsam.Values, jacobians: bool) -> None:
        """Batch-evaluate the body model for every frame before the graph is linearised / evaluated."""
        if self.body is not None:
            kinds = self.active_kinds
            self.body.prefetch(values, self.keys, jacobians,
                               vertices=kinds is None or "lidar_chamfer" in kinds, kinds=kinds)

    def without(self, kinds) -> "TrackProblem":
        """The same problem minus the factors of ``kinds`` (same factor objects, keys and initial values;
        e.g. the first, chamfer-free stage of the staged fit)."""
        drop = set(kinds)
        graph = gtsam.NonlinearFactorGraph()
        kept_kinds, kept_frames = [], []
        for j, (kind, frame) in enumerate(zip(self.factor_kinds, self.factor_frames)):
            if kind not in drop:
                graph.add(self.graph.at(j))
                kept_kinds.append(kind)
                kept_frames.append(frame)
        return TrackProblem(graph=graph, initial=self.initial, keys=self.keys, init=self.init,
                            factor_kinds=kept_kinds, factor_frames=kept_frames, body=self.body,
                            active_kinds=frozenset(kept_kinds), ground=self.ground)

    @property
    def layout(self):
        """The chain + arrow layout of this track's keys (:class:`pedx_graph.graph.layout.ChainLayout`)."""
        if self._layout is None:
            self._layout = ChainLayout(self.keys, int(self.initial.atVector(self.keys[0].betas).shape[0]))
        return self._layout


@dataclass
class TrackEstimate:
    pose: np.ndarray          # (T, 72)
    betas: np.ndarray         # (B,)
    trans: np.ndarray         # (T, 3)
    world_keypoints: np.ndarray   # (T, 18, 3) PedX keypoints of the reported model


def _hip_weights(config: FitConfig, rows: int = len(PEDX_KEYPOINTS)) -> np.ndarray:
    """(rows,) keypoint weights of the reprojection term: the hips' from ``hip_sigma_factor``, 1 elsewhere
    (``rows`` > 18: a detector track's fit layout, its extra keypoints after the PedX rows)."""
    weights = np.ones(rows)
    for name in ("lhip", "rhip"):
        weights[PEDX_KEYPOINTS.index(name)] = 1.0 / config.noise.hip_sigma_factor ** 2
    return weights


def _row_sigmas_px(noise, rows: int = len(PEDX_KEYPOINTS)) -> np.ndarray:
    """(rows,) configured sigma of visible keypoint labels: the PedX rows' (``keypoint_row_sigmas_px``), then
    ``keypoint_sigma_px`` (the whole-figure sigma) for a fit layout's extra rows, whose labels normally carry
    their own ``sigma_px`` (``factors.stereo_reprojection.ImageKeypoints.sigma_px``)."""
    pedx = keypoint_row_sigmas_px(noise)
    return np.concatenate([pedx, np.full(rows - len(pedx), float(noise.keypoint_sigma_px))])


def reprojection_noise(config: FitConfig, rows: int = len(PEDX_KEYPOINTS)) -> dict:
    """The reprojection term's noise arguments for labels of ``rows`` keypoint rows (``sigma_px``,
    ``sigma_occluded_px``, ``keypoint_weights``, ``robust``, ``robust_scale`` of
    :func:`factors.stereo_reprojection.make_reprojection_factor`): what the graph's factors use, also for
    the label screens that judge one image's labels by that term's loss."""
    noise = config.noise
    return dict(sigma_px=_row_sigmas_px(noise, rows), sigma_occluded_px=noise.occluded_keypoint_sigma_px,
                keypoint_weights=_hip_weights(config, rows), robust=_robust(noise.reprojection_loss),
                robust_scale=noise.reprojection_loss_scale)


def _subsample(points: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    points = points[np.all(np.isfinite(points), axis=1)]
    if len(points) > count:
        points = points[np.sort(rng.choice(len(points), size=count, replace=False))]
    return points


def core_points(world_points: np.ndarray, ground: GroundFrame, radius_m: float = 0.5) -> np.ndarray:
    """The instance points within ``radius_m`` (measured in the ground plane of ``ground``) of their median
    (:meth:`GroundFrame.median_point`): the 2D polygons also pick up background and other people's points,
    which would drag a plain mean (paper Eq. 2) by metres."""
    if len(world_points) < 3:
        return world_points
    median = ground.median_point(world_points)
    offset = world_points - median
    offset = offset - np.outer(offset @ ground.world_up, ground.world_up)
    keep = np.linalg.norm(offset, axis=1) <= radius_m
    return world_points[keep] if keep.any() else world_points


def select_template_poses(track: Track, ctx: EstimatorContext, world_R_body: np.ndarray,
                          world_p_centre: np.ndarray, clip_px: float = 40.0, all_views: bool = True) -> np.ndarray:
    """Per frame, the candidate body pose (``ctx.template_candidates``) whose keypoints, placed at the
    initial orientation and centre, best reproject onto the frame's 2D labels (every labelled image of every
    pair, ``TrackFrame.labelled_views``; the primary pair's only when not ``all_views``; squared pixel
    residuals clipped at ``clip_px``).  Returns (T, 69)."""
    cands = ctx.template_candidates
    n = len(track.frames)
    if cands is None or len(cands) == 1:
        return np.tile(ctx.template_body_pose, (n, 1))
    model = ctx.model
    nb = model.num_betas
    pelvis_rest = model.rest_joints(np.zeros(nb))[0]
    out = np.empty((n, cands.shape[1]))
    num_c = len(cands)
    roots = log_so3(np.asarray(world_R_body, dtype=float))                       # (T, 3)
    pose = np.concatenate([np.repeat(roots, num_c, axis=0), np.tile(cands, (n, 1))], axis=1)
    trans = np.repeat(np.asarray(world_p_centre, dtype=float) - pelvis_rest, num_c, axis=0)
    all_kps = model.keypoints(pose, np.zeros((n * num_c, nb)), trans).reshape(n, num_c, -1, 3)
    for i, fr in enumerate(track.frames):
        kps = all_kps[i]
        projected = {pair: track.calibrations[pair].project(kps) for pair in fr.pairs}
        cost = np.zeros(len(cands))
        for pair, side, view in fr.labelled_views(all_views):
            uv = projected[pair][0 if side == "left" else 1]
            ok = view.labelled
            d2 = np.sum((uv[:, ok] - view.keypoints[ok]) ** 2, axis=-1)
            cost += np.minimum(d2, clip_px ** 2).sum(axis=1)
        out[i] = cands[int(np.argmin(cost))]
    return out


def fitted_views(fr: TrackFrame, terms, all_pairs: bool = True) -> list:
    """``(pair, side, view)`` of the images a frame's reprojection factor holds: every labelled image
    (``terms.all_views``; only the primary pair's otherwise, or when ``all_pairs`` is False) of the sides
    ``terms.left_reprojection`` / ``terms.right_reprojection`` switch on."""
    sides = {"left": terms.left_reprojection, "right": terms.right_reprojection}
    return [v for v in fr.labelled_views(terms.all_views and all_pairs) if sides[v[1]]]


def frame_factors(k: FrameKeys, fr: TrackFrame, calibration: StereoCalibration | Mapping[str, StereoCalibration],
                  previous: tuple[FrameKeys, float] | None, heading_yaw: float, speed_mps: float,
                  model, ctx: EstimatorContext, config: FitConfig,
                  rng: np.random.Generator, heading_sigma_rad: float = 0.0, *,
                  ground: GroundFrame) -> list[tuple[gtsam.NonlinearFactor, str]]:
    """The factors of one frame (every term but the track's shape prior), as ``(factor, kind)`` pairs.

    ``k``: the frame's keys; ``calibration``: the stereo pairs by name (``Track.calibrations``; a single
    :class:`StereoCalibration` stands for the frame's primary pair and only its views are used);
    ``previous``: (keys, timestamp) of the track's previous observed frame for the
    temporal prior, or None; ``heading_yaw``/``speed_mps``: the trajectory heading (NaN: unknown) and
    speed; ``model``: the body model the factors evaluate (a :class:`BatchedBodyModel` in batch fits);
    ``rng``: draws the LiDAR subsample; ``heading_sigma_rad``: the trajectory heading's own uncertainty
    (``TrackInit.heading_sigma_rad``; inf: no heading factor); ``ground``: the sequence's up axis, level
    frame and viewpoint (``Track.ground``).  Shared by the batch builder and the streaming estimator so the
    two graphs stay identical.
    """
    noise, terms = config.noise, config.terms
    out: list[tuple[gtsam.NonlinearFactor, str]] = []

    def add(factor, kind: str) -> None:
        if factor is not None:
            out.append((factor, kind))

    calibrations = {fr.pair: calibration} if isinstance(calibration, StereoCalibration) else calibration
    views = fitted_views(fr, terms, all_pairs=not isinstance(calibration, StereoCalibration))
    if views:
        rows = len(views[0][2].keypoints)          # 18, or 18 + E in a detector track's fit layout
        add(make_reprojection_factor(k, model, images_from_views(views, calibrations),
                                     **reprojection_noise(config, rows)), "stereo_reprojection")
    points = _subsample(fr.world_lidar_points, noise.lidar_max_points, rng)
    if terms.lidar_chamfer and len(points):
        seen = {}
        if noise.lidar_seen_side:
            seen = dict(world_p_sensor=ground.world_p_sensor,
                        facing_cos=facing_margin(points, ground.world_p_sensor, noise.lidar_viewpoint_offset_m,
                                                 np.radians(noise.lidar_normal_tolerance_deg)))
        add(make_lidar_chamfer_factor(k, model, points, sigma_m=chamfer_sigma_m(noise),
                                      robust=_robust(noise.lidar_loss), robust_scale=noise.lidar_loss_scale,
                                      candidate_vertex_ids=ctx.chamfer_vertex_ids, **seen), "lidar_chamfer")
    if terms.translation_prior and len(points):
        add(make_translation_prior_factor(k.trans, k.betas, model, core_points(points, ground),
                                          world_up=ground.world_up, world_p_sensor=ground.world_p_sensor,
                                          num_betas=model.num_betas,
                                          depth_offset_m=noise.translation_depth_offset_m,
                                          sigma_ray_m=noise.translation_ray_sigma_m,
                                          sigma_lateral_m=noise.translation_sigma_m,
                                          sigma_vertical_m=noise.translation_vertical_sigma_m,
                                          robust=_robust(noise.translation_loss),
                                          robust_scale=noise.translation_loss_scale,
                                          cache=getattr(model, "term_cache", None)), "translation_prior")
    if terms.heading_prior and np.isfinite(heading_yaw) and np.isfinite(heading_sigma_rad):
        add(make_heading_prior_factor(k.root, heading_yaw, speed_mps, world_R_level=ground.world_R_level,
                                      sigma0_rad=noise.heading_sigma_rad,
                                      v0=noise.heading_min_speed_mps * 2,
                                      min_speed=noise.heading_min_speed_mps,
                                      cache=getattr(model, "term_cache", None),
                                      trajectory_sigma_rad=float(heading_sigma_rad)), "heading_prior")
    if terms.pose_prior:
        add(make_pose_prior_factor(k.body_pose, mixture=ctx.pose_mixture, cache=getattr(model, "term_cache", None)),
            "pose_prior")
        add(make_joint_limit_factor(k.body_pose, sigma_rad=noise.joint_limit_sigma_rad,
                                    cache=getattr(model, "term_cache", None)), "joint_limits")
    if terms.temporal_prior and previous is not None:
        kp, previous_time = previous
        gap = max(1, int(round((fr.timestamp - previous_time) / ctx.temporal_dt)))
        add(make_temporal_prior_factor(kp.root, kp.trans, kp.body_pose, k.root, k.trans, k.body_pose,
                                       mixture=ctx.temporal_mixture, frame_gap=gap,
                                       cache=getattr(model, "term_cache", None)), "temporal_prior")
    for term in frame_terms():          # registered terms that build their own factor (factors/registry.py)
        add(term.frame_factor(k, fr, model, ctx, config, ground), term.kind)
    return out


def _heading_sigma(init: TrackInit, i: int) -> float:
    """The trajectory heading's uncertainty of frame ``i`` (0 when the initialisation did not estimate it)."""
    return 0.0 if init.heading_sigma_rad is None else float(init.heading_sigma_rad[i])


def build_track_graph(track: Track, ctx: EstimatorContext, config: FitConfig,
                      yaw_override: np.ndarray | None = None,
                      initial: gtsam.Values | None = None, init: TrackInit | None = None) -> TrackProblem:
    """The factor graph and initial values of ``track`` (see the module docstring).

    ``yaw_override`` (T,) replaces the initial headings; ``initial`` replaces all initial values (e.g. the
    result of an earlier stage on the same track); ``init``: the track's :func:`initialise_track` with
    ``config``'s noise settings when already computed (e.g. the ``init`` of an earlier stage's problem).
    """
    if len(track.frames) == 0:
        raise ValueError(f"track {track.sequence}/{track.tracking_id} has no frames")
    if track.keypoint_set != "pedx18":
        raise ValueError(f"track {track.sequence}/{track.tracking_id}: its labels are {track.keypoint_set!r} "
                         "keypoints; lay the track out for the fit first (pedx_graph.detections.fit_layout."
                         "fit_layout; fit_track, fit_tracks and fit_dataset do)")
    noise = config.noise
    model = BatchedBodyModel(ctx.model, ctx.chamfer_vertex_ids)
    nb = model.num_betas
    if init is None:
        init = initialise_track(track, surface_offset_m=noise.translation_depth_offset_m,
                                min_speed_mps=noise.heading_min_speed_mps, size_prior=ctx.size_prior,
                                all_views=config.terms.all_views, sigma_px=noise.keypoint_sigma_px,
                                occluded_sigma_px=noise.occluded_keypoint_sigma_px)
    world_R_body = init.world_R_body if yaw_override is None else world_R_body_from_yaw(yaw_override, track.ground)
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    kinds: list[str] = []
    frames_of: list[int] = []

    def add(factor, kind: str, frame: int) -> None:
        if factor is not None:
            graph.add(factor)
            kinds.append(kind)
            frames_of.append(frame)

    rng = np.random.default_rng(config.seed)
    betas0 = np.zeros(nb)
    pelvis_rest = ctx.model.rest_joints(betas0)[0]
    keys = [FrameKeys.for_frame(i) for i in range(len(track.frames))]
    if initial is None:
        values.insert(keys[0].betas, betas0)
    body_pose0 = None if initial is not None else select_template_poses(track, ctx, world_R_body,
                                                                         init.world_p_centre,
                                                                         all_views=config.terms.all_views)
    for i, (fr, k) in enumerate(zip(track.frames, keys)):
        if initial is None:
            values.insert(k.root, gtsam.Rot3(world_R_body[i]))
            values.insert(k.trans, np.asarray(init.world_p_centre[i] - pelvis_rest, dtype=float))
            values.insert(k.body_pose, body_pose0[i].copy())
        previous = (keys[i - 1], track.frames[i - 1].timestamp) if i > 0 else None
        for factor, kind in frame_factors(k, fr, track.calibrations, previous,
                                          float(init.heading_yaw[i]), float(init.speed_mps[i]),
                                          model, ctx, config, rng, _heading_sigma(init, i), ground=track.ground):
            add(factor, kind, i)
    for factor in shape_factors(keys[0].betas, nb, noise.shape_sigma, noise.shape_support_sd,
                                noise.shape_support_sigma):      # the Gaussian prior and its support hinge
        add(factor, "shape_prior", -1)
    if initial is not None:
        values = gtsam.Values(initial)
    return TrackProblem(graph=graph, initial=values, keys=keys, init=init, factor_kinds=kinds,
                        factor_frames=frames_of, body=model, ground=track.ground)


def extract_estimate(problem: TrackProblem, values: gtsam.Values, ctx: EstimatorContext) -> TrackEstimate:
    """Read the per-frame SMPL parameters and world keypoints out of ``values``; the keypoints are the reported
    ones, PedX's 18 of ``ctx.model.report_model`` (the original model when ``ctx.model`` is a detector track's
    fit-layout model with 18 + E keypoints, ``pedx_graph.detections.fit_layout``)."""
    betas = np.asarray(values.atVector(problem.keys[0].betas), dtype=float)
    pose = np.stack([np.concatenate([gtsam.Rot3.Logmap(values.atRot3(k.root)), values.atVector(k.body_pose)])
                     for k in problem.keys])
    trans = np.stack([np.asarray(values.atVector(k.trans), dtype=float) for k in problem.keys])
    reported = getattr(ctx.model, "report_model", ctx.model)
    kps = reported.keypoints(pose, np.broadcast_to(betas, (len(pose), len(betas))), trans)
    return TrackEstimate(pose=pose, betas=betas, trans=trans, world_keypoints=np.asarray(kps))
