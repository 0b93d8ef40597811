"""The run loop shared by ``fit``, ``stream`` and ``baseline``: read the dataset lazily, feed one task per
track to an executor, write each track as it completes, and survive faults and interrupts.

:func:`run_dataset` (a :class:`RunSpec` says what to run):

1. the results folder is checked (:meth:`RunFolder.check`: nothing is created for a refused run or a bad
   dataset) and the executor made;
2. a first lazy pass over the dataset gives the track order and each sequence's ground (and whatever the
   spec's ``make_params`` needs, e.g. the noise estimate); tracks are never all held in memory;
3. the folder is prepared (manifest, configs); with ``resume`` tracks with a completion marker are skipped;
4. tracks are read again one at a time and submitted while at most ``executor.slots()`` are in flight;
   each finished track is written at once (files, then its marker; completion order) and its timings
   appended; a failing track (computation, write, lost worker) is recorded and the run goes on;
5. ``summary.json`` is written in every case (complete, interrupted, aborted), tracks in dataset order,
   every time-dependent figure in its ``timings`` section; interrupts raise :class:`RunInterrupted`.

SIGINT or SIGTERM: pending tasks are cancelled and running ones stopped (local workers terminated, the
local Dask cluster closed), finished tracks are kept, the summary is written; a second signal raises
``KeyboardInterrupt`` at once.
"""
from __future__ import annotations

import logging
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from pedx_graph import __version__
from pedx_graph.execution.executors import ExecutorSpec, make_executor
from pedx_graph.execution.outdir import RunFolder, build_manifest
from pedx_graph.execution.tasks import TaskOutcome, TrackTask

log = logging.getLogger(__name__)

SUMMARY_FORMAT = "pedx-graph summary 2"


class RunInterrupted(KeyboardInterrupt):
    """A run stopped by SIGINT / SIGTERM after writing what it had finished and its summary."""

    def __init__(self, summary: dict | None, signum: int):
        super().__init__(f"interrupted by signal {signum}")
        self.summary = summary
        """The summary written (None when the run stopped before its results folder was made)."""
        self.signum = signum

    @property
    def exit_code(self) -> int:
        """The shell's convention: 128 + the signal number (130 for SIGINT)."""
        return 128 + int(self.signum)


class SignalGuard:
    """SIGINT / SIGTERM during a run: the first asks the run to stop (:attr:`signum`); inside
    :meth:`raising` (work done in this process), or at a second signal, ``KeyboardInterrupt`` is raised."""

    def __init__(self):
        self.signum: int | None = None
        self._raising = 0
        self._previous: dict = {}

    def __enter__(self) -> "SignalGuard":
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()

    def _handle(self, signum, frame) -> None:
        first = self.signum is None
        if first:
            self.signum = signum
        if self._raising or not first:
            raise KeyboardInterrupt

    @contextmanager
    def raising(self) -> Iterator[None]:
        """Signals raise ``KeyboardInterrupt`` inside this block (one already received: raised now)."""
        if self.signum is not None:
            raise KeyboardInterrupt
        self._raising += 1
        try:
            yield
        finally:
            self._raising -= 1


class DatasetTracks:
    """The dataset's tracks as a re-iterable: each iteration reads them again lazily (one track in memory
    at a time); the first complete iteration records the track order (:attr:`keys`) and each sequence's
    ground (:attr:`grounds`)."""

    def __init__(self, dataset, sequences=None, reader_config=None):
        self.dataset = dataset
        self.sequences = sequences
        self.reader_config = reader_config
        self.keys: list[tuple[str, str]] | None = None
        self.grounds: dict[str, dict] | None = None
        self.passes = 0
        self._repeats = _Repeats()

    def __iter__(self):
        from pedx_graph.data.reader import iter_tracks

        keys, grounds = [], {}
        with _quiet_repeats(self._repeats):
            self.passes += 1
            for track in iter_tracks(self.dataset, self.sequences, self.reader_config):
                keys.append((track.sequence, track.tracking_id))
                if track.ground is not None and track.sequence not in grounds:
                    grounds[track.sequence] = track.ground.to_dict()
                yield track
        if self.keys is None:
            self.keys = keys
            self.grounds = dict(sorted(grounds.items()))

    def index(self) -> list[tuple[str, str]]:
        """The track order (reading the dataset once if no pass was completed yet)."""
        if self.keys is None:
            for _ in self:
                pass
        return self.keys


