"""Edge and planar features of a segmented scan (LeGO-LOAM featureAssociation), vectorised.

One call for the whole front end: ``run_front_end(scan, config) -> FrontEndResult`` (segmentation,
features, per-stage ms). Features only: ``extract_features(segmentation, config.features)``; step by
step: ``compute_smoothness`` -> ``select_features``.
"""

from lidar3d.features.frontend import (
    STAGES,
    FrontEndResult,
    PreparedScan,
    extract_features,
    prepare_scan,
    run_front_end,
)
from lidar3d.features.records import FeatureCloud, FeatureSet, Smoothness
from lidar3d.features.selection import select_features, voxel_centroids_per_ring
from lidar3d.features.smoothness import compute_smoothness

__all__ = [
    "STAGES",
    "FeatureCloud",
    "FeatureSet",
    "FrontEndResult",
    "PreparedScan",
    "Smoothness",
    "compute_smoothness",
    "extract_features",
    "prepare_scan",
    "run_front_end",
    "select_features",
    "voxel_centroids_per_ring",
]
