"""Errors a person can read: every CLI error is one line on stderr naming the path or the config key, exit code 1
(2 for a usage error); a traceback only with --debug; a bad dataset, config value or body model file stops the
command before it creates any output."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pedx_graph.cli import main
from pedx_graph.config import ConfigError
from pedx_graph.data.types import DataFormatError
from pedx_graph.sim.config import SimConfig
from pedx_graph.sim.simulate import simulate


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli_scene")
    cfg = SimConfig()
    cfg.scene.n_pedestrians = 2
    cfg.scene.n_frames = 3
    simulate(out, cfg, seed=3)
    return out


def one_error_line(capsys, *needles: str) -> str:
    """The one error line on stderr (log warnings before it are the named warnings of skipped inputs)."""
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("pedx-graph")]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def test_missing_dataset_is_one_line_and_creates_nothing(tmp_path, capsys):
    out = tmp_path / "X"
    assert main(["fit", str(tmp_path / "NOPE"), "--out", str(out)]) == 1
    one_error_line(capsys, "pedx-graph: error: ", "NOPE", "not a PedX dataset folder")
    assert not out.exists()


def test_debug_shows_the_traceback(tmp_path):
    with pytest.raises(DataFormatError, match="not a PedX dataset folder"):
        main(["--debug", "fit", str(tmp_path / "NOPE"), "--out", str(tmp_path / "X")])
    with pytest.raises(DataFormatError):                    # also after the command
        main(["fit", str(tmp_path / "NOPE"), "--out", str(tmp_path / "X"), "--debug"])


@pytest.mark.parametrize("argv, needle", [
    (["fit"], "required"),
    (["fit", "ds", "--out", "o", "--bogus"], "--bogus"),
    (["fit", "ds", "--out", "o", "--solver", "nope"], "--solver"),
    (["no-such-command"], "invalid choice"),
])
def test_usage_errors_exit_2_in_one_line(argv, needle, capsys):
    assert main(argv) == 2
    one_error_line(capsys, "error:", needle, "--help")


def test_bad_config_value_names_file_and_key(scene, tmp_path, capsys):
    preset = tmp_path / "bad.yaml"
    preset.write_text("noise:\n  keypoint_sigma_px: -3\n")
    out = tmp_path / "out"
    assert main(["fit", str(scene), "--out", str(out), "--config", str(preset)]) == 1
    one_error_line(capsys, "bad.yaml", "noise.keypoint_sigma_px", "> 0")
    assert not out.exists()
    preset.write_text("solver:\n  linear_solver: sparse\n")
    assert main(["stream", str(scene), "--out", str(out), "--config", str(preset)]) == 1
    one_error_line(capsys, "bad.yaml", "solver.linear_solver", "chain")
    assert not out.exists()


def test_truncated_body_model_is_named_once(scene, tmp_path, capsys):
    from pedx_graph.body.model import default_model_path

    model = tmp_path / "truncated.npz"
    model.write_bytes(default_model_path().read_bytes()[:50_000])
    preset = tmp_path / "model.yaml"
    preset.write_text(f"body_model: {model}\n")
    out = tmp_path / "out"
    assert main(["fit", str(scene), "--out", str(out), "--config", str(preset), "--workers", "2"]) == 1
    one_error_line(capsys, "model.yaml", "body_model", str(model))
    assert not out.exists()
    assert main(["baseline", "smplify_disp", str(scene), "--out", str(out), "--model", str(model)]) == 1
    one_error_line(capsys, "body_model", str(model))
    assert not out.exists()


def test_bad_calibration_is_one_line_naming_file_and_key(scene, tmp_path, capsys):
    import shutil

    dataset = tmp_path / "ds"
    shutil.copytree(scene, dataset)
    for path in (dataset / "calib").glob("calib_cam_to_cam_*.txt"):     # a focal length of 1e-9 px
        lines = []
        for line in path.read_text().splitlines():
            key, text = line.split(":", 1)
            if key.startswith("P_rect_0"):
                P = np.array(text.split(), dtype=float).reshape(3, 4)
                P[0] *= 1e-9 / P[0, 0]
                P[1, :2] *= 1e-9 / P[1, 1]
                line = f"{key}: " + " ".join(repr(float(v)) for v in P.ravel())
            lines.append(line)
        path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    assert main(["fit", str(dataset), "--out", str(out)]) == 1
    one_error_line(capsys, "calib_cam_to_cam_ylw79D0-red707B.txt: field 'P_rect_00'", "field of view")
    assert not (out / "labels").exists()


def test_eval_refusing_another_scene_is_one_line(scene, tmp_path, capsys):
    from pedx_graph.data.reader import read_smpl_labels
    from pedx_graph.data.writer import write_results

    other = tmp_path / "other"
    cfg = SimConfig()
    cfg.scene.n_pedestrians = 2
    cfg.scene.n_frames = 3
    simulate(other, cfg, seed=4)
    results = tmp_path / "results"
    write_results(results, [lab for labs in read_smpl_labels(scene).values() for lab in labs])
    assert main(["eval", str(results), "--truth", str(other)]) == 1
    one_error_line(capsys, str(results), "ground-truth label", str(other))
    assert not (results / "eval.json").exists()


def test_missing_config_file_is_one_line(scene, tmp_path, capsys):
    assert main(["fit", str(scene), "--out", str(tmp_path / "o"), "--config", str(tmp_path / "none.yaml")]) == 1
    one_error_line(capsys, "none.yaml", "not found")


def test_console_entry_point(tmp_path):
    """The installed command: one line and exit 1; the traceback only with --debug."""
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    argv = [sys.executable, "-m", "pedx_graph.cli", "fit", str(tmp_path / "NOPE"), "--out", str(tmp_path / "X")]
    plain = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=300)
    assert plain.returncode == 1
    assert plain.stderr.strip().splitlines() == [f"pedx-graph: error: {tmp_path / 'NOPE'}: not a PedX dataset folder: "
                                                 f"neither 'labels/' nor 'data/labels/' exists"]
    debug = subprocess.run(argv + ["--debug"], capture_output=True, text=True, env=env, timeout=300)
    assert debug.returncode != 0 and "Traceback" in debug.stderr and "DataFormatError" in debug.stderr
    assert not (tmp_path / "X").exists()


def test_config_error_type_is_the_projects():
    from pedx_graph.config import load_config
    from pedx_graph.graph.config import FitConfig

    assert issubclass(ConfigError, ValueError)
    assert load_config(FitConfig) == FitConfig()
