"""Config loading: presets fill nested dataclasses; bad keys and types name the file and key."""
import pytest

from pedx_graph.config import ConfigError, load_config, save_config
from pedx_graph.graph.config import FitConfig


def test_round_trip(tmp_path):
    cfg = FitConfig()
    cfg.noise.keypoint_sigma_px = 5.0
    cfg.terms.temporal_prior = False
    path = save_config(cfg, tmp_path / "c.yaml")
    back = load_config(FitConfig, path)
    assert back == cfg


def test_unknown_key_names_file_and_key(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("noise:\n  keypoint_sigma: 3\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml.*noise\.keypoint_sigma"):
        load_config(FitConfig, path)


def test_wrong_type_names_key(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("solver:\n  max_iterations: lots\n")
    with pytest.raises(ConfigError, match="solver.max_iterations"):
        load_config(FitConfig, path)


def test_presets_load():
    from pathlib import Path
    for preset in sorted((Path(__file__).resolve().parents[1] / "configs").glob("fit_*.yaml")):
        load_config(FitConfig, preset)


def test_default_preset_mirrors_the_dataclass():
    from pathlib import Path
    preset = Path(__file__).resolve().parents[1] / "configs" / "fit_default.yaml"
    assert load_config(FitConfig, preset) == FitConfig()
