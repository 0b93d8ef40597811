"""Executors of the per-track task (:func:`~pedx_graph.execution.tasks.run_task`): in this process, on a
local process pool (``--workers N``) or on a Dask cluster (``--cluster ADDRESS`` or ``local:N``).

Every executor offers the same small interface, used by :mod:`pedx_graph.execution.runner`:
``slots()`` (tasks to keep in flight), ``submit(task) -> Handle``, ``wait(handles, timeout) -> done
handles``, ``outcome(handle) -> TaskOutcome`` (never raises: a lost task is a failed outcome),
``interrupt(handles)`` (cancel what is pending, stop what runs, fast) and ``close()``.

Faults:

* a local worker process that dies (killed, out of memory) breaks the pool: the pool is rebuilt and the
  tasks it held are submitted again, up to ``max_attempts`` times each, then recorded as failed; on Dask
  the scheduler reschedules the tasks of a lost worker (``distributed.scheduler.allowed-failures``) and a
  task that keeps killing workers comes back as ``KilledWorker``, recorded as failed;
* local workers ignore SIGINT (the parent decides, and terminates them on interrupt) and poll their
  parent: when the parent is gone (even by SIGKILL) they exit within ~0.5 s, so no orphan keeps
  computing.  The worker processes of a Dask ``LocalCluster`` exit with their parent by Dask's own pipe.
"""
from __future__ import annotations

import concurrent.futures as cf
import logging
import os
import secrets
import signal
import threading
import time
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass

from pedx_graph.execution.tasks import TaskOutcome, TrackTask, failed_outcome, run_task

log = logging.getLogger(__name__)


class ExecutorError(ValueError):
    """An executor that cannot be made (bad ``--cluster`` address, Dask missing, scheduler unreachable)."""


@dataclass
class ExecutorSpec:
    """Where tasks run: ``workers`` local processes (1: this process), or a Dask ``cluster``."""

    workers: int = 1
    """Local processes over tracks (1: in this process)."""
    cluster: str | None = None
    """Dask scheduler address (``tcp://host:8786``), a scheduler file (JSON), or ``local:N`` for a
    ``LocalCluster`` of N single-threaded worker processes; None: local execution."""

    def describe(self) -> dict:
        if self.cluster:
            return {"executor": "dask", "cluster": self.cluster}
        return {"executor": "local" if self.workers > 1 else "inline", "workers": int(self.workers)}


def make_executor(spec: ExecutorSpec, interrupt_flag=None):
    """The executor ``spec`` asks for.  ``interrupt_flag``: the run's signal guard (the inline executor
    computes in this process and lets a signal interrupt the track it is running)."""
    if spec.cluster:
        return DaskExecutor(spec.cluster)
    if int(spec.workers) < 1:
        raise ExecutorError(f"workers must be at least 1, got {spec.workers}")
    if int(spec.workers) == 1:
        return InlineExecutor(interrupt_flag)
    return LocalPoolExecutor(int(spec.workers))


class Handle:
    """A submitted task (and, on a pool or cluster, its future)."""

    __slots__ = ("task", "future", "attempts", "generation", "lost", "outcome")

    def __init__(self, task: TrackTask, future=None, generation: int = 0):
        self.task = task
        self.future = future
        self.attempts = 1
        self.generation = generation
        self.lost: str | None = None
        self.outcome: TaskOutcome | None = None


# --- in this process ---------------------------------------------------------------------------------------
class InlineExecutor:
    """Runs each task in this process when it is waited for (one at a time)."""

    name = "inline"

    def __init__(self, guard=None):
        self.guard = guard

    def slots(self) -> int:
        return 1

    def submit(self, task: TrackTask) -> Handle:
        return Handle(task)

    def warm_up(self, fn, params) -> None:
        fn(params)

    def wait(self, handles: list[Handle], timeout: float) -> list[Handle]:
        handle = handles[0]
        if self.guard is not None:
            with self.guard.raising():          # a signal interrupts the track being computed
                handle.outcome = run_task(handle.task)
        else:
            handle.outcome = run_task(handle.task)
        return [handle]

    def outcome(self, handle: Handle) -> TaskOutcome:
        return handle.outcome

    def interrupt(self, handles: list[Handle]) -> None:
        pass

    def close(self) -> None:
        pass


