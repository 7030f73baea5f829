"""Motion compensation (deskewing) of a sweep under a constant-velocity model.

Reference time: the scan's header stamp. Each point fired at ``stamp + time_offset_s`` is moved
into the lidar frame at the stamp, so the deskewed scan looks as if the whole sweep had been
captured instantaneously at the stamp, and the pose estimated for the scan is the lidar pose at
that stamp, whatever instant it marks (the sweep start for raw packets and the simulator, times
0..T; the sweep end for the stock ROS1 velodyne driver's clouds, times -T..0).

The motion model is a body-frame twist (v, w) in m/s and rad/s, held constant over the sweep:
the lidar pose at time tau after the stamp is ``T_stamp_tau = exp(tau * twist)``.
"""

from __future__ import annotations

import numpy as np

from lidar3d.features.records import FeatureCloud, FeatureSet
from lidar3d.mapping.se3 import exp_apply, invert, log_se3
from lidar3d.records import Scan

__all__ = [
    "deskew_again",
    "deskew_features",
    "deskew_points",
    "deskew_scan",
    "share_after_stamp",
    "sweep_twist",
    "trajectory_sweep_twist",
    "twist_between",
]


def twist_between(T_world_a: np.ndarray, T_world_b: np.ndarray, dt_s: float) -> np.ndarray:
    """Constant body-frame twist (6,) that moves pose a to pose b in ``dt_s`` seconds."""
    if dt_s <= 0:
        return np.zeros(6)
    return log_se3(invert(T_world_a) @ T_world_b) / dt_s


def share_after_stamp(time_offset_s: np.ndarray) -> float:
    """The share (0..1) of a sweep's time span that lies after its stamp: 1 for a sweep stamped at
    its start (times 0..T), 0 for one stamped at its end (times -T..0), 1 for an empty or
    instantaneous sweep stamped at or before its points."""
    if len(time_offset_s) == 0:
        return 1.0
    first_s, last_s = float(np.min(time_offset_s)), float(np.max(time_offset_s))
    if last_s <= first_s:
        return 1.0 if first_s >= 0.0 else 0.0
    return (max(last_s, 0.0) - max(first_s, 0.0)) / (last_s - first_s)


def sweep_twist(share_after: float, twist_before: np.ndarray | None, twist_after: np.ndarray | None) -> np.ndarray:
    """The constant body twist (6,) over a sweep, from the twists of the intervals around its stamp.

    ``twist_before`` is the motion from the previous stamp to this one, ``twist_after`` the motion
    from this stamp to the next (None where unknown: the first or the last scan). The sweep's
    points lie in those intervals in the proportion ``share_after`` (:func:`share_after_stamp`),
    so a sweep stamped at its start takes the motion to the next stamp, one stamped at its end the
    motion from the previous stamp, and one stamped in between the time-weighted mean of the two.
    """
    if twist_before is None or share_after >= 1.0:
        chosen = twist_after if twist_after is not None else twist_before
    elif twist_after is None or share_after <= 0.0:
        chosen = twist_before
    else:
        chosen = share_after * twist_after + (1.0 - share_after) * twist_before
    if chosen is None:
        return np.zeros(6)
    return np.array(chosen, dtype=np.float64)


def trajectory_sweep_twist(
    stamps_ns: np.ndarray, T_world_lidar: np.ndarray, index: int, time_offset_s: np.ndarray
) -> np.ndarray:
    """The body twist (6,) to deskew sweep ``index`` of a trajectory with (N,) ``stamps_ns`` and
    (N,4,4) ``T_world_lidar`` poses at them, its points fired at ``time_offset_s`` (N_points,) after
    its stamp: :func:`sweep_twist` of the motions from the previous pose and to the next one (zero
    for a trajectory of one pose)."""

    def between(a: int, b: int) -> np.ndarray | None:
        if a < 0 or b >= len(stamps_ns):
            return None
        return twist_between(T_world_lidar[a], T_world_lidar[b], (stamps_ns[b] - stamps_ns[a]) * 1e-9)

    return sweep_twist(share_after_stamp(time_offset_s), between(index - 1, index), between(index, index + 1))


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


def deskew_again(
    points: np.ndarray, time_offset_s: np.ndarray, old_twist: np.ndarray, new_twist: np.ndarray
) -> np.ndarray:
    """Points (N,3) that were deskewed to the stamp with ``old_twist``, deskewed with ``new_twist``
    instead (each (6,) body velocity, v m/s, w rad/s; ``time_offset_s`` (N,) when each was fired,
    s from the stamp): back to where it was fired, then forward again."""
    return deskew_points(deskew_points(points, time_offset_s, -np.asarray(old_twist)), time_offset_s, new_twist)


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
