"""Estimate where a detector's keypoints sit on the body model from its own fitted tracks (self-calibration).

A detector's hip, ear or ankle is its training data's idea of the point, not the shipped set's definition on
the body model (``pedx_graph/body/data/keypoint_sets``); a systematic offset of a few centimetres biases the
fit and makes its covariances overconfident (docs/detections.md, "A detector whose points are not our
definitions").  The offsets are measured from the user's own fits.

Model, per keypoint ``k`` of the set (frames: world = LiDAR frame, metres; pixels of the rectified images):

    world_p_k'(f) = world_p_k(f) + B_k(f) c_k                          c_k (3,) unitless
    B_k(f)        = [v_b1 - v_a, v_b2 - v_a, v_b3 - v_a](f)            (3, 3) metres

``world_p_k`` is the definition in use (the fit's), ``v_a`` the posed vertex nearest the keypoint at rest and
``v_b1..3`` vertices 2-25 cm from it (across the limb or trunk where the skin around is flat), skinned to the
same joint, whose rest differences lie nearest the rest frame's x, y and z axes, either way
(:func:`offset_basis`).  The offset therefore turns and stretches with the skin around the point, and the
moved point is still a linear map of the posed vertices: the set's file keeps its form (``+c_i`` on
``v_bi``, ``-sum c_i`` on ``v_a``).

Each labelled keypoint of every fitted frame and image gives two rows, linearised at the fit:

    r = z - pi(world_p_k(f))       (2,) pixels             A = dpi/dp (2, 3) @ B_k(f)       r ~ A c_k

with the reprojection term's projection, derivative and sigmas (``factors.stereo_reprojection``: its
``stereo_pixels`` and ``build_reprojection_setup``; the label's sigma, ``View2D.sigma_px``, the import's from
the confidences), whitened by that sigma and weighted by a
Cauchy kernel of the whitened 2D offset (scale ``kernel_sigmas``: a wrong detection does not move the
definition).  With a zero-mean Gaussian prior of ``prior_sigma_m`` on the rest offset ``B_k(rest) c_k`` per
axis (the offset of one keypoint is seen along every viewing direction only over many poses and views), the
normal equations give ``c_k`` and its covariance.  The prior holds the whole offset from the shipped
definition, whatever earlier rounds added (:func:`solve_offsets`).

The fit absorbs part of an offset (pose and shape lean towards the detector's point), so one round recovers
part of it: fit, calibrate, fit again with the written set (``FitConfig.keypoint_sets``), calibrate again
from the new fit (each round adds to the definitions it was fitted with).
"""
from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from factors.stereo_reprojection import build_reprojection_setup, images_from_views, stereo_pixels
from pedx_graph.body.keypoint_defs import keypoint_set_map, set_topology
from pedx_graph.data.types import Track
from pedx_graph.keypoints import load_keypoint_set

#: Labels of a keypoint a track needs for its own estimate to enter the tracks' spread
#: (:attr:`OffsetEstimate.track_sigma_m`).
MIN_TRACK_LABELS = 10

#: Rest-frame axes the three basis differences of a keypoint lie nearest (x, y, z of the model's frame).
_AXES = np.eye(3)


@dataclass(frozen=True)
class OffsetBasis:
    """Per keypoint of a set: the anchor vertex, the three vertices whose differences from it span the
    offset, and those differences at rest (mean shape, rest pose)."""

    set_name: str
    anchors: np.ndarray
    """(K,) vertex nearest each keypoint at rest."""
    others: np.ndarray
    """(K, 3) the vertices ``b_1..3`` of the basis differences ``v_b - v_a``."""
    rest: np.ndarray
    """(K, 3, 3) the differences at rest, metres: ``rest[k][:, i] = v_bi - v_a``."""


