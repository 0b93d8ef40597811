"""The per-track task: :func:`run_task` is the one function every executor runs, locally or on a cluster.

A :class:`TrackTask` carries a track (numpy data, picklable), a module-level function (pickled by
reference) and its parameters.  The function runs in the worker (GTSAM graphs holding CustomFactors do
not pickle: each worker builds its own graph) and returns a :class:`TrackOutput`: the result files as
bytes (serialised in the worker, so the writing process only writes them), the track's summary records
(deterministic fields only) and its timings, kept apart.  Any exception becomes a failed
:class:`TaskOutcome` naming its type and message: one bad track never stops a run.
"""
from __future__ import annotations

import json
import os
import re
import socket
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from pedx_graph import __version__
from pedx_graph.data.types import Track

#: Keys of a record that hold times (``seconds``, ``*_seconds``, ``*_ms``, ``*_ms_*``): they go to the
#: summary's timings section, never into result files or the deterministic part of the summary.
TIMING_KEY = re.compile(r"(^|_)seconds$|(^|_)ms($|_)")


@dataclass
class TrackTask:
    """One track and what to do with it."""

    fn: Callable[[Track, Any], "TrackOutput"]
    """Module-level function ``fn(track, params) -> TrackOutput`` (pickled by reference)."""
    track: Track
    params: Any
    """Picklable parameters of ``fn`` (configs, solver name, ...)."""
    index: int
    """Position of the track in the dataset's order (the summary's order)."""
    kind: str = "track"
    """Command name (``fit``, ``stream``, ``baseline``), for task names on a cluster."""

    @property
    def key(self) -> tuple[str, str]:
        return (self.track.sequence, self.track.tracking_id)


@dataclass
class TrackOutput:
    """What a track produced, ready to be written by any process."""

    files: list[tuple[str, bytes]]
    """``(path relative to the results folder, file content)`` of every result file of the track."""
    records: list[dict]
    """The track's summary entries (usually one; a streamed track that paused longer than the track
    timeout gives one per piece), without timings."""
    timings: dict = field(default_factory=dict)
    """Timing fields of the track (seconds, milliseconds), for the summary's timings section."""
    frames: int = 0
    """Result frames written (the per-frame files of the main results)."""


@dataclass
class TaskOutcome:
    """The result of :func:`run_task` (or of an executor that lost the task): output or failure."""

    sequence: str
    tracking_id: str
    index: int
    output: TrackOutput | None = None
    error: str | None = None
    """``"<ExceptionType>: message"`` when the track failed."""
    stage: str = "task"
    """Where it failed: ``task`` (the computation), ``write`` (its files), ``worker`` (the process running
    it was lost, or its result could not be brought back), ``version`` (a worker of another version)."""
    traceback: str | None = None
    seconds: float = 0.0
    """Wall time of the task in its worker."""
    worker: str = ""
    """``host:pid`` of the process that ran it."""
    version: str = __version__
    """Package version of that process."""

    @property
    def key(self) -> tuple[str, str]:
        return (self.sequence, self.tracking_id)

    @property
    def ok(self) -> bool:
        return self.error is None and self.output is not None


def failed_outcome(task: TrackTask, error: str, stage: str, tb: str | None = None) -> TaskOutcome:
    """A failed outcome of ``task`` recorded by the process that ran (or lost) it."""
    return TaskOutcome(task.track.sequence, task.track.tracking_id, task.index, error=error, stage=stage,
                       traceback=tb)


# --- the task function ---------------------------------------------------------------------------------
_BLAS = {"lock": threading.Lock(), "limits": None}


def limit_blas_threads() -> None:
    """One BLAS thread in this process (once): the products are small and processes (or cluster workers)
    over tracks use the cores instead; more threads only add overhead (measured ~2x on 2 cores)."""
    with _BLAS["lock"]:
        if _BLAS["limits"] is None:
            from threadpoolctl import threadpool_limits
            _BLAS["limits"] = threadpool_limits(limits=1, user_api="blas")


