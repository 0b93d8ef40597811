"""Score associated tracks against the simulator's detector truth: recovered tracks, identity switches, false tracks.

The simulator writes, per detector format, what every written detection is (``truth/detections/<seq>/<fmt>.json``,
:mod:`pedx_graph.sim.detections`): a person (its tracking id, labelled or a bystander), a fragment of a person,
or clutter.  :func:`detection_truth` finds the record of a read detection from its ``source`` (OpenPose:
``<file>#people[i]`` = the i-th person of that image; COCO results: ``<file>#[n]`` = the n-th result).
:func:`score_tracks` then counts, over the output of :func:`pedx_graph.detections.association.associate`:

* each output track's *owner*: the person contributing most of its detections (``None`` when clutter or
  fragments are the majority) and its purity (owner's share of the detections);
* **false tracks**: owner None, or purity below ``min_purity`` (a track made of noise or of several people);
* **bystander tracks**: owned by a person never labelled in the sequence (a real person outside the labelled
  set: reported, not false);
* **recovered**: labelled people (at least ``min_frames`` labelled frames with distance in the bin) owning at
  least one track;
* **mixed frames**: frames of a track holding detections of two people (mostly a left image paired with the
  wrong right image);
* **identity switches**: per output track, over its frames in time order, the number of times the person
  holding most of the frame's detections changes (a tie keeps the previous person) (the track went on with someone else; both people are
  charged with it in ``switches_by_person``);
* **wrong frames**: frames of a track with an owner whose person (as for the switches) is someone else —
  how many frames a switch or a swap left on the wrong track: a neighbour's stretch inside a track counts
  its frames once, where the switches count two (in and out) however short it is;
* **own / others' detections**: people's detections (clutter and fragments left out) on a track their
  person owns, and on a track someone else owns or a false one — the detections a switch or a swap put
  on the wrong track, where the wrong frames count frames;
* **fragmentation**: per labelled person, the number of
  distinct tracks holding its detections beyond the first (a person lost and found again, or seen by two
  pairs whose tracks were not merged).

:func:`placement_counts` judges the tracks' 3D centres against the people's true ones: how many frames lie
off their person, and how many of those claim a depth uncertainty that hides it.  :func:`switch_geometry`
sorts the identity switches by where the two people stood at the switch, seen from the rig: one behind the
other, paths crossing, or beside each other.  :func:`truth_fixes` writes the identity fixes
(:mod:`pedx_graph.detections.fixes`) a reviewer who sees who is who would write: what reviewing the import's
flagged stretches costs and leaves (``benchmarks/bench_identity_fixes.py``).
"""
from __future__ import annotations

import json
import re
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

_OPENPOSE_SOURCE = re.compile(r"#people\[(\d+)\]$")
_COCO_SOURCE = re.compile(r"#\[(\d+)\]$")


def read_detection_truth(root: str | Path, sequence: str, fmt: str) -> list[dict]:
    """The truth records of one format (``truth/detections/<seq>/<fmt>.json``)."""
    return json.loads((Path(root) / "truth" / "detections" / sequence / f"{fmt}.json").read_text())


def detection_records(det, records: list[dict], index: dict | None = None) -> list[dict]:
    """The truth records of a detection: one, or one per part of a person the association joined from two
    (source ``"<upper> + <lower>"``, :func:`pedx_graph.detections.association.join_split_parts`)."""
    return [_record(det.camera, det.frame, source, records, index) for source in det.source.split(" + ")]


def detection_truth(det, records: list[dict], index: dict | None = None) -> dict:
    """The truth record of a read detection (module docstring; of a joined one, its upper part's); KeyError
    when it has none."""
    return _record(det.camera, det.frame, det.source.split(" + ")[0], records, index)


