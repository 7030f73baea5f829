"""The dense point-cloud map: every sweep deskewed and placed with its final pose, moving objects
taken out (:mod:`lidar3d.mapping.free_space`) into a map of their own."""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from lidar3d.config import Config
from lidar3d.mapping.deskew import deskew_scan, twist_between
from lidar3d.mapping.free_space import DynamicFilter, FilteredSweep, PlacedSweep, outvoted_voxels
from lidar3d.mapping.se3 import transform_points
from lidar3d.mapping.voxel import VoxelMap
from lidar3d.records import Scan, Trajectory

__all__ = ["DenseMap", "build_dense_map"]


class DenseMap:
    """The static map (``map.pcd``) and the removed dynamic points (``dynamic.pcd``), both voxel maps
    of ``mapping.map_voxel_m``.

    With ``dynamic.enabled`` a sweep is decided a window of sweeps after it was added (see
    :class:`~lidar3d.mapping.free_space.DynamicFilter`): until :meth:`finish`, the latest sweeps are
    in neither map. Without it every sweep enters the static map at once.
    """

    def __init__(self, config: Config) -> None:
        self.config = config
        self.static = VoxelMap(config.mapping.map_voxel_m)
        self.dynamic = VoxelMap(config.mapping.map_voxel_m)
        model = config.sensor.resolved_model
        self._filter = (
            DynamicFilter(config.dynamic, model.elevation_deg, model.n_columns) if config.dynamic.enabled else None
        )

    @property
    def removes_dynamic(self) -> bool:
        """Whether moving objects are taken out of the static map."""
        return self._filter is not None

    def add(self, scan: Scan, T_world_lidar: np.ndarray, twist: np.ndarray) -> None:
        """Deskew ``scan`` with the body ``twist``, keep points within the sensor's range, and add
        them at ``T_world_lidar``."""
        final = deskew_scan(scan, twist)
        r = np.linalg.norm(final.points, axis=1)
        keep = (r >= self.config.sensor.min_range_m) & (r <= self.config.sensor.resolved_model.max_range_m)
        points_world = transform_points(T_world_lidar, final.points[keep])
        if self._filter is None:
            self.static.insert(points_world, final.intensity[keep])
            return
        sweep = PlacedSweep(final.points[keep], points_world, final.ring[keep], final.intensity[keep], T_world_lidar)
        for decided in self._filter.add(sweep):
            self._insert(decided)

    def finish(self) -> None:
        """End of input: the sweeps still waiting for their window are decided and enter the maps;
        then every map voxel holding more points judged dynamic than static
        (``dynamic.vote_ratio`` times) moves to the dynamic map whole: a voxel a moving object
        crossed in several sweeps is often missed in one of them."""
        if self._filter is None:
            return
        for decided in self._filter.flush():
            self._insert(decided)
        outvoted = outvoted_voxels(
            *self.static.voxel_counts(), *self.dynamic.voxel_counts(), self.config.dynamic.vote_ratio
        )
        self.static.move_voxels(outvoted, self.dynamic)

    def _insert(self, sweep: FilteredSweep) -> None:
        if self.config.dynamic.voxel_m == self.static.voxel_m:  # the sweep comes grouped as the maps take it
            static = ~sweep.voxel_dynamic
            self.static.insert_grouped(sweep.voxel_keys[static], sweep.voxel_sums[static])
            self.dynamic.insert_grouped(sweep.voxel_keys[~static], sweep.voxel_sums[~static])
            return
        static = ~sweep.dynamic
        self.static.insert(sweep.points_world[static], sweep.intensity[static])
        self.dynamic.insert(sweep.points_world[sweep.dynamic], sweep.intensity[sweep.dynamic])


def build_dense_map(scans: Iterable[Scan], trajectory: Trajectory, config: Config) -> DenseMap:
    """The map of ``scans`` placed with ``trajectory`` (scans whose stamp it lacks are skipped).

    Each sweep is deskewed with the motion to the next pose (the last with the motion from the
    previous one), as the pipeline does. Used to rebuild the map after loop closures moved poses.
    """
    dense_map = DenseMap(config)
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
        dense_map.add(scan, poses[i], twist)
    dense_map.finish()
    return dense_map
