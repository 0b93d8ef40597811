"""Benchmark: the id-less association alone (tracks, identity switches, mixed frames) over many seeded scenes.

Method: for every seed, the detection benchmark's two scenes (:func:`bench_detections.scene_configs`:
``crossing`` on seed ``s`` and ``mixed`` on seed ``s + 1``, as ``bench_detections.py --seed s`` simulates them;
CMU hold-out motion when ../shared holds it, the procedural gait otherwise) are simulated with detector output
(OpenPose BODY_25 / BODY_25B and COCO files on distorted raw images, no ids, bystanders, clutter and
fragments); each format's files go through :func:`pedx_graph.detections.association.associate` with the
scene's LiDAR clouds, as ``pedx-graph import`` runs it, and the tracks are scored against the simulator's
``truth/detections`` (:func:`pedx_graph.detections.evaluate.score_tracks`).  No fitting: this is the
benchmark for changes to the association, which the fit benchmark (``bench_detections.py``, three seeds)
samples too thinly.  ``--pedestrians 20 --frames 80`` gives the long dense scenes.

Reported per input (seed, scene, format) and summed: tracks, false tracks, bystander tracks, labelled people
recovered, identity switches (all, and those of people crossing at 5-25 m:
:func:`bench_detections.crossing_people`), wrong frames, frames mixing two people, fragmentations, and
people's detections on their own person's track and on another's (or a false one); the placement of the track
frames' centres (:func:`pedx_graph.detections.evaluate.placement_counts`: frames with a centre, those farther
than ``PLACE_OFF_M`` from the true centre of the person most of their detections belong to, and of those the
ones claiming to be placed more than ``PLACE_SIGMAS`` times better than they are — what the LiDAR cut's depth
gate and the fit's start rely on, and what a switch count does not see); the identity switches by where
their two people stood at the switch (:func:`pedx_graph.detections.evaluate.switch_geometry`: one behind the
other as seen from the rig, paths crossing, beside each other); and the import's identity
review (:mod:`pedx_graph.detections.review`): its stretches, the share of track frames they flag and how many
of the identity switches lie inside them.  With
``--baseline OLD.json`` (an earlier run of this script with the same seeds and sizes) the markdown also lists
the inputs whose counts changed.

    python benchmarks/bench_association.py [--seeds 0-8,17-21] [--pedestrians 10] [--frames 20]
                                           [--rig default|pedx] [--workers 2] [--baseline OLD.json]
                                           [--config FILE] [--range-oracle given|all]
                                           [--fps HZ] [--frame-interval S]
                                           [--name bench_association] [--out benchmarks/results]

``--config FILE`` associates with that import config's ``association`` section (a YAML file as ``pedx-graph
import --config`` reads it, e.g. ``configs/import_backward_births.yaml``) instead of the defaults; the results
name the fields it changes.

``--range-oracle given|all`` is a diagnostic: the association is told its people's true LiDAR ranges
(:func:`truth_ranges`), to measure what better LiDAR evidence could buy it.

``--fps HZ`` simulates the scenes at another frame rate; with ``--frame-interval`` the matching
``association.tracker.frame_interval_s`` (or not), it measures what a frame rate assumed wrongly costs the
association, and every row carries the import's check of the interval against the walking tracks
(:func:`pedx_graph.detections.frame_interval.walking_check`, ``walk_*``).

``--rig pedx`` simulates the scenes on the real PedX rig's preset (its cameras, the z-down LiDAR frame, the
ground's tilt; :data:`bench_detections.RIGS`), nothing of which the association is told.

Writes ``<name>.json`` and ``<name>.md`` into ``--out``.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import hardware, parse_seeds, public_args, rows_per_seed, write_outputs  # noqa: E402
from bench_detections import (FORMATS, RIGS, SHARED_CMU, _truth_frames, crossing_people,  # noqa: E402
                              labelled_instances, read_format, scene_clouds, scene_configs)
from pedx_graph.data.calib import read_calibrations  # noqa: E402
from pedx_graph.data.ground import ground_from_calibrations  # noqa: E402
from pedx_graph.data.reader import read_dataset  # noqa: E402
from pedx_graph.config import ConfigError, load_config, to_dict  # noqa: E402
import pedx_graph.detections.association as association  # noqa: E402
from pedx_graph.detections.association import AssociationConfig, associate  # noqa: E402
from pedx_graph.detections.importer import ImportConfig  # noqa: E402
from pedx_graph.detections.frame_interval import walking_check  # noqa: E402
from pedx_graph.detections.evaluate import (IN_LINE_LATERAL_M, PATHS_CROSS_DEG, PLACE_OFF_M,  # noqa: E402
                                            PLACE_SIGMAS, SWITCH_KINDS, detection_records, placement_counts,
                                            read_detection_truth, score_tracks, switch_geometry)
from pedx_graph.detections.lidar_cut import project_cloud  # noqa: E402
from pedx_graph.detections.review import review_summary, untracked_detections  # noqa: E402
from pedx_graph.keypoints import load_keypoint_set  # noqa: E402
from pedx_graph.sim.config import SimConfig  # noqa: E402
from pedx_graph.sim.simulate import read_truth_frame, simulate  # noqa: E402

#: Counts summed over the inputs, in the tables' order.
COUNTS = ("tracks", "false_tracks", "bystander_tracks", "recovered", "labelled_people", "id_switches",
          "crossing_id_switches", "wrong_frames", "mixed_frames", "fragmentations", "own_detections",
          "others_detections")
#: Placement of the track frames' centres (:func:`pedx_graph.detections.evaluate.placement_counts`), summed and
#: compared like :data:`COUNTS`.
PLACEMENT_COUNTS = ("placed_frames", "misplaced_centres", "overconfident_centres")
#: The identity review's counts (:func:`review_counts`), summed like :data:`COUNTS`, not compared to a baseline.
REVIEW_COUNTS = ("review_stretches", "review_flagged_frames", "track_frames", "switches_in_review",
                 "switches_first_quarter", "switches_first_half", "switches_first_quarter_shortest",
                 "switches_first_half_shortest")
#: The identity switches by where their two people stood (:func:`~pedx_graph.detections.evaluate.switch_geometry`),
#: summed like :data:`COUNTS`, not compared to a baseline.
GEOMETRY_COUNTS = SWITCH_KINDS


#: ``--range-oracle`` modes (:func:`truth_ranges`).
RANGE_ORACLES = ("given", "all")
#: Counts of :func:`truth_ranges`, per input and summed.
ORACLE_COUNTS = ("oracle_ranges_given", "oracle_ranges_replaced", "oracle_ranges_removed", "oracle_ranges_added")
#: A range farther than this from its person's counts as replaced (another person's or the background's), metres.
ORACLE_OFF_M = 0.5


@contextlib.contextmanager
def truth_ranges(scene: Path, sequence: str, records: list[dict], mode: str, counts: dict):
    """Within the block, the association's LiDAR range of a detection
    (:func:`pedx_graph.detections.association.detection_ranges`) is its person's as a perfect cut of the LiDAR
    would give it: the median depth, along the pair's rectified optical axis, of the scan points that the
    simulator's truth says hit that person and that the association keeps (``lidar_cut.ground_clearance_m``
    above the ground); none where fewer than ``lidar_identity_min_points`` did (the LiDAR did not see them).
    ``mode`` ``given``: only the detections the association gave a range are told the truth (a range on the
    wrong cluster is corrected, one of a person the LiDAR missed removed); ``all``: every detection of a person
    the LiDAR saw gets its range.  Clutter and fragments keep what the association gave them.  A diagnostic:
    what better LiDAR evidence could buy the association, not a way to run it.  ``counts`` gathers, over the
    block, the ranges the association gave the detections of one person, those replaced (more than
    :data:`ORACLE_OFF_M` off), removed and added."""
    original = association.detection_ranges
    index = {(r["camera"], r["frame"], r["index"]): r for r in records}
    frames: dict[int, dict] = {}
    known: dict[tuple, float | None] = {}

    def person_range(tid: str, frame: int, calib, side: str, ground, config) -> float | None:
        key = (tid, frame, id(calib), side)
        if key in known:
            return known[key]
        if frame not in frames:
            frames[frame] = read_truth_frame(scene, frame, sequence)
        truth = frames[frame]
        person = truth["people"].get(tid)
        points = (np.asarray(truth["scene_points"], dtype=float)[truth["scene_object_id"] == person["object_id"]]
                  if person is not None else np.zeros((0, 3)))
        if ground.ground_offset_m is not None and len(points):
            points = points[ground.height(points) >= config.lidar_cut.ground_clearance_m]
        known[key] = (float(np.median(project_cloud(calib, side, points)[1]))
                      if len(points) >= config.lidar_identity_min_points else None)
        return known[key]

    def told(items, calib, side, cloud, ground, config, past=None):
        found = original(items, calib, side, cloud, ground, config, past)
        out = {}
        for det, _ in items:
            key = id(det)
            people = {r["tracking_id"] for r in detection_records(det, records, index)
                      if r["kind"] in ("person", "part")}
            if len(people) != 1:
                if key in found:
                    out[key] = found[key]
                continue
            if key not in found and mode == "given":
                continue
            truth = person_range(people.pop(), det.frame, calib, side, ground, config)
            counts["oracle_ranges_given"] += key in found
            if truth is None:
                counts["oracle_ranges_removed"] += key in found
                continue
            if key not in found:
                counts["oracle_ranges_added"] += 1
            elif abs(found[key] - truth) > ORACLE_OFF_M:
                counts["oracle_ranges_replaced"] += 1
            out[key] = truth
            if past is not None:
                past.discard(key)                   # a person's own points end at its silhouette
        return out

    association.detection_ranges = told
    try:
        yield
    finally:
        association.detection_ranges = original


@dataclass
class SimulatedScene:
    """One simulated scene of a seed and what scoring its inputs needs (:func:`simulated_scenes`)."""

    name: str
    """``crossing`` or ``mixed``."""
    root: Path
    """The scene's folder (temporary)."""
    sequence: str
    """Its sequence name."""
    config: SimConfig
    """Its simulator config."""
    labelled: dict
    """Tracking id -> {frame: horizontal distance} of the labelled people (:func:`labelled_instances`)."""
    crossing: set
    """The people crossing at 5-25 m (:func:`bench_detections.crossing_people`)."""
    calibs: dict
    """Stereo pairs by name."""
    clouds: dict
    """Frame -> the scene's LiDAR cloud."""
    ground: object
    """The sequence's ground frame."""
    centres: dict
    """``(tracking id, frame) -> (3,)`` true centres (:func:`true_centres`)."""


