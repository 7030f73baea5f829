"""A 2-D occupancy grid for navigation: log-odds per cell from ray casting each sweep in a height band
above the local ground.

For every point of a sweep (world frame, moving objects already left out) the beam from the sensor
is followed in the plane: its height above the local ground is taken to vary linearly between the
sensor and the point (the ground height under each end, from :class:`GroundModel`), so on a hill the
band follows the slope. Cells the beam crosses while it is inside the band ``[low, high]`` are
*free*, the cell of the point is *occupied* when the point lies inside the band. A cell where an
obstacle was seen (its highest obstacle point over all sweeps, noted first:
:meth:`OccupancyGridBuilder.note_obstacles`) is freed only by a beam passing below that point (world
z, so a dip or crest of the ground between sensor and point does not matter): a beam over a car's
roof or a low wall, inside the band, says nothing of what stands under it. Within one sweep
the beams are gathered per azimuth bin (the farthest free reach of the bin, cast once) and a cell
counts once: occupied wins over free. Each sweep adds ``hit_log_odds`` to its occupied cells and
``miss_log_odds`` to its free ones, clamped to ``[-clamp, clamp]`` (as OctoMap and ROS gmapping
do). Frames: world = the run's map frame (x, y in the plane, z up).

A sweep is cast by one compiled kernel (numba, :func:`lidar3d.jit.lazy_njit`): per point and per
sample, no arrays of every sample as the NumPy version it replaced built (the same log-odds, bit for
bit: ``tests/test_grid.py`` keeps that version as the oracle).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar3d.jit import lazy_njit

__all__ = ["GridParams", "GroundModel", "LowestPerCell", "OccupancyGrid", "OccupancyGridBuilder", "lowest_per_cell"]


@dataclass(frozen=True, slots=True)
class GridParams:
    """How the grid is built.

    Attributes:
        resolution_m: cell side.
        band_m: (low, high) heights above the local ground that count as obstacles / free space.
        max_range_m: beams are followed this far in the plane.
        azimuth_bins: beams of a sweep gathered into this many azimuth bins for the free space.
        hit_log_odds: added to an occupied cell per sweep (p = 0.77).
        miss_log_odds: added to a free cell per sweep (p = 0.4).
        clamp_log_odds: the log-odds stay within +- this.
        top_margin_m: a beam frees a cell with obstacles noted (:meth:`OccupancyGridBuilder.note_obstacles`)
            only where it passes this far below the highest of them (but never lower than this
            above the band's bottom, where beams are cast).
    """

    resolution_m: float = 0.1
    band_m: tuple[float, float] = (0.3, 2.0)
    max_range_m: float = 40.0
    azimuth_bins: int = 1440
    hit_log_odds: float = 1.2
    miss_log_odds: float = -0.4
    clamp_log_odds: float = 3.5
    top_margin_m: float = 0.1

    def __post_init__(self) -> None:
        if not self.resolution_m > 0:
            raise ValueError(f"resolution must be > 0 m, got {self.resolution_m}")
        low, high = self.band_m
        if not low < high:
            raise ValueError(f"height band must be low < high, got {low} to {high}")


@dataclass(frozen=True, slots=True)
class GroundModel:
    """Local ground surface on a coarse grid: per cell a plane z = height + slope . (xy - centre),
    fitted robustly to the lowest map points of the cells around it.

    Each cell's lowest point is its ground candidate (at that point's own x, y, so a slope inside the
    cell is no error). Per cell a least-squares plane is fitted to the candidates of the
    ``(2 window + 1)`` cells square around it; candidates more than ``reject_above_m`` above their own
    cell's plane (a car's underside, a bush, a cell that holds only a wall) or ``reject_below_m``
    below it are dropped and the planes fitted again (``iterations`` times). Cells with fewer than
    three inliers around take the plane of the nearest cell that has one, continued to their centre.

    Attributes:
        origin_xy_m: (2,) world x, y of the corner of cell (0, 0).
        cell_m: cell side.
        height_m: (nx, ny) ground height at each cell's centre, world z.
        slope: (nx, ny, 2) dz/dx, dz/dy of each cell's plane.
    """

    origin_xy_m: np.ndarray
    cell_m: float
    height_m: np.ndarray
    slope: np.ndarray

    @classmethod
    def from_points(
        cls,
        points_world: np.ndarray,
        cell_m: float = 1.0,
        *,
        window: int = 4,
        reject_above_m: float = 0.15,
        reject_below_m: float = 0.5,
        iterations: int = 3,
    ) -> GroundModel:
        """The ground model of a map's (N,3) world points (N >= 1)."""
        from scipy import ndimage

        if not len(points_world):
            raise ValueError("a ground model needs at least one point")
        origin = np.floor(points_world[:, :2].min(axis=0) / cell_m) * cell_m - cell_m
        ij = np.floor((points_world[:, :2] - origin) / cell_m).astype(np.int64)
        shape = (int(ij[:, 0].max()) + 2, int(ij[:, 1].max()) + 2)
        first = _lowest_index(ij, points_world[:, 2])
        # Candidates: the lowest point per cell, as offsets (cell units) from its cell's centre.
        has = np.zeros(shape, bool)
        offset = np.zeros(shape + (2,))
        z = np.zeros(shape)
        ci, cj = ij[first, 0], ij[first, 1]
        has[ci, cj] = True
        offset[ci, cj] = (points_world[first, :2] - origin) / cell_m - ij[first] - 0.5
        z[ci, cj] = points_world[first, 2]
        z_ref = float(np.median(z[has]))  # moments about a typical height keep the fit well conditioned
        dz = np.where(has, z - z_ref, 0.0)
        inlier = has.copy()
        height = np.zeros(shape)
        slope = np.zeros(shape + (2,))
        fitted = np.zeros(shape, bool)
        for _ in range(iterations + 1):
            height, slope, fitted = _fit_planes(inlier, offset, dz, window)
            residual = dz - height - (slope * offset).sum(axis=2)
            inlier = has & fitted & (residual <= reject_above_m) & (residual >= -reject_below_m)
            inlier |= has & ~fitted
        if not fitted.any():
            fitted = has
            height = dz
        missing = ~fitted
        if missing.any():
            nearest = ndimage.distance_transform_edt(missing, return_distances=False, return_indices=True)
            ni, nj = nearest[0], nearest[1]
            di = np.indices(shape)[0] - ni
            dj = np.indices(shape)[1] - nj
            slope = slope[ni, nj]
            height = height[ni, nj] + slope[..., 0] * di + slope[..., 1] * dj
        return cls(origin, float(cell_m), height + z_ref, slope / cell_m)

    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """(N,) ground height under (N,2) world x, y (the nearest cell's plane outside the model)."""
        u = (xy - self.origin_xy_m) / self.cell_m
        ij = np.floor(u).astype(np.int64)
        i = np.clip(ij[:, 0], 0, self.height_m.shape[0] - 1)
        j = np.clip(ij[:, 1], 0, self.height_m.shape[1] - 1)
        along = (u[:, 0] - i - 0.5) * self.cell_m, (u[:, 1] - j - 0.5) * self.cell_m
        slope = self.slope[i, j]
        return self.height_m[i, j] + slope[:, 0] * along[0] + slope[:, 1] * along[1]


