"""One execution path, local or distributed (issue 14, item 1): the same per-track task on a Dask cluster
(a running scheduler and ``local:N``) for fit, stream and baseline; a lost worker (Dask or local pool) is
retried; the CLI stops cleanly on SIGINT (exit 130, one line) and leaves no worker behind after SIGKILL."""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import distributed
import psutil
import pytest
from scene_fixtures import small_scene

from pedx_graph.graph.config import FitConfig
from pedx_graph.solvers.fit import fit_dataset

RUN_SPECIFIC = ("summary.json", "timings.jsonl")


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return small_scene(tmp_path_factory.mktemp("scene") / "data", pedestrians=4, frames=6, seed=11)


@pytest.fixture(scope="module")
def cluster():
    """A running 2-worker cluster, reached by its scheduler address (as a fleet's would be)."""
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=40) as running:
        yield running


def same_results(a: Path, b: Path) -> None:
    fa = {p.relative_to(a).as_posix(): p.read_bytes() for p in a.rglob("*") if p.is_file()}
    fb = {p.relative_to(b).as_posix(): p.read_bytes() for p in b.rglob("*") if p.is_file()}
    assert sorted(fa) == sorted(fb)
    assert [n for n in fa if n not in RUN_SPECIFIC and fa[n] != fb[n]] == []
    sa, sb = (json.loads((d / "summary.json").read_text()) for d in (a, b))
    for s in (sa, sb):
        s.pop("timings"), s.pop("execution")
    assert sa == sb


@pytest.mark.parametrize("command", ["fit", "stream", "baseline"])
def test_a_cluster_runs_the_same_task_as_this_process(scene, cluster, tmp_path, command):
    from pedx_graph.baselines.run import fit_dataset_baseline
    from pedx_graph.solvers.stream import stream_dataset

    run = {"fit": lambda out, **kw: fit_dataset(scene, out, FitConfig(), **kw),
           "stream": lambda out, **kw: stream_dataset(scene, out, **kw),
           "baseline": lambda out, **kw: fit_dataset_baseline(scene, out, "smplify_disp", **kw)}[command]
    here = run(tmp_path / "here")
    there = run(tmp_path / "there", cluster=cluster.scheduler_address)
    assert here["status"] == there["status"] == "complete" and there["counts"]["done"] == 4
    assert there["execution"] == {"executor": "dask", "cluster": cluster.scheduler_address, "resumed": False,
                                  "tracks_from_earlier_runs": 0}
    assert here["execution"]["executor"] == "inline"
    workers = {t["worker"] for t in there["timings"]["tracks"]}
    assert all(w.split(":")[1] != str(os.getpid()) for w in workers)     # computed on the cluster's workers
    same_results(tmp_path / "here", tmp_path / "there")


def test_a_lost_dask_worker_is_retried(scene, cluster, tmp_path):
    """A worker killed after the first track: the scheduler reschedules its task on the other one."""
    client = distributed.Client(cluster.scheduler_address, set_as_default=False)
    killed = []

    def kill_a_worker(info):
        if not killed:
            pid = sorted(client.run(os.getpid).values())[0]
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)

    try:
        summary = fit_dataset(scene, tmp_path / "out", FitConfig(), cluster=cluster.scheduler_address,
                              on_track=kill_a_worker)
        reference = fit_dataset(scene, tmp_path / "ref", FitConfig())
        client.wait_for_workers(2, timeout=60)      # the nanny restarts the killed worker for later tests
    finally:
        client.close()
    assert killed
    assert summary["status"] == "complete" and summary["counts"]["done"] == 4 and not summary["failed"]
    same_results(tmp_path / "out", tmp_path / "ref")
    assert reference["counts"]["done"] == 4


def test_a_lost_local_worker_is_retried(scene, tmp_path):
    """A local pool worker killed after the first track: the pool is rebuilt, its tasks submitted again."""
    killed = []
    before = {p.pid for p in psutil.Process().children()}      # e.g. the cluster fixture's processes

    def kill_a_worker(info):
        if not killed:
            pool = sorted(p.pid for p in psutil.Process().children() if p.pid not in before and p.is_running())
            os.kill(pool[0], signal.SIGKILL)
            killed.append(pool[0])

    summary = fit_dataset(scene, tmp_path / "out", FitConfig(), workers=2, on_track=kill_a_worker)
    fit_dataset(scene, tmp_path / "ref", FitConfig())
    assert killed and summary["execution"]["worker_losses"] == 1
    assert summary["status"] == "complete" and summary["counts"]["done"] == 4 and not summary["failed"]
    same_results(tmp_path / "out", tmp_path / "ref")


# --- the command line, in a subprocess ----------------------------------------------------------------------
@pytest.fixture(scope="module")
def slow_scene(tmp_path_factory):
    """Enough work that a run is still going when the first track is done (8 tracks of 10-12 frames)."""
    return small_scene(tmp_path_factory.mktemp("slow") / "data", pedestrians=8, frames=12, seed=5)


def start_cli(dataset: Path, out: Path, *flags: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    return subprocess.Popen([sys.executable, "-m", "pedx_graph.cli", "fit", str(dataset), "--out", str(out),
                             *flags], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)      # its own process group, as a shell job


def wait_for_first_marker(proc: subprocess.Popen, out: Path, timeout_s: float = 240.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if list((out / "done").rglob("*.json")):
            return
        if proc.poll() is not None:
            raise AssertionError(f"the run ended before a track was done: {proc.communicate()}")
        time.sleep(0.05)
    raise AssertionError("no track finished in time")


def gone(processes: list, within_s: float) -> list:
    """Those of ``processes`` still alive after ``within_s`` seconds (zombies count as gone)."""
    deadline = time.monotonic() + within_s
    while True:
        alive = [p for p in processes if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]
        if not alive or time.monotonic() > deadline:
            return alive
        time.sleep(0.1)


@pytest.mark.parametrize("flags", [("--workers", "2"), ("--cluster", "local:2")], ids=["workers", "cluster"])
def test_ctrl_c_stops_the_cli_cleanly_and_keeps_finished_tracks(slow_scene, tmp_path, flags):
    out = tmp_path / "out"
    proc = start_cli(slow_scene, out, *flags)
    wait_for_first_marker(proc, out)
    workers = psutil.Process(proc.pid).children(recursive=True)
    assert workers
    os.killpg(proc.pid, signal.SIGINT)           # Ctrl-C: the whole process group
    stdout, stderr = proc.communicate(timeout=60)   # (the remaining tracks would take longer: not waited for)
    assert proc.returncode == 130
    lines = [line for line in stderr.splitlines() if line.strip()]
    assert "interrupted" in lines[-1] and "--resume" in lines[-1]
    assert "Traceback" not in stderr, stderr[-2000:]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "interrupted" and summary["counts"]["done"] >= 1
    assert summary["counts"]["not_run"] >= 1
    assert len(list((out / "done").rglob("*.json"))) == summary["counts"]["done"]
    assert not gone(workers, 10.0)


@pytest.mark.parametrize("flags", [("--workers", "2"), ("--cluster", "local:2")], ids=["workers", "cluster"])
def test_sigkill_of_the_cli_leaves_no_orphan_worker(slow_scene, tmp_path, flags):
    out = tmp_path / "out"
    proc = start_cli(slow_scene, out, *flags)
    wait_for_first_marker(proc, out)
    workers = psutil.Process(proc.pid).children(recursive=True)
    assert len(workers) >= 2 and proc.poll() is None
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate(timeout=30)
    survivors = gone(workers, 10.0)
    for p in survivors:                          # never leave them running, even when the test fails
        p.kill()
    assert not survivors
