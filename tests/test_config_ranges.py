"""Value ranges of every config dataclass: each numeric field has a rule, the defaults and the presets pass, and a
bad value is refused at load with an error naming the file and the key."""
from __future__ import annotations

import dataclasses
import importlib
import pkgutil
import typing
from pathlib import Path

import pytest

import pedx_graph
from pedx_graph.config import ConfigError, load_config
from pedx_graph.config_ranges import RULES, SELF_CHECKED, check_config
from pedx_graph.graph.config import FitConfig

ROOT = Path(__file__).resolve().parents[1]


def config_classes() -> dict[str, type]:
    """Every dataclass of the package named ``*Config`` / ``*Limits`` (and the experiment's SceneVariant)."""
    found = {}
    for info in pkgutil.walk_packages(pedx_graph.__path__, "pedx_graph."):
        try:
            module = importlib.import_module(info.name)
        except ModuleNotFoundError as exc:          # an optional third-party extra; never the project itself
            assert not (exc.name or "").startswith("pedx_graph"), exc
            continue
        for name, obj in vars(module).items():
            if isinstance(obj, type) and dataclasses.is_dataclass(obj) and obj.__module__ == module.__name__ \
                    and (name.endswith(("Config", "Limits")) or name == "SceneVariant"):
                found[name] = obj
    return found


def _numeric(tp) -> bool:
    args = typing.get_args(tp)
    if tp in (int, float):
        return True
    return any(_numeric(a) for a in args if a is not Ellipsis and a is not type(None))


def test_every_numeric_field_has_a_range():
    classes = config_classes()
    assert {"FitConfig", "NoiseConfig", "StreamConfig", "CalibrationLimits", "PlausibilityConfig"} <= set(classes)
    missing = []
    for name, cls in sorted(classes.items()):
        if name in SELF_CHECKED:
            continue
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            if hints[f.name] is not bool and _numeric(hints[f.name]) and f"{name}.{f.name}" not in RULES:
                missing.append(f"{name}.{f.name}")
    assert not missing, f"give these fields a rule in pedx_graph/config_ranges.py: {missing}"
    unknown = [key for key in RULES if key.split(".")[0] not in classes]
    assert not unknown, unknown


def test_defaults_and_presets_pass():
    for name, cls in config_classes().items():
        check_config(cls(), name)
    for preset in sorted((ROOT / "configs").glob("*.yaml")):
        if preset.name.startswith("sim_"):
            from pedx_graph.sim.config import load_sim_config
            check_config(load_sim_config(preset), str(preset))
        elif preset.name == "detector_noise.yaml":
            from pedx_graph.eval.detector_noise import DetectorNoiseConfig
            load_config(DetectorNoiseConfig, preset)
        elif preset.name.startswith("import_"):
            from pedx_graph.detections.importer import ImportConfig
            load_config(ImportConfig, preset)
        else:
            load_config(FitConfig, preset)


@pytest.mark.parametrize("text, key, what", [
    ("noise:\n  keypoint_sigma_px: -1\n", "noise.keypoint_sigma_px", "> 0"),
    ("noise:\n  lidar_sigma_m: .nan\n", "noise.lidar_sigma_m", "finite"),
    ("noise:\n  lidar_range_sigma_m: -0.1\n", "noise.lidar_range_sigma_m", ">= 0"),
    ("noise:\n  keypoint_sigma_px_per_keypoint: [2, 2]\n", "noise.keypoint_sigma_px_per_keypoint", "18 numbers"),
    ("noise:\n  lidar_loss: squared\n", "noise.lidar_loss", "one of"),
    ("solver:\n  max_iterations: -2\n", "solver.max_iterations", ">= 0"),
    ("solver:\n  flip_segments: [tail]\n", "solver.flip_segments", "one of"),
    ("ground:\n  source: sky\n", "ground.source", "one of"),
    ("ground:\n  world_up: [0, 0]\n", "ground.world_up", "must be"),
    ("fps: 0\n", "fps", "> 0"),
    ("calibration_limits:\n  min_fov_deg: 120\n  max_fov_deg: 60\n", "calibration_limits", "min_fov_deg"),
    ("plausibility:\n  max_outlier_fraction: 0\n", "plausibility.max_outlier_fraction", "(0, 1]"),
    ("keypoint_margin: -0.1\n", "keypoint_margin", "[0, 10]"),
])
def test_bad_value_names_file_and_key(tmp_path, text, key, what):
    path = tmp_path / "preset.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_config(FitConfig, path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and f"'{key}'" in message and what in message, message
    assert "\n" not in message


def test_stream_and_baseline_configs_are_checked(tmp_path):
    from pedx_graph.baselines.run import BaselineConfig
    from pedx_graph.solvers.stream import StreamConfig

    path = tmp_path / "stream.yaml"
    path.write_text("track_timeout_s: 0\n")
    with pytest.raises(ConfigError, match="'track_timeout_s' must be > 0"):
        load_config(StreamConfig, path)
    path.write_text("isam:\n  presolve_method: newton\n")
    with pytest.raises(ConfigError, match="'isam.presolve_method' must be one of"):
        load_config(StreamConfig, path)
    path.write_text("smplify:\n  min_keypoints: 0\n")
    with pytest.raises(ConfigError, match="'smplify.min_keypoints' must be >= 1"):
        load_config(BaselineConfig, path)


def test_programmatic_configs_are_checked_too():
    config = FitConfig()
    config.plausibility.max_distance_m = float("inf")
    with pytest.raises(ConfigError, match="'plausibility.max_distance_m' must be finite"):
        check_config(config, "<api>")
    config = FitConfig()
    config.noise.shape_support_sd = float("inf")            # documented: inf = no support term
    check_config(config)
