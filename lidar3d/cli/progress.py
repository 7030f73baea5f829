"""Terminal progress of the CLI, drawn by tqdm, and the logging handler that writes above it.

tqdm (no dependencies of its own, under 1 MB installed) draws and throttles the bar; its ``write``
lifts every bar off the terminal line, prints the text and redraws the bar below, so a log record
never lands on the bar's line. The bar is drawn only when stderr is a terminal (tqdm's
``disable=None``): on a pipe or file (CI, ``2> log``) it writes nothing, rather than a
carriage-return redraw every 0.2 s.
"""

from __future__ import annotations

import logging
import sys
from typing import TYPE_CHECKING, TextIO

from tqdm import tqdm

if TYPE_CHECKING:
    from lidar3d.mapping.health import ScanHealth

__all__ = ["ProgressSafeHandler", "ScanProgress"]

#: Redraw a bar at most this often [s].
REDRAW_INTERVAL_S = 0.2
_WITH_TOTAL = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}<{remaining}, {rate_noinv_fmt}{postfix}]"
_WITHOUT_TOTAL = "{desc}: {n_fmt} scans [{elapsed}, {rate_noinv_fmt}{postfix}]"


class ScanProgress:
    """The bar of one SLAM run on stderr: scans done/total, share done, time spent and left, scans/s,
    and, once :meth:`note_health` was called, the share of scans whose health is ok (``health ok
    98%``), followed by the latest scan's flag when that is not ok (``now lost``).

    The rate is the average since the bar was made (tqdm's ``smoothing=0``), the time left the
    scans still to go at that rate.

    Args:
        label: shown before the bar (``"run"``).
        quiet: draw nothing (``-q``).
        stream: where to draw; stderr by default. Nothing is drawn unless it is a terminal.
    """

    def __init__(self, label: str, *, quiet: bool = False, stream: TextIO | None = None) -> None:
        self._bar = tqdm(
            desc=label,
            unit=" scans",
            file=stream if stream is not None else sys.stderr,
            disable=True if quiet else None,
            mininterval=REDRAW_INTERVAL_S,
            smoothing=0.0,
            dynamic_ncols=True,
            bar_format=_WITHOUT_TOTAL,
        )
        self._n_health = 0
        self._n_ok = 0

    def note_health(self, health: ScanHealth) -> None:
        """Count the health of the latest scan; shown at the next redraw."""
        self._n_health += 1
        ok = health.flag.value == "ok"
        self._n_ok += ok
        text = f"health ok {100.0 * self._n_ok / self._n_health:.0f}%"
        self._bar.set_postfix_str(text if ok else f"{text}, now {health.flag.value}", refresh=False)

    def update(self, done: int, total: int | None) -> None:
        """Record that ``done`` scans of ``total`` (None: unknown) are processed; redraw if it is time."""
        if total != self._bar.total:
            self._bar.total = total
            self._bar.bar_format = _WITH_TOTAL if total else _WITHOUT_TOTAL
        self._bar.update(done - self._bar.n)

    def close(self) -> None:
        """Draw the final state once and leave it on its line; a bar that counted no scan is erased."""
        self._bar.leave = self._bar.n > 0
        self._bar.close()


class ProgressSafeHandler(logging.Handler):
    """A handler that writes each record to the current ``sys.stderr`` through ``tqdm.write``, so it
    goes on a line of its own above any progress bar drawn on the same terminal, and the bar is
    redrawn below it. The stream is looked up per record, not kept: a program (or a test) that
    replaces ``sys.stderr`` after the CLI set up logging still gets the records, and a closed
    former stream is never written to."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            stream = sys.stderr
            tqdm.write(self.format(record), file=stream)
            stream.flush()
        except RecursionError:
            raise
        except Exception:
            self.handleError(record)
