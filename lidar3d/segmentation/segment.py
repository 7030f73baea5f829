"""The segmentation record and the one-call segmentation stage (LeGO-LOAM imageProjection).

``segment_scan`` = :func:`project_scan` -> :func:`classify_ground` -> :func:`cluster_cells` ->
:func:`assemble_segmentation`; each step is public so callers (benchmark, CLI) can time them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from lidar3d.config import SegmentationConfig, SensorConfig
from lidar3d.records import Scan, readonly
from lidar3d.segmentation.clustering import cluster_cells
from lidar3d.segmentation.ground import classify_ground, ground_row_count
from lidar3d.segmentation.range_image import RangeImage, project_scan

__all__ = ["Segmentation", "assemble_segmentation", "segment_scan", "usable_rows"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Segmentation:
    """Ground, clusters and the "segmented cloud" of one scan; R = rings, C = columns.

    Image-wide results:
        scan: the input scan (its per-point fields are reached through ``scan_index``).
        image: the scan's :class:`RangeImage`.
        ground_mask: (R, C) bool, ground cells.
        lifted_mask: (R, C) bool, cells the slope tests took for ground and the surface check took
            out of it (bases of walls and cars far out, far ground it cannot confirm; none with the
            check off). Not ground; the feature path treats them as it did before the check, as
            coarse ground (:attr:`coarse_ground_mask`).
        cluster_label: (R, C) int32, id ``0..K-1`` of the kept cluster of each cell; -1 elsewhere.
        outlier_mask: (R, C) bool, cells of rejected (too small) clusters.

    The segmented cloud, LeGO-LOAM's feature input (IP:312-355): coarse-ground cells (thinned to every
    ``ground_column_stride``-th column, plus the columns near the image seam) and kept-cluster
    cells, in row-major order, so each ring is one contiguous block ordered by column. Per point (M):
        scan_index: (M,) int64 index into ``scan``.
        points: (M, 3) float64, lidar frame, metres.
        row: (M,) int64 range-image row (= ring).
        column: (M,) int64 range-image column.
        range_m: (M,) float64 distance from the lidar origin.
        is_coarse_ground: (M,) bool, the point is a coarse-ground cell (flat features come from
            these, edges never).
        ring_start / ring_end: (R,) int64, ring r occupies ``[ring_start[r], ring_end[r])``.

    The outlier cloud for mapping (IP:328-335): outlier cells above the ground rows and on every
    ``outlier_column_stride``-th column:
        outlier_scan_index: (K,) int64 index into ``scan``.
        outlier_row: (K,) int64 range-image row of each outlier point.
    """

    scan: Scan
    image: RangeImage
    ground_mask: np.ndarray
    cluster_label: np.ndarray
    outlier_mask: np.ndarray
    lifted_mask: np.ndarray
    scan_index: np.ndarray
    points: np.ndarray
    row: np.ndarray
    column: np.ndarray
    range_m: np.ndarray
    is_coarse_ground: np.ndarray
    ring_start: np.ndarray
    ring_end: np.ndarray
    outlier_scan_index: np.ndarray
    outlier_row: np.ndarray

    def __post_init__(self) -> None:
        shape = self.image.shape
        masks = (("ground_mask", bool), ("cluster_label", np.int32), ("outlier_mask", bool), ("lifted_mask", bool))
        for name, dtype in masks:
            array = np.asarray(getattr(self, name), dtype=dtype)
            if array.shape != shape:
                raise ValueError(f"Segmentation.{name} must be {shape}, got {array.shape}")
            object.__setattr__(self, name, readonly(array))
        n = np.asarray(self.scan_index).shape[0]
        for name, point_dtype, tail in (
            ("scan_index", np.int64, ()),
            ("points", np.float64, (3,)),
            ("row", np.int64, ()),
            ("column", np.int64, ()),
            ("range_m", np.float64, ()),
            ("is_coarse_ground", bool, ()),
        ):
            array = np.asarray(getattr(self, name), dtype=point_dtype)
            if array.shape != (n,) + tail:
                raise ValueError(f"Segmentation.{name} must be {(n,) + tail}, got {array.shape}")
            object.__setattr__(self, name, readonly(array))
        for name in ("ring_start", "ring_end"):
            array = np.asarray(getattr(self, name), dtype=np.int64)
            if array.shape != (shape[0],):
                raise ValueError(f"Segmentation.{name} must be ({shape[0]},), got {array.shape}")
            object.__setattr__(self, name, readonly(array))
        outliers = np.asarray(self.outlier_scan_index, dtype=np.int64)
        outlier_row = np.asarray(self.outlier_row, dtype=np.int64)
        if outliers.ndim != 1 or outlier_row.shape != outliers.shape:
            raise ValueError(
                "Segmentation.outlier_scan_index and outlier_row must be (K,), "
                f"got {outliers.shape}, {outlier_row.shape}"
            )
        object.__setattr__(self, "outlier_scan_index", readonly(outliers))
        object.__setattr__(self, "outlier_row", readonly(outlier_row))

    def __len__(self) -> int:
        """Number of points in the segmented cloud."""
        return int(self.scan_index.shape[0])

    @property
    def coarse_ground_mask(self) -> np.ndarray:
        """(R, C) bool, the ground by the slope tests alone: ground and lifted cells. The clusters,
        the features and mapping's dense ground cloud are made with it, as they were before the
        surface check (with the lifted cells as objects, `city_traffic` lost 17-88 % ATE,
        docs/stages/segmentation.md)."""
        return self.ground_mask | self.lifted_mask

    @property
    def n_clusters(self) -> int:
        return int(self.cluster_label.max()) + 1 if self.cluster_label.size else 0

    @property
    def time_offset_s(self) -> np.ndarray:
        """(M,) float64 firing time of each segmented-cloud point relative to ``scan.stamp_ns``."""
        return self.scan.time_offset_s[self.scan_index]

    @property
    def outlier_points(self) -> np.ndarray:
        """(K, 3) float64 outlier cloud for mapping, lidar frame."""
        return np.take(self.scan.points, self.outlier_scan_index, axis=0)

    @classmethod
    def empty(cls, scan: Scan, image: RangeImage) -> Segmentation:
        """No ground, no cluster, no segmented point (the result for unusable scans)."""
        shape = image.shape
        none = np.zeros(0, dtype=np.int64)
        return cls(
            scan=scan,
            image=image,
            ground_mask=np.zeros(shape, dtype=bool),
            cluster_label=np.full(shape, -1, dtype=np.int32),
            outlier_mask=np.zeros(shape, dtype=bool),
            lifted_mask=np.zeros(shape, dtype=bool),
            scan_index=none,
            points=np.zeros((0, 3)),
            row=none,
            column=none,
            range_m=np.zeros(0),
            is_coarse_ground=np.zeros(0, dtype=bool),
            ring_start=np.zeros(shape[0], dtype=np.int64),
            ring_end=np.zeros(shape[0], dtype=np.int64),
            outlier_scan_index=none,
            outlier_row=none,
        )


def usable_rows(image: RangeImage) -> int:
    """Number of rows of ``image`` holding at least one point."""
    return int(np.count_nonzero(image.occupied.any(axis=1)))


def assemble_segmentation(
    scan: Scan,
    image: RangeImage,
    ground_mask: np.ndarray,
    cluster_label: np.ndarray,
    outlier_mask: np.ndarray,
    config: SegmentationConfig,
    lifted_mask: np.ndarray | None = None,
) -> Segmentation:
    """Build the segmented cloud and the outlier cloud from the per-cell results (IP:312-355);
    ``lifted_mask`` (R, C) from :func:`classify_ground`, none lifted when omitted; ``cluster_label``
    and ``outlier_mask`` from :func:`cluster_cells` on the coarse ground (ground and lifted)."""
    n_rows, n_columns = image.shape
    columns = np.arange(n_columns)
    stride = max(config.ground_column_stride, 1)
    # LeGO-LOAM keeps all ground near the seam so curvature windows there stay dense
    ground_columns = (columns % stride == 0) | (columns <= stride) | (columns >= n_columns - stride)
    lifted = np.zeros(image.shape, dtype=bool) if lifted_mask is None else lifted_mask
    coarse_ground = ground_mask | lifted
    kept = (cluster_label >= 0) | (coarse_ground & ground_columns[None, :])
    flat = np.flatnonzero(kept.ravel())  # row-major
    row = flat // n_columns
    column = flat % n_columns
    scan_index = image.point_index.ravel()[flat]
    rows = np.arange(n_rows)
    outlier_columns = columns % max(config.outlier_column_stride, 1) == 0
    outlier_cells = outlier_mask & outlier_columns[None, :]
    outlier_cells[: ground_row_count(config, image.row_elevation_rad)] = False
    return Segmentation(
        scan=scan,
        image=image,
        ground_mask=ground_mask,
        cluster_label=cluster_label,
        outlier_mask=outlier_mask,
        lifted_mask=lifted,
        scan_index=scan_index,
        points=np.take(scan.points, scan_index, axis=0),  # take: 5x fancy indexing's speed on rows
        row=row,
        column=column,
        range_m=image.range_m.ravel()[flat],
        is_coarse_ground=coarse_ground.ravel()[flat],
        ring_start=np.searchsorted(row, rows, side="left"),
        ring_end=np.searchsorted(row, rows, side="right"),
        outlier_scan_index=image.point_index[outlier_cells],
        outlier_row=np.nonzero(outlier_cells)[0],
    )


def segment_scan(scan: Scan, config: SegmentationConfig, sensor_config: SensorConfig) -> Segmentation:
    """Range image, ground and clusters of one scan.

    An empty scan, a scan whose points are all out of range, or one with points on fewer than two
    rings gives an empty :class:`Segmentation` and a logged warning.
    """
    image = project_scan(scan, sensor_config, config)
    rows = usable_rows(image)
    if rows < 2:
        if len(scan) == 0:
            reason = "it has no points"
        elif rows == 0:
            reason = "no point lies within the sensor's range"
        else:
            reason = "its points lie on a single ring"
        log.warning("scan at %d ns skipped by the front end: %s", scan.stamp_ns, reason)
        return Segmentation.empty(scan, image)
    ground_mask, lifted_mask = classify_ground(image, config, sensor_config)
    cluster_label, outlier_mask = cluster_cells(image, ground_mask | lifted_mask, config)
    return assemble_segmentation(scan, image, ground_mask, cluster_label, outlier_mask, config, lifted_mask)
