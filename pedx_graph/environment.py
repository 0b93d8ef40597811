"""What a result was computed on: the machine, its CPU, Python and the numerical libraries' versions.

A fit's LM can end in another minimum when a library changes a number in its last digits, so two machines
may give different results for one seeded run; every recorded result names its environment with
:func:`machine_note` (the experiment runner's record, the benchmarks' hardware note).
"""
from __future__ import annotations

import os
import platform
from importlib.metadata import PackageNotFoundError, version

#: The numerical libraries whose versions a result depends on.
LIBRARIES = ("numpy", "scipy", "gtsam", "scikit-learn", "opencv-python-headless", "trimesh")


def cpu_name() -> str:
    """The CPU's name: ``platform.processor()``, else the first ``model name`` of /proc/cpuinfo (Linux), else
    ``unknown cpu``."""
    name = platform.processor()
    if not name and os.path.exists("/proc/cpuinfo"):
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            name = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), "")
    return name or "unknown cpu"


def library_versions() -> str:
    """``name version`` of each installed library of :data:`LIBRARIES`, comma-separated."""
    found = []
    for name in LIBRARIES:
        try:
            found.append(f"{name} {version(name)}")
        except PackageNotFoundError:
            continue
    return ", ".join(found)


def machine_note() -> str:
    """One line: architecture, cores, CPU, Python, operating system; the libraries' versions."""
    return (f"{platform.machine()}, {os.cpu_count()} cores, {cpu_name()}, Python {platform.python_version()}, "
            f"{platform.system()}; {library_versions()}")
