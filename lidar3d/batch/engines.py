"""Where the jobs run: a local process pool (default) or Ray tasks. Both call the same
:func:`~lidar3d.batch.jobs.process_job` with the same :class:`~lidar3d.batch.jobs.BagJob`, so they
write the same outputs.

**local** - :class:`concurrent.futures.ProcessPoolExecutor` with the ``spawn`` start method (no
forked copies of the parent's threads or open files), one process per worker, reused across bags.
Workers ignore SIGINT and SIGTERM (a SIGTERM to the process group reaches the parent alone) and exit
when the parent is gone (:mod:`lidar3d.stop_signals`). On Ctrl-C or SIGTERM the parent sets a shared
stop flag that every running job checks after each scan, so they stop within one scan and remove
their staging folders; bags not yet started are cancelled. A second Ctrl-C kills the workers
outright. If a worker process dies (a crash in native code, the out-of-memory killer), the pool
breaks; the bags that were running are then retried one at a time in a single-worker pool, so the
bag that kills its worker is named and failed and every other bag still runs.

**ray** - each bag is a Ray task (``num_cpus=1``, no automatic retry) on a local Ray instance
(``num_cpus`` = workers) or on an existing cluster (``address``; ``"auto"`` for the one this
machine belongs to). Ray is imported only here. Ctrl-C cancels the tasks (Ray raises
KeyboardInterrupt inside them, and they clean up like local jobs). Per-scan progress is not
reported from Ray tasks, only finished bags. Ray's own output while it connects and shuts down goes
to a log file (the batch's ``.batch/ray.log``), and a cluster that refuses the client's
authentication token (Ray 2.5x+ with ``ray start --head`` and a token) is reported in one line
naming ``RAY_AUTH_MODE=token`` and where the token goes. Workers write each bag's folder themselves,
at the path the driver gives: on a cluster the batch folder must be on a filesystem every node
mounts at the same path (nothing is sent back through Ray's object store but the small result).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any, Protocol

from lidar3d import stop_signals
from lidar3d.batch.jobs import THREAD_VARIABLES, BagJob, JobResult, JobStatus, limit_threads, process_job
from lidar3d.errors import ConfigError

__all__ = ["AUTH_HINT", "Engine", "EngineSink", "ray_output_to", "run_local", "run_ray"]

log = logging.getLogger(__name__)

_POLL_S = 0.25
_SCAN_REPORT_EVERY_S = 0.5


class Engine(str, Enum):
    """Batch execution engines."""

    LOCAL = "local"
    RAY = "ray"


class EngineSink(Protocol):
    """Receives what happens to the jobs (the runner's bookkeeping and progress display)."""

    def started(self, name: str) -> None: ...

    def scan(self, name: str, done: int, total: int | None) -> None: ...

    def finished(self, result: JobResult) -> None: ...


# -- local process pool -----------------------------------------------------------------------
# Worker-process state, set once by the pool initializer.
_STOP: Any = None
_EVENTS: Any = None
_JOB_FUNCTION: Callable[..., JobResult] = process_job


def _init_worker(stop: Any, events: Any, threads: int | None, job_function: Callable[..., JobResult] | None) -> None:
    global _STOP, _EVENTS, _JOB_FUNCTION
    stop_signals.as_child()  # the parent decides how to stop (SIGINT, SIGTERM ignored) and the worker ends with it
    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
    package_log = logging.getLogger("lidar3d")
    package_log.handlers[:] = [handler]
    package_log.setLevel(logging.WARNING)
    package_log.propagate = False
    limit_threads(threads)  # before NumPy and friends load in this process
    _STOP, _EVENTS = stop, events
    _JOB_FUNCTION = job_function or process_job
    events.put(("hello", "", os.getpid()))


def _run_in_worker(job: BagJob) -> JobResult:
    if _STOP.is_set():  # queued before Ctrl-C (the pool hands out a few jobs ahead)
        return JobResult(job.name, JobStatus.NOT_STARTED)
    _EVENTS.put(("start", job.name, os.getpid()))
    last = [0.0]

    def on_scan(name: str, done: int, total: int | None) -> None:
        now = time.monotonic()
        if now - last[0] >= _SCAN_REPORT_EVERY_S:
            last[0] = now
            _EVENTS.put(("scan", name, (done, total)))

    return _JOB_FUNCTION(job, should_stop=_STOP.is_set, on_scan=on_scan)


@dataclass
class _PoolRun:
    interrupted: bool = False
    broken: bool = False
    started: set[str] = field(default_factory=set)
    unfinished: list[BagJob] = field(default_factory=list)
    pids: set[int] = field(default_factory=set)


def _drain(events: Any, sink: EngineSink, run: _PoolRun) -> None:
    import queue

    while True:
        try:
            kind, name, payload = events.get_nowait()
        except queue.Empty:
            return
        except (OSError, ValueError, EOFError):
            return
        if kind == "hello":
            run.pids.add(int(payload))
        elif kind == "start":
            run.started.add(name)
            sink.started(name)
        elif kind == "scan":
            sink.scan(name, int(payload[0]), payload[1])


def _run_pool(
    ctx: Any,
    jobs: Sequence[BagJob],
    workers: int,
    sink: EngineSink,
    threads: int | None,
    job_function: Callable[..., JobResult] | None,
) -> _PoolRun:
    run = _PoolRun()
    stop = ctx.Event()
    events = ctx.Queue()
    pool = ProcessPoolExecutor(
        max_workers=workers, mp_context=ctx, initializer=_init_worker, initargs=(stop, events, threads, job_function)
    )
    futures: dict[Future, BagJob] = {pool.submit(_run_in_worker, job): job for job in jobs}
    pending = set(futures)

    def collect(done: set[Future]) -> None:
        _drain(events, sink, run)
        for future in done:
            job = futures[future]
            if future.cancelled():
                run.unfinished.append(job)
                continue
            error = future.exception()
            if isinstance(error, BrokenProcessPool):
                run.broken = True
                run.unfinished.append(job)
            elif error is not None:
                sink.finished(JobResult(job.name, JobStatus.FAILED, error=f"{type(error).__name__}: {error}"))
            elif future.result().status is JobStatus.NOT_STARTED:
                run.unfinished.append(job)
            else:
                sink.finished(future.result())

    try:
        try:
            while pending:
                done, pending = wait(pending, timeout=_POLL_S, return_when=FIRST_COMPLETED)
                collect(done)
        except KeyboardInterrupt:
            run.interrupted = True
            stop.set()
            for future in pending:
                future.cancel()
            log.warning("stopping: running bags stop after their current scan (Ctrl-C again to kill them)")
            try:
                while pending:
                    done, pending = wait(pending, timeout=_POLL_S, return_when=FIRST_COMPLETED)
                    collect(done)
            except KeyboardInterrupt:
                _drain(events, sink, run)
                for pid in run.pids:
                    with contextlib.suppress(ProcessLookupError, PermissionError):
                        os.kill(pid, signal.SIGKILL)
                for future in pending:
                    run.unfinished.append(futures[future])
                pending = set()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        _drain(events, sink, run)
        events.close()
        events.join_thread()
    return run


def run_local(
    jobs: Sequence[BagJob],
    sink: EngineSink,
    *,
    workers: int,
    threads: int | None = None,
    job_function: Callable[..., JobResult] | None = None,
) -> bool:
    """Run ``jobs`` in a local process pool; returns True when interrupted by Ctrl-C.

    ``job_function`` (default :func:`process_job`, same signature) must be importable by name in
    a fresh interpreter (spawn).
    """
    import multiprocessing

    ctx = multiprocessing.get_context("spawn")
    queue = list(jobs)
    suspects: list[BagJob] = []
    while queue or suspects:
        isolated = bool(suspects)
        batch = [suspects.pop(0)] if isolated else queue
        if not isolated:
            queue = []
        run = _run_pool(ctx, batch, 1 if isolated else min(workers, len(batch)), sink, threads, job_function)
        if run.interrupted:
            return True
        if not run.broken:
            continue
        for job in run.unfinished:
            if isolated:
                sink.finished(
                    JobResult(
                        job.name,
                        JobStatus.FAILED,
                        error="the worker process died while processing this bag "
                        "(crash in native code or out of memory)",
                    )
                )
            elif job.name in run.started or not run.started:
                suspects.append(job)
            else:
                queue.append(job)
        if suspects and not isolated:
            log.warning(
                "a worker process died; retrying %s one at a time to find the bag that caused it",
                ", ".join(j.name for j in suspects),
            )
    return False


# -- Ray ----------------------------------------------------------------------------------------
def _ray_job(job: BagJob) -> JobResult:
    return process_job(job)


def _ray_error_result(job: BagJob, error: BaseException) -> JobResult:
    import ray.exceptions

    if isinstance(error, ray.exceptions.TaskCancelledError):
        return JobResult(job.name, JobStatus.INTERRUPTED, error="cancelled")
    if isinstance(error, ray.exceptions.RayTaskError):
        cause = error.cause if getattr(error, "cause", None) is not None else error
        return JobResult(job.name, JobStatus.FAILED, error=f"{type(cause).__name__}: {cause}", detail=str(error))
    return JobResult(job.name, JobStatus.FAILED, error=f"Ray: {type(error).__name__}: {error}")


#: What Ray logs when the cluster wants a token the client did not send (or sent wrong).
_AUTH_FAILURE_MARKS = ("InvalidAuthToken", "Unauthenticated", "AuthenticationError")
AUTH_HINT = (
    "the cluster uses token authentication: set RAY_AUTH_MODE=token and give the cluster's token as "
    "RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token ('ray get-auth-token' on the head prints it)"
)


@contextlib.contextmanager
def ray_output_to(log_path: Path | None) -> Iterator[None]:
    """Send what is written to file descriptor 2 (Ray's C++ core logs it there, and Python's
    ``sys.stderr``) into ``log_path`` (appended) while the block runs; None: leave stderr alone."""
    if log_path is None:
        yield
        return
    log_path.parent.mkdir(parents=True, exist_ok=True)
    sys.stderr.flush()
    saved = os.dup(2)
    log_fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    try:
        os.dup2(log_fd, 2)
        yield
    finally:
        with contextlib.suppress(Exception):
            sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)
        os.close(log_fd)


