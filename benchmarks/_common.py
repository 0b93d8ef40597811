"""Helpers shared by the benchmark scripts: the command line as recorded, a hardware note, table cells, seed lists."""
from __future__ import annotations

import math
import os


def public_args(args: list[str]) -> list[str]:
    """The command-line arguments without ``--out DIR`` (no machine paths in the written results)."""
    out, skip = [], False
    for a in args:
        if skip:
            skip = False
            continue
        if a == "--out":
            skip = True
            continue
        if not a.startswith("--out="):
            out.append(a)
    return out


def hardware() -> str:
    """The machine, CPU, Python and numerical libraries (:func:`pedx_graph.environment.machine_note`) and the
    load average now (benchmarks run on a shared machine)."""
    from pedx_graph.environment import machine_note

    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    return (f"{machine_note()}; load average at the end {load} "
            "(a shared machine: other jobs may have run beside the benchmark)")


def cell(value, spec: str = ".1f") -> str:
    """A markdown table cell: ``value`` formatted with ``spec``, or ``-`` when it is None or not finite."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return format(value, spec)


def parse_seeds(text: str) -> list[int]:
    """``"0-8,17-21"`` -> [0, ..., 8, 17, ..., 21] (comma-separated seeds and inclusive ranges)."""
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        first, _, last = part.partition("-")
        try:
            seeds.extend(range(int(first), int(last or first) + 1))
        except ValueError:
            raise ValueError(f"--seeds: {part!r} is neither a seed nor a range like 17-21") from None
    if not seeds:
        raise ValueError(f"--seeds: no seed in {text!r}")
    return seeds


def rows_per_seed(run_seed, seeds: list[int], workers: int, *args) -> list[dict]:
    """``run_seed(seed, *args)`` for every seed in ``workers`` processes (one seed each), its rows joined in
    seed order."""
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(max_workers=max(1, workers)) as pool:
        per_seed = list(pool.map(run_seed, seeds, *[[a] * len(seeds) for a in args]))
    return [row for rows in per_seed for row in rows]


def write_outputs(out_dir, name: str, result: dict, markdown_text: str) -> None:
    """``<name>.json`` and ``<name>.md`` into ``out_dir`` (created; each written atomically), and the markdown up
    to its per-input tables printed."""
    from pathlib import Path

    from pedx_graph.utils import atomic_write_json, atomic_write_text

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / f"{name}.json", result)
    atomic_write_text(out / f"{name}.md", markdown_text)
    print(markdown_text.split("## Per input")[0])
