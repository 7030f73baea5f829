"""Writers of georeferenced maps and trajectories: LAS/LAZ 1.4 with a WKT CRS, PCD/PLY in doubles, TUM, CSV.

* **LAS / LAZ** (laspy; LAZ through the lazrs backend): LAS 1.4, point format 6, the CRS as an OGC
  WKT 1 VLR with the global-encoding WKT bit set; coordinates as scaled integers, scale 1 mm, offset
  the minimum of the cloud floored to whole metres (so easting/northing in the millions keep 1 mm);
  intensity the map's mean intensity rounded to an integer (the sensor's 0-255 scale).
* **PCD**: binary, ``x y z`` as 64-bit floats (``SIZE 8``) and ``intensity`` float32, so UTM
  magnitudes keep full precision without an offset; the CRS is named in comment lines of the header.
* **PLY**: binary little endian, ``property double x/y/z`` and ``float intensity``; the CRS in
  ``comment`` lines.
* **TUM** (trajectory): ``stamp x y z qx qy qz qw``, x y z in the CRS axes (easting, northing,
  ellipsoidal height for a projected CRS), the quaternion of ``R_grid_lidar`` (grid axes, see
  :mod:`lidar3d.georef.crs`), 4 decimals (0.1 mm) for coordinates.
* **CSV** (trajectory): a header of named columns: ``stamp_s`` and the CRS axes, the quaternion, the
  lidar heading (degrees clockwise from grid north, or from true north for ENU and WGS84), the
  meridian convergence and the point scale factor.

Every file is written atomically (temporary file, then rename).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from lidar3d.georef.crs import CrsKind, GridPoses, OutputCrs
from lidar3d.io.atomic import atomic_path, write_bytes_atomic, write_text_atomic

__all__ = ["LAS_SCALE_M", "write_grid_tum", "write_las", "write_pcd_double", "write_ply_double", "write_trajectory_csv"]

LAS_SCALE_M = 0.001


def _stamp_text(stamp_ns: int) -> str:
    seconds, nanos = divmod(int(stamp_ns), 1_000_000_000)
    return f"{seconds}.{nanos:09d}"


def write_las(path: str | Path, points: np.ndarray, intensity: np.ndarray, crs: OutputCrs, *, compress: bool) -> None:
    """Write (N, 3) ``points`` in ``crs`` and their (N,) intensity as LAS 1.4 (LAZ when ``compress``)."""
    import laspy
    from laspy.vlrs.known import WktCoordinateSystemVlr

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.full(3, LAS_SCALE_M)
    header.offsets = np.floor(points.min(axis=0)) if len(points) else np.zeros(3)
    header.vlrs.append(WktCoordinateSystemVlr(crs.wkt))
    header.global_encoding.wkt = True
    header.system_identifier = "lidar3d"
    header.generating_software = "lidar3d export"
    las = laspy.LasData(header)
    las.x, las.y, las.z = points[:, 0], points[:, 1], points[:, 2]
    las.intensity = np.clip(np.rint(np.asarray(intensity, dtype=np.float64)), 0, 65535).astype(np.uint16)
    # Map points are voxel means of single returns: each is "return 1 of 1" (LAS 1.4 wants 1-15;
    # lasvalidate flags 0), and the header's points-by-return counts them all as first returns.
    las.return_number = np.ones(len(points), dtype=np.uint8)
    las.number_of_returns = np.ones(len(points), dtype=np.uint8)
    with atomic_path(path) as tmp:
        backend = laspy.LazBackend.Lazrs if compress else None
        las.write(str(tmp), do_compress=compress, laz_backend=backend)


def _crs_comments(crs: OutputCrs) -> list[str]:
    return [f"lidar3d map, CRS {crs.name}, axes {' '.join(crs.axis_names)}, heights ellipsoidal (WGS84)"]


def _double_records(points: np.ndarray, intensity: np.ndarray) -> np.ndarray:
    """(N,) little-endian records of float64 x, y, z and float32 intensity."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    record = np.empty(len(points), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("intensity", "<f4")])
    record["x"], record["y"], record["z"] = points[:, 0], points[:, 1], points[:, 2]
    record["intensity"] = np.asarray(intensity, dtype=np.float32)
    return record


