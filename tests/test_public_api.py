"""The public API of ``pedx_graph``: every name of ``__all__`` resolves to a documented object, and
``import pedx_graph`` stays light (no GTSAM, no Dask, no submodule until a name is used)."""
from __future__ import annotations

import dataclasses
import inspect
import os
import subprocess
import sys
from pathlib import Path

import pytest

import pedx_graph

ROOT = Path(__file__).resolve().parents[1]
PUBLIC = [name for name in pedx_graph.__all__ if name != "__version__"]


def test_import_loads_no_heavy_module():
    code = ("import sys, pedx_graph; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('dask', 'distributed', 'gtsam', 'scipy', "
            "'numpy', 'factors') or m.startswith('pedx_graph.')))")
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_the_promised_names_are_public():
    promised = {"read_dataset", "fit_track", "fit_dataset", "StreamingEstimator", "BodyModel", "simulate",
                "FitConfig", "NoiseConfig", "TermsConfig", "SolverConfig", "StreamConfig", "SimConfig",
                "GroundConfig", "ReaderConfig", "load_config", "__version__"}
    assert promised <= set(pedx_graph.__all__)
    assert len(set(pedx_graph.__all__)) == len(pedx_graph.__all__)


@pytest.mark.parametrize("name", PUBLIC)
def test_every_public_name_resolves_and_is_documented(name):
    obj = getattr(pedx_graph, name)
    assert obj is getattr(pedx_graph, name)                 # cached after the first access
    assert name in dir(pedx_graph)
    doc = inspect.getdoc(obj) or ""
    # a dataclass without a docstring gets its signature as __doc__: that is not documentation
    assert doc.strip() and not doc.startswith(f"{name}("), f"{name} has no docstring"
    assert obj.__module__.startswith("pedx_graph."), obj.__module__


def test_config_classes_are_dataclasses_with_field_docs():
    """Each config dataclass of the public API documents every field (the attribute docstring below it)."""
    import ast

    for name in PUBLIC:
        obj = getattr(pedx_graph, name)
        if not (inspect.isclass(obj) and dataclasses.is_dataclass(obj) and name.endswith(("Config", "Limits"))):
            continue
        tree = ast.parse(inspect.getsource(obj))
        body = tree.body[0].body
        documented = {stmt.target.id for stmt, nxt in zip(body, body[1:])
                      if isinstance(stmt, ast.AnnAssign) and isinstance(nxt, ast.Expr)
                      and isinstance(getattr(nxt, "value", None), ast.Constant) and isinstance(nxt.value.value, str)}
        fields = {f.name for f in dataclasses.fields(obj)}
        assert fields <= documented, f"{name}: undocumented fields {sorted(fields - documented)}"


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no_such_thing"):
        pedx_graph.no_such_thing  # noqa: B018


def test_version_is_a_release_string():
    parts = pedx_graph.__version__.split(".")
    assert len(parts) == 3 and all(p.isdigit() for p in parts)