def _record(camera: str, frame: int, source: str, records: list[dict], index: dict | None) -> dict:
    match = _OPENPOSE_SOURCE.search(source)
    if match:
        if index is None:
            index = {(r["camera"], r["frame"], r["index"]): r for r in records}
        return index[(camera, frame, int(match.group(1)))]
    match = _COCO_SOURCE.search(source)
    if match:
        return records[int(match.group(1))]
    raise KeyError(f"{source}: no truth index in the source")


def _who(record: dict) -> str | None:
    """The person a detection is of: a whole detection or one of the two parts of a split one (``part``);
    None for clutter and fragments."""
    return record["tracking_id"] if record["kind"] in ("person", "part") else None


def frame_owners(track, records: list[dict], index: dict | None = None) -> dict[int, str]:
    """``frame -> the person holding most of the frame's detections`` for one output track (frames holding only
    clutter or fragments are absent).  A tie keeps the previous frame's person when it is among the tied (the
    track going on with its walker), else the first tied id in sorted order — the rule of
    :func:`score_tracks`' identity switches, and the person a benchmark scores the frame's fit against."""
    index = index if index is not None else {(r["camera"], r["frame"], r["index"]): r for r in records}
    out: dict[int, str] = {}
    previous = None
    for fr in track.frames:
        frame_votes = Counter(who for who in (_who(record) for det in fr.detections.values()
                                              for record in detection_records(det, records, index))
                              if who is not None)
        if not frame_votes:
            continue
        best = max(frame_votes.values())
        tied = sorted(tid for tid, n in frame_votes.items() if n == best)
        previous = out[fr.frame] = previous if previous in tied else tied[0]
    return out


def score_tracks(tracks: list, records: list[dict], labelled: dict[str, dict[int, float]],
                 min_purity: float = 0.5, min_frames: int = 3) -> dict:
    """Counts of :func:`score_tracks` (module docstring).

    ``tracks``: :class:`~pedx_graph.detections.association.DetectedTrack` s; ``records``: the format's truth
    records; ``labelled``: tracking id -> {frame: horizontal distance (m)} of the labelled instances.
    Returns ``{"tracks", "false_tracks", "bystander_tracks", "recovered", "labelled_people",
    "id_switches", "fragmentations", "owners": {track id: owner}, "switches_by_person": {tid: count},
    "switches": [(track id, frame, from person, to person)], "mixed_frames", "wrong_frames",
    "own_detections", "others_detections"}``: the last two count people's detections (clutter and
    fragments left out) on a track their person owns, and on a track someone else owns or a false one.
    """
    index = {(r["camera"], r["frame"], r["index"]): r for r in records}
    owners, false, bystander, switches = {}, 0, 0, 0
    by_person: dict[str, int] = {}
    switch_list: list[tuple[str, int, str, str]] = []
    mixed_frames, wrong_frames, own, others = 0, 0, 0, 0
    tracks_of: dict[str, set] = defaultdict(set)
    for track in tracks:
        votes = Counter()
        for fr in track.frames:
            people = set()
            for det in fr.detections.values():
                for record in detection_records(det, records, index):
                    who = _who(record)
                    votes[who] += 1
                    if who is not None:
                        people.add(who)
                        tracks_of[who].add(track.track_id)
            if len(people) > 1:
                mixed_frames += 1               # two people's detections in one frame of one track
        previous = None
        frame_people = frame_owners(track, records, index)
        for frame, current in frame_people.items():
            if previous is not None and current != previous:
                switches += 1                   # the track went on with another person
                switch_list.append((track.track_id, frame, previous, current))
                for tid in (previous, current):
                    by_person[tid] = by_person.get(tid, 0) + 1
            previous = current
        owner, count = max(votes.items(), key=lambda kv: (kv[1], kv[0] is not None, str(kv[0])))
        purity = count / max(sum(votes.values()), 1)
        people_votes = sum(n for who, n in votes.items() if who is not None)
        if owner is None or purity < min_purity:
            false += 1
            others += people_votes
            owners[track.track_id] = None
            continue
        owners[track.track_id] = owner
        own += votes[owner]
        others += people_votes - votes[owner]
        wrong_frames += sum(1 for person in frame_people.values() if person != owner)
        if owner not in labelled:
            bystander += 1
    fragmentations, recovered, eligible = 0, 0, 0
    for tid, frames in sorted(labelled.items()):
        if len(frames) < min_frames:
            continue
        eligible += 1
        if tid in owners.values():
            recovered += 1
        fragmentations += max(len(tracks_of.get(tid, ())) - 1, 0)
    return {"tracks": len(tracks), "false_tracks": false, "bystander_tracks": bystander,
            "recovered": recovered, "labelled_people": eligible, "id_switches": switches,
            "fragmentations": fragmentations, "owners": owners, "switches_by_person": by_person,
            "switches": switch_list, "mixed_frames": mixed_frames, "wrong_frames": wrong_frames,
            "own_detections": own, "others_detections": others}