def lowest_per_cell(points_world: np.ndarray, cell_m: float) -> np.ndarray:
    """(M,3) the lowest of the (N,3) world points in each ``cell_m`` square (cells at multiples of
    ``cell_m``: those of a :class:`GroundModel` with that cell), in no particular order."""
    if not len(points_world):
        return points_world.reshape(0, 3)
    ij = np.floor(points_world[:, :2] / cell_m).astype(np.int64)
    return points_world[_lowest_index(ij - ij.min(axis=0), points_world[:, 2])]


class LowestPerCell:
    """The lowest point per ``cell_m`` square of many world point clouds, gathered cloud by cloud
    (:meth:`add`) without holding them: :meth:`points` is :func:`lowest_per_cell` of all the clouds
    at once, the same points in the same order (cell by cell, x then y; of equal heights the first
    added).

    Args:
        bounds_xy_m: (2,2) [[x_min, y_min], [x_max, y_max]]: every point added lies within.
        cell_m: cell side.
    """

    def __init__(self, bounds_xy_m: np.ndarray, cell_m: float) -> None:
        self.cell_m = float(cell_m)
        bounds = np.floor(np.asarray(bounds_xy_m, float) / self.cell_m).astype(np.int64)
        self._corner_ij = bounds[0] - 1  # a cell of margin on each side
        nx, ny = (int(v) for v in bounds[1] - self._corner_ij + 2)
        self._lowest = np.full((nx, ny, 3), np.nan)  # per cell its lowest point so far, NaN for none

    def add(self, points_world: np.ndarray) -> None:
        """Gather the (N,3) world points (within the bounds, else :class:`ValueError`)."""
        points_world = np.ascontiguousarray(points_world, dtype=np.float64).reshape(-1, 3)
        outside = _keep_lowest(points_world, self.cell_m, self._corner_ij[0], self._corner_ij[1], self._lowest)
        if outside:
            raise ValueError(f"{outside} of {len(points_world)} points lie outside the bounds of the cells")

    def points(self) -> np.ndarray:
        """(M,3) the lowest point of each cell that has one."""
        return self._lowest[~np.isnan(self._lowest[..., 2])]


