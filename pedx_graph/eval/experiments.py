"""What the whole evaluation runs (:class:`ExperimentConfig`): scenes, methods, solvers, ablation, detector labels.

The run itself (simulate, fit, baselines, ablation, detector labels, report) is
:func:`pedx_graph.experiment_runner.run_experiments`, above the simulator and the solvers; this module holds only
its configuration, so that the evaluation layer never imports the simulator.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from pedx_graph.data.detector_model import DetectorNoiseConfig
from pedx_graph.eval.runs import ABLATION_ROWS  # noqa: F401  (the Table IV rows the experiment runs)

#: Solver runs of the experiment (``ExperimentConfig.solvers``; the stream gives two) -> their label.
SOLVER_RUNS = {"admm": "ADMM", "stream": "iSAM2 stream (final)", "stream_causal": "iSAM2 stream (causal)"}


@dataclass
class SceneVariant:
    """One simulated scene of the experiment (its own sequence; intersection placed for a distance range)."""

    name: str = "near"
    """Folder name under ``scenes/``."""
    sequence: str = "20991231T1200"
    """Sequence name (distinct per scene)."""
    intersection_x_m: float = 14.0
    """x of the intersection centre, metres (SceneConfig.intersection_x_m)."""
    distance_mean_m: float = 20.0
    """Soft target of the pedestrians' distance, metres (SceneConfig.distance_mean_m)."""
    distance_std_m: float = 10.0
    """Width of that target, metres (SceneConfig.distance_std_m)."""


def default_scenes() -> list[SceneVariant]:
    """Three scenes covering 5-45 m: the default intersection with a near distance target (5-25 m), one at
    24 m (15-35 m), one at 36 m (25-45 m); ranges measured with seed 1, 8 pedestrians, CMU motion."""
    return [SceneVariant("near", "20991231T1200", 14.0, 12.0, 5.0),
            SceneVariant("mid", "20991231T1300", 24.0, 30.0, 6.0),
            SceneVariant("far", "20991231T1400", 36.0, 38.0, 5.0)]


@dataclass
class ExperimentConfig:
    """Size and content of the experiment (defaults: the committed docs/results.md run)."""

    pedestrians: int = 12
    """Pedestrians per scene."""
    frames: int = 40
    """Frames per scene (10 fps)."""
    scenes: list[SceneVariant] = field(default_factory=default_scenes)
    """The scenes (merged into one dataset, one sequence each)."""
    motion_dir: str = "auto"
    """BVH folder with clips.csv for the simulated motion (hold-out clips); ``auto``: ../shared/mocap/cmu next
    to the project when it exists, else the procedural gait; empty: procedural gait."""
    fit_config: str = ""
    """YAML of the full estimator's FitConfig; empty: the defaults (= configs/fit_default.yaml)."""
    baselines: tuple[str, ...] = ("triangulation", "left_disp", "smplify_disp")
    """Baselines run on the clean labels."""
    ablation: bool = True
    """Run the Table IV rows (row 5 = the ``ours`` run)."""
    detector: DetectorNoiseConfig = field(default_factory=DetectorNoiseConfig)
    """The simulated detector of Table V."""
    detector_config: str = ""
    """YAML of a DetectorNoiseConfig (e.g. configs/detector_noise.yaml) replacing ``detector``; empty: unused."""
    detector_methods: tuple[str, ...] = ("ours", "triangulation")
    """Methods also run on the detector labels."""
    floor_samples: int = 64
    """Monte Carlo samples per frame of the error floor."""
    solvers: tuple[str, ...] = ("admm", "stream")
    """Other solvers run on the clean labels beside the batch LM fit (``ours``), same fit config: ``admm`` (the
    paper's ADMM reference) and ``stream`` (iSAM2, one frame at a time; its final and its causal estimates are
    two runs, ``stream`` and ``stream_causal``)."""


def resolved_scenes(config: ExperimentConfig) -> list[SceneVariant]:
    """``config.scenes`` as :class:`SceneVariant` objects (a YAML config gives plain dicts); names and sequences
    must be distinct."""
    from pedx_graph.config import from_dict

    scenes = [s if isinstance(s, SceneVariant) else from_dict(SceneVariant, s, source="<experiment config>",
                                                               prefix=f"scenes[{i}].")
              for i, s in enumerate(config.scenes)]
    for field_name in ("name", "sequence"):
        values = [getattr(s, field_name) for s in scenes]
        if len(set(values)) != len(values):
            raise ValueError(f"experiment config: scenes need distinct '{field_name}' values, got {values}")
    return scenes


def resolve_motion_dir(setting: str) -> str | None:
    """The BVH folder to use: ``auto`` looks for ``shared/mocap/cmu`` beside the project root."""
    if setting == "auto":
        candidate = Path(__file__).resolve().parents[3] / "shared" / "mocap" / "cmu"
        return str(candidate) if candidate.is_dir() else None
    return setting or None
