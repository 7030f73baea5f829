"""Selection of edge and planar features per ring section (LeGO-LOAM featureAssociation, FA:680-784).

In every section of every ring (``sections_per_ring`` equal point-count chunks of the ring's
pickable span), in ring and section order:

* edges: pickable non-ground points with curvature above the scan's edge threshold (at least
  ``edge_threshold``, higher where the scan's range noise is, see
  :mod:`~lidar3d.features.smoothness`), highest first; the
  first ``sharp_per_section`` picks are sharp, the first ``less_sharp_per_section`` less sharp;
* flats: pickable ground points with curvature below ``planar_threshold``, lowest first, at most
  ``flat_per_section``;
* each pick suppresses its w = ``curvature_half_window`` neighbours on either side, stopping at a
  column gap wider than ``neighbour_max_column_gap`` (or at the ring's end), for every later pick;
* less flat: every section point that is not less sharp, voxel-downsampled per ring
  (``less_flat_voxel_m``, voxel centroids as PCL's VoxelGrid gives them).

The candidates are filtered once for the whole scan and sorted by section and curvature (a stable
bucket sort by section, then each section by curvature), and the sequential pick (which must stay
sequential: each pick changes what later candidates may do) walks only the sorted candidates of each
section, stopping at the section's quota, marking each pick's suppression span as it goes; the
less-flat voxels are grouped with a small hash table per ring. All of it runs in compiled kernels
(numba, cached on disk) whose results are those of the array and Python code they replaced
(``tests/test_front_end_kernels.py`` keeps that code as the oracle). A pick's span reaches up to
``curvature_half_window`` points either side, stopping before the first pair of consecutive points
more than ``neighbour_max_column_gap`` columns apart or in different rings (FA:720-735).
"""

from __future__ import annotations

import numpy as np

from lidar3d.config import FeatureConfig
from lidar3d.features.records import FeatureCloud, FeatureSet, Smoothness
from lidar3d.jit import lazy_njit
from lidar3d.segmentation.segment import Segmentation

__all__ = ["select_features", "voxel_centroids_per_ring"]


def voxel_centroids_per_ring(
    points: np.ndarray, ring: np.ndarray, time_offset_s: np.ndarray, leaf_m: float
) -> FeatureCloud:
    """Centroid (and mean time) of the points of each (ring, voxel) cell of edge ``leaf_m``.

    ``points`` (N, 3), ``ring`` (N,), ``time_offset_s`` (N,); the cells come out in increasing
    (ring, voxel) key order, their sums in point order. Points sorted by ring (as the segmented
    cloud is) are grouped ring by ring, which is faster (a hash table per ring stays in cache).
    """
    if points.shape[0] == 0:
        return FeatureCloud.empty()
    if leaf_m <= 0:
        return FeatureCloud(points=points, ring=ring, time_offset_s=time_offset_s)
    # 17 bits per axis (+-13 km at 0.2 m) and the ring above them: one int64 key per (ring, voxel)
    voxel = np.floor(points / leaf_m).astype(np.int64) + (1 << 16)
    key = (((ring.astype(np.int64) << 17 | voxel[:, 0]) << 17 | voxel[:, 1]) << 17) | voxel[:, 2]
    ring_order = ring.astype(np.int64)
    if np.any(ring_order[1:] < ring_order[:-1]):  # rings not in runs: one run (one big hash table)
        run_start = np.array([0, key.size], dtype=np.int64)
    else:  # (K+1,): the start of each ring's run, then N
        run_start = np.flatnonzero(np.diff(ring_order, prepend=-1, append=-1))
    group, group_key, first_point = _group_keys(key, run_start)
    order = np.argsort(group_key)  # distinct keys: one order; NumPy's sort is the fast one here
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    centroid, mean_time = _group_means(rank[group], points, time_offset_s, order.size)
    return FeatureCloud(points=centroid, ring=ring[first_point[order]], time_offset_s=mean_time)