def rest_keypoints(model, set_name: str, shipped: bool = False) -> np.ndarray:
    """(K, 3) the set's keypoints on ``model`` at rest (mean shape, rest pose), metres: the definitions in use
    (:attr:`BodyModel.keypoint_sets`), or with ``shipped`` the shipped file's."""
    kmap = keypoint_set_map(model.data, set_name) if shipped else model.keypoint_set_map(set_name)
    rest_v = np.asarray(model.v_template, dtype=float)
    return kmap.apply(rest_v[kmap.vertex_ids], model.rest_joints(np.zeros(model.num_betas)))


def offset_basis(model, set_name: str, min_length_m: float = 0.02, max_length_m: float = 0.25) -> OffsetBasis:
    """The :class:`OffsetBasis` of ``set_name`` on ``model`` (a ``BodyModel``), around the shipped definitions
    (the same basis in every round): per keypoint, among the vertices ``min_length_m`` to ``max_length_m``
    from the anchor and skinned mostly to the anchor's joint, the three whose rest difference lies nearest
    the x, y and z axes, either way (any skinning when those are too few or nearly coplanar)."""
    rest_kp = rest_keypoints(model, set_name, shipped=True)
    rest_v = np.asarray(model.v_template, dtype=float)
    weights = np.asarray(model.weights.toarray() if hasattr(model.weights, "toarray") else model.weights)
    dominant = np.argmax(weights, axis=1)
    anchors, others, rest = [], [], []
    for point in rest_kp:
        anchor = int(np.argmin(np.linalg.norm(rest_v - point, axis=1)))
        offsets = rest_v - rest_v[anchor]
        length = np.linalg.norm(offsets, axis=1)
        ring = (length >= min_length_m) & (length <= max_length_m)
        chosen = None
        for pool in (ring & (dominant == dominant[anchor]), ring):
            ids = np.flatnonzero(pool)
            if len(ids) < 3:
                continue
            cosine = np.abs(offsets[ids] @ _AXES.T) / length[ids, None]     # either way along the axis
            pick = ids[np.argmax(cosine, axis=0)]
            basis = offsets[pick].T / length[pick]
            if len(set(pick.tolist())) == 3 and abs(np.linalg.det(basis)) > 0.3:
                chosen = pick
                break
        if chosen is None:
            raise ValueError(f"{model.source}: no vertices around keypoint {len(anchors)} of {set_name} span an "
                             f"offset ({min_length_m:g}-{max_length_m:g} m from its nearest vertex)")
        anchors.append(anchor)
        others.append(chosen)
        rest.append(offsets[chosen].T)
    return OffsetBasis(set_name=set_name, anchors=np.array(anchors, dtype=np.int64),
                       others=np.array(others, dtype=np.int64), rest=np.array(rest))


@dataclass
class OffsetNormals:
    """Normal equations of the offsets of one set, summed over fitted frames and images."""

    hessian: np.ndarray
    """(K, 3, 3) ``sum w A^T A / sigma^2``."""
    gradient: np.ndarray
    """(K, 3) ``sum w A^T r / sigma^2``."""
    count: np.ndarray
    """(K,) labelled keypoints that contributed (int)."""
    whitened_sq: np.ndarray
    """(K,) ``sum w |r / sigma|^2`` at the definitions in use."""
    weight: np.ndarray
    """(K,) ``sum w``."""

    def add(self, other: "OffsetNormals") -> None:
        """Add ``other``'s sums (another track's rows) to these."""
        for name in ("hessian", "gradient", "count", "whitened_sq", "weight"):
            getattr(self, name)[...] += getattr(other, name)

    @staticmethod
    def zeros(num_keypoints: int) -> "OffsetNormals":
        return OffsetNormals(hessian=np.zeros((num_keypoints, 3, 3)), gradient=np.zeros((num_keypoints, 3)),
                             count=np.zeros(num_keypoints, dtype=np.int64), whitened_sq=np.zeros(num_keypoints),
                             weight=np.zeros(num_keypoints))


