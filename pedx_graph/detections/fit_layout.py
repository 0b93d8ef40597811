"""Fit a track labelled in a detector's keypoint set with the PedX-ordered fit: the 18 + E row *fit layout*.

The initialisation (torso direction, triangulation, centre pixel, body-size depth) looks keypoints up by PedX
name in the 18 PedX rows; the reprojection term takes any number of rows (and with it everything that
evaluates the graph: the solvers, the flip search, the marginals).  A track in another set
(``coco17``, ``body25``, ...) is fitted through a *fit layout* of 18 + E rows:

* rows 0-17, PEDX_KEYPOINTS order: row ``i`` holds the set's keypoint that is PedX keypoint ``i``'s body
  point (``KeypointSet.pedx_equivalent``: same joint / same face point), and the body model used for the
  graph projects, in that row, the set's **own** definition of the point (``BodyModel.for_keypoint_set``) —
  never PedX's.  COCO's and OpenPose's surface hips have no PedX equivalent (PedX's hips are SMPL's joints):
  they fill the ``lhip`` / ``rhip`` rows with their own surface definition, so the hip rows project the
  right 3D point and the steps that look up "the hips" (torso direction, centre pixel) use the nearest
  thing the set has.  A PedX row the set lacks (``head``, ``mouth`` in COCO) stays unlabelled.
* rows 18 .. 18 + E - 1: the set's E keypoints that fill no PedX row (ears, big / small toes, heels,
  OpenPose's mid-shoulder Neck and MidHip, BODY_25B's head top and upper neck), in the set's order
  (:func:`extra_sources`), each with its own definition and its own sigma.  The reprojection term reads
  them (``factors.stereo_reprojection``: N keypoint rows), as does the choice of the initial template pose
  (``graph.build.select_template_poses``: reprojection over every row); every step that looks a keypoint
  up by PedX name or row works on rows 0-17 (``TrackFrame.pedx_rows``).

A ``pedx18`` track is fitted as it is (E = 0, the same objects).

Per-keypoint noise: the label files' ``sigma_px`` (from the detector's confidences, per image and keypoint)
travel with the laid-out views, combined in quadrature with the config's body-model error
(``NoiseConfig.keypoint_model_sigma_px``, as the config combines click noise and model error); the
reprojection term uses them instead of the configured sigma for those rows
(``factors.stereo_reprojection.ImageKeypoints.sigma_px``).  Rows without one keep the config's (the extra
rows: ``NoiseConfig.keypoint_sigma_px``, the whole-figure sigma).  ``NoiseConfig.hip_sigma_factor`` is not
applied to a laid-out track (:func:`fit_layout` sets it to 1): it stands for PedX's hip rows projecting the
model's hip *joints* while the labels mark the hip surface, and here those rows project the set's own surface
hips, whose ambiguity is already in their ``sigma_px`` (the import's per-keypoint factors,
``DetectionNoiseConfig.keypoint_scale``) — applying it too would count the hips' noise twice.

Results are reported with the original model: the world keypoints of a result (and their covariances) are
always PedX's 18 (the layout model's ``report_model``).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from pedx_graph.body.keypoint_defs import KeypointMap, load_keypoint_set
from pedx_graph.data.types import Track, View2D
from pedx_graph.keypoints import PEDX_KEYPOINTS

#: Set points filling a PedX row although they are not PedX's body point (their own definition is projected).
NEAREST_ROWS: dict[str, tuple[str, ...]] = {"lhip": ("left_hip", "LHip"), "rhip": ("right_hip", "RHip")}


def row_sources(set_name: str) -> np.ndarray:
    """(18,) index into the set's keypoints of each PedX row's keypoint, -1 where the set has none."""
    kset = load_keypoint_set(set_name)
    out = np.full(len(PEDX_KEYPOINTS), -1, dtype=np.int64)
    for row, pedx_name in enumerate(PEDX_KEYPOINTS):
        index = kset.index_of(pedx_name)
        if index is None:
            for candidate in NEAREST_ROWS.get(pedx_name, ()):
                if candidate in kset.keypoints:
                    index = kset.keypoints.index(candidate)
        if index is not None:
            out[row] = index
    return out


def extra_sources(set_name: str) -> np.ndarray:
    """(E,) indices into the set's keypoints of the keypoints filling no PedX row (:func:`row_sources`), in
    the set's order: the rows 18 .. 18 + E - 1 of the fit layout (empty for ``pedx18``)."""
    if set_name == "pedx18":
        return np.zeros(0, dtype=np.int64)
    used = set(row_sources(set_name).tolist())
    return np.array([i for i in range(len(load_keypoint_set(set_name).keypoints)) if i not in used],
                    dtype=np.int64)


def layout_names(set_name: str) -> tuple[str, ...]:
    """The 18 + E row names of the fit layout: PEDX_KEYPOINTS, then the extra keypoints' names in the set."""
    names = load_keypoint_set(set_name).keypoints
    return PEDX_KEYPOINTS + tuple(names[i] for i in extra_sources(set_name))


