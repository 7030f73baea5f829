"""Keyframes and the bounded submap they form for scan-to-submap registration."""

from __future__ import annotations

import dataclasses
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, overload

import numpy as np

from lidar3d.config import MappingConfig
from lidar3d.mapping.map_pieces import MapAnchor
from lidar3d.mapping.registration import LineMap, PlaneMap
from lidar3d.mapping.se3 import invert, transform_points
from lidar3d.mapping.voxel import KeyedCloud, voxel_downsample_parts

__all__ = ["Keyframe", "KeyframeCloudStore", "KeyframeList", "KeyframeSelector", "Submap", "SubmapTarget"]


@dataclass(frozen=True, slots=True)
class Keyframe:
    """A scan kept for the map.

    Attributes:
        index: keyframe number (0, 1, ...).
        scan_index: index of the scan in the input stream.
        stamp_ns: scan stamp.
        T_world_lidar: (4,4) pose at selection time (corrections live in the pose graph).
        corner_points: (M,3) downsampled edge features, lidar frame (float32 in the pipeline).
        surf_points: (K,3) downsampled planar features, outliers and ground, lidar frame.
        step_covariance: (6,6) covariance of the step from the previous keyframe to this one
            (GTSAM order ``[w (rad), v (m)]``, this keyframe's frame;
            :class:`~lidar3d.mapping.step_uncertainty.StepUncertainty`), None when unknown.
        placed_lost: the health flag of its scan was ``lost``: its pose was dead-reckoned, so a
            scan registered against it is no better (:meth:`Submap.lost_keyframes_in_target`).
    """

    index: int
    scan_index: int
    stamp_ns: int
    T_world_lidar: np.ndarray
    corner_points: np.ndarray
    surf_points: np.ndarray
    step_covariance: np.ndarray | None = None
    placed_lost: bool = False


class KeyframeCloudStore(Protocol):
    """Where a :class:`Submap` keeps the clouds of keyframes older than its resident ones (spilled
    to disk by an adapter: :class:`lidar3d.io.keyframe_spill.SpilledKeyframeClouds`). What comes
    back must be what was put, to the bit: the registrations read it again."""

    def put(self, keyframe: int, corner_points: np.ndarray, surf_points: np.ndarray) -> None:
        """Keep keyframe ``keyframe``'s (M,3) corner and (K,3) surface points (lidar frame); a later
        put for the same keyframe replaces them."""

    def get(self, keyframe: int) -> tuple[np.ndarray, np.ndarray]:
        """The (M,3) corner and (K,3) surface points put for ``keyframe``."""


_NO_POINTS = np.zeros((0, 3), np.float32)
_NO_POINTS.flags.writeable = False


class KeyframeSelector:
    """Decides which scans become keyframes: after enough motion since the latest keyframe.

    Spacing is measured from the latest keyframe's pose as the pipeline last knew it
    (:meth:`anchor`: at selection, and again when re-registration or a loop closure moves it).

    Args:
        distance_m: travelled distance that makes a keyframe.
        angle_deg: rotation that makes a keyframe.
        min_surface_points: scans with fewer surface points (less-flat, outliers, ground) never
            become keyframes (they would add nothing to match against).
    """

    def __init__(self, *, distance_m: float, angle_deg: float, min_surface_points: int) -> None:
        self.distance_m = distance_m
        self.angle_deg = angle_deg
        self.min_surface_points = min_surface_points
        self._anchor: np.ndarray | None = None

    def is_due(self, T_world_lidar: np.ndarray, n_surface_points: int) -> bool:
        """Whether a scan at ``T_world_lidar`` (4,4) with that many surface points is a keyframe."""
        if n_surface_points < self.min_surface_points:
            return False
        if self._anchor is None:
            return True
        delta = invert(self._anchor) @ T_world_lidar
        moved = np.linalg.norm(delta[:3, 3])
        angle = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
        return bool(moved >= self.distance_m or angle >= self.angle_deg)

    def anchor(self, T_world_lidar: np.ndarray) -> None:
        """Measure the spacing of the next keyframes from ``T_world_lidar`` (the latest keyframe)."""
        self._anchor = T_world_lidar


@dataclass(frozen=True, slots=True)
class SubmapTarget:
    """World-frame feature maps of the selected keyframes (None where a cloud is empty)."""

    keyframe_indices: tuple[int, ...]
    corners: LineMap | None
    surfaces: PlaneMap | None