def simulated_scenes(seed: int, pedestrians: int, frames: int, rig: str, folder: str | Path,
                     fps: float | None = None):
    """The seed's two scenes (module docstring), simulated into ``folder`` one after the other, as
    :class:`SimulatedScene` s; ``fps``: their frame rate (None: the simulator's, 10 Hz)."""
    for s, (name, cfg) in enumerate(scene_configs(pedestrians, frames, rig=rig).items()):
        if fps is not None:
            cfg.scene.fps = float(fps)
        scene = Path(folder) / name
        simulate(scene, cfg, seed=seed + s, workers=1)
        seq = cfg.scene.sequence
        labelled = labelled_instances(scene, seq)
        crossing, _ = crossing_people(read_dataset(scene), labelled)
        calibs = read_calibrations(scene / "calib")
        yield SimulatedScene(name, scene, seq, cfg, labelled, crossing, calibs, scene_clouds(scene, seq),
                             ground_from_calibrations(calibs, seq),
                             true_centres(scene, [cfg.scene.first_frame + k for k in range(cfg.scene.n_frames)]))


def run_seed(seed: int, pedestrians: int, frames: int, rig: str = "default",
             config: AssociationConfig | None = None, range_oracle: str | None = None,
             fps: float | None = None) -> list[dict]:
    """The scored inputs of one seed: one row per scene and format (module docstring); ``config``: the
    association's (None: its defaults); ``range_oracle``: a mode of :func:`truth_ranges` (None: the
    association's own LiDAR ranges); ``fps``: the scenes' frame rate (None: the simulator's)."""
    rows = []
    interval_s = (config or AssociationConfig()).frame_interval_s
    with tempfile.TemporaryDirectory(prefix="bench_association_") as tmp:
        for sc in simulated_scenes(seed, pedestrians, frames, rig, tmp, fps):
            name, scene, seq, cfg = sc.name, sc.root, sc.sequence, sc.config
            labelled, crossing, calibs, clouds, ground, centres = (sc.labelled, sc.crossing, sc.calibs, sc.clouds,
                                                                   sc.ground, sc.centres)
            for fmt in FORMATS:
                detections = read_format(scene, fmt, seq)
                records = read_detection_truth(scene, seq, fmt)
                oracle = dict.fromkeys(ORACLE_COUNTS, 0)
                with (truth_ranges(scene, seq, records, range_oracle, oracle) if range_oracle
                      else contextlib.nullcontext()):
                    t0 = time.perf_counter()
                    tracks = associate(detections, calibs, config, clouds=clouds, ground=ground)
                    seconds = time.perf_counter() - t0
                score = score_tracks(tracks, records, labelled)
                score["crossing_id_switches"] = sum(1 for _, _, a, b in score["switches"]
                                                    if a in crossing or b in crossing)
                rows.append({"seed": seed, "scene": name, "format": fmt, "detections": len(detections),
                             "associate_seconds": seconds, **{k: score[k] for k in COUNTS},
                             **(oracle if range_oracle else {}),
                             **placement_counts(tracks, records, centres, ground),
                             **switch_geometry(score["switches"], centres, ground, 1.0 / cfg.scene.fps),
                             **review_counts(tracks, ground, score["switches"],
                                                untracked_detections(detections, tracks)),
                             **{f"walk_{k}": v for k, v in walking_check(tracks, ground, interval_s).items()}})
    return rows


