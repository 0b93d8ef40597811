"""Runs that survive faults (issue 14, item 2): interrupt and resume, write failures of one track, refused
results folders, file permissions, no timings in result files, byte-identical repeats and executors."""
import errno
import json
import os
import signal
import stat
from pathlib import Path

import numpy as np
import pytest
from scene_fixtures import small_scene

from pedx_graph.execution.outdir import RunFolderError
from pedx_graph.execution.runner import RunInterrupted
from pedx_graph.execution.tasks import TIMING_KEY
from pedx_graph.graph.config import FitConfig
from pedx_graph.solvers.fit import fit_dataset

#: Files of a results folder that hold times or the executor (everything else must be byte-identical).
RUN_SPECIFIC = ("summary.json", "timings.jsonl")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return small_scene(tmp_path_factory.mktemp("scene") / "data", pedestrians=4, frames=8, seed=3)


@pytest.fixture(scope="module")
def reference(scene, tmp_path_factory):
    """An uninterrupted run in this process."""
    out = tmp_path_factory.mktemp("reference") / "out"
    summary = fit_dataset(scene, out, FitConfig())
    assert summary["status"] == "complete" and summary["counts"]["done"] == 4 and not summary["failed"]
    return out


def files_of(out: Path) -> dict[str, bytes]:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def deterministic_summary(out: Path) -> dict:
    summary = json.loads((out / "summary.json").read_text())
    summary.pop("timings")
    summary.pop("execution")
    return summary


def assert_same_run(out: Path, reference: Path) -> None:
    """Every file but the summary and the timings byte-identical; the summary equal but for its timings and
    its execution record."""
    a, b = files_of(out), files_of(reference)
    assert sorted(a) == sorted(b)
    different = [name for name in a if name not in RUN_SPECIFIC and a[name] != b[name]]
    assert not different, different[:5]
    assert deterministic_summary(out) == deterministic_summary(reference)


def label_paths(out: Path) -> list[Path]:
    return sorted(p for p in (out / "labels" / "3d" / "smpl").rglob("*.json") if p.is_file())


def test_interrupt_then_resume_gives_the_uninterrupted_results(scene, reference, tmp_path):
    out = tmp_path / "out"
    seen = []

    def interrupt_after_first(info):            # a real SIGINT, deterministically after the first track
        seen.append(info)
        if len(seen) == 1:
            os.kill(os.getpid(), signal.SIGINT)

    with pytest.raises(RunInterrupted) as caught:
        fit_dataset(scene, out, FitConfig(), on_track=interrupt_after_first)
    assert caught.value.exit_code == 130
    summary = json.loads((out / "summary.json").read_text())      # written although interrupted
    assert summary["status"] == "interrupted"
    assert summary["counts"] == {"tracks": 4, "done": 1, "failed": 0, "not_run": 3}
    assert len(summary["not_run"]) == 3 and len(summary["tracks"]) == 1
    assert len(list((out / "done").rglob("*.json"))) == 1
    # the finished track is kept whole
    first = seen[0]
    assert all(p.name.endswith(f"_{first['tracking_id']}.json") for p in label_paths(out))
    assert len(label_paths(out)) == 8

    with pytest.raises(RunFolderError, match="not empty"):
        fit_dataset(scene, out, FitConfig())
    again = []
    resumed = fit_dataset(scene, out, FitConfig(), resume=True, on_track=again.append)
    assert len(again) == 3                      # the completed track is not run again
    assert resumed["status"] == "complete" and resumed["execution"]["tracks_from_earlier_runs"] == 1
    assert_same_run(out, reference)


def test_interrupt_of_a_local_pool_keeps_finished_tracks_and_resumes(scene, reference, tmp_path):
    out = tmp_path / "out"
    sent = []

    def interrupt_once(info):
        if not sent:
            sent.append(info)
            os.kill(os.getpid(), signal.SIGINT)

    with pytest.raises(RunInterrupted):
        fit_dataset(scene, out, FitConfig(), workers=2, on_track=interrupt_once)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["counts"]["done"] >= 1
    assert summary["counts"]["done"] + summary["counts"]["not_run"] == 4
    fit_dataset(scene, out, FitConfig(), workers=2, resume=True)
    assert_same_run(out, reference)


def test_resume_clears_a_track_whose_writing_was_cut(scene, reference, tmp_path):
    """As after a SIGKILL while a track was being written: some of its files, its list of files, no marker.
    Resume removes them and runs the track again."""
    import shutil

    from pedx_graph.execution.outdir import RunFolder

    out = tmp_path / "out"
    shutil.copytree(reference, out)
    marker = sorted((out / "done").rglob("*.json"))[0]
    record = json.loads(marker.read_text())
    marker.unlink()
    listing = marker.with_name(marker.stem + ".writing")
    listing.write_text(json.dumps(record["files"]))
    for rel in record["files"][3:]:
        (out / rel).unlink()                    # three frames written, the rest never
    (out / record["files"][0]).write_bytes(b"{truncated")
    every = {(t["sequence"], t["tracking_id"]) for t in json.loads((reference / "summary.json").read_text())["tracks"]}
    assert RunFolder(out, {}).completed() == every - {(record["sequence"], record["tracking_id"])}
    seen = []
    fit_dataset(scene, out, FitConfig(), resume=True, on_track=seen.append)
    assert [(i["sequence"], i["tracking_id"]) for i in seen] == [(record["sequence"], record["tracking_id"])]
    assert not listing.exists()
    assert_same_run(out, reference)


