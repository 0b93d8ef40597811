"""Whether a stereo pair's two cameras are the detections' left and right, or named the wrong way round.

The calibration says which camera of a pair is the left one (``calib_cam_to_cam_<left>-<right>.txt``; the
right camera's ``P_rect_01`` carries ``-f * baseline``), and the detections name their camera by their file
names, or by ``--camera NAME=CALIB_NAME``.  Named the wrong way round, every person lies to the right in
the image called left: the disparity is negative wherever it is measured, the association pairs no one
between the two images and places everyone from one image and the LiDAR alone, and nothing says why.  The
simulator and the import shared the convention that the names are right.

Per pair, on the frames where both cameras detected someone (at most :data:`MAX_FRAMES`), the people are
matched between the two images as the pair is named and as if it were exchanged
(:func:`pedx_graph.detections.image_frame.match_people`: heights alike, a positive disparity; the pixels
read as they are and, with both raw models, undistorted), and the matches on one row in both images (to
:data:`ROW_FRAC` of the height or :data:`ROW_PX`) are counted: people at one depth share their rows, so
the wrong way round some of them still match someone, but fewer.  A pair with at least :data:`MIN_MATCHES`
people matched exchanged and at least :data:`RATIO` times as many as named stops the import with one line
naming a file, the two cameras and how to name them.  The counts are in ``import_summary.json``
(``sequences.<seq>.pair_order``).
"""
from __future__ import annotations

from collections import defaultdict

import numpy as np

from pedx_graph.data.types import DataFormatError, StereoCalibration
from pedx_graph.detections.image_frame import match_people, pair_row_cost
from pedx_graph.detections.undistort import undistort_rectify

#: A pair is taken as exchanged with at least this many people matched that way ...
MIN_MATCHES = 6
#: ... and at least this many times as many as matched as named.
RATIO = 2.0
#: A matched person lies on one row in both images within this fraction of its height ...
ROW_FRAC = 0.03
#: ... or this many pixels.
ROW_PX = 5.0
#: At most this many frames per pair (evenly spread) are matched.
MAX_FRAMES = 100


def _readings(det, raw, min_confidence: float) -> tuple[np.ndarray, ...]:
    uv = np.where((np.asarray(det.confidence) >= min_confidence)[:, None], np.asarray(det.image_uv, float), np.nan)
    return (uv,) if raw is None else (uv, undistort_rectify(uv, raw))


def _on_one_row(left: list, right: list) -> int:
    """How many of one frame's people matched between ``left`` and ``right`` (:func:`match_people`) lie on
    one row in both, to within :data:`ROW_FRAC` of their height or :data:`ROW_PX` (a person matched with
    someone else in the other image, at about the same rows, is not)."""
    count = 0
    for a, b in match_people(left, right):
        costs = [pair_row_cost(la, rb, 4) for la, rb in zip(left[a], right[b])]
        costs = [c for c in costs if c is not None]
        height = max(np.ptp(left[a][0][np.all(np.isfinite(left[a][0]), axis=1), 1]), 1.0)
        count += int(bool(costs) and min(costs) <= max(ROW_PX, ROW_FRAC * height))
    return count


def pair_order(detections: list, calibrations: dict[str, StereoCalibration], min_confidence: float,
               where: str = "", refuse: bool = True) -> dict[str, dict]:
    """Pair name -> ``{"matched", "matched_exchanged", "exchanged"}`` for the pairs with detections in both
    cameras (module docstring); with ``refuse``, :class:`DataFormatError` for a pair whose cameras look
    exchanged (``exchanged`` true)."""
    out = {}
    for name, calib in sorted(calibrations.items()):
        left, _, right = name.partition("-")
        both_raw = calib.left_raw is not None and calib.right_raw is not None
        raws = {left: calib.left_raw if both_raw else None, right: calib.right_raw if both_raw else None}
        by_frame: dict[int, dict[str, list]] = defaultdict(lambda: {left: [], right: []})
        first = {}
        for det in detections:
            if det.camera in raws:
                by_frame[det.frame][det.camera].append(det)
                first.setdefault(det.camera, det)
        frames = sorted(f for f, sides in by_frame.items() if sides[left] and sides[right])
        if not frames:
            continue
        if len(frames) > MAX_FRAMES:
            frames = [frames[i] for i in np.linspace(0, len(frames) - 1, MAX_FRAMES).round().astype(int)]
        named = exchanged = 0
        for f in frames:            # the readings of the frames matched only
            lf, rt = ([_readings(det, raws[camera], min_confidence) for det in by_frame[f][camera]]
                      for camera in (left, right))
            named += _on_one_row(lf, rt)
            exchanged += _on_one_row(rt, lf)
        looks_exchanged = exchanged >= MIN_MATCHES and exchanged >= RATIO * max(named, 1)
        out[name] = {"matched": named, "matched_exchanged": exchanged, "exchanged": looks_exchanged}
        if looks_exchanged and refuse:
            raise DataFormatError(
                first[left].source.split("#")[0], "camera",
                f"{where or 'detections'}: pair {name}: the people of the image named {left} (the left camera) lie "
                f"to the right of those of {right} ({exchanged} people matched with the cameras exchanged, "
                f"{named} as named): the two cameras' detections look named the wrong way round; check the file "
                f"names or --camera NAME=CALIB_NAME (import.check_pair_order: false only counts)")
    return out
