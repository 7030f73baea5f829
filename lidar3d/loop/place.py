"""Place recognition: Scan Context descriptors of keyframes and a search over earlier ones.

Distance-gated candidates (:mod:`lidar3d.loop.candidates`) find a revisit only while the drift is
below the gate radius. A place descriptor finds it from what the keyframe sees, whatever the
estimate says. The descriptor is Scan Context (G. Kim and A. Kim, "Scan Context: Egocentric
Spatial Descriptor for Place Recognition within 3D Point Cloud Map", IROS 2018; parameters of
its reference implementation and of SC-LeGO-LOAM: 20 rings x 60 sectors out to 80 m, ring-key
k-d tree with 10 candidates, fast alignment by the sector key over 10 % of the sectors):

* the keyframe cloud is levelled with the keyframe's roll and pitch (gravity is the only axis
  the world frame knows for sure), so the descriptor does not depend on the vehicle's tilt;
* a polar grid around the sensor (``rings`` annuli of equal width out to ``max_radius_m``,
  ``sectors`` equal sectors) keeps per cell the highest point above the ground level (the lowest
  points of the cloud): empty cells are 0;
* the ring key (mean of each ring) does not change with yaw: a k-d tree over the ring keys of the
  earlier keyframes proposes the nearest ``candidates``;
* each proposal is compared column by column at every sector shift near the one its sector key
  (mean of each sector) suggests; the distance is one minus the mean cosine similarity of the
  columns that are occupied in both; the best shift is the yaw between the two keyframes.

A proposal whose distance is below ``threshold`` goes to the same ICP verification as a distance
candidate, started from the descriptor's yaw (:func:`place_guess`), never from the drifting
estimate of the translation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from lidar3d.mapping.se3 import transform_points

__all__ = ["PlaceIndex", "PlaceMatch", "ScanContext", "level_rotation", "place_guess"]

_GROUND_PERCENTILE = 5.0  # the ground level of a cloud: this percentile of its heights


def level_rotation(T_world_lidar: np.ndarray) -> np.ndarray:
    """(3,3) rotation taking lidar-frame vectors to the levelled frame: the pose's roll and
    pitch removed, its yaw kept out (z along gravity, x the lidar's heading)."""
    R = np.asarray(T_world_lidar, dtype=np.float64)[:3, :3]
    yaw = np.arctan2(R[1, 0], R[0, 0])
    c, s = np.cos(yaw), np.sin(yaw)
    Rz_inv = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    return Rz_inv @ R


@dataclass(frozen=True, slots=True)
class ScanContext:
    """The descriptor of one keyframe.

    Attributes:
        grid: (rings, sectors) highest point per cell above the cloud's ground level (m), 0 empty;
            sector 0 starts at the levelled lidar's +x axis and sectors go counter-clockwise.
        ring_key: (rings,) mean of each ring (yaw invariant).
        sector_key: (sectors,) mean of each sector.
    """

    grid: np.ndarray
    ring_key: np.ndarray
    sector_key: np.ndarray

    @classmethod
    def of(
        cls, points_lidar: np.ndarray, T_world_lidar: np.ndarray, *, rings: int, sectors: int, max_radius_m: float
    ) -> ScanContext:
        """Descriptor of an (N,3) lidar-frame cloud seen from pose ``T_world_lidar`` (4,4)."""
        grid = np.zeros((rings, sectors))
        if len(points_lidar):
            R = np.eye(4)
            R[:3, :3] = level_rotation(T_world_lidar)
            level = transform_points(R, np.asarray(points_lidar, dtype=np.float64))
            radius = np.hypot(level[:, 0], level[:, 1])
            keep = (radius < max_radius_m) & (radius > 0.0)
            level, radius = level[keep], radius[keep]
            if len(level):
                height = level[:, 2] - np.percentile(level[:, 2], _GROUND_PERCENTILE)
                ring = np.minimum((radius / max_radius_m * rings).astype(np.int64), rings - 1)
                angle = np.mod(np.arctan2(level[:, 1], level[:, 0]), 2.0 * np.pi)
                sector = np.minimum((angle / (2.0 * np.pi) * sectors).astype(np.int64), sectors - 1)
                np.maximum.at(grid, (ring, sector), np.maximum(height, 0.0))
        return cls(grid, grid.mean(axis=1), grid.mean(axis=0))

    def distance(self, other: ScanContext, shifts: np.ndarray) -> tuple[float, int]:
        """(distance, shift): the smallest column-wise cosine distance over the sector ``shifts``
        (``other``'s columns rolled by ``shift`` to line up with this one's), and that shift."""
        best = (1.0, 0)
        q = self.grid
        q_norm = np.linalg.norm(q, axis=0)
        for shift in np.asarray(shifts, dtype=np.int64).tolist():
            c = np.roll(other.grid, shift, axis=1)
            c_norm = np.linalg.norm(c, axis=0)
            both = (q_norm > 0) & (c_norm > 0)
            if not both.any():
                continue
            cosine = np.einsum("ij,ij->j", q[:, both], c[:, both]) / (q_norm[both] * c_norm[both])
            d = 1.0 - float(cosine.mean())
            if d < best[0]:
                best = (d, shift)
        return best


@dataclass(frozen=True, slots=True)
class PlaceMatch:
    """An earlier keyframe whose descriptor resembles the query's.

    Attributes:
        match: keyframe index.
        distance: Scan Context distance (0 identical, 1 nothing in common).
        yaw_rad: yaw of the query's levelled frame in the match's levelled frame.
    """

    match: int
    distance: float
    yaw_rad: float


class PlaceIndex:
    """Scan Context descriptors of all keyframes so far, searchable by ring key.

    Args:
        rings, sectors, max_radius_m: the polar grid.
        candidates: ring-key neighbours compared in full per query.
        threshold: largest descriptor distance that counts as the same place.
        search_ratio: share of the sectors searched around the sector key's best shift.
    """

    def __init__(
        self,
        *,
        rings: int = 20,
        sectors: int = 60,
        max_radius_m: float = 80.0,
        candidates: int = 10,
        threshold: float = 0.2,
        search_ratio: float = 0.1,
    ) -> None:
        self.rings = rings
        self.sectors = sectors
        self.max_radius_m = max_radius_m
        self.candidates = candidates
        self.threshold = threshold
        self.search_ratio = search_ratio
        self.descriptors: list[ScanContext] = []

    def __len__(self) -> int:
        return len(self.descriptors)

    def add(self, points_lidar: np.ndarray, T_world_lidar: np.ndarray) -> ScanContext:
        """Describe and store the next keyframe (its index is the number added before it)."""
        descriptor = ScanContext.of(
            points_lidar, T_world_lidar, rings=self.rings, sectors=self.sectors, max_radius_m=self.max_radius_m
        )
        self.descriptors.append(descriptor)
        return descriptor

    def query(self, query: int, eligible: np.ndarray) -> list[PlaceMatch]:
        """Matches of keyframe ``query`` among the ``eligible`` (older) keyframe indices whose
        distance is below the threshold, best first."""
        eligible = np.asarray(eligible, dtype=np.int64)
        if eligible.size == 0:
            return []
        q = self.descriptors[query]
        if not q.grid.any():
            return []
        keys = np.stack([self.descriptors[k].ring_key for k in eligible.tolist()])
        k = min(self.candidates, len(eligible))
        _, nearest = cKDTree(keys).query(q.ring_key, k=k)
        nearest = np.atleast_1d(nearest)
        half_window = max(1, int(round(self.search_ratio * self.sectors / 2)))
        offsets = np.arange(-half_window, half_window + 1)
        matches = []
        for j in eligible[nearest].tolist():
            c = self.descriptors[j]
            coarse = _best_roll(q.sector_key, c.sector_key)
            distance, shift = q.distance(c, np.mod(coarse + offsets, self.sectors))
            if distance <= self.threshold:
                # other's column s sits at column s + shift of the query: the query's heading is
                # -shift sectors from the match's
                yaw = -2.0 * np.pi * shift / self.sectors
                matches.append(PlaceMatch(int(j), float(distance), float(np.arctan2(np.sin(yaw), np.cos(yaw)))))
        return sorted(matches, key=lambda m: (m.distance, m.match))


def _best_roll(query_key: np.ndarray, other_key: np.ndarray) -> int:
    """Roll of ``other_key`` that best lines it up with ``query_key`` (least squares)."""
    n = len(query_key)
    # rolled[s] is np.roll(other_key, s): element i comes from i - s
    rolled = other_key[(np.arange(n)[None, :] - np.arange(n)[:, None]) % n]
    errors = np.sum((query_key[None, :] - rolled) ** 2, axis=1)
    return int(np.argmin(errors))


def place_guess(T_world_match: np.ndarray, T_world_query: np.ndarray, yaw_rad: float) -> np.ndarray:
    """(4,4) initial ``T_match_query`` for a place match: the two levelled frames at the same
    position, turned by the descriptor's ``yaw_rad``; each keyframe's own roll and pitch kept."""
    L_match = level_rotation(T_world_match)
    L_query = level_rotation(T_world_query)
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = L_match.T @ Rz @ L_query
    return T
