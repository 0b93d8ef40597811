"""All configuration in one place: every config class is set from YAML, round-trips, is documented in
docs/config.md (generated, up to date) and saved with the results; ``pedx-graph config`` prints it all."""
from __future__ import annotations

import dataclasses
import json
import typing
from pathlib import Path

import numpy as np
import pytest
import yaml

from pedx_graph.cli import main
from pedx_graph.config import from_dict, load_config, to_dict
from pedx_graph.config_reference import (COMMAND_CONFIGS, DERIVED, all_config_classes, field_docs, markdown,
                                         sections)
from pedx_graph.data.reader import read_dataset, read_smpl_labels
from pedx_graph.graph.config import FitConfig
from pedx_graph.solvers.fit import fit_dataset
from scene_fixtures import small_scene
from test_config_ranges import config_classes

ROOT = Path(__file__).resolve().parents[1]


def _changed(value, tp):
    """A value of type ``tp`` different from ``value`` (strings and tuples of strings kept: they are choices)."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, int) and tp is not float:
        return value + 1
    if isinstance(value, float):
        return value * 0.5 + 0.25
    if value is None:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if args and args[0] is float:
            return 0.125
    if isinstance(value, tuple) and value and all(isinstance(v, (int, float)) and not isinstance(v, bool)
                                                  for v in value):
        return tuple(v + 1 for v in value)
    return value


def _every_field_changed(cls, instance=None):
    instance = cls() if instance is None else instance
    hints = typing.get_type_hints(cls)
    changes = {}
    for f in dataclasses.fields(cls):
        value = getattr(instance, f.name)
        if dataclasses.is_dataclass(value):
            changes[f.name] = _every_field_changed(type(value), value)
        elif not (isinstance(value, (list, tuple)) and value and dataclasses.is_dataclass(value[0])):
            changes[f.name] = _changed(value, hints[f.name])
    return dataclasses.replace(instance, **changes)


def test_every_config_class_is_reachable_from_a_command_or_derived():
    reachable = set(all_config_classes())
    assert {"FitConfig", "MarginalsConfig", "DiagnosticsConfig", "AdmmConfig", "StreamConfig", "IsamConfig",
            "SimConfig", "BaselineConfig", "ExperimentConfig", "TrainConfig"} <= reachable
    everything = set(config_classes())
    assert everything - reachable == set(DERIVED), "a config class no command's YAML can set"
    assert not reachable & set(DERIVED)


@pytest.mark.parametrize("name", sorted(all_config_classes()))
def test_config_class_round_trips_through_yaml(name):
    cls = all_config_classes()[name]
    for cfg in (cls(), _every_field_changed(cls)):
        data = to_dict(cfg)
        back = from_dict(cls, yaml.safe_load(yaml.safe_dump(data, sort_keys=False)), source="<test>")
        assert back == cfg
        assert to_dict(back) == data


def test_a_changed_field_survives_the_round_trip_of_a_whole_fit_config():
    cfg = _every_field_changed(FitConfig)
    assert cfg.admm.rho != FitConfig().admm.rho and cfg.marginals.max_trans_sigma_m != 5.0
    assert cfg.diagnostics_thresholds.worst_frames == FitConfig().diagnostics_thresholds.worst_frames + 1
    assert from_dict(FitConfig, yaml.safe_load(yaml.safe_dump(to_dict(cfg)))) == cfg


def test_every_option_has_a_docstring():
    for name, cls in all_config_classes().items():
        missing = [f.name for f in dataclasses.fields(cls) if not field_docs(cls).get(f.name)]
        assert not missing, f"{name}: fields without a docstring: {missing}"


def test_docs_config_md_is_generated_from_the_code():
    assert (ROOT / "docs" / "config.md").read_text(encoding="utf-8") == markdown(), \
        "docs/config.md is out of date: run python tools/gen_config_docs.py"


def test_reference_lists_every_option_with_its_default():
    doc = markdown()
    for entry in COMMAND_CONFIGS:
        for sec in sections(entry.cls()):
            for opt in sec.options:
                assert f"**`{opt.path}`**" in doc
    assert "**`admm.rho`** (`float`, default `2.0`)" in doc
    assert "**`marginals.max_trans_sigma_m`** (`float`, default `5.0`)" in doc
    assert "**`diagnostics_thresholds.outlier_weight`** (`float`, default `0.25`)" in doc


def test_cli_config_prints_options_and_a_complete_preset(tmp_path, capsys):
    assert main(["config", "fit"]) == 0
    listing = capsys.readouterr().out
    assert "admm.rho = 2.0" in listing and "marginals.method = chain" in listing
    assert "Penalty of the consensus term" in listing                       # the field's docstring
    assert main(["config", "--yaml"]) == 0
    preset = tmp_path / "fit.yaml"
    preset.write_text(capsys.readouterr().out)
    assert load_config(FitConfig, preset) == FitConfig()
    assert set(yaml.safe_load(preset.read_text())) == {f.name for f in dataclasses.fields(FitConfig)}
    for entry in COMMAND_CONFIGS[1:]:
        assert main(["config", entry.name, "--yaml"]) == 0
        data = yaml.safe_load(capsys.readouterr().out)
        assert from_dict(entry.cls(), data) == entry.cls()()


def test_fit_default_preset_is_complete():
    """configs/fit_default.yaml sets every option of the fit (and only those, at their defaults)."""
    data = yaml.safe_load((ROOT / "configs" / "fit_default.yaml").read_text())
    assert data == to_dict(FitConfig())


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    return small_scene(tmp_path_factory.mktemp("cfg_scene"), pedestrians=2, frames=3, seed=3)


def test_results_folder_saves_every_section_and_yaml_sections_take_effect(tiny_scene, tmp_path):
    preset = tmp_path / "fit.yaml"
    preset.write_text("marginals:\n  max_trans_sigma_m: 1.0e-9\n"       # every frame's covariances too wide
                      "diagnostics_thresholds:\n  worst_frames: 1\n"
                      "admm:\n  rho: 3.0\n")
    config = load_config(FitConfig, preset)
    out = tmp_path / "results"
    summary = fit_dataset(tiny_scene, out, config, workers=1)
    assert summary["tracks"] and not summary["failed"]
    saved = yaml.safe_load((out / "fit_config.yaml").read_text())
    assert saved == to_dict(config)
    for sec in sections(FitConfig):
        node = saved
        for key in filter(None, sec.path.split(".")):
            node = node[key]
        assert {o.path.rsplit(".", 1)[-1] for o in sec.options} <= set(node), sec.path
    assert saved["admm"]["rho"] == 3.0 and saved["marginals"]["max_trans_sigma_m"] == 1e-9
    labels = [lab for labs in read_smpl_labels(out).values() for lab in labs]
    assert labels and all(lab.extra.get("covariance_status") != "ok" for lab in labels)
    tracks = json.loads((out / "summary.json").read_text())["tracks"]
    assert all(len(t["diagnostics"]["worst_frames"]) <= 1 for t in tracks)


def test_admm_section_reaches_the_admm_solver(tiny_scene):
    from pedx_graph.solvers.admm import fit_track_admm

    track = max(read_dataset(tiny_scene), key=len)
    config = FitConfig()
    config.terms.lidar_chamfer = False                      # one stage
    config.admm.max_iterations = 1
    result = fit_track_admm(track, config)
    assert result.extra_track["admm_iterations"] == 1
    assert np.all(np.isfinite(result.world_keypoints))


def test_train_prior_reads_its_config_from_yaml_and_flags_override(tmp_path, capsys):
    from pedx_graph.cli import build_parser
    from pedx_graph.priors.cli import train_config

    preset = tmp_path / "train.yaml"
    preset.write_text("n_pose: 4\nseed: 7\nclips: [\"07_01\"]\n")
    args = build_parser().parse_args(["train-prior", "--config", str(preset), "--seed", "9"])
    cfg = train_config(args)
    assert (cfg.n_pose, cfg.seed, cfg.clips, cfg.mirror) == (4, 9, ("07_01",), True)
    preset.write_text("n_pose: 0\n")
    assert main(["train-prior", "--config", str(preset)]) == 1        # refused before any clip is read
    assert "n_pose" in capsys.readouterr().err


def test_named_sections_in_a_dict_are_built_from_yaml():
    """A ``dict[str, <config class>]`` field (the import's per-keypoint-set sigma curves) holds config classes
    after loading, not plain dicts, and round-trips."""
    from pedx_graph.detections.noise import DetectionNoiseConfig

    data = to_dict(DetectionNoiseConfig())
    data["per_set"] = {"coco17": to_dict(DetectionNoiseConfig().default)}
    cfg = from_dict(DetectionNoiseConfig, yaml.safe_load(yaml.safe_dump(data)))
    assert type(cfg.per_set["coco17"]) is type(DetectionNoiseConfig().default)
    assert to_dict(cfg) == data