def true_centres(scene: Path, frames: list[int]) -> dict[tuple[str, int], np.ndarray]:
    """``(tracking id, frame) -> (3,)`` world point midway between the person's true hips, for every simulated
    person (bystanders too) at each of ``frames`` (:func:`bench_detections._truth_frames`)."""
    names = load_keypoint_set("pedx18").keypoints
    hips = [names.index("lhip"), names.index("rhip")]
    return {(tid, frame): keypoints[hips].mean(axis=0)
            for frame, people in _truth_frames(scene, frames).items() for tid, keypoints, _ in people}


def review_counts(tracks: list, ground, switches: list[tuple], untracked: list | None = None) -> dict:
    """The import's identity review (:func:`pedx_graph.detections.review.review_stretches`, default config,
    with ``untracked``, the detections no track holds, as the import passes them) against the truth: its
    stretches, the track frames they flag of all, and the identity switches (``(track, frame, from, to)`` of
    :func:`score_tracks`) whose frame lies in a stretch naming their track."""
    review = review_summary(tracks, ground, untracked=untracked)
    stretches = review["stretches"]
    inside = sum(1 for tid, frame, _, _ in switches if any(
        tid in s["tracks"] and s["first_frame"] <= frame <= s["last_frame"] for s in stretches))

    def caught(order: list[int], share: float) -> int:
        """Switches inside the stretches begun before ``share`` of the stretches' held frames, in ``order``."""
        total = sum(s["frames_held"] for s in stretches)
        looked, taken = 0, []
        for i in order:
            if looked >= share * total:
                break
            taken.append(stretches[i])
            looked += stretches[i]["frames_held"]
        return sum(1 for tid, frame, _, _ in switches if any(
            tid in s["tracks"] and s["first_frame"] <= frame <= s["last_frame"] for s in taken))

    shortest = sorted(range(len(stretches)), key=lambda i: (stretches[i]["frames_held"], i))
    return {"review_stretches": len(stretches), "review_flagged_frames": review["flagged_track_frames"],
            "track_frames": review["track_frames"], "switches_in_review": inside,
            "switches_first_quarter": caught(review["check_order"], 0.25),
            "switches_first_half": caught(review["check_order"], 0.5),
            "switches_first_quarter_shortest": caught(shortest, 0.25),
            "switches_first_half_shortest": caught(shortest, 0.5)}