def add_track(normals: OffsetNormals, model, basis: OffsetBasis, track: Track, frames: list[int],
              pose: np.ndarray, betas: np.ndarray, trans: np.ndarray, kernel_sigmas: float = 3.0,
              default_sigma_px: float = 4.0, chunk: int = 32) -> None:
    """Add one fitted track's rows to ``normals``: ``frames`` (T,) with the fit's ``pose`` (T, 72), ``betas``
    (B,) and ``trans`` (T, 3); every image of those frames labelled in ``basis.set_name`` (a view without
    sigmas uses ``default_sigma_px``).  ``model`` is the body model with the definitions the track was
    fitted with."""
    kmap = model.keypoint_set_map(basis.set_name)
    by_frame = {fr.frame: fr for fr in track.frames}
    pose = np.asarray(pose, dtype=float).reshape(len(frames), -1)
    trans = np.asarray(trans, dtype=float).reshape(len(frames), 3)
    for start in range(0, len(frames), chunk):
        sl = slice(start, start + chunk)
        body = model.forward(pose[sl], np.broadcast_to(betas, (len(pose[sl]), len(betas))), trans[sl])
        world_p = kmap.apply(body.vertices[:, kmap.vertex_ids], body.joints)                  # (n, K, 3)
        spans = body.vertices[:, basis.others] - body.vertices[:, basis.anchors][:, :, None]  # (n, K, 3, 3)
        spans = np.swapaxes(spans, 2, 3)                                                      # columns = basis
        for i, frame in enumerate(frames[sl]):
            fr = by_frame.get(int(frame))
            if fr is None:
                continue
            views = [v for v in fr.labelled_views() if v[2].keypoint_set == basis.set_name]
            # the reprojection term's own pixels, derivatives and sigmas (a label's sigma, else the default)
            setup = build_reprojection_setup(images_from_views(views, track.calibrations), default_sigma_px,
                                             default_sigma_px, np.ones(len(basis.anchors)))
            if not setup.num_images:
                continue
            uv, d_uv = stereo_pixels(world_p[i][None], [setup], derivatives=True)
            row = 0
            for m, image in enumerate(setup.images):
                k = image.index
                sigma = setup.sigmas[row:row + 2 * len(k):2]
                row += 2 * len(k)
                e = (image.uv - uv[0, m, k]) / sigma[:, None]
                e_sq = np.sum(e * e, axis=1)
                w = 1.0 / (1.0 + e_sq / kernel_sigmas ** 2)                                   # Cauchy
                A = d_uv[0, m, k] @ spans[i, k] / sigma[:, None, None]                        # (n, 2, 3)
                normals.hessian[k] += w[:, None, None] * np.einsum("nri,nrj->nij", A, A)
                normals.gradient[k] += w[:, None] * np.einsum("nri,nr->ni", A, e)
                normals.count[k] += 1
                normals.whitened_sq[k] += w * e_sq
                normals.weight[k] += w


@dataclass
class OffsetEstimate:
    """The offsets of one set's keypoints and their uncertainty."""

    set_name: str
    coeffs: np.ndarray
    """(K, 3) ``c_k``."""
    coeff_cov: np.ndarray
    """(K, 3, 3) covariance of ``c_k``."""
    rest_offset_m: np.ndarray
    """(K, 3) the offset ``B_k(rest) c_k`` added to the definitions in use, at rest, metres (model frame)."""
    offset_in_use_m: np.ndarray
    """(K, 3) how far the definitions in use lay from the shipped ones at rest, metres (earlier rounds')."""
    rest_cov_m2: np.ndarray
    """(K, 3, 3) the covariance of ``rest_offset_m`` from the labels' noise given the fitted bodies, square
    metres."""
    count: np.ndarray
    """(K,) labelled keypoints it rests on."""
    residual_rms: np.ndarray
    """(K,) RMS of the whitened residuals per axis at the definitions in use (kernel-weighted; 1: the labels'
    noise as their sigmas say; NaN without rows)."""
    track_sigma_m: np.ndarray | None = None
    """(K, 3) the standard error of the offset from how the tracks disagree: the spread of each track's own
    estimate (tracks with at least :data:`MIN_TRACK_LABELS` labels of the keypoint) over the square root of
    their number, metres per axis; it carries the fits' own errors where they differ between tracks, which
    ``rest_cov_m2`` does not (an error common to every track, e.g. an offset the basis cannot follow, it does
    not see either).  NaN with fewer than two such tracks."""


