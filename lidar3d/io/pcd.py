"""Point clouds to and from PCD (binary, float32 x y z, extra scalar fields).

:func:`write_pcd` writes the uncompressed binary layout with NumPy, byte for byte as Open3D's tensor
API writes it (its header, float32 / int32 fields interleaved per point, the extra fields in name
order), without importing Open3D
(about 1.5 s per process). :func:`read_pcd_fields` reads that layout, and the header-only PCD of an
empty cloud, with NumPy alone and falls back to :func:`read_pcd` (Open3D) for other layouts.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lidar3d.errors import OutputError
from lidar3d.io.atomic import atomic_path, write_text_atomic

__all__ = ["read_pcd", "read_pcd_fields", "write_pcd"]


def write_pcd(path: str | Path, points: np.ndarray, **fields: np.ndarray) -> None:
    """Write ``points`` (N,3) and per-point scalar ``fields`` (each (N,)) as a binary PCD.

    Typical fields: ``intensity`` (float32) and ``label`` (int32); integer fields are written as
    int32, the others as float32. The file opens in PCL, CloudCompare and Open3D. Written
    atomically. An empty cloud gets a valid header-only PCD (as Open3D, which refuses to write
    those, would not).
    """
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points must be (N, 3), got {points.shape}")
    if len(points) == 0:
        _write_empty_pcd(path, fields)
        return
    n = points.shape[0]
    columns = {"x": points[:, 0], "y": points[:, 1], "z": points[:, 2]}
    for name in sorted(fields):  # Open3D writes the extra fields in name order
        values = np.asarray(fields[name])
        if values.shape != (n,):
            raise ValueError(f"field {name} must be ({n},), got {values.shape}")
        columns[name] = values
    types = {name: "<i4" if np.issubdtype(v.dtype, np.integer) else "<f4" for name, v in columns.items()}
    record = np.empty(n, dtype=np.dtype([(name, types[name]) for name in columns]))
    for name, values in columns.items():
        record[name] = values  # cast as Open3D's Tensor(np.ascontiguousarray(values, dtype)) does
    names = list(columns)
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(names)}\nSIZE {' '.join('4' for _ in names)}\n"
        f"TYPE {' '.join('I' if types[name] == '<i4' else 'F' for name in names)}\n"
        f"COUNT {' '.join('1' for _ in names)}\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA binary\n"
    )
    try:
        with atomic_path(path) as tmp, open(tmp, "wb") as stream:
            stream.write(header.encode("ascii"))
            record.tofile(stream)
    except OSError as err:
        raise OutputError(f"{path}: cannot write the point cloud: {err.strerror or err}") from err


def _write_empty_pcd(path: str | Path, fields: dict[str, np.ndarray]) -> None:
    names = ["x", "y", "z", *fields]
    types = ["F", "F", "F"] + ["I" if np.issubdtype(np.asarray(v).dtype, np.integer) else "F" for v in fields.values()]
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(names)}\nSIZE {' '.join('4' for _ in names)}\nTYPE {' '.join(types)}\n"
        f"COUNT {' '.join('1' for _ in names)}\nWIDTH 0\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 0\nDATA ascii\n"
    )
    write_text_atomic(path, header)


def read_pcd(path: str | Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read a PCD: (N,3) float64 points and a dict of its other per-point fields."""
    import open3d as o3d

    path = Path(path)
    if not path.exists():
        raise OutputError(f"{path}: point cloud file not found")
    cloud = o3d.t.io.read_point_cloud(str(path))  # type: ignore[arg-type]  # str is accepted, see write_pcd
    points = cloud.point.positions.numpy().astype(np.float64)
    extra = {}
    for name in cloud.point:
        if name != "positions":
            extra[name] = cloud.point[name].numpy().reshape(-1)
    return points, extra


_PCD_TYPES = {
    ("F", 4): "<f4",
    ("F", 8): "<f8",
    ("I", 1): "<i1",
    ("I", 2): "<i2",
    ("I", 4): "<i4",
    ("I", 8): "<i8",
    ("U", 1): "<u1",
    ("U", 2): "<u2",
    ("U", 4): "<u4",
    ("U", 8): "<u8",
}


def read_pcd_fields(path: str | Path) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """As :func:`read_pcd`: (N,3) float64 points and the other fields; binary PCDs and empty clouds
    (what :func:`write_pcd` writes) read by NumPy, other layouts by Open3D."""
    path = Path(path)
    try:
        with open(path, "rb") as stream:
            header: dict[str, list[str]] = {}
            while True:
                line = stream.readline()
                if not line:
                    return read_pcd(path)
                words = line.decode("ascii", "replace").split()
                if not words or words[0].startswith("#"):
                    continue
                header[words[0].upper()] = words[1:]
                if words[0].upper() == "DATA":
                    break
            offset = stream.tell()
    except FileNotFoundError:
        raise OutputError(f"{path}: point cloud file not found") from None
    try:
        names, sizes, types = header["FIELDS"], [int(v) for v in header["SIZE"]], header["TYPE"]
        counts = [int(v) for v in header.get("COUNT", ["1"] * len(names))]
        n = int(header["POINTS"][0])
        dtype = np.dtype([(name, _PCD_TYPES[(t, size)]) for name, t, size in zip(names, types, sizes)])
    except (KeyError, ValueError, IndexError):
        return read_pcd(path)
    if any(c != 1 for c in counts) or not {"x", "y", "z"} <= set(names):
        return read_pcd(path)
    if header["DATA"] == ["ascii"] and n == 0:
        record = np.zeros(0, dtype)
    elif header["DATA"] == ["binary"]:
        record = np.fromfile(path, dtype=dtype, count=n, offset=offset)
    else:
        return read_pcd(path)
    if len(record) != n:
        raise OutputError(f"{path}: truncated point cloud ({len(record)} of {n} points)")
    points = np.column_stack([record["x"], record["y"], record["z"]]).astype(np.float64)
    return points, {name: record[name].copy() for name in names if name not in ("x", "y", "z")}
