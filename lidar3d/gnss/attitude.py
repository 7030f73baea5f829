"""SPAN attitude (roll, pitch, azimuth) to and from rotations in a local ENU frame.

SPAN's vehicle frame is x right, y forward, z up. Roll is a right-handed rotation about y, pitch a
right-handed rotation about x, azimuth a left-handed rotation about z in degrees clockwise from
north, applied in intrinsic Z-X-Y order (NovAtel OEM7 SPAN manual; Waypoint note "Determining
Rotations in SPAN & IE"), hence

    R_enu_vehicle = Rz(-azimuth) . Rx(pitch) . Ry(roll)

The IMU frame of the logs is this vehicle frame (attitude output after SETINSROTATION RBV).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["R_enu_vehicle_from_span", "span_from_R_enu_vehicle"]


def R_enu_vehicle_from_span(roll_deg, pitch_deg, azimuth_deg) -> np.ndarray:
    """Rotation(s) (..., 3, 3) mapping vehicle-frame vectors to ENU, from SPAN angles in degrees."""
    roll, pitch, azimuth = np.broadcast_arrays(
        np.asarray(roll_deg, float), np.asarray(pitch_deg, float), np.asarray(azimuth_deg, float)
    )
    angles = np.stack([-azimuth, pitch, roll], axis=-1).reshape(-1, 3)
    matrices = Rotation.from_euler("ZXY", angles, degrees=True).as_matrix()
    return matrices.reshape(roll.shape + (3, 3))


def span_from_R_enu_vehicle(R_enu_vehicle: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`R_enu_vehicle_from_span`: (roll, pitch, azimuth) in degrees, azimuth in [0, 360)."""
    R = np.asarray(R_enu_vehicle, float)
    angles = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_euler("ZXY", degrees=True)
    azimuth = np.mod(-angles[:, 0], 360.0)
    pitch = angles[:, 1]
    roll = angles[:, 2]
    shape = R.shape[:-2]
    return roll.reshape(shape), pitch.reshape(shape), azimuth.reshape(shape)