#: A track frame's centre farther than this from its person's true centre on the ground plane is misplaced,
#: metres (the LiDAR cut's depth gate reaches 0.6 m in front of the centre and 0.8 m behind it).
PLACE_OFF_M = 0.5
#: ... and overconfident when its error is also more than this many of the centre's own depth sigmas.
PLACE_SIGMAS = 3.0


def placement_counts(tracks, records: list[dict], centres: dict, ground) -> dict:
    """How well the association placed its tracks' frames in 3D.

    ``tracks``: :class:`~pedx_graph.detections.association.DetectedTrack` s; ``records``: the detector truth
    (:func:`read_detection_truth`), giving each frame's person (:func:`frame_owners`); ``centres``:
    ``(tracking id, frame) -> (3,)`` the person's true centre (world frame); ``ground``: the sequence's
    :class:`~pedx_graph.data.ground.GroundFrame`, whose plane the distances are measured in.  Returns
    ``placed_frames`` (frames with a centre whose person and true centre are known), ``misplaced_centres`` (of
    those, the ones farther than :data:`PLACE_OFF_M` from it) and ``overconfident_centres`` (of those, the
    ones whose error is also more than :data:`PLACE_SIGMAS` times the frame's ``depth_sigma_m``)."""
    index = {(r["camera"], r["frame"], r["index"]): r for r in records}
    placed = misplaced = overconfident = 0
    for track in tracks:
        owners = frame_owners(track, records, index)
        for fr in track.frames:
            truth = centres.get((owners.get(fr.frame), fr.frame))
            if fr.world_p is None or truth is None:
                continue
            level = ground.to_level(np.stack([np.asarray(fr.world_p, dtype=float), np.asarray(truth, dtype=float)]))
            error = float(np.linalg.norm(level[0, :2] - level[1, :2]))
            placed += 1
            if error > PLACE_OFF_M:
                misplaced += 1
                sigma = float(fr.depth_sigma_m) if fr.depth_sigma_m is not None else np.inf
                overconfident += int(error > PLACE_SIGMAS * sigma)
    return {"placed_frames": placed, "misplaced_centres": misplaced, "overconfident_centres": overconfident}


#: Two people whose true centres lie within this of one viewing ray from the rig (across it, on the ground
#: plane) stand one behind the other: the nearer hides most of the farther from every camera of the rig (an
#: adult's shoulders are about 0.4 m wide), metres.
IN_LINE_LATERAL_M = 0.4
#: Two people walking in directions this far apart have crossing paths, degrees.
PATHS_CROSS_DEG = 60.0
#: A person moving less than this is standing (no walking direction), metres per second.
STANDING_MPS = 0.3
#: The kinds of :func:`switch_geometry`, in its order.
SWITCH_KINDS = ("switches_in_line", "switches_paths_crossing", "switches_beside", "switches_unplaced")


