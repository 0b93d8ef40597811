"""Run a baseline on one track or on a whole dataset, writing results exactly as ``pedx-graph fit`` does.

``run_baseline(name, track, model)`` -> :class:`~pedx_graph.solvers.fit.TrackResult`;
``fit_dataset_baseline(dataset, out, name, workers)``: every track of every sequence (process pool over
tracks, the body model and the pose prior loaded once per worker), results in the PedX SMPL layout under
``out`` (with our ``keypoints_3d`` field, which the evaluation uses), ``summary.json`` and the resolved
``baseline_config.yaml`` beside them.  One failing track is reported in the summary and never stops the run.
"""
from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pedx_graph.baselines.smplify_disparity import SmplifyDispConfig
from pedx_graph.config import save_config
from pedx_graph.data.types import Track
from pedx_graph.solvers.fit import map_tracks, track_failure

log = logging.getLogger(__name__)

#: Baseline names accepted by :func:`run_baseline` and the ``baseline`` command.
BASELINES: tuple[str, ...] = ("triangulation", "left_disp", "smplify_disp")


@dataclass
class BaselineConfig:
    """Settings of the baselines (the keypoint baselines have none besides the body model)."""

    body_model: str = ""
    """Path of an SMPL-format model file; empty: the shipped open model.  Fills never-seen joints of the
    keypoint baselines and is the body fitted by ``smplify_disp``."""
    smplify: SmplifyDispConfig = field(default_factory=SmplifyDispConfig)
    """Settings of the ``smplify_disp`` baseline."""


def _check_name(name: str) -> str:
    if name not in BASELINES:
        raise ValueError(f"unknown baseline {name!r}; choose one of {', '.join(BASELINES)}")
    return name


def load_pose_mixture(covariance_scale: float = 1.0):
    """The shipped GMM pose prior as a ``MaxMixture`` and its template body pose (the component mean
    nearest the rest pose, as the graph's initialisation uses)."""
    from factors.common import MaxMixture
    from pedx_graph.graph.build import neutral_template
    from pedx_graph.priors import load_pose_prior

    prior = load_pose_prior()
    mixture = MaxMixture.from_gmm(prior, covariance_scale=covariance_scale)
    return mixture, neutral_template(prior.means)


def run_baseline(name: str, track: Track, model, config: BaselineConfig | None = None,
                 pose_mixture=None, template_body_pose: np.ndarray | None = None):
    """Run baseline ``name`` (one of :data:`BASELINES`) on ``track`` with body model ``model``.

    ``smplify_disp`` needs the pose prior: pass ``pose_mixture`` (a ``factors.common.MaxMixture``) and
    optionally ``template_body_pose`` (69,), else the shipped prior is loaded.
    """
    from pedx_graph.baselines.left_disparity import left_disparity_baseline
    from pedx_graph.baselines.smplify_disparity import smplify_disparity_baseline
    from pedx_graph.baselines.triangulation import triangulation_baseline

    config = config or BaselineConfig()
    if _check_name(name) == "triangulation":
        return triangulation_baseline(track, model)
    if name == "left_disp":
        return left_disparity_baseline(track, model)
    if pose_mixture is None:
        pose_mixture, template = load_pose_mixture(config.smplify.pose_prior_covariance_scale)
        template_body_pose = template if template_body_pose is None else template_body_pose
    return smplify_disparity_baseline(track, model, pose_mixture, template_body_pose, config.smplify)


# --- per-process state (body model and prior loaded once per worker) ------------------------------------
_WORKER: dict = {}


def _worker_state(name: str, config: BaselineConfig) -> dict:
    key = (config.body_model, name == "smplify_disp", config.smplify.pose_prior_covariance_scale)
    if _WORKER.get("key") != key:
        from pedx_graph.body import BodyModel

        state = {"model": BodyModel.load(config.body_model or None), "mixture": None, "template": None}
        if name == "smplify_disp":
            state["mixture"], state["template"] = load_pose_mixture(config.smplify.pose_prior_covariance_scale)
        _WORKER.clear()
        _WORKER.update(key=key, state=state)
    return _WORKER["state"]


def _run_one(args):
    name, track, config = args
    try:
        state = _worker_state(name, config)
        return run_baseline(name, track, state["model"], config, state["mixture"], state["template"]), None
    except Exception as exc:  # one bad track never kills the run
        return None, track_failure(track, exc)


def run_tracks(name: str, tracks: list[Track], config: BaselineConfig, workers: int = 1):
    """Run baseline ``name`` on tracks (process pool when ``workers > 1``); yields (result, error) in order."""
    _check_name(name)
    yield from map_tracks(_run_one, [(name, tr, config) for tr in tracks], workers)


def fit_dataset_baseline(dataset: str | os.PathLike, out: str | os.PathLike, name: str, workers: int = 1,
                         config: BaselineConfig | None = None, sequences: list[str] | None = None) -> dict:
    """Run baseline ``name`` on every track of ``dataset``; results under ``out``; returns the summary.

    Same layout and summary fields as :func:`pedx_graph.solvers.fit.fit_dataset`, plus ``baseline`` and
    each track's baseline extras (e.g. how many keypoints were filled).
    """
    from pedx_graph.data.reader import read_dataset
    from pedx_graph.solvers.fit import sequence_grounds, write_outcomes

    _check_name(name)
    config = config or BaselineConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    save_config(config, out / "baseline_config.yaml")
    t0 = time.perf_counter()
    tracks = read_dataset(dataset, sequences=sequences)
    summary = {"dataset": str(dataset), "baseline": name, "tracks": [], "failed": [], "workers": workers,
               "ground": sequence_grounds(tracks)}
    return write_outcomes(run_tracks(name, tracks, config, workers), out, summary, t0)
