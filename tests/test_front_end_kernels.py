"""The compiled front-end kernels (numba) against the NumPy/SciPy/Python code they replaced, on
simulated scans: the same range image, ground, cluster labels, outliers and features, bit for bit.

The references below are the previous implementations, kept here as oracles: the range image's
cells filled by NumPy fancy indexing, the ground walk as row-by-row array work over all columns at
once, the clusters as connected components of a sparse graph (``scipy.sparse.csgraph``), the
curvature and rejection flags as array expressions, the less-flat voxels by ``np.unique``, the
greedy feature pick as a Python loop over the candidates sorted by ``np.lexsort``.
"""

import dataclasses

import numpy as np
import pytest
from frontend_sim import joins_by_beta, suppression_spans
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from lidar3d.config import Config
from lidar3d.features import run_front_end
from lidar3d.features.selection import voxel_centroids_per_ring
from lidar3d.features.smoothness import compute_smoothness
from lidar3d.segmentation import cluster_cells, ground, mark_ground, project_scan
from lidar3d.sensors import SensorModel
from lidar3d.sim import Simulation


def _reference_cluster_cells(image, ground_mask, config):
    """``cluster_cells`` as it was: the components of the joining graph by scipy."""
    n_rows, n_columns = image.shape
    candidate = image.occupied & ~ground_mask
    range_m = np.where(candidate, image.range_m, np.nan)
    tan_theta = np.tan(np.deg2rad(config.cluster_angle_deg))
    node = np.arange(n_rows * n_columns).reshape(n_rows, n_columns)
    right_m = np.roll(range_m, -1, axis=1)
    horizontal = joins_by_beta(
        np.fmin(range_m, right_m), np.fmax(range_m, right_m), image.azimuth_resolution_rad, tan_theta
    )
    up_m = range_m[1:]
    alpha_rows = np.abs(np.diff(image.row_elevation_rad))[:, None]
    vertical = joins_by_beta(np.fmin(range_m[:-1], up_m), np.fmax(range_m[:-1], up_m), alpha_rows, tan_theta)
    horizontal &= candidate & np.roll(candidate, -1, axis=1)
    vertical &= candidate[:-1] & candidate[1:]
    source = np.concatenate([node[horizontal], node[:-1][vertical]])
    target = np.concatenate([np.roll(node, -1, axis=1)[horizontal], node[1:][vertical]])
    n_nodes = n_rows * n_columns
    graph = csr_matrix((np.ones(source.size, dtype=np.int8), (source, target)), shape=(n_nodes, n_nodes))
    _, component = connected_components(graph, directed=False)
    cells = np.flatnonzero(candidate.ravel())
    label = np.full(n_nodes, -1, dtype=np.int32)
    outlier = np.zeros(n_nodes, dtype=bool)
    if cells.size == 0:
        return label.reshape(n_rows, n_columns), outlier.reshape(n_rows, n_columns)
    cell_component = component[cells]
    present = np.zeros(n_nodes, dtype=bool)
    present[cell_component] = True
    dense_of_component = np.cumsum(present) - 1
    dense = dense_of_component[cell_component]
    n_clusters = int(dense_of_component[-1]) + 1
    size = np.bincount(dense, minlength=n_clusters)
    touched = np.zeros((n_clusters, n_rows), dtype=bool)
    touched[dense, cells // n_columns] = True
    n_rings = touched.sum(axis=1)
    keep = (size >= config.min_cluster_points) | (
        (size >= config.min_cluster_points_multi_ring) & (n_rings >= config.min_cluster_rings)
    )
    new_id = np.full(n_clusters, -1, dtype=np.int32)
    new_id[keep] = np.arange(int(keep.sum()), dtype=np.int32)
    label[cells] = new_id[dense]
    outlier[cells] = ~keep[dense]
    return label.reshape(n_rows, n_columns), outlier.reshape(n_rows, n_columns)


def _reference_image_cells(scan, sensor: SensorModel, config):
    """The cells of ``project_scan``'s image as they were filled: (point_index, points, range_m)."""
    range_m = np.sqrt(np.einsum("ij,ij->i", scan.points, scan.points))  # as project_scan computes it
    rows = np.asarray(scan.ring, dtype=np.int64)  # the simulator's rings are the image rows
    valid = (range_m >= config.sensor.min_range_m) & (range_m <= sensor.max_range_m)
    index = np.flatnonzero(valid)
    resolution_rad = np.deg2rad(sensor.azimuth_resolution_deg)
    columns = np.rint(np.arctan2(scan.points[index, 1], scan.points[index, 0]) / resolution_rad).astype(np.int64)
    columns = (columns + sensor.n_columns // 2) % sensor.n_columns
    flat_index = np.full(sensor.n_rings * sensor.n_columns, -1, dtype=np.int64)
    flat_index[rows[index] * sensor.n_columns + columns] = index  # repeated cells: the last point stays
    point_index = flat_index.reshape(sensor.n_rings, sensor.n_columns)
    occupied = point_index >= 0
    points = np.full((sensor.n_rings, sensor.n_columns, 3), np.nan)
    points[occupied] = scan.points[point_index[occupied]]
    image_range = np.full((sensor.n_rings, sensor.n_columns), np.nan)
    image_range[occupied] = range_m[point_index[occupied]]
    return point_index, points, image_range


def _reference_walk(
    ground_mask,
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
    min_baseline_m,
    support_margin_m,
):
    """The ground's column walk as it was: row by row, every column at once (marks in place)."""

    def gentle(new_angle, old_angle, run):
        bend = np.abs(new_angle - old_angle) <= max_change
        return bend | (np.abs(np.tan(new_angle) - np.tan(old_angle)) * run <= noise_m)

    n_columns = ground_mask.shape[1]
    last_ground = np.full((n_columns, 3), np.nan)
    anchor = np.full((n_columns, 3), np.nan)
    with np.errstate(invalid="ignore"):
        for i in range(points.shape[0] - 1):
            in_ground_rows = i < n_ground - 1
            if not in_ground_rows and not ground_mask[i].any():
                break
            columns = np.flatnonzero(flat[i] if in_ground_rows else flat[i] & ground_mask[i])
            if columns.size == 0:
                continue
            last, start = last_ground[columns], anchor[columns]
            baseline = last - start
            baseline_run = np.hypot(baseline[:, 0], baseline[:, 1])
            slope = np.where(baseline_run >= min_baseline_m, np.arctan2(baseline[:, 2], baseline_run), np.nan)
            slope_known = ~np.isnan(slope)
            continues = ground_mask[i, columns]
            pair_angle, pair_run = angle[i, columns], run_m[i, columns]
            smooth = ~slope_known | gentle(pair_angle, slope, pair_run)
            if in_ground_rows:
                across = points[i, columns] - last
                across_run = np.hypot(across[:, 0], across[:, 1])
                bridge = np.arctan2(across[:, 2], across_run)
                reachable = (
                    (np.abs(across[:, 2]) <= tan_threshold * across_run + noise_m)
                    & (~slope_known | gentle(bridge, slope, across_run))
                    & gentle(pair_angle, bridge, pair_run)
                )
                has_ground_below = ~np.isnan(last[:, 0])
                accept = np.where(continues, smooth, np.where(has_ground_below, reachable, at_level[i, columns]))
            else:
                accept = smooth
            bend_m = np.abs(tan_angle[i, columns] - np.tan(slope)) * pair_run
            upper_supported = np.where(continues & slope_known, bend_m <= support_margin_m, at_level[i + 1, columns])
            supported[i + 1, columns] |= accept & upper_supported
            supported[i, columns] |= accept & ~continues & at_level[i, columns]
            accepted = columns[accept]
            ground_mask[i, accepted] = True
            ground_mask[i + 1, accepted] = True
            move = accept & (~continues | np.isnan(start[:, 0]) | (pair_run >= min_baseline_m))
            anchor[columns[move]] = points[i, columns[move]]
            last_ground[accepted] = points[i + 1, accepted]


def _reference_smoothness(segmentation, config):
    """Curvature, in-section, section and pickable flags as array work: (curvature, in_section,
    section, pickable)."""
    range_m, row, w = segmentation.range_m, segmentation.row, config.curvature_half_window
    n = range_m.shape[0]
    index = np.arange(n)
    first, stop = segmentation.ring_start[row], segmentation.ring_end[row]
    in_section = (index - first >= w) & (stop - 1 - index >= w)
    prefix = np.concatenate(([0.0], np.cumsum(range_m)))
    window_sum = prefix[np.minimum(index + w + 1, n)] - prefix[np.maximum(index - w, 0)]
    curvature = np.where(in_section, (window_sum - (2 * w + 1) * range_m) ** 2, 0.0)
    span = np.maximum(stop - first - 2 * w, 1)
    sections = config.sections_per_ring
    section = np.where(in_section, row * sections + ((index - first - w) * sections) // span, -1)
    pair_ok = (row[1:] == row[:-1]) & (np.abs(np.diff(segmentation.column)) < config.neighbour_max_column_gap)
    step = np.diff(range_m)
    far_then_near = np.zeros(n, dtype=np.int64)
    near_then_far = np.zeros(n, dtype=np.int64)
    far_then_near[:-1] = pair_ok & (-step > config.occlusion_depth_m)
    near_then_far[:-1] = pair_ok & (step > config.occlusion_depth_m)
    count_ftn = np.concatenate(([0], np.cumsum(far_then_near)))
    count_ntf = np.concatenate(([0], np.cumsum(near_then_far)))
    occluded = (count_ftn[np.minimum(index + w + 1, n)] - count_ftn[index]) > 0
    occluded |= (count_ntf[index] - count_ntf[np.maximum(index - w - 1, 0)]) > 0
    jump_prev = np.full(n, np.inf)
    jump_next = np.full(n, np.inf)
    jump_prev[1:] = np.abs(step)
    jump_next[:-1] = np.abs(step)
    limit = config.parallel_beam_ratio * range_m
    parallel = (jump_prev > limit) & (jump_next > limit)
    return curvature, in_section, section, in_section & ~occluded & ~parallel


def _reference_voxel_centroids(points, ring, time_offset_s, leaf_m):
    """Per-ring voxel centroids by ``np.unique`` and ``np.bincount``: (points, ring, time)."""
    voxel = np.floor(points / leaf_m).astype(np.int64) + (1 << 16)
    key = (((ring.astype(np.int64) << 17 | voxel[:, 0]) << 17 | voxel[:, 1]) << 17) | voxel[:, 2]
    _, group = np.unique(key, return_inverse=True)
    count = np.bincount(group).astype(np.float64)
    centroid = np.stack([np.bincount(group, weights=points[:, k]) for k in range(3)], axis=1) / count[:, None]
    group_ring = np.zeros(count.shape[0], dtype=np.uint16)
    group_ring[group] = ring
    return centroid, group_ring, np.bincount(group, weights=time_offset_s) / count


def _reference_sorted_by_section(candidate, section, key, n_sections, lo, hi):
    """Candidates sorted by (section, key) by ``np.lexsort``: indices, suppression spans, section starts."""
    index = np.flatnonzero(candidate)
    index = index[np.lexsort((key[index], section[index]))]
    bounds = np.searchsorted(section[index], np.arange(n_sections + 1))
    return index, lo[index], hi[index], bounds


def _reference_release(image, ground_mask, supported, config):
    """The release of ground contacts as it was: row by row from the top, every column at once."""
    tan_theta = np.tan(np.deg2rad(config.cluster_angle_deg))
    alpha = np.abs(np.diff(image.row_elevation_rad))
    rows_with_ground = np.flatnonzero(ground_mask.any(axis=1))
    top = min(int(rows_with_ground[-1]), ground_mask.shape[0] - 2) if rows_with_ground.size else -1
    for i in range(top, -1, -1):
        above_is_object = image.occupied[i + 1] & ~ground_mask[i + 1]
        near = np.fmin(image.range_m[i], image.range_m[i + 1])
        far = np.fmax(image.range_m[i], image.range_m[i + 1])
        ground_mask[i] &= ~(above_is_object & ~supported[i] & joins_by_beta(near, far, alpha[i], tan_theta))


def _reference_check_surface(ground_mask, points, azimuth_resolution_rad, config):
    """The surface check as it was: row by row, every column at once, the sector sums by cumsum."""
    n_top, n_columns = points.shape[:2]
    half_width = int(round(np.deg2rad(config.ground_surface_sector_deg) / 2.0 / azimuth_resolution_rad))
    half_width = min(half_width, (n_columns - 1) // 2)

    def sector_sum(values):
        padded = np.concatenate([values[n_columns - half_width :], values, values[:half_width]])
        cumulative = np.concatenate([np.zeros((1, values.shape[1])), np.cumsum(padded, axis=0)])
        return cumulative[2 * half_width + 1 :] - cumulative[:n_columns]

    distance = np.hypot(points[..., 0], points[..., 1])
    height = points[..., 2]
    tan_range = np.tan(np.deg2rad(config.ground_surface_range_slope_deg))
    prefix = np.zeros((n_top + 1, n_columns, 8))
    sector_rows = np.zeros(n_columns)
    rows_with_ground = np.flatnonzero(ground_mask[:n_top].any(axis=1))
    for i in range(int(rows_with_ground[-1]) + 1 if rows_with_ground.size else 0):
        on_row = ground_mask[i]
        if i >= 3 and on_row.any():
            first_local = max(i - config.ground_surface_rows, 0)
            sector = sector_sum(np.concatenate([prefix[i], prefix[i] - prefix[first_local]], axis=1))
            columns = np.flatnonzero(on_row & (sector_rows >= 3))
            s0, s1, s2, s3, s4, t0, t1, t2 = sector[columns, :8].T
            local = sector[columns, 8:]
            determinant = s0 * (s2 * s4 - s3 * s3) - s1 * (s1 * s4 - s3 * s2) + s2 * (s1 * s3 - s2 * s2)
            numerator = s0 * (s2 * t2 - s3 * t1) - s1 * (s1 * t2 - s2 * t1) + t0 * (s1 * s3 - s2 * s2)
            n, sum_d, sum_dd, sum_z, sum_zd = local[:, 0], local[:, 1], local[:, 2], local[:, 5], local[:, 6]
            with np.errstate(invalid="ignore", divide="ignore"):
                d0, z0 = sum_d / n, sum_z / n
                spread = sum_dd - n * d0**2
                offset = distance[i, columns] - d0
                above_m = height[i, columns] - (z0 + (sum_zd - n * d0 * z0) / spread * offset)
                tolerance = (
                    config.ground_surface_margin_m
                    + distance[i, columns] * tan_range
                    + np.abs(numerator / determinant) * offset**2
                )
                fitted = (np.abs(determinant) > 1e-9 * s0 * s2 * s4) & (n >= 3) & (spread >= n * 1.0)
                on_row[columns[fitted & ~(above_m <= tolerance)]] = False
        d, z = np.where(on_row, distance[i], 0.0), np.where(on_row, height[i], 0.0)
        one = on_row.astype(np.float64)
        prefix[i + 1] = prefix[i] + np.stack([one, d, d**2, d**3, d**4, z, z * d, z * d**2], axis=1)
        sector_rows += sector_sum(one[:, None])[:, 0] > 0


def _reference_picks(segmentation, smoothness, config):
    """The greedy pick as it was, in Python, over the precomputed suppression spans: (sharp, less
    sharp, flat) indices."""
    n = len(segmentation)
    curvature, section = smoothness.curvature, smoothness.section
    n_sections = segmentation.ring_start.shape[0] * config.sections_per_ring
    edge_candidate = smoothness.pickable & ~segmentation.is_coarse_ground & (curvature > smoothness.edge_threshold)
    flat_candidate = smoothness.pickable & segmentation.is_coarse_ground & (curvature < config.planar_threshold)
    lo, hi = suppression_spans(segmentation, config.curvature_half_window, config.neighbour_max_column_gap)
    edges, edge_lo, edge_hi, edge_bounds = (
        a.tolist() for a in _reference_sorted_by_section(edge_candidate, section, -curvature, n_sections, lo, hi)
    )
    flats, flat_lo, flat_hi, flat_bounds = (
        a.tolist() for a in _reference_sorted_by_section(flat_candidate, section, curvature, n_sections, lo, hi)
    )
    picked = bytearray(n)
    ones = b"\x01" * (2 * config.curvature_half_window + 1)
    sharp, less_sharp, flat = [], [], []
    for s in range(n_sections):
        count = 0
        for k in range(edge_bounds[s], edge_bounds[s + 1]):
            if count >= config.less_sharp_per_section:
                break
            i = edges[k]
            if picked[i]:
                continue
            count += 1
            if count <= config.sharp_per_section:
                sharp.append(i)
            less_sharp.append(i)
            picked[edge_lo[k] : edge_hi[k]] = ones[: edge_hi[k] - edge_lo[k]]
        count = 0
        for k in range(flat_bounds[s], flat_bounds[s + 1]):
            if count >= config.flat_per_section:
                break
            i = flats[k]
            if picked[i]:
                continue
            count += 1
            flat.append(i)
            picked[flat_lo[k] : flat_hi[k]] = ones[: flat_hi[k] - flat_lo[k]]
    return sharp, less_sharp, flat


@pytest.fixture(scope="module")
def scans():
    """Scans of a street with parked and moving cars and of the loop's buildings and poles."""
    picked = []
    for scenario in ("city_traffic", "loop"):
        sweeps = list(Simulation(scenario, seed=0, duration_s=1.0).scans())
        picked += [sweeps[i].scan for i in (0, 4, 9)]
    return picked


def test_range_image_cells_are_those_of_the_fancy_indexing(scans):
    config = Config()
    for scan in scans:
        image = project_scan(scan, config.sensor, config.segmentation)
        point_index, points, range_m = _reference_image_cells(scan, config.sensor.resolved_model, config)
        assert np.count_nonzero(point_index >= 0) > 10_000
        np.testing.assert_array_equal(image.point_index, point_index)
        np.testing.assert_array_equal(image.points, points)
        np.testing.assert_array_equal(image.range_m, range_m)


def test_ground_walk_is_that_of_the_row_by_row_array_walk(scans, monkeypatch):
    """Every call of the compiled walk during ``mark_ground`` marks what the array walk marks."""
    compiled = ground._walk_columns
    n_calls = []

    def both(ground_mask, supported, *rest):
        reference_ground, reference_supported = ground_mask.copy(), supported.copy()
        compiled(ground_mask, supported, *rest)
        _reference_walk(reference_ground, reference_supported, *rest)
        np.testing.assert_array_equal(ground_mask, reference_ground)
        np.testing.assert_array_equal(supported, reference_supported)
        n_calls.append(int(ground_mask.sum()))

    monkeypatch.setattr(ground, "_walk_columns", both)
    config = Config()
    for scan in scans:
        mark_ground(project_scan(scan, config.sensor, config.segmentation), config.segmentation, config.sensor)
    assert len(n_calls) == len(scans) and min(n_calls) > 5_000  # each scan walked, much ground found


def _unmarked_as_by_reference(monkeypatch, scans, name, reference, mask_arg, segmentation_config):
    """Run ``mark_ground`` on ``scans`` with ``ground.<name>`` checked against ``reference`` (the same
    arguments, the mask the ``mask_arg``-th, unmarked in place) at every call; the cells each call
    unmarked."""
    compiled = getattr(ground, name)
    unmarked = []

    def both(*args):
        mask = args[mask_arg]
        expected = mask.copy()
        before = int(mask.sum())
        compiled(*args)
        reference(*args[:mask_arg], expected, *args[mask_arg + 1 :])
        np.testing.assert_array_equal(mask, expected)
        unmarked.append(before - int(mask.sum()))

    monkeypatch.setattr(ground, name, both)
    sensor = Config().sensor
    for scan in scans:
        mark_ground(project_scan(scan, sensor, segmentation_config), segmentation_config, sensor)
    return unmarked


def test_ground_contacts_are_released_as_by_the_row_by_row_array_walk(scans, monkeypatch):
    """Every release of ground contacts during ``mark_ground`` unmarks what the array version does."""
    released = _unmarked_as_by_reference(
        monkeypatch, scans, "_release_contacts", _reference_release, 1, Config().segmentation
    )
    assert len(released) == len(scans) and sum(released) > 0  # contacts were released


def test_ground_surface_check_is_that_of_the_row_by_row_array_check(scans, monkeypatch):
    """Every surface check during ``mark_ground`` (check on) unmarks what the array version does."""
    segmentation = dataclasses.replace(Config().segmentation, ground_surface_sector_deg=2.0)
    lifted = _unmarked_as_by_reference(monkeypatch, scans, "_check_surface", _reference_check_surface, 0, segmentation)
    assert len(lifted) == len(scans) and sum(lifted) > 0  # cells were taken out of the ground


def test_smoothness_is_that_of_the_array_expressions(scans):
    config = Config()
    for scan in scans:
        segmentation = run_front_end(scan, config).segmentation
        smoothness = compute_smoothness(segmentation, config.features)
        curvature, in_section, section, pickable = _reference_smoothness(segmentation, config.features)
        assert pickable.sum() > 5_000
        np.testing.assert_array_equal(smoothness.curvature, curvature)
        np.testing.assert_array_equal(smoothness.in_section, in_section)
        np.testing.assert_array_equal(smoothness.section, section)
        np.testing.assert_array_equal(smoothness.pickable, pickable)


def test_voxel_centroids_are_those_of_unique_and_bincount(scans):
    """Ring-sorted (as the segmented cloud is: a hash table per ring) and shuffled (one table)."""
    segmentation = run_front_end(scans[0], Config()).segmentation
    points, ring, time_offset_s = segmentation.points, segmentation.row, segmentation.time_offset_s
    shuffle = np.random.default_rng(0).permutation(len(points))
    for order in (np.arange(len(points)), shuffle):
        cloud = voxel_centroids_per_ring(points[order], ring[order], time_offset_s[order], 0.2)
        centroid, group_ring, mean_time = _reference_voxel_centroids(
            points[order], ring[order], time_offset_s[order], 0.2
        )
        assert 1_000 < len(centroid) < len(points) // 2  # voxels with several points
        np.testing.assert_array_equal(cloud.points, centroid)
        np.testing.assert_array_equal(cloud.ring, group_ring)
        np.testing.assert_array_equal(cloud.time_offset_s, mean_time)


def test_clusters_are_those_of_the_sparse_graph_components(scans):
    config = Config()
    n_clusters = 0
    for scan in scans:
        image = project_scan(scan, config.sensor, config.segmentation)
        ground = mark_ground(image, config.segmentation, config.sensor)
        label, outlier = cluster_cells(image, ground, config.segmentation)
        reference_label, reference_outlier = _reference_cluster_cells(image, ground, config.segmentation)
        np.testing.assert_array_equal(label, reference_label)
        np.testing.assert_array_equal(outlier, reference_outlier)
        n_clusters += int(label.max()) + 1
        # no ground at all (every occupied cell a candidate: one big wrap-around component), no cell
        for mask in (np.zeros_like(ground), image.occupied):
            label, outlier = cluster_cells(image, mask, config.segmentation)
            reference_label, reference_outlier = _reference_cluster_cells(image, mask, config.segmentation)
            np.testing.assert_array_equal(label, reference_label)
            np.testing.assert_array_equal(outlier, reference_outlier)
    assert n_clusters > 10 * len(scans)  # the scans hold many objects


def test_feature_picks_are_those_of_the_python_loop(scans):
    config = Config()
    for scan in scans:
        front = run_front_end(scan, config)
        segmentation, features = front.segmentation, front.features
        smoothness = compute_smoothness(segmentation, config.features)
        sharp, less_sharp, flat = _reference_picks(segmentation, smoothness, config.features)
        assert len(sharp) > 10 and len(flat) > 10
        for cloud, index in ((features.sharp, sharp), (features.less_sharp, less_sharp), (features.flat, flat)):
            np.testing.assert_array_equal(cloud.points, segmentation.points[np.asarray(index, dtype=np.int64)])
            np.testing.assert_array_equal(cloud.ring, segmentation.row[np.asarray(index, dtype=np.int64)])
