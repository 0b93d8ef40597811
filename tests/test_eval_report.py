"""Evaluation report: tables from known inputs, the floor's Monte Carlo, the detector noise, ablation presets,
and one tiny end-to-end report (simulate, baseline, detector labels, report)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pedx_graph.data.detector_model import SWAP_PAIRS, DetectorNoiseConfig, corrupt_keypoints, corrupt_polygon
from pedx_graph.eval import floor as fl
from pedx_graph.eval import report as rp
from pedx_graph.eval import runs
from pedx_graph.eval import tables as tb
from pedx_graph.eval.experiments import ABLATION_ROWS, ExperimentConfig, SceneVariant
from pedx_graph.eval.metrics import summarise
from pedx_graph.keypoints import EVAL_JOINTS, PEDX_KEYPOINTS

ROOT = Path(__file__).resolve().parents[1]


def constant_summary(global_mm: float, rel_mm: float, distances=(10.0, 20.0, 30.0, 40.0)) -> dict:
    """A summarise() dict whose every error is the given constant (one frame per distance)."""
    n = len(distances)
    glob = np.full((n, 13), global_mm / 1000.0)
    rel = np.full((n, 13), rel_mm / 1000.0)
    return summarise(glob, rel, np.ones((n, 13)), np.array(distances))


def test_per_joint_table_columns_and_mean():
    table = tb.per_joint_table({"a": constant_summary(100, 40), "b": constant_summary(250, 60)}, "global_mm",
                               floor=constant_summary(10, 5))
    lines = table.strip().splitlines()
    assert lines[0] == "| joint | a | b | floor |"
    assert len(lines) == 2 + 13 + 1
    assert lines[2] == f"| {EVAL_JOINTS[0]} | 100.0 | 250.0 | 10.0 |"
    assert lines[-1] == "| **mean** | **100.0** | **250.0** | **10.0** |"


def test_distance_and_floor_ratio_tables():
    methods = {"m": constant_summary(300, 90)}
    floor = constant_summary(30, 10)
    dist = tb.distance_table(methods, floor)
    assert "| frames | 1 | 1 | 1 | 1 |" in dist
    assert "| m | 300.0 / 90.0 | 300.0 / 90.0 | 300.0 / 90.0 | 300.0 / 90.0 |" in dist
    ratio = tb.floor_ratio_table(methods, floor)
    assert "| m | 10.0 / 9.0 | 10.0 / 9.0 |" in ratio


def test_distance_table_leaves_empty_bins_out():
    table = tb.distance_table({"m": constant_summary(100, 50, distances=(10.0,))})
    assert "| method | 5-15 m |" in table and "15-25" not in table and "nan" not in table
    assert "| m | 100.0 / 50.0 |" in table
    both = tb.distance_table({"m": constant_summary(100, 50, distances=(10.0,)),
                              "n": constant_summary(90, 40, distances=(20.0,))})
    assert "| m | 100.0 / 50.0 | - / - |" in both and "25-35" not in both


def test_ablation_table_and_ordering():
    rows = [(i + 1, r.label, r.terms, constant_summary(400 - 50 * i, 100 - 10 * i))
            for i, r in enumerate(ABLATION_ROWS[:5])]
    table = tb.ablation_table(rows)
    assert "| 1: left image | x |  |  |  |  | 400.0 | 100.0 |" in table
    assert "| 5: full (+ temporal) | x | x | x | x | x | 200.0 | 60.0 |" in table
    steps = tb.ablation_ordering(rows)
    assert [s["to_row"] for s in steps] == [2, 3, 4, 5]
    assert all(s["global_change_mm"] == pytest.approx(-50.0) for s in steps)
    assert "helps" in tb.ordering_text(steps) and "does not help" not in tb.ordering_text(steps)


def test_assemble_groups_runs():
    def run(name, label, group, labels="clean", kind="fit", terms=None, g=100.0):
        return {"name": name, "label": label, "group": group, "labels": labels, "kind": kind, "terms": terms,
                "path": name, "eval": constant_summary(g, g / 2),
                "summary": {"wall_seconds": 2.0, "total_frames": 4, "workers": 1, "tracks": 1, "failed": 0,
                            "track_seconds_sum": 1.0, "track_seconds_median": 1.0}}
    full = ABLATION_ROWS[4].fit_terms()
    runs = [run("ours", "ours", "methods", terms=full, g=150.0),
            run("triangulation", "triangulation", "methods", kind="baseline", g=400.0),
            run("ablation1", "left image", "ablation", terms=ABLATION_ROWS[0].fit_terms(), g=900.0),
            run("ours_detector", "ours", "detector", labels="detector", terms=full, g=250.0)]
    out = rp.assemble(runs)
    assert out["methods"] == ["ours", "triangulation"]
    assert [a["row"] for a in out["ablation"]] == [1, 5]
    assert out["noisy"][0]["method"] == "ours"
    assert out["noisy"][0]["detector"]["global_mm"] == pytest.approx(250.0)
    assert "| ours | annotator | 150.0 | 75.0 | - | - | - % |" in out["tables"]["table5_noisy_labels"]
    assert "| ours | detector | 250.0 | 125.0 | - | - | - % |" in out["tables"]["table5_noisy_labels"]
    assert "| ours | 1 (0) | 4 | 1 | 2.0 | 0.250 | 1.00 |" in out["tables"]["speed"]
    md = tb.render_markdown(out)
    assert md.index("Table II") < md.index("Table III") < md.index("Table IV") < md.index("Table V")


def test_solver_runs_keep_their_names_and_stay_out_of_the_ablation():
    full = ABLATION_ROWS[4].fit_terms()

    def run(name, label, g, **extra):
        return {"name": name, "label": label, "group": "methods", "labels": "clean", "kind": "fit",
                "terms": full, "path": name, "eval": constant_summary(g, g / 2),
                "summary": {"wall_seconds": None, "total_frames": None, "workers": None, "tracks": 0, "failed": 0,
                            "track_seconds_sum": None, "track_seconds_median": None}, **extra}
    runs = [run("ours", "ours", 150.0, ablation_row=5), run("admm", "ADMM", 160.0, ablation_row=None),
            run("stream", "iSAM2 stream (final)", 140.0, ablation_row=None),
            run("stream_causal", "iSAM2 stream (causal)", 300.0, ablation_row=None),
            run("other", "other", 170.0)]                    # no experiment.json: matched by its switches
    out = rp.assemble(runs)
    assert out["methods"] == ["ours", "ADMM", "iSAM2 stream (final)", "iSAM2 stream (causal)", "other"]
    assert "| joint | ours | ADMM | iSAM2 stream (final) | iSAM2 stream (causal) | other |" in \
        out["tables"]["table2_root_relative_per_joint"]
    table4 = out["tables"]["table4_ablation"]
    assert "| 5: full (+ temporal) (ours) |" in table4 and "| 5: full (+ temporal) (other) |" in table4
    assert "ADMM" not in table4 and "stream" not in table4


def test_expected_errors_isotropic():
    """E||N(0, s^2 I3)|| = s sqrt(8/pi); the root-relative error is smaller (the alignment absorbs some)."""
    sigma = 0.01
    truth = np.random.default_rng(1).normal(size=(13, 3)) * 0.4
    glob, rel = fl.expected_errors(sigma ** 2 * np.eye(39), truth, 4000, np.random.default_rng(0))
    assert glob.mean() == pytest.approx(sigma * np.sqrt(8 / np.pi), rel=0.02)
    assert np.all(rel < glob)


def test_eval_jacobian_hip_is_mid_hips():
    full = np.random.default_rng(0).normal(size=(2, 18, 3, 5))
    j13 = fl.eval_jacobian(full)
    assert j13.shape == (2, 13, 3, 5)
    hip = EVAL_JOINTS.index("hip")
    lh, rh = PEDX_KEYPOINTS.index("lhip"), PEDX_KEYPOINTS.index("rhip")
    np.testing.assert_allclose(j13[:, hip], 0.5 * (full[:, lh] + full[:, rh]))
    np.testing.assert_allclose(j13[:, EVAL_JOINTS.index("neck")], full[:, PEDX_KEYPOINTS.index("neck")])


def _quiet() -> DetectorNoiseConfig:
    return DetectorNoiseConfig(sigma_px=0.0, sigma_height_frac=0.0, miss_prob_visible=0.0, miss_prob_occluded=0.0,
                               swap_prob=0.0, outlier_prob=0.0, polygon_scale_sigma=0.0, polygon_shift_frac=0.0,
                               polygon_vertex_noise_px=0.0)


def test_detector_noise_switches():
    rng = np.random.default_rng(0)
    uv0 = rng.uniform(100, 900, size=(18, 2))
    lab = np.ones(18, bool)
    vis = rng.random(18) < 0.7
    box = (uv0.min(0), uv0.max(0))
    uv, v = corrupt_keypoints(uv0, lab, vis, 500.0, box, _quiet(), np.random.default_rng(1), (1000, 1000))
    np.testing.assert_allclose(uv, uv0)
    np.testing.assert_array_equal(v, vis)
    swap = _quiet()
    swap.swap_prob = 1.0
    uv, v = corrupt_keypoints(uv0, lab, vis, 500.0, box, swap, np.random.default_rng(1), (1000, 1000))
    for a, b in SWAP_PAIRS:
        ia, ib = PEDX_KEYPOINTS.index(a), PEDX_KEYPOINTS.index(b)
        np.testing.assert_allclose(uv[ia], uv0[ib])
        assert v[ia] == vis[ib]
    miss = _quiet()
    miss.miss_prob_visible = miss.miss_prob_occluded = 1.0
    uv, v = corrupt_keypoints(uv0, lab, vis, 500.0, box, miss, np.random.default_rng(1), (1000, 1000))
    assert np.isnan(uv).all() and not v.any()
    noisy = DetectorNoiseConfig(sigma_px=5.0, sigma_height_frac=0.0, miss_prob_visible=0.0, miss_prob_occluded=0.0,
                                swap_prob=0.0, outlier_prob=0.0, occluded_sigma_factor=1.0)
    many = np.concatenate([corrupt_keypoints(uv0, lab, vis, 0.0, box, noisy, np.random.default_rng(s),
                                             (1000, 1000))[0] - uv0 for s in range(200)])
    assert many.std() == pytest.approx(5.0, rel=0.1)
    poly = np.array([[10.0, 10.0], [50.0, 10.0], [50.0, 90.0], [10.0, 90.0]])
    np.testing.assert_allclose(corrupt_polygon(poly, 80.0, _quiet(), np.random.default_rng(0), (100, 100)), poly)


def test_ablation_presets_match_rows():
    from pedx_graph.config import load_config
    from pedx_graph.graph.config import FitConfig

    files = sorted((ROOT / "configs").glob("ablation_*.yaml"))
    assert len(files) == len(ABLATION_ROWS) == 6
    seen = set()
    for number, path in enumerate(files, start=1):
        terms = vars(load_config(FitConfig, path).terms)
        assert terms == ABLATION_ROWS[number - 1].fit_terms() | {k: v for k, v in terms.items()
                                                               if k not in ABLATION_ROWS[0].fit_terms()}
        assert runs.ablation_row(terms) == number
        assert terms["pose_prior"] is True
        seen.add(tuple(sorted(terms.items())))
    assert len(seen) == 6
    assert runs.ablation_row(vars(FitConfig().terms)) == 5


def test_detector_preset_loads():
    from pedx_graph.config import load_config

    cfg = load_config(DetectorNoiseConfig, ROOT / "configs" / "detector_noise.yaml")
    assert cfg == DetectorNoiseConfig()


@pytest.fixture(scope="module")
def tiny_experiment(tmp_path_factory):
    """Two tiny scenes merged, the triangulation baseline on clean and detector labels."""
    from pedx_graph.baselines.run import fit_dataset_baseline
    from pedx_graph.eval.detector_noise import make_noisy_dataset
    from pedx_graph.experiment_runner import merge_scenes, scene_config
    from pedx_graph.sim.simulate import simulate

    work = tmp_path_factory.mktemp("report")
    cfg = ExperimentConfig(pedestrians=2, frames=3, motion_dir="")
    scenes = []
    variants = [SceneVariant("a", "20991231T1200"), SceneVariant("b", "20991231T1300", 24.0, 30.0, 6.0)]
    for k, variant in enumerate(variants):
        simulate(work / variant.name, scene_config(variant, cfg), seed=k)
        scenes.append(work / variant.name)
    dataset = merge_scenes(scenes, work / "dataset")
    counts = make_noisy_dataset(dataset, work / "noisy", DetectorNoiseConfig(), seed=0)
    fit_dataset_baseline(dataset, work / "runs" / "triangulation", "triangulation")
    fit_dataset_baseline(work / "noisy", work / "runs" / "triangulation_detector", "triangulation")
    (work / "runs" / "triangulation_detector" / "experiment.json").write_text(json.dumps(
        {"name": "triangulation_detector", "label": "triangulation", "group": "detector", "labels": "detector"}))
    return work, dataset, counts


def test_merge_and_detector_dataset(tiny_experiment):
    from pedx_graph.data.reader import list_sequences, read_dataset

    work, dataset, counts = tiny_experiment
    assert list_sequences(dataset) == ["20991231T1200", "20991231T1300"]
    assert (dataset / "truth" / "20991231T1300" / "meta.json").is_file()
    assert counts["labels"] > 0 and counts["from_truth"] == counts["labels"]
    clean = {(t.sequence, t.tracking_id): t for t in read_dataset(dataset)}
    noisy = {(t.sequence, t.tracking_id): t for t in read_dataset(work / "noisy")}
    assert set(noisy) <= set(clean)
    key = next(iter(noisy))
    a, b = clean[key].frames[0].left.keypoints, noisy[key].frames[0].left.keypoints
    both = np.all(np.isfinite(a), 1) & np.all(np.isfinite(b), 1)
    assert both.any() and not np.allclose(a[both], b[both])


def test_report_end_to_end(tiny_experiment, tmp_path):
    work, dataset, _ = tiny_experiment
    out = rp.build_report([work / "runs" / "triangulation", work / "runs" / "triangulation_detector"], dataset,
                          tmp_path / "report", rp.ReportConfig(floor_samples=8, figures=False))
    md = (tmp_path / "report" / "report.md").read_text()
    assert "Table II" in md and "Table V" in md and "error floor" in md
    saved = json.loads((tmp_path / "report" / "report.json").read_text())
    assert saved["methods"] == ["triangulation"]
    floor = out["floor"]
    assert floor is not None and floor["frames"] > 0
    tri = next(r for r in out["runs"] if r["name"] == "triangulation")["eval"]
    robust = tri["robust"]
    assert 0 < robust["frames"] <= tri["frames"] and 0.0 <= robust["gross_failure_rate"] <= 1.0
    assert "median frame, global" in md
    # the floor is the estimator's best case: far below a keypoint triangulation
    assert floor["overall"]["global_mm"] < tri["overall"]["global_mm"]


def test_experiment_config_round_trip(tmp_path):
    from pedx_graph.config import load_config, save_config
    from pedx_graph.eval.experiments import resolved_scenes

    save_config(ExperimentConfig(), tmp_path / "experiment.yaml")
    loaded = load_config(ExperimentConfig, tmp_path / "experiment.yaml")
    assert resolved_scenes(loaded) == ExperimentConfig().scenes
    with pytest.raises(ValueError, match="distinct 'sequence'"):
        resolved_scenes(ExperimentConfig(scenes=[SceneVariant("a"), SceneVariant("b")]))


def test_notes_survive_regeneration(tmp_path):
    from pedx_graph.eval.report_cli import NOTES_BEGIN, NOTES_END, kept_notes

    path = tmp_path / "results.md"
    assert kept_notes(path).strip() == f"{NOTES_BEGIN}\n{NOTES_END}"
    path.write_text(f"# old numbers\n\n{NOTES_BEGIN}\nhand-written\n{NOTES_END}\n")
    assert kept_notes(path).strip() == f"{NOTES_BEGIN}\nhand-written\n{NOTES_END}"