@lazy_njit
def _keep_lowest(points_world: np.ndarray, cell_m: float, corner_i: int, corner_j: int, lowest: np.ndarray) -> int:
    """Keep in ``lowest`` (nx, ny, 3; NaN where empty) each (N,3) point lower than its cell's (cell
    ``floor(x / cell_m) - corner_i``, ``floor(y / cell_m) - corner_j``), in place; an equal height
    keeps the point already there. Returns the number of points outside ``lowest``, left out."""
    nx, ny = lowest.shape[0], lowest.shape[1]
    outside = 0
    for k in range(points_world.shape[0]):
        i = int(np.floor(points_world[k, 0] / cell_m)) - corner_i
        j = int(np.floor(points_world[k, 1] / cell_m)) - corner_j
        if not (0 <= i < nx and 0 <= j < ny):
            outside += 1
        elif not lowest[i, j, 2] <= points_world[k, 2]:  # also where the cell is empty (NaN)
            lowest[i, j, 0] = points_world[k, 0]
            lowest[i, j, 1] = points_world[k, 1]
            lowest[i, j, 2] = points_world[k, 2]
    return outside


def _lowest_index(ij: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Index of the lowest ``z`` among the points of each cell (N,2) ``ij`` (non-negative)."""
    flat = ij[:, 0] * (int(ij[:, 1].max()) + 1) + ij[:, 1]
    order = np.lexsort((z, flat))
    return order[np.r_[True, flat[order][1:] != flat[order][:-1]]]


def _fit_planes(
    inlier: np.ndarray, offset: np.ndarray, dz: np.ndarray, window: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per cell the least-squares plane through the inlier candidates of the cells within ``window``:
    height at the cell's centre, (dz/du, dz/dv) in cell units, and whether the fit is determined
    (three or more inliers, not all on a line)."""
    nx, ny = inlier.shape
    w = window
    pad = ((w, w), (w, w))
    weight = np.pad(inlier.astype(np.float64), pad)
    pu = np.pad(offset[..., 0], pad)
    pv = np.pad(offset[..., 1], pad)
    pz = np.pad(dz, pad)
    sums = np.zeros((9, nx, ny))
    for a in range(-w, w + 1):
        for b in range(-w, w + 1):
            sl = (slice(w + a, w + a + nx), slice(w + b, w + b + ny))
            m = weight[sl]
            u = (pu[sl] + a) * m
            v = (pv[sl] + b) * m
            zz = pz[sl] * m
            uu, vv = pu[sl] + a, pv[sl] + b
            sums += np.stack([m, u, v, u * uu, u * vv, v * vv, zz, u * pz[sl], v * pz[sl]])
    n, su, sv, suu, suv, svv, sz, suz, svz = sums
    A = np.stack([np.stack([n, su, sv], -1), np.stack([su, suu, suv], -1), np.stack([sv, suv, svv], -1)], -2)
    rhs = np.stack([sz, suz, svz], -1)
    det = np.linalg.det(A)
    ok = (n >= 3) & (np.abs(det) > 1e-6 * np.maximum(n, 1) ** 3)
    solution = np.zeros((nx, ny, 3))
    solution[ok] = np.linalg.solve(A[ok], rhs[ok][..., None])[..., 0]
    return solution[..., 0], solution[..., 1:], ok


@dataclass(frozen=True, slots=True)
class OccupancyGrid:
    """A finished grid.

    Attributes:
        origin_xy_m: (2,) world x, y of the outer corner of cell (0, 0) (the lowest x and y).
        resolution_m: cell side.
        log_odds: (nx, ny) float32 log-odds of occupancy per cell, index [i, j] = cell at
            x = origin_x + (i + 0.5) * resolution, y = origin_y + (j + 0.5) * resolution; 0 = unknown.
        observed: (nx, ny) bool, some sweep updated the cell.
    """

    origin_xy_m: np.ndarray
    resolution_m: float
    log_odds: np.ndarray
    observed: np.ndarray

    @property
    def probability(self) -> np.ndarray:
        """(nx, ny) occupancy probability per cell (0.5 where never observed)."""
        return 1.0 / (1.0 + np.exp(-self.log_odds.astype(np.float64)))

    def cell_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell indices (i, j) of (N,2) world x, y and a (N,) mask of those inside the grid."""
        return _cells_of(xy, self.origin_xy_m, self.resolution_m, self.log_odds.shape)


def _cells_of(
    xy: np.ndarray, origin_xy_m: np.ndarray, resolution_m: float, shape: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cell indices (i, j) of (N,2) world x, y in a grid of ``shape`` cells from ``origin_xy_m``, and
    a (N,) mask of those inside it."""
    ij = np.floor((xy - origin_xy_m) / resolution_m).astype(np.int64)
    inside = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < shape[0]) & (ij[:, 1] < shape[1])
    return ij[:, 0], ij[:, 1], inside


