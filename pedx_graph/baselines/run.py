"""Run a baseline on one track or on a whole dataset, writing results exactly as ``pedx-graph fit`` does.

``run_baseline(name, track, model)`` -> :class:`~pedx_graph.solvers.fit.TrackResult`;
``fit_dataset_baseline(dataset, out, name, workers)``: every track of every sequence as one task each
(:func:`baseline_task`, run by :mod:`pedx_graph.execution` in this process, on a local process pool or a Dask
cluster; the body model and the pose prior loaded once per worker), results in the PedX SMPL layout under
``out`` as each track completes (with our ``keypoints_3d`` field, which the evaluation uses), the manifest,
completion markers, ``summary.json`` and the resolved ``baseline_config.yaml`` beside them (resumable).  One
failing track is reported in the summary and never stops the run.
"""
from __future__ import annotations

import logging
import os
import threading
from dataclasses import dataclass, field

import numpy as np

from pedx_graph.baselines.smplify_disparity import SmplifyDispConfig
from pedx_graph.data.types import Track

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
    from pedx_graph.graph.context import neutral_template
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
_WORKER_LOCK = threading.Lock()


def _worker_state(name: str, config: BaselineConfig) -> dict:
    key = (config.body_model, name == "smplify_disp", config.smplify.pose_prior_covariance_scale)
    with _WORKER_LOCK:         # a Dask worker may run tasks in several threads
        return _load_worker_state(name, config, key)


def _load_worker_state(name: str, config: BaselineConfig, key: tuple) -> dict:
    if _WORKER.get("key") != key:
        from pedx_graph.body import BodyModel

        state = {"model": BodyModel.load(config.body_model or None), "mixture": None, "template": None}
        if name == "smplify_disp":
            state["mixture"], state["template"] = load_pose_mixture(config.smplify.pose_prior_covariance_scale)
        _WORKER.clear()
        _WORKER.update(key=key, state=state)
    return _WORKER["state"]


def baseline_task(track: Track, params: tuple):
    """The task of one track in :func:`fit_dataset_baseline` (run in a worker): ``params = (name, config)``
    -> :class:`~pedx_graph.execution.tasks.TrackOutput`."""
    from pedx_graph.execution.tasks import limit_blas_threads, result_output

    name, config = params
    limit_blas_threads()
    state = _worker_state(name, config)
    return result_output([run_baseline(name, track, state["model"], config, state["mixture"], state["template"])],
                         track=track)


def baseline_warm_up(params: tuple) -> None:
    """Load the body model (and the pose prior of ``smplify_disp``) of ``params = (name, config)`` here."""
    from pedx_graph.execution.tasks import limit_blas_threads

    limit_blas_threads()
    _worker_state(*params)


def fit_dataset_baseline(dataset: str | os.PathLike, out: str | os.PathLike, name: str, workers: int = 1,
                         config: BaselineConfig | None = None, sequences: list[str] | None = None, *,
                         cluster: str | None = None, resume: bool = False, overwrite: bool = False,
                         progress: bool = False, keep_records: bool = True, on_track=None) -> dict:
    """Run baseline ``name`` on every track of ``dataset``; results under ``out``; returns the summary.

    Same layout, summary fields, executors and resume / overwrite as
    :func:`pedx_graph.solvers.fit.fit_dataset`, with ``baseline`` instead of ``solver`` and each track's
    baseline extras (e.g. how many keypoints were filled).
    """
    from pedx_graph.execution.executors import ExecutorSpec
    from pedx_graph.execution.runner import RunSpec, run_dataset

    _check_name(name)
    config = config or BaselineConfig()
    spec = RunSpec(command="baseline", method=name, method_key="baseline", dataset=dataset, task_fn=baseline_task,
                   configs={"baseline_config": config}, make_params=lambda tracks: ((name, config), {}),
                   sequences=sequences, warm_up=baseline_warm_up)
    return run_dataset(spec, out, ExecutorSpec(workers=workers, cluster=cluster), resume=resume,
                       overwrite=overwrite, progress=progress, keep_records=keep_records, on_track=on_track)
