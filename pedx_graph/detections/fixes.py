"""A reviewer's identity fixes: read from a YAML file and applied to the import's tracks before they are written.

The association decides who is who without ids and can take one person for another (walkers on nearly one
ray, crossings); the identity review (:mod:`pedx_graph.detections.review`) lists where.  A team building a
dataset looks there and writes down what is wrong, once, in a file the import applies
(``pedx-graph import ... --identity-fixes FILE``), so the import stays one reproducible command: the
association is deterministic, so the same inputs and config give the same track ids the fixes name.

The file maps each sequence to a list of operations, applied in order; each names the tracks (ids as the
import wrote them, ``det000006``, or the files' ids with ``--use-file-ids``) and optionally which frames
(``frames: [first, last]``, inclusive, or one frame) and which cameras (``cameras: [...]``; omitted: all)::

    20171130T2000:
      - exchange: [det000006, det000007]   # the two tracks' detections exchanged there
        frames: [14, 18]
        cameras: [red707B]
      - move: [det000011, det000006]       # det000011's detections there given to det000006
        frames: 16
      - split: det000011                   # frames from `at` on become a track of their own
        at: 14
        new_id: det000031                  # optional; default: the next free detNNNNNN
      - merge: [det000002, det000009]      # one person: all into the first
      - remove: det000004                  # a false track, or its detections there (then untracked)
        frames: [3, 5]
      - add: det000007                     # a detection no track holds (the review lists them) given to it:
        frames: 12                         # in each selected camera and frame the one there, or the one
        cameras: red707B                   # whose index in its file is `detection` (OpenPose people[i],
        detection: 3                       # a COCO results file's [n])
      - checked: [det000002, det000005]    # looked at, right as it is: the review's stretches of these
        frames: [0, 19]                    # tracks within these frames are marked checked

Track ids are only stable while the association's output is: another version of pedx-graph, another config or
other detection files can number the tracks differently, and an old fix would then exchange the wrong
people.  The import writes each sequence's ``tracks_digest`` (:func:`tracks_digest`: a digest of which
detections each track holds, before any fix) into ``import_summary.json``; a sequence's entry may be written
as a mapping that names it, and the import then refuses fixes made for other tracks::

    20171130T2000:
      made_for: 3f9c0a1b2d4e5f60        # sequences.<seq>.tracks_digest of the import the fixes were made on
      operations:
        - exchange: [det000006, det000007]
          frames: [14, 18]

Every import also writes ``identity_fixes_template.yaml`` beside its output (:func:`fixes_template`): per
sequence its ``made_for`` digest and, commented out, one ``checked`` operation per stretch still to look at,
in the order to check them, naming the stretch's review sheet: what the reviewer edits into the fix it needs
(or uncomments as it is) and adds to the fixes file.

The review is made again on the fixed tracks (:func:`mark_checked`): stretches a ``checked`` operation covers
are marked ``"checked": true`` and left out of the order to check in and of the review sheets, so a second
run of the import lists only what is still to look at.

An operation that selects no detection, names a track or camera the import does not have, or would put two
detections of one camera into one track at a frame is an error naming the file and the operation
(``<sequence>[i].<kind>``): a fix that silently does nothing would leave the switch it was written for.
After the fixes (:func:`fix_tracks`) the tracks they changed are placed again from their detections as with
the files' ids (:func:`pedx_graph.detections.association.tracks_from_ids`, every track's detections taking
part, so each image's LiDAR clusters are shared out among all its people): the fixed ids are given, not
guessed.  The tracks no fix changed keep the association's frames and centres as they were.
"""
from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from pedx_graph.data.types import DataFormatError
from pedx_graph.detections.types import Detection

#: Operations of a fixes file, and the fewest and most tracks each names (None: no limit).
FIX_KINDS = {"exchange": (2, 2), "move": (2, 2), "split": (1, 1), "merge": (2, None), "remove": (1, 1),
             "add": (1, 1), "checked": (1, 2)}
#: Keys an operation may hold beside its kind.
_OPTIONS = {"exchange": {"frames", "cameras"}, "move": {"frames", "cameras"}, "split": {"at", "new_id"},
            "merge": set(), "remove": {"frames", "cameras"}, "add": {"frames", "cameras", "detection"},
            "checked": {"frames"}}
