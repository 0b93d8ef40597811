"""Where the association's identities deserve a second look: stretches of frames where two tracks came close.

An id-less association decides who is who from positions, sizes and depths; where two people overlap in an
image or walk within a metre of each other it can carry one person's track on with the other
(docs/detections.md lists the cases).  Those places are known without any truth: this module lists them, so
that a team building a dataset checks a few stretches instead of every frame.

Two tracks are *close* at a frame when

* **in an image** both have a detection in, at that frame or up to ``frame_step`` frames apart (a track that
  took another's detection where its own person was missed sits where the other was a frame before): their
  keypoints' median columns differ by at most ``column_frac`` times the taller one's keypoint height, their
  keypoint rows overlap and their heights differ by at most ``max_height_ratio`` (one stands in front of the
  other at a similar distance: the tracker's and the swap repair's confusion), or
* **on the ground**: both have a 3D centre and the two lie within ``ground_m`` of each other in the ground
  plane (the merging of pairs' tracks and the LiDAR cut can confuse them there).

A track is also close to a detection *no track holds* (``untracked``: dropped as a duplicate of the track's
own, or left over by the tracker) by the same image test (with ``ReviewConfig.untracked``): two people on
nearly one ray look alike in one image, the association keeps one of two such detections and can keep the
other person's (a detector's true duplicate is flagged too; the sheet shows which it is).  Such a stretch
names the one track and lists those detections (``"untracked"``).

Each close frame is widened by ``pad_frames`` on both sides, and on across a gap of either track to the
frame where it is seen again (a track can take the other's person across frames where its own was missed);
the frames of each pair of tracks are joined into stretches.  Pixels are the raw images' (an overlap test:
the lens distortion does not matter at this tolerance), metres the world (LiDAR) frame's.

Which to check first: a tracker takes one person for another where it has missed its own (a gap, while the
other walks on near it), so each stretch counts the frames its two tracks hold in it and the frames inside
their own spans they do not, and :func:`review_summary` orders the stretches by that missed share, highest
first (``check_order``; equal shares: the shorter first).  Measured in ``benchmarks/bench_association.py``
(its "Identity review"; docs/detections.md).
"""
from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from pedx_graph.data.ground import GroundFrame


@dataclass
class ReviewConfig:
    """When two tracks, or a track and a detection no track holds, count as close (module docstring).
    Defaults: on ``benchmarks/bench_association.py``'s inputs (crossings and walking groups) the stretches hold
    13 of the 14 identity switches and flag 34 % of the track frames (without ``untracked``: 12 and 31 %);
    wider tests flag more for little more (docs/detections.md, "Where to check who is who")."""

    column_frac: float = 0.2
    """Two detections in one image are close when their median keypoint columns differ by at most this
    fraction of the taller one's keypoint height (about a body's width: one stands in front of the other)."""
    max_height_ratio: float = 1.2
    """... and the taller one's keypoint height is at most this many times the other's (people at very
    different depths overlap in the image but are not taken for each other: their sizes differ)."""
    frame_step: int = 1
    """Detections up to this many frames apart are compared too (a track that took, in a frame where its own
    person was missed, the detection of someone another track holds the frame before or after)."""
    ground_m: float = 0.7
    """Two tracks' centres within this distance of each other in the ground plane are close (people walking
    side by side), metres."""
    pad_frames: int = 1
    """Each close frame also flags this many frames before and after it."""
    min_confidence: float = 0.1
    """Keypoints below this confidence are left out of the columns and heights."""
    untracked: bool = True
    """Compare each track's detections with the detections no track holds as well (module docstring): a track
    that kept the other of two people on one ray is flagged where it did."""


def _extent(uv: np.ndarray, confidence: np.ndarray, min_confidence: float) -> tuple[float, float, float] | None:
    """(median column, top row, bottom row) of a detection's confident keypoints, or None with fewer than 2."""
    ok = np.all(np.isfinite(uv), axis=1) & (np.asarray(confidence) >= min_confidence)
    if ok.sum() < 2:
        return None
    return float(np.median(uv[ok, 0])), float(uv[ok, 1].min()), float(uv[ok, 1].max())


def _close_in_image(a: tuple[float, float, float], b: tuple[float, float, float], column_frac: float,
                    max_height_ratio: float) -> bool:
    """Two detections' (median column, top row, bottom row) in one image: close (module docstring)."""
    ha, hb = max(a[2] - a[1], 1.0), max(b[2] - b[1], 1.0)
    rows_overlap = min(a[2], b[2]) >= max(a[1], b[1])
    return (rows_overlap and abs(a[0] - b[0]) <= column_frac * max(ha, hb)
            and max(ha, hb) <= max_height_ratio * min(ha, hb))