def switch_geometry(switches: list[tuple], centres: dict, ground, frame_interval_s: float = 0.1) -> dict:
    """Identity switches sorted by where their two people stood at the switch frame, seen from the rig.

    ``switches``: ``(track id, frame, from person, to person)`` (:func:`score_tracks`' ``switches``);
    ``centres``: ``(tracking id, frame) -> (3,)`` true centres (world frame); ``ground``: the sequence's
    :class:`~pedx_graph.data.ground.GroundFrame` (its level frame's origin, the sensor, is the rig's
    viewpoint; distances on its ground plane).  Each person's walking velocity at the frame is the central
    difference of its centres at the frames beside it (one-sided at its ends), over ``frame_interval_s``.
    Returns counts of ``switches_paths_crossing`` (both walk, at least ``STANDING_MPS``, in directions more than
    ``PATHS_CROSS_DEG`` apart), else ``switches_in_line`` (the farther one's centre within
    ``IN_LINE_LATERAL_M`` of the nearer one's viewing ray: one behind the other), else ``switches_beside``,
    and ``switches_unplaced`` (a person without a true centre at that frame)."""
    counts = dict.fromkeys(SWITCH_KINDS, 0)

    def velocity(person, frame: int, here: np.ndarray) -> np.ndarray | None:
        after, before = centres.get((person, frame + 1)), centres.get((person, frame - 1))
        if after is not None and before is not None:
            step = (ground.to_level(after) - ground.to_level(before)) / 2.0
        elif after is not None or before is not None:
            step = ground.to_level(after) - here if after is not None else here - ground.to_level(before)
        else:
            return None
        return step[:2] / frame_interval_s

    for _, frame, one, other in switches:
        a, b = centres.get((one, frame)), centres.get((other, frame))
        if a is None or b is None:
            counts["switches_unplaced"] += 1
            continue
        level_a, level_b = ground.to_level(np.asarray(a, dtype=float)), ground.to_level(np.asarray(b, dtype=float))
        va, vb = velocity(one, frame, level_a), velocity(other, frame, level_b)
        if va is not None and vb is not None and min(np.linalg.norm(va), np.linalg.norm(vb)) >= STANDING_MPS:
            cos = float(va @ vb / (np.linalg.norm(va) * np.linalg.norm(vb)))
            if cos < np.cos(np.radians(PATHS_CROSS_DEG)):
                counts["switches_paths_crossing"] += 1
                continue
        near, far = sorted((level_a[:2], level_b[:2]), key=np.linalg.norm)
        ray = near / max(float(np.linalg.norm(near)), 1e-9)
        lateral = abs(float(far[0] * ray[1] - far[1] * ray[0]))
        counts["switches_in_line" if lateral <= IN_LINE_LATERAL_M else "switches_beside"] += 1
    return counts


