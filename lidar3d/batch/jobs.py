"""One bag's job: run it exactly as ``lidar3d run`` would, then publish its folder in one step.

:func:`process_job` is what every engine executes (in a worker process or a Ray task). It

1. runs :func:`lidar3d.run.run_bag` into a hidden staging folder ``.<name>.partial-<id>`` beside the
   final folder (run_bag's own periodic checkpoints are switched off: nothing in staging is ever
   seen);
2. rewrites the staging folder's absolute path to the final one inside the JSON outputs
   (``summary.json``, ``eval/report.json``), so published files point at published files;
3. writes ``batch_job.json`` (job fingerprint, inputs, timing, host) last;
4. renames the staging folder onto ``<out>/<name>`` (an older folder there is first renamed
   aside, then deleted).

A bag whose SLAM finished but whose GNSS evaluation failed is still published (status ``done``)
with the evaluation error as a note: the trajectory and the map are good. Any other error leaves
nothing published and comes back as a ``failed`` result; nothing is raised, so one bad bag never
stops the batch. This module imports nothing heavy at its top, so worker processes can limit
their BLAS/OpenMP threads before NumPy loads.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import socket
import time
import traceback
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

from lidar3d.errors import SummaryError
from lidar3d.summary import RunSummary, read_summary

__all__ = [
    "JOB_FILE",
    "THREAD_VARIABLES",
    "BagJob",
    "JobResult",
    "JobStatus",
    "JobStopped",
    "RunOptions",
    "limit_threads",
    "process_job",
    "publish_folder",
    "read_job_record",
    "staging_folders",
]

JOB_FILE = "batch_job.json"
THREAD_VARIABLES = (
    "OMP_NUM_THREADS",
    "OPENBLAS_NUM_THREADS",
    "MKL_NUM_THREADS",
    "NUMEXPR_NUM_THREADS",
    "VECLIB_MAXIMUM_THREADS",
    "NUMBA_NUM_THREADS",
)
_STAGING_MARK = ".partial-"
_ASIDE_MARK = ".old-"


class JobStatus(str, Enum):
    """Outcome of one bag in a batch."""

    DONE = "done"  # processed in this run and published
    UP_TO_DATE = "up to date"  # finished earlier with the same fingerprint: reused
    FAILED = "failed"  # an error; nothing (new) published
    INTERRUPTED = "interrupted"  # stopped by Ctrl-C while running
    NOT_STARTED = "not started"  # never started (the batch was interrupted first)


@dataclass(frozen=True, slots=True)
class RunOptions:
    """The per-bag options of ``lidar3d run`` that are not configuration keys, the same for every bag.

    Attributes:
        start: scans skipped at the start of each bag (``--start``).
        max_scans: at most this many scans per bag (``--max-scans``; None: all).
        gnss_factors: fuse each bag's SPAN log into its pose graph (``--gnss-factors``).
    """

    start: int = 0
    max_scans: int | None = None
    gnss_factors: bool = False


@dataclass(frozen=True, slots=True)
class BagJob:
    """Everything a worker needs for one bag; plain, picklable values only.

    Attributes:
        name: output folder name (unique within the batch).
        bag: the ``.bag`` file or ROS2 bag folder (absolute).
        out_dir: the final output folder, ``<batch out>/<name>``.
        config_toml: the resolved configuration as TOML text (as ``config.toml`` holds it); text
            rather than a pickled object, so a worker on another node or code version reads it
            by key, and it is exactly what the fingerprint hashed.
        fingerprint: the job fingerprint written into ``batch_job.json``.
        span_log, extrinsics: evaluation inputs (None: no evaluation).
        span_match: how the SPAN log was chosen, in words.
        threads: BLAS/OpenMP threads for the job (None: leave the environment as it is).
        size_bytes: bag size, for progress estimates.
        run_options: ``--start``, ``--max-scans``, ``--gnss-factors``.
    """

    name: str
    bag: Path
    out_dir: Path
    config_toml: str
    fingerprint: str
    span_log: Path | None = None
    extrinsics: Path | None = None
    span_match: str = ""
    threads: int | None = None
    size_bytes: int = 0
    run_options: RunOptions = RunOptions()


@dataclass(frozen=True, slots=True)
class JobResult:
    """What came back from one job.

    ``summary`` is the bag's published ``summary.json`` (None unless done); ``error`` one line;
    ``detail`` a traceback for unexpected errors; ``note`` an evaluation error of a done bag.
    """

    name: str
    status: JobStatus
    summary: RunSummary | None = None
    error: str | None = None
    detail: str | None = None
    note: str | None = None
    wall_s: float = 0.0
    worker: str = ""


class JobStopped(Exception):
    """Raised inside a running job when the batch is being stopped (Ctrl-C)."""


def limit_threads(threads: int | None) -> None:
    """Set the BLAS/OpenMP thread variables (effective for libraries not loaded yet)."""
    if threads is None:
        return
    for name in THREAD_VARIABLES:
        os.environ[name] = str(int(threads))


def staging_folders(out_dir: Path) -> list[Path]:
    """Left-over staging and set-aside folders of an interrupted or killed batch."""
    if not out_dir.is_dir():
        return []
    return sorted(
        p for p in out_dir.iterdir() if p.name.startswith(".") and (_STAGING_MARK in p.name or _ASIDE_MARK in p.name)
    )


def read_job_record(folder: Path) -> dict | None:
    """``batch_job.json`` of a published folder (None when absent or unreadable)."""
    try:
        record = json.loads((folder / JOB_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) else None


def publish_folder(staging: Path, final: Path) -> None:
    """Make ``staging`` appear as ``final`` by renames; a previous ``final`` is replaced."""
    if final.exists():
        aside = final.parent / f".{final.name}{_ASIDE_MARK}{uuid.uuid4().hex[:8]}"
        os.replace(final, aside)
        os.replace(staging, final)
        shutil.rmtree(aside, ignore_errors=True)
    else:
        os.replace(staging, final)


def _replace_prefix(value: Any, old: str, new: str) -> Any:
    if isinstance(value, str):
        if value == old or value.startswith(old + os.sep):
            return new + value[len(old) :]
        return value
    if isinstance(value, list):
        return [_replace_prefix(v, old, new) for v in value]
    if isinstance(value, dict):
        return {k: _replace_prefix(v, old, new) for k, v in value.items()}
    return value


def _relocate_json(staging: Path, final: Path) -> None:
    """Point absolute paths inside the staging folder's JSON outputs at the final folder
    (republished as one set, so the summary's manifest describes the rewritten files)."""
    from lidar3d.io.run_folder import SUMMARY_NAME

    old, new = str(staging), str(final)
    rewritten = {}
    for path in sorted(staging.rglob("*.json")):
        text = path.read_text(encoding="utf-8")
        if old in text:
            data = json.loads(text)
            rewritten[path.relative_to(staging).as_posix()] = (
                json.dumps(_replace_prefix(data, old, new), indent=2) + "\n"
            )
    if not rewritten:
        return
    summary = RunSummary.from_json(rewritten.pop(SUMMARY_NAME, "") or (staging / SUMMARY_NAME).read_text("utf-8"))
    _republish(staging, summary, rewritten)


def _republish(folder: Path, summary: RunSummary, texts: dict[str, str] | None = None) -> None:
    """Publish ``summary`` with the files ``texts`` (relative path -> text) rewritten, the rest kept."""
    from lidar3d.io.atomic import write_text_atomic
    from lidar3d.io.run_folder import publish_set

    texts = texts or {}

    def write(staging: Path) -> None:
        for path, text in texts.items():
            write_text_atomic(staging / path, text)

    keep = [entry.path for entry in summary.outputs if entry.path not in texts]
    publish_set(folder, summary, write, keep=keep)


def _worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _finished_summary(staging: Path) -> RunSummary | None:
    """The staging summary when SLAM itself completed (not partial), else None."""
    try:
        summary = read_summary(staging / "summary.json")
    except SummaryError:
        return None
    return None if summary.partial else summary


def process_job(
    job: BagJob,
    *,
    should_stop: Callable[[], bool] | None = None,
    on_scan: Callable[[str, int, int | None], None] | None = None,
) -> JobResult:
    """Run one bag and publish its folder; never raises for a bag's own errors.

    Args:
        should_stop: polled after every scan; when it returns True the job stops (``interrupted``).
        on_scan: called as ``on_scan(name, done, total)`` after every scan.
    """
    from lidar3d import __version__
    from lidar3d.errors import Lidar3dError

    limit_threads(job.threads)
    t0 = time.perf_counter()
    staging = job.out_dir.parent / f".{job.name}{_STAGING_MARK}{uuid.uuid4().hex[:8]}"

    def scan_callback(done: int, total: int | None) -> None:
        if on_scan is not None:
            on_scan(job.name, done, total)
        if should_stop is not None and should_stop():
            raise JobStopped(f"{job.name}: stopped after {done} scans")

    def result(status: JobStatus, **kwargs: Any) -> JobResult:
        return JobResult(job.name, status, wall_s=time.perf_counter() - t0, worker=_worker_name(), **kwargs)

    note = None
    try:
        from lidar3d.config import config_from_dict
        from lidar3d.io.atomic import write_text_atomic
        from lidar3d.run import run_bag

        try:
            import tomllib
        except ModuleNotFoundError:  # Python 3.10
            import tomli as tomllib

        config = config_from_dict(tomllib.loads(job.config_toml))
        try:
            run_bag(
                job.bag,
                staging,
                config,
                span_log=job.span_log,
                extrinsics=job.extrinsics if job.span_log is not None else None,
                start=job.run_options.start,
                max_scans=job.run_options.max_scans,
                gnss_factors=job.run_options.gnss_factors and job.span_log is not None,
                on_scan=scan_callback,
                checkpoint_every_s=math.inf,
                map_checkpoint_every_s=math.inf,
                # A batch gets its parallelism from running bags side by side: one core per job.
                prefetch=False,
            )
        except Lidar3dError as err:
            summary = _finished_summary(staging) if job.span_log is not None else None
            if summary is None:
                raise
            note = f"evaluation against {job.span_log} failed: {err}"
            _republish(staging, dataclasses.replace(summary, evaluation_error=str(err)))
        _relocate_json(staging, job.out_dir)
        record = {
            "fingerprint": job.fingerprint,
            "bag": str(job.bag),
            "span_log": str(job.span_log) if job.span_log else None,
            "span_match": job.span_match,
            "extrinsics": str(job.extrinsics) if job.extrinsics and job.span_log else None,
            "lidar3d_version": __version__,
            "finished_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "wall_s": round(time.perf_counter() - t0, 3),
            "worker": _worker_name(),
            "note": note,
        }
        write_text_atomic(staging / JOB_FILE, json.dumps(record, indent=2) + "\n")
        job.out_dir.parent.mkdir(parents=True, exist_ok=True)
        publish_folder(staging, job.out_dir)
        return result(JobStatus.DONE, summary=read_summary(job.out_dir / "summary.json"), note=note)
    except (JobStopped, KeyboardInterrupt) as err:
        return result(JobStatus.INTERRUPTED, error=str(err) or "interrupted")
    except Lidar3dError as err:
        return result(JobStatus.FAILED, error=str(err))
    except Exception as err:
        return result(JobStatus.FAILED, error=f"{type(err).__name__}: {err}", detail=traceback.format_exc())
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