def _image_items(tracks: list, untracked: list, config: ReviewConfig) -> dict[tuple[str, int], list[tuple]]:
    """``(camera, frame)`` -> ``(owner, extent, detection)`` of every detection in that image: owner the track
    id, or ``None`` for one of ``untracked``."""
    by_image: dict[tuple[str, int], list[tuple]] = defaultdict(list)
    entries = [(track.track_id, fr.frame, camera, det) for track in tracks for fr in track.frames
               for camera, det in fr.detections.items()]
    entries += [(None, det.frame, det.camera, det) for det in untracked]
    for owner, frame, camera, det in entries:
        extent = _extent(np.asarray(det.image_uv, dtype=float), det.confidence, config.min_confidence)
        if extent is not None:
            by_image[(camera, frame)].append((owner, extent, det))
    return by_image


def close_detections(tracks: list, ground: GroundFrame | None = None, config: ReviewConfig | None = None,
                     untracked: list | None = None) -> tuple[dict[tuple[str, str], set[int]], dict[str, dict]]:
    """Where tracks came close (module docstring; without the padding): ``(pairs, lone)``.  ``pairs``: ``(track
    id a, track id b)`` (a < b) -> the frames at which the two were close; ``lone``: track id -> ``{frame:
    [untracked detection, ...]}``, the frames at which one of ``untracked`` (the detections no track holds;
    only with ``config.untracked``) was close to the track, with those detections (each at its own frame,
    which is that frame or ``frame_step`` from it).  ``tracks``:
    :class:`~pedx_graph.detections.association.DetectedTrack` s; ``ground`` for the ground-plane test (None:
    the world's x-y plane)."""
    config = config or ReviewConfig()
    by_image = _image_items(tracks, list(untracked or []) if config.untracked else [], config)
    centres: dict[int, list[tuple[str, np.ndarray]]] = defaultdict(list)
    for track in tracks:
        for fr in track.frames:
            if fr.world_p is not None and np.all(np.isfinite(fr.world_p)):
                p = np.asarray(fr.world_p, dtype=float)
                centres[fr.frame].append((track.track_id, (ground.to_level(p) if ground is not None else p)[:2]))
    pairs: dict[tuple[str, str], set[int]] = defaultdict(set)
    lone: dict[str, dict[int, list]] = defaultdict(lambda: defaultdict(list))
    for (camera, frame), items in sorted(by_image.items(), key=lambda item: item[0]):
        for step in range(config.frame_step + 1):          # the same frame, and the next ones
            later = items if step == 0 else by_image.get((camera, frame + step), [])
            for i, (ta, ea, da) in enumerate(items):
                for tb, eb, db in (later[i + 1:] if step == 0 else later):
                    if ta == tb or not _close_in_image(ea, eb, config.column_frac, config.max_height_ratio):
                        continue
                    if ta is not None and tb is not None:
                        pairs[tuple(sorted((ta, tb)))].update((frame, frame + step))
                    elif ta is not None:
                        lone[ta][frame].append(db)
                    elif tb is not None:
                        lone[tb][frame + step].append(da)
    for frame, items in centres.items():
        for i in range(len(items)):
            for j in range(i + 1, len(items)):
                (ta, pa), (tb, pb) = items[i], items[j]
                if ta != tb and np.linalg.norm(pa - pb) <= config.ground_m:
                    pairs[tuple(sorted((ta, tb)))].add(frame)
    return dict(pairs), {tid: dict(frames) for tid, frames in lone.items()}


def close_frames(tracks: list, ground: GroundFrame | None = None,
                 config: ReviewConfig | None = None) -> dict[tuple[str, str], set[int]]:
    """``(track id a, track id b)`` (a < b) -> the frames at which the two were close (module docstring;
    without the padding; two tracks only: :func:`close_detections` gives the untracked detections too).
    ``tracks``: :class:`~pedx_graph.detections.association.DetectedTrack` s; ``ground`` for the ground-plane
    test (None: the world's x-y plane)."""
    return close_detections(tracks, ground, config)[0]


