"""Immutable records handed between stages.

Poses cross every boundary as 4x4 float64 homogeneous matrices named by the frames they connect:
``T_world_lidar`` maps points from the lidar frame into the world frame. Axes follow REP-105
(x forward, y left, z up). Time inside the library is integer nanoseconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Scan", "Trajectory", "readonly"]


def readonly(array: np.ndarray) -> np.ndarray:
    """Mark ``array`` read-only (records hand out views that must not be changed) and return it."""
    array.flags.writeable = False
    return array


@dataclass(frozen=True, slots=True)
class Scan:
    """One sweep of the lidar.

    Attributes:
        stamp_ns: header stamp of the sweep in integer nanoseconds, whatever instant it marks (the
            first firing for lidar3d's packet decoder and simulator; the last packet for the stock
            ROS1 velodyne driver); the scan's pose is the lidar pose at this stamp.
        points: (N, 3) float64, metres, lidar frame.
        intensity: (N,) float32, sensor units (0-255 for Velodyne).
        ring: (N,) uint16, laser index ordered by elevation, 0 = lowest beam.
        time_offset_s: (N,) float64, seconds of each point's firing time relative to ``stamp_ns``.
    """

    stamp_ns: int
    points: np.ndarray
    intensity: np.ndarray
    ring: np.ndarray
    time_offset_s: np.ndarray

    def __post_init__(self) -> None:
        points = np.ascontiguousarray(self.points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"Scan.points must be (N, 3), got {points.shape}")
        n = points.shape[0]
        intensity = np.ascontiguousarray(self.intensity, dtype=np.float32)
        ring = np.ascontiguousarray(self.ring, dtype=np.uint16)
        time_offset_s = np.ascontiguousarray(self.time_offset_s, dtype=np.float64)
        for name, array in (("intensity", intensity), ("ring", ring), ("time_offset_s", time_offset_s)):
            if array.shape != (n,):
                raise ValueError(f"Scan.{name} must be ({n},), got {array.shape}")
        object.__setattr__(self, "stamp_ns", int(self.stamp_ns))
        object.__setattr__(self, "points", readonly(points))
        object.__setattr__(self, "intensity", readonly(intensity))
        object.__setattr__(self, "ring", readonly(ring))
        object.__setattr__(self, "time_offset_s", readonly(time_offset_s))

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def range_m(self) -> np.ndarray:
        """(N,) float64 distance of each point from the sensor origin."""
        return np.linalg.norm(self.points, axis=1)

    def select(self, mask: np.ndarray) -> Scan:
        """A new scan holding only the points where ``mask`` (bool or index array) selects."""
        return Scan(
            stamp_ns=self.stamp_ns,
            points=self.points[mask],
            intensity=self.intensity[mask],
            ring=self.ring[mask],
            time_offset_s=self.time_offset_s[mask],
        )


@dataclass(frozen=True, slots=True)
class Trajectory:
    """A sequence of timed poses.

    Attributes:
        stamps_ns: (N,) int64 strictly increasing stamps.
        T_world_lidar: (N, 4, 4) float64 poses of the lidar in the world frame.
    """

    stamps_ns: np.ndarray
    T_world_lidar: np.ndarray

    def __post_init__(self) -> None:
        stamps = np.ascontiguousarray(self.stamps_ns, dtype=np.int64)
        poses = np.ascontiguousarray(self.T_world_lidar, dtype=np.float64)
        if stamps.ndim != 1:
            raise ValueError(f"Trajectory.stamps_ns must be (N,), got {stamps.shape}")
        if poses.shape != (stamps.shape[0], 4, 4):
            raise ValueError(f"Trajectory.T_world_lidar must be ({stamps.shape[0]}, 4, 4), got {poses.shape}")
        if stamps.size > 1 and np.any(np.diff(stamps) <= 0):
            raise ValueError("Trajectory.stamps_ns must be strictly increasing")
        object.__setattr__(self, "stamps_ns", readonly(stamps))
        object.__setattr__(self, "T_world_lidar", readonly(poses))

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    @property
    def positions_m(self) -> np.ndarray:
        """(N, 3) positions of the lidar in the world frame."""
        return self.T_world_lidar[:, :3, 3]

    @property
    def path_length_m(self) -> float:
        """Length of the polyline through the positions."""
        if len(self) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.positions_m, axis=0), axis=1).sum())
