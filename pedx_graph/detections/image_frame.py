"""Which images a pair's detections were made on — the raw (distorted) ones or the rectified ones — told
from the detections' own stereo rows.

A calibration with the raw keys ``K_0x`` / ``D_0x`` says what the raw images were, not that the detector
saw them: a release may ship only rectified images (PedX's 12 MP images are rectified, while its
calibration files carry the raw keys), and a detector run on those gives rectified pixels.  Undistorting
and rectifying such pixels once more moves every keypoint by the difference between the two image models
(tens of pixels on a real rig: principal points, distortion, the rectifying rotations), and nothing
downstream would notice it as an error of its own.  So each pair is decided from data:

* in a rectified pair, a body point seen by both cameras lies on one image row.  The two images' people
  of each frame are matched (Hungarian, on the smaller of the two readings' median ``|v_left - v_right|``;
  the match must show positive disparity, a like height and rows within a quarter of it), and each matched
  person's median row difference ``v_left - v_right`` over its shared keypoints is taken under both
  readings: the pixels undistorted and rectified with the raw models (``raw``), and as they are
  (``rectified``) — the same people for both;
* per reading, those row differences are fitted as a field across the image (an offset and a tilt over the
  horizontal position, :func:`row_field`).  Read the right way the field vanishes, up to what a real
  pair's rectification leaves (``row_offset_sd_px``, ``row_tilt_sd_px``); each reading's chi-square is its
  field's distance from zero under the fit's uncertainty plus that allowance, and half their difference is
  the log evidence (:func:`reading_evidence`).  Per-person medians keep the test to the rows' location: the
  two readings scale the keypoint noise differently (undistortion stretches pixels), which a likelihood of
  the single keypoints would count as evidence;
* the reading ahead by ``min_log_evidence`` is the pair's.  With fewer than ``min_matches`` people matched,
  or readings too close to tell (two image models alike in the rows, where the choice matters least), the
  pair follows what the sequence's decided pairs agree on (one detector run on one kind of image), else it
  is taken as ``raw`` — what its raw keys suggest — and the import warns; ``images: raw`` / ``rectified``
  in the config skips the test.

A pair without raw keys has rectified images to begin with.  The pairs decided ``rectified`` lose their raw
models (:func:`pixel_calibrations`), so every later step (association, the written labels, the LiDAR cut,
the images written into the dataset) reads the pixels as rectified from that one decision.
"""
from __future__ import annotations

import dataclasses
import logging
from collections import defaultdict
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from pedx_graph.data.types import StereoCalibration
from pedx_graph.detections.noise import MAD_TO_SIGMA
from pedx_graph.detections.undistort import undistort_rectify

log = logging.getLogger(__name__)

#: Values of :attr:`ImageFrameConfig.images`.
IMAGE_FRAMES = ("auto", "raw", "rectified")


@dataclass
class ImageFrameConfig:
    """Which images the detections' pixels are in (module docstring)."""

    images: str = "auto"
    """``auto``: per pair, from the detections' stereo rows; ``raw``: the distorted camera images (undistorted
    and rectified with the calibration's ``K_0x`` / ``D_0x`` / ``R_rect_0x``); ``rectified``: the pair's
    rectified images (used as they are, whatever raw keys the calibration has).  A pair without raw keys is
    rectified in every case."""
    min_matches: int = 6
    """Fewer people matched between a pair's two images than this: its rows cannot tell (the pair follows the
    sequence's decided pairs, else it is taken as ``raw`` with a warning)."""
    min_log_evidence: float = 10.0
    """A reading wins when the rows' log-likelihood under it exceeds the other's by at least this much
    (natural log; :func:`reading_evidence`)."""
    row_offset_sd_px: float = 1.0
    """Standard deviation of a row offset common to a pair's rows under either reading (a real pair's
    rectification error: PedX's blu-grn pair is off by a median 1 px), pixels: a constant difference
    between the two readings counts only as far as it exceeds such an offset."""
    row_tilt_sd_px: float = 1.0
    """Standard deviation of the change of that offset across the image, pixels per focal length of
    horizontal image position (a rectifying rotation off by 0.02 degrees about the optical axis tilts a
    3300 px pair's rows by about 1.2 px per focal length)."""
    max_frames: int = 200
    """At most this many frames per pair (evenly spread over those where both cameras detected someone)
    enter the test."""
    min_keypoints: int = 4
    """A person is matched between the two images on at least this many keypoints present in both."""

    def __post_init__(self) -> None:
        if self.images not in IMAGE_FRAMES:
            raise ValueError(f"image_frame.images must be one of {', '.join(IMAGE_FRAMES)}, got {self.images!r}")
        if not self.min_log_evidence > 0 or not self.row_offset_sd_px > 0 or not self.row_tilt_sd_px > 0:
            raise ValueError("image_frame.min_log_evidence, row_offset_sd_px and row_tilt_sd_px must be > 0")
        if self.min_matches < 1 or self.max_frames < 1 or self.min_keypoints < 2:
            raise ValueError("image_frame.min_matches and max_frames must be >= 1, min_keypoints >= 2")


