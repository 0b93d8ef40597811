"""The package's layers and import cycles, read from the source with ``ast`` (nothing is imported).

Layers, lowest first (a module may import its own layer and those below, never one above):

    utils, small_arrays, environment, keypoints, config, config_ranges   <  data, motion   <  execution   <  body
    <  priors   <  factors   <  graph   <  detections   <  solvers   <  eval, baselines, export, preflight   <  sim
    <  demo, experiment_runner, config_reference, every ``*cli`` module

``execution`` (running one task per track, writing results) knows tracks and outputs but no solver: the
solvers' dataset drivers (``fit_dataset``, ``stream_dataset``) use it.  A command-line module
(``*cli.py``) sits on top whatever its package.  Imports inside functions count like any other: a cycle
hidden by a lazy import is still a cycle (a child module importing its own package's ``__init__`` is not
an edge: Python initialises the parent first).
"""
from __future__ import annotations

import ast
import functools
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

RANKS = {
    "utils": 0, "small_arrays": 0, "environment": 0, "keypoints": 0, "config": 0, "config_ranges": 0,
    "data": 1, "motion": 1,
    "execution": 2,
    "body": 3,
    "priors": 4,
    "factors": 5,
    "graph": 6,
    "detections": 7,
    "solvers": 8,
    "eval": 9, "baselines": 9, "export": 9, "preflight": 9,
    "sim": 10,
    "demo": 11, "experiment_runner": 11, "cli": 11, "config_reference": 11,
}


def modules() -> dict[str, Path]:
    """Dotted name -> file of every module of ``pedx_graph`` and ``factors``."""
    out = {}
    for base in ("pedx_graph", "factors"):
        for path in sorted((ROOT / base).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


def import_edges(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the project modules it imports (at module level or inside functions)."""

    def resolve(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    edges: dict[str, set[str]] = {m: set() for m in mods}
    for mod, path in mods.items():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                targets = [resolve(f"{node.module}.{a.name}") for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [resolve(a.name) for a in node.names]
            else:
                continue
            for target in targets:
                # the package itself (its lazy public API) and a module's own parent packages are not edges
                if target and target != mod and target != "pedx_graph" and not mod.startswith(target + "."):
                    edges[mod].add(target)
    return edges


@functools.lru_cache(maxsize=1)
def project_edges() -> dict[str, frozenset[str]]:
    """:func:`import_edges` of the project (parsed once per test session)."""
    return {m: frozenset(t) for m, t in import_edges(modules()).items()}


def layer(mod: str) -> tuple[str, int]:
    parts = mod.split(".")
    if parts[-1].endswith("cli") or parts[-1] == "__main__":
        return "cli", RANKS["cli"]
    name = "factors" if parts[0] == "factors" else (parts[1] if len(parts) > 1 else "cli")
    assert name in RANKS, f"{mod}: give package {name!r} a layer in tests/test_layers.py"
    return name, RANKS[name]


def cycles(edges: dict[str, set[str]]) -> list[set[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index, low, on_stack, stack, out, counter = {}, {}, set(), [], [], [0]
    for start in edges:
        if start in index:
            continue
        work = [(start, iter(sorted(edges[start])))]
        index[start] = low[start] = counter[0]
        counter[0] += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = counter[0]
                    counter[0] += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges.get(child, ())))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = set()
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.add(member)
                    if member == node:
                        break
                if len(component) > 1:
                    out.append(component)
    return out


def test_no_module_imports_a_higher_layer():
    edges = project_edges()
    upward = sorted((a, b) for a, targets in edges.items() for b in targets if layer(b)[1] > layer(a)[1])
    assert not upward, "upward imports (module -> module of a higher layer): " + "; ".join(
        f"{a} ({layer(a)[0]}) -> {b} ({layer(b)[0]})" for a, b in upward)


def test_no_import_cycle_even_inside_functions():
    found = [sorted(c) for c in cycles(project_edges())]
    assert not found, f"import cycles: {found}"


def test_the_checks_see_a_planted_cycle_and_an_upward_import(tmp_path):
    """The checkers themselves, on planted files: a cycle through an import inside a function, and an
    upward import (graph -> solvers)."""
    (tmp_path / "fit.py").write_text("def fit_result():\n    from pedx_graph.solvers.admm import fit_track_admm\n")
    (tmp_path / "admm.py").write_text("from pedx_graph.solvers.fit import TrackResult\n")
    (tmp_path / "build.py").write_text("import numpy\n\nclass P:\n    def layout(self):\n"
                                       "        from pedx_graph.solvers.chain import ChainLayout\n")
    (tmp_path / "chain.py").write_text("import numpy\n")
    planted = {"pedx_graph.solvers.fit": tmp_path / "fit.py", "pedx_graph.solvers.admm": tmp_path / "admm.py",
               "pedx_graph.graph.build": tmp_path / "build.py", "pedx_graph.solvers.chain": tmp_path / "chain.py"}
    edges = import_edges(planted)
    assert cycles(edges) == [{"pedx_graph.solvers.fit", "pedx_graph.solvers.admm"}]
    assert edges["pedx_graph.graph.build"] == {"pedx_graph.solvers.chain"}
    assert layer("pedx_graph.solvers.chain")[1] > layer("pedx_graph.graph.build")[1]


def test_solvers_and_the_layers_below_them_import_no_command_line_module():
    edges = project_edges()
    bad = sorted((a, b) for a, targets in edges.items() for b in targets
                 if layer(a)[1] <= RANKS["solvers"] and layer(b)[0] == "cli")
    assert not bad, f"a library module imports a command-line module: {bad}"
