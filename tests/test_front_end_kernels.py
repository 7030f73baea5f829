"""The compiled front-end kernels (numba) against the NumPy/SciPy/Python code they replaced, on
simulated scans: the same cluster labels, outliers and features, bit for bit.

The references below are the previous implementations, kept here as oracles: the clusters as
connected components of a sparse graph (``scipy.sparse.csgraph``), the greedy feature pick as a
Python loop over the sorted candidates.
"""

import numpy as np
import pytest
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from lidar3d.config import Config
from lidar3d.features import run_front_end
from lidar3d.features.selection import _sorted_by_section, suppression_spans
from lidar3d.features.smoothness import compute_smoothness
from lidar3d.segmentation import cluster_cells, mark_ground, project_scan
from lidar3d.segmentation.clustering import joins_by_beta
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


def _reference_picks(segmentation, smoothness, config):
    """The greedy pick as it was, in Python: (sharp, less sharp, flat) indices."""
    n = len(segmentation)
    curvature, section = smoothness.curvature, smoothness.section
    n_sections = segmentation.ring_start.shape[0] * config.sections_per_ring
    edge_candidate = smoothness.pickable & ~segmentation.is_ground & (curvature > smoothness.edge_threshold)
    flat_candidate = smoothness.pickable & segmentation.is_ground & (curvature < config.planar_threshold)
    lo, hi = suppression_spans(segmentation, config.curvature_half_window, config.neighbour_max_column_gap)
    edges, edge_lo, edge_hi, edge_bounds = (
        a.tolist() for a in _sorted_by_section(edge_candidate, section, -curvature, n_sections, lo, hi)
    )
    flats, flat_lo, flat_hi, flat_bounds = (
        a.tolist() for a in _sorted_by_section(flat_candidate, section, curvature, n_sections, lo, hi)
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