def review_stretches(tracks: list, ground: GroundFrame | None = None,
                     config: ReviewConfig | None = None, untracked: list | None = None) -> list[dict]:
    """The stretches to check: ``{"tracks": [a, b], "first_frame", "last_frame", "close_frames",
    "frames_held", "frames_missed"}`` per run of frames where tracks ``a`` and ``b`` were close, each close
    frame widened by ``pad_frames`` and on to the nearest frames where each of the two is seen (a track can
    take the other's person across frames where its own was missed), within the frames either spans (a < b;
    sorted by tracks, then frame).  ``frames_held``: the stretch's frames each of the two holds, summed;
    ``frames_missed``: those inside each one's own first and last frame that it does not hold, summed.
    A track close to detections of ``untracked`` (those no track holds; :func:`close_detections`) gets
    stretches of its own the same way: ``"tracks": [a]`` and ``"untracked"``: the ``{"camera", "frame",
    "source"}`` of those detections (sorted; after the pairs' stretches, sorted by track, then frame)."""
    config = config or ReviewConfig()
    seen = {t.track_id: {fr.frame for fr in t.frames} for t in tracks}
    pairs, lone = close_detections(tracks, ground, config, untracked)
    out = []
    for names, frames, near in ([((a, b), frames, None) for (a, b), frames in sorted(pairs.items())]
                                + [((a,), set(near), near) for a, near in sorted(lone.items())]):
        owns = [seen[name] for name in names]
        first = min(min(own) for own in owns)
        last = max(max(own) for own in owns)
        flagged = set()
        for f in frames:
            lo, hi = f - config.pad_frames, f + config.pad_frames
            for own in owns:                    # on through a track's gap, to where it is seen again
                lo = min(lo, max((g for g in own if g <= f - config.pad_frames), default=lo))
                hi = max(hi, min((g for g in own if g >= f + config.pad_frames), default=hi))
            flagged.update(range(max(lo, first), min(hi, last) + 1))
        runs: list[list[int]] = []                  # consecutive flagged frames: [first, last]
        for frame in sorted(flagged):
            if runs and frame == runs[-1][1] + 1:
                runs[-1][1] = frame
            else:
                runs.append([frame, frame])
        for start, end in runs:
            held = missed = 0
            for own in owns:
                lo, hi = max(start, min(own)), min(end, max(own))
                inside = sum(1 for f in own if lo <= f <= hi)
                held += inside
                missed += max(hi - lo + 1, 0) - inside
            stretch = {"tracks": list(names), "first_frame": int(start), "last_frame": int(end),
                       "close_frames": sorted(int(f) for f in frames if start <= f <= end),
                       "frames_held": int(held), "frames_missed": int(missed)}
            if near is not None:
                listed = sorted({(det.camera, int(det.frame), det.source) for f, dets in near.items()
                                 if start <= f <= end for det in dets})
                stretch["untracked"] = [{"camera": c, "frame": f, "source": src} for c, f, src in listed]
            out.append(stretch)
    return out


def check_order(stretches: list[dict]) -> list[int]:
    """Indices of ``stretches`` in the order to check them (module docstring): by missed share
    ``frames_missed / (frames_held + frames_missed)``, highest first; equal shares, fewer frames first."""
    def share(stretch: dict) -> float:
        total = stretch["frames_held"] + stretch["frames_missed"]
        return stretch["frames_missed"] / total if total else 0.0

    return sorted(range(len(stretches)), key=lambda i: (-share(stretches[i]), stretches[i]["frames_held"], i))


def flagged_frames(tracks: list, stretches: list[dict]) -> dict[str, set[int]]:
    """Track id -> its own frames inside one of ``stretches`` that names it."""
    own = {t.track_id: {fr.frame for fr in t.frames} for t in tracks}
    out: dict[str, set[int]] = {tid: set() for tid in own}
    for stretch in stretches:
        for tid in stretch["tracks"]:
            out[tid] |= {f for f in own.get(tid, ()) if stretch["first_frame"] <= f <= stretch["last_frame"]}
    return out


def untracked_detections(detections: list, tracks: list) -> list:
    """The detections of ``detections`` no track holds (compared by camera, frame and source; a track's
    detection joined from two parts, ``"<upper> + <lower>"``, holds both), in their order."""
    held = {(det.camera, det.frame, part) for track in tracks for fr in track.frames
            for det in fr.detections.values() for part in str(det.source).split(" + ")}
    return [det for det in detections if (det.camera, det.frame, det.source) not in held]


def review_summary(tracks: list, ground: GroundFrame | None = None, config: ReviewConfig | None = None,
                   untracked: list | None = None) -> dict:
    """What the import records (``import_summary.json``, ``sequences.<seq>.identity_review``): the
    :func:`review_stretches` (with the detections no track holds, ``untracked``:
    :func:`untracked_detections`), how many of the tracks' frames they flag of all, and the order to check
    them in (:func:`check_order`)."""
    stretches = review_stretches(tracks, ground, config, untracked)
    return {"flagged_track_frames": sum(len(v) for v in flagged_frames(tracks, stretches).values()),
            "track_frames": sum(len(t.frames) for t in tracks), "stretches": stretches,
            "check_order": check_order(stretches)}