class _Repeats(logging.Filter):
    """Drops a log record identical to one already emitted (the dataset is read more than once)."""

    def __init__(self):
        super().__init__()
        self.seen: set = set()

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.name, record.levelno, record.getMessage())
        if key in self.seen:
            return False
        self.seen.add(key)
        return True


@contextmanager
def _quiet_repeats(flt: _Repeats):
    """While reading: the data loggers' warnings are shown once per run, not once per pass."""
    names = [name for name in list(logging.root.manager.loggerDict) if name.startswith("pedx_graph.data")]
    loggers = [logging.getLogger(name) for name in names + ["pedx_graph.data"]]
    for lg in loggers:
        lg.addFilter(flt)
    try:
        yield
    finally:
        for lg in loggers:
            lg.removeFilter(flt)


@dataclass
class RunSpec:
    """What a run computes; the rest (executor, folder, resume) is shared."""

    command: str
    """``fit``, ``stream`` or ``baseline`` (the manifest's and the summary's ``command``)."""
    method: str
    """Solver or baseline name."""
    method_key: str
    """Summary key holding ``method`` (``solver`` or ``baseline``)."""
    dataset: Any
    task_fn: Callable
    """Module-level ``fn(track, params) -> TrackOutput`` run in the workers."""
    configs: dict
    """Name -> config saved as ``<name>.yaml`` in the folder and hashed into the manifest."""
    make_params: Callable[[DatasetTracks], tuple[Any, dict]]
    """``make_params(tracks) -> (task params, extra summary sections)``, after the first pass."""
    sequences: list[str] | None = None
    reader_config: Any = None
    summarise_timings: Callable[[list[dict]], dict] | None = None
    """Whole-run timing figures from the per-track timings (e.g. the stream's update latencies)."""
    warm_up: Callable[[Any], None] | None = None
    """Module-level ``warm_up(params)`` run once by every worker before the first track (loads the body
    model and priors; a local pool's workers inherit this process's).  Its errors stop the run before
    anything is written."""
    inline_only: bool = False
    """The params hold objects meant for this process only (e.g. a given estimator context)."""


@dataclass
class _Progress:
    previous: int = 0
    """Tracks done by earlier runs (resume)."""
    done: int = 0
    """Tracks done, earlier runs included."""
    failed: list = field(default_factory=list)
    failed_keys: set = field(default_factory=set)


