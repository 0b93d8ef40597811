"""The reference of every configuration option, generated from the config dataclasses: ``docs/config.md`` and
``pedx-graph config``.

Each command that reads a YAML config has one top-level dataclass (:data:`COMMAND_CONFIGS`); every other
config class is a section nested in one of them, so one YAML file per command sets everything and the
resolved file saved beside its results holds every section.  An option's documentation is the string
literal right after its field (:func:`field_docs`); the reference lists each option with its type, default
and that text, grouped by section.  ``python tools/gen_config_docs.py`` rewrites ``docs/config.md`` (a test
fails when the file is out of date with the code).
"""
from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import importlib
import inspect
import re
import textwrap
import typing
from dataclasses import dataclass
from typing import Any

import yaml


@dataclass(frozen=True)
class CommandEntry:
    """Where one command's configuration lives, how it is given and where it is saved."""

    name: str
    """Short name (``pedx-graph config NAME``)."""
    target: str
    """``module:Class`` of the top-level dataclass."""
    option: str
    """How it is given on the command line."""
    saved_as: str
    """Where the resolved config is written beside the results."""

    def cls(self) -> type:
        module, name = self.target.split(":")
        return getattr(importlib.import_module(module), name)


#: Every command's top-level config, in the order of the reference.
COMMAND_CONFIGS = (
    CommandEntry("fit", "pedx_graph.graph.config:FitConfig",
                  "`pedx-graph fit|stream|demo|noise --config FILE` (presets: `configs/fit_default.yaml`, "
                  "`configs/ablation_*.yaml`)", "`fit_config.yaml` in the results folder"),
    CommandEntry("stream", "pedx_graph.solvers.stream:StreamConfig",
                  "`pedx-graph stream --stream-config FILE`", "`stream_config.yaml` in the results folder"),
    CommandEntry("simulate", "pedx_graph.sim.config:SimConfig",
                  "`pedx-graph simulate --config FILE` (presets: `configs/sim_default.yaml`, "
                  "`configs/sim_pedx.yaml`)", "`sim_config.yaml` in the simulated dataset"),
    CommandEntry("baseline", "pedx_graph.baselines.run:BaselineConfig",
                  "`pedx-graph baseline --config FILE`", "`baseline_config.yaml` in the results folder"),
    CommandEntry("experiments", "pedx_graph.eval.experiments:ExperimentConfig",
                  "`pedx-graph experiments --config FILE`",
                  "`experiments.json` (key `config`) in the experiment folder"),
    CommandEntry("import", "pedx_graph.detections.importer:ImportConfig",
                  "`pedx-graph import --config FILE`",
                  "`import_config.yaml` in the imported dataset (its labels also carry each keypoint's "
                  "`sigma_px` and `confidence`)"),
    CommandEntry("train-prior", "pedx_graph.priors.train:TrainConfig",
                  "`pedx-graph train-prior --config FILE` (flags given override the file)",
                  "`provenance.json` (key `config`) beside the trained priors"),
)


#: Config classes no command's YAML holds, with the reason: each is built from other options (or flags).
DERIVED = {
    "ReaderConfig": "built by ``FitConfig.reader_config()`` from the fit's ``fps``, ``ground``, "
                    "``calibration_limits`` and ``keypoint_margin`` (its other fields keep their defaults)",
    "NoiseEstimateConfig": "built from the fit's ``noise.keypoint_noise_min_samples`` and "
                           "``noise.lidar_noise_min_samples`` (its other fields keep their defaults)",
    "ReportConfig": "built from the flags of ``pedx-graph report`` (and ``experiments``' ``floor_samples``)",
    "ExportConfig": "built from the flags of ``pedx-graph export``",
}


def command_config(name: str) -> CommandEntry:
    for entry in COMMAND_CONFIGS:
        if entry.name == name:
            return entry
    raise KeyError(f"no command config {name!r} (known: {[c.name for c in COMMAND_CONFIGS]})")


