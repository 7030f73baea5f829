"""Reading and the front end in a second process, a few scans ahead of the pipeline.

The front end depends on nothing but the scan, so a child process can read the bag and run it
while the main process deskews, registers and maps the previous scans: on a 2-core machine the two
halves of the work overlap. The child sends :class:`~lidar3d.features.frontend.PreparedScan` records
through a bounded queue; errors raised there (a bad bag, a decode error) are re-raised here
unchanged, so the user sees the same one-line message as without prefetching. The child ignores
SIGINT and SIGTERM and exits when the pipeline's process is gone (:mod:`lidar3d.stop_signals`).
"""

from __future__ import annotations

import itertools
import multiprocessing
import queue as queue_module
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from lidar3d import stop_signals
from lidar3d.config import Config
from lidar3d.errors import Lidar3dError
from lidar3d.features.frontend import PreparedScan, prepare_scan
from lidar3d.io.scan_reading import ReadStats
from lidar3d.io.scan_source import open_scan_source

__all__ = ["InlineScanStream", "PreparedScanStream", "open_prepared_scans"]

_POLL_S = 0.5


def _prepared(source, config: Config, start: int, stop: int | None) -> Iterator[tuple[PreparedScan, float]]:
    """Scans ``start`` to ``stop`` of an open source through the front end, with read times (ms)."""
    scans = itertools.islice(iter(source), start, stop)
    while True:
        t0 = time.perf_counter()
        scan = next(scans, None)
        if scan is None:
            return
        read_ms = (time.perf_counter() - t0) * 1e3
        yield prepare_scan(scan, config), read_ms


def _produce(paths: list[str], config: Config, start: int, stop: int | None, out: multiprocessing.Queue) -> None:
    """Child process: read, prepare and send every scan, then the read statistics."""
    stop_signals.as_child()  # the parent decides when to stop
    try:
        with open_scan_source(paths, config) as source:
            out.put(("open", source.topic, len(source)))
            for prepared, read_ms in _prepared(source, config, start, stop):
                out.put(("scan", prepared, read_ms))
        out.put(("end", source.stats))
    except BaseException as err:
        out.put(("error", err))


class PreparedScanStream:
    """Prepared scans of ``paths`` (scans ``start`` to ``start + max_scans``), made ``depth`` ahead.

    Use as a context manager; iterate to get ``(PreparedScan, read_ms)``. ``topic`` and ``total``
    are known once entered, ``stats`` once exhausted.
    """

    def __init__(
        self,
        paths: Sequence[str | Path],
        config: Config,
        *,
        start: int = 0,
        max_scans: int | None = None,
        depth: int = 4,
    ) -> None:
        self.paths = [str(p) for p in paths]
        self.config = config
        self.start = start
        self.stop = None if max_scans is None else start + max_scans
        self.topic = ""
        self.total = 0
        self.stats = ReadStats()
        context = multiprocessing.get_context("spawn")
        self._queue = context.Queue(maxsize=depth)
        self._process = context.Process(
            target=_produce,
            args=(self.paths, config, start, self.stop, self._queue),
            name="lidar3d-prefetch",
            daemon=True,
        )

    def _get(self):
        while True:
            try:
                message = self._queue.get(timeout=_POLL_S)
            except queue_module.Empty:
                if not self._process.is_alive():
                    raise Lidar3dError(
                        f"{', '.join(self.paths)}: the reading process ended unexpectedly "
                        f"(exit code {self._process.exitcode})"
                    ) from None
                continue
            if message[0] == "error":
                raise message[1]
            return message

    def __enter__(self) -> PreparedScanStream:
        stop_signals.start_child(self._process)
        try:
            _, self.topic, n_scans = self._get()
        except BaseException:
            self.close()
            raise
        self.total = max(0, n_scans - self.start)
        if self.stop is not None:
            self.total = min(self.total, self.stop - self.start)
        return self

    def __iter__(self) -> Iterator[tuple[PreparedScan, float]]:
        while True:
            message = self._get()
            if message[0] == "end":
                self.stats = message[1]
                return
            yield message[1], message[2]

    def close(self) -> None:
        if self._process.is_alive():
            self._process.kill()  # it ignores SIGTERM
        self._process.join(timeout=5)
        self._queue.close()
        self._queue.cancel_join_thread()

    def __exit__(self, *exc_info: object) -> None:
        self.close()


class InlineScanStream:
    """The same interface as :class:`PreparedScanStream`, all in this process."""

    def __init__(
        self, paths: Sequence[str | Path], config: Config, *, start: int = 0, max_scans: int | None = None
    ) -> None:
        self.config = config
        self.start = start
        self.stop = None if max_scans is None else start + max_scans
        self._source = open_scan_source(list(paths), config)
        self.topic = ""
        self.total = 0
        self.stats = ReadStats()

    def __enter__(self) -> InlineScanStream:
        self._source.__enter__()
        self.topic = self._source.topic
        self.total = max(0, len(self._source) - self.start)
        if self.stop is not None:
            self.total = min(self.total, self.stop - self.start)
        return self

    def __iter__(self) -> Iterator[tuple[PreparedScan, float]]:
        yield from _prepared(self._source, self.config, self.start, self.stop)
        self.stats = self._source.stats

    def __exit__(self, *exc_info: object) -> None:
        self._source.__exit__(*exc_info)
        self.stats = self._source.stats


def open_prepared_scans(
    paths: Sequence[str | Path], config: Config, *, start: int = 0, max_scans: int | None = None, prefetch: bool = True
) -> PreparedScanStream | InlineScanStream:
    """Prepared scans from a child process (``prefetch``) or from this one."""
    if prefetch:
        return PreparedScanStream(paths, config, start=start, max_scans=max_scans)
    return InlineScanStream(paths, config, start=start, max_scans=max_scans)
