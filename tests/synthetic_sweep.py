"""A synthetic sweep consistent with a sensor's beam table, for the decoding tests."""

from __future__ import annotations

import numpy as np

from lidar3d.records import Scan
from lidar3d.sensors import VLP16, SensorModel


def synthetic_sweep(
    n_columns: int,
    stamp_ns: int,
    *,
    sensor: SensorModel = VLP16,
    seed: int = 0,
    azimuth_offset: float = 0.0,
    time_offset: float = 0.0,
) -> Scan:
    """``n_columns`` columns of ``sensor``'s beams in firing order at random ranges (2-60 m), the
    azimuth (clockwise) and the time (0 .. one sweep period) growing with the column: column ``c``
    is at the azimuth fraction ``(c + azimuth_offset) / n_columns`` of a turn and fires at the time
    fraction ``(c + time_offset) / n_columns`` of a sweep, so ring-less and time-less decoding can
    recover both. Intensities are random integers 0-255."""
    rng = np.random.default_rng(seed)
    column = np.repeat(np.arange(n_columns), sensor.n_rings)
    ring = np.tile(np.arange(sensor.n_rings), n_columns)
    azimuth_cw = (column + azimuth_offset) / n_columns * 2.0 * np.pi
    elevation = sensor.elevation_rad[ring]
    range_m = rng.uniform(2.0, 60.0, column.size)
    points = np.stack(
        [
            range_m * np.cos(elevation) * np.cos(azimuth_cw),
            -range_m * np.cos(elevation) * np.sin(azimuth_cw),
            range_m * np.sin(elevation),
        ],
        axis=1,
    )
    intensity = rng.integers(0, 256, column.size).astype(np.float32)
    return Scan(stamp_ns, points, intensity, ring, (column + time_offset) / n_columns * sensor.sweep_period_s)
