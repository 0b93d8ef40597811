"""Benchmark of the execution path over tracks (seeded): Dask speed-up, per-task overhead, memory at scale.

1. Speed-up: ``fit_dataset`` on a 40-track scene through the Dask path, ``--cluster local:1`` vs ``local:2``
   (and the local process pool, ``--workers 1`` / ``2``, for reference); the figure is the ratio of the run
   loops' wall times (first task submitted to last track written, ``summary.json`` timings; the shortest of
   ``--repeats`` runs), so the cluster's start-up, the workers' warm-up and the dataset's first reading are
   left out (they are reported beside it).  What the shared machine allows at that moment is measured
   beside it: a pure-Python loop in 1 and in 2 processes.
2. Per-task overhead: tasks that do nothing (each still carrying a real 3-frame track to and a result from
   the worker) through each executor with 2 workers, kept as full as ``pedx-graph fit`` keeps them;
   overhead per task = wall time x workers / tasks.
3. Memory at scale: ``pedx-graph fit --cluster local:2`` in a subprocess on 250 / 500 / 1000 short tracks
   (3 frames; one dataset of four 250-track sequences, chosen with ``--sequence``), the resident memory of
   the command and of its worker processes sampled every 0.2 s; the peaks should not grow with the number
   of tracks (the dataset is read lazily, results are written as tracks complete, the summary is streamed).

Scenes: one simulated scene per part (seeded); its tracks are written again under new tracking ids until the
wanted number of tracks is reached (identical work per copy, so the speed-up is not blurred by one long
track).  The machine is shared with other jobs: the load average before and after is in the hardware line.

    python benchmarks/bench_scale.py [--seed 0] [--speedup-tracks 40] [--repeats 2] [--overhead-tasks 200]
                                     [--memory-sizes 250,500,1000] [--out benchmarks/results]

Writes ``bench_scale.json`` and ``bench_scale.md`` into ``--out``.
"""
from __future__ import annotations

import argparse
import copy
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from _common import cell, hardware, public_args  # noqa: E402
from pedx_graph.data.reader import read_dataset  # noqa: E402
from pedx_graph.data.writer import write_tracks  # noqa: E402
from pedx_graph.execution.tasks import TrackOutput, TrackTask  # noqa: E402
from pedx_graph.graph.config import FitConfig  # noqa: E402
from pedx_graph.sim.config import SimConfig  # noqa: E402
from pedx_graph.sim.simulate import simulate  # noqa: E402
from pedx_graph.solvers.fit import fit_dataset  # noqa: E402
from pedx_graph.utils import atomic_write_json, atomic_write_text  # noqa: E402


# --- scenes ------------------------------------------------------------------------------------------------
def source_tracks(work: Path, seed: int, pedestrians: int, frames: int, min_frames: int) -> list:
    """Tracks of one simulated scene with at least ``min_frames`` frames, cut to ``frames``."""
    cfg = SimConfig()
    cfg.scene.n_pedestrians = pedestrians
    cfg.scene.n_frames = frames
    scene = work / f"source_{seed}_{pedestrians}_{frames}"
    simulate(scene, cfg, seed=seed)
    tracks = [t for t in read_dataset(scene) if len(t.frames) >= min_frames]
    for track in tracks:
        track.frames = track.frames[:frames]
    if not tracks:
        raise RuntimeError("the simulated scene has no track long enough")
    return tracks


def replicated(tracks: list, n: int, sequence: str, salt: str) -> list:
    """``n`` tracks cycling through ``tracks``, each under a new tracking id, in ``sequence``."""
    out = []
    for k in range(n):
        track = copy.copy(tracks[k % len(tracks)])
        track.sequence = sequence
        track.tracking_id = hashlib.md5(f"{salt}-{sequence}-{k}".encode()).hexdigest()
        out.append(track)
    return out


# --- 1. speed-up ------------------------------------------------------------------------------------------------
def burn(n: int) -> int:
    """Pure-Python arithmetic: what a core gives a process now."""
    total = 0
    for i in range(n):
        total += i * i
    return total


