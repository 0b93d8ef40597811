"""Left/right label screen: exchange an image's left/right keypoint labels back where the fitted body shows the
detector (or the annotator) took the person's left for its right.

A 2D keypoint detector confuses a person's left and right: one pair (a wrist crossing the body, one knee for
the other), or the whole body at once (a back view read as a front view, by every camera alike), often with
full confidence.  With its robust loss the reprojection term treats an exchanged pair as an outlier when the
frame's other images contradict it — its information is lost; where every image of a frame agrees on the
wrong side nothing in the frame contradicts it, and the fit turns the body or crosses its legs to follow.

For one image and a left/right pair ``(a, b)`` of the labels' keypoint rows
(:func:`pedx_graph.keypoints.mirror_index` of the body model's row names: PedX's ``lsho`` / ``rsho``, a
detector set's ``LBigToe`` / ``RBigToe``, ``left_ear`` / ``right_ear``), the reprojection term's own loss
(:func:`factors.stereo_reprojection.keypoint_losses`: the second stage's kernel, each label with its own
sigma) at a body's keypoints gives the log likelihood ratio "exchanged" vs "as labelled" (nats)::

    gain(a, b) = rho(a as labelled) + rho(b as labelled) - rho(a's label on b) - rho(b's label on a)

A pair of which one side is labelled moves that label to the other side.  After the second stage, image by
image:

1. **the whole image** (every pair exchanged) is judged at the body its *neighbouring frames* predict
   (:func:`neighbour_poses`: each joint's rotation and the root's interpolated in time between the previous
   and the next frame, the frame's own translation; interior frames without a long gap only): the sum of
   the pairs' gains less the prior log odds must beat the best choice of single pairs at that body (each
   pair's gain less the prior log odds, where positive) — a fit that followed a confused frame cannot
   testify against it, its neighbours can, and a leg confused alone does not drag the arms along;
2. otherwise **pair by pair** at the fitted body: the frame's other images and the priors hold it where one
   image's pair is wrong.

An exchange is made when its gain exceeds the prior log odds ``log((1 - p) / p)``,
``p = noise.left_right_swap_prob`` (the prior probability of each hypothesis: one pair of one image, or one
whole image; ``noise.detector_left_right_swap_prob`` for a detector's tracks).  A side view, whose left and
right limbs project close together, leaves a small gain and keeps its labels (exchanging them would move the
fit little either way).  :func:`pedx_graph.solvers.staging.solve_staged` then solves the screened track again
from its estimate and screens it once more (a body freed of one exchange can show another; at most two
rounds); the exchanges are recorded in the track's report (``mirrored_labels``: frame, pair, side,
the pair's row names or ``"all"``, the gain).  The batch LM fit only: the incremental (iSAM2, streaming) and
ADMM solvers fit the labels as given.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
from scipy.spatial.transform import Rotation

from factors.stereo_reprojection import ImageKeypoints, build_reprojection_setup, keypoint_losses
from pedx_graph.data.types import Track, View2D
from pedx_graph.graph.build import extract_estimate, fitted_views, reprojection_noise
from pedx_graph.keypoints import mirror_index


def prior_log_odds(swap_prob: float) -> float:
    """``log((1 - p) / p)``: the gain (nats) an exchange must exceed; inf for ``p`` <= 0 (no screen)."""
    p = float(swap_prob)
    if not p > 0:
        return math.inf
    return math.log((1.0 - p) / p)


def mirrored_view(view: View2D, pairs) -> View2D:
    """``view`` with the labels of each ``(a, b)`` row pair exchanged (positions, visible flags and the labels'
    own sigmas and confidences travel together)."""
    order = np.arange(len(view.keypoints))
    for a, b in pairs:
        order[a], order[b] = b, a

    def moved(arr):
        return None if arr is None or len(arr) != len(order) else np.asarray(arr)[order]

    return dataclasses.replace(view, keypoints=np.asarray(view.keypoints)[order],
                               visible=np.asarray(view.visible)[order], sigma_px=moved(view.sigma_px),
                               confidence=moved(view.confidence))


def pair_gains(points: np.ndarray, view: View2D, calibration, side: str, pairs, noise: dict) -> np.ndarray:
    """(P,) the gain of exchanging each of ``pairs`` in one image (module docstring), nats; NaN for a pair
    with no label.  ``points``: (N, 3) the body's world keypoints in the labels' rows; ``noise``:
    :func:`pedx_graph.graph.build.reprojection_noise`."""
    sigma_args = {k: noise[k] for k in ("sigma_px", "sigma_occluded_px", "keypoint_weights")}
    out = np.full(len(pairs), np.nan)
    if not pairs:
        return out
    losses = []
    for labels in (view, mirrored_view(view, pairs)):
        setup = build_reprojection_setup([ImageKeypoints.from_view(labels, calibration, side)], **sigma_args)
        if setup.num_images == 0:
            return out
        losses.append(keypoint_losses(points, setup, noise["robust"], noise["robust_scale"])[0])
    as_labelled, exchanged = losses
    labelled = np.all(np.isfinite(np.asarray(view.keypoints, dtype=float)), axis=1)
    for p, (a, b) in enumerate(pairs):
        if labelled[a] or labelled[b]:
            out[p] = as_labelled[a] + as_labelled[b] - exchanged[a] - exchanged[b]
    return out


def neighbour_poses(pose: np.ndarray, timestamps: np.ndarray, max_gaps: int = 3
                    ) -> tuple[np.ndarray, np.ndarray]:
    """``(predicted, usable)``: (T, 72) each frame's root orientation and body pose predicted from its
    neighbours alone — every joint's rotation interpolated (slerp, by time) between the previous and the
    next frame — and (T,) bool where that prediction is usable: interior frames whose two neighbours lie
    within ``max_gaps`` of the track's median frame interval of each other (a gait is not extrapolated past
    a track's ends, nor interpolated over long gaps; elsewhere ``predicted`` holds the frame's own pose).
    ``pose``: (T, 72) axis-angle, root first; ``timestamps``: (T,) seconds."""
    pose = np.asarray(pose, dtype=float)
    count = len(pose)
    out = pose.copy()
    usable = np.zeros(count, dtype=bool)
    if count < 3:
        return out, usable
    times = np.asarray(timestamps, dtype=float)
    step = float(np.median(np.diff(times)))
    rot = pose.reshape(count, -1, 3)
    for i in range(1, count - 1):
        span = times[i + 1] - times[i - 1]
        if not (span > 0 and step > 0 and span <= max_gaps * step):
            continue
        w = (times[i] - times[i - 1]) / span
        before, after = Rotation.from_rotvec(rot[i - 1]), Rotation.from_rotvec(rot[i + 1])
        out[i] = (before * Rotation.from_rotvec(w * (before.inv() * after).as_rotvec())).as_rotvec().ravel()
        usable[i] = True
    return out, usable


def mirror_screen(track: Track, ctx, problem, values, config) -> tuple[Track, list[dict]]:
    """``(track, records)``: ``track`` with the left/right labels that the estimate ``values`` of ``problem``
    shows to be exchanged put back (module docstring), one record per exchange (``frame``, ``pair``, ``side``,
    ``keypoints``: the pair's two row names, or ``"all"`` for a whole image; ``gain``); the same track and no
    record when none qualifies or ``noise.left_right_swap_prob`` is 0.  ``ctx.model``: the body model of the
    labels' rows (a detector track's fit layout)."""
    limit = prior_log_odds(config.noise.left_right_swap_prob)
    if not math.isfinite(limit):
        return track, []
    names = tuple(ctx.model.keypoint_names)
    pairs = mirror_index(names)
    if not pairs:
        return track, []
    est = extract_estimate(problem, values, ctx)
    betas = np.broadcast_to(est.betas, (len(est.pose), len(est.betas)))
    world_p = np.asarray(ctx.model.keypoints(est.pose, betas, est.trans))
    timestamps = np.array([fr.timestamp for fr in track.frames], dtype=float)
    predicted, usable = neighbour_poses(est.pose, timestamps)
    world_p_predicted = np.asarray(ctx.model.keypoints(predicted, betas, est.trans))
    noise = reprojection_noise(config, len(names))
    records: list[dict] = []
    frames = list(track.frames)
    for i, frame in enumerate(track.frames):
        changed = {}
        for pair, side, view in fitted_views(frame, config.terms):
            calibration = track.calibrations[pair]
            if usable[i]:                       # the whole image, judged by the body its neighbours predict
                whole = pair_gains(world_p_predicted[i], view, calibration, side, pairs, noise)
                gain = float(np.nansum(whole))
                # against the best choice of single pairs at that body (each with its own prior odds)
                single = float(np.sum(np.maximum(whole[np.isfinite(whole)] - limit, 0.0)))
                if np.isfinite(whole).any() and gain - limit > max(0.0, single):
                    changed[pair, side] = mirrored_view(view, pairs)
                    records.append({"frame": int(frame.frame), "pair": pair, "side": side, "keypoints": "all",
                                    "gain": round(gain, 2)})
                    continue
            gains = pair_gains(world_p[i], view, calibration, side, pairs, noise)   # pair by pair: the fit's body
            chosen = [p for p in range(len(pairs)) if np.isfinite(gains[p]) and gains[p] > limit]
            if not chosen:
                continue
            changed[pair, side] = mirrored_view(view, [pairs[p] for p in chosen])
            records += [{"frame": int(frame.frame), "pair": pair, "side": side,
                         "keypoints": [names[pairs[p][0]], names[pairs[p][1]]], "gain": round(float(gains[p]), 2)}
                        for p in chosen]
        if changed:
            frames[i] = _with_views(frame, changed)
    if not records:
        return track, []
    return dataclasses.replace(track, frames=frames), records


def _with_views(frame, changed: dict):
    """``frame`` with the views of ``changed`` (``(pair, side) -> View2D``) replaced."""
    def pick(pair, side, view):
        return changed.get((pair, side), view)
    other = {pair: (pick(pair, "left", a), pick(pair, "right", b)) for pair, (a, b) in frame.other_views.items()}
    return dataclasses.replace(frame, left=pick(frame.pair, "left", frame.left),
                               right=pick(frame.pair, "right", frame.right), other_views=other)


__all__ = ["mirror_screen", "mirrored_view", "pair_gains", "prior_log_odds"]