def solve_offsets(normals: OffsetNormals, basis: OffsetBasis, prior_sigma_m: float = 0.05,
                  offset_in_use_m: np.ndarray | None = None) -> OffsetEstimate:
    """The offsets ``c_k`` added to the definitions in use, minimising the whitened rows plus the prior on the
    whole offset from the shipped definitions, ``|offset_in_use_k + B_k(rest) c_k| / prior_sigma_m`` per axis
    (``offset_in_use_m`` (K, 3): how far the definitions in use already lie from the shipped ones at rest, 0
    without; a keypoint without rows is pulled back to the shipped definition, by the prior alone)."""
    prior = np.einsum("kai,kaj->kij", basis.rest, basis.rest) / prior_sigma_m ** 2
    info = normals.hessian + prior
    cov = np.linalg.inv(info)
    pull = np.zeros_like(normals.gradient) if offset_in_use_m is None else \
        np.einsum("kai,ka->ki", basis.rest, np.asarray(offset_in_use_m, dtype=float)) / prior_sigma_m ** 2
    coeffs = np.einsum("kij,kj->ki", cov, normals.gradient - pull)
    rest_offset = np.einsum("kai,ki->ka", basis.rest, coeffs)
    rest_cov = basis.rest @ cov @ np.swapaxes(basis.rest, 1, 2)
    return OffsetEstimate(set_name=basis.set_name, coeffs=coeffs, coeff_cov=cov, rest_offset_m=rest_offset,
                          offset_in_use_m=np.zeros_like(rest_offset) if offset_in_use_m is None else
                          np.asarray(offset_in_use_m, dtype=float),
                          residual_rms=np.sqrt(np.divide(normals.whitened_sq, 2 * normals.weight,
                                                         out=np.full(len(normals.weight), np.nan),
                                                         where=normals.weight > 0)),
                          rest_cov_m2=rest_cov, count=normals.count.copy())


def calibrated_set(model, basis: OffsetBasis, estimate: OffsetEstimate, provenance: dict | None = None) -> dict:
    """The keypoint-set document (the shipped file's form, :func:`pedx_graph.body.keypoint_defs.read_keypoint_set_file`)
    of the definitions in use on ``model`` moved by ``estimate``, for the model's topology (the other
    topology's definitions are the ones in use, unmoved); ``provenance`` is stored with the offsets."""
    name = basis.set_name
    shipped = load_keypoint_set(name)
    kset = model.keypoint_sets.get(name, shipped)
    topology = set_topology(model.data, name)
    doc = {"name": name, "description": shipped.description, "generated_by": "pedx-graph calibrate-keypoints",
           "keypoints": list(shipped.keypoints), "pedx_equivalent": dict(shipped.pedx_equivalent),
           "definitions": copy.deepcopy(kset.definitions)}
    points = doc["definitions"][topology]["points"]
    for k, point in enumerate(shipped.keypoints):
        terms: dict[int, float] = {}
        for v, c in points[point]["vertices"]:
            terms[int(v)] = terms.get(int(v), 0.0) + float(c)
        anchor = int(basis.anchors[k])
        for other, c in zip(basis.others[k], estimate.coeffs[k]):
            terms[int(other)] = terms.get(int(other), 0.0) + float(c)
            terms[anchor] = terms.get(anchor, 0.0) - float(c)
        points[point]["vertices"] = [[v, round(c, 9)] for v, c in sorted(terms.items()) if abs(c) > 1e-12]
    doc["calibration"] = {
        "topology": topology, "model": Path(str(model.source)).name,      # the file's name: no machine path
        "keypoints": {point: {"rest_offset_m": [round(float(x), 5) for x in
                                                (estimate.offset_in_use_m + estimate.rest_offset_m)[k]],
                              "round_offset_m": [round(float(x), 5) for x in estimate.rest_offset_m[k]],
                              "rest_sigma_m": [round(float(x), 5)
                                               for x in np.sqrt(np.diagonal(estimate.rest_cov_m2[k]))],
                              "residual_rms_sigmas": round(float(estimate.residual_rms[k]), 4),
                              "track_sigma_m": None if estimate.track_sigma_m is None else
                              [None if not np.isfinite(x) else round(float(x), 5) for x in estimate.track_sigma_m[k]],
                              "labelled": int(estimate.count[k])}
                      for k, point in enumerate(shipped.keypoints)},
        **(provenance or {})}
    return doc


