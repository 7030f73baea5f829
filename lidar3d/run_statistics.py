"""What a SLAM run counts and times while it goes: per-stage milliseconds, counters, warnings.

The counters (``scans``, ``dropped_duplicate_stamps``, ``motion_model_scans``,
``degenerate_scans``, ``redeskewed_scans``, ``loop_closures``...) end up in ``summary.json``.
Stretches of scans whose pose came from the motion model alone are reported as one warning each;
the stretches the health signal flagged lost (:mod:`lidar3d.mapping.health`) as one warning line,
and those it flagged degraded as another.
"""

from __future__ import annotations

import logging
from collections import defaultdict

import numpy as np

from lidar3d.summary import HealthStretch, HealthSummary

__all__ = ["RunStatistics"]

log = logging.getLogger(__name__)


class RunStatistics:
    """Timings, counters and warnings of one run.

    Attributes:
        counts: counter name -> value.
        loop_ms: milliseconds spent in loop detection and the pose graph.
        map_rebuild_s: seconds spent placing the map again after loop closures (None: not placed again).
    """

    def __init__(self) -> None:
        self._timings: dict[str, list[float]] = defaultdict(list)
        self.counts: dict[str, int] = defaultdict(int)
        self.loop_ms = 0.0
        self.map_rebuild_s: float | None = None
        self._warnings: list[str] = []
        self._fallback_start: int | None = None

    def add_timings(self, stage_ms: dict[str, float]) -> None:
        """Append one scan's milliseconds per stage."""
        for stage, ms in stage_ms.items():
            self._timings[stage].append(ms)

    def count(self, name: str, n: int = 1) -> None:
        self.counts[name] += n

    def scan_tracked(self, scan_index: int, motion_model_only: bool) -> None:
        """Note whether scan ``scan_index`` was posed by the motion model alone; a stretch of such
        scans becomes a warning when it ends."""
        if motion_model_only:
            self.counts["motion_model_scans"] += 1
            if self._fallback_start is None:
                self._fallback_start = scan_index
        elif self._fallback_start is not None:
            self._close_fallback(scan_index)

    def end_of_input(self, n_scans_seen: int) -> None:
        """Close an open motion-model stretch at the end of the input (``n_scans_seen`` scans)."""
        if self._fallback_start is not None:
            self._close_fallback(n_scans_seen)

    def timings_ms(self) -> dict[str, np.ndarray]:
        """Stage name -> (N,) milliseconds per processed scan."""
        return {k: np.asarray(v) for k, v in self._timings.items()}

    def warnings(self, n_scans_seen: int, health: HealthSummary | None = None) -> tuple[str, ...]:
        """The warnings so far; an open motion-model stretch is reported up to the last scan, and the
        lost stretches of ``health`` (the run's health so far) in one line at the end, its degraded
        stretches in another."""
        warnings = list(self._warnings)
        if self._fallback_start is not None:
            warnings.append(_fallback_message(self._fallback_start, n_scans_seen))
        if health is not None and health.lost_stretches:
            warnings.append(_lost_message(health))
        if health is not None and health.degraded_stretches:
            warnings.append(_degraded_message(health))
        return tuple(warnings)

    def _close_fallback(self, end_index: int) -> None:
        assert self._fallback_start is not None
        message = _fallback_message(self._fallback_start, end_index)
        self._fallback_start = None
        self._warnings.append(message)
        log.warning(message)


def _fallback_message(start: int, end_index: int) -> str:
    return f"scans {start}-{end_index - 1}: too few features, pose from the motion model"


#: Lost stretches named one by one in the warning; the rest are counted.
_STRETCHES_NAMED = 5


def _lost_message(health: HealthSummary) -> str:
    """One line naming the lost stretches of a run, e.g. ``health: lost on 1 stretch (151.2 m, 38 %
    of the scans): scans 330-598 (151.2 m); poses there may be metres wrong, see health.csv``."""
    return _stretches_message(
        "lost", health.lost_stretches, health.lost_m, health.lost_scans, health.scans, "metres wrong"
    )


def _degraded_message(health: HealthSummary) -> str:
    """One line naming the degraded stretches of a run, as :func:`_lost_message` does the lost ones."""
    return _stretches_message(
        "degraded",
        health.degraded_stretches,
        health.degraded_m,
        health.degraded_scans,
        health.scans,
        "decimetres to metres wrong",
    )


def _stretches_message(
    flag: str, stretches: tuple[HealthStretch, ...], length_m: float, n_flagged: int, n_scans: int, error: str
) -> str:
    named = [f"{s.first_scan}-{s.last_scan} ({s.length_m:.1f} m)" for s in stretches[:_STRETCHES_NAMED]]
    if len(stretches) > _STRETCHES_NAMED:
        named.append(f"and {len(stretches) - _STRETCHES_NAMED} more")
    share = 100.0 * n_flagged / n_scans if n_scans else 0.0
    plural = "es" if len(stretches) != 1 else ""
    return (
        f"health: {flag} on {len(stretches)} stretch{plural} ({length_m:.1f} m, {share:.0f} % of the scans): "
        f"scans {', '.join(named)}; poses there may be {error}, see health.csv"
    )