def changed_fields(config: AssociationConfig) -> dict:
    """The fields of an association config that differ from the defaults, as dotted names -> values."""
    def flat(value, prefix=""):
        if isinstance(value, dict):
            return {k: v for key, item in value.items() for k, v in flat(item, f"{prefix}{key}.").items()}
        return {prefix[:-1]: value}
    mine, defaults = flat(to_dict(config)), flat(to_dict(AssociationConfig()))
    return {k: v for k, v in mine.items() if defaults.get(k) != v}


def changed_inputs(rows: list[dict], baseline: list[dict]) -> list[tuple[dict, dict]]:
    """(before, now) of the inputs whose counts (:data:`COUNTS`, :data:`PLACEMENT_COUNTS`) differ from the
    baseline's row of the same seed, scene and format (the counts both runs have: a baseline from before a
    count was added is compared on the rest)."""
    before = {(r["seed"], r["scene"], r["format"]): r for r in baseline}
    out = []
    for row in rows:
        old = before.get((row["seed"], row["scene"], row["format"]))
        if old is not None and any(k in old and old[k] != row[k] for k in COUNTS + PLACEMENT_COUNTS):
            out.append((old, row))
    return out


def markdown(result: dict) -> str:
    header = ("| seed | scene | format | tracks | false | bystander | recovered / labelled | id switches (crossing) "
              "| wrong frames | mixed frames | fragmentations | own / others' detections "
              f"| centres off > {PLACE_OFF_M:g} m (overconfident) / placed |")
    rule = "|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"

    def line(r: dict, label: str | None = None) -> str:
        key = label or f"{r['seed']} | {r['scene']} | {r['format']}"
        placement = (f"{r['misplaced_centres']} ({r['overconfident_centres']}) / {r['placed_frames']}"
                     if "placed_frames" in r else "-")
        return (f"| {key} | {r['tracks']} | {r['false_tracks']} | {r['bystander_tracks']} | "
                f"{r['recovered']} / {r['labelled_people']} | {r['id_switches']} ({r['crossing_id_switches']}) | "
                f"{r['wrong_frames']} | {r['mixed_frames']} | {r['fragmentations']} | "
                f"{r.get('own_detections', '-')} / {r.get('others_detections', '-')} | {placement} |")

    total, seeds = result["totals"], len(result["seeds"])
    lines = ["# bench_association: the id-less association over many scenes", "",
             f"Command: `{result['command']}`", "",
             f"Seeds {result['seeds_text']} ({seeds} seed{'s' * (seeds != 1)} x 2 scenes x {len(FORMATS)} formats = "
             f"{len(result['rows'])} inputs), {result['pedestrians']} pedestrians x {result['frames']} frames per "
             f"scene, {result['motion']}, {result.get('rig', 'default')} rig.  Method: see the script's docstring "
             "(the detection benchmark's scenes, `associate` as the import runs it, scored against the simulator's "
             f"truth; no fitting).  The last column: track frames whose centre lies more than {PLACE_OFF_M:g} m "
             "from the true centre (mid-hips, on the ground plane) of the person most of their detections belong "
             f"to, in brackets those whose error is also more than {PLACE_SIGMAS:g} times the depth sigma they "
             "claim, of all track frames with a centre.", "",
             "## Totals", "", header, rule, line(total, "all | | "), ""]
    if result.get("range_oracle"):
        lines += ["## LiDAR ranges from the truth", "",
                  f"A diagnostic run (`--range-oracle {result['range_oracle']}`, `truth_ranges` in the script): the "
                  "association's LiDAR range of a detection is its person's as a perfect cut of the scan would give "
                  "it (the median depth of the points the simulator says hit that person), "
                  + ("only where the association found a range" if result["range_oracle"] == "given" else
                     "for every detection of a person the LiDAR saw")
                  + f".  Ranges the association found on a detection of one person: "
                  f"{total['oracle_ranges_given']}; of those more than "
                  f"{ORACLE_OFF_M:g} m off their person's and replaced: {total['oracle_ranges_replaced']}; of a "
                  f"person the LiDAR did not see, removed: {total['oracle_ranges_removed']}; added: "
                  f"{total['oracle_ranges_added']}.", ""]
    if "switches_in_line" in total:
        lines += ["## Where the switches happen", "",
                  f"Identity switches by where their two people stood at the switch frame (true centres, seen "
                  f"from the rig; `pedx_graph.detections.evaluate.switch_geometry`): one behind the other (the "
                  f"farther within {IN_LINE_LATERAL_M:g} m of the nearer one's viewing ray) "
                  f"{total['switches_in_line']}, paths crossing (walking directions more than "
                  f"{PATHS_CROSS_DEG:g} degrees apart) {total['switches_paths_crossing']}, beside each other "
                  f"{total['switches_beside']}, a person without a true centre there "
                  f"{total['switches_unplaced']}; of {total['id_switches']}.", ""]
    if "switches_in_review" in total:
        lines += ["## Identity review", "",
                  f"The import lists where two tracks came close (`import_summary.json`, "
                  f"`identity_review`; pedx_graph.detections.review, default config): {total['review_stretches']} "
                  f"stretches over the inputs, flagging {total['review_flagged_frames']} of "
                  f"{total['track_frames']} track frames "
                  f"({total['review_flagged_frames'] / max(total['track_frames'], 1):.0%}).  Identity switches "
                  f"whose frame lies in a stretch naming their track: {total['switches_in_review']} of "
                  f"{total['id_switches']}."
                  + (f"  Checked in the import's order (`check_order`: the stretches whose tracks missed the "
                     f"largest share of their frames first), the stretches begun within the first quarter of an "
                     f"input's flagged frames hold {total['switches_first_quarter']} of those, within the first "
                     f"half {total['switches_first_half']} (shortest stretches first: "
                     f"{total['switches_first_quarter_shortest']} and {total['switches_first_half_shortest']})."
                     if "switches_first_quarter" in total else ""),
                  ""]
    walks = [r for r in result["rows"] if r.get("walk_ratio") is not None]
    if walks:
        flagged = sum(not r["walk_agrees"] for r in walks)
        ratios = [r["walk_ratio"] for r in walks]
        lines += ["## Frame interval check", "",
                  f"Scenes at {result['scene_fps']:g} Hz, associated with frames {result['frame_interval_s']:g} s "
                  f"apart.  The import's check of that interval against the walking tracks "
                  f"(`pedx_graph.detections.frame_interval.walking_check`): {len(walks)} of {len(result['rows'])} "
                  f"inputs had enough walking tracks; the interval their walks imply over the one used: "
                  f"{min(ratios):.2f}-{max(ratios):.2f} (median {float(np.median(ratios)):.2f}); flagged: "
                  f"{flagged}.", ""]
    if result.get("changed") is not None:
        lines += [f"## Changed against the baseline ({result['baseline_command']})", ""]
        if result["changed"]:
            lines += ["Each changed input: the baseline's row, then this run's.", "", header, rule]
            for old, new in result["changed"]:
                lines += [line(old, f"{old['seed']} | {old['scene']} | {old['format']} (before)"), line(new)]
        else:
            lines.append("No input's counts changed.")
        lines.append("")
    lines += ["## Per input", "", header, rule] + [line(r) for r in result["rows"]]
    lines += ["", f"Association time over all inputs: {result['associate_seconds']:.1f} s "
              f"(wall time {result['total_seconds']:.0f} s with {result['workers']} worker processes).", "",
              f"Hardware: {result['hardware']}", ""]
    return "\n".join(lines)


