"""Ground marking on the range image (LeGO-LOAM imageProjection, IP:260-310, extended).

LeGO-LOAM's test: for every column and every pair of vertically adjacent rows below the ground row
count, the vector from the lower to the upper point has an elevation angle within
``ground_angle_threshold_deg`` (10 deg) of horizontal; then both points are ground. Here the vector is
first rotated into the level vehicle frame (undoing the mount roll and pitch); LeGO-LOAM subtracts
one ``sensorMountAngle``, which is exact only straight ahead. ``ground_continuity = false`` gives
exactly this test.

On simulated streets that test alone marks 10-30 % false ground (precision 0.85 on the "loop"
scenario): the first point up a wall seen beyond far ground (a 1 m step over the 20 m between two
sparse lower rings looks flat), car hoods and roofs seen from above, the feet of walls and cars.
With ``ground_continuity`` (default) every column is walked upwards, keeping the last ground point
and the slope of the ground run below it (measured over at least ``ground_noise_m / tan(max
change)``, so that range noise between close rows cannot tilt it), and a flat pair is ground when:

1. it continues a run and bends from the run's slope by at most ``ground_max_angle_change_deg``,
   or by a height within ``ground_noise_m`` over its length;
2. it starts above an object (no ground right below) and is reachable from the column's last ground
   point: that step is flat itself and bends as little from the run's slope;
3. it starts a column's first run at the scan's ground level: the median height of the flat pairs
   of the lowest well-filled row, within ``ground_height_margin_m`` + distance *
   tan(``ground_height_slope_deg``).

Runs continue above the ground rows (uphill roads seen by upward beams) but never start there.
Then a ground cell joined to the non-ground cell above it by the clustering criterion (beta >
``cluster_angle_deg``: one surface) belongs to that object, unless it lies within
``ground_support_margin_m`` of its run's line or at the ground level (checked from the top down).
Last, the surface check (``ground_surface_sector_deg`` > 0, default 2): the slope tests compare
angles, and over the long gaps between the lowest beams' rings far out (34 m to 60-100 m on a
VLP-16) a small angle makes a large height, so the base of a car or wall hit by the -1 deg beam at
60 m, 0.75 m up, bends only 1.7 deg from flat ground. Each ground cell must also lie on the ground
below it in its azimuth sector: at most a margin, a range term and the departure of the sector's
observed curvature from the local line above that line (see ``_check_surface``). The cells it takes
out are *lifted* (:func:`classify_ground`): not ground, but still surfaces at the ground's level.
The per-pair tests are array work over the whole image; the walk up each column, which carries its
run from row to row, the release and the surface check are compiled kernels (numba; with the walk
as an array loop over rows the ground stage took 3.1 ms per VLP-16 scan, with the kernel 1.7 ms,
median on ``loop``; the surface check as array work took 6-8 ms, compiled about 1 ms).
"""

from __future__ import annotations

import math

import numpy as np

from lidar3d.config import SegmentationConfig, SensorConfig
from lidar3d.errors import ConfigError
from lidar3d.jit import lazy_njit
from lidar3d.segmentation.range_image import RangeImage

__all__ = ["R_base_lidar_from_mount", "classify_ground", "ground_row_count", "mark_ground"]


def R_base_lidar_from_mount(mount_roll_deg: float, mount_pitch_deg: float) -> np.ndarray:
    """(3, 3) rotation taking lidar-frame vectors into the level vehicle (base) frame.

    REP-103 angles, yaw zero: ``R = R_y(pitch) @ R_x(roll)``. Positive pitch tilts the lidar's x axis
    down (nose down), so level ground ahead appears at +pitch elevation in the lidar frame, which is
    the sign of LeGO-LOAM's ``sensorMountAngle``.
    """
    roll, pitch = np.deg2rad(mount_roll_deg), np.deg2rad(mount_pitch_deg)
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    R_y = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    R_x = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    return R_y @ R_x


def ground_row_count(config: SegmentationConfig, row_elevation_rad: np.ndarray) -> int:
    """Rows ``0 .. n-1`` may be ground: ``config.ground_rows``, or when 0 every beam below the horizon."""
    n_rows = row_elevation_rad.shape[0]
    if config.ground_rows > 0:
        return min(config.ground_rows, n_rows)
    return int(np.count_nonzero(row_elevation_rad < 0.0))


