"""PointTree (pykdtree) answers exactly as scipy's cKDTree, which the matching used before."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lidar3d.mapping.nearest import PointTree


@pytest.mark.parametrize("k", [1, 2, 10])
def test_same_neighbours_and_distances_as_ckdtree(k: int) -> None:
    rng = np.random.default_rng(7)
    points = rng.uniform(-20.0, 20.0, size=(5000, 3))
    queries = rng.uniform(-22.0, 22.0, size=(800, 3))
    bound = 1.0
    dist, idx = PointTree(points).query(queries, k=k, distance_upper_bound=bound)
    ref_dist, ref_idx = cKDTree(points).query(queries, k=k, distance_upper_bound=bound)
    assert idx.dtype == np.int64 and dist.dtype == np.float64
    assert dist.shape == ref_dist.shape
    np.testing.assert_array_equal(idx, ref_idx)  # beyond the bound: index n_points, as cKDTree
    np.testing.assert_array_equal(dist, ref_dist)


def test_four_dimensional_ring_tree_and_empty_queries() -> None:
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.normal(size=(300, 3)), rng.integers(0, 16, 300) * 1.0e4])
    dist, idx = PointTree(points).query(points[:5], k=2)
    assert np.all(dist[:, 0] == 0.0) and np.array_equal(idx[:, 0], np.arange(5))
    empty_dist, empty_idx = PointTree(points).query(np.zeros((0, 4)), k=2)
    assert empty_dist.shape == (0, 2) and empty_idx.shape == (0, 2)


def test_no_points_is_refused() -> None:
    with pytest.raises(ValueError, match="N >= 1"):
        PointTree(np.zeros((0, 3)))
