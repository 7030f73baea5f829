"""``lidar3d batch``: SLAM over many bags, resumable, with one report. Library twin: :func:`run_batch`.

Batch folder layout::

    OUT/
      <name>/            one folder per finished bag: exactly what `lidar3d run` writes, plus
                         batch_job.json (fingerprint, inputs, timing); published by a rename
      summary.csv        one row per bag (see lidar3d.batch.report.ROW_FIELDS)
      summary.json       the same rows plus totals and how the batch ran
      report.html        the sortable, self-contained report page
      .batch/            lock file and the time-span cache of SPAN-log matching
      .<name>.partial-*  staging folders of running bags (removed when a batch starts or ends)

A bag is *up to date*, and skipped, when ``OUT/<name>/batch_job.json`` holds the same job
fingerprint (bag content, configuration, SPAN log and extrinsic content, lidar3d version: see
:mod:`lidar3d.batch.fingerprint`). Since a bag's folder appears only when complete, re-running the
same command after a crash, a kill or Ctrl-C redoes exactly the bags that had not finished.
Failed bags are retried on every run. ``force=True`` redoes every bag.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import os
import shutil
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from lidar3d.batch.discovery import BagInput, discover_bags
from lidar3d.batch.engines import Engine, run_local, run_ray
from lidar3d.batch.fingerprint import bag_size_bytes, content_fingerprint, job_fingerprint
from lidar3d.batch.jobs import JOB_FILE, BagJob, JobResult, JobStatus, RunOptions, read_job_record, staging_folders
from lidar3d.batch.progress import BatchProgress
from lidar3d.batch.report import ReportPaths, bag_row, write_report
from lidar3d.batch.span_match import SpanMatch, TimeRangeCache, match_span_logs, resolve_extrinsics
from lidar3d.errors import ConfigError, OutputError, SummaryError
from lidar3d.io.run_folder import RunFolderState, check_run_folder
from lidar3d.summary import RunSummary, read_summary

__all__ = ["BatchOutcome", "ProgressCallback", "default_workers", "run_batch"]

log = logging.getLogger(__name__)

STATE_DIR = ".batch"

#: ``callback(event, progress, result)``: event is "start" (jobs known), "update" (a bag started
#: or scans progressed), "finished" (``result`` is the bag's) or "end".
ProgressCallback = Callable[[str, BatchProgress, JobResult | None], None]


@dataclass(frozen=True, slots=True)
class BatchOutcome:
    """What :func:`run_batch` did.

    Attributes:
        out_dir: the batch folder.
        rows: one report row per bag, in input order (see :data:`lidar3d.batch.report.ROW_FIELDS`).
        report: paths of summary.csv, summary.json and report.html.
        interrupted: True when Ctrl-C stopped the batch (the report says what finished).
        wall_s: wall time of the whole call.
    """

    out_dir: Path
    rows: tuple[dict, ...]
    report: ReportPaths
    interrupted: bool
    wall_s: float

    def names(self, status: JobStatus | str) -> list[str]:
        """Names of the bags with ``status``."""
        value = JobStatus(status).value
        return [r["name"] for r in self.rows if r["status"] == value]

    @property
    def counts(self) -> dict[str, int]:
        """Bags per status (every status listed, zeros included)."""
        return {s.value: sum(1 for r in self.rows if r["status"] == s.value) for s in JobStatus}

    @property
    def ok(self) -> bool:
        """Every bag is done or up to date."""
        return all(r["status"] in (JobStatus.DONE.value, JobStatus.UP_TO_DATE.value) for r in self.rows)


def default_workers() -> int:
    """CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _open_lock_file(out: Path) -> TextIO:
    """The batch folder's lock file, opened for appending (the folder is created if missing)."""
    state = out / STATE_DIR
    try:
        state.mkdir(parents=True, exist_ok=True)
        return open(state / "lock", "a+")
    except OSError as err:
        raise OutputError(f"{out}: cannot create the batch folder: {err.strerror or err}") from err