#: The index of a detection in its file, at the end of its ``source``: OpenPose ``#people[i]``, COCO ``#[n]``.
_SOURCE_INDEX = re.compile(r"#(?:people)?\[(\d+)\]$")
#: A track's frames: frame -> camera -> detection.
Groups = dict[str, dict[int, dict[str, Detection]]]


@dataclass(frozen=True)
class IdentityFix:
    """One operation of a fixes file (module docstring)."""

    kind: str
    """One of :data:`FIX_KINDS`."""
    tracks: tuple[str, ...]
    """The track ids it names, in the file's order (``move``: from, to; ``merge``: into the first)."""
    first_frame: int | None = None
    """First frame it acts on (inclusive); None: from the tracks' first (``split``: the first frame of the new
    track)."""
    last_frame: int | None = None
    """Last frame it acts on (inclusive); None: to the tracks' last."""
    cameras: tuple[str, ...] | None = None
    """Cameras it acts on; None: every camera."""
    new_id: str | None = None
    """``split``: the new track's id; None: the next free ``detNNNNNN``."""
    detection: int | None = None
    """``add``: the index of the detection in its file (OpenPose ``people[i]``, COCO results ``[n]``); None:
    the one detection no track holds in each selected camera and frame."""
    where: str = ""
    """Where in the file: ``<sequence>[i].<kind>``, for error messages."""

    def selects(self, frame: int, camera: str) -> bool:
        """Whether the operation acts on ``camera``'s detection at ``frame``."""
        return ((self.first_frame is None or frame >= self.first_frame)
                and (self.last_frame is None or frame <= self.last_frame)
                and (self.cameras is None or camera in self.cameras))


@dataclass(frozen=True)
class SequenceFixes:
    """The fixes of one sequence."""

    operations: tuple[IdentityFix, ...]
    """Applied in order."""
    made_for: str | None = None
    """The :func:`tracks_digest` of the tracks the fixes were written for; None: not checked."""


def tracks_digest(tracks) -> str:
    """16 hex digits that change whenever a track's id or the detections it holds change (camera, frame and
    source of each, the source by its file's name and place in the file, so the same files read from
    another folder or by a relative path give the same digest; over
    :class:`~pedx_graph.detections.association.DetectedTrack` s): what fixes naming track ids depend on."""
    import hashlib

    def where(source: str) -> str:
        return " + ".join(f"{Path(file).name}#{place}" for file, _, place in
                          (part.partition("#") for part in str(source).split(" + ")))

    items = sorted((track.track_id, fr.frame, camera, where(det.source))
                   for track in tracks for fr in track.frames for camera, det in fr.detections.items())
    return hashlib.sha256(repr(items).encode()).hexdigest()[:16]


def read_fixes(path: str | Path) -> dict[str, SequenceFixes]:
    """The fixes of a fixes file per sequence (module docstring); a malformed file or operation raises
    :class:`~pedx_graph.data.types.DataFormatError` naming the file and the field."""
    import yaml

    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1})" if mark is not None else ""
        raise DataFormatError(path, None, f"not YAML{where}: {getattr(exc, 'problem', exc)}") from None
    if doc is None:
        return {}
    if not isinstance(doc, dict):
        raise DataFormatError(path, None, "expected a mapping of sequence names to lists of operations")
    out: dict[str, SequenceFixes] = {}
    for seq, entry in doc.items():
        made_for = None
        items, where = entry, str(seq)
        if isinstance(entry, dict):
            unknown = set(entry) - {"made_for", "operations"}
            if unknown:
                raise DataFormatError(path, f"{seq}.{sorted(map(str, unknown))[0]}",
                                      "not a key of a sequence's fixes (made_for, operations)")
            made_for = entry.get("made_for")
            if made_for is not None and not (isinstance(made_for, str) and made_for):
                raise DataFormatError(path, f"{seq}.made_for", f"expected a tracks digest, got {made_for!r}")
            items, where = entry.get("operations") or [], f"{seq}.operations"
        if not isinstance(items, list):
            raise DataFormatError(path, where, "expected a list of operations")
        out[str(seq)] = SequenceFixes(tuple(_parse_fix(path, f"{where}[{i}]", item) for i, item in enumerate(items)),
                                      made_for)
    return out


