"""Clustering of the non-ground cells of the range image (LeGO-LOAM imageProjection, IP:370-460).

Two 4-neighbour cells (horizontal neighbours wrap around the sweep) belong to one object when the
angle beta between the beam to the farther point and the line joining the two points exceeds
``cluster_angle_deg`` (Bogoslavskyi & Stachniss; LeGO-LOAM ``segmentTheta``):

    beta = atan2(d2 sin(alpha), d1 - d2 cos(alpha)),  d1 = max range, d2 = min range,

with alpha the angle between the two beams: the column width for horizontal neighbours, the
difference of the two rows' beam elevations for vertical ones (LeGO-LOAM uses the uniform 2 degree
spacing; the table handles non-uniform sensors such as the VLP-32C). LeGO-LOAM grows each cluster by
breadth-first search; here every pair of neighbour cells is tested and the clusters are the
connected components of the joined pairs, found by union-find in a compiled kernel (numba, cached on
disk). The test needs no arctangent: with s = d2 sin(alpha) > 0, beta exceeds theta (0 < theta <
90 deg) exactly when s > tan(theta) (d1 - d2 cos(alpha)). A cluster is kept when it has at least
``min_cluster_points`` points, or at least ``min_cluster_points_multi_ring`` points on at least
``min_cluster_rings`` rows (IP:430-450); the others are outliers.
"""

from __future__ import annotations

import numpy as np

from lidar3d.config import SegmentationConfig
from lidar3d.errors import ConfigError
from lidar3d.jit import lazy_njit
from lidar3d.segmentation.range_image import RangeImage

__all__ = ["cluster_cells"]


@lazy_njit
def _cluster_kernel(
    range_m: np.ndarray,
    candidate: np.ndarray,
    sin_cos_horizontal: np.ndarray,
    sin_cos_vertical: np.ndarray,
    tan_theta: float,
    min_points: int,
    min_points_multi_ring: int,
    min_rings: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Labels and outlier flags of the candidate cells (see :func:`cluster_cells`).

    ``range_m``, ``candidate`` (R, C); ``sin_cos_horizontal`` (2,) the sine and cosine of the
    column width; ``sin_cos_vertical`` (R-1, 2) those of the elevation step from each row to the
    next. The components are found by union-find over the joined neighbour pairs (a cell and its
    right neighbour, wrapping; a cell and the one above), a root being its component's first cell
    in row-major order (the smaller root becomes the parent); they are numbered in that order.
    """
    n_rows, n_columns = range_m.shape
    parent = np.arange(n_rows * n_columns)
    for r in range(n_rows):
        for c in range(n_columns):
            if not candidate[r, c]:
                continue
            node = r * n_columns + c
            for direction in range(2):  # 0: the right neighbour, 1: the one above
                if direction == 0:
                    other_r, other_c = r, (c + 1) % n_columns
                    sin_alpha, cos_alpha = sin_cos_horizontal[0], sin_cos_horizontal[1]
                elif r + 1 < n_rows:
                    other_r, other_c = r + 1, c
                    sin_alpha, cos_alpha = sin_cos_vertical[r, 0], sin_cos_vertical[r, 1]
                else:
                    continue
                if not candidate[other_r, other_c]:
                    continue
                # beta > theta, without the arctangent (module doc)
                near = min(range_m[r, c], range_m[other_r, other_c])
                far = max(range_m[r, c], range_m[other_r, other_c])
                if not near * sin_alpha > tan_theta * (far - near * cos_alpha):
                    continue
                a, b = node, other_r * n_columns + other_c
                while parent[a] != a:
                    parent[a] = parent[parent[a]]  # path halving
                    a = parent[a]
                while parent[b] != b:
                    parent[b] = parent[parent[b]]
                    b = parent[b]
                parent[max(a, b)] = min(a, b)
    # components numbered densely in row-major order of their first cell; size and rows of each
    dense_of_root = np.full(n_rows * n_columns, -1, np.int64)
    component = np.full(n_rows * n_columns, -1, np.int64)
    size = np.zeros(n_rows * n_columns, np.int64)
    n_component_rows = np.zeros(n_rows * n_columns, np.int64)
    last_row = np.full(n_rows * n_columns, -1, np.int64)  # rows are walked in order: count each once
    n_components = 0
    for node in range(n_rows * n_columns):
        if not candidate[node // n_columns, node % n_columns]:
            continue
        root = node
        while parent[root] != root:
            root = parent[root]
        if dense_of_root[root] < 0:
            dense_of_root[root] = n_components
            n_components += 1
        k = dense_of_root[root]
        component[node] = k
        size[k] += 1
        if last_row[k] != node // n_columns:
            last_row[k] = node // n_columns
            n_component_rows[k] += 1
    new_id = np.full(n_components, -1, np.int32)
    n_kept = 0
    for k in range(n_components):
        if size[k] >= min_points or (size[k] >= min_points_multi_ring and n_component_rows[k] >= min_rings):
            new_id[k] = n_kept
            n_kept += 1
    label = np.full((n_rows, n_columns), -1, np.int32)
    outlier = np.zeros((n_rows, n_columns), np.bool_)
    for node in range(n_rows * n_columns):
        k = component[node]
        if k >= 0:
            label[node // n_columns, node % n_columns] = new_id[k]
            outlier[node // n_columns, node % n_columns] = new_id[k] < 0
    return label, outlier


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
    alpha_rows = np.abs(np.diff(image.row_elevation_rad))  # (R-1,)
    alpha_column = image.azimuth_resolution_rad
    return _cluster_kernel(
        image.range_m,
        image.occupied & ~ground_mask,
        np.array([np.sin(alpha_column), np.cos(alpha_column)]),
        np.stack([np.sin(alpha_rows), np.cos(alpha_rows)], axis=1),
        float(np.tan(np.deg2rad(config.cluster_angle_deg))),
        config.min_cluster_points,
        config.min_cluster_points_multi_ring,
        config.min_cluster_rings,
    )