# --- a local process pool ---------------------------------------------------------------------------------
def watch_parent(parent_pid: int, period_s: float = 0.5) -> threading.Thread:
    """Start a daemon thread that ends this process (``os._exit``) once its parent ``parent_pid`` is gone
    (the process was re-parented): a worker never outlives the run that started it."""
    def loop():
        while True:
            if os.getppid() != parent_pid:
                os._exit(70)
            time.sleep(period_s)

    thread = threading.Thread(target=loop, name="pedx-parent-watch", daemon=True)
    thread.start()
    return thread


def local_worker_init(parent_pid: int, warm_up=None, params=None) -> None:
    """Initialiser of local pool workers: ignore SIGINT (a Ctrl-C reaches the whole process group; the
    parent decides and terminates the workers), exit when the parent is gone, run ``warm_up(params)``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    watch_parent(parent_pid)
    if warm_up is not None:
        warm_up(params)


def new_process_pool(workers: int, warm_up=None, params=None) -> cf.ProcessPoolExecutor:
    """A ``ProcessPoolExecutor`` whose workers ignore SIGINT, die with their parent and run
    ``warm_up(params)`` first (a cache hit in workers forked from a warmed-up parent)."""
    return cf.ProcessPoolExecutor(max_workers=workers, initializer=local_worker_init,
                                  initargs=(os.getpid(), warm_up, params))


def stop_pool(pool: cf.ProcessPoolExecutor | None, grace_s: float = 2.0) -> None:
    """Cancel what ``pool`` has pending and terminate its worker processes now (SIGTERM, then SIGKILL after
    ``grace_s``)."""
    if pool is None:
        return
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for proc in processes:
        try:
            proc.terminate()
        except (OSError, ValueError, AttributeError):
            pass
    pool.shutdown(wait=False, cancel_futures=True)
    deadline = time.monotonic() + grace_s
    for proc in processes:
        try:
            proc.join(max(0.0, deadline - time.monotonic()))
            if proc.is_alive():
                proc.kill()
                proc.join(1.0)
        except (OSError, ValueError, AttributeError, AssertionError):
            pass


class LocalPoolExecutor:
    """A process pool on this machine; a broken pool (a worker died) is rebuilt and its tasks retried."""

    name = "local"

    def __init__(self, workers: int, max_attempts: int = 3):
        self.workers = int(workers)
        self.max_attempts = int(max_attempts)
        self._pool: cf.ProcessPoolExecutor | None = None
        self._generation = 0
        self.worker_losses = 0
        """How many times a worker process died and the pool was rebuilt."""
        self._warm: tuple = (None, None)

    def _ensure(self) -> cf.ProcessPoolExecutor:
        if self._pool is None:
            self._pool = new_process_pool(self.workers, *self._warm)
            self._generation += 1
        return self._pool

    def warm_up(self, fn, params) -> None:
        """Warm this process up (forked workers inherit it), and every worker started later."""
        fn(params)
        self._warm = (fn, params)

    def slots(self) -> int:
        return 2 * self.workers + 1

    def submit(self, task: TrackTask) -> Handle:
        pool = self._ensure()
        return Handle(task, pool.submit(run_task, task), self._generation)

    def wait(self, handles: list[Handle], timeout: float) -> list[Handle]:
        by_future = {h.future: h for h in handles if h.lost is None}
        lost = [h for h in handles if h.lost is not None]
        if lost:
            return lost
        done, _ = cf.wait(by_future, timeout=timeout, return_when=cf.FIRST_COMPLETED)
        ready, broken = [], False
        for future in done:
            if not future.cancelled() and isinstance(future.exception(), BrokenProcessPool):
                broken = True
            else:
                ready.append(by_future[future])
        if broken:
            ready += self._recover(handles, {id(h) for h in ready})
        return ready

    def _recover(self, handles: list[Handle], finished: set[int]) -> list[Handle]:
        """The pool broke: rebuild it and submit again the tasks it held (those past ``max_attempts`` are
        returned, marked lost)."""
        old, generation = self._pool, self._generation
        self._pool = None
        self.worker_losses += 1
        stop_pool(old, grace_s=1.0)
        gave_up = []
        for handle in handles:
            if handle.generation != generation or id(handle) in finished:
                continue
            future = handle.future
            if future.done() and not future.cancelled() and future.exception() is None:
                continue                       # finished before the break: collected by a later wait
            if handle.attempts >= self.max_attempts:
                handle.lost = (f"WorkerLost: a worker process died while this track was running or queued "
                               f"({handle.attempts} attempts)")
                gave_up.append(handle)
                continue
            handle.attempts += 1
            log.warning("a worker process died; track %s/%s submitted again (attempt %d)",
                        handle.task.track.sequence, handle.task.track.tracking_id, handle.attempts)
            pool = self._ensure()
            handle.future = pool.submit(run_task, handle.task)
            handle.generation = self._generation
        return gave_up

    def outcome(self, handle: Handle) -> TaskOutcome:
        if handle.lost is not None:
            return failed_outcome(handle.task, handle.lost, "worker")
        try:
            return handle.future.result()
        except Exception as exc:  # noqa: BLE001 -- e.g. a result that could not be sent back
            return failed_outcome(handle.task, f"{type(exc).__name__}: {exc}", "worker")

    def interrupt(self, handles: list[Handle]) -> None:
        pool, self._pool = self._pool, None
        stop_pool(pool)

    def close(self) -> None:
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True)


# --- Dask -----------------------------------------------------------------------------------------------------
def parse_local_cluster(address: str) -> int | None:
    """N of ``local:N`` (None when ``address`` is not of that form); ExecutorError on a bad N."""
    if not address.startswith("local:"):
        return None
    text = address.split(":", 1)[1]
    try:
        n = int(text)
    except ValueError:
        raise ExecutorError(f"--cluster {address}: the number of local workers must be an integer") from None
    if n < 1:
        raise ExecutorError(f"--cluster {address}: the number of local workers must be at least 1")
    return n


def dask_setup(worker) -> None:
    """Preload of the workers of a ``local:N`` cluster (Dask calls it in each worker process as it starts,
    in the thread that receives signals): ignore SIGINT.  A Ctrl-C reaches the whole process group; the run
    decides and closes the cluster itself (without this, every worker prints a KeyboardInterrupt traceback)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