def _parse_fix(path: Path, where: str, item) -> IdentityFix:
    if not isinstance(item, dict):
        raise DataFormatError(path, where, f"expected a mapping with one of {', '.join(FIX_KINDS)}")
    kinds = [k for k in item if k in FIX_KINDS]
    if len(kinds) != 1:
        raise DataFormatError(path, where, f"expected exactly one of {', '.join(FIX_KINDS)}, got "
                                           f"{', '.join(map(str, item)) or 'nothing'}")
    kind = kinds[0]
    field = f"{where}.{kind}"
    unknown = set(item) - {kind} - _OPTIONS[kind]
    if unknown:
        raise DataFormatError(path, f"{where}.{sorted(map(str, unknown))[0]}",
                              f"not an option of {kind} (options: {', '.join(sorted(_OPTIONS[kind])) or 'none'})")
    value = item[kind]
    tracks = (value,) if isinstance(value, (str, int)) else tuple(value) if isinstance(value, list) else None
    if tracks is None or not all(_is_name(t) for t in tracks):
        raise DataFormatError(path, field, f"expected track ids, got {value!r}")
    tracks = tuple(str(t) for t in tracks)              # numeric file ids (OpenPose person_id) unquoted
    fewest, most = FIX_KINDS[kind]
    if len(tracks) < fewest or (most is not None and len(tracks) > most):
        takes = f"{fewest}" if fewest == most else f"{fewest} or more" if most is None else f"{fewest} to {most}"
        raise DataFormatError(path, field, f"names {len(tracks)} tracks, {kind} takes {takes}")
    if len(set(tracks)) != len(tracks):
        raise DataFormatError(path, field, f"names a track twice: {list(tracks)}")
    first = last = None
    if "frames" in item:
        first, last = _frames(path, f"{where}.frames", item["frames"])
    if kind == "split":
        if "at" not in item:
            raise DataFormatError(path, f"{where}.at", "split needs the frame the new track begins at")
        if not _is_int(item["at"]):
            raise DataFormatError(path, f"{where}.at", f"expected a frame number, got {item['at']!r}")
        first = int(item["at"])
    cameras = None
    if "cameras" in item:
        cams = item["cameras"]
        cams = [cams] if isinstance(cams, (str, int)) else cams
        if not isinstance(cams, list) or not cams or not all(_is_name(c) for c in cams):
            raise DataFormatError(path, f"{where}.cameras", f"expected camera names, got {item['cameras']!r}")
        cameras = tuple(str(c) for c in cams)
    new_id = item.get("new_id")
    if new_id is not None and not _is_name(new_id):
        raise DataFormatError(path, f"{where}.new_id", f"expected a track id, got {new_id!r}")
    new_id = None if new_id is None else str(new_id)
    detection = item.get("detection")
    if kind == "add":
        if first is None or cameras is None:
            raise DataFormatError(path, f"{where}.{'frames' if first is None else 'cameras'}",
                                  "add needs the frames and cameras of the detections it gives")
        if detection is not None and not (_is_int(detection) and detection >= 0):
            raise DataFormatError(path, f"{where}.detection", f"expected an index in the file, got {detection!r}")
        if detection is not None and (first != last or len(cameras) != 1):
            raise DataFormatError(path, f"{where}.detection", "names one detection: give one frame and one camera")
    return IdentityFix(kind=kind, tracks=tracks, first_frame=first, last_frame=last, cameras=cameras,
                       new_id=new_id, detection=detection, where=field)


def _is_name(value) -> bool:
    """A track id or camera name as YAML gives it: a non-empty string or an integer (not a boolean)."""
    return (isinstance(value, str) and bool(value)) or _is_int(value)


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _frames(path: Path, field: str, value) -> tuple[int, int]:
    if _is_int(value):
        return int(value), int(value)
    if isinstance(value, list) and len(value) == 2 and all(_is_int(v) for v in value) and value[0] <= value[1]:
        return int(value[0]), int(value[1])
    raise DataFormatError(path, field, f"expected a frame or [first, last] with first <= last, got {value!r}")


