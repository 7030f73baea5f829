"""A 2-D occupancy grid for navigation: log-odds per cell from ray casting each sweep in a height band
above the local ground.

For every point of a sweep (world frame, moving objects already left out) the beam from the sensor
is followed in the plane: its height above the local ground is taken to vary linearly between the
sensor and the point (the ground height under each end, from :class:`GroundModel`), so on a hill the
band follows the slope. Cells the beam crosses while it is inside the band ``[low, high]`` are
*free*, the cell of the point is *occupied* when the point lies inside the band. Within one sweep
the beams are gathered per azimuth bin (the farthest free reach of the bin, cast once) and a cell
counts once: occupied wins over free. Each sweep adds ``hit_log_odds`` to its occupied cells and
``miss_log_odds`` to its free ones, clamped to ``[-clamp, clamp]`` (as OctoMap and ROS gmapping
do). Frames: world = the run's map frame (x, y in the plane, z up).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GridParams", "GroundModel", "OccupancyGrid", "OccupancyGridBuilder", "lowest_per_cell"]


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
    """

    resolution_m: float = 0.1
    band_m: tuple[float, float] = (0.3, 2.0)
    max_range_m: float = 40.0
    azimuth_bins: int = 1440
    hit_log_odds: float = 1.2
    miss_log_odds: float = -0.4
    clamp_log_odds: float = 3.5

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
        ij = np.floor((xy - self.origin_xy_m) / self.resolution_m).astype(np.int64)
        inside = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < self.log_odds.shape[0])
        inside &= ij[:, 1] < self.log_odds.shape[1]
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
        self._n_sweeps = 0

    def add(self, origin_world: np.ndarray, points_world: np.ndarray, on_ground: np.ndarray | None = None) -> None:
        """Ray cast one sweep: sensor position (3,) and its (N,3) points, world frame; ``on_ground``
        (N,) bool marks the points the segmentation called ground: never obstacles (their beams
        still free the band before them)."""
        p = self.params
        ground = self.ground
        low, high = p.band_m
        sweep = self._n_sweeps
        self._n_sweeps += 1
        if not len(points_world):
            return
        delta = points_world[:, :2] - origin_world[:2]
        length = np.hypot(delta[:, 0], delta[:, 1])
        ok = (length > p.resolution_m) & (length <= p.max_range_m)
        points_world, delta, length = points_world[ok], delta[ok], length[ok]
        not_ground = np.ones(len(points_world), bool) if on_ground is None else ~np.asarray(on_ground, bool)[ok]
        h0 = float(origin_world[2] - ground.height_at(origin_world[None, :2])[0])
        h1 = points_world[:, 2] - ground.height_at(points_world[:, :2])
        # Where along the beam (fraction s of its length) its height above ground is in the band.
        slope = h1 - h0
        with np.errstate(divide="ignore", invalid="ignore"):
            s_low, s_high = (low - h0) / slope, (high - h0) / slope
        s_enter = np.where(slope > 0, s_low, s_high)
        s_leave = np.where(slope > 0, s_high, s_low)
        flat = np.abs(slope) < 1e-9
        inside_at_start = (h0 >= low) & (h0 <= high)
        s_enter = np.where(flat, 0.0 if inside_at_start else np.inf, np.clip(s_enter, 0.0, None))
        s_leave = np.where(flat, 1.0 if inside_at_start else -np.inf, np.minimum(s_leave, 1.0))
        end_free = length - p.resolution_m  # the last cell before the point is free at most
        free_from = s_enter * length
        free_to = np.minimum(s_leave * length, end_free)
        occupied = (h1 >= low) & (h1 <= high) & not_ground
        # The nearest obstacle in the band ends the free space of its azimuth: beams that pass over a
        # car or a low wall say nothing about the band below them.
        blocked_at = np.where(occupied, end_free, np.inf)
        free_cells = self._free_cells(origin_world[:2], delta, free_from, free_to, blocked_at)
        hit_cells = self._cells(points_world[occupied, :2])
        mark, log_odds = self._mark, self._log_odds
        if free_cells.size:
            mark[free_cells] = sweep
            log_odds[free_cells] = np.maximum(log_odds[free_cells] + p.miss_log_odds, -p.clamp_log_odds)
        if hit_cells.size:
            # A cell counts once per sweep (a repeated index is written once): occupied wins over free.
            step = np.where(mark[hit_cells] == sweep, p.hit_log_odds - p.miss_log_odds, p.hit_log_odds)
            log_odds[hit_cells] = np.minimum(log_odds[hit_cells] + step, p.clamp_log_odds)
            mark[hit_cells] = sweep

    def grid(self) -> OccupancyGrid:
        """The grid so far."""
        return OccupancyGrid(
            self.origin_xy_m.copy(),
            self.params.resolution_m,
            self._log_odds.reshape(self.shape).copy(),
            (self._mark >= 0).reshape(self.shape),
        )

    def _cells(self, xy: np.ndarray) -> np.ndarray:
        """Flat indices of the cells of (N,2) world x, y inside the grid."""
        ij = np.floor((xy - self.origin_xy_m) / self.params.resolution_m).astype(np.int64)
        inside = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < self.shape[0]) & (ij[:, 1] < self.shape[1])
        return ij[inside, 0] * self.shape[1] + ij[inside, 1]

    def _free_cells(
        self,
        origin_xy: np.ndarray,
        delta: np.ndarray,
        free_from: np.ndarray,
        free_to: np.ndarray,
        blocked_at: np.ndarray,
    ) -> np.ndarray:
        """Flat indices of the cells the sweep's beams cross in the band: per azimuth bin from the
        nearest entry to the farthest reach, but not past the bin's nearest obstacle
        (``blocked_at``, (N,) distance, inf for none), sampled every cell along the bin's direction;
        near the sensor, where the bins crowd, only every 2nd, 4th, ... bin is sampled (the bins stay
        about a cell apart)."""
        p = self.params
        n_bins = p.azimuth_bins
        azimuth = np.arctan2(delta[:, 1], delta[:, 0])
        bins = (np.floor((azimuth + np.pi) * (n_bins / (2 * np.pi))).astype(np.int64)) % n_bins
        order = np.argsort(bins, kind="stable")
        sorted_bins = bins[order]
        first = np.flatnonzero(np.r_[True, sorted_bins[1:] != sorted_bins[:-1]])
        useful = free_to > free_from
        start = np.full(n_bins, np.inf)
        reach = np.zeros(n_bins)
        start[sorted_bins[first]] = np.minimum.reduceat(np.where(useful, free_from, np.inf)[order], first)
        reach[sorted_bins[first]] = np.minimum(
            np.maximum.reduceat(np.where(useful, free_to, 0.0)[order], first),
            np.minimum.reduceat(blocked_at[order], first),
        )
        step = p.resolution_m
        spread_m = 2 * np.pi / n_bins  # bin spacing per metre of distance
        cells = []
        level, far = 0, np.inf
        while far > step:
            near = 0.7 * step / (spread_m * 2 ** (level + 1)) if level < 12 else 0.0
            stride = 2**level
            chosen = np.arange(0, n_bins, stride)
            lo = np.maximum(start[chosen], near)
            hi = np.minimum(reach[chosen], far)
            keep = hi > lo
            if keep.any():
                cells.append(self._cast(origin_xy, chosen[keep], lo[keep], hi[keep]))
            level, far = level + 1, near
        return np.concatenate(cells) if cells else np.zeros(0, np.int64)

    def _cast(self, origin_xy: np.ndarray, bins: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Flat cell indices sampled every cell from distance ``lo`` to ``hi`` along each bin's centre
        line (inside the grid: its bounds hold every sensor position +- ``max_range_m``)."""
        step = self.params.resolution_m
        first = np.ceil(lo / step).astype(np.int64)
        count = np.floor(hi / step).astype(np.int64) - first + 1
        ok = count > 0
        bins, first, count = bins[ok], first[ok], count[ok]
        ray = np.repeat(np.arange(bins.size), count)
        index = (np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count - first, count)).astype(np.float32)
        angle = (bins + 0.5) * (2 * np.pi / self.params.azimuth_bins) - np.pi
        # In cell units the sample k of a bin lies at origin + k * (cos, sin): one multiply-add per axis.
        start = (origin_xy - self.origin_xy_m) / step
        nx, ny = self.shape
        i = np.clip((start[0] + np.cos(angle).astype(np.float32)[ray] * index).astype(np.int64), 0, nx - 1)
        j = np.clip((start[1] + np.sin(angle).astype(np.float32)[ray] * index).astype(np.int64), 0, ny - 1)
        return i * ny + j