def pair_row_cost(left: np.ndarray, right: np.ndarray, min_keypoints: int) -> float | None:
    """Median ``|v_left - v_right|`` (pixels) over the keypoints present in both ((K, 2) rectified pixels,
    NaN = absent), or None when they are too few, the disparity is not positive, the heights differ by
    more than 1.5x or the rows by more than a quarter of the height (not one person)."""
    both = np.all(np.isfinite(left), axis=1) & np.all(np.isfinite(right), axis=1)
    if both.sum() < min_keypoints:
        return None
    if np.median(left[both, 0] - right[both, 0]) <= 0:
        return None
    h_left, h_right = np.ptp(left[both, 1]), np.ptp(right[both, 1])
    if h_left <= 0 or h_right <= 0 or not 2 / 3 <= h_left / h_right <= 1.5:
        return None
    cost = float(np.median(np.abs(left[both, 1] - right[both, 1])))
    return cost if cost <= 0.25 * max(h_left, h_right) else None


def match_people(left: list, right: list, min_keypoints: int = 4) -> list[tuple[int, int]]:
    """One frame's people matched between a pair's two images: ``(index in left, index in right)``.  ``left``,
    ``right``: per detection a tuple of readings of its pixels ((K, 2) each, NaN = absent; the same readings
    in the same order on both sides).  A pair of detections is a candidate when :func:`pair_row_cost` accepts it
    under some reading; the match (Hungarian) minimises the smallest of the readings' median row
    differences."""
    if not left or not right:
        return []
    readings = len(left[0])
    costs = np.full((len(left), len(right), readings), np.inf)
    for a, la in enumerate(left):
        for b, rb in enumerate(right):
            for h in range(readings):
                cost = pair_row_cost(la[h], rb[h], min_keypoints)
                if cost is not None:
                    costs[a, b, h] = cost
    best = costs.min(axis=2)
    return [(int(a), int(b)) for a, b in zip(*linear_sum_assignment(np.where(np.isfinite(best), best, 1e12)))
            if np.isfinite(best[a, b])]


def matched_people(frames: list[tuple[list, list]], min_keypoints: int = 4) -> np.ndarray:
    """(M, 4) per person matched between the two images: the median row difference ``v_left - v_right``
    (pixels) over the keypoints present in both with the pixels read as raw (undistorted and rectified) and
    as rectified (as they are), and the person's median keypoint position in the left image as read
    rectified (u, v pixels).  ``frames``: per frame ``(left, right)``, each a list per detection of
    ``(uv_read_as_raw, uv_as_it_is)`` ((K, 2) each, NaN = absent), matched by :func:`match_people`."""
    rows = []
    for left, right in frames:
        for a, b in match_people(left, right, min_keypoints):
            both = np.all(np.isfinite(left[a][0]) & np.isfinite(right[b][0]), axis=1)
            rows.append((np.median(left[a][0][both, 1] - right[b][0][both, 1]),
                         np.median(left[a][1][both, 1] - right[b][1][both, 1]),
                         *np.median(left[a][1][both], axis=0)))
    return np.asarray(rows, dtype=float).reshape(-1, 4)


