"""Input sanity: the points of a decoded scan that no sensor can have measured are dropped and counted.

A decoded :class:`~lidar3d.records.Scan` may still hold what a damaged or mislabelled cloud
produces: NaN/inf coordinates (also what drivers write for missing returns in organised clouds),
coordinates of 1e38 (a big-endian flag on little-endian data, a flipped exponent bit) and point
times far outside the sweep (a flipped byte in a time field). :func:`sanitize_scan` drops, per
point:

* **non-finite points**: a NaN or infinite coordinate;
* **absurd coordinates**: any of ``|x|, |y|, |z|`` above :func:`coordinate_limit_m` (the larger of
  :data:`MIN_COORDINATE_LIMIT_M` and :data:`RANGE_MARGIN` times the sensor's maximum range: a
  return no sensor measures, while a genuine point of the configured sensor never reaches it);
* **outlier point times**: a non-finite time, or one outside ``[-W T, +W T]`` around the header
  stamp, with ``T`` the sensor's sweep period and ``W`` = :data:`TIME_WINDOW_SWEEPS`. Times
  relative to the sweep start (0..T, velodyne_pointcloud) and to the sweep end (-T..0) both fit.

A scan with nothing left is an empty scan; the pipeline poses it with the motion model. The counts
of every scan (:class:`SanityCounts`) are summed into the run's input statistics
(``input_stats`` in ``summary.json``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar3d.records import Scan
from lidar3d.sensors import SensorModel

__all__ = [
    "MIN_COORDINATE_LIMIT_M",
    "RANGE_MARGIN",
    "TIME_WINDOW_SWEEPS",
    "SanityCounts",
    "coordinate_limit_m",
    "plausible_coordinates",
    "sanitize_scan",
]

#: No coordinate of a lidar point is taken as measured beyond this many metres, whatever the sensor.
MIN_COORDINATE_LIMIT_M = 1000.0
#: A coordinate beyond this many times the sensor's maximum range is absurd (when above 1 km).
RANGE_MARGIN = 2.0
#: Point times more than this many sweep periods before or after the header stamp are outliers.
TIME_WINDOW_SWEEPS = 1.5


@dataclass(frozen=True, slots=True)
class SanityCounts:
    """Points :func:`sanitize_scan` dropped from one scan, by reason (each point counted once, under
    the first reason that applies, in this order)."""

    n_nonfinite: int = 0
    n_absurd_coordinates: int = 0
    n_outlier_times: int = 0

    @property
    def n_dropped(self) -> int:
        return self.n_nonfinite + self.n_absurd_coordinates + self.n_outlier_times


def coordinate_limit_m(sensor: SensorModel) -> float:
    """The largest ``|x|``, ``|y|`` or ``|z|`` (m) a point of ``sensor`` may have."""
    return max(MIN_COORDINATE_LIMIT_M, RANGE_MARGIN * sensor.max_range_m)


def plausible_coordinates(points: np.ndarray, sensor: SensorModel) -> tuple[np.ndarray, np.ndarray]:
    """``(finite, plausible)`` (N,) bool masks of (N, 3) points: every coordinate finite, and finite
    with every coordinate within :func:`coordinate_limit_m`."""
    finite = np.isfinite(points).all(axis=1)
    plausible = finite & (np.abs(points) <= coordinate_limit_m(sensor)).all(axis=1)
    return finite, plausible


def sanitize_scan(scan: Scan, sensor: SensorModel) -> tuple[Scan, SanityCounts]:
    """``scan`` without its non-finite points, absurd coordinates and outlier point times.

    Args:
        scan: a decoded scan (times relative to its stamp, s).
        sensor: its maximum range sets the coordinate limit, its sweep period the time window.

    Returns:
        The scan (the same object when nothing is dropped) and the counts of what was dropped.
    """
    window_s = TIME_WINDOW_SWEEPS * sensor.sweep_period_s
    times = scan.time_offset_s
    if not len(scan) or _all_sane(scan.points, times, coordinate_limit_m(sensor), window_s):
        return scan, SanityCounts()
    finite, plausible = plausible_coordinates(scan.points, sensor)
    in_window = np.isfinite(times) & (times >= -window_s) & (times <= window_s)
    keep = plausible & in_window
    n_kept = int(np.count_nonzero(keep))
    n_finite = int(np.count_nonzero(finite))
    counts = SanityCounts(
        n_nonfinite=len(scan) - n_finite,
        n_absurd_coordinates=n_finite - int(np.count_nonzero(plausible)),
        n_outlier_times=int(np.count_nonzero(plausible)) - n_kept,
    )
    return scan.select(keep), counts


def _all_sane(points: np.ndarray, times: np.ndarray, limit_m: float, window_s: float) -> bool:
    """Whether every point and time passes, by whole-array extremes (NaN propagates into them and
    fails the comparisons): the quick check of the common clean scan."""
    return bool(np.abs(points).max() <= limit_m and times.min() >= -window_s and times.max() <= window_s)