@contextlib.contextmanager
def _batch_lock(out: Path) -> Iterator[None]:
    """Hold an exclusive lock on the batch folder (one batch per folder at a time)."""
    with _open_lock_file(out) as handle:
        try:
            import fcntl
        except ImportError:  # pragma: no cover - not POSIX: no locking
            yield
            return
        try:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            raise OutputError(f"{out}: another lidar3d batch is writing to this folder") from None
        try:
            handle.seek(0)
            handle.truncate()
            handle.write(f"{os.getpid()}\n")
            handle.flush()
            yield
        finally:
            fcntl.flock(handle.fileno(), fcntl.LOCK_UN)


def _remove_staging(out: Path) -> None:
    for folder in staging_folders(out):
        log.info("removing %s (left by an interrupted batch)", folder)
        shutil.rmtree(folder, ignore_errors=True)


def _read_json(path: Path) -> dict | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _published_summary(folder: Path) -> RunSummary | None:
    """The run summary of a bag's output folder (None when absent or not a valid summary)."""
    try:
        return read_summary(folder / "summary.json")
    except SummaryError:
        return None


def _up_to_date(job: BagJob) -> bool:
    """Finished earlier with the same fingerprint, and the folder still holds the set its summary
    describes (sizes checked: hashing every map of a big batch would take minutes)."""
    record = read_job_record(job.out_dir)
    if record is None or record.get("fingerprint") != job.fingerprint:
        return False
    check = check_run_folder(job.out_dir, verify_content=False, extra=(JOB_FILE,))
    return check.state is RunFolderState.CONSISTENT and check.summary is not None and not check.summary.partial


class _Collector:
    """The engines' sink: feeds the progress bookkeeping and the caller's callback."""

    def __init__(self, progress: BatchProgress, callback: ProgressCallback | None) -> None:
        self.progress = progress
        self.callback = callback

    def _emit(self, event: str, result: JobResult | None = None) -> None:
        if self.callback is not None:
            self.callback(event, self.progress, result)

    def started(self, name: str) -> None:
        self.progress.started(name)
        self._emit("update")

    def scan(self, name: str, done: int, total: int | None) -> None:
        self.progress.scan(name, done, total)
        self._emit("update")

    def finished(self, result: JobResult) -> None:
        self.progress.finished_job(result)
        if result.status is JobStatus.FAILED and result.detail:
            log.debug("%s failed:\n%s", result.name, result.detail)
        self._emit("finished", result)


def _make_jobs(
    bags: Sequence[BagInput],
    out: Path,
    config: Any,
    matches: dict[str, SpanMatch],
    extrinsics: dict[str, Path | None],
    fingerprints: dict[Path, str],
    threads: int | None,
    run_options: RunOptions,
) -> list[BagJob]:
    from lidar3d import __version__
    from lidar3d.config import config_to_toml

    config_toml = config_to_toml(config)
    changed_options = {
        field.name: getattr(run_options, field.name)
        for field in dataclasses.fields(run_options)
        if getattr(run_options, field.name) != field.default
    }

    def fingerprint_of(path: Path | None) -> str | None:
        if path is None or not path.exists():
            return None
        if path not in fingerprints:
            fingerprints[path] = content_fingerprint(path)
        return fingerprints[path]

    jobs = []
    for bag in bags:
        match = matches[bag.name]
        extrinsic = extrinsics[bag.name] if match.span_log is not None else None
        fingerprint = job_fingerprint(
            fingerprint_of(bag.path) or "",
            config_toml,
            span_fingerprint=fingerprint_of(match.span_log),
            extrinsics_fingerprint=fingerprint_of(extrinsic) if extrinsic is not None else None,
            version=__version__,
            run_options=changed_options,
        )
        jobs.append(
            BagJob(
                name=bag.name,
                bag=bag.path,
                out_dir=out / bag.name,
                config_toml=config_toml,
                fingerprint=fingerprint,
                span_log=match.span_log,
                extrinsics=extrinsic,
                span_match=match.how,
                threads=threads,
                size_bytes=bag_size_bytes(bag.path),
                run_options=run_options,
            )
        )
    return jobs