def row_field(rows: np.ndarray, u: np.ndarray, iterations: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """``(coefficients, covariance)`` of the robust (Huber, k = 1.5, residuals beyond 4 robust standard
    deviations left out) least-squares fit ``rows = a + c * u`` over people (``u`` the horizontal image
    position in units of the focal length, ``rows`` pixels): a pair's row differences as a field over the
    image — an offset, and the tilt across the image a rotation about the optical axis or a principal point
    leaves.  (People stand near one image row, the horizon: a vertical tilt is left out, the data would
    hardly fix it.)"""
    design = np.column_stack([np.ones(len(rows)), u])
    weights = np.ones(len(rows))
    coef = np.zeros(2)
    scale = 1.0
    for _ in range(iterations):
        w = np.sqrt(weights)
        coef = np.linalg.lstsq(design * w[:, None], rows * w, rcond=None)[0]
        residual = rows - design @ coef
        scale = max(MAD_TO_SIGMA * float(np.median(np.abs(residual))), 1e-3)
        ratio = np.abs(residual) / (1.5 * scale)
        weights = np.where(ratio <= 1, 1.0, 1.0 / np.maximum(ratio, 1e-12))
        weights[np.abs(residual) > 4 * scale] = 0.0          # gross outliers: no pull at any leverage
    information = (design * weights[:, None]).T @ design / scale ** 2
    return coef, np.linalg.pinv(information)


def reading_evidence(people: np.ndarray, focal_px: float, allowance_px: tuple[float, float]) -> dict:
    """How much better the rows fit when the pixels are read as rectified than as raw.  Each reading's row
    field (:func:`row_field`) should vanish — up to ``allowance_px``, the standard deviations of what a real
    pair's rectification leaves (an offset, the tilt across the image in pixels per focal length); its
    ``chi2`` is the field's distance from zero under its own uncertainty plus that allowance.
    ``log_evidence`` = (chi2 as raw - chi2 as rectified) / 2: > 0 favours rectified.  ``people``:
    :func:`matched_people`."""
    # about the people's median position: the offset there is what the data fix best
    u = (people[:, 2] - np.median(people[:, 2])) / focal_px
    allowance = np.diag(np.square(allowance_px))
    out = {}
    for column, name in ((0, "raw"), (1, "rectified")):
        coef, cov = row_field(people[:, column], u)
        chi2 = float(coef @ np.linalg.solve(cov + allowance, coef))
        out[name] = {"chi2": chi2, "field_px": [round(float(c), 3) for c in coef]}
    return {"log_evidence": 0.5 * (out["raw"]["chi2"] - out["rectified"]["chi2"]), **out}


def _sample(frames: list[int], count: int) -> list[int]:
    if len(frames) <= count:
        return frames
    return [frames[i] for i in np.linspace(0, len(frames) - 1, count).round().astype(int)]


def decide_pair(calib: StereoCalibration, detections: list, config: ImageFrameConfig,
                min_confidence: float) -> dict:
    """The record of one pair's decision: ``images`` (``raw`` / ``rectified``), ``decided_by``, and for the
    test the matched people and each hypothesis's median row difference (pixels).  ``detections``: the
    pair's cameras' :class:`~pedx_graph.detections.types.Detection` s; keypoints below ``min_confidence``
    are left out of the test."""
    left_name, _, right_name = calib.name.partition("-")
    raws = {left_name: calib.left_raw, right_name: calib.right_raw}
    if calib.left_raw is None and calib.right_raw is None:
        return {"images": "rectified", "decided_by": "no raw keys in the calibration"}
    if config.images != "auto":
        return {"images": config.images, "decided_by": "config"}
    by_frame: dict[int, dict[str, list]] = defaultdict(lambda: {left_name: [], right_name: []})
    for det in detections:
        if det.camera in raws:
            by_frame[det.frame][det.camera].append(det)
    usable = sorted(f for f, sides in by_frame.items() if sides[left_name] and sides[right_name])
    frames = []
    for frame in _sample(usable, config.max_frames):
        sides = []
        for camera in (left_name, right_name):
            views = []
            for det in by_frame[frame][camera]:
                kept = np.asarray(det.confidence) >= min_confidence
                uv = np.where(kept[:, None], np.asarray(det.image_uv, dtype=float), np.nan)
                raw = raws[camera]
                views.append((undistort_rectify(uv, raw) if raw is not None else uv, uv))
            sides.append(views)
        frames.append(tuple(sides))
    people = matched_people(frames, config.min_keypoints)
    record = {"matches": int(len(people)), "row_difference_px": None}
    if len(people):
        record["row_difference_px"] = {"raw": round(float(np.median(np.abs(people[:, 0]))), 3),
                                       "rectified": round(float(np.median(np.abs(people[:, 1]))), 3)}
    if len(people) < config.min_matches:
        return {"images": "raw", "decided_by": f"too few people matched between the pair's images "
                                               f"({len(people)} < {config.min_matches})", **record}
    evidence = reading_evidence(people, calib.focal_px,
                                (config.row_offset_sd_px, config.row_tilt_sd_px))
    record.update(log_evidence_rectified=round(evidence["log_evidence"], 2),
                  row_field_px={k: evidence[k]["field_px"] for k in ("raw", "rectified")})
    if abs(evidence["log_evidence"]) >= config.min_log_evidence:
        return {"images": "rectified" if evidence["log_evidence"] > 0 else "raw", "decided_by": "stereo rows",
                **record}
    return {"images": "raw", "decided_by": "stereo rows too close to tell", **record}


def image_frames(detections: list, calibrations: dict[str, StereoCalibration], config: ImageFrameConfig,
                 min_confidence: float, where: str = "") -> dict[str, dict]:
    """Pair name -> :func:`decide_pair`'s record, for every pair of ``calibrations`` with a detection in
    either camera.  A pair its own rows cannot decide takes the frame the other pairs' rows agree on (one
    detector run on one kind of image); with none to follow it stays ``raw`` and, when its cameras hold at
    least ``2 * min_matches`` detections, is logged as a warning naming ``where`` (the sequence)."""
    out = {}
    for name, calib in sorted(calibrations.items()):
        cameras = set(name.split("-"))
        dets = [d for d in detections if d.camera in cameras]
        if dets:
            out[name] = (decide_pair(calib, dets, config, min_confidence), len(dets))
    decided = {record["images"] for record, _ in out.values() if record["decided_by"] == "stereo rows"}
    for name, (record, count) in out.items():
        if record["decided_by"] in ("stereo rows", "config", "no raw keys in the calibration"):
            continue
        if len(decided) == 1:
            frame = next(iter(decided))
            record.update(images=frame, decided_by=f"the other pairs' stereo rows; its own: {record['decided_by']}")
            continue
        reason = record["decided_by"]
        record["decided_by"] = f"its raw keys; its own stereo rows: {reason}"
        if count >= 2 * config.min_matches:
            log.warning("%s: pair %s: could not tell from its stereo rows whether the detections were made on raw "
                        "or rectified images (%s): taken as raw; set image_frame.images in --config (or "
                        "--image-frame)", where or "detections", name, reason)
    return {name: record for name, (record, _) in out.items()}


def pixel_calibrations(calibrations: dict[str, StereoCalibration], frames: dict[str, dict]
                       ) -> dict[str, StereoCalibration]:
    """``calibrations`` with the raw models removed from the pairs whose detections are ``rectified`` (so
    that :func:`~pedx_graph.detections.undistort.rectified` takes their pixels as they are)."""
    return {name: (dataclasses.replace(calib, left_raw=None, right_raw=None)
                   if frames.get(name, {}).get("images") == "rectified" else calib)
            for name, calib in calibrations.items()}