@lazy_njit
def _group_means(group: np.ndarray, points: np.ndarray, time_offset_s: np.ndarray, n_groups: int):
    """(G, 3) mean point and (G,) mean time of each group; ``group`` (N,) int64 in 0..G-1. The sums
    run in point order, as ``np.bincount`` adds them (the same bits)."""
    count = np.zeros(n_groups)
    means = np.zeros((n_groups, 3))
    mean_time = np.zeros(n_groups)
    for i in range(group.shape[0]):
        g = group[i]
        count[g] += 1.0
        means[g, 0] += points[i, 0]
        means[g, 1] += points[i, 1]
        means[g, 2] += points[i, 2]
        mean_time[g] += time_offset_s[i]
    for g in range(n_groups):
        means[g, 0] /= count[g]
        means[g, 1] /= count[g]
        means[g, 2] /= count[g]
        mean_time[g] /= count[g]
    return means, mean_time


@lazy_njit
def _group_keys(key: np.ndarray, run_start: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct values of ``key`` (N,) int64, numbered in order of first appearance.

    ``run_start`` (K+1,) int64 cuts the points into K runs that share no key (the rings of a
    ring-sorted cloud), so that each run is grouped with a small open-addressing hash table
    (linear probing, Fibonacci hashing) that stays in cache. Returns each point's group (N,), each
    group's key (G,) and its first point (G,).
    """
    n = key.shape[0]
    longest = 1
    for r in range(run_start.shape[0] - 1):
        longest = max(longest, run_start[r + 1] - run_start[r])
    bits = 1
    while (1 << bits) < 2 * longest:
        bits += 1
    mask = (1 << bits) - 1
    slot_key = np.empty(1 << bits, np.int64)
    slot_group = np.full(1 << bits, -1, np.int64)
    group_of_point = np.empty(n, np.int64)
    first_point = np.empty(n, np.int64)
    group_slot = np.empty(n, np.int64)
    n_groups = 0
    for r in range(run_start.shape[0] - 1):
        run_first_group = n_groups
        for i in range(run_start[r], run_start[r + 1]):
            slot = np.int64((np.uint64(key[i]) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits))
            while slot_group[slot] >= 0 and slot_key[slot] != key[i]:
                slot = (slot + 1) & mask
            if slot_group[slot] < 0:
                slot_key[slot] = key[i]
                slot_group[slot] = n_groups
                first_point[n_groups] = i
                group_slot[n_groups] = slot
                n_groups += 1
            group_of_point[i] = slot_group[slot]
        for g in range(run_first_group, n_groups):  # empty the table for the next run
            slot_group[group_slot[g]] = -1
    return group_of_point, key[first_point[:n_groups]], first_point[:n_groups]


@lazy_njit
def _by_section(candidate, section, key, n_sections):
    """Indices of the ``candidate`` points sorted by (section, key), ties in index order (as
    ``np.lexsort((key, section))``), and the (n_sections + 1,) start of each section among them."""
    bounds = np.zeros(n_sections + 1, np.int64)
    for i in range(candidate.shape[0]):
        if candidate[i]:
            bounds[section[i] + 1] += 1
    for s in range(n_sections):
        bounds[s + 1] += bounds[s]
    index = np.empty(bounds[n_sections], np.int64)
    filled = bounds[:-1].copy()
    for i in range(candidate.shape[0]):  # in index order: a stable bucket sort by section
        if candidate[i]:
            index[filled[section[i]]] = i
            filled[section[i]] += 1
    for s in range(n_sections):
        members = index[bounds[s] : bounds[s + 1]]
        if members.size > 1:
            index[bounds[s] : bounds[s + 1]] = members[np.argsort(key[members], kind="mergesort")]
    return index, bounds


@lazy_njit
def _pick(row, column, edges, edge_bounds, flats, flat_bounds, quota, half_window, max_column_gap):
    """The greedy pick, section by section: edges first, then flats; each pick marks as picked its
    suppression span (module doc), walked from the pick. ``quota``: (sharp, less
    sharp, flat) per section. Returns the indices of the sharp, less-sharp and flat picks, in pick
    order."""
    n_points = row.shape[0]
    n_sharp, n_less_sharp, n_flat = quota[0], quota[1], quota[2]
    picked = np.zeros(n_points, np.bool_)
    sharp = np.empty(edges.size, np.int64)
    less_sharp = np.empty(edges.size, np.int64)
    flat = np.empty(flats.size, np.int64)
    n_sharp_picked = n_less_sharp_picked = n_flat_picked = 0
    for s in range(edge_bounds.size - 1):
        for kind in range(2):  # 0: edges, 1: flats
            candidates, bounds = (edges, edge_bounds) if kind == 0 else (flats, flat_bounds)
            count = 0
            for k in range(bounds[s], bounds[s + 1]):
                if count >= (n_less_sharp if kind == 0 else n_flat):
                    break
                i = candidates[k]
                if picked[i]:
                    continue
                count += 1
                if kind == 1:
                    flat[n_flat_picked] = i
                    n_flat_picked += 1
                else:
                    if count <= n_sharp:
                        sharp[n_sharp_picked] = i
                        n_sharp_picked += 1
                    less_sharp[n_less_sharp_picked] = i
                    n_less_sharp_picked += 1
                picked[i] = True
                for step in (1, -1):  # up to half_window neighbours each way, while they stay linked
                    j = i
                    for _ in range(half_window):
                        a, b = min(j, j + step), max(j, j + step)
                        if b >= n_points or a < 0 or row[a] != row[b] or abs(column[b] - column[a]) > max_column_gap:
                            break
                        j += step
                        picked[j] = True
    return sharp[:n_sharp_picked], less_sharp[:n_less_sharp_picked], flat[:n_flat_picked]


def select_features(segmentation: Segmentation, smoothness: Smoothness, config: FeatureConfig) -> FeatureSet:
    """Sharp, less-sharp, flat and less-flat features of one scan, lidar frame (see module doc)."""
    scan = segmentation.scan
    n = len(segmentation)
    outliers = FeatureCloud(
        points=np.take(scan.points, segmentation.outlier_scan_index, axis=0),
        ring=segmentation.outlier_row,
        time_offset_s=scan.time_offset_s[segmentation.outlier_scan_index],
    )
    if n == 0:
        empty = FeatureCloud.empty()
        return FeatureSet(
            stamp_ns=scan.stamp_ns, sharp=empty, less_sharp=empty, flat=empty, less_flat=empty, outliers=outliers
        )
    curvature = smoothness.curvature
    section = smoothness.section
    n_sections = segmentation.ring_start.shape[0] * config.sections_per_ring
    edge_candidate = smoothness.pickable & ~segmentation.is_coarse_ground & (curvature > smoothness.edge_threshold)
    flat_candidate = smoothness.pickable & segmentation.is_coarse_ground & (curvature < config.planar_threshold)
    edges, edge_bounds = _by_section(edge_candidate, section, -curvature, n_sections)
    flats, flat_bounds = _by_section(flat_candidate, section, curvature, n_sections)

    quota = np.array([config.sharp_per_section, config.less_sharp_per_section, config.flat_per_section], np.int64)
    sharp, less_sharp, flat = _pick(
        segmentation.row,
        segmentation.column,
        edges,
        edge_bounds,
        flats,
        flat_bounds,
        quota,
        config.curvature_half_window,
        config.neighbour_max_column_gap,
    )

    time_offset_s = segmentation.time_offset_s

    def cloud(index) -> FeatureCloud:
        index = np.asarray(index, dtype=np.int64)
        return FeatureCloud(
            points=np.take(segmentation.points, index, axis=0),
            ring=segmentation.row[index],
            time_offset_s=time_offset_s[index],
        )

    less_flat_mask = smoothness.in_section.copy()
    less_flat_mask[less_sharp] = False
    less_flat_index = np.flatnonzero(less_flat_mask)
    less_flat = voxel_centroids_per_ring(
        np.take(segmentation.points, less_flat_index, axis=0),
        segmentation.row[less_flat_index],
        time_offset_s[less_flat_index],
        config.less_flat_voxel_m,
    )
    return FeatureSet(
        stamp_ns=scan.stamp_ns,
        sharp=cloud(sharp),
        less_sharp=cloud(less_sharp),
        flat=cloud(flat),
        less_flat=less_flat,
        outliers=outliers,
    )
