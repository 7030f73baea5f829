"""A sweep's features as mapping uses them: deskewed with a motion, reduced to registration clouds.

The front end hands over a sweep's features as fired (each point at its own time in the sweep).
Mapping deskews them to the scan stamp with a body twist, more than once when a better estimate
of the motion over the sweep arrives, and registers or stores two clouds made from them:

* corner cloud: the less-sharp edge features, voxel-downsampled;
* surface cloud: the less-flat planar features, the cluster outliers and the dense coarse-ground
  cloud, voxel-downsampled (the ground fixes z, roll and pitch).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar3d.config import MappingConfig
from lidar3d.features.frontend import PreparedScan
from lidar3d.features.records import FeatureCloud, FeatureSet
from lidar3d.mapping.deskew import deskew_features, deskew_points
from lidar3d.mapping.voxel import voxel_downsample

__all__ = ["SweepFeatures"]


@dataclass(frozen=True, slots=True)
class SweepFeatures:
    """A sweep's feature set plus its dense coarse-ground cloud (lidar frame).

    Attributes:
        features: edge/planar features; as fired, or deskewed when made by :meth:`deskewed`
            (time offsets are kept either way, so a sweep can be deskewed again).
        coarse_ground: every coarse-ground cell of the range image (``PreparedScan.coarse_ground``),
            same frame and timing as ``features``.
    """

    features: FeatureSet
    coarse_ground: FeatureCloud

    @classmethod
    def of(cls, prepared: PreparedScan) -> SweepFeatures:
        """The features of a front-end output, as fired."""
        return cls(prepared.features, prepared.coarse_ground)

    @property
    def n_surface_points(self) -> int:
        """Points of the surface cloud before downsampling (less-flat, outliers, coarse ground)."""
        return len(self.features.less_flat) + len(self.features.outliers) + len(self.coarse_ground)

    def deskewed(self, twist: np.ndarray) -> SweepFeatures:
        """Every point moved to the lidar frame at the stamp with the constant body ``twist``
        (6,) (v m/s, w rad/s); only valid on a sweep as fired."""
        coarse_ground = FeatureCloud(
            deskew_points(self.coarse_ground.points, self.coarse_ground.time_offset_s, twist),
            self.coarse_ground.ring,
            self.coarse_ground.time_offset_s,
        )
        return SweepFeatures(deskew_features(self.features, twist), coarse_ground)

    def without(self, moving: dict[str, np.ndarray]) -> SweepFeatures:
        """The sweep without the points marked in ``moving``: feature cloud name (``sharp``,
        ``less_sharp``, ``flat``, ``less_flat``, ``outliers``) -> (M,) bool; the coarse ground is kept."""
        f = self.features

        def kept(name: str) -> FeatureCloud:
            cloud = getattr(f, name)
            if name not in moving:
                return cloud
            keep = ~np.asarray(moving[name], dtype=bool)
            return FeatureCloud(cloud.points[keep], cloud.ring[keep], cloud.time_offset_s[keep])

        features = FeatureSet(
            stamp_ns=f.stamp_ns,
            sharp=kept("sharp"),
            less_sharp=kept("less_sharp"),
            flat=kept("flat"),
            less_flat=kept("less_flat"),
            outliers=kept("outliers"),
        )
        return SweepFeatures(features, self.coarse_ground)

    def registration_clouds(self, config: MappingConfig) -> tuple[np.ndarray, np.ndarray]:
        """(M,3) corner and (K,3) surface clouds, voxel-downsampled with the map's voxel sizes."""
        corner, _, surf, _ = self.timed_registration_clouds(config)
        return corner, surf

    def timed_registration_clouds(self, config: MappingConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`registration_clouds` with each voxel's mean time offset (s from the stamp): (M,3)
        corner points, (M,) their times, (K,3) surface points, (K,) their times."""
        f = self.features
        corner, corner_time_s = voxel_downsample(f.less_sharp.points, config.corner_voxel_m, f.less_sharp.time_offset_s)
        surfaces = (f.less_flat, f.outliers, self.coarse_ground)
        surf, surf_time_s = voxel_downsample(
            np.concatenate([c.points for c in surfaces]),
            config.surf_voxel_m,
            np.concatenate([c.time_offset_s for c in surfaces]),
        )
        return corner, corner_time_s, surf, surf_time_s

    def keyframe_clouds(self, config: MappingConfig) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`registration_clouds` in float32, as a keyframe keeps them for the whole run
        (sub-millimetre within the lidar's range)."""
        corner, surf = self.registration_clouds(config)
        return corner.astype(np.float32), surf.astype(np.float32)