class Submap:
    """Selects keyframes around the current position and keeps their world clouds cached.

    Selection: every keyframe within ``radius_m`` (horizontal distance) of the query position,
    at most ``max_keyframes`` of them (the nearest first), always including the ``recent``
    latest keyframes. World-frame clouds of keyframes are cached (at most ``cache_size``,
    least recently used dropped); the cache is invalidated when poses are corrected.
    :attr:`revision` counts the changes to keyframes already in it (clouds replaced, poses
    corrected; not keyframes added): correspondences found in it hold while it is unchanged.

    With a ``cloud_store``, the lidar-frame clouds of all but the ``resident`` latest keyframes
    live there (on disk in a run) and are read back when needed: when a keyframe enters the
    world-cloud cache again, and by the loop verification through :attr:`keyframes`.
    """

    def __init__(
        self,
        *,
        radius_m: float,
        max_keyframes: int,
        recent: int,
        corner_voxel_m: float,
        surf_voxel_m: float,
        cache_size: int = 100,
        rebuild_every_keyframes: int = 1,
        plane_neighbours: int = 5,
        plane_max_distance_m: float = 1.0,
        cloud_store: KeyframeCloudStore | None = None,
        resident: int = 10,
    ) -> None:
        self.radius_m = radius_m
        self.max_keyframes = max_keyframes
        self.recent = recent
        self.corner_voxel_m = corner_voxel_m
        self.surf_voxel_m = surf_voxel_m
        self.cache_size = cache_size
        self.rebuild_every_keyframes = rebuild_every_keyframes
        self.plane_neighbours = plane_neighbours
        self.plane_max_distance_m = plane_max_distance_m
        self._added_since_build = 0
        self.revision = 0
        self._keyframes = KeyframeList(cloud_store, resident)
        self._poses: list[np.ndarray] = []
        self._cache: OrderedDict[int, tuple[KeyedCloud, KeyedCloud]] = OrderedDict()
        self._target: SubmapTarget | None = None

    @classmethod
    def of_config(cls, mp: MappingConfig, cloud_store: KeyframeCloudStore | None = None) -> Submap:
        """The submap of the ``[mapping]`` section, older keyframes' clouds in ``cloud_store``
        (the latest ``submap_recent_keyframes`` stay resident)."""
        return cls(
            radius_m=mp.submap_radius_m,
            max_keyframes=mp.submap_max_keyframes,
            recent=mp.submap_recent_keyframes,
            corner_voxel_m=mp.corner_voxel_m,
            surf_voxel_m=mp.surf_voxel_m,
            cache_size=mp.submap_cache_keyframes,
            rebuild_every_keyframes=mp.submap_rebuild_every_keyframes,
            plane_neighbours=mp.plane_neighbours,
            plane_max_distance_m=mp.plane_max_distance_m,
            cloud_store=cloud_store,
            resident=mp.submap_recent_keyframes,
        )

    def __len__(self) -> int:
        return len(self._keyframes)

    @property
    def keyframes(self) -> KeyframeList:
        """Every keyframe so far (an item comes with its clouds, read back from the store for
        older ones)."""
        return self._keyframes

    @property
    def poses(self) -> np.ndarray:
        """(K,4,4) current keyframe poses."""
        return np.array(self._poses) if self._poses else np.zeros((0, 4, 4))

    def anchor(self) -> MapAnchor:
        """The keyframe a sweep placed now follows in the dense map: the latest one, at its current pose."""
        if not self._keyframes:
            return MapAnchor(None, np.eye(4))
        return MapAnchor(len(self._keyframes) - 1, self._poses[-1])

    def add(self, keyframe: Keyframe) -> None:
        """Append ``keyframe`` (its ``index`` the next number)."""
        self._keyframes.append(keyframe)
        self._poses.append(np.array(keyframe.T_world_lidar))
        self._added_since_build += 1

    def replace_clouds(self, k: int, corner_points: np.ndarray, surf_points: np.ndarray) -> None:
        """Replace keyframe ``k``'s clouds (e.g. once a better deskewing motion is known)."""
        self._keyframes.replace_clouds(k, corner_points, surf_points)
        self._cache.pop(k, None)
        self._target = None
        self.revision += 1

    def set_poses(self, poses: np.ndarray) -> None:
        """Replace all keyframe poses (after a pose-graph correction) and drop the cache."""
        if len(poses) != len(self._keyframes):
            raise ValueError(f"expected {len(self._keyframes)} poses, got {len(poses)}")
        self._poses = [np.array(p) for p in poses]
        self._cache.clear()
        self._target = None
        self.revision += 1

    def _world_clouds(self, k: int) -> tuple[KeyedCloud, KeyedCloud]:
        """Keyframe ``k``'s corner and surface clouds in the world frame, keyed by the submap's
        corner and surface voxels (cached)."""
        cached = self._cache.get(k)
        if cached is not None:
            self._cache.move_to_end(k)
            return cached
        kf = self._keyframes[k]
        T = self._poses[k]
        clouds = (
            KeyedCloud.of(transform_points(T, kf.corner_points.astype(np.float64)), self.corner_voxel_m),
            KeyedCloud.of(transform_points(T, kf.surf_points.astype(np.float64)), self.surf_voxel_m),
        )
        self._cache[k] = clouds
        if len(self._cache) > self.cache_size:
            self._cache.popitem(last=False)
        return clouds

    def select(self, position_m: np.ndarray) -> tuple[int, ...]:
        """Keyframe indices forming the submap around ``position_m``."""
        n = len(self._keyframes)
        if n == 0:
            return ()
        positions = np.array([p[:3, 3] for p in self._poses])
        dist = np.linalg.norm(positions[:, :2] - position_m[:2], axis=1)
        near = np.flatnonzero(dist <= self.radius_m)
        near = near[np.argsort(dist[near], kind="stable")][: self.max_keyframes]
        recent = np.arange(max(0, n - self.recent), n)
        return tuple(sorted(set(near.tolist()) | set(recent.tolist())))

    def target(self, position_m: np.ndarray) -> SubmapTarget:
        """The submap around ``position_m``.

        The previous build is reused while fewer than ``rebuild_every_keyframes`` keyframes were
        added since and the selection holds no other keyframe than those (building costs a voxel
        filter and two k-d trees); replacing poses or clouds forces a rebuild.
        """
        selection = self.select(position_m)
        if self._target is not None and self._added_since_build < self.rebuild_every_keyframes:
            newest = set(range(len(self._keyframes) - self._added_since_build, len(self._keyframes)))
            if set(selection) <= set(self._target.keyframe_indices) | newest:
                return self._target
        self._added_since_build = 0
        clouds = [self._world_clouds(k) for k in selection]
        corner = voxel_downsample_parts([corners for corners, _ in clouds])
        surf = voxel_downsample_parts([surfs for _, surfs in clouds])
        self._target = SubmapTarget(
            keyframe_indices=selection,
            corners=LineMap(corner) if len(corner) else None,
            surfaces=(
                PlaneMap(surf, k=self.plane_neighbours, max_sq_dist=self.plane_max_distance_m**2) if len(surf) else None
            ),
        )
        return self._target

    def lost_keyframes_in_target(self) -> int:
        """How many keyframes of the submap last registered against (:meth:`target`) were placed
        while the tracker was lost (:attr:`Keyframe.placed_lost`); 0 before any target."""
        if self._target is None:
            return 0
        return sum(self._keyframes.record(k).placed_lost for k in self._target.keyframe_indices)