def write_pcd_double(path: str | Path, points: np.ndarray, intensity: np.ndarray, crs: OutputCrs) -> None:
    """Binary PCD with float64 x y z and float32 intensity; the CRS in the header's comment lines."""
    record = _double_records(points, intensity)
    n = len(record)
    comments = "".join(f"# {line}\n" for line in _crs_comments(crs))
    header = (
        f"# .PCD v0.7 - Point Cloud Data file format\n{comments}VERSION 0.7\nFIELDS x y z intensity\n"
        f"SIZE 8 8 8 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {n}\nDATA binary\n"
    )
    write_bytes_atomic(path, header.encode("ascii") + record.tobytes())


def write_ply_double(path: str | Path, points: np.ndarray, intensity: np.ndarray, crs: OutputCrs) -> None:
    """Binary little-endian PLY with double x y z and float intensity; the CRS in ``comment`` lines."""
    record = _double_records(points, intensity)
    n = len(record)
    comments = "".join(f"comment {line}\n" for line in _crs_comments(crs))
    header = (
        f"ply\nformat binary_little_endian 1.0\n{comments}element vertex {n}\n"
        "property double x\nproperty double y\nproperty double z\nproperty float intensity\nend_header\n"
    )
    write_bytes_atomic(path, header.encode("ascii") + record.tobytes())


def write_grid_tum(path: str | Path, stamps_ns: np.ndarray, poses: GridPoses, crs: OutputCrs) -> None:
    """TUM lines: stamp, the three CRS coordinates, the grid-axis quaternion (x y z w)."""
    q = Rotation.from_matrix(poses.R_grid_lidar).as_quat() if len(stamps_ns) else np.zeros((0, 4))
    lines = [f"# timestamp {' '.join(crs.axis_names)} qx qy qz qw (CRS {crs.name}, grid axes, heights ellipsoidal)"]
    for stamp, p, quat in zip(stamps_ns, poses.positions, q):
        lines.append(
            f"{_stamp_text(stamp)} {p[0]:.4f} {p[1]:.4f} {p[2]:.4f} "
            f"{quat[0]:.9f} {quat[1]:.9f} {quat[2]:.9f} {quat[3]:.9f}"
        )
    write_text_atomic(path, "\n".join(lines) + "\n")


def write_trajectory_csv(path: str | Path, stamps_ns: np.ndarray, poses: GridPoses, crs: OutputCrs) -> None:
    """CSV with named columns (module docstring); lat/lon with 10 decimals, metric axes with 4."""
    q = Rotation.from_matrix(poses.R_grid_lidar).as_quat() if len(stamps_ns) else np.zeros((0, 4))
    x_axis = poses.R_grid_lidar[:, :, 0] if len(stamps_ns) else np.zeros((0, 3))
    heading = np.mod(np.degrees(np.arctan2(x_axis[:, 0], x_axis[:, 1])), 360.0)
    heading_name = "heading_grid_deg" if crs.kind is CrsKind.PROJECTED else "heading_deg"
    columns = ["stamp_s", *crs.axis_names, "qx", "qy", "qz", "qw", heading_name, "convergence_deg", "scale_factor"]
    digits = (10, 10, 4) if crs.kind is CrsKind.WGS84 else (4, 4, 4)
    out = io.StringIO()
    out.write(",".join(columns) + "\n")
    for i, stamp in enumerate(stamps_ns):
        p = poses.positions[i]
        out.write(
            f"{_stamp_text(stamp)},{p[0]:.{digits[0]}f},{p[1]:.{digits[1]}f},{p[2]:.{digits[2]}f},"
            f"{q[i, 0]:.9f},{q[i, 1]:.9f},{q[i, 2]:.9f},{q[i, 3]:.9f},{heading[i]:.6f},"
            f"{poses.convergence_deg[i]:.9f},{poses.scale_factor[i]:.9f}\n"
        )
    write_text_atomic(path, out.getvalue())