def _rows(
    bags: Sequence[BagInput],
    jobs: Sequence[BagJob],
    out: Path,
    skipped: set[str],
    progress: BatchProgress,
    rpe_distance_m: float | None,
) -> list[dict]:
    rows = []
    for bag, job in zip(bags, jobs):
        result = progress.results.get(bag.name)
        if bag.name in skipped:
            status, error, note = JobStatus.UP_TO_DATE, None, (read_job_record(job.out_dir) or {}).get("note")
        elif result is not None:
            status, error, note = result.status, result.error, result.note
        elif bag.name in progress.running:
            status, error, note = JobStatus.INTERRUPTED, "interrupted", None
        else:
            status, error, note = JobStatus.NOT_STARTED, None, None
        published = status in (JobStatus.DONE, JobStatus.UP_TO_DATE)
        summary = _published_summary(job.out_dir) if published else None
        eval_report = _read_json(job.out_dir / "eval" / "report.json") if published else None
        rows.append(
            bag_row(
                name=bag.name,
                bag=bag.path,
                status=status.value,
                batch_dir=out,
                summary=summary,
                eval_report=eval_report,
                span_log=job.span_log,
                span_match=job.span_match,
                error=error,
                note=note,
                fingerprint=job.fingerprint,
                rpe_distance_m=rpe_distance_m,
            )
        )
    return rows


