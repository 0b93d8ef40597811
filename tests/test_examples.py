"""Every script in ``examples/`` runs (as a user would: ``python examples/NAME.py ...`` in a subprocess) on a tiny
scene in a temporary folder, and does what its docstring says."""
from __future__ import annotations

import ast
import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

#: example script -> the test below that runs it (every script must have one)
TESTED = {
    "fit_simulated_scene.py": "test_fit_simulated_scene",
    "stream_live.py": "test_stream_live",
    "run_on_cluster.py": "test_run_on_cluster",
    "draw_uncertainty.py": "test_draw_uncertainty",
    "load_smpl_model.py": "test_load_smpl_model_npz_and_pkl",
    "import_detections.py": "test_import_detections",
}


def run_example(name: str, *args: str, cwd: Path) -> str:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, str(EXAMPLES / name), *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=600)
    assert done.returncode == 0, f"{name} failed:\n{done.stdout}\n{done.stderr}"
    return done.stdout


def test_every_example_has_a_docstring_a_main_and_a_test():
    scripts = sorted(p.name for p in EXAMPLES.glob("*.py"))
    assert scripts and set(scripts) == set(TESTED)
    for name in scripts:
        tree = ast.parse((EXAMPLES / name).read_text())
        doc = ast.get_docstring(tree)
        assert doc and len(doc.splitlines()[0]) > 20, f"{name}: no opening docstring"
        assert any(isinstance(n, ast.FunctionDef) and n.name == "main" for n in tree.body), f"{name}: no main()"
        assert TESTED[name] in globals(), f"{name}: no test {TESTED[name]}"


def test_fit_simulated_scene(tmp_path):
    out = tmp_path / "fit"
    stdout = run_example("fit_simulated_scene.py", "--out", str(out), "--pedestrians", "2", "--frames", "4",
                         cwd=tmp_path)
    summary = json.loads((out / "fit_summary.json").read_text())
    assert len(summary["tracks"]) == 2 and "NEES/dof" in stdout
    for track in summary["tracks"]:
        assert track["frames"] == 4
        assert track["keypoint_error_mm"] < 125          # seed 0 measured 82 and 27 mm
        assert 0.2 < track["nees_per_dof"] < 2.0          # measured 0.81 and 0.54: covariances near honest
        cov = np.asarray(track["cov_trans_frame0_m2"])
        assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
        assert all(1.0 < s < 300.0 for s in track["sigma_trans_mm"])


def test_stream_live(tmp_path):
    out = tmp_path / "stream"
    run_example("stream_live.py", "--out", str(out), "--pedestrians", "2", "--frames", "4", cwd=tmp_path)
    summary = json.loads((out / "stream_summary.json").read_text())
    assert [s["observed"] for s in summary["samples"]] == [2, 2, 2, 2]
    assert all(s["estimated"] == s["observed"] for s in summary["samples"])     # a causal estimate per frame
    assert summary["failed"] == []
    assert sorted(t["frames"] for t in summary["tracks"]) == [4, 4]             # each track smoothed at the end
    assert all(0 < s < 300 for t in summary["tracks"] for s in t["sigma_trans_last_frame_mm"])


def test_run_on_cluster(tmp_path):
    out = tmp_path / "cluster"
    stdout = run_example("run_on_cluster.py", "--out", str(out), "--cluster", "local:2", "--pedestrians", "2",
                         "--frames", "3", cwd=tmp_path)
    summary = json.loads((out / "results" / "summary.json").read_text())
    assert summary["execution"]["executor"] == "dask" and summary["execution"]["cluster"] == "local:2"
    assert summary["counts"]["done"] == summary["counts"]["tracks"] == 2 and summary["counts"]["failed"] == 0
    labels = sorted((out / "results" / "labels" / "3d" / "smpl").rglob("*.json"))
    assert len(labels) == 6
    assert "2 of 2 tracks fitted on local:2" in stdout


def test_draw_uncertainty(tmp_path):
    from pedx_graph import read_dataset

    out = tmp_path / "ellipses"
    run_example("draw_uncertainty.py", "--out", str(out), "--pedestrians", "2", "--frames", "3", cwd=tmp_path)
    record = json.loads((out / "uncertainty.json").read_text())
    image = cv2.imread(str(out / "uncertainty.png"))
    width, height = record["image_size"]
    assert image.shape == (height, width, 3)                  # the camera's image size
    assert record["people"]
    calib = read_dataset(out / "scene")[0].calibrations[record["pair"]]
    for person in record["people"]:
        world_p, world_cov = np.asarray(person["world_keypoints_m"]), np.asarray(person["world_cov_m2"])
        uv, cov_uv = np.asarray(person["uv_px"]), np.asarray(person["cov_uv_px2"])
        assert uv == pytest.approx(calib.project(world_p)[0], abs=1e-6)
        # first-order propagation, checked with a numerical Jacobian of the calibration's own projection
        step = 1e-5
        jac = np.stack([(calib.project(world_p + step * e)[0] - calib.project(world_p - step * e)[0]) / (2 * step)
                        for e in np.eye(3)], axis=-1)                                    # (18, 2, 3) px / m
        assert cov_uv == pytest.approx(jac @ world_cov @ np.swapaxes(jac, 1, 2), rel=1e-4, abs=1e-6)
        axes = np.asarray(person["semi_axes_px"])                                        # 95 %: chi2(2) = 5.991
        assert axes == pytest.approx(np.sqrt(5.991465 * np.linalg.eigvalsh(cov_uv)[:, ::-1]), rel=1e-4)
        inside = np.all((uv >= 0) & (uv < [width, height]), axis=1)
        assert inside.mean() > 0.9
        u, v = np.round(uv[inside].mean(axis=0)).astype(int)
        patch = image[v - 40:v + 40, u - 40:u + 40].reshape(-1, 3)
        assert (np.abs(patch.astype(int) - 96).max(axis=1) > 30).mean() > 0.2           # drawn over the grey canvas


