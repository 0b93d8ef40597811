"""The command line's help and version: ``--version`` prints the package version; every subcommand's ``--help``
exits 0, states defaults and carries no reStructuredText markup; progress bars follow ``--quiet``."""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest

import pedx_graph
from pedx_graph.cli import build_parser, main, plain_text

ROOT = Path(__file__).resolve().parents[1]


def subcommands() -> list[str]:
    action = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return sorted(action.choices)


def test_version_prints_the_package_version(capsys):
    assert main(["--version"]) == 0
    out = capsys.readouterr().out.strip()
    assert out == f"pedx-graph {pedx_graph.__version__}"


def test_version_matches_the_installed_metadata():
    """The hard-coded ``__version__`` (kept so that ``import pedx_graph`` reads no metadata) is the
    project's version in pyproject.toml."""
    text = (ROOT / "pyproject.toml").read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("version"))
    assert line.split("=")[1].strip().strip('"') == pedx_graph.__version__
    try:
        installed = metadata.version("pedx-graph")
    except metadata.PackageNotFoundError:       # run from a checkout without installing: pyproject decides
        return
    assert installed == pedx_graph.__version__


def test_the_known_commands_are_registered():
    names = set(subcommands())
    assert {"info", "simulate", "fit", "stream", "baseline", "eval", "report", "experiments", "demo"} <= names


@pytest.mark.parametrize("command", subcommands())
def test_every_subcommand_help_shows_defaults_without_markup(command, capsys):
    assert main([command, "--help"]) == 0
    out = capsys.readouterr().out
    assert f"usage: pedx-graph {command}" in out
    assert "default" in out
    assert "`" not in out and ":func:" not in out and ":class:" not in out and ":mod:" not in out


def test_option_defaults_are_appended_unless_stated(capsys):
    assert main(["fit", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "(default: lm)" in out                          # --solver: appended
    assert "(default 1: this process)" in out              # --workers: stated in its help, not repeated
    assert "(default: 1)" not in out


def test_plain_text_removes_roles_and_literals():
    text = "see :func:`~pedx_graph.solvers.fit.fit_dataset` and ``--out``, `pedx-graph eval`"
    assert plain_text(text) == "see pedx_graph.solvers.fit.fit_dataset and --out, pedx-graph eval"


@pytest.mark.parametrize("command", ["fit", "stream", "baseline"])
def test_quiet_turns_the_progress_bar_off(command):
    parser = build_parser()
    base = [command] + (["triangulation"] if command == "baseline" else []) + ["DATA", "--out", "OUT"]
    assert parser.parse_args(base).no_progress is False
    assert parser.parse_args(base + ["--quiet"]).no_progress is True
    assert parser.parse_args(base + ["-q"]).no_progress is True
    assert parser.parse_args(base + ["--no-progress"]).no_progress is True


def test_experiments_has_quiet():
    parser = build_parser()
    assert parser.parse_args(["experiments", "OUT"]).quiet is False
    assert parser.parse_args(["experiments", "OUT", "-q"]).quiet is True


def test_version_from_the_console_entry_point():
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-m", "pedx_graph.cli", "--version"], capture_output=True, text=True,
                          env=env, timeout=120)
    assert done.returncode == 0
    assert done.stdout.strip() == f"pedx-graph {pedx_graph.__version__}"


def run_on_a_terminal(argv: list[str]) -> tuple[int, str, str]:
    """Run ``python -m pedx_graph.cli ARGV`` with stderr on a pseudo-terminal (120 columns); returns the exit
    code, stdout and what the terminal received."""
    import fcntl
    import pty
    import struct
    import termios

    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "pedx_graph.cli", *argv], stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=slave, env=env)
    os.close(slave)
    received = b""
    while True:
        try:
            chunk = os.read(master, 65536)
        except OSError:                  # the child closed the terminal
            break
        if not chunk:
            break
        received += chunk
    os.close(master)
    stdout = proc.stdout.read().decode()
    return proc.wait(timeout=300), stdout, received.decode(errors="replace")


def test_progress_bar_per_track_on_a_terminal_only(tmp_path):
    from scene_fixtures import small_scene

    scene = small_scene(tmp_path / "scene", pedestrians=2, frames=3, seed=0)
    code, stdout, terminal = run_on_a_terminal(["fit", str(scene), "--out", str(tmp_path / "a")])
    assert code == 0 and "fitted 2 of 2 tracks" in stdout
    assert "fit: 100%" in terminal and "2/2" in terminal and "track/s" in terminal
    code, _, terminal = run_on_a_terminal(["fit", str(scene), "--out", str(tmp_path / "b"), "--quiet"])
    assert code == 0 and "fit:" not in terminal
    env = dict(os.environ, PYTHONPATH=str(ROOT))        # stderr to a pipe: no bar either
    done = subprocess.run([sys.executable, "-m", "pedx_graph.cli", "fit", str(scene), "--out", str(tmp_path / "c")],
                          capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0 and "fit:" not in done.stderr and "%|" not in done.stderr
