"""The whole evaluation from one seed: simulate, fit, baselines, ablation, detector labels, report.

``run_experiments(out, ExperimentConfig, seed, workers)`` (the configuration:
:class:`pedx_graph.eval.experiments.ExperimentConfig`) writes under ``out``::

    scenes/<name>/      one simulated scene per :class:`SceneVariant` (distance ranges differ)
    dataset/            the scenes merged (one sequence per scene; the truth of each kept)
    dataset_detector/   the same with detector-like 2D labels and re-cut segments (detector_noise)
    runs/<name>/        one results folder per method / ablation row / detector run (+ experiment.json)
    report/             report.md, report.json, figures/ (pedx_graph.eval.report)
    experiments.json    the resolved config, seed, phase wall times, hardware note

Table IV rows (:data:`ABLATION_ROWS`): the pose and shape priors and the joint limits stay on in every row;
the heading prior E_D comes from the LiDAR trajectory, so it is switched with E_T (both are the "LiDAR
translation" information of the paper's row).  Row 5 is the full estimator (the ``ours`` run).
"""
from __future__ import annotations

import dataclasses
import json
import logging
import os
import shutil
import time
from pathlib import Path

from pedx_graph.data.detector_model import DetectorNoiseConfig
from pedx_graph.environment import machine_note
from pedx_graph.eval.experiments import (SOLVER_RUNS, ExperimentConfig, SceneVariant, resolve_motion_dir,
                                         resolved_scenes)
from pedx_graph.eval.runs import ABLATION_ROWS
from pedx_graph.utils import atomic_write_json

log = logging.getLogger(__name__)


def scene_config(variant: SceneVariant, config: ExperimentConfig):
    """The SimConfig of one scene."""
    from pedx_graph.sim.config import SimConfig

    sim = SimConfig()
    sim.scene.n_pedestrians = config.pedestrians
    sim.scene.n_frames = config.frames
    sim.scene.sequence = variant.sequence
    sim.scene.intersection_x_m = variant.intersection_x_m
    sim.scene.distance_mean_m = variant.distance_mean_m
    sim.scene.distance_std_m = variant.distance_std_m
    motion = resolve_motion_dir(config.motion_dir)
    if motion:
        sim.motion.motion_dir = motion
        sim.motion.split = "holdout"
    return sim


def merge_scenes(scene_dirs: list[Path], out: Path) -> Path:
    """Merge simulated scenes (distinct sequences, same cameras) into one dataset at ``out`` (hard links where
    possible).  Calibration files must be identical; ``truth/meta.json`` of each scene becomes
    ``truth/<sequence>/meta.json``; the first scene's ``sim_config.yaml`` is kept (noise settings)."""
    out.mkdir(parents=True, exist_ok=True)
    for i, scene in enumerate(scene_dirs):
        meta = json.loads((scene / "truth" / "meta.json").read_text())
        for path in sorted(p for p in scene.rglob("*") if p.is_file()):
            rel = path.relative_to(scene)
            if rel.parts[0] in ("summary.json", "sim_config.yaml"):
                if i == 0 and rel.parts[0] == "sim_config.yaml":
                    shutil.copy2(path, out / rel)
                continue
            if rel == Path("truth/meta.json"):
                rel = Path("truth") / meta["sequence"] / "meta.json"
            dst = out / rel
            if dst.exists():
                if rel.parts[0] == "calib" and dst.read_bytes() == path.read_bytes():
                    continue
                raise FileExistsError(f"{dst}: two scenes write the same file")
            dst.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.link(path, dst)
            except OSError:
                shutil.copy2(path, dst)
    return out


