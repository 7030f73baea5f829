"""The lidar-to-IMU extrinsic file.

Format (TOML), ``T_imu_lidar`` mapping lidar-frame points into the IMU (SPAN vehicle: x right,
y forward, z up) frame::

    # T_imu_lidar: pose of the lidar in the IMU frame (p_imu = R p_lidar + t)
    [T_imu_lidar]
    translation_m = [0.0, 0.3, 0.8]
    quaternion_xyzw = [0.0, 0.0, -0.7071067811865476, 0.7071067811865476]

or the same table in YAML (``.yaml``/``.yml``)::

    T_imu_lidar:
      translation_m: [0.0, 0.3, 0.8]
      rpy_deg: [0.0, 0.0, -90.0]

The rotation is given by exactly one of ``quaternion_xyzw`` (x, y, z, w; unit norm) or ``rpy_deg``
(roll, pitch, yaw in degrees about the fixed x, y, z axes, i.e. R = Rz(yaw) Ry(pitch) Rx(roll), the
URDF/ROS ``rpy`` convention). Optionally ``[imu_to_antenna]`` with ``translation_m`` (the
SETINSTRANSLATION ANT1 lever arm); it is not needed for evaluation against INS solutions.
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


def _numbers(values: np.ndarray) -> str:
    # repr of a Python float round-trips exactly (numpy 2 scalars would print as np.float64(...))
    return ", ".join(repr(float(v)) for v in values)


def write_extrinsic(path: str | Path, T_imu_lidar: np.ndarray) -> None:
    """Write ``T_imu_lidar`` (4x4) in the extrinsic TOML format, atomically."""
    T = np.asarray(T_imu_lidar, float)
    q = Rotation.from_matrix(T[:3, :3]).as_quat()
    t = T[:3, 3]
    text = (
        "# T_imu_lidar: pose of the lidar in the IMU (SPAN vehicle: x right, y forward, z up) frame\n"
        "# p_imu = R p_lidar + t\n"
        "[T_imu_lidar]\n"
        f"translation_m = [{_numbers(t)}]\n"
        f"quaternion_xyzw = [{_numbers(q)}]\n"
    )
    write_text_atomic(path, text)


def _load_table(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise GnssError(f"{path}: extrinsic file not found") from None
    except OSError as err:
        raise GnssError(f"{path}: cannot read extrinsic file: {err.strerror}") from err
    if path.suffix.lower() in (".yaml", ".yml"):
        from ruamel.yaml import YAML
        from ruamel.yaml.error import YAMLError

        try:
            data = YAML(typ="safe", pure=True).load(text)
        except YAMLError as err:
            raise GnssError(f"{path}: extrinsic file is not valid YAML: {err}") from err
        if not isinstance(data, dict):
            raise GnssError(f"{path}: extrinsic YAML must be a mapping with a T_imu_lidar key")
        return data
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise GnssError(f"{path}: extrinsic file is not valid TOML: {err}") from err


def _vector(section: dict, key: str, size: int, path: Path) -> np.ndarray:
    try:
        value = np.asarray(section[key], dtype=float)
    except (ValueError, TypeError) as err:
        raise GnssError(f"{path}: T_imu_lidar.{key} must be {size} numbers") from err
    if value.shape != (size,) or not np.all(np.isfinite(value)):
        raise GnssError(f"{path}: T_imu_lidar.{key} must be {size} finite numbers, got {section[key]!r}")
    return value


def read_extrinsic(path: str | Path) -> np.ndarray:
    """Read ``T_imu_lidar`` (4x4 float64) from an extrinsic TOML or YAML file (by suffix)."""
    path = Path(path)
    data = _load_table(path)
    section = data.get("T_imu_lidar")
    if not isinstance(section, dict):
        raise GnssError(f"{path}: extrinsic file has no T_imu_lidar table")
    unknown = set(section) - {"translation_m", "quaternion_xyzw", "rpy_deg"}
    if unknown:
        raise GnssError(f"{path}: unknown key(s) in T_imu_lidar: {', '.join(sorted(unknown))}")
    if "translation_m" not in section:
        raise GnssError(f"{path}: T_imu_lidar needs translation_m (3 numbers)")
    rotations = [key for key in ("quaternion_xyzw", "rpy_deg") if key in section]
    if len(rotations) != 1:
        raise GnssError(f"{path}: T_imu_lidar needs exactly one of quaternion_xyzw (4) or rpy_deg (3)")
    t = _vector(section, "translation_m", 3, path)
    if rotations[0] == "quaternion_xyzw":
        q = _vector(section, "quaternion_xyzw", 4, path)
        if abs(np.linalg.norm(q) - 1.0) > 1e-6:
            raise GnssError(f"{path}: T_imu_lidar.quaternion_xyzw is not a unit quaternion")
        R = Rotation.from_quat(q).as_matrix()
    else:
        R = Rotation.from_euler("xyz", _vector(section, "rpy_deg", 3, path), degrees=True).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T