class OccupancyGridBuilder:
    """Accumulates sweeps into a grid covering ``bounds_xy_m``; :meth:`add` per sweep, then :meth:`grid`.

    Args:
        params: how the grid is built.
        ground: the local ground height.
        bounds_xy_m: (2,2) [[x_min, y_min], [x_max, y_max]] world extent of the grid.
    """

    def __init__(self, params: GridParams, ground: GroundModel, bounds_xy_m: np.ndarray) -> None:
        self.params = params
        self.ground = ground
        res = params.resolution_m
        self.origin_xy_m = np.floor(np.asarray(bounds_xy_m[0], float) / res) * res
        self.shape = tuple(int(v) for v in np.ceil((np.asarray(bounds_xy_m[1], float) - self.origin_xy_m) / res) + 1)
        self._log_odds = np.zeros(self.shape[0] * self.shape[1], np.float32)
        self._mark = np.full(self._log_odds.size, -1, np.int32)
        # per cell the world z a beam must pass below to free it (-inf: no obstacle noted, any beam)
        self._free_below_z = np.full(self._log_odds.size, -np.inf)
        self._n_sweeps = 0
        n_bins = params.azimuth_bins
        bin_angle_rad = (np.arange(n_bins) + 0.5) * (2 * np.pi / n_bins) - np.pi
        # Direction of each bin's centre line, float32: a sample k cells out is k * (cos, sin) cells away.
        self._bin_direction = np.stack([np.cos(bin_angle_rad), np.sin(bin_angle_rad)], axis=1).astype(np.float32)
        self._levels = _casting_levels(res, n_bins)

    def note_obstacles(self, points_world: np.ndarray, on_ground: np.ndarray | None = None) -> None:
        """Note the obstacle points of a sweep before any is ray cast: (N,3) world points, (N,) bool
        ground marks as for :meth:`add`. A cell with an obstacle noted is freed only by a beam that
        passes through it ``top_margin_m`` below the highest obstacle point noted there (world z): a
        beam passing over a car's roof or a low wall, inside the band, says nothing of what is under
        it. Below ``band low + top_margin_m`` above the ground no beam is cast, so a cell whose
        obstacles stay under that height is freed by any beam in the band, as without the note."""
        p = self.params
        points_world = np.ascontiguousarray(points_world, dtype=np.float64).reshape(-1, 3)
        ground_z = self.ground.height_at(points_world[:, :2])
        height = points_world[:, 2] - ground_z
        obstacle = (height >= p.band_m[0]) & (height <= p.band_m[1])
        if on_ground is not None:
            on_ground = np.asarray(on_ground, bool)
            if on_ground.shape != (len(points_world),):
                raise ValueError(f"on_ground must be ({len(points_world)},), got {on_ground.shape}")
            obstacle &= ~on_ground
        threshold_z = np.maximum(points_world[:, 2] - p.top_margin_m, ground_z + p.band_m[0] + p.top_margin_m)
        i, j, inside = _cells_of(points_world[obstacle, :2], self.origin_xy_m, p.resolution_m, self.shape)
        np.maximum.at(self._free_below_z, i[inside] * self.shape[1] + j[inside], threshold_z[obstacle][inside])

    def add(self, origin_world: np.ndarray, points_world: np.ndarray, on_ground: np.ndarray | None = None) -> None:
        """Ray cast one sweep: sensor position (3,) and its (N,3) points, world frame; ``on_ground``
        (N,) bool marks the points the segmentation called ground: never obstacles (their beams
        still free the band before them)."""
        p = self.params
        ground = self.ground
        points_world = np.ascontiguousarray(points_world, dtype=np.float64)
        n = len(points_world)
        on_ground = np.zeros(n, bool) if on_ground is None else np.asarray(on_ground, bool)
        if points_world.shape != (n, 3) or on_ground.shape != (n,):  # the kernel does not check its indices
            raise ValueError(f"points must be (N, 3) and on_ground (N,), got {points_world.shape}, {on_ground.shape}")
        sweep = self._n_sweeps
        self._n_sweeps += 1
        if not n:
            return
        delta = points_world[:, :2] - origin_world[:2]
        length = np.hypot(delta[:, 0], delta[:, 1])
        azimuth = np.arctan2(delta[:, 1], delta[:, 0])
        n_bins = p.azimuth_bins
        bins = (np.floor((azimuth + np.pi) * (n_bins / (2 * np.pi))).astype(np.int64)) % n_bins
        sensor_height_m = float(origin_world[2] - ground.height_at(origin_world[None, :2])[0])
        sensor_cell = (np.asarray(origin_world[:2], float) - self.origin_xy_m) / p.resolution_m
        _ray_cast_sweep(
            points_world,
            length,
            bins,
            on_ground,
            ground.origin_xy_m,
            ground.cell_m,
            ground.height_m,
            ground.slope,
            sensor_height_m,
            p.band_m[0],
            p.band_m[1],
            p.resolution_m,
            p.max_range_m,
            self.origin_xy_m,
            sensor_cell,
            self._bin_direction,
            self._levels,
            np.float32(p.miss_log_odds),
            np.float32(-p.clamp_log_odds),
            p.hit_log_odds,
            p.hit_log_odds - p.miss_log_odds,
            p.clamp_log_odds,
            sweep,
            self.shape[1],
            self._log_odds,
            self._mark,
            float(origin_world[2]),
            self._free_below_z,
        )

    def grid(self) -> OccupancyGrid:
        """The grid so far."""
        return OccupancyGrid(
            self.origin_xy_m.copy(),
            self.params.resolution_m,
            self._log_odds.reshape(self.shape).copy(),
            (self._mark >= 0).reshape(self.shape),
        )


