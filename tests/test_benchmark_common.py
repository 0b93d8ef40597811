"""The benchmark scripts' shared helpers: the recorded command line and the hardware note (the package's
machine note, :mod:`pedx_graph.environment`, plus the load)."""
from __future__ import annotations

import importlib.util
from importlib.metadata import version
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _load(name: str, path: Path):
    """The script at ``path`` imported as module ``name`` (benchmarks/ and tools/ are not packages)."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _common():
    return _load("bench_common", ROOT / "benchmarks" / "_common.py")


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


def test_parse_seeds_reads_seeds_and_inclusive_ranges():
    parse = _common().parse_seeds
    assert parse("0-2,17,20-21") == [0, 1, 2, 17, 20, 21]
    for bad in ("a", "3-x", ","):
        try:
            parse(bad)
        except ValueError as exc:
            assert "--seeds" in str(exc)
        else:
            raise AssertionError(f"{bad!r} was accepted")


def _rerun():
    return _load("rerun_results", ROOT / "tools" / "rerun_results.py")


def test_every_recorded_command_can_be_run_again_where_its_result_lies():
    """tools/rerun_results.py: each committed result's command names an existing benchmark script, gets
    ``--out`` its own folder when that is not the scripts' default, and a bare ``--baseline`` file resolved
    beside it."""
    rerun = _rerun()
    commands = [(path, command) for path, command in rerun.recorded() if command]
    assert len(commands) >= 20
    for path, command in commands:
        argv = rerun.rerun_argv(path, command)
        assert (ROOT / argv[1]).is_file(), f"{path}: {argv[1]} does not exist"
        if path.parent == rerun.RESULTS:
            assert "--out" not in argv
        else:
            assert argv[argv.index("--out") + 1] == str(path.parent.relative_to(ROOT))
    path = rerun.RESULTS / "some" / "bench_x.json"
    argv = rerun.rerun_argv(path, "python benchmarks/bench_x.py --seed 3 --baseline old.json")
    assert argv[2:] == ["--seed", "3", "--baseline", "benchmarks/results/some/old.json",
                        "--out", "benchmarks/results/some"]
