"""Config loading: presets fill nested dataclasses; bad keys and types name the file and key."""
import dataclasses

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


def test_a_nested_section_changes_only_the_fields_it_names(tmp_path):
    """A preset setting one field of a nested section keeps the parent's own defaults for the others: the
    association's per-camera tracker (confirms at once, keeps every tracklet) and the simulated detector's
    keypoint noise (drawn from the truth) are not their classes' defaults."""
    from pedx_graph.detections.importer import ImportConfig
    from pedx_graph.sim.config import SimConfig

    path = tmp_path / "import.yaml"
    path.write_text("association:\n  tracklet:\n    max_misses: 6\n")
    loaded = load_config(ImportConfig, path).association.tracklet
    default = ImportConfig().association.tracklet
    assert loaded.max_misses == 6
    assert loaded == dataclasses.replace(default, max_misses=6)
    assert (loaded.confirm_hits, loaded.min_track_frames, loaded.range_sigma_m) == (1, 1, 0.25)
    path = tmp_path / "sim.yaml"
    path.write_text("detections:\n  keypoint_noise:\n    sigma_px: 2.0\n")
    noise = load_config(SimConfig, path).detections.keypoint_noise
    assert noise.use_truth and noise.sigma_px == 2.0
