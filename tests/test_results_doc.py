"""docs/results.md: the solver / real-rig block is exactly what the committed benchmark JSON renders, no table
prints nan, and the hand-written notes carry no typed figure (every number comes from generated JSON); the same
for docs/detections.md's bench_detections table."""
from __future__ import annotations

import re
from pathlib import Path

from pedx_graph.eval.benchmark_tables import BEGIN, END, benchmark_block

ROOT = Path(__file__).resolve().parents[1]


def test_benchmark_block_matches_the_json():
    text = (ROOT / "docs" / "results.md").read_text()
    block = text[text.index(BEGIN):text.index(END) + len(END)] + "\n"
    assert block == benchmark_block(ROOT / "benchmarks" / "results")
    assert "| admm |" in block and "iSAM2 stream, causal" in block and "iSAM2 stream, final" in block


def test_no_nan_and_no_typed_figures_in_the_notes():
    text = (ROOT / "docs" / "results.md").read_text()
    assert "nan" not in text.lower().replace("nans", "")
    notes = text[text.index("<!-- notes -->"):text.index("<!-- /notes -->")]
    assert not re.findall(r"\d+\.\d", notes), "a decimal figure typed into the notes"
    assert not re.findall(r"\d+ ?mm", notes)


def test_detections_table_matches_the_json():
    """docs/detections.md's bench_detections table is what the committed JSON (seed 0 and seed*/) renders."""
    from pedx_graph.eval.benchmark_tables import DETECTIONS_BEGIN, DETECTIONS_END, detections_block

    text = (ROOT / "docs" / "detections.md").read_text()
    block = text[text.index(DETECTIONS_BEGIN):text.index(DETECTIONS_END) + len(DETECTIONS_END)] + "\n"
    assert block == detections_block(ROOT / "benchmarks" / "results")
    assert block.count("| openpose_body25 |") >= 3 and "nan" not in block.lower()


def test_pedx_rig_detections_table_matches_the_json():
    """docs/detections.md's table of the same benchmark on the real PedX rig (``--rig pedx``) is what the JSON
    committed under benchmarks/results/detections_pedx_rig renders, each command named with its folder."""
    from pedx_graph.eval.benchmark_tables import (DETECTIONS_PEDX_BEGIN, DETECTIONS_PEDX_END,
                                                  DETECTIONS_PEDX_FOLDER, detection_runs, detections_block)

    text = (ROOT / "docs" / "detections.md").read_text()
    block = text[text.index(DETECTIONS_PEDX_BEGIN):text.index(DETECTIONS_PEDX_END) + len(DETECTIONS_PEDX_END)] + "\n"
    assert block == detections_block(ROOT / DETECTIONS_PEDX_FOLDER, DETECTIONS_PEDX_FOLDER, DETECTIONS_PEDX_BEGIN,
                                     DETECTIONS_PEDX_END)
    runs = detection_runs(ROOT / DETECTIONS_PEDX_FOLDER)
    assert runs and all(run["rig"] == "pedx" and "--rig pedx" in run["command"] for run in runs)
    assert f"(written to `{DETECTIONS_PEDX_FOLDER}`)" in block and "nan" not in block.lower()
    assert all(run.get("rig", "default") == "default" for run in detection_runs(ROOT / "benchmarks" / "results"))


