"""Trajectory files in TUM and KITTI formats (both readable by evo).

TUM: one line per pose, ``timestamp tx ty tz qx qy qz qw`` with the timestamp in seconds.
KITTI: one line per pose, the first three rows of ``T_world_lidar`` row-major (12 numbers), no time;
we write the stamps beside it in ``<name>.times.txt`` (seconds, one per line) as KITTI odometry does.
:func:`read_trajectory` reads either, telling them apart by the number of columns.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from lidar3d.errors import Lidar3dError
from lidar3d.io.atomic import write_text_atomic
from lidar3d.records import Trajectory

__all__ = ["TrajectoryFileError", "read_kitti", "read_trajectory", "read_tum", "write_kitti", "write_tum"]


class TrajectoryFileError(Lidar3dError):
    """A trajectory file is missing or malformed."""


def _stamp_text(stamp_ns: int) -> str:
    seconds, nanos = divmod(int(stamp_ns), 1_000_000_000)
    return f"{seconds}.{nanos:09d}"


def write_tum(path: str | Path, trajectory: Trajectory) -> None:
    """Write ``trajectory`` as a TUM file (stamps with full nanosecond precision)."""
    poses = trajectory.T_world_lidar
    quat_xyzw = Rotation.from_matrix(poses[:, :3, :3]).as_quat() if len(trajectory) else np.zeros((0, 4))
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for stamp, pose, q in zip(trajectory.stamps_ns, poses, quat_xyzw):
        t = pose[:3, 3]
        lines.append(
            f"{_stamp_text(stamp)} {t[0]:.6f} {t[1]:.6f} {t[2]:.6f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}"
        )
    write_text_atomic(path, "\n".join(lines) + "\n")


def _parse_stamp_ns(token: str) -> int:
    if "." in token and "e" not in token.lower():
        whole, frac = token.split(".", 1)
        frac = (frac + "000000000")[:9]
        sign = -1 if whole.startswith("-") else 1
        return int(whole) * 1_000_000_000 + sign * int(frac)
    return int(round(float(token) * 1e9))


_MIN_QUATERNION_NORM = 1e-9


def _check_finite(path: Path, lineno: int, line: str, values: list[float]) -> None:
    """:class:`TrajectoryFileError` naming the file and line when a value is NaN or infinite."""
    bad = [v for v in values if not np.isfinite(v)]
    if bad:
        raise TrajectoryFileError(f"{path}:{lineno}: non-finite value ({bad[0]}) in {line.strip()!r}")


def read_tum(path: str | Path) -> Trajectory:
    """Read a TUM trajectory; raises :class:`TrajectoryFileError` naming the file and line."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise TrajectoryFileError(f"{path}: trajectory file not found") from None
    stamps: list[int] = []
    rows: list[list[float]] = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        tokens = line.replace(",", " ").split()
        if len(tokens) != 8:
            raise TrajectoryFileError(f"{path}:{lineno}: expected 8 TUM columns, got {len(tokens)}")
        try:
            values = [float(t) for t in tokens]
        except ValueError:
            raise TrajectoryFileError(f"{path}:{lineno}: not a number in {line!r}") from None
        _check_finite(path, lineno, line, values)
        if np.linalg.norm(values[4:8]) < _MIN_QUATERNION_NORM:
            raise TrajectoryFileError(f"{path}:{lineno}: quaternion of zero length in {line!r}")
        stamps.append(_parse_stamp_ns(tokens[0]))
        rows.append(values[1:])
    table = np.asarray(rows, dtype=np.float64).reshape(-1, 7)
    poses = np.tile(np.eye(4), (len(stamps), 1, 1))
    if len(stamps):
        poses[:, :3, :3] = Rotation.from_quat(table[:, 3:7]).as_matrix()
        poses[:, :3, 3] = table[:, :3]
    try:
        return Trajectory(np.asarray(stamps, dtype=np.int64), poses)
    except ValueError as err:
        raise TrajectoryFileError(f"{path}: {err}") from err


def write_kitti(path: str | Path, trajectory: Trajectory) -> None:
    """Write KITTI poses to ``path`` and the stamps to ``path`` with suffix ``.times.txt``."""
    path = Path(path)
    lines = [" ".join(f"{v:.9e}" for v in pose[:3, :].reshape(-1)) for pose in trajectory.T_world_lidar]
    write_text_atomic(path, "\n".join(lines) + ("\n" if lines else ""))
    times = [f"{_stamp_text(s)}" for s in trajectory.stamps_ns]
    write_text_atomic(path.with_suffix(".times.txt"), "\n".join(times) + ("\n" if times else ""))


def read_kitti(path: str | Path) -> Trajectory:
    """Read KITTI poses (and stamps from the ``.times.txt`` sibling when present, else 0.1 s apart)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise TrajectoryFileError(f"{path}: trajectory file not found") from None
    rows = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue
        tokens = line.split()
        if len(tokens) != 12:
            raise TrajectoryFileError(f"{path}:{lineno}: expected 12 KITTI columns, got {len(tokens)}")
        values = [float(t) for t in tokens]
        _check_finite(path, lineno, line, values)
        rows.append(values)
    poses = np.tile(np.eye(4), (len(rows), 1, 1))
    if rows:
        poses[:, :3, :] = np.asarray(rows).reshape(-1, 3, 4)
    times_path = path.with_suffix(".times.txt")
    if times_path.exists():
        stamps = []
        for lineno, line in enumerate(times_path.read_text().splitlines(), start=1):
            for token in line.split():
                _check_finite(times_path, lineno, line, [float(token)])
                stamps.append(_parse_stamp_ns(token))
        if len(stamps) != len(rows):
            raise TrajectoryFileError(f"{times_path}: {len(stamps)} stamps for {len(rows)} poses")
    else:
        stamps = [i * 100_000_000 for i in range(len(rows))]
    return Trajectory(np.asarray(stamps, dtype=np.int64), poses)


def _malformed_kitti_line(path: Path) -> str:
    for lineno, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        for token in line.split():
            try:
                float(token)
            except ValueError:
                return f"{path}:{lineno}: not a number ({token!r}) in {line.strip()!r}"
    return f"{path}: malformed KITTI trajectory"


def read_trajectory(path: str | Path) -> Trajectory:
    """Read a TUM (8 columns) or KITTI (12 columns, stamps from ``.times.txt``) trajectory.

    The format is taken from the first data row. Raises :class:`TrajectoryFileError` naming the line
    of a malformed row, including a NaN or infinite value.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise TrajectoryFileError(f"{path}: trajectory file not found") from None
    except (OSError, UnicodeDecodeError) as err:
        raise TrajectoryFileError(f"{path}: cannot read trajectory file: {err}") from err
    first = next((ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")), None)
    if first is None:
        raise TrajectoryFileError(f"{path}: trajectory file has no poses")
    columns = len(first.replace(",", " ").split())
    if columns == 12:
        try:
            return read_kitti(path)
        except ValueError as err:  # a non-numeric token (TrajectoryFileError is no ValueError)
            raise TrajectoryFileError(_malformed_kitti_line(path)) from err
    return read_tum(path)