def test_the_summary_is_written_when_a_run_aborts(scene, tmp_path):
    """An error outside any track (here the caller's callback) stops the run; the summary says so."""
    out = tmp_path / "out"

    def broken_callback(info):
        raise RuntimeError("the caller's callback failed")

    with pytest.raises(RuntimeError, match="callback failed"):
        fit_dataset(scene, out, FitConfig(), on_track=broken_callback)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "aborted" and "callback failed" in summary["error"]
    assert summary["counts"]["done"] == 1 and summary["counts"]["not_run"] == 3 and len(summary["tracks"]) == 1


def test_a_track_whose_files_cannot_be_written_fails_alone(scene, reference, tmp_path, monkeypatch):
    """A directory squatting on one result path and a full disk halfway through another track: those two
    tracks fail (their other files removed, no marker), the others are written unchanged."""
    import pedx_graph.execution.outdir as outdir

    out = tmp_path / "out"
    ref_labels = [p.relative_to(reference).as_posix() for p in label_paths(reference)]
    tids = sorted({name.rsplit("_", 1)[1][:-5] for name in ref_labels})
    full_disk_tid = tids[0]
    calls = {"n": 0}
    real_write = outdir.atomic_write_bytes

    def write(path, data):
        if Path(path).name.endswith(f"_{full_disk_tid}.json"):
            calls["n"] += 1
            if calls["n"] == 3:                 # two frames of the track are written, then the disk is full
                raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real_write(path, data)

    squatted = {}

    def squat(info):                            # after the first track: a folder where a later one writes
        if not squatted:
            tid = next(t for t in tids if t not in (info["tracking_id"], full_disk_tid))
            squatted["tid"] = tid
            (out / next(n for n in ref_labels if n.endswith(f"_{tid}.json"))).mkdir(parents=True)

    monkeypatch.setattr(outdir, "atomic_write_bytes", write)
    summary = fit_dataset(scene, out, FitConfig(), on_track=squat)
    failed = {f["tracking_id"]: f for f in summary["failed"]}
    assert set(failed) == {squatted["tid"], full_disk_tid}
    assert all(f["stage"] == "write" for f in failed.values())
    assert "IsADirectoryError" in failed[squatted["tid"]]["error"]
    assert "No space left" in failed[full_disk_tid]["error"]
    assert summary["counts"] == {"tracks": 4, "done": 2, "failed": 2, "not_run": 0}
    written = {p.relative_to(out).as_posix() for p in label_paths(out)}
    for tid in (squatted["tid"], full_disk_tid):
        assert not [name for name in written if name.endswith(f"_{tid}.json")]   # nothing half-written
    assert not list((out / "done").rglob("*.writing"))
    for name in written:                        # the good tracks: byte for byte the reference
        assert (out / name).read_bytes() == (reference / name).read_bytes()
    assert len(written) == 16 and json.loads((out / "summary.json").read_text())["counts"]["failed"] == 2


def test_a_non_finite_estimate_is_a_failed_track_not_a_result(scene, reference, tmp_path, monkeypatch):
    import pedx_graph.solvers.fit as fit_module

    real_fit = fit_module.fit_track
    victim = {}

    def fit_track(track, config=None, context=None):
        result = real_fit(track, config, context)
        if not victim:
            victim["tid"] = track.tracking_id
            result.trans = result.trans.copy()
            result.trans[2] = np.nan
        return result

    monkeypatch.setattr(fit_module, "fit_track", fit_track)
    out = tmp_path / "out"
    summary = fit_dataset(scene, out, FitConfig())
    (bad,) = summary["failed"]
    assert bad["tracking_id"] == victim["tid"] and bad["stage"] == "task" and "non-finite" in bad["error"]
    names = [p.name for p in label_paths(out)]
    assert len(names) == 24 and not [n for n in names if n.endswith(f"_{victim['tid']}.json")]
    for path in label_paths(out):
        rel = path.relative_to(out)
        assert path.read_bytes() == (reference / rel).read_bytes()