def test_identity_fixes_table_matches_the_json():
    """docs/detections.md's table of bench_identity_fixes is what the committed JSON renders, every set there,
    and the prose's claims hold: on the default rig's 84 inputs and held-out seeds the review's fixes leave no
    switch, fixes everywhere none anywhere, and they leave fewer centres off their person on four sets."""
    import json

    from pedx_graph.eval.benchmark_tables import (IDENTITY_FIXES_BEGIN, IDENTITY_FIXES_END, IDENTITY_FIXES_RUNS,
                                                  identity_fixes_block)

    results = ROOT / "benchmarks" / "results"
    text = (ROOT / "docs" / "detections.md").read_text()
    block = text[text.index(IDENTITY_FIXES_BEGIN):text.index(IDENTITY_FIXES_END) + len(IDENTITY_FIXES_END)] + "\n"
    assert block == identity_fixes_block(results)
    assert block.count("\n| ") == 1 + len(IDENTITY_FIXES_RUNS)          # the header and every set
    fewer_off = 0
    for name, _ in IDENTITY_FIXES_RUNS:
        t = json.loads((results / f"{name}.json").read_text())["totals"]
        assert t["all_fixed_id_switches"] == 0 and t["all_fixed_others_detections"] == 0, name
        assert t["review_fixed_id_switches"] <= t["associated_id_switches"], name
        if name in ("bench_identity_fixes", "bench_identity_fixes_heldout"):
            assert t["review_fixed_id_switches"] == 0, name
        fewer_off += t["all_fixed_misplaced_centres"] < t["associated_misplaced_centres"]
    assert "fall on four of the five sets" in " ".join(text.split()) and fewer_off == 4
    t = json.loads((results / "bench_identity_fixes.json").read_text())["totals"]
    readme = " ".join((ROOT / "README.md").read_text().split())
    assert (f"fixing what the flagged stretches show takes {t['review_operations']} operations and leaves no "
            f"identity switch" in readme) and t["review_fixed_id_switches"] == 0


def test_image_frame_table_matches_the_json():
    """docs/detections.md's table of bench_image_frame is what the committed JSON renders, and the prose's claims
    hold: no pair read the wrong way by its own rows, and on the real rig's preset no pair read the wrong way at
    all."""
    import json

    from pedx_graph.eval.benchmark_tables import IMAGE_FRAME_BEGIN, IMAGE_FRAME_END, image_frame_block

    results = ROOT / "benchmarks" / "results"
    text = (ROOT / "docs" / "detections.md").read_text()
    block = text[text.index(IMAGE_FRAME_BEGIN):text.index(IMAGE_FRAME_END) + len(IMAGE_FRAME_END)] + "\n"
    assert block == image_frame_block(results)
    summary = json.loads((results / "bench_image_frame.json").read_text())["summary"]
    assert {(s["rig"], s["images"]) for s in summary} == {(r, i) for r in ("default", "pedx")
                                                          for i in ("raw", "rectified")}
    assert all(s["wrong_by_own_rows"] == 0 for s in summary)
    assert all(s["right"] == s["pairs"] for s in summary if s["rig"] == "pedx")
    rows = json.loads((results / "bench_image_frame.json").read_text())["rows"]
    assert all(r["decided_by"] == "stereo rows" or r["decided_by"].startswith("the other pairs' stereo rows")
               for r in rows if r["rig"] == "pedx")
    prose = " ".join(text.split())
    assert "No pair was read the wrong way by its own rows." in prose
    assert "on the real rig's preset every pair was decided by its own rows or followed one" in prose


def test_pixel_scale_table_matches_the_json():
    """docs/detections.md's table of bench_pixel_scale is what the committed JSON renders, and the prose's claims
    hold: every input handled right, refusals naming the factor to within the trial grid, the accepted inputs
    far from a refusal."""
    import json

    from pedx_graph.eval.benchmark_tables import PIXEL_SCALE_BEGIN, PIXEL_SCALE_END, pixel_scale_block

    results = ROOT / "benchmarks" / "results"
    text = (ROOT / "docs" / "detections.md").read_text()
    block = text[text.index(PIXEL_SCALE_BEGIN):text.index(PIXEL_SCALE_END) + len(PIXEL_SCALE_END)] + "\n"
    assert block == pixel_scale_block(results)
    rows = json.loads((results / "bench_pixel_scale.json").read_text())["rows"]
    assert len(rows) == 190 and all(r["right"] for r in rows)
    assert {(r["rig"], r["written_scale"], r["written_units"]) for r in rows} == {
        (rig, scale, units) for rig in ("default", "pedx")
        for scale, units in ((1.0, "pixels"), (0.75, "pixels"), (0.5, "pixels"), (1.0, "unit"), (1.0, "signed_unit"))}
    refused = [r for r in rows if r.get("best_scale") and r["refused"]]
    assert refused and all(abs(r["best_scale"] / r["written_scale"] - 1) < 0.015 for r in refused)
    accepted = [r for r in rows if not r["refused"] and r.get("people_on_lidar")]
    assert max(r["people_on_lidar_elsewhere"] / r["people_on_lidar"] for r in accepted) < 0.79
    prose = " ".join(text.split())
    assert "Every input is handled right" in prose and "0.79 times as many people" in prose


