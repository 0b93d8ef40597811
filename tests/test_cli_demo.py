"""The README's main job: `pedx-graph demo` simulates, fits and evaluates on the embedded defaults."""
import json

from pedx_graph.cli import main


def test_demo_runs_end_to_end(tmp_path, capsys):
    out = tmp_path / "demo"
    rc = main(["demo", "--out", str(out), "--pedestrians", "3", "--frames", "6", "--workers", "1", "--seed", "3"])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "| visible joints |" in printed
    summary = json.loads((out / "results" / "summary.json").read_text())
    assert summary["tracks"] and not summary["failed"]
    report = json.loads((out / "results" / "eval.json").read_text())
    assert report["frames"] > 0 and report["overall"]["global_mm"] < 82.0     # measured 54.5 mm (seed 3)
    assert report["overall"]["root_relative_mm"] < 59.0                        # measured 39.1 mm
    assert (out / "results" / "fit_config.yaml").is_file()
    assert (out / "scene" / "labels" / "3d" / "smpl").is_dir()


def test_cli_without_command_prints_help(capsys):
    assert main([]) == 2
    assert "demo" in capsys.readouterr().out


def test_demo_runs_again_into_the_same_folder(tmp_path):
    """The README's first command can be run twice: the demo owns its output folder."""
    from pedx_graph.cli import main

    out = tmp_path / "demo"
    args = ["demo", "--out", str(out), "--pedestrians", "2", "--frames", "3"]
    assert main(args) == 0
    assert main(args) == 0
    assert (out / "results" / "summary.json").is_file()