def parsed_seeds(parser: argparse.ArgumentParser, argv: list[str]) -> tuple[argparse.Namespace, list[int]]:
    """``parser``'s arguments of ``argv`` and the seeds they name (a usage error when they name none)."""
    args = parser.parse_args(argv)
    try:
        return args, parse_seeds(args.seeds)
    except ValueError as exc:
        parser.error(str(exc))


def add_scene_arguments(parser: argparse.ArgumentParser) -> None:
    """The options naming this benchmark's scenes (seeds, sizes, rig) and its worker count, which
    ``bench_identity_fixes.py`` shares (:func:`parsed_seeds` reads them)."""
    parser.add_argument("--seeds", default="0-8,17-21", help="seeds and inclusive ranges, comma-separated")
    parser.add_argument("--pedestrians", type=int, default=10)
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--rig", default="default", choices=RIGS,
                        help="the simulated rig (pedx: the real PedX rig's preset)")
    parser.add_argument("--workers", type=int, default=2, help="processes, one seed each")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_scene_arguments(parser)
    parser.add_argument("--baseline", help="an earlier run's JSON to list the changed inputs against")
    parser.add_argument("--config", help="an import config YAML whose association section is used")
    parser.add_argument("--fps", type=float, default=None,
                        help="simulate the scenes at this frame rate (default: the simulator's, 10 Hz); the "
                             "association steps frames by --frame-interval all the same")
    parser.add_argument("--frame-interval", type=float, default=None, metavar="S",
                        help="the association's tracker.frame_interval_s (default: its config's, 0.1 s)")
    parser.add_argument("--range-oracle", choices=RANGE_ORACLES,
                        help="tell the association its people's true LiDAR ranges (a diagnostic: truth_ranges)")
    parser.add_argument("--name", default="bench_association", help="file name of the outputs, without suffix")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args, seeds = parsed_seeds(parser, argv)
    baseline = None
    if args.baseline:
        try:
            baseline = json.loads(Path(args.baseline).read_text())
        except (OSError, ValueError) as exc:
            parser.error(f"--baseline {args.baseline}: {exc}")
        if (baseline.get("pedestrians"), baseline.get("frames")) != (args.pedestrians, args.frames):
            parser.error(f"--baseline {args.baseline}: its scenes are {baseline.get('pedestrians')} pedestrians x "
                         f"{baseline.get('frames')} frames, this run's {args.pedestrians} x {args.frames}")
        if baseline.get("rig", "default") != args.rig:
            parser.error(f"--baseline {args.baseline}: its scenes are on the {baseline.get('rig', 'default')} rig, "
                         f"this run's on the {args.rig} rig")
    try:
        config = load_config(ImportConfig, args.config).association
    except ConfigError as exc:
        parser.error(str(exc))
    if args.frame_interval is not None:
        if not args.frame_interval > 0:
            parser.error(f"--frame-interval must be positive, got {args.frame_interval}")
        config = config.with_frame_interval(args.frame_interval)
    t0 = time.perf_counter()
    rows = rows_per_seed(run_seed, seeds, args.workers, args.pedestrians, args.frames, args.rig, config,
                         args.range_oracle, args.fps)
    shown = public_args(argv)                 # the baseline by its file name: no machine paths in the results
    shown = [Path(a).name if k and shown[k - 1] == "--baseline" else
             f"--baseline={Path(a.split('=', 1)[1]).name}" if a.startswith("--baseline=") else a
             for k, a in enumerate(shown)]
    result = {"command": " ".join(["python benchmarks/bench_association.py"] + shown),
              "seeds_text": args.seeds, "seeds": seeds, "pedestrians": args.pedestrians, "frames": args.frames,
              "rig": args.rig, "workers": args.workers, "association_changes": changed_fields(config),
              "range_oracle": args.range_oracle, "scene_fps": args.fps or SimConfig().scene.fps,
              "frame_interval_s": config.frame_interval_s,
              "motion": "CMU hold-out clips" if SHARED_CMU.is_dir() else "procedural gait",
              "rows": rows, "totals": {k: sum(r[k] for r in rows) for k in COUNTS + PLACEMENT_COUNTS + REVIEW_COUNTS
                                       + GEOMETRY_COUNTS + (ORACLE_COUNTS if args.range_oracle else ())},
              "associate_seconds": sum(r["associate_seconds"] for r in rows),
              "total_seconds": time.perf_counter() - t0, "hardware": hardware()}
    if baseline is not None:
        result["baseline_command"] = baseline.get("command", args.baseline)
        result["changed"] = changed_inputs(rows, baseline.get("rows", []))
    write_outputs(args.out, args.name, result, markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