def test_frame_rates_table_matches_the_json():
    """docs/detections.md's table of the association at other frame rates is what the committed JSON renders,
    and the prose's claims hold: the walking check flags every input associated at the wrong rate and none at
    the right one, told the interval a 5 Hz scene keeps nearly every labelled person (it was about half), and
    over one duration the switches fall as the rate rises."""
    import json

    from pedx_graph.eval.benchmark_tables import FRAME_RATES_BEGIN, FRAME_RATES_END, frame_rates_block

    results = ROOT / "benchmarks" / "results"
    text = (ROOT / "docs" / "detections.md").read_text()
    block = text[text.index(FRAME_RATES_BEGIN):text.index(FRAME_RATES_END) + len(FRAME_RATES_END)] + "\n"
    assert block == frame_rates_block(results)

    def rows(name):
        return json.loads((results / f"{name}.json").read_text())["rows"]

    for name, right in (("bench_association_5hz_at_10hz", False), ("bench_association_5hz", True),
                        ("bench_association_20hz_at_10hz", False), ("bench_association_20hz", True),
                        ("bench_association_10hz_4s", True), ("bench_association_20hz_4s", True)):
        checked = [r for r in rows(name) if r.get("walk_ratio") is not None]
        assert len(checked) >= 20 and all(r["walk_agrees"] == right for r in checked), name
    assert all(r["walk_agrees"] for r in rows("bench_association") if r.get("walk_ratio") is not None)
    told, untold = rows("bench_association_5hz"), rows("bench_association_5hz_at_10hz")
    assert sum(r["recovered"] for r in told) >= 0.95 * sum(r["labelled_people"] for r in told)
    assert sum(r["recovered"] for r in untold) < 0.7 * sum(r["labelled_people"] for r in untold)
    prose = " ".join(text.split())
    assert "flags every input associated at the wrong rate and none at the right one" in prose
    # over one duration (4 s) the more frames, the fewer switches; the prose quotes the runs' totals
    totals = {name: json.loads((results / f"{name}.json").read_text())["totals"]
              for name in ("bench_association_5hz", "bench_association_10hz_4s", "bench_association_20hz_4s")}
    switches = [(t["id_switches"], t["crossing_id_switches"]) for t in totals.values()]
    assert switches[0][0] > switches[1][0] > switches[2][0]
    assert ("switches less the more frames it sees: {} times ({} crossing) at 5 Hz, {} ({}) at 10 Hz, {} ({}) at "
            "20 Hz".format(*switches[0], *switches[1], *switches[2])) in prose
    assert "now the 4 s scenes break {} tracks into pieces against {} at 10 Hz and {} at 5 Hz".format(
        totals["bench_association_20hz_4s"]["fragmentations"], totals["bench_association_10hz_4s"]["fragmentations"],
        totals["bench_association_5hz"]["fragmentations"]) in prose


def test_joint_table_pools_the_seeds_by_frames():
    """The per-joint table and the pooled ratio weight each seed's means by its frames; the table lists every
    input that reports per-joint errors; runs without them add no table."""
    from pedx_graph.eval.benchmark_tables import detections_section

    def run(seed, frames, knee, joints=True, coco_mm=30.0):
        def stats(mpjpe=30.0):
            out = {"frames": frames, "mpjpe_mm": mpjpe, "rel_mpjpe_mm": 20.0}
            if joints:
                out["joint_mpjpe_mm"] = {"rknee": knee, "hip": 2 * knee}
            return out
        goal = {"mpjpe_ratio_5_25": 1.0, "within_1.5x": True, "crossing_id_switches": 0, "false_tracks": 0}
        scene = {"association": {"coco": {"recovered": 1, "labelled_people": 1}}}
        return {"seed": seed, "command": f"bench --seed {seed}", "goals": {"coco": goal}, "scenes": {"crossing": scene},
                "accuracy": {"manual": {"5-25": stats()}, "coco": {"5-25": stats(coco_mm)}}}

    text = detections_section([run(0, 1, 10.0, coco_mm=60.0), run(1, 3, 40.0)])
    assert "ratio to the manual labels: coco 1.25." in text       # (60 * 1 + 30 * 3) / 4 over 30
    assert [line for line in text.splitlines() if line.startswith("| coco | 4 |")] == ["| coco | 4 | 32.5 | 65.0 |"]
    assert "| input | frames | rknee | hip |" in text and "seeds 0, 1" in text
    assert "per joint" not in detections_section([run(0, 1, 10.0, joints=False)])


