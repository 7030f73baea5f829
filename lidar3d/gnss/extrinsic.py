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

Instead, or as well, the whole transform as calibration tools write it, row-major 4x4::

    [T_imu_lidar]
    matrix = [[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.3], [0.0, 0.0, 1.0, 0.8], [0.0, 0.0, 0.0, 1.0]]

Its last row must be 0 0 0 1 and its rotation orthonormal with determinant +1, each within
:data:`MATRIX_TOLERANCE`. Given beside ``translation_m`` and/or a rotation, the two must agree: the
translations within :data:`MATRIX_TOLERANCE` metres, the rotations within :data:`MATRIX_TOLERANCE`
radians.
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

__all__ = ["MATRIX_TOLERANCE", "read_extrinsic", "write_extrinsic"]

MATRIX_TOLERANCE = 1e-6
_KEYS = ("matrix", "translation_m", "quaternion_xyzw", "rpy_deg")


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


def _yaml_problem(err: Exception) -> str:
    """One line for a ruamel.yaml error (its own text spans several, with a caret diagram)."""
    problem = getattr(err, "problem", None) or (str(err).splitlines() or ["unreadable"])[0]
    mark = getattr(err, "problem_mark", None)
    return f"{problem} (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else problem


def _load_table(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise GnssError(f"{path}: extrinsic file not found") from None
    except OSError as err:
        raise GnssError(f"{path}: cannot read extrinsic file: {err.strerror}") from err
    except UnicodeDecodeError as err:
        raise GnssError(f"{path}: extrinsic file is not UTF-8 text (byte {err.start})") from None
    if path.suffix.lower() in (".yaml", ".yml"):
        from ruamel.yaml import YAML
        from ruamel.yaml.error import YAMLError

        try:
            data = YAML(typ="safe", pure=True).load(text)
        except YAMLError as err:
            raise GnssError(f"{path}: extrinsic file is not valid YAML: {_yaml_problem(err)}") from err
        if not isinstance(data, dict):
            raise GnssError(f"{path}: extrinsic YAML must be a mapping with a T_imu_lidar key")
        return data
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise GnssError(f"{path}: extrinsic file is not valid TOML: {err}") from err


def _numeric(section: dict, key: str, shape: tuple[int, ...], wanted: str, path: Path) -> np.ndarray:
    try:
        value = np.asarray(section[key], dtype=float)
    except (ValueError, TypeError, OverflowError) as err:
        raise GnssError(f"{path}: T_imu_lidar.{key} must be {wanted}") from err
    if value.shape != shape or not np.all(np.isfinite(value)):
        raise GnssError(f"{path}: T_imu_lidar.{key} must be {wanted} (finite), got {section[key]!r}"[:300])
    return value


def _vector(section: dict, key: str, size: int, path: Path) -> np.ndarray:
    return _numeric(section, key, (size,), f"{size} numbers", path)


def _matrix(section: dict, path: Path) -> np.ndarray:
    """The checked 4x4 ``T_imu_lidar.matrix`` (row-major), its last row set exactly to 0 0 0 1."""
    T = _numeric(section, "matrix", (4, 4), "a 4x4 matrix (4 rows of 4 numbers)", path)
    if np.max(np.abs(T[3] - [0.0, 0.0, 0.0, 1.0])) > MATRIX_TOLERANCE:
        raise GnssError(f"{path}: T_imu_lidar.matrix last row must be 0 0 0 1, got {T[3].tolist()}")
    R = T[:3, :3]
    orthonormality = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if orthonormality > MATRIX_TOLERANCE:
        raise GnssError(
            f"{path}: T_imu_lidar.matrix rotation is not orthonormal (|R^T R - I| = {orthonormality:.2e} "
            f"> {MATRIX_TOLERANCE:g})"
        )
    det = float(np.linalg.det(R))
    if abs(det - 1.0) > MATRIX_TOLERANCE:
        raise GnssError(f"{path}: T_imu_lidar.matrix rotation has determinant {det:.6f}, not +1 (a reflection)")
    T[3] = [0.0, 0.0, 0.0, 1.0]
    return T


def read_extrinsic(path: str | Path) -> np.ndarray:
    """Read ``T_imu_lidar`` (4x4 float64) from an extrinsic TOML or YAML file (by suffix).

    Raises :class:`~lidar3d.errors.GnssError` (one line naming the file and key) for anything the
    module docstring does not allow.
    """
    path = Path(path)
    data = _load_table(path)
    section = data.get("T_imu_lidar")
    if not isinstance(section, dict):
        raise GnssError(f"{path}: extrinsic file has no T_imu_lidar table")
    unknown = {str(key) for key in section} - set(_KEYS)
    if unknown:
        raise GnssError(f"{path}: unknown key(s) in T_imu_lidar: {', '.join(sorted(unknown))}"[:300])
    rotations = [key for key in ("quaternion_xyzw", "rpy_deg") if key in section]
    matrix = _matrix(section, path) if "matrix" in section else None
    if matrix is None and "translation_m" not in section:
        raise GnssError(f"{path}: T_imu_lidar needs translation_m (3 numbers) or matrix (4x4)")
    if len(rotations) > 1 or (matrix is None and not rotations):
        raise GnssError(
            f"{path}: T_imu_lidar needs exactly one of quaternion_xyzw (4) or rpy_deg (3)"
            + ("" if matrix is None else " beside matrix, or neither")
        )
    t = _vector(section, "translation_m", 3, path) if "translation_m" in section else None
    R = None
    if rotations and rotations[0] == "quaternion_xyzw":
        q = _vector(section, "quaternion_xyzw", 4, path)
        if abs(np.linalg.norm(q) - 1.0) > 1e-6:
            raise GnssError(f"{path}: T_imu_lidar.quaternion_xyzw is not a unit quaternion")
        R = Rotation.from_quat(q).as_matrix()
    elif rotations:
        R = Rotation.from_euler("xyz", _vector(section, "rpy_deg", 3, path), degrees=True).as_matrix()
    if matrix is None:
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = t
        return T
    if t is not None:
        gap_m = float(np.linalg.norm(matrix[:3, 3] - t))
        if gap_m > MATRIX_TOLERANCE:
            raise GnssError(
                f"{path}: T_imu_lidar.matrix and T_imu_lidar.translation_m disagree by {gap_m:.3g} m "
                f"(tolerance {MATRIX_TOLERANCE:g} m)"
            )
    if R is not None:
        gap_rad = float(Rotation.from_matrix(matrix[:3, :3].T @ R).magnitude())
        if gap_rad > MATRIX_TOLERANCE:
            raise GnssError(
                f"{path}: T_imu_lidar.matrix and T_imu_lidar.{rotations[0]} disagree by {np.degrees(gap_rad):.3g} deg "
                f"(tolerance {MATRIX_TOLERANCE:g} rad)"
            )
    return matrix
