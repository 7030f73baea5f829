"""The dense point-cloud map: every sweep deskewed and placed with its final pose."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from lidar3d.config import Config
from lidar3d.mapping.deskew import deskew_scan, twist_between
from lidar3d.mapping.se3 import transform_points
from lidar3d.mapping.voxel import VoxelMap
from lidar3d.records import Scan, Trajectory

__all__ = ["add_scan_to_map", "build_dense_map"]


def add_scan_to_map(
    dense_map: VoxelMap, scan: Scan, T_world_lidar: np.ndarray, twist: np.ndarray, config: Config
) -> None:
    """Deskew ``scan`` with the body ``twist``, keep points within the sensor's range, and add them
    to ``dense_map`` at ``T_world_lidar``."""
    final = deskew_scan(scan, twist)
    r = np.linalg.norm(final.points, axis=1)
    keep = (r >= config.sensor.min_range_m) & (r <= config.sensor.resolved_model.max_range_m)
    dense_map.insert(transform_points(T_world_lidar, final.points[keep]), final.intensity[keep])


def build_dense_map(scans: Iterable[Scan], trajectory: Trajectory, config: Config) -> VoxelMap:
    """The map of ``scans`` placed with ``trajectory`` (scans whose stamp it lacks are skipped).

    Each sweep is deskewed with the motion to the next pose (the last with the motion from the
    previous one), as the pipeline does. Used to rebuild the map after loop closures moved poses.
    """
    dense_map = VoxelMap(config.mapping.map_voxel_m)
    stamps = trajectory.stamps_ns
    poses = trajectory.T_world_lidar
    for scan in scans:
        i = int(np.searchsorted(stamps, scan.stamp_ns))
        if i >= len(stamps) or stamps[i] != scan.stamp_ns:
            continue
        if len(stamps) < 2:
            twist = np.zeros(6)
        else:
            a, b = (i, i + 1) if i + 1 < len(stamps) else (i - 1, i)
            twist = twist_between(poses[a], poses[b], (stamps[b] - stamps[a]) * 1e-9)
        add_scan_to_map(dense_map, scan, poses[i], twist, config)
    return dense_map