def machine_ceiling(n: int = 15_000_000) -> dict:
    """Speed-up of a pure-CPU loop on 2 processes vs 1, now (other jobs share the cores)."""
    import multiprocessing

    t0 = time.perf_counter()
    burn(n)
    burn(n)
    serial = time.perf_counter() - t0
    with multiprocessing.get_context("fork").Pool(2) as pool:
        t0 = time.perf_counter()
        pool.map(burn, [n, n])
        parallel = time.perf_counter() - t0
    return {"serial_seconds": serial, "two_processes_seconds": parallel, "speedup": serial / parallel}


def speedup(dataset: Path, work: Path, repeats: int) -> list[dict]:
    rows = []
    for label, kwargs in (("dask local:1", {"cluster": "local:1"}), ("dask local:2", {"cluster": "local:2"}),
                          ("local pool, --workers 1 (in process)", {"workers": 1}),
                          ("local pool, --workers 2", {"workers": 2})):
        runs = []
        for r in range(repeats):
            out = work / f"speedup_{len(rows)}_{r}"
            summary = fit_dataset(dataset, out, FitConfig(), keep_records=False, **kwargs)
            timings = summary["timings"]
            runs.append({"tracks": summary["counts"]["done"], "failed": summary["counts"]["failed"],
                         "loop_seconds": timings["loop_seconds"], "setup_seconds": timings["setup_seconds"],
                         "wall_seconds": timings["wall_seconds"],
                         "task_seconds_sum": sum(t["task_seconds"] for t in timings["tracks"])})
        best = min(runs, key=lambda run: run["loop_seconds"])
        rows.append({"executor": label, **best, "loop_seconds_all": [run["loop_seconds"] for run in runs]})
        print(f"speed-up: {label}: loop {best['loop_seconds']:.1f} s (of {rows[-1]['loop_seconds_all']}), setup "
              f"{best['setup_seconds']:.1f} s", flush=True)
    return rows


# --- 2. per-task overhead -----------------------------------------------------------------------------------------
def noop_task(track, params) -> TrackOutput:
    """A task that computes nothing: what is left of its wall time is the executor's."""
    return TrackOutput(files=[], records=[{"sequence": track.sequence, "tracking_id": track.tracking_id}])


def overhead(tracks: list, n_tasks: int) -> list[dict]:
    from pedx_graph.execution.executors import DaskExecutor, InlineExecutor, LocalPoolExecutor

    rows = []
    for label, make, workers in (("in process", InlineExecutor, 1),
                                 ("local pool, 2 workers", lambda: LocalPoolExecutor(2), 2),
                                 ("dask LocalCluster, 2 workers", lambda: DaskExecutor("local:2"), 2)):
        executor = make()
        try:
            warm = [executor.submit(TrackTask(noop_task, tracks[i % len(tracks)], None, i, "bench"))
                    for i in range(2 * workers)]          # processes started, modules imported
            while warm:
                for handle in executor.wait(warm, 1.0):
                    warm.remove(handle)
            t0 = time.perf_counter()
            submitted, inflight, done = 0, [], 0
            while done < n_tasks:
                while submitted < n_tasks and len(inflight) < executor.slots():
                    task = TrackTask(noop_task, tracks[submitted % len(tracks)], None, submitted, "bench")
                    inflight.append(executor.submit(task))
                    submitted += 1
                for handle in executor.wait(inflight, 0.2):
                    inflight.remove(handle)
                    assert executor.outcome(handle).ok
                    done += 1
            wall = time.perf_counter() - t0
        finally:
            executor.close()
        rows.append({"executor": label, "workers": workers, "tasks": n_tasks, "wall_seconds": wall,
                     "overhead_ms_per_task": 1e3 * wall * workers / n_tasks})
        print(f"overhead: {label}: {rows[-1]['overhead_ms_per_task']:.2f} ms per task", flush=True)
    return rows


