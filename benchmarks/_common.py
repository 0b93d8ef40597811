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


#: The numerical libraries whose versions a result depends on (a fit's LM can end in another minimum when a
#: library changes a number in its last digits), in the hardware note.
_LIBRARIES = ("numpy", "scipy", "gtsam", "scikit-learn", "opencv-python-headless", "trimesh")


def _cpu() -> str:
    """The CPU's name: ``platform.processor()``, else the first ``model name`` of /proc/cpuinfo (Linux)."""
    name = platform.processor()
    if not name and os.path.exists("/proc/cpuinfo"):
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            name = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), "")
    return name or "unknown cpu"


def _libraries() -> str:
    """``name version`` of each installed library of :data:`_LIBRARIES`, comma-separated."""
    from importlib.metadata import PackageNotFoundError, version

    found = []
    for name in _LIBRARIES:
        try:
            found.append(f"{name} {version(name)}")
        except PackageNotFoundError:
            continue
    return ", ".join(found)


def hardware() -> str:
    """Machine, cores, CPU, Python, the numerical libraries' versions and the load average now (benchmarks
    run on a shared machine)."""
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    return (f"{platform.machine()}, {os.cpu_count()} cores, {_cpu()}, Python {platform.python_version()}, "
            f"{platform.system()}; {_libraries()}; load average at the end {load} "
            "(a shared machine: other jobs may have run beside the benchmark)")


def cell(value, spec: str = ".1f") -> str:
    """A markdown table cell: ``value`` formatted with ``spec``, or ``-`` when it is None or not finite."""
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return format(value, spec)
