"""A stereo pair's two cameras named the wrong way round (file names or --camera) stop the import in one line
(pedx_graph.detections.pair_order); named right, the pair's people are matched as named."""
from __future__ import annotations

import json

import pytest

from pedx_graph.cli import main
from scene_fixtures import small_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from pedx_graph.sim.config import pedx_rig_config

    config = pedx_rig_config()
    config.detections.formats = ("openpose_body25",)
    return small_scene(tmp_path_factory.mktemp("scene"), pedestrians=5, frames=8, seed=1, config=config)


def _import(scene, out, *extra) -> int:
    return main(["import", "openpose", str(scene / "detections" / "openpose_body25"), "--keypoint-set", "body25",
                 "--calib", str(scene), "--out", str(out), *extra])


def test_named_right_the_pairs_match_as_named(scene, tmp_path):
    assert _import(scene, tmp_path / "out") == 0
    (record,) = json.loads((tmp_path / "out" / "import_summary.json").read_text())["sequences"].values()
    order = record["pair_order"]
    assert set(order) == {"blu79CF-grn43E3", "ylw79D0-red707B"}
    for counts in order.values():
        assert counts["matched"] >= 6 and counts["matched_exchanged"] <= counts["matched"] // 3


def test_cameras_named_the_wrong_way_round_are_refused(scene, tmp_path, capsys):
    capsys.readouterr()
    assert _import(scene, tmp_path / "out", "--camera", "blu79CF=grn43E3", "--camera", "grn43E3=blu79CF") != 0
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "field 'camera'" in err and "pair blu79CF-grn43E3" in err and "wrong way round" in err
    assert "--camera NAME=CALIB_NAME" in err
