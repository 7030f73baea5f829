"""``lidar3d export RUN_DIR --crs CRS --out FILE``: a run's map or trajectory in a real coordinate reference system.

Library twin: :func:`export_run`. It reads the run folder (``summary.json`` checked), its
``georef.json`` (written by ``lidar3d run --span``), and ``map.pcd`` or ``trajectory_tum.txt``,
moves them into ENU with ``T_enu_world`` and then into the CRS (:mod:`lidar3d.georef.crs`), and writes
the file named by its extension (:mod:`lidar3d.export.georef_files`):

=========  ==========  ===========================================================================
extension  content     CRS
=========  ==========  ===========================================================================
.laz/.las  map         utm, EPSG:NNNN (projected), enu; LAS 1.4 with WKT
.pcd/.ply  map         same; float64 coordinates
.tum       trajectory  utm, EPSG:NNNN, enu
.csv       trajectory  utm, EPSG:NNNN, enu, wgs84 (lat/lon/h)
=========  ==========  ===========================================================================
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar3d.errors import GeoreferenceError
from lidar3d.georef.crs import OutputCrs, enu_to_crs_points, enu_to_crs_poses, resolve_crs
from lidar3d.georef.georeference import Georeference, read_georeference

__all__ = ["GEOREF_NAME", "MAP_EXTENSIONS", "TRAJECTORY_EXTENSIONS", "ExportOutcome", "export_run"]

log = logging.getLogger(__name__)

GEOREF_NAME = "georef.json"
MAP_EXTENSIONS = (".laz", ".las", ".pcd", ".ply")
TRAJECTORY_EXTENSIONS = (".tum", ".csv")


@dataclass(frozen=True, slots=True)
class ExportOutcome:
    """What :func:`export_run` wrote.

    Attributes:
        out: the file written.
        crs: the CRS it is in.
        kind: ``map`` or ``trajectory``.
        count: points or poses written.
        bounds_min, bounds_max: (3,) coordinate bounds in the CRS axes.
        seconds: wall time of the export.
    """

    out: Path
    crs: OutputCrs
    kind: str
    count: int
    bounds_min: np.ndarray
    bounds_max: np.ndarray
    seconds: float


def _suffix(out: Path) -> str:
    suffix = out.suffix.lower()
    if suffix not in MAP_EXTENSIONS + TRAJECTORY_EXTENSIONS:
        known = ", ".join(MAP_EXTENSIONS + TRAJECTORY_EXTENSIONS)
        raise GeoreferenceError(f"{out}: output extension {out.suffix or '(none)'!r} is not supported (use {known})")
    return suffix


def _read_georef(run_dir: Path) -> Georeference:
    from lidar3d.io.run_folder import read_run_folder

    read_run_folder(run_dir)  # a clear error for a folder that is no (complete) run
    return read_georeference(run_dir / GEOREF_NAME)


def export_run(run_dir: str | Path, crs: str, out: str | Path) -> ExportOutcome:
    """Write the map (``.laz .las .pcd .ply``) or trajectory (``.tum .csv``) of ``run_dir`` in ``crs``.

    Raises :class:`GeoreferenceError` for an unsupported extension, a run without ``georef.json``
    (made without ``--span``), an unknown or unusable CRS (geographic for a map, ``wgs84`` for TUM),
    and :class:`~lidar3d.errors.SummaryError` / :class:`~lidar3d.errors.OutputError` for a folder
    that is not a complete run.
    """
    t0 = time.perf_counter()
    run_dir, out = Path(run_dir), Path(out)
    suffix = _suffix(out)
    is_map = suffix in MAP_EXTENSIONS
    georef = _read_georef(run_dir)
    if suffix == ".tum" and crs.strip().lower() == "wgs84":
        raise GeoreferenceError("--crs wgs84: TUM needs metric coordinates; write .csv for latitude/longitude/height")
    output_crs = resolve_crs(crs, georef.origin, for_map=is_map)
    T = georef.T_enu_world
    if is_map:
        from lidar3d.io.pcd import read_pcd_fields

        points_world, fields = read_pcd_fields(run_dir / "map.pcd")
        intensity = fields.get("intensity", np.zeros(len(points_world), np.float32)).astype(np.float32)
        coordinates = enu_to_crs_points(points_world @ T[:3, :3].T + T[:3, 3], georef.origin, output_crs)
        _write_map(out, suffix, coordinates, intensity, output_crs)
        count = len(coordinates)
    else:
        from lidar3d.export.georef_files import write_grid_tum, write_trajectory_csv
        from lidar3d.io.trajectory_io import read_tum

        trajectory = read_tum(run_dir / "trajectory_tum.txt")
        poses = enu_to_crs_poses(T @ trajectory.T_world_lidar, georef.origin, output_crs)
        coordinates = poses.positions
        writer = write_grid_tum if suffix == ".tum" else write_trajectory_csv
        writer(out, trajectory.stamps_ns, poses, output_crs)
        count = len(coordinates)
    low = coordinates.min(axis=0) if count else np.zeros(3)
    high = coordinates.max(axis=0) if count else np.zeros(3)
    seconds = time.perf_counter() - t0
    log.info("%s: %d %s in %s (%.2f s)", out, count, "points" if is_map else "poses", output_crs.name, seconds)
    return ExportOutcome(out, output_crs, "map" if is_map else "trajectory", count, low, high, seconds)


def _write_map(out: Path, suffix: str, points: np.ndarray, intensity: np.ndarray, crs: OutputCrs) -> None:
    from lidar3d.export.georef_files import write_las, write_pcd_double, write_ply_double

    if suffix in (".las", ".laz"):
        write_las(out, points, intensity, crs, compress=suffix == ".laz")
    elif suffix == ".pcd":
        write_pcd_double(out, points, intensity, crs)
    else:
        write_ply_double(out, points, intensity, crs)