async def _close_nannies(nannies: list, timeout_s: float) -> None:
    import asyncio

    await asyncio.gather(*(nanny.close(timeout=timeout_s) for nanny in nannies), return_exceptions=True)


class DaskExecutor:
    """Tasks on a Dask cluster: ``local:N`` starts a ``LocalCluster`` of N single-threaded worker
    processes (closed with the run); any other address (or a scheduler JSON file) connects to a running
    scheduler whose workers have pedx-graph installed (the same version: the runner checks it)."""

    name = "dask"

    def __init__(self, address: str, connect_timeout_s: float = 30.0):
        try:
            import distributed
        except ImportError:
            raise ExecutorError("--cluster needs Dask: install the 'dask' extra of pedx-graph "
                                "(dask[distributed])") from None
        import dask

        self.address = address
        self.cluster = None
        # While this executor lives (its cluster's workers get the same config at their start):
        # * Dask keeps the last `low-level-log-length` (1000) messages of every connection for debugging, and a
        #   task's message holds the whole track: the memory would grow with the first thousand tracks;
        # * its nannies set MALLOC_TRIM_THRESHOLD_=65536 in their workers: the many small numpy temporaries of
        #   a fit then cost page faults and system calls (measured 1.3-2x slower per track).
        self._config = dask.config.set({"distributed.admin.low-level-log-length": 16,
                                        "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None})
        self._dask_log = logging.getLogger("distributed")
        self._dask_log_level = self._dask_log.level
        self._dask_log.setLevel(logging.ERROR)          # its start / close chatter is not ours to show
        n_local = parse_local_cluster(address)
        try:
            if n_local is not None:
                # the workers' own logs stay quiet up to CRITICAL: a worker still alive after a Ctrl-C closed
                # the scheduler logs its failed heartbeat as an error with a traceback (seen once, under load);
                # a local worker's failures reach the run through its futures (outcome)
                self.cluster = distributed.LocalCluster(
                    n_workers=n_local, threads_per_worker=1, processes=True, dashboard_address=None,
                    silence_logs=logging.CRITICAL, preload=[__name__])
                self.client = distributed.Client(self.cluster, set_as_default=False)
            elif os.path.isfile(address):
                self.client = distributed.Client(scheduler_file=address, set_as_default=False,
                                                 timeout=connect_timeout_s)
            else:
                self.client = distributed.Client(address, set_as_default=False, timeout=connect_timeout_s)
        except (OSError, TimeoutError, ValueError, RuntimeError) as exc:
            if self.cluster is not None:
                self.cluster.close()
            self._dask_log.setLevel(self._dask_log_level)
            self._config.__exit__(None, None, None)
            hint = ("; a script that starts a local cluster needs its work under `if __name__ == '__main__':`"
                    if n_local is not None and isinstance(exc, RuntimeError) else "")
            raise ExecutorError(f"--cluster {address}: cannot start or reach the cluster "
                                f"({type(exc).__name__}: {exc}){hint}") from None
        self.token = secrets.token_hex(4)
        self._slots = (3, -1e9)
        self._finished = threading.Event()

    def slots(self) -> int:
        now = time.monotonic()
        if now - self._slots[1] > 2.0:           # the cluster may grow or shrink; asked every 2 s at most
            try:
                threads = sum(self.client.nthreads().values())
            except Exception:  # noqa: BLE001 -- scheduler busy or gone: keep a small window
                threads = 1
            self._slots = (2 * max(int(threads), 1) + 1, now)
        return self._slots[0]

    def warm_up(self, fn, params) -> None:
        """Run ``fn(params)`` on every worker now (workers joining later warm up with their first track)."""
        self.client.run(fn, params)

    def submit(self, task: TrackTask) -> Handle:
        key = f"pedx-{task.kind}-{task.index}-{self.token}"
        future = self.client.submit(run_task, task, key=key, pure=False)
        future.add_done_callback(lambda _: self._finished.set())
        return Handle(task, future)

    def wait(self, handles: list[Handle], timeout: float) -> list[Handle]:
        # woken by the futures' callbacks (``distributed.wait`` needs a default client; this one is not one)
        deadline = time.monotonic() + timeout
        while True:
            self._finished.clear()              # cleared before looking: a completion in between is not lost
            done = [h for h in handles if h.future.done()]
            remaining = deadline - time.monotonic()
            if done or remaining <= 0:
                return done
            self._finished.wait(remaining)

    def outcome(self, handle: Handle) -> TaskOutcome:
        try:
            return handle.future.result()
        except Exception as exc:  # noqa: BLE001 -- KilledWorker, a lost scheduler, an unpicklable result
            name = type(exc).__name__
            hint = (" (it was running on workers that died, e.g. out of memory)" if name == "KilledWorker" else "")
            return failed_outcome(handle.task, f"{name}: {exc}{hint}", "worker")
        finally:
            handle.future.release()

    def interrupt(self, handles: list[Handle]) -> None:
        if self.client is None:
            return
        try:
            self.client.cancel([h.future for h in handles], force=True)
        except Exception as exc:  # noqa: BLE001 -- the scheduler may be gone already
            log.debug("cancel failed: %s", exc)
        if self.cluster is not None:
            # a worker busy with a track does not stop gracefully: its nanny kills it after a short grace
            try:
                self.cluster.sync(_close_nannies, list(self.cluster.workers.values()), 0.5)
            except Exception as exc:  # noqa: BLE001 -- fall back to the cluster's own close
                log.debug("fast close failed: %s", exc)
        self.close()

    def close(self) -> None:
        client, cluster = getattr(self, "client", None), self.cluster
        self.client, self.cluster = None, None
        if client is not None:
            try:
                client.close(timeout=5)
            except Exception as exc:  # noqa: BLE001
                log.debug("client close: %s", exc)
        if cluster is not None:
            try:
                cluster.close(timeout=5)
            except Exception as exc:  # noqa: BLE001
                log.debug("cluster close: %s", exc)
        if client is not None or cluster is not None:
            self._dask_log.setLevel(self._dask_log_level)
            self._config.__exit__(None, None, None)


# --- ordered map (for callers that want results in input order) -----------------------------------------------
def map_ordered(fn, jobs: list, workers: int = 1):
    """``fn`` over ``jobs``, results yielded in input order; a local pool (workers ignore SIGINT, die with
    the parent) when ``workers > 1``.  ``fn`` must be a module-level function."""
    if workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            yield fn(job)
        return
    pool = new_process_pool(workers)
    try:
        yield from pool.map(fn, jobs, chunksize=1)
    except BaseException:
        stop_pool(pool)
        raise
    finally:
        pool.shutdown(wait=True)