def truth_fixes(tracks, records: list[dict], cameras, stretches: list[dict] | None = None,
                untracked: list | None = None) -> list:
    """The identity fixes (:mod:`pedx_graph.detections.fixes`) a reviewer who sees who is who would write: each
    person's detection on a track another person owns (the owner as in :func:`score_tracks`: most of the
    track's detections) is moved to the track its person owns (the nearest in time when several), exchanged
    with the detection that track holds in that camera and frame, or removed when its person owns no track;
    then, with ``untracked`` (the detections no track holds), each of them whose person owns a track without
    a detection in that camera and frame is added to it.  With ``stretches`` (the identity review's,
    :func:`pedx_graph.detections.review.review_stretches`) only detections inside a stretch naming their track
    are looked at, and only the untracked ones a one-track stretch lists (drawn on its sheet): what a reviewer
    checking the flagged stretches alone would fix.  Operations of consecutive frames alike are written as
    one (``frames: [first, last]``), as a reviewer writes a stretch.  Clutter and fragments are left where
    they are."""
    from pedx_graph.detections.fixes import IdentityFix, apply_fixes, source_index

    index = {(r["camera"], r["frame"], r["index"]): r for r in records}
    groups = {t.track_id: {fr.frame: dict(fr.detections) for fr in t.frames} for t in tracks}

    def who(det) -> str | None:
        return _who(detection_records(det, records, index)[0])

    owners = score_tracks(tracks, records, {})["owners"]

    def reviewed(tid: str, frame: int) -> bool:
        return stretches is None or any(tid in s["tracks"] and s["first_frame"] <= frame <= s["last_frame"]
                                        for s in stretches)

    fixes: list = []
    for _ in range(4):                                   # an exchange can bring in a detection to fix next round
        before = len(fixes)
        for tid in sorted(groups):
            owner = owners.get(tid)
            if owner is None:
                continue
            for frame in sorted(groups.get(tid, {})):
                for cam in sorted(groups.get(tid, {}).get(frame, {})):
                    det = groups[tid][frame].get(cam)
                    person = who(det) if det is not None else None
                    if person is None or person == owner or not reviewed(tid, frame):
                        continue
                    targets = [t for t, o in sorted(owners.items()) if o == person and t in groups and t != tid]
                    if not targets:
                        fix = IdentityFix("remove", (tid,), frame, frame, (cam,))
                    else:
                        target = min(targets, key=lambda t: (min(abs(f - frame) for f in groups[t]), t))
                        kind = "exchange" if cam in groups[target].get(frame, {}) else "move"
                        fix = IdentityFix(kind, (tid, target), frame, frame, (cam,))
                    groups, _ = apply_fixes(groups, [fix], "<truth>", cameras)
                    fixes.append(fix)
        if len(fixes) == before:
            break
    if untracked:
        listed = None if stretches is None else {
            (s["tracks"][0], u["camera"], u["frame"], u["source"]) for s in stretches if len(s["tracks"]) == 1
            for u in s.get("untracked", [])}
        remaining = list(untracked)
        for det in untracked:
            person = who(det)
            targets = sorted(t for t, o in owners.items() if o == person and t in groups) if person else []
            if not targets:
                continue
            target = min(targets, key=lambda t: (min(abs(f - det.frame) for f in groups[t]), t))
            if det.camera in groups[target].get(det.frame, {}) or (
                    listed is not None and (target, det.camera, det.frame, det.source) not in listed):
                continue
            alike = [d for d in remaining if (d.camera, d.frame) == (det.camera, det.frame)]
            named = source_index(det) if len(alike) > 1 else None
            if len(alike) > 1 and named is None:
                continue                                 # a joined detection among others: no index names it
            fix = IdentityFix("add", (target,), det.frame, det.frame, (det.camera,), detection=named)
            groups, _ = apply_fixes(groups, [fix], "<truth>", cameras, remaining)
            remaining = [d for d in remaining if d is not det]
            fixes.append(fix)
    return _coalesced(fixes)


def _coalesced(fixes: list) -> list:
    """``fixes`` with operations of one kind on the same tracks written together: at one frame over several
    cameras, then over consecutive frames with the same cameras."""
    import dataclasses

    out: list = []
    for fix in fixes:
        last = out[-1] if out else None
        if last is not None and last.kind == fix.kind and last.tracks == fix.tracks \
                and last.detection is None and fix.detection is None:
            if (last.first_frame, last.last_frame) == (fix.first_frame, fix.last_frame) \
                    and not set(fix.cameras) & set(last.cameras):
                out[-1] = dataclasses.replace(last, cameras=tuple(sorted(set(last.cameras) | set(fix.cameras))))
                continue
        out.append(fix)
    runs: list = []
    for fix in out:
        last = runs[-1] if runs else None
        if last is not None and last.kind == fix.kind and last.tracks == fix.tracks \
                and last.cameras == fix.cameras and fix.first_frame == last.last_frame + 1 \
                and last.detection is None and fix.detection is None:
            runs[-1] = dataclasses.replace(last, last_frame=fix.last_frame)
            continue
        runs.append(fix)
    return runs