def _check(config: SegmentationConfig) -> None:
    if not 0.0 < config.ground_angle_threshold_deg < 90.0:
        raise ConfigError(
            "config segmentation.ground_angle_threshold_deg: must be in (0, 90), "
            f"got {config.ground_angle_threshold_deg}"
        )
    if config.ground_continuity and not 0.0 < config.ground_max_angle_change_deg < 90.0:
        raise ConfigError(
            "config segmentation.ground_max_angle_change_deg: must be in (0, 90), "
            f"got {config.ground_max_angle_change_deg}"
        )


def mark_ground(
    image: RangeImage, config: SegmentationConfig, sensor_config: SensorConfig, *, surface_check: bool = True
) -> np.ndarray:
    """(R, C) bool mask of the ground cells of ``image`` (see the module doc for the tests); with
    ``surface_check=False`` the coarse ground (:func:`classify_ground`)."""
    return classify_ground(image, config, sensor_config, surface_check=surface_check)[0]


def classify_ground(
    image: RangeImage, config: SegmentationConfig, sensor_config: SensorConfig, *, surface_check: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """(R, C) bool masks of ``image``: the ground cells, and the lifted cells, those the slope tests
    took for ground and the surface check took out of it (the bases of walls and cars far out, and
    far ground it cannot confirm; none when the check is off). Together they are the coarse ground
    the feature path uses (``Segmentation.coarse_ground_mask``). See the module doc.

    ``surface_check=False`` skips the check whatever the configuration says (the ground is then the
    coarse ground, no cell lifted): for callers that use the coarse ground only (the SLAM's front
    end, the grid), which saves its 0.6 ms a scan."""
    _check(config)
    n_rows, n_columns = image.shape
    ground = np.zeros((n_rows, n_columns), dtype=bool)
    lifted = np.zeros((n_rows, n_columns), dtype=bool)
    n_ground = ground_row_count(config, image.row_elevation_rad)
    if n_ground < 2:
        return ground, lifted
    # continuity mode follows ground runs above the ground rows (uphill); see the module doc
    n_top = n_rows if config.ground_continuity else n_ground
    points = image.points[:n_top]  # (n_top, C, 3), NaN where empty
    if sensor_config.mount_roll_deg or sensor_config.mount_pitch_deg:
        points = points @ R_base_lidar_from_mount(sensor_config.mount_roll_deg, sensor_config.mount_pitch_deg).T
    step = points[1:] - points[:-1]  # (n_top-1, C, 3); NaN where a cell is empty
    run_m = np.sqrt(step[..., 0] ** 2 + step[..., 1] ** 2)  # np.hypot is 8x slower (not vectorised)
    with np.errstate(invalid="ignore"):
        angle = np.arctan2(step[..., 2], run_m)
        flat = np.abs(angle) <= np.deg2rad(config.ground_angle_threshold_deg)
    if not config.ground_continuity:
        ground[: n_ground - 1] |= flat
        ground[1:n_ground] |= flat
        return ground, lifted
    supported = _walk_up_columns(ground, points, step, run_m, angle, flat, n_ground, config)
    _release_contacts(image, ground, supported, config)
    if surface_check and config.ground_surface_sector_deg > 0.0:
        lifted[:] = ground
        _check_surface(ground, points, image.azimuth_resolution_rad, config)
        lifted &= ~ground
    return ground, lifted


def _walk_up_columns(
    ground: np.ndarray,
    points: np.ndarray,
    step: np.ndarray,
    run_m: np.ndarray,
    angle: np.ndarray,
    flat: np.ndarray,
    n_ground: int,
    config: SegmentationConfig,
) -> np.ndarray:
    """Mark ``ground`` (in place) by walking up every column; returns the (R, C) "supported" mask.

    The per-pair tests and the scan's ground level are array work here; the walk itself, which
    carries each column's run from row to row, is the :func:`_walk_columns` kernel. Shapes:
    ``points`` (n_top, C, 3) in the level frame; ``step``, ``run_m``, ``angle``, ``flat`` for the
    pairs of consecutive rows, (n_top-1, C[, 3]).
    """
    n_rows, n_columns = ground.shape
    tan_threshold = np.tan(np.deg2rad(config.ground_angle_threshold_deg))
    noise_m = config.ground_noise_m
    max_change = np.deg2rad(config.ground_max_angle_change_deg)
    with np.errstate(invalid="ignore", divide="ignore"):
        # closely spaced rows (32-beam sensors near the vehicle): range noise alone tilts a pair
        flat = flat | (np.abs(step[..., 2]) <= tan_threshold * run_m + noise_m)
        tan_angle = step[..., 2] / run_m
        reference_z = np.nan  # the scan's ground level: median height of the lowest well-filled flat row
        for i in range(n_ground - 1):
            if np.count_nonzero(flat[i]) >= max(20, n_columns // 20):
                reference_z = float(np.median(points[i, flat[i], 2]))
                break
        if np.isnan(reference_z):
            at_level = np.ones(points.shape[:2], dtype=bool)
        else:
            distance = np.sqrt(points[..., 0] ** 2 + points[..., 1] ** 2)
            tolerance = config.ground_height_margin_m + np.tan(np.deg2rad(config.ground_height_slope_deg)) * distance
            at_level = np.abs(points[..., 2] - reference_z) <= tolerance

    supported = np.zeros((n_rows, n_columns), dtype=bool)  # ground that certainly is ground
    _walk_columns(
        ground,
        supported,
        points,
        run_m,
        angle,
        flat,
        tan_angle,
        at_level,
        n_ground,
        tan_threshold,
        noise_m,
        max_change,
        # the slope a run is compared with is measured over at least this run, so that range noise
        # between close rows cannot tilt it by more than the allowed change
        noise_m / np.tan(max_change),
        config.ground_support_margin_m,
    )
    return supported


@lazy_njit
def _walk_columns(
    ground: np.ndarray,
    supported: np.ndarray,
    points: np.ndarray,
    run_m: np.ndarray,
    angle: np.ndarray,
    flat: np.ndarray,
    tan_angle: np.ndarray,
    at_level: np.ndarray,
    n_ground: int,
    tan_threshold: float,
    noise_m: float,
    max_change: float,
    min_baseline_m: float,
    support_margin_m: float,
) -> None:
    """The column walk of :func:`_walk_up_columns`, marking ``ground`` and ``supported`` (R, C) in place.

    Each column is walked up its pairs of rows, keeping the highest ground point so far (``last``) and
    an earlier point of the same run at least ``min_baseline_m`` back (``anchor``), whose line is the
    run's slope. Shapes: ``points`` (n_top, C, 3) level frame, NaN where empty; ``run_m``, ``angle``,
    ``flat``, ``tan_angle`` (n_top-1, C) of each pair; ``at_level`` (n_top, C).
    """
    n_top, n_columns = points.shape[0], points.shape[1]

    def gentle(new_angle: float, old_angle: float, run: float) -> bool:
        """The slope bends little, or the height it makes over ``run`` differs within the noise."""
        return abs(new_angle - old_angle) <= max_change or abs(np.tan(new_angle) - np.tan(old_angle)) * run <= noise_m

    for c in range(n_columns):
        last = np.full(3, np.nan)
        anchor = np.full(3, np.nan)
        for i in range(n_top - 1):
            in_ground_rows = i < n_ground - 1
            continues = ground[i, c]
            if not in_ground_rows and not continues:
                break  # above the ground rows runs only continue
            if not flat[i, c]:
                continue  # only flat pairs can be accepted
            baseline_run = math.hypot(last[0] - anchor[0], last[1] - anchor[1])
            slope = math.atan2(last[2] - anchor[2], baseline_run) if baseline_run >= min_baseline_m else np.nan
            slope_known = not math.isnan(slope)
            pair_angle, pair_run = angle[i, c], run_m[i, c]
            accept = not slope_known or gentle(pair_angle, slope, pair_run)
            if in_ground_rows and not continues:
                if math.isnan(last[0]):
                    accept = at_level[i, c]
                else:  # from the last ground point, across an object
                    across_z = points[i, c, 2] - last[2]
                    across_run = math.hypot(points[i, c, 0] - last[0], points[i, c, 1] - last[1])
                    bridge = math.atan2(across_z, across_run)
                    accept = (
                        abs(across_z) <= tan_threshold * across_run + noise_m
                        and (not slope_known or gentle(bridge, slope, across_run))
                        and gentle(pair_angle, bridge, pair_run)
                    )
            if not accept:
                continue
            # support: the upper point lies on the line of the run below (within the margin), or a
            # new run lies at the scan's ground level
            if continues and slope_known:
                upper_supported = abs(tan_angle[i, c] - np.tan(slope)) * pair_run <= support_margin_m
            else:
                upper_supported = at_level[i + 1, c]
            if upper_supported:
                supported[i + 1, c] = True
            if not continues and at_level[i, c]:
                supported[i, c] = True
            ground[i, c] = True
            ground[i + 1, c] = True
            # the anchor moves up to the lower point once that is far enough behind the new last point
            if not continues or math.isnan(anchor[0]) or pair_run >= min_baseline_m:
                anchor[:] = points[i, c]
            last[:] = points[i + 1, c]


def _check_surface(
    ground: np.ndarray, points: np.ndarray, azimuth_resolution_rad: float, config: SegmentationConfig
) -> None:
    """Unmark (in place) ground cells that stand above the ground surface fitted below them.

    Row by row upwards, each ground cell of row i is compared with the accepted ground of rows < i
    in its azimuth sector (``ground_surface_sector_deg`` wide, centred on its column): a line
    z = z0 + slope (d - d0) fitted to the sector's ground on the ``ground_surface_rows`` rows below
    (d: horizontal distance, d0 their mean distance), and the curvature c of a parabola fitted to all
    the sector's ground below (z'' = 2c). A surface with that curvature departs from its tangent at d0
    by |c| (d - d0)^2, so the cell stays ground when its height above the line is at most

        ground_surface_margin_m + d * tan(ground_surface_range_slope_deg) + |c| (d - d0)^2.

    Only heights above the line count (objects stand on the ground; a crest drops away below it).
    Cells whose sector below holds fewer than three rows of ground (the parabola is undetermined)
    or whose local rows span under a metre keep their mark. ``points``: (n_top, C, 3) level frame.
    The walk over the rows is the compiled :func:`_surface_kernel`.
    """
    n_top = points.shape[0]
    rows_with_ground = np.flatnonzero(ground[:n_top].any(axis=1))
    if rows_with_ground.size == 0:
        return
    half_width = int(round(np.deg2rad(config.ground_surface_sector_deg) / 2.0 / azimuth_resolution_rad))
    _surface_kernel(
        ground,
        np.hypot(points[..., 0], points[..., 1]),
        np.ascontiguousarray(points[..., 2]),
        int(rows_with_ground[-1]) + 1,
        min(half_width, (points.shape[1] - 1) // 2),
        config.ground_surface_rows,
        config.ground_surface_margin_m,
        float(np.tan(np.deg2rad(config.ground_surface_range_slope_deg))),
    )


@lazy_njit
def _surface_kernel(
    ground: np.ndarray,
    distance: np.ndarray,
    height: np.ndarray,
    n_walked: int,
    half_width: int,
    n_local_rows: int,
    margin_m: float,
    tan_range: float,
) -> None:
    """The walk of :func:`_check_surface` over rows ``0 .. n_walked-1``, unmarking ``ground`` (R, C)
    in place. ``distance``, ``height``: (n_top, C) horizontal distance and level-frame height.

    ``prefix[i]`` (C, 8) holds, per column, the sums over the accepted ground of rows 0 .. i-1 of
    the moments 1, d, d^2, d^3, d^4, z, z d, z d^2; a sector's sums are differences of a running
    sum along the columns (the sector wraps around the seam).
    """
    n_columns = ground.shape[1]
    width = 2 * half_width + 1
    prefix = np.zeros((n_walked + 1, n_columns, 8))
    sector_rows = np.zeros(n_columns, np.int64)  # rows holding ground in each column's sector
    running = np.zeros((n_columns + width, 16))  # running[k]: sum of the first k padded columns
    for i in range(n_walked):
        if i >= 3:
            first_local = max(i - n_local_rows, 0)
            for k in range(n_columns + width - 1):
                column = (k - half_width) % n_columns
                for m in range(8):
                    running[k + 1, m] = running[k, m] + prefix[i, column, m]
                    running[k + 1, 8 + m] = running[k, 8 + m] + (prefix[i, column, m] - prefix[first_local, column, m])
            for c in range(n_columns):
                if not ground[i, c] or sector_rows[c] < 3:
                    continue
                a, b = running[c + width], running[c]  # the sector's moments below, then local
                s0, s1, s2, s3, s4 = a[0] - b[0], a[1] - b[1], a[2] - b[2], a[3] - b[3], a[4] - b[4]
                t0, t1, t2 = a[5] - b[5], a[6] - b[6], a[7] - b[7]
                n, sum_d, sum_dd, sum_z, sum_zd = a[8] - b[8], a[9] - b[9], a[10] - b[10], a[13] - b[13], a[14] - b[14]
                # least-squares parabola z = a + b d + c d^2: its c by Cramer's rule on the normal equations
                determinant = s0 * (s2 * s4 - s3 * s3) - s1 * (s1 * s4 - s3 * s2) + s2 * (s1 * s3 - s2 * s2)
                if n < 3 or not abs(determinant) > 1e-9 * s0 * s2 * s4:
                    continue  # undetermined: the mark stays
                d0, z0 = sum_d / n, sum_z / n
                spread = sum_dd - n * d0**2
                if not spread >= n * 1.0:
                    continue  # the local rows span under a metre
                numerator = s0 * (s2 * t2 - s3 * t1) - s1 * (s1 * t2 - s2 * t1) + t0 * (s1 * s3 - s2 * s2)
                slope = (sum_zd - n * d0 * z0) / spread
                offset = distance[i, c] - d0
                above_m = height[i, c] - (z0 + slope * offset)
                tolerance = margin_m + distance[i, c] * tan_range + abs(numerator / determinant) * offset**2
                if not above_m <= tolerance:
                    ground[i, c] = False
        for c in range(n_columns):
            for m in range(8):
                prefix[i + 1, c, m] = prefix[i, c, m]
            if ground[i, c]:
                d, z = distance[i, c], height[i, c]
                moments = (1.0, d, d * d, d**3, d**4, z, z * d, z * d * d)
                for m in range(8):
                    prefix[i + 1, c, m] += moments[m]
        count = 0  # ground columns in the window of column c, slid along the row (wrapping)
        for j in range(-half_width, half_width + 1):
            count += int(ground[i, j % n_columns])
        for c in range(n_columns):
            if count > 0:
                sector_rows[c] += 1
            count += int(ground[i, (c + half_width + 1) % n_columns]) - int(ground[i, (c - half_width) % n_columns])


def _release_contacts(image: RangeImage, ground: np.ndarray, supported: np.ndarray, config: SegmentationConfig) -> None:
    """Unmark (in place) unsupported ground on the same surface as the object cell above it."""
    rows_with_ground = np.flatnonzero(ground.any(axis=1))
    if rows_with_ground.size == 0:
        return
    alpha = np.abs(np.diff(image.row_elevation_rad))  # (R-1,) elevation step to the row above
    # each row's sine and cosine, as NumPy scalars (the bits the array version of the test used)
    sin_cos = np.array([(np.sin(a), np.cos(a)) for a in alpha]).reshape(-1, 2)
    top = min(int(rows_with_ground[-1]), ground.shape[0] - 2)
    _release_kernel(ground, supported, image.range_m, sin_cos, float(np.tan(np.deg2rad(config.cluster_angle_deg))), top)


@lazy_njit
def _release_kernel(
    ground: np.ndarray, supported: np.ndarray, range_m: np.ndarray, sin_cos: np.ndarray, tan_theta: float, top: int
) -> None:
    """The release of :func:`_release_contacts`, column by column from row ``top`` down, so that a
    released cell can release the one below. ``ground``, ``supported``, ``range_m`` (R, C) (NaN
    where empty); ``sin_cos`` (R-1, 2) of the elevation step from each row to the next."""
    for c in range(ground.shape[1]):
        for i in range(top, -1, -1):
            if not ground[i, c] or supported[i, c] or ground[i + 1, c] or np.isnan(range_m[i + 1, c]):
                continue  # released only: unsupported ground below an object cell
            near = min(range_m[i, c], range_m[i + 1, c])
            far = max(range_m[i, c], range_m[i + 1, c])
            if near * sin_cos[i, 0] > tan_theta * (
                far - near * sin_cos[i, 1]
            ):  # beta > theta (clustering's module doc)
                ground[i, c] = False
