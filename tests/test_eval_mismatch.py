"""`eval` refuses ground truth that is not of the results' scene (other tracks, other frames, or the same names in
another world frame) with an error naming what does not match, instead of reporting metres of error; results
of the scene itself, also partial ones, are scored."""
from __future__ import annotations

import pytest

from pedx_graph.data.reader import read_smpl_labels
from pedx_graph.data.types import SmplLabel
from pedx_graph.data.writer import write_results
from pedx_graph.eval.evaluate import EvalMismatchError, evaluate
from pedx_graph.sim.config import SimConfig
from pedx_graph.sim.simulate import simulate


def _scene(root, seed: int, pedestrians: int = 3):
    cfg = SimConfig()
    cfg.scene.n_pedestrians = pedestrians
    cfg.scene.n_frames = 4
    simulate(root, cfg, seed=seed)
    return root


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    base = tmp_path_factory.mktemp("eval_mismatch")
    return _scene(base / "a", seed=3), _scene(base / "b", seed=4)


def as_results(truth_root, out, offset_m=(0.0, 0.0, 0.0), keep=None):
    """The truth's SMPL labels written as results, moved by ``offset_m``; ``keep(key)`` selects tracks."""
    labels = []
    for key, labs in read_smpl_labels(truth_root).items():
        if keep is None or keep(key):
            labels += [SmplLabel(lab.sequence, lab.frame, lab.tracking_id, lab.betas, lab.pose,
                                 lab.trans + offset_m) for lab in labs]
    write_results(out, labels)
    return out


def test_results_of_the_scene_are_scored(scenes, tmp_path):
    a, _ = scenes
    report = evaluate(as_results(a, tmp_path / "same"), a)
    assert report["overall"]["global_mm"] < 1e-6
    # a fit 20 cm off is an error to report, not another scene
    report = evaluate(as_results(a, tmp_path / "off", offset_m=(0.0, 0.2, 0.0)), a)
    assert report["overall"]["global_mm"] == pytest.approx(200.0, abs=1e-6)   # every joint 0.2 m off
    # results for some of the tracks only: scored, the rest counted missing
    first = sorted(read_smpl_labels(a))[0]
    report = evaluate(as_results(a, tmp_path / "part", keep=lambda key: key == first), a)
    assert report["missing_frames"] > 0


def test_another_scene_is_refused_naming_its_tracks(scenes, tmp_path):
    a, b = scenes
    with pytest.raises(EvalMismatchError) as info:
        evaluate(as_results(a, tmp_path / "res"), b)
    message = str(info.value)
    assert "only 0 of" in message and "tracks without ground truth" in message and "\n" not in message
    some_track = sorted(read_smpl_labels(a))[0][1]
    assert some_track in message


def test_other_sequence_is_refused(scenes, tmp_path):
    a, _ = scenes
    labels = [SmplLabel("20000101T0000", lab.frame, lab.tracking_id, lab.betas, lab.pose, lab.trans)
              for labs in read_smpl_labels(a).values() for lab in labs]
    out = tmp_path / "renamed"
    write_results(out, labels)
    with pytest.raises(EvalMismatchError, match="sequences 20000101T0000 of the results have no ground truth"):
        evaluate(out, a)


def test_same_names_another_world_frame_is_refused(scenes, tmp_path):
    a, _ = scenes
    with pytest.raises(EvalMismatchError, match="person sizes away from the 2D labels"):
        evaluate(as_results(a, tmp_path / "moved", offset_m=(0.0, 4.0, 0.0)), a)