def smpl_format_files(folder: Path) -> tuple[Path, Path]:
    """The open model's arrays under SMPL's keys only (no PedX keypoint keys, as a real SMPL file): an ``.npz``
    and a ``.pkl`` with a scipy-sparse ``J_regressor`` and SMPL's string fields, as the SMPL pickles hold."""
    from pedx_graph.body.model import default_model_path

    data = np.load(default_model_path())
    arrays = {k: data[k] for k in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights",
                                   "kintree_table", "f")}
    npz = folder / "SMPL_LIKE_NEUTRAL.npz"
    np.savez_compressed(npz, **arrays)
    pkl = folder / "smpl_like_neutral.pkl"
    payload = dict(arrays, J_regressor=__import__("scipy.sparse").sparse.csc_matrix(arrays["J_regressor"]),
                   bs_type="lrotmin", bs_style="lbs")
    with open(pkl, "wb") as fh:
        pickle.dump(payload, fh, protocol=2)
    return npz, pkl


def test_load_smpl_model_npz_and_pkl(tmp_path):
    from pedx_graph import BodyModel

    npz, pkl = smpl_format_files(tmp_path)
    open_model = BodyModel.load()
    rest_height = float(np.ptp(open_model.forward(np.zeros(72), np.zeros(10), np.zeros(3)).vertices[:, 1]))
    summaries = []
    for path, extra in ((npz, ["--fit", "--pedestrians", "1", "--frames", "3"]), (pkl, [])):
        out = tmp_path / path.stem
        run_example("load_smpl_model.py", str(path), "--out", str(out), *extra, cwd=tmp_path)
        summary = json.loads((out / "model_summary.json").read_text())
        assert summary["vertices"] == 6890 and summary["joints"] == 24 and summary["betas"] == 10
        assert summary["rest_height_m"] == pytest.approx(rest_height, abs=1e-5)
        mesh = trimesh.load(out / "posed.obj", process=False)
        assert len(mesh.vertices) == 6890 and len(mesh.faces) == summary["faces"]
        summaries.append(summary)
    # the same model from either file: the same posed keypoints
    for name, point in summaries[0]["keypoints"].items():
        assert summaries[1]["keypoints"][name] == pytest.approx(point, abs=1e-4)
    # the left knee was bent: the left ankle moved by a lower leg's swing, the right one stayed (trans 2 m in z)
    rest = open_model.forward(np.zeros(72), np.zeros(10), np.array([0.0, 0.0, 2.0])).keypoints
    names = open_model.keypoint_names
    moved = np.asarray(summaries[0]["keypoints"]["lankl"]) - rest[names.index("lankl")]
    assert 0.15 < np.linalg.norm(moved) < 0.5
    assert np.asarray(summaries[0]["keypoints"]["rankl"]) == pytest.approx(rest[names.index("rankl")], abs=1e-3)
    fits = summaries[0]["fits"]
    assert len(fits) == 1 and fits[0]["frames"] == 3 and np.isfinite(fits[0]["final_error"])


def test_import_detections(tmp_path):
    out = tmp_path / "detections"
    run_example("import_detections.py", "--out", str(out), "--pedestrians", "4", "--frames", "10", "--seed", "1",
                cwd=tmp_path)
    summary = json.loads((out / "detections_summary.json").read_text())
    assert summary["detections"] > 0 and summary["counts"]["failed"] == 0
    assert summary["counts"]["done"] == len(summary["tracks"]) >= 2
    labels = sorted((out / "imported" / "labels" / "2d").rglob("*.json"))
    assert labels and all(json.loads(p.read_text())["keypoint_set"] == "body25" for p in labels)   # the set's own
    # seed 1 measured 36, 53, 62 mm for three labelled people (and a bystander's track with no truth nearby)
    good = [t for t in summary["tracks"] if t["keypoint_error_mm"] < 95]
    assert len(good) >= 2 and len({t["person"] for t in good}) == len(good)
