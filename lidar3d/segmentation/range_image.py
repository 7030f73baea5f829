"""Projection of a scan onto a rings x columns range image (LeGO-LOAM imageProjection, IP:225-250).

Rows come from the scan's ``ring`` field (LeGO-LOAM ``useCloudRing``), or from each point's
elevation and the sensor's elevation table. Columns come from the azimuth at the sensor's horizontal
resolution, with LeGO-LOAM's layout in REP-105 axes: column ``n_columns // 2`` looks along +x
(forward), columns grow counter-clockwise seen from above (+y, left, is at three quarters), and the
image wraps at -x (backward). Each cell keeps one point (in practice the last written, as LeGO-LOAM's
``rangeMat`` does) and remembers its index in the scan.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from lidar3d.config import SegmentationConfig, SensorConfig
from lidar3d.jit import lazy_njit
from lidar3d.records import Scan, readonly
from lidar3d.sensors import SensorModel

__all__ = ["RangeImage", "project_scan"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class RangeImage:
    """A scan resampled onto the sensor's (rows, columns) grid; R = rings, C = columns.

    Attributes:
        range_m: (R, C) float64 distance of each cell's point from the lidar origin; NaN where empty.
        point_index: (R, C) int64 index of each cell's point in the scan; -1 where empty.
        points: (R, C, 3) float64 cell points in the lidar frame, metres; NaN where empty.
        row_elevation_rad: (R,) float64 nominal beam elevation of each row (the sensor's table).
        azimuth_resolution_rad: angular width of one column.
    """

    range_m: np.ndarray
    point_index: np.ndarray
    points: np.ndarray
    row_elevation_rad: np.ndarray
    azimuth_resolution_rad: float

    def __post_init__(self) -> None:
        range_m = np.asarray(self.range_m, dtype=np.float64)
        if range_m.ndim != 2:
            raise ValueError(f"RangeImage.range_m must be (R, C), got {range_m.shape}")
        n_rows, n_columns = range_m.shape
        point_index = np.asarray(self.point_index, dtype=np.int64)
        points = np.asarray(self.points, dtype=np.float64)
        elevation = np.asarray(self.row_elevation_rad, dtype=np.float64)
        if point_index.shape != range_m.shape:
            raise ValueError(f"RangeImage.point_index must be {range_m.shape}, got {point_index.shape}")
        if points.shape != (n_rows, n_columns, 3):
            raise ValueError(f"RangeImage.points must be ({n_rows}, {n_columns}, 3), got {points.shape}")
        if elevation.shape != (n_rows,):
            raise ValueError(f"RangeImage.row_elevation_rad must be ({n_rows},), got {elevation.shape}")
        object.__setattr__(self, "range_m", readonly(range_m))
        object.__setattr__(self, "point_index", readonly(point_index))
        object.__setattr__(self, "points", readonly(points))
        object.__setattr__(self, "row_elevation_rad", readonly(elevation))
        object.__setattr__(self, "azimuth_resolution_rad", float(self.azimuth_resolution_rad))

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns)."""
        return self.range_m.shape

    @property
    def occupied(self) -> np.ndarray:
        """(R, C) bool, True where a cell holds a point."""
        return self.point_index >= 0

    @classmethod
    def empty(cls, sensor: SensorModel) -> RangeImage:
        """An image of ``sensor``'s shape with no point in any cell."""
        shape = (sensor.n_rings, sensor.n_columns)
        return cls(
            range_m=np.full(shape, np.nan),
            point_index=np.full(shape, -1, dtype=np.int64),
            points=np.full(shape + (3,), np.nan),
            row_elevation_rad=sensor.elevation_rad,
            azimuth_resolution_rad=np.deg2rad(sensor.azimuth_resolution_deg),
        )


def _rows(scan: Scan, range_m: np.ndarray, sensor: SensorModel, use_ring_field: bool) -> np.ndarray:
    """(N,) int64 row of each point; -1 for points outside the beam table."""
    if use_ring_field and scan.ring.size and int(scan.ring.max()) < sensor.n_rings:
        return scan.ring.astype(np.int64)
    if use_ring_field and scan.ring.size:
        log.warning(
            "scan at %d ns has ring %d but %s has %d rings; rows taken from elevation instead",
            scan.stamp_ns,
            int(scan.ring.max()),
            sensor.name,
            sensor.n_rings,
        )
    with np.errstate(invalid="ignore", divide="ignore"):
        elevation = np.arcsin(np.clip(scan.points[:, 2] / range_m, -1.0, 1.0))
    table = sensor.elevation_rad
    margin = 0.5 * float(np.min(np.diff(table))) if table.size > 1 else np.deg2rad(1.0)
    inside = (elevation >= table[0] - margin) & (elevation <= table[-1] + margin)
    rows = sensor.ring_from_elevation(np.where(inside, elevation, table[0])).astype(np.int64)
    rows[~inside] = -1
    return rows


@lazy_njit
def _fill_cells(
    points: np.ndarray,
    range_m: np.ndarray,
    rows: np.ndarray,
    columns: np.ndarray,
    valid: np.ndarray,
    point_index: np.ndarray,
    image_points: np.ndarray,
    image_range: np.ndarray,
) -> None:
    """Write each ``valid`` point into its cell (``rows[i]``, ``columns[i]``), in place. Where several
    points fall into one cell the last in scan order stays, as in LeGO-LOAM. ``points`` (N, 3),
    ``range_m`` (N,), ``rows`` and ``columns`` (N,) int64, ``valid`` (N,) bool; ``point_index``
    (R, C) int64 filled with -1, ``image_points`` (R, C, 3) and ``image_range`` (R, C) filled with NaN."""
    for i in range(points.shape[0]):
        if valid[i]:
            point_index[rows[i], columns[i]] = i
    for r in range(point_index.shape[0]):
        for c in range(point_index.shape[1]):
            i = point_index[r, c]
            if i >= 0:
                image_points[r, c, 0] = points[i, 0]
                image_points[r, c, 1] = points[i, 1]
                image_points[r, c, 2] = points[i, 2]
                image_range[r, c] = range_m[i]


def project_scan(scan: Scan, sensor_config: SensorConfig, config: SegmentationConfig) -> RangeImage:
    """Project ``scan`` onto the range image of ``sensor_config.resolved_model``.

    Points closer than ``sensor_config.min_range_m``, farther than the sensor's maximum range, or
    non-finite are left out. Rows come from ``scan.ring`` when ``config.use_ring_field`` is set and
    every ring fits the sensor, else from elevation (nearest beam of the table, points more than half
    a beam spacing outside the table are left out). Column (IP:235-242, REP-105 axes):
    ``round(atan2(y, x) / resolution) + C/2`` modulo ``C``.
    """
    sensor = sensor_config.resolved_model
    n_rows, n_columns = sensor.n_rings, sensor.n_columns
    if len(scan) == 0:
        return RangeImage.empty(sensor)
    points = scan.points
    with np.errstate(invalid="ignore"):
        range_m = np.sqrt(np.einsum("ij,ij->i", points, points))
        valid = np.isfinite(range_m) & (range_m >= sensor_config.min_range_m) & (range_m <= sensor.max_range_m)
    rows = _rows(scan, range_m, sensor, config.use_ring_field)
    valid &= rows >= 0
    if not valid.any():
        return RangeImage.empty(sensor)
    resolution_rad = np.deg2rad(sensor.azimuth_resolution_deg)
    # NumPy's arctan2 is vectorised (ten times a scalar loop's speed); empty points give any column
    with np.errstate(invalid="ignore"):
        columns = np.rint(np.arctan2(points[:, 1], points[:, 0]) / resolution_rad)
    columns = np.where(valid, columns, 0.0).astype(np.int64)
    columns += n_columns // 2
    columns %= n_columns
    point_index = np.full((n_rows, n_columns), -1, dtype=np.int64)
    image_points = np.full((n_rows, n_columns, 3), np.nan)
    image_range = np.full((n_rows, n_columns), np.nan)
    _fill_cells(points, range_m, rows, columns, valid, point_index, image_points, image_range)
    return RangeImage(
        range_m=image_range,
        point_index=point_index,
        points=image_points,
        row_elevation_rad=sensor.elevation_rad,
        azimuth_resolution_rad=resolution_rad,
    )
