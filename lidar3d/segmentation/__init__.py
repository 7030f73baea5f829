"""Range image, ground marking and clustering (LeGO-LOAM imageProjection), vectorised.

One call: ``segment_scan(scan, config.segmentation, config.sensor) -> Segmentation``. Step by step:
``project_scan`` -> ``classify_ground`` (or ``mark_ground``) -> ``cluster_cells`` -> ``assemble_segmentation``.
"""

from lidar3d.segmentation.clustering import cluster_cells
from lidar3d.segmentation.ground import (
    R_base_lidar_from_mount,
    classify_ground,
    ground_row_count,
    mark_ground,
)
from lidar3d.segmentation.range_image import RangeImage, project_scan
from lidar3d.segmentation.segment import Segmentation, assemble_segmentation, segment_scan, usable_rows

__all__ = [
    "R_base_lidar_from_mount",
    "RangeImage",
    "Segmentation",
    "assemble_segmentation",
    "classify_ground",
    "cluster_cells",
    "ground_row_count",
    "mark_ground",
    "project_scan",
    "segment_scan",
    "usable_rows",
]