def apply_fixes(groups: Mapping[str, Mapping[int, Mapping[str, Detection]]], fixes: Iterable[IdentityFix],
                path: str | Path, cameras: Iterable[str], untracked: Iterable[Detection] = ()
                ) -> tuple[Groups, dict]:
    """``groups`` (track id -> frame -> camera -> detection) after ``fixes`` in order (module docstring), with
    each detection's ``track_id`` set to its track's; tracks left without a detection are gone.  ``cameras``:
    the import's calibrated cameras (a fix naming another is an error); ``untracked``: the detections no track
    holds (:func:`pedx_graph.detections.review.untracked_detections`), which ``add`` gives to a track (a
    detection ``remove`` takes out joins them).  ``checked`` operations change nothing here (their tracks must
    exist; :func:`mark_checked` uses them).  Returns the new groups and a record for the import summary:
    operations, detections moved, added and removed, the tracks changed."""
    out: Groups = {tid: {frame: dict(cams) for frame, cams in frames.items()} for tid, frames in groups.items()}
    loose: dict[tuple[str, int], list[Detection]] = {}
    for det in untracked:
        loose.setdefault((det.camera, det.frame), []).append(det)
    known = set(cameras)
    path = Path(path)
    moved = removed = added = 0
    changed: set[str] = set()
    fixes = list(fixes)
    for fix in fixes:
        missing = [t for t in fix.tracks if t not in out]
        if missing:
            raise DataFormatError(path, fix.where, f"no track {missing[0]} here ({_id_range(out)})")
        unknown = [c for c in fix.cameras or () if c not in known]
        if unknown:
            raise DataFormatError(path, fix.where, f"no camera {unknown[0]} in the calibration "
                                                   f"({', '.join(sorted(known))})")
        if fix.kind == "checked":
            continue
        if fix.kind == "exchange":
            a, b = fix.tracks
            taken = [_take(out[a], fix), _take(out[b], fix)]
            if not taken[0] and not taken[1]:
                raise DataFormatError(path, fix.where, f"selects no detection of {a} or {b}")
            _put(out[b], taken[0]), _put(out[a], taken[1])
            moved += len(taken[0]) + len(taken[1])
            changed.update(fix.tracks)
        elif fix.kind == "move":
            a, b = fix.tracks
            taken = _take(out[a], fix)
            if not taken:
                raise DataFormatError(path, fix.where, f"selects no detection of {a}")
            clash = [(f, c) for f, c, _ in taken if c in out[b].get(f, {})]
            if clash:
                raise DataFormatError(path, fix.where, f"{b} already holds camera {clash[0][1]} at frame "
                                                       f"{clash[0][0]} (exchange them instead)")
            _put(out[b], taken)
            moved += len(taken)
            changed.update(fix.tracks)
        elif fix.kind == "split":
            (a,) = fix.tracks
            new_id = fix.new_id or _next_id(out)
            if new_id in out:
                raise DataFormatError(path, fix.where, f"new_id {new_id} is a track already")
            later = {f: cams for f, cams in out[a].items() if f >= fix.first_frame}
            if not later or len(later) == len(out[a]):
                raise DataFormatError(path, fix.where, f"frame {fix.first_frame} does not split {a} "
                                                       f"(frames {min(out[a])}-{max(out[a])})")
            out[new_id] = later
            out[a] = {f: cams for f, cams in out[a].items() if f < fix.first_frame}
            changed.update((a, new_id))
        elif fix.kind == "merge":
            into = out[fix.tracks[0]]
            for other in fix.tracks[1:]:
                for frame, cams in out[other].items():
                    clash = [c for c in cams if c in into.get(frame, {})]
                    if clash:
                        raise DataFormatError(path, fix.where, f"{fix.tracks[0]} and {other} both hold camera "
                                                               f"{clash[0]} at frame {frame}")
                    into.setdefault(frame, {}).update(cams)
                    moved += len(cams)
                del out[other]
            changed.update(fix.tracks)
        elif fix.kind == "add":
            (a,) = fix.tracks
            given = []
            for frame in range(fix.first_frame, fix.last_frame + 1):
                for cam in fix.cameras:
                    there = loose.get((cam, frame), [])
                    if fix.detection is not None:
                        there = [d for d in there if source_index(d) == fix.detection]
                    if len(there) != 1:
                        named = f" with index {fix.detection}" if fix.detection is not None else ""
                        hint = " (name one with `detection`)" if there else ""
                        raise DataFormatError(path, fix.where, f"{len(there)} untracked detections{named} of camera "
                                                               f"{cam} at frame {frame}{hint}")
                    if cam in out[a].get(frame, {}):
                        raise DataFormatError(path, fix.where, f"{a} already holds camera {cam} at frame {frame} "
                                                               "(remove or exchange it first)")
                    given.append((frame, cam, there[0]))
            for frame, cam, det in given:
                loose[(cam, frame)] = [d for d in loose[(cam, frame)] if d is not det]
            _put(out[a], given)
            added += len(given)
            changed.add(a)
        else:                                             # remove
            (a,) = fix.tracks
            taken = _take(out[a], fix)
            if not taken:
                raise DataFormatError(path, fix.where, f"selects no detection of {a}")
            for frame, cam, det in taken:
                loose.setdefault((cam, frame), []).append(det)
            removed += len(taken)
            changed.add(a)
        for tid in list(out):
            if not out[tid]:
                del out[tid]
    out = {tid: {frame: {cam: dataclasses.replace(det, track_id=tid) for cam, det in sorted(cams.items())}
                 for frame, cams in sorted(frames.items())} for tid, frames in sorted(out.items())}
    return out, {"operations": len(fixes), "detections_moved": moved, "detections_added": added,
                 "detections_removed": removed, "tracks_changed": sorted(changed)}


