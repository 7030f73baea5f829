"""Clustering of the non-ground cells of the range image (LeGO-LOAM imageProjection, IP:370-460).

Two 4-neighbour cells (horizontal neighbours wrap around the sweep) belong to one object when the
angle beta between the beam to the farther point and the line joining the two points exceeds
``cluster_angle_deg`` (Bogoslavskyi & Stachniss; LeGO-LOAM ``segmentTheta``):

    beta = atan2(d2 sin(alpha), d1 - d2 cos(alpha)),  d1 = max range, d2 = min range,

with alpha the angle between the two beams: the column width for horizontal neighbours, the
difference of the two rows' beam elevations for vertical ones (LeGO-LOAM uses the uniform 2 degree
spacing; the table handles non-uniform sensors such as the VLP-32C). LeGO-LOAM grows each cluster by
breadth-first search; here the joining test runs on the whole image at once and the clusters are the
connected components of the resulting graph, found by union-find in a compiled kernel (numba, cached
on disk; integer work only). A cluster is kept when it has
at least ``min_cluster_points`` points, or at least ``min_cluster_points_multi_ring`` points on at
least ``min_cluster_rings`` rows (IP:430-450); the others are outliers.
"""

from __future__ import annotations

import numpy as np

from lidar3d.config import SegmentationConfig
from lidar3d.errors import ConfigError
from lidar3d.jit import lazy_njit
from lidar3d.segmentation.range_image import RangeImage

__all__ = ["cluster_cells", "joins_by_beta"]


def joins_by_beta(near_m: np.ndarray, far_m: np.ndarray, alpha_rad: np.ndarray | float, tan_theta: float) -> np.ndarray:
    """beta > theta for 0 < theta < 90 deg, written without the arctangent.

    With s = d2 sin(alpha) > 0, beta = atan2(s, d1 - d2 cos(alpha)) exceeds theta exactly when
    s > tan(theta) * (d1 - d2 cos(alpha)) (a non-positive denominator means beta >= 90 deg).
    NaN ranges (empty cells) compare False.
    """
    with np.errstate(invalid="ignore"):
        return near_m * np.sin(alpha_rad) > tan_theta * (far_m - near_m * np.cos(alpha_rad))


@lazy_njit
def _components(cells: np.ndarray, horizontal: np.ndarray, vertical: np.ndarray) -> tuple[np.ndarray, int]:
    """Connected components of the candidate cells, by union-find; ``cells``: (K,) flat indices of
    the candidate cells in row-major order; ``horizontal`` (R, C): a cell joins its right neighbour
    (wrapping); ``vertical`` (R-1, C): a cell joins the one above. Returns (K,) int64 component of
    each cell, numbered 0, 1, ... in row-major order of each component's first cell, and their number.
    A component's root is its first cell (the smaller root becomes the parent)."""
    n_rows, n_columns = horizontal.shape
    parent = np.arange(n_rows * n_columns)
    for r in range(n_rows):
        for c in range(n_columns):
            node = r * n_columns + c
            for direction in range(2):  # 0: the right neighbour, 1: the one above
                if direction == 0 and horizontal[r, c]:
                    other = r * n_columns + (c + 1) % n_columns
                elif direction == 1 and r + 1 < n_rows and vertical[r, c]:
                    other = node + n_columns
                else:
                    continue
                a, b = node, other
                while parent[a] != a:
                    parent[a] = parent[parent[a]]  # path halving
                    a = parent[a]
                while parent[b] != b:
                    parent[b] = parent[parent[b]]
                    b = parent[b]
                parent[max(a, b)] = min(a, b)
    dense_of_root = np.full(n_rows * n_columns, -1, np.int64)
    component = np.empty(cells.size, np.int64)
    n_components = 0
    for k in range(cells.size):
        root = cells[k]
        while parent[root] != root:
            root = parent[root]
        if dense_of_root[root] < 0:
            dense_of_root[root] = n_components
            n_components += 1
        component[k] = dense_of_root[root]
    return component, n_components


def cluster_cells(
    image: RangeImage, ground_mask: np.ndarray, config: SegmentationConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Cluster the occupied non-ground cells of ``image``.

    Returns:
        label: (R, C) int32, cluster id ``0 .. K-1`` of each cell of a kept cluster, numbered in
            row-major order of each cluster's first cell; -1 elsewhere (empty, ground, outlier).
        outlier_mask: (R, C) bool, cells of clusters too small to keep.
    """
    if not 0.0 < config.cluster_angle_deg < 90.0:
        raise ConfigError(f"config segmentation.cluster_angle_deg: must be in (0, 90), got {config.cluster_angle_deg}")
    n_rows, n_columns = image.shape
    candidate = image.occupied & ~ground_mask
    range_m = np.where(candidate, image.range_m, np.nan)
    tan_theta = np.tan(np.deg2rad(config.cluster_angle_deg))

    right_m = np.roll(range_m, -1, axis=1)  # horizontal neighbour, wrapping at the last column
    horizontal = joins_by_beta(
        np.fmin(range_m, right_m), np.fmax(range_m, right_m), image.azimuth_resolution_rad, tan_theta
    )
    up_m = range_m[1:]
    alpha_rows = np.abs(np.diff(image.row_elevation_rad))[:, None]  # (R-1, 1)
    vertical = joins_by_beta(np.fmin(range_m[:-1], up_m), np.fmax(range_m[:-1], up_m), alpha_rows, tan_theta)
    # fmin/fmax return the other operand where one is NaN, so re-exclude pairs with an empty cell
    horizontal &= candidate & np.roll(candidate, -1, axis=1)
    vertical &= candidate[:-1] & candidate[1:]

    cells = np.flatnonzero(candidate.ravel())
    n_nodes = n_rows * n_columns
    label = np.full(n_nodes, -1, dtype=np.int32)
    outlier = np.zeros(n_nodes, dtype=bool)
    if cells.size == 0:
        return label.reshape(n_rows, n_columns), outlier.reshape(n_rows, n_columns)
    # components of candidate cells numbered densely, in row-major order of their first cell
    dense, n_clusters = _components(cells, horizontal, vertical)
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
