"""pedx-graph report on results alone: residuals, covariances per distance, per-track diagnostics and pictures,
no ground truth needed; empty distance bins are left out."""
from __future__ import annotations

import json

from pedx_graph.cli import main
from pedx_graph.graph.config import FitConfig
from pedx_graph.solvers.fit import fit_dataset
from scene_fixtures import small_scene


def test_report_without_truth_succeeds_and_says_what_the_results_say(tmp_path):
    scene = small_scene(tmp_path / "scene", 2, 4, seed=4)
    results = tmp_path / "results"
    summary = fit_dataset(scene, results, FitConfig(), workers=1)
    out = tmp_path / "report"
    assert main(["report", str(results), "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    stats = report["results"]["results"]
    assert stats["frames"] == summary["total_frames"]
    assert {t["tracking_id"] for t in stats["tracks"]} == {t["tracking_id"] for t in summary["tracks"]}
    assert stats["residuals"]["stereo_reprojection"]["rows"] > 0
    bins = stats["per_distance"]
    assert bins and all(b["frames"] > 0 for b in bins.values())
    assert sum(b["frames"] for b in bins.values()) <= stats["frames"]
    assert all(0 < b["trans_sd_median_mm"] < b["keypoint_sd_median_mm"] * 10 for b in bins.values())
    text = (out / "report.md").read_text()
    assert "nan" not in text and "Residuals" in text and "Per-track diagnostics" in text
    assert report["pictures"] and all((out / p).is_file() for p in report["pictures"])
    assert all(f"]({p})" in text for p in report["pictures"])
