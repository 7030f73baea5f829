"""Loop-closure candidates: earlier keyframes near the query keyframe's estimated position.

LeGO-LOAM (``mapOptmization.cpp``, ``detectLoopClosure``) searches a 7 m radius around the latest
keyframe and takes a keyframe older than 30 s; LIO-SAM widens the radius to 15 m; hdl_graph_slam
measures the distance in the horizontal plane only (x, y), so that height drift, the usual failure
of LiDAR-only odometry, does not hide a revisit. Here the distance is horizontal by default (3-D on
request), every keyframe at least ``min_time_gap_s`` older than the query is eligible, and the
eligible keyframes within the radius are returned nearest first (ties: lower index first), at most
``max_candidates`` of them, each more than ``min_separation`` keyframes from the nearer ones: the
verification registers against a match's ``±submap_neighbours`` keyframes, so the neighbour of a
rejected match is the same test again (on the suite's drives a second candidate next to the first
was accepted twice in some 200 tries, and cost a verification each time), while a keyframe of
another pass is a different one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["CandidateSet", "find_candidates"]


@dataclass(frozen=True, slots=True)
class CandidateSet:
    """Earlier keyframes that may close a loop with a query keyframe.

    Attributes:
        query: index of the query keyframe.
        matches: (C,) int64 keyframe indices, nearest first.
        distances_m: (C,) float64 gating distance of each (horizontal or 3-D, at the current estimate).
    """

    query: int
    matches: np.ndarray
    distances_m: np.ndarray

    def __post_init__(self) -> None:
        if self.matches.shape != self.distances_m.shape or self.matches.ndim != 1:
            raise ValueError("matches and distances_m must be (C,) arrays of the same length")

    def __len__(self) -> int:
        return int(self.matches.size)


def find_candidates(
    positions_m: np.ndarray,
    stamps_ns: np.ndarray,
    query: int,
    *,
    radius_m: float,
    min_time_gap_s: float,
    horizontal: bool = True,
    max_candidates: int = 1,
    min_separation: int = 0,
) -> CandidateSet:
    """Keyframes before ``query`` within ``radius_m`` of it and at least ``min_time_gap_s`` older.

    Args:
        positions_m: (K,3) keyframe positions in the world frame (current estimate).
        stamps_ns: (K,) keyframe stamps, integer nanoseconds.
        query: index of the query keyframe (0 <= query < K); only keyframes ``j < query`` qualify.
        radius_m: search radius.
        min_time_gap_s: a candidate must be at least this much older than the query.
        horizontal: measure the distance on (x, y) only (default) instead of (x, y, z).
        max_candidates: return at most this many, nearest first.
        min_separation: skip a keyframe within this many keyframes of a nearer candidate.

    Returns:
        The candidate set (possibly empty).
    """
    positions_m = np.asarray(positions_m, dtype=np.float64)
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    if positions_m.ndim != 2 or positions_m.shape[1] != 3 or stamps_ns.shape != (len(positions_m),):
        raise ValueError(f"expected (K,3) positions and (K,) stamps, got {positions_m.shape} and {stamps_ns.shape}")
    if not 0 <= query < len(positions_m):
        raise ValueError(f"query {query} out of range for {len(positions_m)} keyframes")
    empty = CandidateSet(query, np.zeros(0, np.int64), np.zeros(0))
    if query == 0 or max_candidates <= 0:
        return empty
    gap_ns = int(round(min_time_gap_s * 1e9))
    earlier = np.flatnonzero(stamps_ns[:query] <= stamps_ns[query] - gap_ns)
    if earlier.size == 0:
        return empty
    dims = 2 if horizontal else 3
    delta = positions_m[earlier, :dims] - positions_m[query, :dims]
    distance = np.sqrt(np.einsum("ij,ij->i", delta, delta))
    inside = distance <= radius_m
    earlier, distance = earlier[inside], distance[inside]
    chosen: list[int] = []
    for i in np.lexsort((earlier, distance)).tolist():
        if all(abs(int(earlier[i]) - int(earlier[j])) > min_separation for j in chosen):
            chosen.append(i)
            if len(chosen) == max_candidates:
                break
    return CandidateSet(query, earlier[chosen].astype(np.int64), distance[chosen])