def run_dataset(spec: RunSpec, out, executor: ExecutorSpec | None = None, resume: bool = False,
                overwrite: bool = False, progress: bool = False, keep_records: bool = True,
                on_track: Callable[[dict], None] | None = None) -> dict:
    """Run ``spec`` over every track of its dataset into ``out`` (see the module docstring); returns the
    summary (with its ``tracks`` records when ``keep_records``, else their count only).

    ``on_track(info)`` is called in this process after each track is written or recorded as failed
    (``info``: sequence, tracking_id, status, done, failed, total).  Raises :class:`RunInterrupted` after
    SIGINT / SIGTERM (the summary written), :class:`~pedx_graph.execution.outdir.RunFolderError` for an
    unusable ``out``, :class:`~pedx_graph.execution.executors.ExecutorError` for a bad cluster.
    """
    executor_spec = executor or ExecutorSpec()
    if spec.inline_only and (executor_spec.cluster or executor_spec.workers > 1):
        raise ValueError(f"{spec.command}: a given estimator context runs in this process only (workers=1)")
    t0 = time.perf_counter()
    manifest = build_manifest(spec.command, spec.method, spec.dataset, spec.sequences, spec.configs)
    folder = RunFolder.check(out, spec.dataset, manifest, resume=resume, overwrite=overwrite)
    source = DatasetTracks(spec.dataset, spec.sequences, spec.reader_config)
    with SignalGuard() as guard:
        executor = None
        try:
            try:
                executor = make_executor(executor_spec, guard)      # first: an unreachable cluster fails fast
                with guard.raising():                               # (and its start is not cut short)
                    params, sections = spec.make_params(source)
                    keys = source.index()
                    if spec.warm_up is not None:                    # model and priors loaded by every worker
                        executor.warm_up(spec.warm_up, params)
            except KeyboardInterrupt:
                raise RunInterrupted(None, guard.signum or signal.SIGINT) from None
            folder.prepare(spec.configs)
            completed = folder.completed() & set(keys) if not folder.fresh else set()
            if completed:
                log.info("resume: %d of %d tracks already done in %s", len(completed), len(keys), folder.path)
            state = _Progress(previous=len(completed), done=len(completed))
            status, error = "complete", None
            clock = {"setup_seconds": time.perf_counter() - t0}
            t_loop = time.perf_counter()
            try:
                _loop(spec, params, source, keys, completed, folder, executor, guard, state, progress, on_track)
                if guard.signum is not None:
                    status = "interrupted"
            except KeyboardInterrupt:
                status = "interrupted"
                guard.signum = guard.signum or signal.SIGINT
                executor.interrupt([])
            except BaseException as exc:
                status, error = "aborted", f"{type(exc).__name__}: {exc}"
                executor.interrupt([])
                raise
            finally:
                clock["loop_seconds"] = time.perf_counter() - t_loop
                executor.close()
                clock["wall_seconds"] = time.perf_counter() - t0
                summary = _write_summary(spec, folder, keys, source.grounds, sections, executor_spec, state, status,
                                         error, resume and not folder.fresh, clock, keep_records,
                                         getattr(executor, "worker_losses", None))
        finally:
            if executor is not None:
                executor.close()
    if status == "interrupted":
        raise RunInterrupted(summary, guard.signum)
    return summary


def _loop(spec: RunSpec, params, source: DatasetTracks, keys: list, completed: set, folder: RunFolder,
          executor, guard: SignalGuard, state: _Progress, progress: bool, on_track) -> None:
    from tqdm import tqdm

    total = len(keys)
    bar = tqdm(total=total, initial=len(completed), disable=None if progress else True, file=sys.stderr,
               unit="track",
               desc=spec.command, dynamic_ncols=True, leave=True)
    tasks = _tasks(spec, params, source, keys, completed)
    inflight: dict = {}
    try:
        exhausted = False
        while True:
            while not exhausted and guard.signum is None and len(inflight) < executor.slots():
                task = next(tasks, None)
                if task is None:
                    exhausted = True
                    break
                inflight[executor.submit(task)] = task
            if not inflight or guard.signum is not None:
                break
            for handle in executor.wait(list(inflight), timeout=0.2):
                inflight.pop(handle)
                _finish(executor.outcome(handle), folder, state)
                bar.set_postfix(failed=len(state.failed), refresh=False)
                bar.update(1)
                if on_track is not None:
                    key = (handle.task.track.sequence, handle.task.track.tracking_id)
                    on_track({"sequence": key[0], "tracking_id": key[1],
                              "status": "failed" if key in state.failed_keys else "done",
                              "done": state.done, "failed": len(state.failed), "total": total})
            if guard.signum is not None:
                break
    finally:
        if guard.signum is not None or inflight:
            executor.interrupt(list(inflight))
        bar.close()


def _tasks(spec: RunSpec, params, source: DatasetTracks, keys: list, completed: set) -> Iterator[TrackTask]:
    for index, track in enumerate(source):
        key = (track.sequence, track.tracking_id)
        if index >= len(keys) or keys[index] != key:
            raise RuntimeError(f"the dataset changed while it was being run (track {index}: {key}, expected "
                               f"{keys[index] if index < len(keys) else 'none'})")
        if key not in completed:
            yield TrackTask(spec.task_fn, track, params, index, spec.command)