# --- field docstrings --------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=None)
def field_docs(cls: type) -> dict[str, str]:
    """``{field: docstring}`` of a dataclass: the string literal right after each field in its class body
    (base classes first).  A field without one is missing from the dict."""
    docs: dict[str, str] = {}
    for base in reversed(cls.__mro__):
        if base is object or not dataclasses.is_dataclass(base):
            continue
        tree = ast.parse(textwrap.dedent(inspect.getsource(base)))
        body = tree.body[0].body
        for stmt, nxt in zip(body, body[1:]):
            if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name) \
                    and isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant) \
                    and isinstance(nxt.value.value, str):
                docs[stmt.target.id] = inspect.cleandoc(nxt.value.value)
    return docs


_RST_ROLE = re.compile(r":(?:func|class|mod|meth|attr|data|obj|exc):`~?([^`]+)`")


def plain(doc: str) -> str:
    """A docstring on one line, Sphinx roles reduced to code spans (``:class:`X``` -> ```X```)."""
    return " ".join(_RST_ROLE.sub(r"``\1``", doc).split())


def class_doc(cls: type) -> str:
    """The first paragraph of a class docstring, on one line."""
    return plain(inspect.cleandoc(cls.__doc__ or "").split("\n\n")[0])


def _dataclass_arg(tp: Any) -> type | None:
    """The dataclass a field holds: itself, or the element of a ``list[...]`` / ``tuple[..., ...]``."""
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        return tp
    if typing.get_origin(tp) in (list, tuple):
        for arg in typing.get_args(tp):
            if isinstance(arg, type) and dataclasses.is_dataclass(arg):
                return arg
    return None


def _type_name(tp: Any) -> str:
    if isinstance(tp, type) and typing.get_origin(tp) is None:
        return tp.__name__
    return str(tp).replace("typing.", "").replace("NoneType", "None")


@dataclass
class Option:
    """One documented option."""

    path: str
    """Dotted key in the YAML file (``noise.keypoint_sigma_px``; ``scenes[].name`` for list elements)."""
    type: str
    default: Any
    doc: str


@dataclass
class Section:
    """The options of one config class at one place in a command's YAML."""

    path: str
    """Dotted key of the section (``""``: the top level)."""
    cls: type
    options: list[Option]


def sections(cls: type, instance: Any = None, path: str = "") -> list[Section]:
    """Every section (nested config class) of ``cls`` depth first, each with its own options; defaults are
    read from ``instance`` (default: ``cls()``)."""
    from pedx_graph.config import to_dict

    instance = cls() if instance is None else instance
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    own: list[Option] = []
    nested: list[Section] = []
    for f in dataclasses.fields(cls):
        key = f"{path}{f.name}"
        value = getattr(instance, f.name)
        sub = _dataclass_arg(hints[f.name])
        if sub is not None and dataclasses.is_dataclass(value):
            nested += sections(sub, value, f"{key}.")
            continue
        if sub is not None:                           # a list of sections (e.g. the experiment's scenes)
            elements = list(value) if isinstance(value, (list, tuple)) else []
            nested += sections(sub, elements[0] if elements else None, f"{key}[].")
        default = to_dict(instance)[f.name]
        own.append(Option(key, _type_name(hints[f.name]), default, docs.get(f.name, "")))
    return [Section(path.rstrip("."), cls, own)] + nested


def all_config_classes() -> dict[str, type]:
    """Every config class reachable from the commands' top-level configs: ``{class name: class}``."""
    found: dict[str, type] = {}
    for entry in COMMAND_CONFIGS:
        for sec in sections(entry.cls()):
            found.setdefault(sec.cls.__name__, sec.cls)
    return found


# --- renderings -------------------------------------------------------------------------------------------
def _inline(value: Any) -> str:
    return yaml.safe_dump(value, default_flow_style=True, width=10 ** 6).strip().removesuffix("...").strip()


