"""The whole front end in one call, with per-stage timing: scan -> Segmentation -> FeatureSet.

:func:`prepare_scan` is what the SLAM pipeline consumes: the features plus the dense
coarse-ground cloud (a :class:`PreparedScan`); it depends on nothing but the scan and the configuration, so an
adapter may run it ahead in another process (:mod:`lidar3d.prefetch`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from lidar3d.config import Config, FeatureConfig
from lidar3d.features.records import FeatureCloud, FeatureSet
from lidar3d.features.selection import select_features
from lidar3d.features.smoothness import compute_smoothness
from lidar3d.records import Scan
from lidar3d.segmentation import (
    Segmentation,
    assemble_segmentation,
    classify_ground,
    cluster_cells,
    project_scan,
    segment_scan,
    usable_rows,
)

__all__ = ["STAGES", "FrontEndResult", "PreparedScan", "extract_features", "prepare_scan", "run_front_end"]

STAGES = ("projection", "ground", "clustering", "smoothness", "selection")
"""Names of the timed sub-stages, in order, as keys of :attr:`FrontEndResult.stage_ms`."""


def extract_features(segmentation: Segmentation, config: FeatureConfig) -> FeatureSet:
    """Edge and planar features of a segmented scan (smoothness, then selection)."""
    return select_features(segmentation, compute_smoothness(segmentation, config), config)


@dataclass(frozen=True, slots=True)
class FrontEndResult:
    """Segmentation and features of one scan.

    Attributes:
        segmentation: the :class:`Segmentation` (range image, ground, clusters, outliers).
        features: the :class:`FeatureSet`; empty (with a logged warning) for unusable scans.
        stage_ms: wall time of each stage of :data:`STAGES`, milliseconds.
    """

    segmentation: Segmentation
    features: FeatureSet
    stage_ms: dict[str, float] = field(default_factory=dict)

    @property
    def total_ms(self) -> float:
        return float(sum(self.stage_ms.values()))


def run_front_end(scan: Scan, config: Config, *, surface_check: bool = True) -> FrontEndResult:
    """Run ``segment_scan`` then ``extract_features`` on ``scan``, timing each sub-stage.

    Same result as the two calls; an empty, single-ring or all-out-of-range scan gives an empty
    segmentation and an empty feature set, with a warning logged. ``surface_check=False`` skips the
    ground surface check, which only separates the lifted cells from the ground label: the features
    are the same, the segmentation's ground is then the coarse ground (:func:`prepare_scan`).
    """
    clock = time.perf_counter
    stage_ms = dict.fromkeys(STAGES, 0.0)
    t0 = clock()
    image = project_scan(scan, config.sensor, config.segmentation)
    t1 = clock()
    stage_ms["projection"] = (t1 - t0) * 1e3
    if usable_rows(image) < 2:
        segmentation = segment_scan(scan, config.segmentation, config.sensor)  # logs why, returns empty
        features = FeatureSet.empty(scan.stamp_ns)
        return FrontEndResult(segmentation=segmentation, features=features, stage_ms=stage_ms)
    ground_mask, lifted_mask = classify_ground(image, config.segmentation, config.sensor, surface_check=surface_check)
    t2 = clock()
    cluster_label, outlier_mask = cluster_cells(image, ground_mask | lifted_mask, config.segmentation)
    segmentation = assemble_segmentation(
        scan, image, ground_mask, cluster_label, outlier_mask, config.segmentation, lifted_mask
    )
    t3 = clock()
    smoothness = compute_smoothness(segmentation, config.features)
    t4 = clock()
    features = select_features(segmentation, smoothness, config.features)
    t5 = clock()
    stage_ms.update(
        ground=(t2 - t1) * 1e3, clustering=(t3 - t2) * 1e3, smoothness=(t4 - t3) * 1e3, selection=(t5 - t4) * 1e3
    )
    return FrontEndResult(segmentation=segmentation, features=features, stage_ms=stage_ms)


@dataclass(frozen=True, slots=True)
class PreparedScan:
    """A scan with its front-end output: what the SLAM pipeline needs of the front end.

    Attributes:
        scan: the raw sweep (lidar frame, as fired: not deskewed).
        features: its LeGO-LOAM feature set (lidar frame, not deskewed).
        coarse_ground: every coarse-ground cell (``Segmentation.coarse_ground_mask``: ground and
            lifted cells) of its range image as a cloud (lidar frame, not deskewed): the surfaces
            at the ground's level that mapping registers densely.
        stage_ms: front-end milliseconds per sub-stage of :data:`STAGES`.
    """

    scan: Scan
    features: FeatureSet
    coarse_ground: FeatureCloud
    stage_ms: dict[str, float]


def prepare_scan(scan: Scan, config: Config) -> PreparedScan:
    """Run the front end on ``scan`` (a pure function of the scan and the configuration). The SLAM
    reads the coarse ground only, so the ground label's surface check is skipped (0.6 ms a scan)."""
    front = run_front_end(scan, config, surface_check=False)
    return PreparedScan(scan, front.features, _coarse_ground_cloud(front.segmentation), front.stage_ms)


def _coarse_ground_cloud(segmentation: Segmentation) -> FeatureCloud:
    """Every coarse-ground cell of the range image as a cloud (the segmented cloud keeps only every
    fifth ground column; mapping wants the ground dense, since it fixes z, roll and pitch)."""
    idx = segmentation.image.point_index[segmentation.coarse_ground_mask]
    idx = idx[idx >= 0]
    scan = segmentation.scan
    return FeatureCloud(np.take(scan.points, idx, axis=0), scan.ring[idx], scan.time_offset_s[idx])