def layout_map(model, set_name: str) -> KeypointMap:
    """An 18 + E row :class:`KeypointMap`: the set's definitions in the PedX rows it fills (PedX's in the
    others), then its extra keypoints' definitions (:func:`extra_sources`)."""
    pedx = model.keypoint_set_map("pedx18")
    own = model.keypoint_set_map(set_name)
    src = row_sources(set_name)
    extra = extra_sources(set_name)
    rows = [(own, int(src[row])) if src[row] >= 0 else (pedx, row) for row in range(len(PEDX_KEYPOINTS))]
    rows += [(own, int(k)) for k in extra]
    used = sorted(set(pedx.vertex_ids.tolist()) | set(own.vertex_ids.tolist()))
    col = {v: i for i, v in enumerate(used)}
    vertex_coeffs = np.zeros((len(rows), len(used)))
    joint_coeffs = np.zeros((len(rows), pedx.joint_coeffs.shape[1]))
    for row, (kmap, k) in enumerate(rows):
        for v, c in zip(kmap.vertex_ids, kmap.vertex_coeffs[k]):
            vertex_coeffs[row, col[int(v)]] += c
        joint_coeffs[row] = kmap.joint_coeffs[k]
    return KeypointMap(names=layout_names(set_name), vertex_ids=np.array(used, dtype=np.int64),
                       vertex_coeffs=vertex_coeffs, joint_coeffs=joint_coeffs, source=f"{set_name}:fit-layout")


def layout_model(model, set_name: str):
    """The body model whose 18 + E keypoints are :func:`layout_map` (cached on ``model``); its
    ``report_model`` is ``model`` (results: PedX's 18 keypoints of the original model)."""
    from pedx_graph.body.model import BodyModel

    cache = model.__dict__.setdefault("_layout_models", {})
    if set_name not in cache:
        laid = BodyModel(model.data, layout_map(model, set_name))
        laid.report_model = model
        cache[set_name] = laid
    return cache[set_name]


def layout_view(view: View2D | None, model_sigma_px: float = 0.0) -> View2D | None:
    """A view of the set's keypoints in the 18 + E rows of the fit layout (PedX rows without a source
    unlabelled; the set's extra keypoints after them); its ``sigma_px`` (the detector's noise) combined with
    the body model's own error ``model_sigma_px`` in quadrature, as the config combines click noise and model
    error (``NoiseConfig.keypoint_model_sigma_px``)."""
    if view is None or view.keypoint_set == "pedx18":
        return view
    src = np.concatenate([row_sources(view.keypoint_set), extra_sources(view.keypoint_set)])
    has = src >= 0
    keypoints = np.full((len(src), 2), np.nan)
    visible = np.zeros(len(src), dtype=bool)
    keypoints[has] = view.keypoints[src[has]]
    visible[has] = view.visible[src[has]]
    sigma = None
    if view.sigma_px is not None:
        sigma = np.full(len(src), np.nan)
        sigma[has] = np.sqrt(view.sigma_px[src[has]] ** 2 + model_sigma_px ** 2)
    return View2D(keypoints=keypoints, visible=visible, polygon=view.polygon, keypoint_set="pedx18", sigma_px=sigma)


def layout_track(track: Track, model_sigma_px: float = 0.0) -> Track:
    """``track`` with every view in the 18 + E row layout (:func:`layout_view`)."""
    def lay(view):
        return layout_view(view, model_sigma_px)
    frames = []
    for fr in track.frames:
        frames.append(dataclasses.replace(
            fr, left=lay(fr.left), right=lay(fr.right),
            other_views={pair: (lay(a), lay(b)) for pair, (a, b) in fr.other_views.items()}))
    return dataclasses.replace(track, frames=frames)


def fit_layout(track: Track, ctx, config):
    """``(track, ctx, config)`` to fit a track of another keypoint set through the 18 + E row layout (module
    docstring): the laid-out track, a context with the layout's body model and ``config`` with
    ``noise.hip_sigma_factor`` 1 (the hip rows are the set's own surface hips) and
    ``noise.left_right_swap_prob`` the detector's (``noise.detector_left_right_swap_prob``: the left/right
    label screen, :mod:`pedx_graph.solvers.mirror`); the same objects for a ``pedx18`` track."""
    set_name = track.keypoint_set
    if set_name == "pedx18":
        return track, ctx, config
    laid = layout_track(track, model_sigma_px=float(getattr(config.noise, "keypoint_model_sigma_px", 0.0)))
    noise = config.noise
    changes = {}
    if getattr(noise, "hip_sigma_factor", 1.0) != 1.0:
        changes["hip_sigma_factor"] = 1.0
    if hasattr(noise, "detector_left_right_swap_prob"):
        changes["left_right_swap_prob"] = noise.detector_left_right_swap_prob
    if changes:
        config = dataclasses.replace(config, noise=dataclasses.replace(noise, **changes))
    return laid, dataclasses.replace(ctx, model=layout_model(ctx.model, set_name)), config


__all__ = ["extra_sources", "fit_layout", "layout_map", "layout_model", "layout_names", "layout_track", "layout_view",
           "row_sources"]