def estimate_offsets(model, set_name: str,
                     fitted: Iterable[tuple[Track, list[int], np.ndarray, np.ndarray, np.ndarray]],
                     prior_sigma_m: float = 0.05, kernel_sigmas: float = 3.0,
                     step: float = 1.0) -> tuple[OffsetBasis, OffsetEstimate]:
    """:func:`offset_basis`, :func:`add_track` over ``fitted`` (``(track, frames, pose, betas, trans)``) and
    :func:`solve_offsets`; the change times ``step`` (over-relaxation: a fit absorbs part of an offset, so
    each round's change falls short of it; 1: the change as estimated)."""
    basis = offset_basis(model, set_name)
    in_use = rest_keypoints(model, set_name) - rest_keypoints(model, set_name, shipped=True)
    normals = OffsetNormals.zeros(len(basis.anchors))
    per_track, labels = [], []
    for track, frames, pose, betas, trans in fitted:
        own = OffsetNormals.zeros(len(basis.anchors))
        add_track(own, model, basis, track, frames, pose, betas, trans, kernel_sigmas=kernel_sigmas)
        normals.add(own)
        per_track.append(solve_offsets(own, basis, prior_sigma_m, in_use).rest_offset_m)
        labels.append(own.count)
    estimate = solve_offsets(normals, basis, prior_sigma_m, in_use)
    spread = np.full((len(basis.anchors), 3), np.nan)
    if per_track:
        per_track, labels = np.array(per_track), np.array(labels)                 # (T, K, 3), (T, K)
        for k in range(len(basis.anchors)):
            enough = labels[:, k] >= MIN_TRACK_LABELS
            if enough.sum() >= 2:
                spread[k] = per_track[enough, k].std(axis=0, ddof=1) / np.sqrt(enough.sum())
    estimate = dataclasses.replace(estimate, track_sigma_m=spread)
    if step != 1.0:
        estimate = dataclasses.replace(estimate, coeffs=step * estimate.coeffs,
                                       rest_offset_m=step * estimate.rest_offset_m)
    return basis, estimate


def offsets_markdown(estimates: dict[str, OffsetEstimate], command: str) -> str:
    """The offsets as a markdown table per set, millimetres at rest on the model: each keypoint's whole offset
    from the shipped definition, this round's change, its standard deviations (the labels' noise; the tracks'
    spread), the residuals' RMS and the labelled keypoints it rests on."""
    lines = ["# Keypoint definitions calibrated from fitted tracks", "", f"Command: `{command}`", "",
             "Where the detector's points lie from the shipped definitions, at rest on the model (mean shape, "
             "rest pose; the model's axes: for SMPL-format models x to the body's left, y up, z forward), "
             "millimetres.  This round's change is what the last fit's residuals added to the definitions it "
             "was fitted with; a fit absorbs part of an offset, so fit again with the written sets and "
             "calibrate again until the changes are small.  Sigma, labels: the labels' noise given the fitted "
             "bodies; sigma, tracks: how the tracks' own estimates disagree, over the square root of their "
             "number (it carries the fits' own errors; - with fewer than two tracks); the residual RMS is that of "
             "the last fit's whitened residuals per axis at the definitions it used (1: the labels' sigmas about "
             "right).", ""]
    for name, est in estimates.items():
        lines += [f"## {name}", "",
                  "| keypoint | x | y | z | length | this round's change | sigma, labels (x, y, z) | "
                  "sigma, tracks (x, y, z) | residual RMS (sigmas) | labelled |",
                  "|---|---:|---:|---:|---:|---:|---|---|---:|---:|"]
        for k, point in enumerate(load_keypoint_set(name).keypoints):
            off = 1000 * (est.offset_in_use_m[k] + est.rest_offset_m[k])
            sd = 1000 * np.sqrt(np.diagonal(est.rest_cov_m2[k]))
            spread = np.full(3, np.nan) if est.track_sigma_m is None else 1000 * est.track_sigma_m[k]
            tracks = "-" if not np.all(np.isfinite(spread)) else ", ".join(f"{x:.1f}" for x in spread)
            lines.append(f"| {point} | {off[0]:.1f} | {off[1]:.1f} | {off[2]:.1f} | {np.linalg.norm(off):.1f} | "
                         f"{1000 * np.linalg.norm(est.rest_offset_m[k]):.1f} | "
                         f"{sd[0]:.1f}, {sd[1]:.1f}, {sd[2]:.1f} | {tracks} | {est.residual_rms[k]:.2f} | "
                         f"{int(est.count[k])} |")
        lines.append("")
    return "\n".join(lines)


