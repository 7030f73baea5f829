"""``grid_run``: a ROS map_server occupancy grid of a finished run (library twin of ``lidar3d grid``).

The run folder gives the poses (``trajectory_tum.txt``), the configuration (``config.toml``) and the
moving objects to leave out (the voxels of ``dynamic.pcd``); the scans are read again from the run's
input bag(s) (``summary.json`` ``inputs``), each deskewed with the motion to the next pose as the map
was, once (the placed scans are kept in memory): first the segmentation marks each scan's ground
cells and the local ground is fitted to them (:class:`~lidar3d.mapping.occupancy_grid.GroundModel`;
``map.pcd``'s lowest points only when no scan has ground cells), then every scan is ray cast into the grid
(:class:`~lidar3d.mapping.occupancy_grid.OccupancyGridBuilder`).
Outputs in the output folder: ``map.yaml`` + ``map.pgm`` (map_server) and ``map.png`` (preview).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar3d.config import Config, load_config
from lidar3d.errors import BagError, ConfigError, OutputError
from lidar3d.io.map_server import trinary_image, write_map_server
from lidar3d.io.pcd import read_pcd_fields
from lidar3d.io.run_folder import read_run_folder
from lidar3d.io.scan_source import open_scan_source
from lidar3d.io.trajectory_io import read_tum
from lidar3d.mapping.deskew import deskew_scan, trajectory_sweep_twist
from lidar3d.mapping.occupancy_grid import (
    GridParams,
    GroundModel,
    LowestPerCell,
    OccupancyGrid,
    OccupancyGridBuilder,
    lowest_per_cell,
)
from lidar3d.mapping.se3 import transform_points
from lidar3d.mapping.voxel import voxel_keys
from lidar3d.records import Trajectory
from lidar3d.segmentation import mark_ground, project_scan

__all__ = ["GridOutcome", "check_grid_options", "grid_run"]

log = logging.getLogger(__name__)

YAML_NAME = "map.yaml"
PREVIEW_NAME = "map.png"
GROUND_CELL_M = 1.0  # cell of the local ground model


@dataclass(frozen=True, slots=True)
class GridOutcome:
    """What :func:`grid_run` produced.

    Attributes:
        grid: the occupancy grid (log-odds per cell).
        yaml: the map_server YAML; ``pgm`` its image; ``png`` the preview.
        scans: scans ray cast into the grid.
        partial: the run folder holds a partial run (stopped before the end of its input).
        dynamic_points_left_out: scan points left out as moving objects (in ``dynamic.pcd`` voxels).
        runtime_s: wall time.
    """

    grid: OccupancyGrid
    yaml: Path
    pgm: Path
    png: Path
    scans: int
    partial: bool
    dynamic_points_left_out: int
    runtime_s: float


def check_grid_options(resolution_m: float, band_m: tuple[float, float]) -> GridParams:
    """The grid parameters of the options, or :class:`ConfigError` (one line) when they are unusable."""
    if not resolution_m > 0 or not np.isfinite(resolution_m):
        raise ConfigError(f"--resolution must be > 0 m, got {resolution_m:g}")
    low, high = band_m
    if not (np.isfinite(low) and np.isfinite(high)):
        raise ConfigError(f"--band must be two finite heights, got {low:g} {high:g}")
    if low == high:
        raise ConfigError(f"--band {low:g} {high:g} is empty: LOW must be below HIGH")
    if low > high:
        raise ConfigError(f"--band {low:g} {high:g} is inverted: LOW must be below HIGH")
    return GridParams(resolution_m=float(resolution_m), band_m=(float(low), float(high)))


def grid_run(
    run_dir: str | Path,
    out_dir: str | Path,
    *,
    resolution_m: float = 0.1,
    band_m: tuple[float, float] = (0.3, 2.0),
    on_scan: Callable[[int, int | None], None] | None = None,
) -> GridOutcome:
    """Grid the run in ``run_dir`` into ``out_dir`` (see the module docstring).

    Args:
        resolution_m: cell side.
        band_m: (low, high) heights above the local ground that hold obstacles.
        on_scan: called as ``on_scan(done, total)`` after each scan (progress display).

    Raises:
        ConfigError: a resolution <= 0, an empty or inverted band.
        OutputError: ``run_dir`` is not a consistent run folder, has no poses, or gives no ground
            (no scan has ground cells and there is no map, or an empty one).
        BagError: the run's input bag cannot be read.
    """
    params = check_grid_options(resolution_m, band_m)
    t0 = time.perf_counter()
    run = Path(run_dir)
    if not run.is_dir():
        raise OutputError(f"{run}: not a run folder (no such folder)")
    summary = read_run_folder(run)
    if summary.partial:
        log.warning("%s: a partial run (stopped after %d scans): gridding the scans it has", run, summary.scans)
    config = load_config(run / "config.toml")
    trajectory = read_tum(run / "trajectory_tum.txt")
    if not len(trajectory):
        raise OutputError(f"{run}: the run has no poses: nothing to grid")
    dynamic_keys = np.zeros(0, np.int64)
    if summary.output("dynamic.pcd") is not None:
        dynamic_points, _ = read_pcd_fields(run / "dynamic.pcd")
        dynamic_keys = np.unique(voxel_keys(dynamic_points, config.mapping.map_voxel_m))
    inputs = [_input_path(run, p) for p in summary.inputs]
    ground, placed_scans = _ground_of_scans(inputs, config, trajectory, dynamic_keys)
    if ground is None:  # no scan marked ground cells (e.g. segmentation failed on every scan)
        ground = _ground_of_map(run, summary.output("map.pcd") is not None)
    positions = trajectory.positions_m
    reach = params.max_range_m
    bounds = np.array([positions[:, :2].min(axis=0) - reach, positions[:, :2].max(axis=0) + reach])
    builder = OccupancyGridBuilder(params, ground, bounds)
    for placed in placed_scans:
        builder.note_obstacles(placed.points_world, placed.ground)
    n_scans = n_left_out = 0
    for placed in placed_scans:
        n_left_out += placed.n_moving
        builder.add(placed.origin_world, placed.points_world, placed.ground)
        n_scans += 1
        if on_scan is not None:
            on_scan(n_scans, len(trajectory))
    grid = builder.grid()
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"{out}: cannot create output folder: {err.strerror or err}") from err
    probability = np.where(grid.observed, grid.probability, 0.5)
    image = trinary_image(probability)
    pgm = write_map_server(out / YAML_NAME, image, params.resolution_m, grid.origin_xy_m)
    from lidar3d.export.grid_preview import write_grid_preview

    title = f"{run.name}: occupancy {params.band_m[0]:g}-{params.band_m[1]:g} m above ground, {params.resolution_m:g} m"
    png = write_grid_preview(
        out / PREVIEW_NAME, image, params.resolution_m, grid.origin_xy_m, positions[:, :2], title=title
    )
    return GridOutcome(grid, out / YAML_NAME, pgm, png, n_scans, summary.partial, n_left_out, time.perf_counter() - t0)


@dataclass(frozen=True, slots=True)
class _PlacedScan:
    """One scan of the run, deskewed and in the world frame (moving objects left out).

    Attributes:
        origin_world: (3,) lidar position.
        points_world: (N,3) its points.
        ground: (N,) bool, the segmentation's ground cells.
        n_moving: points left out as moving objects.
    """

    origin_world: np.ndarray
    points_world: np.ndarray
    ground: np.ndarray
    n_moving: int


def _placed_scans(
    inputs: list[Path], config: Config, trajectory: Trajectory, dynamic_keys: np.ndarray
) -> Iterator[_PlacedScan]:
    """The run's scans that have a pose, deskewed with the motion over each sweep as the map was,
    placed in the world, their ground cells marked."""
    stamps, poses = trajectory.stamps_ns, trajectory.T_world_lidar
    model = config.sensor.resolved_model
    with open_scan_source(inputs, config) as source:
        for scan in source:
            if scan.stamp_ns > stamps[-1]:
                break
            i = int(np.searchsorted(stamps, scan.stamp_ns))
            if stamps[i] != scan.stamp_ns:
                continue
            final = deskew_scan(scan, trajectory_sweep_twist(stamps, poses, i, scan.time_offset_s))
            r = np.linalg.norm(final.points, axis=1)
            keep = (r >= config.sensor.min_range_m) & (r <= model.max_range_m)
            ground = np.zeros(len(scan), bool)
            image = project_scan(final, config.sensor, config.segmentation)
            # the coarse ground (no surface check): with the lifted cells as candidate obstacles, far
            # ground on hills that the check cannot confirm entered the band (hilly seed 0: precision
            # 0.962 -> 0.936, docs/commands/grid.md)
            coarse = mark_ground(image, config.segmentation, config.sensor, surface_check=False)
            ground[image.point_index[coarse]] = True
            points = transform_points(poses[i], final.points[keep])
            ground = ground[keep]
            n_moving = 0
            if dynamic_keys.size:
                keys = voxel_keys(points, config.mapping.map_voxel_m)
                at = np.minimum(np.searchsorted(dynamic_keys, keys), dynamic_keys.size - 1)
                moving = dynamic_keys[at] == keys
                n_moving = int(moving.sum())
                points, ground = points[~moving], ground[~moving]
            yield _PlacedScan(poses[i][:3, 3], points, ground, n_moving)


def _ground_of_scans(
    inputs: list[Path], config: Config, trajectory: Trajectory, dynamic_keys: np.ndarray
) -> tuple[GroundModel | None, list[_PlacedScan]]:
    """The local ground fitted to the ground cells the segmentation marks in every scan (the lowest
    per ``GROUND_CELL_M`` cell over all scans; None when no scan has any), and the placed scans with
    their ground marked, in :func:`_placed_scans` order (kept, so the bag is read and deskewed once)."""
    positions = trajectory.positions_m[:, :2]
    reach = config.sensor.resolved_model.max_range_m  # no point of a scan lies farther from its pose
    lowest = LowestPerCell(np.array([positions.min(axis=0) - reach, positions.max(axis=0) + reach]), GROUND_CELL_M)
    scans = []
    for placed in _placed_scans(inputs, config, trajectory, dynamic_keys):
        lowest.add(placed.points_world[placed.ground])
        scans.append(placed)
    every = lowest.points()
    if not len(every):
        return None, scans
    return GroundModel.from_points(every, GROUND_CELL_M), scans


def _ground_of_map(run: Path, has_map: bool) -> GroundModel:
    """The local ground from the lowest points of the run's ``map.pcd`` (when no scan has ground
    cells); :class:`OutputError` when the set has no map (a run stopped before its first map
    checkpoint) or the map is empty."""
    if not has_map:
        raise OutputError(f"{run}: no scan has ground cells and the run has no map.pcd yet: no ground to grid on")
    log.warning("%s: no ground cells in the scans: the local ground is taken from map.pcd", run)
    map_points, _ = read_pcd_fields(run / "map.pcd")
    if not len(map_points):
        raise OutputError(f"{run}: no scan has ground cells and map.pcd is empty: no ground to grid on")
    return GroundModel.from_points(lowest_per_cell(map_points, GROUND_CELL_M), GROUND_CELL_M)


def _input_path(run: Path, recorded: str) -> Path:
    """The run's input as recorded, else relative to the run folder; :class:`BagError` when neither exists."""
    path = Path(recorded)
    if path.exists():
        return path
    beside = run / recorded
    if not path.is_absolute() and beside.exists():
        return beside
    raise BagError(f"{recorded}: input of the run in {run} not found (lidar3d grid reads its scans again)")