def _casting_levels(resolution_m: float, azimuth_bins: int) -> np.ndarray:
    """(L,3) the casting levels of a sweep's bins, outermost first: (near, far, stride) per row. Level
    ``l`` casts every ``2**l``-th bin between ``near`` and ``far`` metres from the sensor, so that near
    the sensor, where the bins crowd, the sampled bins stay about a cell apart; the last level reaches
    the sensor."""
    spread_m = 2 * np.pi / azimuth_bins  # bin spacing per metre of distance
    levels = []
    level, far = 0, np.inf
    while far > resolution_m:
        near = 0.7 * resolution_m / (spread_m * 2 ** (level + 1)) if level < 12 else 0.0
        levels.append((near, far, 2**level))
        level, far = level + 1, near
    return np.array(levels, dtype=np.float64).reshape(-1, 3)


@lazy_njit
def _ray_cast_sweep(
    points_world: np.ndarray,
    length_m: np.ndarray,
    azimuth_bin: np.ndarray,
    on_ground: np.ndarray,
    ground_origin_xy_m: np.ndarray,
    ground_cell_m: float,
    ground_height_m: np.ndarray,
    ground_slope: np.ndarray,
    sensor_height_m: float,
    band_low_m: float,
    band_high_m: float,
    resolution_m: float,
    max_range_m: float,
    grid_origin_xy_m: np.ndarray,
    sensor_cell: np.ndarray,
    bin_direction: np.ndarray,
    levels: np.ndarray,
    miss_log_odds: np.float32,
    free_floor: np.float32,
    hit_log_odds: float,
    hit_after_free: float,
    clamp_log_odds: float,
    sweep: int,
    ny: int,
    log_odds: np.ndarray,
    mark: np.ndarray,
    sensor_z: float,
    free_below_z: np.ndarray,
) -> None:
    """Ray cast one sweep into the flat grid ``log_odds`` (float32) / ``mark`` (int32, the last sweep
    that updated each cell), in place: see the module docstring and :class:`OccupancyGridBuilder`.

    Per point (``points_world`` (N,3), its plane distance ``length_m`` (N,) and ``azimuth_bin`` (N,)
    from the sensor, ``on_ground`` (N,) bool): the fractions of the beam inside the band from the
    ground under it (``ground_*``: the arrays of :class:`GroundModel`) and the sensor's height above
    ground; per azimuth bin the nearest entry (``start``), the farthest free reach and the nearest
    obstacle. Then each bin's centre line is sampled every cell from ``start`` to its reach, level by
    level (``levels`` from :func:`_casting_levels`; ``bin_direction`` (B,2) float32 cos, sin;
    ``sensor_cell`` (2,) the sensor in cell units from the grid's corner). Free cells take
    ``miss_log_odds`` (float32 arithmetic, floored at ``free_floor``), occupied cells
    ``hit_log_odds`` (``hit_after_free`` where the sweep freed them first; float64, capped at
    ``clamp_log_odds``); a cell counts once per sweep. A cell with an obstacle noted
    (``free_below_z``, flat like ``log_odds``: the world z a beam must pass below, -inf where none;
    :meth:`OccupancyGridBuilder.note_obstacles`) is freed only where the lowest of the bin's beams
    over that sample (world z from the sensor's ``sensor_z`` along the beam) passes below it."""
    n_bins = bin_direction.shape[0]
    gx, gy = ground_height_m.shape[0], ground_height_m.shape[1]
    nx = log_odds.size // ny
    inside_at_start = band_low_m <= sensor_height_m <= band_high_m
    start = np.full(n_bins, np.inf)
    reach = np.zeros(n_bins)
    blocked = np.full(n_bins, np.inf)
    hits = np.empty(points_world.shape[0], np.int64)
    n_hits = 0
    # every beam's stretch in the band: bin, from, to (m in the plane) and its world z rise per metre
    beam_bin = np.empty(points_world.shape[0], np.int64)
    beam_from = np.empty(points_world.shape[0])
    beam_to = np.empty(points_world.shape[0])
    beam_rise = np.empty(points_world.shape[0])
    n_beams = 0
    for k in range(points_world.shape[0]):
        length = length_m[k]
        if not (length > resolution_m and length <= max_range_m):
            continue
        x, y, z = points_world[k, 0], points_world[k, 1], points_world[k, 2]
        # The ground under the point: its cell's plane (GroundModel.height_at).
        u = (x - ground_origin_xy_m[0]) / ground_cell_m
        v = (y - ground_origin_xy_m[1]) / ground_cell_m
        gi = min(max(int(np.floor(u)), 0), gx - 1)
        gj = min(max(int(np.floor(v)), 0), gy - 1)
        ground_z = (
            ground_height_m[gi, gj]
            + ground_slope[gi, gj, 0] * ((u - gi - 0.5) * ground_cell_m)
            + ground_slope[gi, gj, 1] * ((v - gj - 0.5) * ground_cell_m)
        )
        height = z - ground_z
        # Where along the beam (fraction of its length) its height above ground is in the band.
        rise = height - sensor_height_m
        if abs(rise) < 1e-9:
            enter = 0.0 if inside_at_start else np.inf
            leave = 1.0 if inside_at_start else -np.inf
        else:
            at_low = (band_low_m - sensor_height_m) / rise
            at_high = (band_high_m - sensor_height_m) / rise
            enter, leave = (at_low, at_high) if rise > 0 else (at_high, at_low)
            enter = max(enter, 0.0)
            leave = min(leave, 1.0)
        end_free = length - resolution_m  # the last cell before the point is free at most
        free_from = enter * length
        free_to = min(leave * length, end_free)
        b = azimuth_bin[k]
        if free_to > free_from:
            start[b] = min(start[b], free_from)
            reach[b] = max(reach[b], free_to)
            beam_bin[n_beams] = b
            beam_from[n_beams] = free_from
            beam_to[n_beams] = free_to
            beam_rise[n_beams] = (z - sensor_z) / length
            n_beams += 1
        if band_low_m <= height <= band_high_m and not on_ground[k]:
            # The nearest obstacle in the band ends the free space of its azimuth.
            blocked[b] = min(blocked[b], end_free)
            i = int(np.floor((x - grid_origin_xy_m[0]) / resolution_m))
            j = int(np.floor((y - grid_origin_xy_m[1]) / resolution_m))
            if 0 <= i < nx and 0 <= j < ny:
                hits[n_hits] = i * ny + j
                n_hits += 1
    # the beams of each bin, contiguous: bin b's are order[first[b]:first[b + 1]]
    order = np.argsort(beam_bin[:n_beams], kind="mergesort")
    first = np.zeros(n_bins + 1, np.int64)
    for k in range(n_beams):
        first[beam_bin[k] + 1] += 1
    for b in range(n_bins):
        first[b + 1] += first[b]
    for level in range(levels.shape[0]):
        near, far, stride = levels[level, 0], levels[level, 1], int(levels[level, 2])
        for b in range(0, n_bins, stride):
            lo = max(start[b], near)
            hi = min(reach[b], far, blocked[b])
            if not hi > lo:
                continue
            cos, sin = bin_direction[b, 0], bin_direction[b, 1]
            for sample in range(int(np.ceil(lo / resolution_m)), int(np.floor(hi / resolution_m)) + 1):
                index = np.float32(sample)
                i = min(max(int(sensor_cell[0] + cos * index), 0), nx - 1)
                j = min(max(int(sensor_cell[1] + sin * index), 0), ny - 1)
                cell = i * ny + j
                if mark[cell] == sweep:
                    continue
                below_z = free_below_z[cell]
                if below_z > -np.inf:
                    # the lowest beam of the bin over this sample must pass below what was seen here
                    distance = sample * resolution_m
                    lowest = np.inf
                    for k in range(first[b], first[b + 1]):
                        beam = order[k]
                        if beam_from[beam] <= distance <= beam_to[beam]:
                            lowest = min(lowest, sensor_z + beam_rise[beam] * distance)
                    if not lowest < below_z:
                        continue
                mark[cell] = sweep
                log_odds[cell] = max(log_odds[cell] + miss_log_odds, free_floor)
    # Occupied wins over free; a cell hit by several points counts once (all read, then written).
    updated = np.empty(n_hits, np.float64)
    for h in range(n_hits):
        cell = hits[h]
        step = hit_after_free if mark[cell] == sweep else hit_log_odds
        updated[h] = min(np.float64(log_odds[cell]) + step, clamp_log_odds)
    for h in range(n_hits):
        log_odds[hits[h]] = updated[h]
        mark[hits[h]] = sweep