def test_views_table_pools_the_seeds_by_joint_frames():
    """The limbs-by-views table sums each bin's joint-frames over the seeds: share of all joint-frames, mean
    error weighted by joint-frames, part of the summed error; runs without the split add no table."""
    from pedx_graph.eval.benchmark_tables import detections_section

    def run(seed, bins):
        stats = {"frames": 1, "mpjpe_mm": 30.0, "rel_mpjpe_mm": 20.0}
        if bins is not None:
            stats = dict(stats, limbs_by_views={label: {"joint_frames": n, "mpjpe_mm": mm if n else None}
                                                for label, (n, mm) in bins.items()})
        goal = {"mpjpe_ratio_5_25": 1.0, "within_1.5x": True, "crossing_id_switches": 0, "false_tracks": 0}
        scene = {"association": {"coco": {"recovered": 1, "labelled_people": 1}}}
        return {"seed": seed, "command": f"bench --seed {seed}", "goals": {"coco": goal}, "scenes": {"crossing": scene},
                "accuracy": {"manual": {"5-25": stats}, "coco": {"5-25": stats}}}

    text = detections_section([run(0, {"0": (1, 100.0), "1": (3, 40.0), "2": (0, None)}),
                               run(1, {"0": (1, 60.0), "1": (1, 40.0), "2": (4, 25.0)})])
    # joint-frames 2 / 4 / 4 of 10; errors 160 / 160 / 100 of 420 mm summed
    row = [line for line in text.splitlines() if line.startswith("| coco | 0.20")]
    assert row == ["| coco | 0.20, 80.0 (0.38) | 0.40, 40.0 (0.38) | 0.40, 25.0 (0.24) |"]
    assert "| input | 0 images | 1 image | 2 images |" in text and "seeds 0, 1 pooled" in text
    assert "held them" not in detections_section([run(0, None)])


def test_association_placement_figures_match_the_json():
    """The placement figures docs/detections.md quotes for the association benchmark (default rig, the real
    rig's preset and the long scenes) are the totals of the committed JSON."""
    import json

    text = " ".join((ROOT / "docs" / "detections.md").read_text().split())
    for name in ("bench_association", "bench_association_pedx_rig", "bench_association_long"):
        result = json.loads((ROOT / "benchmarks" / "results" / f"{name}.json").read_text())
        total = result["totals"]
        share = lambda n: f"({100 * n / total['placed_frames']:.1f} %)"     # noqa: E731
        quoted = (f"{total['misplaced_centres']} of {total['placed_frames']:,}"
                  f"{' placed frames' if name == 'bench_association' else ''} {share(total['misplaced_centres'])}")
        assert quoted in text, f"{name}: {quoted!r} not in docs/detections.md"
        assert f"{total['overconfident_centres']} {share(total['overconfident_centres'])}" in text


