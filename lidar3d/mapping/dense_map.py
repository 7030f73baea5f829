"""The dense point-cloud map: every sweep deskewed and placed with its final pose, moving objects
taken out (:mod:`lidar3d.mapping.free_space`) into a map of their own, and (with loop closure) kept
in pieces anchored to keyframes (:mod:`lidar3d.mapping.map_pieces`) so that it can be placed again
when loop closures move the keyframes."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from lidar3d.config import Config
from lidar3d.mapping.deskew import deskew_scan, trajectory_sweep_twist
from lidar3d.mapping.free_space import DynamicFilter, FilteredSweep, PlacedSweep, outvoted_voxels
from lidar3d.mapping.map_pieces import MapAnchor, MapPieces, place_pieces
from lidar3d.mapping.se3 import transform_points
from lidar3d.mapping.voxel import VoxelMap, group_by_voxel
from lidar3d.records import Scan, Trajectory

__all__ = ["DenseMap", "MapClouds", "build_dense_map"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class MapClouds:
    """The dense map's two voxel maps as clouds, world frame.

    Attributes:
        points: (M,3) float64 static map, one point (the voxel mean) per voxel.
        intensity: (M,) float64 mean intensity per voxel.
        dynamic_points: (D,3) float64 the removed moving objects, per voxel.
        dynamic_intensity: (D,) float64 their mean intensity.
    """

    points: np.ndarray
    intensity: np.ndarray
    dynamic_points: np.ndarray
    dynamic_intensity: np.ndarray

    @classmethod
    def empty(cls) -> MapClouds:
        """No map (a snapshot taken without it)."""
        return cls(np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros(0))


class DenseMap:
    """The static map (``map.pcd``) and the removed dynamic points (``dynamic.pcd``), both voxel maps
    of ``mapping.map_voxel_m``.

    With ``dynamic.enabled`` a sweep is decided a window of sweeps after it was added (see
    :class:`~lidar3d.mapping.free_space.DynamicFilter`): until :meth:`finish`, the latest sweeps are
    in neither map. Without it every sweep enters the static map at once.

    Args:
        config: the run's configuration.
        pieces: also collect every sweep into these pieces (by the anchor given to :meth:`add`), so
            that :meth:`place_again` can move the map with its keyframes; None: the map is final as
            placed.
    """

    def __init__(self, config: Config, pieces: MapPieces | None = None) -> None:
        self.config = config
        self.static = VoxelMap(config.mapping.map_voxel_m)
        self.dynamic = VoxelMap(config.mapping.map_voxel_m)
        model = config.sensor.resolved_model
        # the filter hands on its voxels as the maps take them; points one by one only otherwise
        self._filter_voxels_are_the_maps = config.dynamic.voxel_m == config.mapping.map_voxel_m
        self._filter = (
            DynamicFilter(
                config.dynamic,
                model.elevation_deg,
                model.n_columns,
                per_point=not self._filter_voxels_are_the_maps,
            )
            if config.dynamic.enabled
            else None
        )
        self._pieces = pieces
        self._anchors: deque[MapAnchor | None] = deque()  # of the sweeps waiting in the filter, oldest first

    @property
    def removes_dynamic(self) -> bool:
        """Whether moving objects are taken out of the static map."""
        return self._filter is not None

    def add(self, scan: Scan, T_world_lidar: np.ndarray, twist: np.ndarray, anchor: MapAnchor | None = None) -> None:
        """Deskew ``scan`` with the body ``twist``, keep points within the sensor's range, and add
        them at ``T_world_lidar``; ``anchor``: the keyframe the sweep follows (needed with pieces)."""
        if self._pieces is not None and anchor is None:
            raise ValueError("a dense map kept in pieces needs the anchor of every sweep")
        final = deskew_scan(scan, twist)
        r = np.linalg.norm(final.points, axis=1)
        keep = (r >= self.config.sensor.min_range_m) & (r <= self.config.sensor.resolved_model.max_range_m)
        points_world = transform_points(T_world_lidar, final.points[keep])
        if self._filter is None:
            keys, sums = group_by_voxel(points_world, final.intensity[keep], self.static.voxel_m)
            self.static.insert_grouped(keys, sums)
            if self._pieces is not None and anchor is not None:
                self._pieces.add(anchor, keys, sums, np.zeros(len(keys), bool))
            return
        sweep = PlacedSweep(final.points[keep], points_world, final.ring[keep], final.intensity[keep], T_world_lidar)
        self._anchors.append(anchor)
        for decided in self._filter.add(sweep):
            self._insert(decided, self._anchors.popleft())

    def finish(self) -> None:
        """End of input: the sweeps still waiting for their window are decided and enter the maps;
        then every map voxel holding more points judged dynamic than static
        (``dynamic.vote_ratio`` times) moves to the dynamic map whole: a voxel a moving object
        crossed in several sweeps is often missed in one of them."""
        if self._filter is not None:
            for decided in self._filter.flush():
                self._insert(decided, self._anchors.popleft())
            self._vote()
        if self._pieces is not None:
            self._pieces.close()

    def clouds(self) -> MapClouds:
        """Both maps as they stand, as clouds."""
        points, intensity = self.static.points_and_intensity()
        dynamic_points, dynamic_intensity = self.dynamic.points_and_intensity()
        return MapClouds(points, intensity, dynamic_points, dynamic_intensity)

    def place_again(self, keyframe_poses: np.ndarray) -> None:
        """After :meth:`finish`: place the map again from its pieces, each moved with its keyframe's
        pose in ``keyframe_poses`` (K,4,4) (after loop closures moved them), and vote the voxels again.

        Raises:
            ValueError: the map is not kept in pieces.
        """
        if self._pieces is None:
            raise ValueError("the dense map is not kept in pieces")
        self._pieces.close()
        try:
            placed = place_pieces(self._pieces.store.pieces(), keyframe_poses, self.static.voxel_m)
        except OSError as err:  # a spill file that cannot be read back: the map stays as placed
            log.warning(
                "the dense map's pieces cannot be read back (%s); map.pcd keeps the poses before the loop closures", err
            )
            return
        self.static, self.dynamic = placed
        if self._filter is not None:
            self._vote()

    def _vote(self) -> None:
        outvoted = outvoted_voxels(
            *self.static.voxel_counts(), *self.dynamic.voxel_counts(), self.config.dynamic.vote_ratio
        )
        self.static.move_voxels(outvoted, self.dynamic)

    def _insert(self, sweep: FilteredSweep, anchor: MapAnchor | None) -> None:
        if self._filter_voxels_are_the_maps:  # the sweep comes grouped as the maps take it
            static = ~sweep.voxel_dynamic
            self.static.insert_grouped(sweep.voxel_keys[static], sweep.voxel_sums[static])
            self.dynamic.insert_grouped(sweep.voxel_keys[~static], sweep.voxel_sums[~static])
            if self._pieces is not None and anchor is not None:
                self._pieces.add(anchor, sweep.voxel_keys, sweep.voxel_sums, sweep.voxel_dynamic)
            return
        points, intensity, dynamic = sweep.points_world, sweep.intensity, sweep.dynamic
        assert points is not None and intensity is not None and dynamic is not None  # a per-point filter's
        self.static.insert(points[~dynamic], intensity[~dynamic])
        self.dynamic.insert(points[dynamic], intensity[dynamic])
        if self._pieces is not None and anchor is not None:
            self._pieces.add_points(anchor, points, intensity, dynamic)


def build_dense_map(scans: Iterable[Scan], trajectory: Trajectory, config: Config) -> DenseMap:
    """The map of ``scans`` placed with ``trajectory`` (scans whose stamp it lacks are skipped).

    Each sweep is deskewed with the motion between the poses around its points, as the pipeline
    does (:func:`~lidar3d.mapping.deskew.trajectory_sweep_twist`: the motion to the next pose for a
    sweep stamped at its start, from the previous pose for one stamped at its end; the first and
    last sweeps take the one they have). Used to rebuild the map after loop closures moved poses.
    """
    dense_map = DenseMap(config)
    stamps = trajectory.stamps_ns
    poses = trajectory.T_world_lidar
    for scan in scans:
        i = int(np.searchsorted(stamps, scan.stamp_ns))
        if i >= len(stamps) or stamps[i] != scan.stamp_ns:
            continue
        dense_map.add(scan, poses[i], trajectory_sweep_twist(stamps, poses, i, scan.time_offset_s))
    dense_map.finish()
    return dense_map
