"""LOAM's ring-aware correspondences for scan-to-scan matching.

A single sweep is sparse across rings and dense along them, so k nearest neighbours all fall on
one ring and give no line or plane across rings. LOAM therefore builds each correspondence from
the nearest point j plus points on chosen neighbouring rings (LeGO-LOAM featureAssociation.cpp
1044-1268, search radius 5 m):

* edge: j and the nearest point l on a *different* ring within +-2 rings of j -> line (j, l);
* plane: j, the nearest point l on j's ring or one ring below, and the nearest point m on a
  ring above -> plane (j, l, m).

Both searches are batched queries (see :class:`RingIndexedCloud` for the ring-restricted one).
"""

from __future__ import annotations

import numpy as np

from lidar3d.mapping.nearest import PointTree
from lidar3d.mapping.registration import MatchRows, line_rows_from_directions
from lidar3d.mapping.se3 import cross

__all__ = ["RingIndexedCloud"]


class RingIndexedCloud:
    """A feature cloud of one sweep, searchable by nearest point overall or on a given ring.

    Ring-restricted search uses one 4-D k-d tree over (x, y, z, ring * RING_SPACING_M): with
    the ring coordinate spaced far beyond any search radius, the nearest neighbour of
    (q, r * RING_SPACING_M) within the radius is the nearest point on ring r, so a whole batch of
    queries, each aimed at its own ring, is one tree query.
    """

    RING_SPACING_M = 1.0e4

    def __init__(self, points: np.ndarray, ring: np.ndarray, n_rings: int) -> None:
        self.points = np.asarray(points, dtype=np.float64)
        self.ring = np.asarray(ring, dtype=np.int64)
        self.n_rings = n_rings
        self.tree = PointTree(self.points) if len(self.points) else None
        self._ring_tree = (
            PointTree(np.column_stack([self.points, self.ring * self.RING_SPACING_M])) if len(self.points) else None
        )

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def _nearest_on_rings(
        self, queries: np.ndarray, ring_offsets: range, base_ring: np.ndarray, exclude: np.ndarray, max_dist: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Index and distance of the nearest point on rings base_ring + offsets (not ``exclude``)."""
        best_idx = np.full(len(queries), -1, np.int64)
        best_dist = np.full(len(queries), np.inf)
        if self._ring_tree is None or len(queries) == 0:
            return best_idx, best_dist
        k = min(2, len(self.points))
        for offset in ring_offsets:
            target_ring = base_ring + offset
            on_sensor = (target_ring >= 0) & (target_ring < self.n_rings)
            q4 = np.column_stack([queries, target_ring * self.RING_SPACING_M])
            dist, idx = self._ring_tree.query(q4, k=k, distance_upper_bound=max_dist)
            dist = dist.reshape(len(queries), k)
            idx = idx.reshape(len(queries), k)
            valid = np.isfinite(dist) & on_sensor[:, None] & (idx != exclude[:, None])
            dist = np.where(valid, dist, np.inf)
            pick = np.argmin(dist, axis=1)
            rows = np.arange(len(queries))
            d = dist[rows, pick]
            better = d < best_dist
            best_dist[better] = d[better]
            best_idx[better] = idx[rows, pick][better]
        return best_idx, best_dist

    def _nearest(self, queries: np.ndarray, max_dist_m: float) -> tuple[np.ndarray, np.ndarray]:
        """(query rows with a point within ``max_dist_m``, index of that nearest point j)."""
        if self.tree is None or len(queries) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        dist, j = self.tree.query(queries, k=1, distance_upper_bound=max_dist_m)
        ok = np.isfinite(dist)
        return np.flatnonzero(ok), j[ok]

    def match_lines(self, queries: np.ndarray, max_dist_m: float = 5.0) -> MatchRows:
        """Point-to-line rows for ``queries`` (already in this cloud's frame)."""
        q_idx, j = self._nearest(queries, max_dist_m)
        if q_idx.size == 0:
            return MatchRows.empty()
        ring_j = self.ring[j]
        l_lower, d_lower = self._nearest_on_rings(queries[q_idx], range(-2, 0), ring_j, j, max_dist_m)
        l_upper, d_upper = self._nearest_on_rings(queries[q_idx], range(1, 3), ring_j, j, max_dist_m)
        use_upper = d_upper < d_lower
        l_idx = np.where(use_upper, l_upper, l_lower)
        good = l_idx >= 0
        pj = self.points[j[good]]
        pl = self.points[l_idx[good]]
        direction = pl - pj
        length = np.linalg.norm(direction, axis=1)
        keep = length > 1e-3
        return line_rows_from_directions(q_idx[good][keep], pj[keep], direction[keep])

    def match_planes(self, queries: np.ndarray, max_dist_m: float = 5.0) -> MatchRows:
        """Point-to-plane rows for ``queries`` (already in this cloud's frame)."""
        q_idx, j = self._nearest(queries, max_dist_m)
        if q_idx.size == 0:
            return MatchRows.empty()
        ring_j = self.ring[j]
        l_idx, _ = self._nearest_on_rings(queries[q_idx], range(-1, 1), ring_j, j, max_dist_m)
        m_idx, _ = self._nearest_on_rings(queries[q_idx], range(1, 3), ring_j, j, max_dist_m)
        good = (l_idx >= 0) & (m_idx >= 0)
        pj = self.points[j[good]]
        pl = self.points[l_idx[good]]
        pm = self.points[m_idx[good]]
        normal = cross(pl - pj, pm - pj)
        norm = np.linalg.norm(normal, axis=1)
        keep = norm > 1e-6
        normal = normal[keep] / norm[keep, None]
        offset = -np.einsum("ij,ij->i", normal, pj[keep])
        return MatchRows(q_idx[good][keep].astype(np.int64), normal, offset)
