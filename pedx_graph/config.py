"""Configuration as nested dataclasses, loaded from YAML presets and saved beside every result.

Every config class is a dataclass whose fields carry a docstring (the string literal right after the
field).  :func:`load_config` fills one from a YAML file (unknown keys are an error naming the file and the
key), :func:`save_config` writes the resolved config (every field, defaults included) atomically.
"""
from __future__ import annotations

import dataclasses
import os
import types
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml

from pedx_graph.config_ranges import ConfigError, check_config
from pedx_graph.utils import atomic_write_text, to_jsonable

T = TypeVar("T")


def _is_dataclass_type(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _field_default(f: dataclasses.Field) -> Any:
    """A dataclass field's default value (its factory called), or None without one."""
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None if f.default is dataclasses.MISSING else f.default


def from_dict(cls: type[T], data: dict | None, *, source: str = "<dict>", prefix: str = "", base: T | None = None) -> T:
    """Build dataclass ``cls`` from a nested dict; missing fields keep their defaults: ``base``'s values when
    given, else the class's.  A nested dataclass field starts from its parent's default for it (e.g. the
    association's own per-camera tracker settings, not ``TrackerConfig``'s class defaults), so a preset that
    sets one of its fields changes that field alone."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: '{prefix or '<root>'}' must be a mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - names, key=str)       # YAML keys may be numbers, null, ...
    if unknown:
        raise ConfigError(f"{source}: unknown config key '{prefix}{unknown[0]}' (known: {sorted(names)})")
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name not in data:
            continue
        value = data[f.name]
        tp = hints.get(f.name)
        if _is_dataclass_type(tp):
            nested = getattr(base, f.name) if base is not None else _field_default(f)
            kwargs[f.name] = from_dict(tp, value, source=source, prefix=f"{prefix}{f.name}.",
                                       base=nested if isinstance(nested, tp) else None)
        else:
            kwargs[f.name] = _coerce(value, tp, source, f"{prefix}{f.name}")
    try:
        return dataclasses.replace(base, **kwargs) if base is not None else cls(**kwargs)
    except (TypeError, ValueError) as exc:           # a class's own check of its fields (``__post_init__``)
        raise ConfigError(f"{source}: '{prefix.rstrip('.') or '<root>'}': {exc}") from None


def _list_element(tp: Any) -> type | None:
    """The dataclass of the elements of ``list[X]`` / ``tuple[X, ...]`` (None for anything else)."""
    args = typing.get_args(tp)
    if typing.get_origin(tp) in (list, tuple) and args and _is_dataclass_type(args[0]) \
            and (typing.get_origin(tp) is list or args[1:] in ((), (Ellipsis,))):
        return args[0]
    return None


def _coerce(value: Any, tp: Any, source: str, key: str) -> Any:
    origin = typing.get_origin(tp)
    try:
        if origin is typing.Union or origin is types.UnionType:    # e.g. ``tuple[float, float] | None``
            args = typing.get_args(tp)
            if value is None and type(None) in args:
                return None
            for arg in args:
                if arg is not type(None):
                    try:
                        return _coerce(value, arg, source, key)
                    except ConfigError:
                        pass
            raise TypeError
        if tp is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        if tp is int and isinstance(value, int) and not isinstance(value, bool):
            if not -2 ** 63 <= value < 2 ** 63:     # what numpy and the solvers can hold
                raise ConfigError(f"{source}: config key '{key}' is out of the 64-bit integer range")
            return value
        if tp is bool and isinstance(value, bool):
            return value
        if tp is str and isinstance(value, str):
            return value
        if tp in (tuple, list) and isinstance(value, (list, tuple)):       # bare ``tuple`` / ``list``
            return tp(value)
        element = _list_element(tp)
        if element is not None and isinstance(value, (list, tuple)):   # a list of sections
            items = [v if isinstance(v, element) else from_dict(element, v, source=source, prefix=f"{key}[{i}].")
                     for i, v in enumerate(value)]
            return tuple(items) if origin is tuple else items
        if origin is dict and isinstance(value, dict) and len(typing.get_args(tp)) == 2 \
                and _is_dataclass_type(typing.get_args(tp)[1]):             # named sections
            element = typing.get_args(tp)[1]
            return {k: v if isinstance(v, element) else from_dict(element, v, source=source, prefix=f"{key}.{k}.")
                    for k, v in value.items()}
        if origin in (tuple,) and isinstance(value, (list, tuple)):
            args = typing.get_args(tp)
            if len(args) == 2 and args[1] is Ellipsis:
                return tuple(_coerce(v, args[0], source, key) for v in value)
            if len(value) != len(args):
                raise TypeError
            return tuple(_coerce(v, a, source, key) for v, a in zip(value, args))
        if origin in (list,) and isinstance(value, (list, tuple)):
            (arg,) = typing.get_args(tp) or (Any,)
            return [_coerce(v, arg, source, key) for v in value]
        if tp in (Any, None):
            return value
        if tp in (float, int, bool, str) or origin in (tuple, list):
            raise TypeError
        return value
    except (TypeError, OverflowError):          # OverflowError: an integer beyond the float range
        pass
    raise ConfigError(f"{source}: config key '{key}' must be {getattr(tp, '__name__', tp)}, got {value!r}")


def read_yaml(path: str | os.PathLike) -> Any:
    """The parsed content of a YAML file (None when empty); :class:`ConfigError` naming the file, in one line,
    when it cannot be read or parsed."""
    path = Path(path)
    try:
        return yaml.safe_load(path.read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise ConfigError(f"{path}: config file not found") from exc
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config file ({exc.strerror or exc})") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not valid YAML (not UTF-8 text: {exc.reason} at byte {exc.start})") from exc
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({_yaml_problem(exc)})") from exc
    except RecursionError as exc:
        raise ConfigError(f"{path}: not valid YAML (nested too deeply)") from exc


def _yaml_problem(exc: yaml.YAMLError) -> str:
    """YAML's own message spans several lines with a source excerpt: its problem and position on one line."""
    problem, mark = getattr(exc, "problem", None), getattr(exc, "problem_mark", None)
    if problem and mark is not None:
        context = getattr(exc, "context", None)
        text = f"{context + ': ' if context else ''}{problem} at line {mark.line + 1}, column {mark.column + 1}"
    else:
        text = str(exc)
    return " ".join(text.split())


def load_config(cls: type[T], path: str | os.PathLike | None = None) -> T:
    """Load ``cls`` from a YAML file (``None``: all defaults), every value's range checked
    (:func:`pedx_graph.config_ranges.check_config`: :class:`ConfigError` naming the file and the key)."""
    if path is None:
        return check_config(cls(), "<defaults>")
    data = read_yaml(path)
    return check_config(from_dict(cls, {} if data is None else data, source=str(path)), str(path))


def to_dict(cfg: Any) -> dict:
    """The resolved config as a plain nested dict."""
    return to_jsonable(dataclasses.asdict(cfg))


def save_config(cfg: Any, path: str | os.PathLike) -> Path:
    """Save the resolved config (all fields) as YAML, atomically."""
    return atomic_write_text(path, yaml.safe_dump(to_dict(cfg), sort_keys=False))
