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

Everything but the greedy pick is array work: candidates are filtered and sorted once for the whole
scan, the suppression span of every point is precomputed, and the sequential pick (which must stay
sequential: each pick changes what later candidates may do) walks only the sorted candidates of each
section, stopping at the section's quota, in a compiled kernel (numba, cached on disk: integer work
only, so its picks are exactly those of the same loop in Python).
"""

from __future__ import annotations

import numpy as np

from lidar3d.config import FeatureConfig
from lidar3d.features.records import FeatureCloud, FeatureSet, Smoothness
from lidar3d.jit import lazy_njit
from lidar3d.segmentation.segment import Segmentation

__all__ = ["select_features", "suppression_spans", "voxel_centroids_per_ring"]


def suppression_spans(
    segmentation: Segmentation, half_window: int, max_column_gap: int
) -> tuple[np.ndarray, np.ndarray]:
    """(M,) int64 ``lo`` and ``hi``: picking point i marks ``[lo[i], hi[i])`` as picked.

    The span reaches up to ``half_window`` points either side of i, stopping before the first pair
    of consecutive points more than ``max_column_gap`` columns apart or in different rings (FA:720-735).
    """
    n = len(segmentation)
    link = np.zeros(n, dtype=bool)  # link[k]: points k and k+1 are close neighbours
    link[:-1] = (segmentation.row[1:] == segmentation.row[:-1]) & (
        np.abs(np.diff(segmentation.column)) <= max_column_gap
    )
    forward = np.zeros(n, dtype=np.int64)
    backward = np.zeros(n, dtype=np.int64)
    reach_forward = np.ones(n, dtype=bool)
    reach_backward = np.ones(n, dtype=bool)
    for step in range(half_window):
        ahead = np.zeros(n, dtype=bool)
        ahead[: n - step] = link[step:]  # link between i+step and i+step+1
        reach_forward &= ahead
        forward += reach_forward
        behind = np.zeros(n, dtype=bool)
        behind[step + 1 :] = link[: n - step - 1]  # link between i-step-1 and i-step
        reach_backward &= behind
        backward += reach_backward
    index = np.arange(n)
    return index - backward, index + forward + 1


def voxel_centroids_per_ring(
    points: np.ndarray, ring: np.ndarray, time_offset_s: np.ndarray, leaf_m: float
) -> FeatureCloud:
    """Centroid (and mean time) of the points of each (ring, voxel) cell of edge ``leaf_m``."""
    if points.shape[0] == 0:
        return FeatureCloud.empty()
    if leaf_m <= 0:
        return FeatureCloud(points=points, ring=ring, time_offset_s=time_offset_s)
    # 17 bits per axis (+-13 km at 0.2 m) and the ring above them: one int64 key per (ring, voxel)
    voxel = np.floor(points / leaf_m).astype(np.int64) + (1 << 16)
    key = (((ring.astype(np.int64) << 17 | voxel[:, 0]) << 17 | voxel[:, 1]) << 17) | voxel[:, 2]
    _, group = np.unique(key, return_inverse=True)
    count = np.bincount(group).astype(np.float64)
    centroid = np.stack([np.bincount(group, weights=points[:, k]) for k in range(3)], axis=1) / count[:, None]
    mean_time = np.bincount(group, weights=time_offset_s) / count
    group_ring = np.zeros(count.shape[0], dtype=np.uint16)
    group_ring[group] = ring
    return FeatureCloud(points=centroid, ring=group_ring, time_offset_s=mean_time)


def _sorted_by_section(candidate, section, key, n_sections, lo, hi):
    """Candidates sorted by (section, key): their indices, suppression spans, and section starts."""
    index = np.flatnonzero(candidate)
    order = np.lexsort((key[index], section[index]))
    index = index[order]
    bounds = np.searchsorted(section[index], np.arange(n_sections + 1))
    return index, lo[index], hi[index], bounds


@lazy_njit
def _pick(n_points, edges, edge_lo, edge_hi, edge_bounds, flats, flat_lo, flat_hi, flat_bounds, quota):
    """The greedy pick, section by section: edges first, then flats; each pick marks its span as
    picked. ``quota``: (sharp, less sharp, flat) per section. Returns the indices of the sharp,
    less-sharp and flat picks, in pick order."""
    n_sharp, n_less_sharp, n_flat = quota[0], quota[1], quota[2]
    picked = np.zeros(n_points, np.bool_)
    sharp = np.empty(edges.size, np.int64)
    less_sharp = np.empty(edges.size, np.int64)
    flat = np.empty(flats.size, np.int64)
    n_sharp_picked = n_less_sharp_picked = n_flat_picked = 0
    for s in range(edge_bounds.size - 1):
        count = 0
        for k in range(edge_bounds[s], edge_bounds[s + 1]):
            if count >= n_less_sharp:
                break
            i = edges[k]
            if picked[i]:
                continue
            count += 1
            if count <= n_sharp:
                sharp[n_sharp_picked] = i
                n_sharp_picked += 1
            less_sharp[n_less_sharp_picked] = i
            n_less_sharp_picked += 1
            picked[edge_lo[k] : edge_hi[k]] = True
        count = 0
        for k in range(flat_bounds[s], flat_bounds[s + 1]):
            if count >= n_flat:
                break
            i = flats[k]
            if picked[i]:
                continue
            count += 1
            flat[n_flat_picked] = i
            n_flat_picked += 1
            picked[flat_lo[k] : flat_hi[k]] = True
    return sharp[:n_sharp_picked], less_sharp[:n_less_sharp_picked], flat[:n_flat_picked]


def select_features(segmentation: Segmentation, smoothness: Smoothness, config: FeatureConfig) -> FeatureSet:
    """Sharp, less-sharp, flat and less-flat features of one scan, lidar frame (see module doc)."""
    scan = segmentation.scan
    n = len(segmentation)
    outliers = FeatureCloud(
        points=scan.points[segmentation.outlier_scan_index],
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
    edge_candidate = smoothness.pickable & ~segmentation.is_ground & (curvature > smoothness.edge_threshold)
    flat_candidate = smoothness.pickable & segmentation.is_ground & (curvature < config.planar_threshold)
    lo, hi = suppression_spans(segmentation, config.curvature_half_window, config.neighbour_max_column_gap)
    edges, edge_lo, edge_hi, edge_bounds = _sorted_by_section(edge_candidate, section, -curvature, n_sections, lo, hi)
    flats, flat_lo, flat_hi, flat_bounds = _sorted_by_section(flat_candidate, section, curvature, n_sections, lo, hi)

    quota = np.array([config.sharp_per_section, config.less_sharp_per_section, config.flat_per_section], np.int64)
    sharp, less_sharp, flat = _pick(
        n, edges, edge_lo, edge_hi, edge_bounds, flats, flat_lo, flat_hi, flat_bounds, quota
    )

    time_offset_s = segmentation.time_offset_s

    def cloud(index) -> FeatureCloud:
        index = np.asarray(index, dtype=np.int64)
        return FeatureCloud(
            points=segmentation.points[index], ring=segmentation.row[index], time_offset_s=time_offset_s[index]
        )

    less_flat_mask = smoothness.in_section.copy()
    less_flat_mask[less_sharp] = False
    less_flat = voxel_centroids_per_ring(
        segmentation.points[less_flat_mask],
        segmentation.row[less_flat_mask],
        time_offset_s[less_flat_mask],
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
