"""Progress across the bags of a batch: bookkeeping (:class:`BatchProgress`) and a stderr display
(:class:`ProgressDisplay`, used by the CLI, drawn by tqdm).

Overall speed is scans per second of wall time over the bags processed in this run (bags reused
from an earlier run do not count). The time left is estimated from bytes: the share of the bags'
total size processed so far (finished bags whole, running bags by their share of scans done) per
second of wall time, applied to the bytes still to go. Bag sizes are known up front, scan counts
only once a bag is opened; bytes are the better common measure.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Mapping
from typing import TextIO

from tqdm import tqdm

from lidar3d.batch.jobs import JobResult, JobStatus

__all__ = ["BatchProgress", "ProgressDisplay", "format_duration"]


def format_duration(seconds: float) -> str:
    """``"42 s"``, ``"3 min 20 s"``, ``"2 h 05 min"``."""
    seconds = max(0.0, float(seconds))
    if seconds < 60:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s"
    return f"{int(seconds // 3600)} h {int(seconds % 3600 // 60):02d} min"


class BatchProgress:
    """Counts and rates of a batch while it runs.

    Args:
        sizes: bytes of every bag to process in this run, by name.
        up_to_date: number of bags reused from an earlier run.
    """

    def __init__(self, sizes: Mapping[str, int], up_to_date: int = 0) -> None:
        self.sizes = dict(sizes)
        self.up_to_date = up_to_date
        self.start = time.perf_counter()
        self.running: dict[str, tuple[int, int | None]] = {}
        self.results: dict[str, JobResult] = {}
        self.scans_finished = 0

    @property
    def total(self) -> int:
        """All bags of the batch (including those up to date)."""
        return len(self.sizes) + self.up_to_date

    @property
    def finished(self) -> int:
        """Bags with a final state: done, failed, interrupted, or up to date."""
        return len(self.results) + self.up_to_date

    def count(self, status: JobStatus) -> int:
        return sum(1 for r in self.results.values() if r.status is status)

    def started(self, name: str) -> None:
        self.running.setdefault(name, (0, None))

    def scan(self, name: str, done: int, total: int | None) -> None:
        if name not in self.results:
            self.running[name] = (done, total)

    def finished_job(self, result: JobResult) -> None:
        self.running.pop(result.name, None)
        self.results[result.name] = result
        if result.summary is not None:
            self.scans_finished += result.summary.scans

    @property
    def elapsed_s(self) -> float:
        return time.perf_counter() - self.start

    @property
    def scans_done(self) -> int:
        """Scans processed in this run, including those of running bags."""
        return self.scans_finished + sum(done for done, _ in self.running.values())

    @property
    def scans_per_s(self) -> float:
        elapsed = self.elapsed_s
        return self.scans_done / elapsed if elapsed > 0 else 0.0

    @property
    def bytes_total(self) -> int:
        """Bytes of all bags to process in this run."""
        return sum(self.sizes.values())

    @property
    def bytes_done(self) -> float:
        """Bytes processed so far: finished bags whole, running bags by their share of scans done."""
        done: float = sum(self.sizes.get(name, 0) for name in self.results)
        for name, (scans, total) in self.running.items():
            if total:
                done += self.sizes.get(name, 0) * min(scans / total, 1.0)
        return done

    @property
    def eta_s(self) -> float | None:
        """Estimated seconds left, or None before anything could be measured."""
        done = self.bytes_done
        total = self.bytes_total
        elapsed = self.elapsed_s
        if done <= 0 or elapsed <= 0:
            return None
        return max(total - done, 0.0) / (done / elapsed)

    def line(self) -> str:
        """One status line: bags finished, running, scans/s, time left."""
        return f"{self.bags_text()}, {self.speed_text()}"

    def bags_text(self) -> str:
        """Bags finished of all, up to date, failed and running: ``"batch: 3/5 bags (1 failed), 2 running"``."""
        text = f"batch: {self.finished}/{self.total} bags"
        parts = []
        if self.up_to_date:
            parts.append(f"{self.up_to_date} up to date")
        failed = self.count(JobStatus.FAILED)
        if failed:
            parts.append(f"{failed} failed")
        if parts:
            text += f" ({', '.join(parts)})"
        if self.running:
            text += f", {len(self.running)} running"
        return text

    def speed_text(self) -> str:
        """Overall speed and, until every bag is finished, time left: ``"4.1 scans/s, about 3 min 20 s left"``."""
        text = f"{self.scans_per_s:.1f} scans/s"
        eta = self.eta_s
        if eta is not None and self.finished < self.total:
            text += f", about {format_duration(eta)} left"
        return text


def _describe(result: JobResult) -> str:
    s = result.summary
    if result.status is JobStatus.DONE:
        scans, length_m, scans_per_s = (s.scans, s.length_m, s.scans_per_s) if s is not None else (0, 0.0, 0.0)
        text = f"{scans} scans, {length_m:.1f} m, {result.wall_s:.1f} s ({scans_per_s:.1f} scans/s)"
        if s is not None and s.health is not None and s.health.lost_scans:
            text += f"; health: lost over {s.health.lost_m:.1f} m"
        return text + (f"; {result.note}" if result.note else "")
    return result.error or ""


class ProgressDisplay:
    """Shows a batch on ``stream`` (stderr by default): one line per finished bag, a status bar while
    it runs, and the status line once at the end.

    The bar (bags finished and running, share of bytes processed, scans/s, time left) is drawn by
    tqdm and only on a terminal, at most every 0.2 s; on a pipe or file only the lines are written.
    Lines are written through ``tqdm.write``, so they never land on the bar's line.
    """

    _BAR_FORMAT = "{desc} |{bar}| {percentage:3.0f}%{postfix}"

    def __init__(self, progress: BatchProgress, stream: TextIO | None = None) -> None:
        self.progress = progress
        self.stream = stream if stream is not None else sys.stderr
        self._bar = tqdm(
            desc=progress.bags_text(),
            total=progress.bytes_total,
            postfix=progress.speed_text(),
            file=self.stream,
            disable=None,
            mininterval=0.2,
            miniters=0,
            dynamic_ncols=True,
            bar_format=self._BAR_FORMAT,
        )

    def _sync(self) -> None:
        """Copy the bookkeeping into the bar without drawing it."""
        self._bar.desc = self.progress.bags_text()
        self._bar.set_postfix_str(self.progress.speed_text(), refresh=False)
        self._bar.n = self.progress.bytes_done

    def update(self) -> None:
        """Redraw the status bar if it is time to."""
        self._sync()
        self._bar.update(0)

    def finished(self, result: JobResult) -> None:
        """Print the line of a finished bag above the status bar, which is redrawn below it."""
        p = self.progress
        label = result.status.value if result.status is not JobStatus.FAILED else "FAILED"
        self._sync()
        tqdm.write(f"[{p.finished}/{p.total}] {label:<11} {result.name}: {_describe(result)}", file=self.stream)
        self.stream.flush()

    def close(self) -> None:
        """Erase the bar and, if any bag was processed, print the final status line (once)."""
        self._bar.leave = False
        self._bar.close()
        if self.progress.results:
            self.stream.write(self.progress.line() + "\n")
            self.stream.flush()
