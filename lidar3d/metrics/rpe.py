"""Relative pose error (RPE): KITTI odometry style and per fixed distance.

Relative error of a pair (i, j), reference Q and estimate P (KITTI devkit ``calcSequenceErrors``,
evo ``RPE``): E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j); translation error |t(E_ij)|, rotation error
angle(R(E_ij)). Both trajectories must be poses of the same body (the lidar). RPE does not depend
on a global alignment of the estimate.

* KITTI (``kitti_rpe``): path length d along the reference; a segment starts every ``step_s``
  seconds (KITTI: every 10 frames at 10 Hz); for each length L (100..800 m) the segment ends at the
  first pose with d_j > d_i + L. t_err = |t(E)| / L, r_err = angle(E) / L; the sequence score pools
  all (start, L) samples: t_rel = 100 mean(t_err) [%], r_rel = mean(r_err) [deg/m] x 100
  = [deg/100 m] (the devkit prints deg/m; LiDAR papers report deg/100 m).
* Per fixed distance (``distance_rpe``): consecutive, non-overlapping pairs where the reference path
  travelled since the previous pair start reaches ``distance_m`` (evo ``-d D -u m
  --pairs_from_reference``, ``filter_pairs_by_path``); statistics of |t(E)| (m) and angle(E) (deg).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lidar3d.metrics.ate import rotation_angle_deg
from lidar3d.metrics.statistics import ErrorStatistics

__all__ = [
    "KITTI_SEGMENT_LENGTHS_M",
    "DistanceRpe",
    "KittiLengthError",
    "KittiRpe",
    "distance_rpe",
    "kitti_rpe",
    "path_distances_m",
    "relative_errors",
]

KITTI_SEGMENT_LENGTHS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


def path_distances_m(T_world: np.ndarray) -> np.ndarray:
    """(N,) cumulative path length through the positions, starting at 0."""
    p = np.asarray(T_world, float)[:, :3, 3]
    if len(p) == 0:
        return np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def _inverse(T: np.ndarray) -> np.ndarray:
    R = T[..., :3, :3]
    Rt = np.swapaxes(R, -1, -2)
    inv = np.zeros_like(T)
    inv[..., :3, :3] = Rt
    inv[..., :3, 3] = -(Rt @ T[..., :3, 3, None])[..., 0]
    inv[..., 3, 3] = 1.0
    return inv


def relative_errors(
    T_reference: np.ndarray, T_estimate: np.ndarray, i: np.ndarray, j: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and rotation (deg) errors of E_ij = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)."""
    Q = np.asarray(T_reference, float)
    P = np.asarray(T_estimate, float)
    dQ = _inverse(Q[i]) @ Q[j]
    dP = _inverse(P[i]) @ P[j]
    E = _inverse(dQ) @ dP
    return np.linalg.norm(E[:, :3, 3], axis=1), rotation_angle_deg(E[:, :3, :3])


@dataclass(frozen=True, slots=True)
class KittiLengthError:
    """KITTI errors of the segments of one length (NaN when n = 0)."""

    length_m: float
    n: int
    translation_percent: float
    rotation_deg_per_100m: float


@dataclass(frozen=True, slots=True)
class KittiRpe:
    """KITTI sequence score pooled over all lengths, and per length (NaN when n = 0)."""

    translation_percent: float
    rotation_deg_per_100m: float
    n: int
    per_length: tuple[KittiLengthError, ...]


def _segment_starts(stamps_ns: np.ndarray, step_s: float) -> np.ndarray:
    starts = []
    next_ns = None
    step_ns = int(round(step_s * 1e9))
    for index, stamp in enumerate(np.asarray(stamps_ns, dtype=np.int64)):
        if next_ns is None or stamp >= next_ns:
            starts.append(index)
            next_ns = int(stamp) + step_ns
    return np.asarray(starts, dtype=np.int64)


def kitti_rpe(
    stamps_ns: np.ndarray,
    T_reference: np.ndarray,
    T_estimate: np.ndarray,
    lengths_m: tuple[float, ...] = KITTI_SEGMENT_LENGTHS_M,
    step_s: float = 1.0,
) -> KittiRpe:
    """KITTI relative errors (module docstring); segments longer than the drive are skipped."""
    Q = np.asarray(T_reference, float)
    P = np.asarray(T_estimate, float)
    distances = path_distances_m(Q)
    starts = _segment_starts(stamps_ns, step_s) if len(Q) else np.zeros(0, np.int64)
    per_length = []
    t_all, r_all = [], []
    for length in lengths_m:
        ends = np.searchsorted(distances, distances[starts] + length, side="right")
        ok = ends < len(Q)
        i, j = starts[ok], ends[ok]
        t_err, r_err = relative_errors(Q, P, i, j)
        t_rel = t_err / length
        r_rel = np.radians(r_err) / length
        t_all.append(t_rel)
        r_all.append(r_rel)
        n = int(ok.sum())
        per_length.append(
            KittiLengthError(
                length_m=float(length),
                n=n,
                translation_percent=float(100.0 * t_rel.mean()) if n else math.nan,
                rotation_deg_per_100m=float(np.degrees(r_rel.mean()) * 100.0) if n else math.nan,
            )
        )
    t_pool = np.concatenate(t_all) if t_all else np.zeros(0)
    r_pool = np.concatenate(r_all) if r_all else np.zeros(0)
    n = int(t_pool.size)
    return KittiRpe(
        translation_percent=float(100.0 * t_pool.mean()) if n else math.nan,
        rotation_deg_per_100m=float(np.degrees(r_pool.mean()) * 100.0) if n else math.nan,
        n=n,
        per_length=tuple(per_length),
    )


@dataclass(frozen=True, slots=True)
class DistanceRpe:
    """RPE over consecutive pairs about ``distance_m`` of reference path apart.

    ``translation_percent`` is mean(|t(E)| / path length of the pair) x 100.
    """

    distance_m: float
    translation_m: ErrorStatistics
    rotation_deg: ErrorStatistics
    translation_percent: float


def _path_pairs(T_reference: np.ndarray, distance_m: float) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(T_reference, float)[:, :3, 3]
    ids = [0]
    travelled = 0.0
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    for index, step in enumerate(steps, start=1):
        travelled += float(step)
        if travelled >= distance_m:
            ids.append(index)
            travelled = 0.0
    ids_array = np.asarray(ids, dtype=np.int64)
    return ids_array[:-1], ids_array[1:]


def distance_rpe(T_reference: np.ndarray, T_estimate: np.ndarray, distance_m: float) -> DistanceRpe:
    """RPE per fixed distance (module docstring); empty statistics when the drive is shorter."""
    Q = np.asarray(T_reference, float)
    P = np.asarray(T_estimate, float)
    if len(Q) < 2:
        i = j = np.zeros(0, np.int64)
    else:
        i, j = _path_pairs(Q, distance_m)
    t_err, r_err = relative_errors(Q, P, i, j)
    distances = path_distances_m(Q) if len(Q) else np.zeros(0)
    segment = distances[j] - distances[i] if len(i) else np.zeros(0)
    return DistanceRpe(
        distance_m=float(distance_m),
        translation_m=ErrorStatistics.of(t_err),
        rotation_deg=ErrorStatistics.of(r_err),
        translation_percent=float(100.0 * np.mean(t_err / segment)) if len(i) else math.nan,
    )
