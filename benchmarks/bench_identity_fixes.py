"""Benchmark: what a reviewer's identity fixes cost and leave, checking only the stretches the import flags.

Method: the association benchmark's scenes and inputs (``bench_association.py``: for every seed the detection
benchmark's ``crossing`` and ``mixed`` scenes, OpenPose BODY_25 / BODY_25B and COCO files, no ids), each
associated as ``pedx-graph import`` associates it, with its identity review (:mod:`pedx_graph.detections.review`,
the detections no track holds passed as the import passes them).  A reviewer who sees who is who in the
images then writes the fixes :func:`pedx_graph.detections.evaluate.truth_fixes` writes from the simulator's
truth: every person's detection on another person's track moved to its own person's track (exchanged, or
removed when its person has none) — once looking only inside the review's stretches (what checking the
flagged frames finds), once everywhere (what checking every frame would find).  The fixes go through
:func:`pedx_graph.detections.fixes.fix_tracks` (the tracks they change placed again), as ``pedx-graph import
--identity-fixes`` applies them, and the tracks are scored again (:func:`~pedx_graph.detections.evaluate.score_tracks`,
:func:`~pedx_graph.detections.evaluate.placement_counts`).

Reported per input and summed: identity switches (all, and of people crossing at 5-25 m), people's
detections on another's track, frames mixing two people and centres off their person by more than 0.5 m —
as associated, after the review's fixes, after fixes everywhere — with the fix operations written
(consecutive frames alike as one operation, as a reviewer writes a stretch) and the track frames the review
flags for a look.  Fragmentation (one person in two tracks) is left as it is: the fixes here only give
detections back to their people.

    python benchmarks/bench_identity_fixes.py [--seeds 0-8,17-21] [--rig default|pedx] [--workers 2]
                                              [--pedestrians 10] [--frames 20]
                                              [--name bench_identity_fixes] [--out benchmarks/results]

Writes ``<name>.json`` and ``<name>.md`` into ``--out``.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _common import hardware, public_args, rows_per_seed, write_outputs  # noqa: E402
from bench_association import add_scene_arguments, parsed_seeds, simulated_scenes  # noqa: E402
from bench_detections import FORMATS, SHARED_CMU, read_format  # noqa: E402
from pedx_graph.detections.association import associate  # noqa: E402
from pedx_graph.detections.evaluate import (placement_counts, read_detection_truth, score_tracks,  # noqa: E402
                                            truth_fixes)
from pedx_graph.detections.fixes import fix_tracks  # noqa: E402
from pedx_graph.detections.review import review_summary, untracked_detections  # noqa: E402

#: The stages each input is scored at: as associated, after the review's fixes, after fixes everywhere.
STAGES = ("associated", "review_fixed", "all_fixed")
#: Counts scored at every stage.
STAGE_COUNTS = ("id_switches", "crossing_id_switches", "others_detections", "mixed_frames", "misplaced_centres")
#: Counts of one input, summed over the inputs.
COUNTS = ("track_frames", "review_flagged_frames", "review_operations", "all_operations") + tuple(
    f"{stage}_{count}" for stage in STAGES for count in STAGE_COUNTS)


def _scored(tracks, records, labelled, crossing, centres, ground) -> dict:
    score = score_tracks(tracks, records, labelled)
    return {"id_switches": score["id_switches"],
            "crossing_id_switches": sum(1 for _, _, a, b in score["switches"] if a in crossing or b in crossing),
            "others_detections": score["others_detections"], "mixed_frames": score["mixed_frames"],
            "misplaced_centres": placement_counts(tracks, records, centres, ground)["misplaced_centres"]}


def run_seed(seed: int, pedestrians: int, frames: int, rig: str = "default") -> list[dict]:
    """One row per scene and format of ``seed`` (module docstring)."""
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_identity_fixes_") as tmp:
        for sc in simulated_scenes(seed, pedestrians, frames, rig, tmp):
            name, scene, seq = sc.name, sc.root, sc.sequence
            labelled, crossing, calibs, clouds, ground, centres = (sc.labelled, sc.crossing, sc.calibs, sc.clouds,
                                                                   sc.ground, sc.centres)
            cameras = {cam for pair in calibs for cam in pair.split("-")}
            for fmt in FORMATS:
                detections = read_format(scene, fmt, seq)
                records = read_detection_truth(scene, seq, fmt)
                tracks = associate(detections, calibs, clouds=clouds, ground=ground)
                review = review_summary(tracks, ground, untracked=untracked_detections(detections, tracks))
                row = {"seed": seed, "scene": name, "format": fmt, "track_frames": review["track_frames"],
                       "review_flagged_frames": review["flagged_track_frames"]}
                scored = {"associated": _scored(tracks, records, labelled, crossing, centres, ground)}
                for stage, stretches in (("review_fixed", review["stretches"]), ("all_fixed", None)):
                    fixes = truth_fixes(tracks, records, cameras, stretches)
                    row[f"{stage.split('_')[0]}_operations"] = len(fixes)
                    if not fixes:
                        scored[stage] = scored["associated"]
                        continue
                    fixed, _ = fix_tracks(tracks, fixes, "<truth>", calibs, None, ground, clouds=clouds)
                    scored[stage] = _scored(fixed, records, labelled, crossing, centres, ground)
                row.update({f"{stage}_{k}": v for stage in STAGES for k, v in scored[stage].items()})
                rows.append(row)
    return rows


def markdown(result: dict) -> str:
    t = result["totals"]

    def stage(prefix: str) -> str:
        return (f"{t[prefix + '_id_switches']} ({t[prefix + '_crossing_id_switches']}) | "
                f"{t[prefix + '_others_detections']} | {t[prefix + '_mixed_frames']} | "
                f"{t[prefix + '_misplaced_centres']}")

    lines = [
        "# bench_identity_fixes: what the review's fixes cost and leave",
        "",
        f"Command: `{result['command']}`",
        "",
        f"Seeds {result['seeds_text']} ({len(result['seeds'])} seeds x 2 scenes x 3 formats = {len(result['rows'])} "
        f"inputs), {result['pedestrians']} pedestrians x {result['frames']} frames per scene, {result['motion']}, "
        f"{result['rig']} rig.  Method: see the script's docstring (the association benchmark's inputs; a reviewer "
        "who sees who is who fixes every person's detection on another's track, once inside the identity "
        "review's stretches alone, once everywhere; the fixes applied and the tracks placed again as "
        "`pedx-graph import --identity-fixes` does).",
        "",
        f"The review flags {t['review_flagged_frames']} of {t['track_frames']} track frames "
        f"({100 * t['review_flagged_frames'] / max(t['track_frames'], 1):.0f} %).",
        "",
        "| stage | fix operations | id switches (crossing) | others' detections | mixed frames | "
        "centres off > 0.5 m |",
        "|---|---:|---:|---:|---:|---:|",
        f"| as associated | 0 | {stage('associated')} |",
        f"| fixes inside the review's stretches | {t['review_operations']} | {stage('review_fixed')} |",
        f"| fixes everywhere | {t['all_operations']} | {stage('all_fixed')} |",
        "",
        "## Per input (switches as associated -> after the review's fixes -> after fixes everywhere)",
        "",
        "| seed | scene | format | flagged / track frames | operations, review / everywhere | id switches | "
        "others' detections | centres off > 0.5 m |",
        "|---:|---|---|---:|---:|---:|---:|---:|",
    ]
    for r in result["rows"]:
        lines.append(
            f"| {r['seed']} | {r['scene']} | {r['format']} | {r['review_flagged_frames']} / {r['track_frames']} | "
            f"{r['review_operations']} / {r['all_operations']} | "
            + " | ".join(" -> ".join(str(r[f"{s}_{k}"]) for s in STAGES)
                         for k in ("id_switches", "others_detections", "misplaced_centres")) + " |")
    lines += ["", f"Total time {result['total_seconds']:.0f} s with {result['workers']} workers.  Hardware: "
                  f"{result['hardware']}", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_scene_arguments(parser)
    parser.add_argument("--name", default="bench_identity_fixes", help="file name of the outputs, without suffix")
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args, seeds = parsed_seeds(parser, argv)
    t0 = time.perf_counter()
    rows = rows_per_seed(run_seed, seeds, args.workers, args.pedestrians, args.frames, args.rig)
    result = {"command": " ".join(["python benchmarks/bench_identity_fixes.py"] + public_args(argv)),
              "seeds_text": args.seeds, "seeds": seeds, "pedestrians": args.pedestrians, "frames": args.frames,
              "rig": args.rig, "workers": args.workers,
              "motion": "CMU hold-out clips" if SHARED_CMU.is_dir() else "procedural gait",
              "rows": rows, "totals": {k: sum(r[k] for r in rows) for k in COUNTS},
              "total_seconds": time.perf_counter() - t0, "hardware": hardware()}
    write_outputs(args.out, args.name, result, markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
