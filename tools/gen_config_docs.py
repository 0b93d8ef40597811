"""Write ``docs/config.md``, the reference of every configuration option, from the config dataclasses.

Run from the repository root after changing a config field or its docstring::

    python tools/gen_config_docs.py [--check]

``--check`` writes nothing and exits with 1 when the file is out of date (``tests/test_config_all.py`` checks
the same).  The text comes from :func:`pedx_graph.config_reference.markdown` (``pedx-graph config --markdown``).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from pedx_graph.config_reference import markdown  # noqa: E402
from pedx_graph.utils import atomic_write_text  # noqa: E402

DOC = ROOT / "docs" / "config.md"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 when docs/config.md is out of date")
    args = parser.parse_args(argv)
    text = markdown()
    current = DOC.read_text(encoding="utf-8") if DOC.is_file() else ""
    if args.check:
        if current != text:
            print(f"{DOC.relative_to(ROOT)} is out of date: run python tools/gen_config_docs.py", file=sys.stderr)
            return 1
        return 0
    if current != text:
        atomic_write_text(DOC, text)
        print(f"wrote {DOC.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