def run_task(task: TrackTask) -> TaskOutcome:
    """Run ``task.fn`` on the track; every executor calls this one function.  Never raises for a failing
    track (the outcome records the error); ``KeyboardInterrupt`` and ``SystemExit`` pass through."""
    limit_blas_threads()
    t0 = time.perf_counter()
    outcome = TaskOutcome(task.track.sequence, task.track.tracking_id, task.index,
                          worker=f"{socket.gethostname()}:{os.getpid()}")
    try:
        output = task.fn(task.track, task.params)
        if not isinstance(output, TrackOutput):
            raise TypeError(f"{getattr(task.fn, '__name__', task.fn)} returned {type(output).__name__}, "
                            "not a TrackOutput")
        outcome.output = output
    except Exception as exc:  # noqa: BLE001 -- one bad track never stops the run
        outcome.error = f"{type(exc).__name__}: {exc}"
        outcome.traceback = traceback.format_exc(limit=6)
    outcome.seconds = time.perf_counter() - t0
    return outcome


# --- building outputs ----------------------------------------------------------------------------------
def split_timings(record: dict) -> tuple[dict, dict]:
    """``(record without timing keys, the timing keys)``, recursively through nested dicts (the timings
    keep the nesting, e.g. ``{"flips": {"seconds": ...}}``)."""
    kept, times = {}, {}
    for key, value in record.items():
        if TIMING_KEY.search(str(key)):
            times[key] = value
        elif isinstance(value, dict):
            sub_kept, sub_times = split_timings(value)
            kept[key] = sub_kept
            if sub_times:
                times[key] = sub_times
        else:
            kept[key] = value
    return kept, times


def json_bytes(obj) -> bytes:
    """The bytes every JSON result file is written with (numpy converted, non-finite floats as null,
    one-space indent, a final newline): the same object gives the same bytes in every process."""
    from pedx_graph.utils import to_jsonable

    return (json.dumps(to_jsonable(obj), indent=1, sort_keys=False) + "\n").encode("utf-8")


def label_files(labels, prefix: str = "") -> list[tuple[str, bytes]]:
    """``(relative path, bytes)`` of SMPL labels in the release layout (``labels/3d/smpl/<seq>/...``) under
    ``prefix``; every label is validated first (lengths, finite betas / pose / trans), so a track with a
    bad estimate fails before any of its files is written."""
    from pedx_graph.data.smpl_labels import smpl_label_path, smpl_label_to_json

    files = []
    for label in labels:
        if "_" in label.sequence:
            raise ValueError(f"sequence names must not contain '_': {label.sequence!r}")
        rel = smpl_label_path(prefix or ".", label.sequence, label.frame, label.tracking_id)
        files.append((rel.as_posix().removeprefix("./"), json_bytes(smpl_label_to_json(label))))
    return files


def result_record(result) -> dict:
    """The summary entry of a :class:`~pedx_graph.solvers.fit.TrackResult` (timings included; split them
    with :func:`split_timings`)."""
    return {"sequence": result.sequence, "tracking_id": result.tracking_id, "frames": len(result.frames),
            "betas": result.betas, "initial_error": result.initial_error, "final_error": result.final_error,
            "iterations": result.iterations, "seconds": result.seconds, "solver": result.solver,
            **result.extra_track}


def result_output(results: list, prefix: str = "", extra_files: list | None = None,
                  extra_timings: dict | None = None, track=None) -> TrackOutput:
    """The :class:`TrackOutput` of one or more ``TrackResult`` pieces of a track: their labels as files,
    their records (JSON-ready, without timings) and their timings (``pieces``: one dict per piece).  With the
    ``track``, a record also lists the track's ``identity_review`` stretches that overlap its frames (where
    the import found the track close to another: check who is who there)."""
    from pedx_graph.utils import to_jsonable

    files = list(extra_files or [])
    records, pieces = [], []
    frames = 0
    review = list(getattr(track, "identity_review", None) or [])
    for result in results:
        files += label_files(result.to_labels(), prefix)
        frames += len(result.frames)
        kept, times = split_timings(to_jsonable(result_record(result)))
        if review and result.frames:
            lo, hi = min(result.frames), max(result.frames)
            overlapping = [s for s in review if s["first_frame"] <= hi and s["last_frame"] >= lo]
            if overlapping:
                kept["identity_review"] = overlapping
        records.append(kept)
        pieces.append(times)
    timings = {"pieces": pieces} if len(pieces) != 1 else dict(pieces[0])
    timings.update(extra_timings or {})
    return TrackOutput(files=files, records=records, timings=timings, frames=frames)
