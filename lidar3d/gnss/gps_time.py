"""GPS week and seconds to UNIX time.

GPS time started at 1980-01-06 00:00:00 UTC (UNIX 315964800) and has no leap seconds, so

    t_unix = 315964800 + 604800 * week + seconds_of_week - leap_seconds

with ``leap_seconds`` = GPS - UTC = 18 s since 2017-01-01 (17 s from 2015-07-01, 16 s from
2012-07-01). ``shared/reference/gnss-and-metrics.md`` section 1.11 lists test vectors, e.g.
(2158, 95593.0) -> 1621218775.0 (UrbanNav ground truth) and (2269, 129755.02) -> 1688385737.02.

The optional ``time_offset_s`` is the constant offset of the bag clock against GPS-derived UNIX
time: ``t_bag = t_unix + time_offset_s``.
"""

from __future__ import annotations

import numpy as np

__all__ = ["DEFAULT_LEAP_SECONDS", "GPS_EPOCH_UNIX_S", "SECONDS_PER_WEEK", "gps_to_unix_ns", "unix_ns_to_gps"]

GPS_EPOCH_UNIX_S = 315_964_800
SECONDS_PER_WEEK = 604_800
DEFAULT_LEAP_SECONDS = 18
_NS = 1_000_000_000


def gps_to_unix_ns(gps_week, gps_seconds, leap_seconds: int = DEFAULT_LEAP_SECONDS, time_offset_s: float = 0.0):
    """UNIX time in integer nanoseconds (int64 array, or int for scalars) of GPS week/seconds.

    ``gps_seconds`` is rounded to the nanosecond; whole seconds are added in integer arithmetic, so
    no precision is lost at UNIX magnitudes.
    """
    week = np.asarray(gps_week, dtype=np.int64)
    seconds = np.asarray(gps_seconds, dtype=np.float64)
    whole = np.floor(seconds)
    fraction_ns = np.rint((seconds - whole) * _NS).astype(np.int64)
    offset_ns = int(round(float(time_offset_s) * _NS))
    stamps = (
        (GPS_EPOCH_UNIX_S + SECONDS_PER_WEEK * week + whole.astype(np.int64) - int(leap_seconds)) * _NS
        + fraction_ns
        + offset_ns
    )
    if stamps.ndim == 0:
        return int(stamps)
    return stamps


def unix_ns_to_gps(stamp_ns, leap_seconds: int = DEFAULT_LEAP_SECONDS) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`gps_to_unix_ns` (without offset): (week, seconds of week)."""
    gps_ns = np.asarray(stamp_ns, dtype=np.int64) - (GPS_EPOCH_UNIX_S - int(leap_seconds)) * _NS
    week, rest_ns = np.divmod(gps_ns, SECONDS_PER_WEEK * _NS)
    return week, rest_ns / _NS