def run_batch(
    inputs: str | Path | Sequence[str | Path],
    out_dir: str | Path,
    config: Any = None,
    *,
    span_dir: str | Path | None = None,
    span_pattern: str | None = None,
    extrinsics: str | Path | None = None,
    workers: int | None = None,
    engine: Engine | str = Engine.LOCAL,
    ray_address: str | None = None,
    force: bool = False,
    run_options: RunOptions | None = None,
    on_progress: ProgressCallback | None = None,
    job_function: Callable[..., JobResult] | None = None,
) -> BatchOutcome:
    """Run SLAM over every bag of ``inputs``, one output folder each, and write the batch report.

    Args:
        inputs: bags, ROS2 bag folders, folders to search, or glob patterns
            (see :mod:`lidar3d.batch.discovery`).
        out_dir: the batch folder (created).
        config: a :class:`lidar3d.config.Config` (defaults when None), the same for every bag.
        span_dir / span_pattern: how to find each bag's SPAN log (see :mod:`lidar3d.batch.span_match`).
        extrinsics: lidar-to-IMU extrinsic file for the evaluation, or a per-bag pattern.
        workers: parallel bags (local: processes, default all CPUs; ray: CPUs of the local
            instance, or tasks in flight on a cluster).
        engine: ``"local"`` (process pool) or ``"ray"``.
        ray_address: an existing Ray cluster (``"auto"``, ``"ray://head:10001"``...).
        force: redo bags that are up to date.
        run_options: ``--start``, ``--max-scans``, ``--gnss-factors`` for every bag (defaults when None).
        on_progress: see :data:`ProgressCallback`.
        job_function: replaces :func:`lidar3d.batch.jobs.process_job` in the local engine (tests).

    Returns a :class:`BatchOutcome`; bag failures are in its rows, never raised. Ctrl-C stops the
    running bags after their current scan, writes the report and returns with ``interrupted``.

    Raises:
        ConfigError: bad options (both span options, workers < 1, unknown engine, Ray missing).
        BagError: an input that does not exist or holds no bag.
        OutputError: the batch folder cannot be written, or another batch holds it.
    """
    from lidar3d import __version__
    from lidar3d.config import Config

    t0 = time.perf_counter()
    config = config or Config()
    try:
        engine = Engine(engine)
    except ValueError:
        raise ConfigError(f"unknown engine {engine!r} (known: {', '.join(e.value for e in Engine)})") from None
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers must be at least 1, got {workers}")
    if ray_address and engine is not Engine.RAY:
        raise ConfigError("--ray-address needs --engine ray")
    if span_dir is not None and span_pattern is not None:
        raise ConfigError("give --span-dir or --span-pattern, not both")
    if isinstance(inputs, (str, Path)):
        inputs = [inputs]
    bags = discover_bags(inputs)
    out = Path(out_dir).expanduser().resolve()
    for bag in bags:
        final = out / bag.name
        if final == bag.path or final in bag.path.parents or out == bag.path:
            raise ConfigError(f"--out {out}: the output folder {final} would replace the bag {bag.path}")

    with _batch_lock(out):
        _remove_staging(out)
        fingerprints: dict[Path, str] = {}
        matches = match_span_logs(
            bags,
            span_dir=span_dir,
            span_pattern=span_pattern,
            gnss_config=config.gnss,
            cache=TimeRangeCache(out / STATE_DIR / "time_ranges.json"),
            fingerprints=fingerprints,
        )
        extrinsic_files = resolve_extrinsics(extrinsics, bags)
        n_workers = workers or (default_workers() if engine is Engine.LOCAL else None)
        threads = 1 if engine is Engine.RAY or (n_workers or 1) > 1 else None
        jobs = _make_jobs(
            bags, out, config, matches, extrinsic_files, fingerprints, threads, run_options or RunOptions()
        )
        skipped = set() if force else {job.name for job in jobs if _up_to_date(job)}
        todo = [job for job in jobs if job.name not in skipped]
        for job in jobs:
            if job.name in skipped:
                log.debug("%s: up to date, skipped", job.name)
        progress = BatchProgress({job.name: job.size_bytes for job in todo}, up_to_date=len(skipped))
        collector = _Collector(progress, on_progress)
        collector._emit("start")
        interrupted = False
        try:
            if todo:
                if engine is Engine.LOCAL:
                    interrupted = run_local(
                        todo,
                        collector,
                        workers=min(n_workers or 1, len(todo)),
                        threads=threads,
                        job_function=job_function,
                    )
                else:
                    interrupted = run_ray(
                        todo,
                        collector,
                        workers=n_workers,
                        address=ray_address,
                        threads=threads,
                        log_path=out / STATE_DIR / "ray.log",
                    )
        except KeyboardInterrupt:
            interrupted = True
        finally:
            _remove_staging(out)
            collector._emit("end")
        rpe_distances = config.gnss.rpe_distances_m
        rows = _rows(bags, jobs, out, skipped, progress, rpe_distances[0] if rpe_distances else None)
        by_status = {s.value: sum(1 for r in rows if r["status"] == s.value) for s in JobStatus}
        with_outputs = [r for r in rows if r["output"]]
        meta = {
            "lidar3d_version": __version__,
            "written_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "out_dir": str(out),
            "inputs": [str(i) for i in inputs],
            "engine": engine.value,
            "ray_address": ray_address,
            "workers": n_workers,
            "threads_per_job": threads,
            "force": force,
            "span_dir": str(span_dir) if span_dir is not None else None,
            "span_pattern": span_pattern,
            "interrupted": interrupted,
            "wall_s": round(time.perf_counter() - t0, 3),
            "rpe_distance_m": rpe_distances[0] if rpe_distances else None,
            "totals": {
                "bags": len(rows),
                "by_status": by_status,
                "scans": sum(int(r["scans"] or 0) for r in with_outputs),
                "length_m": round(sum(float(r["length_m"] or 0.0) for r in with_outputs), 3),
                "scans_this_run": progress.scans_finished,
                "scans_per_s_this_run": round(progress.scans_finished / progress.elapsed_s, 2)
                if progress.elapsed_s > 0
                else 0.0,
            },
        }
        report = write_report(out, rows, meta)
    return BatchOutcome(out, tuple(rows), report, interrupted, time.perf_counter() - t0)