def fix_tracks(tracks: list, fixes: list[IdentityFix], path: str | Path, calibrations: Mapping, config=None,
               ground=None, clouds: Mapping | None = None, made_for: str | None = None,
               where: str = "", untracked: Iterable[Detection] = ()) -> tuple[list, dict]:
    """``tracks`` (:class:`~pedx_graph.detections.association.DetectedTrack`) after ``fixes``
    (:func:`apply_fixes`), the changed ones placed again (module docstring), sorted by id; and the record of
    :func:`apply_fixes`.  ``config``: the association's (:class:`AssociationConfig`), ``ground`` and
    ``clouds`` as :func:`~pedx_graph.detections.association.tracks_from_ids` takes them.  ``made_for``: the
    :func:`tracks_digest` the fixes were written for (``where``: its field in the file), an error when
    ``tracks`` have another; ``untracked``: the detections no track holds (``add``)."""
    from pedx_graph.detections.association import tracks_from_ids

    if made_for is not None and made_for != tracks_digest(tracks):
        raise DataFormatError(path, where or "made_for", f"the fixes were made for tracks {made_for}, this "
                                                         f"import's are {tracks_digest(tracks)} (another version, "
                                                         "config or detections: check the ids again)")
    groups = {track.track_id: {fr.frame: dict(fr.detections) for fr in track.frames} for track in tracks}
    cameras = {cam for name in calibrations for cam in str(name).split("-")}
    groups, record = apply_fixes(groups, fixes, path, cameras, untracked)
    if not record["tracks_changed"]:
        return sorted(tracks, key=lambda t: t.track_id), record
    placed = {t.track_id: t for t in tracks_from_ids(groups, calibrations, config, ground, clouds=clouds)}
    kept = {t.track_id: t for t in tracks}
    changed = set(record["tracks_changed"])
    return [placed[tid] if tid in changed else kept[tid] for tid in sorted(groups)], record


def mark_checked(review: dict, fixes: Iterable[IdentityFix], tracks: list | None = None) -> int:
    """Marks the stretches of ``review`` (:func:`pedx_graph.detections.review.review_summary`'s record) a
    ``checked`` operation of ``fixes`` covers — every track the stretch names among the operation's, its
    frames within the operation's — with ``"checked": true`` and drops them from ``check_order``; returns how
    many.  The record gains ``checked_stretches`` and, given the ``tracks`` it was made on,
    ``unchecked_flagged_track_frames`` (the track frames the stretches still to check flag)."""
    from pedx_graph.detections.review import flagged_frames

    checks = [fix for fix in fixes if fix.kind == "checked"]
    marked = 0
    for stretch in review["stretches"]:
        if any(set(stretch["tracks"]) <= set(fix.tracks)
               and (fix.first_frame is None or stretch["first_frame"] >= fix.first_frame)
               and (fix.last_frame is None or stretch["last_frame"] <= fix.last_frame) for fix in checks):
            stretch["checked"] = True
            marked += 1
    review["check_order"] = [i for i in review["check_order"] if not review["stretches"][i].get("checked")]
    review["checked_stretches"] = marked
    if tracks is not None:
        still = [stretch for stretch in review["stretches"] if not stretch.get("checked")]
        review["unchecked_flagged_track_frames"] = sum(len(v) for v in flagged_frames(tracks, still).values())
    return marked


