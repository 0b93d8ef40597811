"""Start-up checks of a command, before it creates any output: the dataset folder, the config's value ranges and
the files it names (body model, pose and temporal priors), each loaded once.

A bad input then ends the command with one line naming the path or the config key (``pedx_graph.cli`` prints
it), instead of an empty results folder, a ``fit_config.yaml`` of a run that never ran, or the same
``BadZipFile`` once per track from every worker.
"""
from __future__ import annotations

import os
import zipfile
from pathlib import Path

from pedx_graph.config import ConfigError
from pedx_graph.config_ranges import check_config


def check_dataset(dataset: str | os.PathLike) -> Path:
    """The dataset's root (the folder holding ``labels/``) when it has ``labels/2d`` and ``calib/`` folders;
    :class:`~pedx_graph.data.types.DataFormatError` naming the path otherwise."""
    from pedx_graph.data.reader import resolve_root
    from pedx_graph.data.types import DataFormatError

    root = resolve_root(dataset)
    for sub in ("calib", "labels/2d"):
        if not (root / sub).is_dir():
            raise DataFormatError(root / sub, None, "folder missing (a PedX dataset holds calib/ and labels/2d/)")
    return root


def _load(where: str, loader, path=None):
    """``loader()``; a missing or unreadable file becomes a :class:`ConfigError` saying ``where`` it was named
    and, when the loader's message does not, the file ``path``."""
    try:
        return loader()
    except ConfigError:
        raise
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if path and str(path) not in text:
            text = f"{path}: {text}"
        raise ConfigError(f"{where}: {text}") from exc


def _key(source: str, key: str) -> str:
    return f"{source}: config key '{key}'"


def check_fit_setup(config, dataset: str | os.PathLike | None = None, source: str = "<config>"):
    """Check a :class:`~pedx_graph.graph.config.FitConfig` and the dataset before a ``fit`` / ``stream`` /
    ``noise`` run: value ranges, then the body model and both priors loaded (and the estimator context built
    from them, e.g. ``chamfer_vertices`` against the model); returns the context (reuse it or drop it)."""
    from pedx_graph.body import BodyModel
    from pedx_graph.graph.build import EstimatorContext
    from pedx_graph.priors import load_pose_prior, load_temporal_prior

    check_config(config, source)
    if dataset is not None:
        check_dataset(dataset)
    _load(_key(source, "body_model"), lambda: BodyModel.load(config.body_model or None), config.body_model)
    _load(_key(source, "pose_prior"), lambda: load_pose_prior(config.pose_prior or None), config.pose_prior)
    _load(_key(source, "temporal_prior"), lambda: load_temporal_prior(config.temporal_prior or None),
          config.temporal_prior)
    if config.keypoint_sets:
        from pedx_graph.body.keypoint_defs import read_keypoint_set_folder
        _load(_key(source, "keypoint_sets"), lambda: read_keypoint_set_folder(config.keypoint_sets),
              config.keypoint_sets)
    return _load(source, lambda: EstimatorContext.create(config))


def check_baseline_setup(config, name: str, dataset: str | os.PathLike | None = None, source: str = "<config>"):
    """Check a :class:`~pedx_graph.baselines.run.BaselineConfig` before baseline ``name`` runs: value ranges,
    the body model, and the shipped pose prior for ``smplify_disp``."""
    from pedx_graph.body import BodyModel
    from pedx_graph.priors import load_pose_prior

    check_config(config, source)
    if dataset is not None:
        check_dataset(dataset)
    _load(_key(source, "body_model"), lambda: BodyModel.load(config.body_model or None), config.body_model)
    if name == "smplify_disp":
        _load("the shipped pose prior", load_pose_prior)


def check_model_file(path: str | os.PathLike | None, option: str = "--model") -> None:
    """Load the body model ``path`` (None: the shipped one) once; :class:`ConfigError` naming ``option``."""
    from pedx_graph.body import BodyModel

    _load(f"option {option}", lambda: BodyModel.load(path), path)