def markdown() -> str:
    """``docs/config.md``: every command's config, every section and option with its default and docstring."""
    lines = ["# Configuration reference", "",
             "Generated from the config dataclasses by `python tools/gen_config_docs.py` "
             "(`pedx-graph config` prints the same); do not edit by hand.", "",
             "Each command reads one YAML file whose keys mirror the sections below (nested sections are nested",
             "mappings; keys left out keep their defaults; an unknown key or a value out of its range is refused",
             "with an error naming the file and the key).  The resolved config, every section and default",
             "included, is saved beside the results.  `pedx-graph config NAME --yaml` prints a complete preset.",
             "Noise values are standard deviations in physical units (px, m, rad), never loss weights.", ""]
    for entry in COMMAND_CONFIGS:
        cls = entry.cls()
        lines += [f"- [`{entry.name}`](#{entry.name}): {class_doc(cls)}"]
    lines += ["", "Built from the options above, not set by a YAML key of their own:", ""]
    lines += [f"- `{name}`: {plain(reason)}" for name, reason in DERIVED.items()]
    lines.append("")
    for entry in COMMAND_CONFIGS:
        cls = entry.cls()
        lines += [f"## {entry.name}", "", f"`{cls.__module__}.{cls.__name__}`: {class_doc(cls)}", "",
                  f"- Given with: {entry.option}", f"- Saved as: {entry.saved_as}", ""]
        for sec in sections(cls):
            title = f"`{sec.path}`" if sec.path else "top level"
            lines += [f"### {entry.name}: {title} ({sec.cls.__name__})", "", class_doc(sec.cls), ""]
            for opt in sec.options:
                doc = plain(opt.doc) or "(undocumented)"
                lines.append(f"- **`{opt.path}`** (`{opt.type}`, default `{_inline(opt.default)}`): {doc}")
            lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def text(name: str | None = None) -> str:
    """Plain-text listing (``pedx-graph config``): every option with its default and docstring."""
    out = []
    for entry in COMMAND_CONFIGS if name is None else (command_config(name),):
        cls = entry.cls()
        out += [f"[{entry.name}] {cls.__name__}: {class_doc(cls)}", f"  given with: {entry.option}",
                f"  saved as:   {entry.saved_as}", ""]
        for sec in sections(cls):
            if sec.path:
                out.append(f"  {sec.path}:  ({sec.cls.__name__}) {class_doc(sec.cls)}")
            for opt in sec.options:
                out.append(f"    {opt.path} = {_inline(opt.default)}   ({opt.type})")
                doc = plain(opt.doc)
                out += textwrap.wrap(doc, 110, initial_indent=" " * 8, subsequent_indent=" " * 8) if doc else []
        out.append("")
    return "\n".join(out).rstrip() + "\n"


def preset_yaml(name: str = "fit") -> str:
    """A complete YAML preset of command ``name`` with every default (loads back to the defaults)."""
    from pedx_graph.config import to_dict

    entry = command_config(name)
    cls = entry.cls()
    header = (f"# Complete {entry.name} config ({cls.__module__}.{cls.__name__}), every option at its default.\n"
              f"# Given with: {entry.option.replace('`', '')}.\n"
              f"# Every option: docs/config.md or `pedx-graph config {entry.name}`.\n")
    return header + yaml.safe_dump(to_dict(cls()), sort_keys=False)


# --- pedx-graph config --------------------------------------------------------------------------------------
def register(subparsers) -> None:
    p = subparsers.add_parser("config", help="print every configuration option with its default and docstring",
                              description="Print every configuration option (all commands, or one) with its "
                                          "default and docstring; --yaml prints a complete preset.")
    p.add_argument("name", nargs="?", default=None, choices=[c.name for c in COMMAND_CONFIGS],
                   help="one command's config (default: every command; with --yaml: fit)")
    fmt = p.add_mutually_exclusive_group()
    fmt.add_argument("--yaml", action="store_true", help="print a complete YAML preset with every default")
    fmt.add_argument("--markdown", action="store_true", help="print the reference as Markdown (docs/config.md)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.yaml:
        print(preset_yaml(args.name or "fit"), end="")
    elif args.markdown:
        print(markdown(), end="")
    else:
        print(text(args.name), end="")
    return 0