# --- 3. memory at scale --------------------------------------------------------------------------------------------
class TreeMemory:
    """Samples the resident memory of a process and of its descendants in a thread."""

    def __init__(self, pid: int, period_s: float = 0.2):
        import psutil

        self.root = psutil.Process(pid)
        self.period_s = period_s
        self.peak_parent = self.peak_total = self.peak_worker = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        import psutil

        while not self._stop.is_set():
            try:
                parent = self.root.memory_info().rss
                children = []
                for child in self.root.children(recursive=True):
                    try:
                        children.append(child.memory_info().rss)
                    except psutil.Error:
                        pass
            except psutil.Error:
                break
            self.peak_parent = max(self.peak_parent, parent)
            self.peak_total = max(self.peak_total, parent + sum(children))
            self.peak_worker = max([self.peak_worker] + children)
            time.sleep(self.period_s)

    def stop(self):
        self._stop.set()
        self._thread.join()


def memory(dataset: Path, sequences: list[str], sizes: list[int], per_sequence: int, work: Path) -> list[dict]:
    rows = []
    for size in sizes:
        chosen = sequences[:size // per_sequence]
        out = work / f"memory_{size}"
        cmd = [sys.executable, "-m", "pedx_graph.cli", "fit", str(dataset), "--out", str(out), "--cluster", "local:2",
               "--no-progress"] + [arg for seq in chosen for arg in ("--sequence", seq)]
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        sampler = TreeMemory(proc.pid)
        stdout, stderr = proc.communicate()
        sampler.stop()
        if proc.returncode != 0:
            raise RuntimeError(f"fit of {size} tracks failed ({proc.returncode}): {stderr[-2000:]}")
        summary = json.loads((out / "summary.json").read_text())
        timings = summary["timings"]
        rows.append({"tracks": size, "done": summary["counts"]["done"], "failed": summary["counts"]["failed"],
                     "frames": summary["total_frames"], "peak_command_mib": sampler.peak_parent / 2 ** 20,
                     "peak_worker_mib": sampler.peak_worker / 2 ** 20, "peak_total_mib": sampler.peak_total / 2 ** 20,
                     "loop_seconds": timings["loop_seconds"], "setup_seconds": timings["setup_seconds"],
                     "tracks_per_second": size / timings["loop_seconds"]})
        print(f"memory: {size} tracks: command {rows[-1]['peak_command_mib']:.0f} MiB, worker "
              f"{rows[-1]['peak_worker_mib']:.0f} MiB, total {rows[-1]['peak_total_mib']:.0f} MiB, "
              f"loop {timings['loop_seconds']:.0f} s", flush=True)
    return rows


# --- report ----------------------------------------------------------------------------------------------------------
def markdown(result: dict) -> str:
    sp = {r["executor"]: r for r in result["speedup"]}
    dask1, dask2 = sp["dask local:1"], sp["dask local:2"]
    pool1, pool2 = sp["local pool, --workers 1 (in process)"], sp["local pool, --workers 2"]
    lines = ["# Scale-out: one task per track, locally or on Dask", "",
             f"Command: `python benchmarks/bench_scale.py {' '.join(result['args'])}`  ",
             f"Hardware: {result['hardware']}; load average before: {result['load_before']}.", "",
             "## Method", "",
             "* Speed-up: `fit_dataset` (batch LM, default config) on "
             f"{dask1['tracks']} tracks of {result['speedup_frames']} frames (a simulated scene's tracks written "
             "again under new ids, seed " f"{result['seed']}), ratio of the run loops' wall times (first task "
             "submitted to last track written; the shortest of "
             f"{result['repeats']} runs); cluster start-up, the workers' warm-up and the dataset's first reading "
             "are reported as setup.  The machine's ceiling at that moment: a pure-Python loop on 2 processes vs 1 "
             f"ran {result['ceiling']['speedup']:.2f}x faster.",
             "* Overhead: tasks that compute nothing (each carries a 3-frame track to the worker and brings a "
             f"record back), {result['overhead'][0]['tasks']} per executor, the executor kept as full as a run keeps "
             "it; overhead per task = wall x workers / tasks.",
             "* Memory: `pedx-graph fit --cluster local:2` in a subprocess on datasets of "
             f"{', '.join(str(r['tracks']) for r in result['memory'])} tracks of {result['memory_frames']} frames; "
             "resident memory of the command (client, scheduler, nannies) and of each worker process sampled every "
             "0.2 s.", "",
             "## Speed-up (goal >= 1.8x with 2 workers)", "",
             "| executor | tracks | failed | loop s | setup s | sum of task s |", "|---|---|---|---|---|---|"]
    for r in result["speedup"]:
        lines.append(f"| {r['executor']} | {r['tracks']} | {r['failed']} | {cell(r['loop_seconds'])} | "
                     f"{cell(r['setup_seconds'])} | {cell(r['task_seconds_sum'])} |")
    lines += ["", f"Dask local:2 vs local:1: **{dask1['loop_seconds'] / dask2['loop_seconds']:.2f}x**; local pool "
              f"2 workers vs in process: {pool1['loop_seconds'] / pool2['loop_seconds']:.2f}x; a pure-CPU loop on 2 "
              f"processes vs 1 at the same time: {result['ceiling']['speedup']:.2f}x.", "",
              "## Per-task overhead", "", "| executor | workers | tasks | wall s | overhead ms / task |",
              "|---|---|---|---|---|"]
    for r in result["overhead"]:
        lines.append(f"| {r['executor']} | {r['workers']} | {r['tasks']} | {cell(r['wall_seconds'], '.2f')} | "
                     f"{cell(r['overhead_ms_per_task'], '.2f')} |")
    lines += ["", "## Memory at scale (LocalCluster, 2 workers)", "",
              "| tracks | done | failed | frames | peak command MiB | peak worker MiB | peak total MiB | loop s | "
              "tracks / s |", "|---|---|---|---|---|---|---|---|---|"]
    for r in result["memory"]:
        lines.append(f"| {r['tracks']} | {r['done']} | {r['failed']} | {r['frames']} | "
                     f"{cell(r['peak_command_mib'], '.0f')} | "
                     f"{cell(r['peak_worker_mib'], '.0f')} | {cell(r['peak_total_mib'], '.0f')} | "
                     f"{cell(r['loop_seconds'], '.0f')} | {cell(r['tracks_per_second'], '.1f')} |")
    lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--speedup-tracks", type=int, default=40)
    parser.add_argument("--speedup-frames", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=2, help="runs per executor in the speed-up (shortest kept)")
    parser.add_argument("--overhead-tasks", type=int, default=200)
    parser.add_argument("--memory-sizes", default="250,500,1000",
                        help="dataset sizes in tracks (multiples of the first)")
    parser.add_argument("--memory-frames", type=int, default=3)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "results"))
    args = parser.parse_args(argv)
    sizes = [int(x) for x in args.memory_sizes.split(",")]
    per_sequence = sizes[0]
    if any(s % per_sequence for s in sizes):
        parser.error("--memory-sizes must be multiples of the first size")
    load_before = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        long_tracks = source_tracks(work, args.seed, 12, args.speedup_frames, args.speedup_frames // 2)
        speed_data = work / "speedup_data"
        write_tracks(speed_data, replicated(long_tracks, args.speedup_tracks, "20991231T1200", f"s{args.seed}"))
        short = source_tracks(work, args.seed + 1, 12, args.memory_frames, args.memory_frames)
        memory_data = work / "memory_data"
        sequences = [f"20991231T{1201 + k:04d}" for k in range(max(sizes) // per_sequence)]
        write_tracks(memory_data, [t for k, seq in enumerate(sequences)
                                   for t in replicated(short, per_sequence, seq, f"m{args.seed}")])
        result = {"args": public_args(sys.argv[1:] if argv is None else argv), "seed": args.seed,
                  "speedup_frames": args.speedup_frames, "memory_frames": args.memory_frames,
                  "repeats": args.repeats, "load_before": load_before}
        result["ceiling"] = machine_ceiling()
        result["speedup"] = speedup(speed_data, work, args.repeats)
        result["overhead"] = overhead(short, args.overhead_tasks)
        result["memory"] = memory(memory_data, sequences, sizes, per_sequence, work)
    result["hardware"] = hardware()
    out = Path(args.out)
    atomic_write_json(out / "bench_scale.json", result)
    atomic_write_text(out / "bench_scale.md", markdown(result))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
