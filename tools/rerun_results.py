"""List, and on request rerun, the commands behind the committed benchmark results.

Every result JSON under ``benchmarks/results`` records the command that wrote it (``"command"``, without
``--out``).  This lists each with the folder it was written to and runs them again there, in order, when asked
(``--run``; ``--match REGEX`` picks some by their path or command) — e.g. after a change to the simulator that
changes every simulated scene.  A ``--baseline NAME`` the command names by file name alone is looked for in
the result's folder.  Results without a recorded command are listed as such (their scripts' docstrings say
how they were made).

    python tools/rerun_results.py [--match REGEX] [--run] [--dry-run]
"""
from __future__ import annotations

import argparse
import json
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def recorded(results: Path = RESULTS) -> list[tuple[Path, str | None]]:
    """(result JSON, its recorded command or None) for every result under ``results``, sorted by path."""
    out = []
    for path in sorted(results.rglob("*.json")):
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        command = data.get("command") if isinstance(data, dict) else None
        out.append((path, command if isinstance(command, str) and command.startswith("python ") else None))
    return out


def rerun_argv(path: Path, command: str, results: Path = RESULTS) -> list[str]:
    """The argv that writes ``path`` again: ``command`` with ``--out`` the result's folder (when it is not the
    scripts' default ``benchmarks/results``) and a bare ``--baseline NAME`` resolved in that folder."""
    argv = shlex.split(command)
    argv[0] = sys.executable
    for i, arg in enumerate(argv[:-1]):
        if arg == "--baseline" and not Path(argv[i + 1]).is_absolute() and "/" not in argv[i + 1]:
            argv[i + 1] = str((path.parent / argv[i + 1]).relative_to(ROOT))
    if path.parent != results:
        argv += ["--out", str(path.parent.relative_to(ROOT))]
    return argv


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--match", default="", help="only results whose path or command matches this regex")
    parser.add_argument("--run", action="store_true", help="run the selected commands, one after the other")
    parser.add_argument("--dry-run", action="store_true", help="with --run: print the argv only")
    args = parser.parse_args(argv)
    pattern = re.compile(args.match)
    failed = 0
    for path, command in recorded():
        name = str(path.relative_to(ROOT))
        if not (pattern.search(name) or (command and pattern.search(command))):
            continue
        if command is None:
            print(f"{name}: no command recorded")
            continue
        call = rerun_argv(path, command)
        print(f"{name}: {shlex.join(['python'] + call[1:])}", flush=True)
        if args.run and not args.dry_run:
            t0 = time.perf_counter()
            code = subprocess.run(call, cwd=ROOT, stdout=subprocess.DEVNULL).returncode
            failed += code != 0
            print(f"  exit {code}, {time.perf_counter() - t0:.0f} s", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
