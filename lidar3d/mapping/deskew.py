"""Motion compensation (deskewing) of a sweep under a constant-velocity model.

Reference time: the scan's header stamp. Each point fired at ``stamp + time_offset_s`` is moved
into the lidar frame at the stamp, so the deskewed scan looks as if the whole sweep had been
captured instantaneously at the stamp, and the pose estimated for the scan is the lidar pose at
that stamp (for the velodyne driver and our simulator: the start of the sweep).

The motion model is a body-frame twist (v, w) in m/s and rad/s, held constant over the sweep:
the lidar pose at time tau after the stamp is ``T_stamp_tau = exp(tau * twist)``.
"""

from __future__ import annotations

import numpy as np

from lidar3d.features.records import FeatureCloud, FeatureSet
from lidar3d.mapping.se3 import exp_apply, invert, log_se3
from lidar3d.records import Scan

__all__ = ["deskew_features", "deskew_points", "deskew_scan", "twist_between"]


def twist_between(T_world_a: np.ndarray, T_world_b: np.ndarray, dt_s: float) -> np.ndarray:
    """Constant body-frame twist (6,) that moves pose a to pose b in ``dt_s`` seconds."""
    if dt_s <= 0:
        return np.zeros(6)
    return log_se3(invert(T_world_a) @ T_world_b) / dt_s


def deskew_scan(scan: Scan, twist: np.ndarray) -> Scan:
    """The scan with every point moved into the lidar frame at the stamp; times become zero.

    Args:
        scan: the raw sweep.
        twist: (6,) body-frame velocity (v in m/s, w in rad/s) of the lidar during the sweep.
    """
    points = deskew_points(scan.points, scan.time_offset_s, twist)
    return Scan(scan.stamp_ns, points, scan.intensity, scan.ring, np.zeros(len(scan)))


def deskew_points(points: np.ndarray, time_offset_s: np.ndarray, twist: np.ndarray) -> np.ndarray:
    """Points (N,3) fired at ``time_offset_s`` moved into the lidar frame at the stamp."""
    if len(points) == 0 or not np.any(twist):
        return np.asarray(points, dtype=np.float64)
    return exp_apply(twist, time_offset_s, points)


def deskew_features(features: FeatureSet, twist: np.ndarray) -> FeatureSet:
    """The feature set with every cloud deskewed to the stamp (time offsets are kept, so a raw
    feature set can be deskewed again with a better motion estimate)."""

    def move(cloud: FeatureCloud) -> FeatureCloud:
        return FeatureCloud(deskew_points(cloud.points, cloud.time_offset_s, twist), cloud.ring, cloud.time_offset_s)

    return FeatureSet(
        stamp_ns=features.stamp_ns,
        sharp=move(features.sharp),
        less_sharp=move(features.less_sharp),
        flat=move(features.flat),
        less_flat=move(features.less_flat),
        outliers=move(features.outliers),
    )