def _connect_error(address: str | None, error: BaseException, log_path: Path | None) -> ConfigError:
    """One line for a failed ``ray.init``: what to set when the cluster refused the token."""
    logged = log_path.read_text(errors="replace") if log_path is not None and log_path.is_file() else ""
    where = f" at {address}" if address else ""
    see = f" (Ray's log: {log_path})" if log_path is not None else ""
    if any(mark in logged or mark in str(error) or mark in type(error).__name__ for mark in _AUTH_FAILURE_MARKS):
        if os.environ.get("RAY_AUTH_MODE", "").lower() == "token":
            return ConfigError(
                f"cannot reach Ray{where}: the cluster refused this client's token (RAY_AUTH_TOKEN, "
                f"RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token); give the cluster's ('ray get-auth-token' on the head){see}"
            )
        return ConfigError(f"cannot reach Ray{where}: authentication failed; {AUTH_HINT}{see}")
    first_line = (str(error).strip().splitlines() or [type(error).__name__])[0]
    return ConfigError(f"cannot start or reach Ray{where}: {first_line}{see}")


def run_ray(
    jobs: Sequence[BagJob],
    sink: EngineSink,
    *,
    workers: int | None,
    address: str | None = None,
    threads: int | None = 1,
    log_path: Path | None = None,
) -> bool:
    """Run ``jobs`` as Ray tasks; returns True when interrupted by Ctrl-C.

    Without ``address`` a local Ray instance with ``workers`` CPUs is started (and stopped at the
    end); with one, the existing cluster is joined and at most ``workers`` tasks (all when None)
    are in flight. An already initialised Ray session is used as it is. Ray's own messages while it
    starts and stops (connection retries, token warnings) go to ``log_path`` rather than the
    terminal; a refused authentication token is named in the error with what to set.

    Raises:
        ConfigError: Ray is not installed, or the cluster cannot be reached (or refused the token).
    """
    try:
        import ray
        import ray.exceptions
    except ImportError:
        raise ConfigError("--engine ray needs Ray: pip install 'lidar3d[ray]'") from None

    owns_session = not ray.is_initialized()
    if owns_session:
        options: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False, "configure_logging": False}
        try:
            with ray_output_to(log_path):
                if address:
                    ray.init(address=address, **options)
                else:
                    ray.init(num_cpus=workers, **options)
        except (ConnectionError, RuntimeError, ValueError, ray.exceptions.RayError) as err:
            raise _connect_error(address, err, log_path) from err
    env = {name: str(threads) for name in THREAD_VARIABLES} if threads is not None else {}
    task = ray.remote(_ray_job).options(
        num_cpus=1, max_retries=0, runtime_env={"env_vars": env} if env else None, name="lidar3d-batch-bag"
    )
    queue = list(jobs)
    limit = max(1, workers) if workers else len(queue)
    in_flight: dict[Any, BagJob] = {}
    interrupted = False

    def submit() -> None:
        while queue and len(in_flight) < limit:
            job = queue.pop(0)
            in_flight[task.remote(job)] = job
            sink.started(job.name)

    def collect(refs: list[Any]) -> None:
        for ref in refs:
            job = in_flight.pop(ref)
            try:
                sink.finished(ray.get(ref))
            except Exception as err:
                sink.finished(_ray_error_result(job, err))

    try:
        try:
            submit()
            while in_flight:
                ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=_POLL_S)
                collect(ready)
                submit()
        except KeyboardInterrupt:
            interrupted = True
            queue.clear()
            log.warning("stopping: cancelling running Ray tasks (Ctrl-C again to force)")
            for ref in in_flight:
                ray.cancel(ref)
            try:
                while in_flight:
                    ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=_POLL_S)
                    collect(ready)
            except KeyboardInterrupt:
                for ref in in_flight:
                    ray.cancel(ref, force=True)
                in_flight.clear()
    finally:
        if owns_session:
            with ray_output_to(log_path):
                ray.shutdown()
    return interrupted
