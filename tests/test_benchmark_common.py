"""The benchmark scripts' shared helpers: the recorded command line and the hardware note (the package's
machine note, :mod:`pedx_graph.environment`, plus the load)."""
from __future__ import annotations

import importlib.util
from importlib.metadata import version
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _common():
    spec = importlib.util.spec_from_file_location("bench_common", ROOT / "benchmarks" / "_common.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_hardware_note_names_the_cpu_and_the_numerical_libraries_a_result_depends_on():
    """Two machines gave different fits of one simulated scene with the same code; the note must tell them
    apart: the installed numpy, scipy and gtsam by version, and the CPU."""
    from pedx_graph.environment import machine_note

    note = _common().hardware()
    for name in ("numpy", "scipy", "gtsam"):
        assert f"{name} {version(name)}" in note, note
    assert "cores" in note and "load average at the end" in note
    assert note.startswith(machine_note())          # one definition, also the experiment runner's record


def test_the_recorded_command_leaves_out_the_output_folder():
    args = ["--seed", "1", "--out", "somewhere", "--out=elsewhere", "--rig", "pedx"]
    assert _common().public_args(args) == ["--seed", "1", "--rig", "pedx"]