def code_version() -> dict:
    """The project's git commit and whether package files differ from it (``dirty``), when in a checkout."""
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True,
                                text=True, check=True).stdout.strip()
        status = subprocess.run(["git", "status", "--porcelain", "--", "pedx_graph", "factors"], cwd=root,
                                capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return {"commit": None, "dirty": None}
    return {"commit": commit, "dirty": bool(status.strip())}


def _mark(run_dir: Path, **fields) -> None:
    atomic_write_json(run_dir / "experiment.json", fields)


def run_experiments(out: str | os.PathLike, config: ExperimentConfig | None = None, seed: int = 0,
                    workers: int = 2, report: bool = True, progress: bool = False) -> dict:
    """Run everything (module docstring) into ``out``; returns the ``experiments.json`` dict.  ``progress``: a
    progress bar per phase on stderr (frames simulated, tracks fitted; only when stderr is a terminal)."""
    from pedx_graph.baselines.run import fit_dataset_baseline
    from pedx_graph.config import load_config, to_dict
    from pedx_graph.eval.detector_noise import make_noisy_dataset
    from pedx_graph.graph.config import FitConfig
    from pedx_graph.sim.simulate import simulate
    from pedx_graph.solvers.fit import fit_dataset

    config = config or ExperimentConfig()
    config = dataclasses.replace(config, scenes=resolved_scenes(config))
    out = Path(out)
    if (out / "runs").exists() or (out / "dataset").exists():
        raise FileExistsError(f"{out}: already holds an experiment (choose a new folder)")
    out.mkdir(parents=True, exist_ok=True)
    phases: dict[str, float] = {}
    t_all = time.perf_counter()

    def timed(name: str, fn, *args, **kwargs):
        t0 = time.perf_counter()
        log.info("experiment: %s", name)
        result = fn(*args, **kwargs)
        phases[name] = time.perf_counter() - t0
        return result

    scene_dirs = []
    for k, variant in enumerate(config.scenes):
        path = out / "scenes" / variant.name
        timed(f"simulate {variant.name}", simulate, path, scene_config(variant, config), seed=seed + k,
              workers=workers, progress=progress)
        scene_dirs.append(path)
    dataset = timed("merge scenes", merge_scenes, scene_dirs, out / "dataset")
    fit_cfg = load_config(FitConfig, config.fit_config or None)
    runs = out / "runs"

    timed("fit ours", fit_dataset, dataset, runs / "ours", fit_cfg, workers=workers, progress=progress)
    _mark(runs / "ours", name="ours", label="ours", group="methods", labels="clean", ablation_row=5)
    for name in config.baselines:
        timed(f"baseline {name}", fit_dataset_baseline, dataset, runs / name, name, workers=workers,
              progress=progress)
        _mark(runs / name, name=name, label=name, group="methods", labels="clean")
    unknown = [name for name in config.solvers if name not in SOLVER_RUNS]
    if unknown:
        raise ValueError(f"experiment config: solvers must be among {list(SOLVER_RUNS)}, got {unknown}")
    if "admm" in config.solvers:
        timed("fit admm", fit_dataset, dataset, runs / "admm", fit_cfg, workers=workers, solver="admm",
              progress=progress)
        _mark(runs / "admm", name="admm", label=SOLVER_RUNS["admm"], group="methods", labels="clean",
              ablation_row=None)
    if "stream" in config.solvers:
        from pedx_graph.solvers.stream import StreamConfig, stream_dataset

        timed("stream", stream_dataset, dataset, runs / "stream", fit_cfg, StreamConfig(), workers=workers,
              progress=progress)
        _mark(runs / "stream", name="stream", label=SOLVER_RUNS["stream"], group="methods", labels="clean",
              ablation_row=None)
        _mark(runs / "stream" / "causal", name="stream_causal", label=SOLVER_RUNS["stream_causal"],
              group="methods", labels="clean", ablation_row=None)
    if config.ablation:
        for number, row in enumerate(ABLATION_ROWS, start=1):
            if number == 5:
                continue
            cfg = dataclasses.replace(fit_cfg, terms=dataclasses.replace(fit_cfg.terms, **row.fit_terms()))
            name = f"ablation{number}"
            timed(f"fit {name}", fit_dataset, dataset, runs / name, cfg, workers=workers, progress=progress)
            _mark(runs / name, name=name, label=row.label, group="ablation", labels="clean", ablation_row=number)
    if config.detector_methods:
        noisy = out / "dataset_detector"
        detector = load_config(DetectorNoiseConfig, config.detector_config) if config.detector_config \
            else config.detector
        counts = timed("detector labels", make_noisy_dataset, dataset, noisy, detector, seed=seed)
        atomic_write_json(noisy / "detector_counts.json", counts)
        for name in config.detector_methods:
            run = runs / f"{name}_detector"
            if name == "ours":
                timed("fit ours_detector", fit_dataset, noisy, run, fit_cfg, workers=workers, progress=progress)
            else:
                timed(f"baseline {name}_detector", fit_dataset_baseline, noisy, run, name, workers=workers,
                      progress=progress)
            _mark(run, name=f"{name}_detector", label=name, group="detector", labels="detector")
    record = {"seed": seed, "workers": workers, "config": to_dict(config), "phases_seconds": phases,
              "code": code_version(),
              "hardware": machine_note(),
              "motion": "CMU hold-out clips" if resolve_motion_dir(config.motion_dir) else "procedural gait"}
    if report:
        from pedx_graph.eval.report import ReportConfig, build_report

        paths = [runs / n for n in ("ours", *config.baselines)]
        if "admm" in config.solvers:
            paths.append(runs / "admm")
        if "stream" in config.solvers:
            paths += [runs / "stream", runs / "stream" / "causal"]
        names = []
        if config.ablation:
            names += [f"ablation{n}" for n in range(1, len(ABLATION_ROWS) + 1) if n != 5]
        names += [f"{m}_detector" for m in config.detector_methods]
        t0 = time.perf_counter()
        build_report(paths + [runs / n for n in names], dataset, out / "report",
                     ReportConfig(floor_samples=config.floor_samples, seed=seed))
        phases["report"] = time.perf_counter() - t0
    record["total_seconds"] = time.perf_counter() - t_all
    atomic_write_json(out / "experiments.json", record)
    return record