class KeyframeList(Sequence[Keyframe]):
    """The keyframes of a :class:`Submap`, in order; an item comes with its clouds.

    With a ``cloud_store``, only the ``resident`` latest keyframes keep their lidar-frame clouds in
    memory: the clouds of the keyframe that falls out of them go to the store (on disk in a run),
    its record keeps the rest (:meth:`record`), and taking the item reads them back.
    """

    def __init__(self, cloud_store: KeyframeCloudStore | None = None, resident: int = 10) -> None:
        self.cloud_store = cloud_store
        self.resident = max(1, resident)
        self._records: list[Keyframe] = []  # a stored keyframe's record holds no points

    def __len__(self) -> int:
        return len(self._records)

    @overload
    def __getitem__(self, k: int) -> Keyframe: ...

    @overload
    def __getitem__(self, k: slice) -> list[Keyframe]: ...

    def __getitem__(self, k: int | slice) -> Keyframe | list[Keyframe]:
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        record = self._records[k]
        if not self._is_stored(k):
            return record
        assert self.cloud_store is not None
        corner, surf = self.cloud_store.get(record.index)
        return dataclasses.replace(record, corner_points=corner, surf_points=surf)

    def record(self, k: int) -> Keyframe:
        """Keyframe ``k`` without reading its clouds back (a stored one's clouds are empty)."""
        return self._records[k]

    @property
    def stamps_ns(self) -> np.ndarray:
        """(K,) int64 keyframe stamps (no clouds read)."""
        return np.array([kf.stamp_ns for kf in self._records], dtype=np.int64)

    @property
    def scan_indices(self) -> np.ndarray:
        """(K,) int64 input scan index of each keyframe (no clouds read)."""
        return np.array([kf.scan_index for kf in self._records], dtype=np.int64)

    def append(self, keyframe: Keyframe) -> None:
        """Append ``keyframe`` (its ``index`` the next number); with a cloud store, the keyframe
        that now falls out of the resident ones hands its clouds to the store."""
        if keyframe.index != len(self._records):
            raise ValueError(f"keyframe {keyframe.index} added as number {len(self._records)}")
        self._records.append(keyframe)
        newly_stored = len(self._records) - self.resident - 1
        if self.cloud_store is not None and newly_stored >= 0:
            self._store(newly_stored, self._records[newly_stored])

    def replace_clouds(self, k: int, corner_points: np.ndarray, surf_points: np.ndarray) -> None:
        """Replace keyframe ``k``'s clouds, in the store when its clouds are there."""
        new = dataclasses.replace(self._records[k], corner_points=corner_points, surf_points=surf_points)
        if self._is_stored(k):
            self._store(k, new)
        else:
            self._records[k] = new

    def _store(self, k: int, keyframe: Keyframe) -> None:
        """Keyframe ``k``'s clouds to the store; its record keeps the rest."""
        assert self.cloud_store is not None
        self.cloud_store.put(k, keyframe.corner_points, keyframe.surf_points)
        self._records[k] = dataclasses.replace(keyframe, corner_points=_NO_POINTS, surf_points=_NO_POINTS)

    def _is_stored(self, k: int) -> bool:
        """Keyframe ``k``'s clouds are in the store: every keyframe older than the resident ones
        (the latest always stays: its clouds are replaced once the next sweep settles it)."""
        return self.cloud_store is not None and range(len(self._records))[k] < len(self._records) - self.resident