def test_true_ids_ratio_is_shown_and_pooled_apart_from_the_associations():
    """The ratio with the simulator's ids is a column of its own (``-`` for a run without it), pooled over the
    seeds by frames like the association's ratio (only when every run has it), and kept out of the per-joint
    table."""
    from pedx_graph.eval.benchmark_tables import TRUE_IDS, detections_section

    def run(seed, frames, coco_mm, known_mm):
        def stats(mpjpe):
            return {"frames": frames, "mpjpe_mm": mpjpe, "rel_mpjpe_mm": 20.0, "joint_mpjpe_mm": {"rknee": mpjpe}}
        goal = {"mpjpe_ratio_5_25": coco_mm / 30.0, "within_1.5x": True, "crossing_id_switches": 0,
                "false_tracks": 0}
        accuracy = {"manual": {"5-25": stats(30.0)}, "coco": {"5-25": stats(coco_mm)}}
        if known_mm is not None:
            goal["mpjpe_ratio_5_25_true_ids"] = known_mm / 30.0
            accuracy["coco" + TRUE_IDS] = {"5-25": stats(known_mm)}
        scene = {"association": {"coco": {"recovered": 1, "labelled_people": 1}}}
        return {"seed": seed, "command": f"bench --seed {seed}", "goals": {"coco": goal},
                "scenes": {"crossing": scene}, "accuracy": accuracy}

    text = detections_section([run(0, 1, 60.0, 45.0), run(1, 3, 30.0, 30.0)])
    rows = [line.split(" | ") for line in text.splitlines() if line.startswith("| 0 | coco |")]
    assert rows and rows[0][4:6] == ["2.00", "1.50"]
    assert "ratio to the manual labels: coco 1.25." in text                # (60 * 1 + 30 * 3) / 4 over 30
    assert "With the simulator's ids: coco 1.12." in text                  # (45 * 1 + 30 * 3) / 4 over 30
    assert not any(line.startswith("| coco" + TRUE_IDS) for line in text.splitlines())
    older = detections_section([run(0, 1, 60.0, None), run(1, 3, 30.0, 30.0)])
    assert [line.split(" | ")[5] for line in older.splitlines() if line.startswith("| 0 | coco |")] == ["-"]
    assert "With the simulator's ids" not in older


def test_association_switch_geometry_figures_match_the_json():
    """The switch kinds docs/detections.md quotes for the association benchmark (default rig, the real rig's
    preset and the long scenes) are the totals of the committed JSON, and the kinds add up to the switches."""
    import json

    text = " ".join((ROOT / "docs" / "detections.md").read_text().split())
    for name in ("bench_association", "bench_association_pedx_rig", "bench_association_long"):
        total = json.loads((ROOT / "benchmarks" / "results" / f"{name}.json").read_text())["totals"]
        kinds = ("switches_in_line", "switches_paths_crossing", "switches_beside", "switches_unplaced")
        assert sum(total[k] for k in kinds) == total["id_switches"], name
        quoted = (f"{total['switches_in_line']} of {total['id_switches']} switches one behind the other, "
                  f"{total['switches_paths_crossing']} on crossing paths, {total['switches_beside']} beside")
        assert quoted in text, f"{name}: {quoted!r} not in docs/detections.md"


def test_readme_crowd_figures_match_the_json():
    """The crowded scenes' figures the README quotes (switches of walkers one behind the other; switches the
    first quarter of the identity review's flagged frames holds) are the committed long run's totals."""
    import json

    text = " ".join((ROOT / "README.md").read_text().split())
    total = json.loads((ROOT / "benchmarks" / "results" / "bench_association_long.json").read_text())["totals"]
    assert f"{total['switches_in_line']} of {total['id_switches']} on the benchmark's crowded scenes" in text
    assert (f"holds {total['switches_first_quarter']} of the {total['switches_in_review']} switches they hold"
            in text)


def test_keypoint_calibration_table_matches_its_runs():
    """docs/detections.md's keypoint-calibration table is the one the committed runs' JSON gives."""
    from pedx_graph.eval.benchmark_tables import (KEYPOINT_CALIBRATION_BEGIN, KEYPOINT_CALIBRATION_END,
                                                  keypoint_calibration_block)

    text = (ROOT / "docs" / "detections.md").read_text()
    block = text[text.index(KEYPOINT_CALIBRATION_BEGIN):
                 text.index(KEYPOINT_CALIBRATION_END) + len(KEYPOINT_CALIBRATION_END)] + "\n"
    assert block == keypoint_calibration_block(ROOT / "benchmarks" / "results")
