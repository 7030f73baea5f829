"""Records of the feature stage."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar3d.records import readonly

__all__ = ["FeatureCloud", "FeatureSet", "Smoothness"]


@dataclass(frozen=True, slots=True)
class FeatureCloud:
    """One class of feature points of a scan.

    Attributes:
        points: (M, 3) float64, lidar frame, metres (not deskewed).
        ring: (M,) uint16 ring (= range-image row) of each point.
        time_offset_s: (M,) float64 firing time relative to the scan's ``stamp_ns``; for voxel
            centroids, the mean over the voxel's points.
    """

    points: np.ndarray
    ring: np.ndarray
    time_offset_s: np.ndarray

    def __post_init__(self) -> None:
        points = np.ascontiguousarray(self.points, dtype=np.float64)
        if points.size == 0:
            points = points.reshape(0, 3)
        if points.ndim != 2 or points.shape[1] != 3:
            raise ValueError(f"FeatureCloud.points must be (M, 3), got {points.shape}")
        n = points.shape[0]
        ring = np.ascontiguousarray(self.ring, dtype=np.uint16)
        time_offset_s = np.ascontiguousarray(self.time_offset_s, dtype=np.float64)
        for name, array in (("ring", ring), ("time_offset_s", time_offset_s)):
            if array.shape != (n,):
                raise ValueError(f"FeatureCloud.{name} must be ({n},), got {array.shape}")
        object.__setattr__(self, "points", readonly(points))
        object.__setattr__(self, "ring", readonly(ring))
        object.__setattr__(self, "time_offset_s", readonly(time_offset_s))

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @classmethod
    def empty(cls) -> FeatureCloud:
        return cls(points=np.zeros((0, 3)), ring=np.zeros(0, dtype=np.uint16), time_offset_s=np.zeros(0))


@dataclass(frozen=True, slots=True)
class FeatureSet:
    """Edge and planar features of one scan (LeGO-LOAM featureAssociation outputs), lidar frame.

    Attributes:
        stamp_ns: the scan's stamp (sweep start), integer nanoseconds.
        sharp: edge points, at most ``sharp_per_section`` per ring section (the odometry's query set).
        less_sharp: edge points, at most ``less_sharp_per_section`` per section; includes ``sharp``
            (the odometry's and mapping's edge target set).
        flat: ground points of lowest curvature, at most ``flat_per_section`` per section.
        less_flat: every segmented-cloud point of the ring sections that is not in ``less_sharp``
            (``flat`` included, unlabelled points too), voxel-downsampled per ring (centroids).
        outliers: the segmentation's outlier cloud (rejected small clusters, thinned), which
            LeGO-LOAM's mapping adds to the planar points.
    """

    stamp_ns: int
    sharp: FeatureCloud
    less_sharp: FeatureCloud
    flat: FeatureCloud
    less_flat: FeatureCloud
    outliers: FeatureCloud

    def __post_init__(self) -> None:
        object.__setattr__(self, "stamp_ns", int(self.stamp_ns))

    @property
    def is_empty(self) -> bool:
        """True when the scan gave no feature of any kind."""
        return not (len(self.sharp) or len(self.less_sharp) or len(self.flat) or len(self.less_flat))

    @classmethod
    def empty(cls, stamp_ns: int) -> FeatureSet:
        none = FeatureCloud.empty()
        return cls(stamp_ns=stamp_ns, sharp=none, less_sharp=none, flat=none, less_flat=none, outliers=none)


@dataclass(frozen=True, slots=True)
class Smoothness:
    """Curvature of the segmented cloud and which points may be picked (M = segmented points).

    Attributes:
        curvature: (M,) float64, c_i = (sum_{j in i-w..i+w, j != i} r_j - 2w r_i)^2 in m^2 over the
            ring's neighbours (FA:621-641, unnormalised as in LeGO-LOAM's code); 0 where undefined.
        in_section: (M,) bool, points at least w from both ends of their ring (a full window).
        section: (M,) int64, ``ring * sections_per_ring + section`` of each point; -1 outside.
        pickable: (M,) bool, in a section and not rejected as occluded or beam-parallel.
        edge_threshold: m^2, the curvature an edge candidate must exceed in this scan: the configured
            ``edge_threshold`` or, when higher, the curvature the scan's own range noise reaches on a
            smooth surface only once in ``1 / edge_noise_false_rate`` points.
    """

    curvature: np.ndarray
    in_section: np.ndarray
    section: np.ndarray
    pickable: np.ndarray
    edge_threshold: float

    def __post_init__(self) -> None:
        curvature = np.asarray(self.curvature, dtype=np.float64)
        n = curvature.shape[0]
        object.__setattr__(self, "curvature", readonly(curvature))
        for name, dtype in (("in_section", bool), ("section", np.int64), ("pickable", bool)):
            array = np.asarray(getattr(self, name), dtype=dtype)
            if array.shape != (n,):
                raise ValueError(f"Smoothness.{name} must be ({n},), got {array.shape}")
            object.__setattr__(self, name, readonly(array))