def _finish(outcome: TaskOutcome, folder: RunFolder, state: _Progress) -> None:
    """Write one finished track (or record its failure)."""
    if outcome.ok and outcome.version != __version__:
        outcome.error = (f"VersionMismatch: worker {outcome.worker} runs pedx-graph {outcome.version}, this run "
                         f"{__version__}")
        outcome.stage, outcome.output = "version", None
    if outcome.ok:
        try:
            folder.commit(outcome)
        except Exception as exc:  # noqa: BLE001 -- a full disk, a folder in the way: this track only
            outcome.error, outcome.stage = f"{type(exc).__name__}: {exc}", "write"
            outcome.traceback = traceback.format_exc(limit=4)
    if not outcome.ok:
        log.warning("track %s/%s failed (%s): %s", outcome.sequence, outcome.tracking_id, outcome.stage,
                    outcome.error)
        state.failed.append({"sequence": outcome.sequence, "tracking_id": outcome.tracking_id,
                             "stage": outcome.stage, "error": outcome.error, "traceback": outcome.traceback})
        state.failed_keys.add(outcome.key)
        return
    state.done += 1
    try:
        folder.append_timing(outcome.key, {"task_seconds": outcome.seconds, "worker": outcome.worker,
                                           **outcome.output.timings})
    except OSError as exc:
        log.warning("%s: timings of %s/%s not recorded (%s)", folder.path, outcome.sequence, outcome.tracking_id,
                    exc)


def _write_summary(spec: RunSpec, folder: RunFolder, keys: list, grounds, sections: dict,
                   executor_spec: ExecutorSpec, state: _Progress, status: str, error: str | None, resumed: bool,
                   clock: dict, keep_records: bool, losses: int | None) -> dict:
    failed_keys = {(f["sequence"], f["tracking_id"]) for f in state.failed}
    done_keys = folder.completed() & set(keys)
    not_run = [{"sequence": s, "tracking_id": t} for s, t in keys if (s, t) not in done_keys | failed_keys]
    head = {"format": SUMMARY_FORMAT, "command": spec.command, spec.method_key: spec.method,
            "dataset": str(spec.dataset), "status": status,
            "counts": {"tracks": len(keys), "done": len(done_keys), "failed": len(failed_keys),
                       "not_run": len(not_run)}}
    if error is not None:
        head["error"] = error
    head["ground"] = grounds or {}
    head.update(sections)
    update_failures: list[dict] = []
    frames = {"total": 0}

    def records():
        for key in keys:
            if key not in done_keys:
                continue
            marker = folder.read_marker(key)
            if marker is None:
                continue
            frames["total"] += int(marker.get("frames", 0))
            for record in marker["records"]:
                for bad in record.get("failed_updates", []) or []:
                    update_failures.append({"sequence": key[0], "tracking_id": key[1], "stage": "update", **bad})
                yield record

    timings_by_key = folder.read_timings()
    track_timings = [timings_by_key[key] for key in keys if key in done_keys and key in timings_by_key]
    # wall: the whole call; setup: checks, reading the dataset's index, estimates, the executor's start;
    # loop: from the first task submitted to the last one written
    run_timings = {"wall_seconds": clock["wall_seconds"], "setup_seconds": clock["setup_seconds"],
                   "loop_seconds": clock["loop_seconds"]}
    if spec.summarise_timings is not None:
        run_timings.update(spec.summarise_timings(track_timings))
    run_timings["tracks"] = track_timings
    tail = _Lazy(lambda: {      # built after the records are streamed (frames, update failures)
        "failed": state.failed + update_failures, "not_run": not_run, "total_frames": frames["total"],
        "execution": {**executor_spec.describe(), "resumed": resumed, "tracks_from_earlier_runs": state.previous,
                      **({"worker_losses": losses} if losses is not None else {})},
        "timings": run_timings})
    path = folder.write_summary(head, records(), tail)
    if keep_records:
        import json

        return json.loads(path.read_text())
    return {**head, **dict(tail.items()), "tracks": None}


class _Lazy(dict):
    """A dict built on first use (the summary's tail depends on the streamed records)."""

    def __init__(self, build):
        super().__init__()
        self._build = build
        self._built = False

    def items(self):
        if not self._built:
            self.update(self._build())
            self._built = True
        return super().items()
