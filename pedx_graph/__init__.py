"""pedx-graph: metric 3D pedestrian body models from stereo 2D labels and LiDAR, as GTSAM factor graphs.

The public Python API, in four lines (a dataset in the PedX release layout, e.g. from ``pedx-graph simulate``)::

    from pedx_graph import read_dataset, fit_track
    tracks = read_dataset("SIM")                  # list[Track]: one pedestrian of one sequence each
    result = fit_track(tracks[0])                 # TrackResult: pose, betas, trans, world_keypoints
    result.extra_per_frame[0]["cov_trans"]        # (3, 3) marginal covariance of frame 0's translation, m^2

Every name of ``__all__`` is imported on first use (``import pedx_graph`` loads neither GTSAM nor Dask):
reading and writing data (:func:`read_dataset`, :func:`read_smpl_labels`, :func:`write_results`), fitting
(:func:`fit_track`, :func:`fit_dataset`), streaming (:class:`StreamingEstimator`, :func:`stream_dataset`), the
body model (:class:`BodyModel`), the simulator (:func:`simulate`) and the config dataclasses
(:class:`FitConfig` and its sections, :class:`StreamConfig`, :class:`SimConfig`, :class:`GroundConfig`, ...;
:func:`load_config` reads any of them from YAML), detector files in (:func:`read_openpose`, :func:`read_coco`,
:func:`import_detections`) and meshes and pictures out (:func:`export_results`).
"""
from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: Public name -> the module that defines it (imported on first access).
_PUBLIC: dict[str, str] = {
    # data in and out
    "read_dataset": "pedx_graph.data.reader",
    "iter_tracks": "pedx_graph.data.reader",
    "read_smpl_labels": "pedx_graph.data.reader",
    "write_results": "pedx_graph.data.writer",
    "Track": "pedx_graph.data.types",
    "TrackFrame": "pedx_graph.data.types",
    "StereoCalibration": "pedx_graph.data.types",
    "SmplLabel": "pedx_graph.data.types",
    "DataFormatError": "pedx_graph.data.types",
    "GroundFrame": "pedx_graph.data.ground",
    # fitting
    "fit_track": "pedx_graph.solvers.track_lm",
    "fit_dataset": "pedx_graph.solvers.fit",
    "TrackResult": "pedx_graph.solvers.result",
    "EstimatorContext": "pedx_graph.graph.context",
    # streaming
    "StreamingEstimator": "pedx_graph.solvers.stream",
    "FrameEstimate": "pedx_graph.solvers.stream",
    "stream_dataset": "pedx_graph.solvers.stream",
    # detections in, pictures and meshes out
    "read_openpose": "pedx_graph.detections.openpose",
    "read_coco": "pedx_graph.detections.coco",
    "import_detections": "pedx_graph.detections.importer",
    "export_results": "pedx_graph.export.run",
    # body model
    "BodyModel": "pedx_graph.body.model",
    # simulator
    "simulate": "pedx_graph.sim.simulate",
    # configuration
    "FitConfig": "pedx_graph.graph.config",
    "NoiseConfig": "pedx_graph.graph.config",
    "TermsConfig": "pedx_graph.graph.config",
    "SolverConfig": "pedx_graph.graph.config",
    "ReaderConfig": "pedx_graph.data.reader",
    "GroundConfig": "pedx_graph.data.ground",
    "CalibrationLimits": "pedx_graph.data.calib",
    "PlausibilityConfig": "pedx_graph.graph.config",
    "StreamConfig": "pedx_graph.solvers.stream",
    "IsamConfig": "pedx_graph.solvers.isam",
    "SimConfig": "pedx_graph.sim.config",
    "rig_config": "pedx_graph.sim.config",
    "ImportConfig": "pedx_graph.detections.importer",
    "ExportConfig": "pedx_graph.export.run",
    "load_config": "pedx_graph.config",
    "save_config": "pedx_graph.config",
    "ConfigError": "pedx_graph.config",
}

__all__ = ["__version__", *_PUBLIC]


def __getattr__(name: str):
    """Import a public name's module on first access (keeps ``import pedx_graph`` fast)."""
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'pedx_graph' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_PUBLIC))