def test_unusable_results_folders_are_refused_before_anything_is_written(scene, reference, tmp_path):
    import shutil

    from pedx_graph.data.types import DataFormatError

    before = files_of(scene)
    for dataset, out in ((scene, scene), (scene, scene / "results"), (scene.parent, scene.parent / "results")):
        with pytest.raises(RunFolderError, match="dataset or inside it"):
            fit_dataset(dataset, out, FitConfig())
    assert files_of(scene) == before and not (scene.parent / "results").exists()
    # a folder with other files
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "notes.txt").write_text("mine")
    with pytest.raises(RunFolderError, match="not empty"):
        fit_dataset(scene, busy, FitConfig())
    with pytest.raises(RunFolderError, match="manifest"):
        fit_dataset(scene, busy, FitConfig(), resume=True)
    assert sorted(p.name for p in busy.iterdir()) == ["notes.txt"]
    # a missing dataset creates nothing
    with pytest.raises(DataFormatError):
        fit_dataset(tmp_path / "nope", tmp_path / "never", FitConfig())
    assert not (tmp_path / "never").exists()
    # resume with another config or another command is refused, naming the manifest key
    changed = FitConfig()
    changed.solver.max_iterations += 1
    with pytest.raises(RunFolderError, match="config_sha256"):
        fit_dataset(scene, reference, changed, resume=True)
    from pedx_graph.baselines.run import fit_dataset_baseline
    with pytest.raises(RunFolderError, match="'command'"):
        fit_dataset_baseline(scene, reference, "triangulation", resume=True)
    # overwrite never empties a dataset
    copy = tmp_path / "copy"
    shutil.copytree(scene, copy)
    with pytest.raises(RunFolderError, match="holds a dataset"):
        fit_dataset(scene, copy, FitConfig(), overwrite=True)
    assert files_of(copy) == before


def test_overwrite_replaces_a_previous_run_and_its_stale_files(scene, reference, tmp_path):
    import shutil

    out = tmp_path / "out"
    shutil.copytree(reference, out)
    stale = out / "labels" / "3d" / "smpl" / "20991231T1200" / "20991231T1200_0000099_gone.json"
    stale.write_text("{}")
    (out / "notes.txt").write_text("kept")
    fit_dataset(scene, out, FitConfig(), overwrite=True)
    assert not stale.exists() and (out / "notes.txt").read_text() == "kept"
    (out / "notes.txt").unlink()
    assert_same_run(out, reference)


def test_files_get_the_umask_permissions(scene, tmp_path):
    from pedx_graph.baselines.run import fit_dataset_baseline

    previous = os.umask(0o027)
    try:
        out = tmp_path / "out"
        fit_dataset_baseline(scene, out, "triangulation")
    finally:
        os.umask(previous)
    files = [p for p in out.rglob("*") if p.is_file()]
    assert len(files) > 10
    for path in files:
        assert stat.S_IMODE(path.stat().st_mode) == 0o640, path
    previous = os.umask(0o022)
    try:
        from pedx_graph.utils import atomic_write_text
        path = atomic_write_text(tmp_path / "plain.txt", "x")
    finally:
        os.umask(previous)
    assert stat.S_IMODE(path.stat().st_mode) == 0o644


def _timing_keys(obj, prefix=""):
    if isinstance(obj, dict):
        for key, value in obj.items():
            if TIMING_KEY.search(key):
                yield prefix + key
            yield from _timing_keys(value, prefix + key + ".")
    elif isinstance(obj, list):
        for value in obj:
            yield from _timing_keys(value, prefix)


def test_result_files_hold_no_timings_and_the_summary_keeps_them_apart(scene, reference, tmp_path):
    from pedx_graph.baselines.run import fit_dataset_baseline
    from pedx_graph.solvers.stream import stream_dataset

    stream_out = tmp_path / "stream"
    stream_dataset(scene, stream_out)
    base_out = tmp_path / "base"
    fit_dataset_baseline(scene, base_out, "triangulation")
    for out in (reference, stream_out, base_out):
        results = [p for p in out.rglob("*.json") if p.name != "summary.json"]
        assert results
        for path in results:
            assert not list(_timing_keys(json.loads(path.read_text()))), path
        summary = json.loads((out / "summary.json").read_text())
        timings = summary.pop("timings")
        assert not list(_timing_keys(summary))
        assert timings["wall_seconds"] > 0 and len(timings["tracks"]) == 4
        assert all(t["task_seconds"] > 0 for t in timings["tracks"])
    causal = list((stream_out / "causal").rglob("*.json"))
    assert len(causal) == 32 and "timestamp" in json.loads(causal[0].read_text())


def test_repeats_and_executors_are_byte_identical(scene, reference, tmp_path):
    """The same seeded run in this process, again, on 2 local processes and on a 2-worker LocalCluster."""
    for name, kwargs in (("again", {}), ("workers2", {"workers": 2}), ("cluster", {"cluster": "local:2"})):
        out = tmp_path / name
        summary = fit_dataset(scene, out, FitConfig(), **kwargs)
        assert summary["status"] == "complete" and summary["counts"]["done"] == 4
        assert_same_run(out, reference)
    executors = {json.loads((tmp_path / n / "summary.json").read_text())["execution"]["executor"]
                 for n in ("again", "workers2", "cluster")}
    assert executors == {"inline", "local", "dask"}
