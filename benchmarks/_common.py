"""Helpers shared by the benchmark scripts: the command line as recorded, a hardware note, table cells."""
from __future__ import annotations

import math
import os
import platform


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
    """Machine, cores, Python and the load average now (benchmarks run on a shared machine)."""
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    return (f"{platform.machine()}, {os.cpu_count()} cores, {platform.processor() or 'unknown cpu'}, "
            f"Python {platform.python_version()}, {platform.system()}; load average at the end {load} "
            "(a shared machine: other jobs may have run beside the benchmark)")


def cell(value, spec: str = ".1f") -> str:
    """A markdown table cell: ``value`` formatted with ``spec``, or ``-`` when it is None or not finite."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return format(value, spec)
