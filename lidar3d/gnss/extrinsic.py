"""The lidar-to-IMU extrinsic file.

Format (TOML), ``T_imu_lidar`` mapping lidar-frame points into the IMU (SPAN vehicle) frame::

    # T_imu_lidar: pose of the lidar in the IMU frame (p_imu = R p_lidar + t)
    [T_imu_lidar]
    translation_m = [0.0, 0.3, 0.8]
    quaternion_xyzw = [0.0, 0.0, -0.7071067811865476, 0.7071067811865476]

Optionally ``[imu_to_antenna]`` with ``translation_m`` (the SETINSTRANSLATION ANT1 lever arm).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from lidar3d.errors import GnssError
from lidar3d.io.atomic import write_text_atomic

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

__all__ = ["read_extrinsic", "write_extrinsic"]


def write_extrinsic(path: str | Path, T_imu_lidar: np.ndarray) -> None:
    """Write ``T_imu_lidar`` (4x4) in the extrinsic TOML format, atomically."""
    T = np.asarray(T_imu_lidar, float)
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    t = T[:3, 3]
    text = (
        "# T_imu_lidar: pose of the lidar in the IMU (SPAN vehicle: x right, y forward, z up) frame\n"
        "# p_imu = R p_lidar + t\n"
        "[T_imu_lidar]\n"
        f"translation_m = [{t[0]!r}, {t[1]!r}, {t[2]!r}]\n"
        f"quaternion_xyzw = [{q[0]!r}, {q[1]!r}, {q[2]!r}, {q[3]!r}]\n"
    )
    write_text_atomic(path, text)


def read_extrinsic(path: str | Path) -> np.ndarray:
    """Read ``T_imu_lidar`` (4x4 float64) from an extrinsic TOML file."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise GnssError(f"{path}: extrinsic file not found") from None
    except tomllib.TOMLDecodeError as err:
        raise GnssError(f"{path}: extrinsic file is not valid TOML: {err}") from err
    section = data.get("T_imu_lidar")
    if not isinstance(section, dict):
        raise GnssError(f"{path}: extrinsic file has no [T_imu_lidar] table")
    try:
        t = np.asarray(section["translation_m"], dtype=float).reshape(3)
        q = np.asarray(section["quaternion_xyzw"], dtype=float).reshape(4)
    except (KeyError, ValueError, TypeError) as err:
        raise GnssError(f"{path}: [T_imu_lidar] needs translation_m (3) and quaternion_xyzw (4)") from err
    if not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1.0) > 1e-6:
        raise GnssError(f"{path}: [T_imu_lidar] quaternion_xyzw is not a unit quaternion")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(q).as_matrix()
    T[:3, 3] = t
    return T