def fixes_template(sequences: Mapping[str, dict]) -> str:
    """The text of ``identity_fixes_template.yaml`` (module docstring): ``sequences`` maps each sequence to its
    import summary record (``tracks_digest``, ``identity_review`` and ``review_sheets``, as
    :func:`pedx_graph.detections.importer.import_detections` records them); a stretch beside detections no
    track holds lists them as an ``add`` names them (camera, frame, index in the file).  Valid YAML as it is
    (every operation commented out) and a valid fixes file once operations are uncommented."""
    lines = ["# Identity fixes for `pedx-graph import ... --identity-fixes FILE` (docs/detections.md, \"Fixing who",
             "# is who\").  Per sequence, the stretches still to check, in the order to check them, each as a",
             "# commented `checked` operation: uncomment it where the tracks are right there, or write the fix it",
             "# needs (exchange, move, split, merge, remove) under `operations:`.  Ids are those of this import's",
             "# output: if it applied a fixes file already, add these after that file's operations (they apply in",
             "# order).  `made_for` is the digest of the association's tracks before any fix: a later import",
             "# refuses the fixes if its tracks differ."]
    for seq, record in sorted(sequences.items()):
        review = record.get("identity_review") or {"stretches": [], "check_order": []}
        sheets = {(tuple(s["tracks"]), s["first_frame"], s["last_frame"]): s["sheet"]
                  for s in (record.get("review_sheets") or {}).get("sheets", []) if s.get("sheet")}
        folder = (record.get("review_sheets") or {}).get("folder")
        lines += [f"'{seq}':", f"  made_for: '{record['tracks_digest']}'", "  operations:"]
        for n, i in enumerate(review["check_order"], start=1):
            stretch = review["stretches"][i]
            names = list(stretch["tracks"])
            held, missed = stretch["frames_held"], stretch["frames_missed"]
            sheet = sheets.get((tuple(names), stretch["first_frame"], stretch["last_frame"]))
            who = " and ".join(names) if len(names) > 1 else f"{names[0]} beside untracked detections"
            lines += [f"    # {n}. {who}, frames {stretch['first_frame']}-{stretch['last_frame']} ({missed} of "
                      f"{held + missed} of their frames missed)" + (f"; sheet {folder}/{sheet}" if sheet else "")]
            loose = [(u["camera"], u["frame"], _SOURCE_INDEX.search(str(u["source"])))
                     for u in stretch.get("untracked", [])]
            if loose:                                  # what an `add` names: camera, frame, index in the file
                lines.append("    #    untracked: " + ", ".join(
                    f"{cam} frame {frame}" + (f" detection {m.group(1)}" if m else "") for cam, frame, m in loose))
            lines += [f"    # - checked: [{', '.join(names)}]",
                      f"    #   frames: [{stretch['first_frame']}, {stretch['last_frame']}]"]
    return "\n".join(lines) + "\n"


def source_index(det: Detection) -> int | None:
    """The index of ``det`` in its file (OpenPose ``#people[i]``, COCO ``#[n]``), or None (a joined detection)."""
    match = _SOURCE_INDEX.search(str(det.source))
    return int(match.group(1)) if match else None


def _take(frames: dict[int, dict[str, Detection]], fix: IdentityFix) -> list[tuple[int, str, Detection]]:
    """Removes and returns the detections of one track ``fix`` selects."""
    taken = [(frame, cam, det) for frame, cams in sorted(frames.items()) for cam, det in sorted(cams.items())
             if fix.selects(frame, cam)]
    for frame, cam, _ in taken:
        del frames[frame][cam]
        if not frames[frame]:
            del frames[frame]
    return taken


def _put(frames: dict[int, dict[str, Detection]], taken: list[tuple[int, str, Detection]]) -> None:
    for frame, cam, det in taken:
        frames.setdefault(frame, {})[cam] = det


_ID = re.compile(r"^det(\d+)$")


def _next_id(groups: Mapping[str, object]) -> str:
    """The next free ``detNNNNNN`` after every id of that form."""
    numbers = [int(m.group(1)) for tid in groups if (m := _ID.match(tid))]
    return f"det{max(numbers, default=0) + 1:06d}"


def _id_range(groups: Mapping[str, object]) -> str:
    ids = sorted(groups)
    if not ids:
        return "the import has no tracks"
    return f"this import's tracks: {ids[0]}" + (f" ... {ids[-1]}, {len(ids)} in all" if len(ids) > 1 else "")
