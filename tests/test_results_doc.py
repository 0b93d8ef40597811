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
