"""Nearest-neighbour search over a fixed point set: :class:`PointTree`, a k-d tree (pykdtree).

pykdtree builds its tree 3-4x faster than ``scipy.spatial.cKDTree`` and answers the queries of
scan-to-submap matching (a few thousand points, k = 1, against 10-40 k submap points) 1.5-1.7x
faster, with the same neighbours and bit-identical distances (docs/performance.md has the figures).

It parallelises a query with OpenMP. On a machine whose cores are already busy (the pipeline uses
two processes: the front end and the mapping) the extra threads wait for each other and a query
takes 3-6x longer than on one thread, so this module loads pykdtree's OpenMP runtime (its own copy,
in the wheel) with one thread unless ``OMP_NUM_THREADS`` says otherwise. The runtime reads that
variable once, when it is loaded, so the environment is left as it was right after the import.
"""

from __future__ import annotations

import os

import numpy as np


def _import_kdtree():
    """pykdtree's ``KDTree`` class, its OpenMP runtime loaded single-threaded (see module doc)."""
    before = os.environ.get("OMP_NUM_THREADS")
    if before is None:
        os.environ["OMP_NUM_THREADS"] = "1"
    try:
        from pykdtree.kdtree import KDTree
    finally:
        if before is None:
            del os.environ["OMP_NUM_THREADS"]
    return KDTree


_KDTree = _import_kdtree()

__all__ = ["PointTree"]


class PointTree:
    """A k-d tree over (N,D) float64 points (N >= 1) answering k-nearest queries.

    Args:
        points: (N,D) points, any frame and unit; copied to contiguous float64 when they are not.
    """

    __slots__ = ("_tree", "n_points")

    def __init__(self, points: np.ndarray) -> None:
        data = np.ascontiguousarray(points, dtype=np.float64)
        if data.ndim != 2 or len(data) == 0:
            raise ValueError(f"a PointTree needs (N, D) points with N >= 1, got shape {data.shape}")
        self.n_points = int(data.shape[0])
        self._tree = _KDTree(data)

    def query(
        self, queries: np.ndarray, k: int = 1, distance_upper_bound: float | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest points of each of the (M,D) ``queries``, nearest first.

        Returns ``(distance, index)``: float64 (Euclidean, same unit as the points) and int64,
        shaped (M,) for ``k == 1`` and (M,k) otherwise. A neighbour farther than
        ``distance_upper_bound`` (or missing because ``k`` exceeds the points) has distance inf
        and index ``n_points``, as in ``scipy.spatial.cKDTree.query``.
        """
        q = np.ascontiguousarray(queries, dtype=np.float64)
        if len(q) == 0:
            shape = (0,) if k == 1 else (0, k)
            return np.zeros(shape), np.zeros(shape, np.int64)
        dist, idx = self._tree.query(q, k=k, distance_upper_bound=distance_upper_bound)
        return dist, idx.astype(np.int64)
