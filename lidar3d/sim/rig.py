"""The sensor rig on the simulated vehicle: where the lidar and the GNSS antenna sit relative to the IMU.

Frames: the IMU frame is the SPAN vehicle frame (x right, y forward, z up); the lidar frame is
REP-105 (x forward, y left, z up). A perfectly aligned lidar therefore has ``R_imu_lidar`` mapping
lidar x to IMU y and lidar y to IMU -x (a +90 degree turn about z). Real mounts are never perfect, so
the default adds a small roll/pitch/yaw misalignment and a lever arm (0.8 m up, 0.35 m forward).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["R_IMU_LIDAR_ALIGNED", "RigParams"]

# Lidar (x forward, y left, z up) -> SPAN vehicle (x right, y forward, z up), exact alignment.
R_IMU_LIDAR_ALIGNED = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, slots=True)
class RigParams:
    """Mounting of the lidar and the GNSS antenna.

    Attributes:
        lidar_translation_m: lidar origin in the IMU frame (x right, y forward, z up).
        lidar_misalignment_deg: extra rotation of the lidar about its own x, y, z axes (roll,
            pitch, yaw; extrinsic xyz order), applied after the nominal alignment.
        imu_to_antenna_m: GNSS antenna phase centre in the IMU frame (SETIMUTOANTOFFSET lever arm).
    """

    lidar_translation_m: tuple[float, float, float] = (0.02, 0.35, 0.80)
    lidar_misalignment_deg: tuple[float, float, float] = (0.3, -0.5, 0.8)
    imu_to_antenna_m: tuple[float, float, float] = (0.0, -0.40, 1.05)

    @property
    def T_imu_lidar(self) -> np.ndarray:
        """4x4 pose of the lidar in the IMU frame (p_imu = R p_lidar + t)."""
        T = np.eye(4)
        misalignment = Rotation.from_euler("xyz", self.lidar_misalignment_deg, degrees=True).as_matrix()
        T[:3, :3] = R_IMU_LIDAR_ALIGNED @ misalignment
        T[:3, 3] = self.lidar_translation_m
        return T