def calibrate_from_results(dataset, results, out, prior_sigma_m: float = 0.05, kernel_sigmas: float = 3.0,
                           command: str = "") -> dict[str, OffsetEstimate]:
    """Calibrate every detector keypoint set of ``dataset``'s tracks from their fit in ``results`` (a ``fit``
    output folder: its labels/3d/smpl and the fit_config.yaml it was fitted with, whose body model and
    ``keypoint_sets`` are the definitions the offsets add to).  Writes into ``out``: ``<set>.json`` per set
    (:func:`calibrated_set`), ``calibration.md`` (:func:`offsets_markdown`) and ``fit_config.yaml``, the
    results' config with ``keypoint_sets`` set to ``out`` (fit again with it).  Returns the estimates."""
    from pedx_graph.config import load_config, save_config
    from pedx_graph.data.reader import read_dataset, read_smpl_labels
    from pedx_graph.data.types import DataFormatError
    from pedx_graph.graph.config import FitConfig
    from pedx_graph.graph.context import fit_body_model
    from pedx_graph.utils import atomic_write_json, atomic_write_text

    results, out = Path(results), Path(out)
    config_path = results / "fit_config.yaml"
    if not config_path.is_file():
        raise DataFormatError(config_path, None, "missing: the results of a fit (pedx-graph fit --out) hold the "
                                                 "config they were fitted with")
    config = load_config(FitConfig, config_path)
    model = fit_body_model(config)                  # the definitions the results were fitted with
    fitted = read_smpl_labels(results)
    by_set: dict[str, list] = {}
    for track in read_dataset(dataset):
        labels = fitted.get((track.sequence, track.tracking_id))
        if not labels or track.keypoint_set == "pedx18":
            continue
        by_set.setdefault(track.keypoint_set, []).append(
            (track, [lab.frame for lab in labels], np.array([lab.pose for lab in labels]), np.asarray(labels[0].betas),
             np.array([lab.trans for lab in labels])))
    if not by_set:
        raise DataFormatError(results, None, f"no fitted track of {dataset} is labelled in a detector's keypoint set")
    estimates = {}
    out.mkdir(parents=True, exist_ok=True)
    for name, tracks in sorted(by_set.items()):
        basis, estimates[name] = estimate_offsets(model, name, tracks, prior_sigma_m, kernel_sigmas)
        atomic_write_json(out / f"{name}.json", calibrated_set(
            model, basis, estimates[name], {"tracks": len(tracks), "prior_sigma_m": prior_sigma_m,
                                            "kernel_sigmas": kernel_sigmas}))
    atomic_write_text(out / "calibration.md", offsets_markdown(estimates, command))
    config.keypoint_sets = str(out.resolve())
    save_config(config, out / "fit_config.yaml")
    return estimates


__all__ = ["OffsetBasis", "OffsetEstimate", "OffsetNormals", "add_track", "calibrated_set", "calibrate_from_results",
           "estimate_offsets", "offset_basis", "offsets_markdown", "solve_offsets"]
