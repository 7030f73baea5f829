"""Voxel-grid downsampling and an incremental voxel map for the dense point-cloud map."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "KeyedCloud",
    "VoxelMap",
    "group_by_voxel",
    "group_sums",
    "key_groups",
    "voxel_downsample",
    "voxel_downsample_parts",
    "voxel_key_step",
    "voxel_keys",
]

_OFFSET = 1 << 20  # voxel indices are shifted into [0, 2^21) per axis before packing


def voxel_keys(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """Pack the integer voxel coordinates of (N,3) points into one int64 per point.

    Covers +-2^20 voxels per axis (about +-200 km at 0.2 m).
    """
    ijk = np.floor(points / voxel_m).astype(np.int64) + _OFFSET
    return (ijk[:, 0] << 42) | (ijk[:, 1] << 21) | ijk[:, 2]


def voxel_key_step(di: int, dj: int, dk: int) -> int:
    """What to add to a :func:`voxel_keys` key for the key of the voxel (di, dj, dk) voxels away
    (each within +-1: the neighbour's indices stay in range for any voxel not at the edge of the
    packed range)."""
    return (di << 42) + (dj << 21) + dk


def key_groups(keys: np.ndarray, counts: bool = False, order: np.ndarray | None = None) -> tuple[np.ndarray, ...]:
    """The groups of equal (N,) integer ``keys``: ``(unique, inverse)``, the sorted unique keys and
    each key's row in them, plus ``counts`` (per unique key) when asked; the same arrays as
    ``np.unique(keys, return_inverse=True, return_counts=counts)``.

    np.unique sorts with quicksort. Voxel keys come in runs of nearby points (a scan in firing
    order, a submap keyframe by keyframe), which a stable sort (timsort) merges instead of sorting
    again: 9 against 15 ms for the 265,000 keys of a `loop` submap (docs/performance.md).
    ``order``: a stable sorting permutation of ``keys`` when the caller has one already.
    """
    keys = np.asarray(keys).reshape(-1)
    if keys.size == 0:
        empty = (keys.copy(), np.zeros(0, np.intp))
        return (*empty, np.zeros(0, np.intp)) if counts else empty
    if order is None:
        order = np.argsort(keys, kind="stable")
    ordered = keys[order]
    first = np.empty(keys.size, dtype=bool)
    first[0] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    inverse = np.empty(keys.size, dtype=np.intp)
    inverse[order] = np.cumsum(first) - 1
    unique = ordered[first]
    if not counts:
        return unique, inverse
    return unique, inverse, np.diff(np.r_[np.flatnonzero(first), keys.size])


def voxel_downsample(points: np.ndarray, voxel_m: float, values: np.ndarray | None = None):
    """Replace the points of each occupied voxel by their centroid.

    Returns the (M,3) centroids, and when ``values`` (N,) is given also their per-voxel means.
    Output order is by voxel key, so it is deterministic.
    """
    if len(points) == 0 or voxel_m <= 0:
        return (points, values) if values is not None else points
    keys = voxel_keys(points, voxel_m)
    _, inverse, counts = key_groups(keys, counts=True)
    centroids = group_sums(inverse, points, counts.size) / counts[:, None]
    if values is None:
        return centroids
    mean_values = np.bincount(inverse, weights=values, minlength=counts.size) / counts
    return centroids, mean_values


@dataclass(frozen=True, slots=True)
class KeyedCloud:
    """A cloud with its voxel keys and their stable sort, for clouds filtered together again and
    again (a submap's keyframes, each rebuild a different set of them).

    Attributes:
        points: (N,3) points, any frame (the one the voxels are in).
        keys: (N,) :func:`voxel_keys` of ``points``.
        order: (N,) the stable sorting permutation of ``keys``.
    """

    points: np.ndarray
    keys: np.ndarray
    order: np.ndarray

    @staticmethod
    def of(points: np.ndarray, voxel_m: float) -> KeyedCloud:
        keys = voxel_keys(points, voxel_m)
        return KeyedCloud(points, keys, np.argsort(keys, kind="stable"))


def voxel_downsample_parts(parts: Sequence[KeyedCloud]) -> np.ndarray:
    """(M,3) :func:`voxel_downsample` of the concatenated ``parts`` (keyed with one voxel size),
    to the bit, from their sorted keys: the sort of the whole merges the parts' sorted runs
    instead of sorting every key again, and no key is computed again.

    A stable sort of the runs orders equal keys by part, then by their order within the part:
    the concatenation's own stable order, so the groups, and the sums taken in point order, are
    the same.
    """
    if not parts:
        return np.zeros((0, 3))
    points = np.concatenate([part.points for part in parts])
    if len(points) == 0:
        return points
    keys = np.concatenate([part.keys for part in parts])
    starts = np.cumsum([0] + [len(part.keys) for part in parts[:-1]])
    in_runs = np.concatenate([start + part.order for start, part in zip(starts, parts)])
    order = in_runs[np.argsort(keys[in_runs], kind="stable")]
    _, inverse, counts = key_groups(keys, counts=True, order=order)
    return group_sums(inverse, points, counts.size) / counts[:, None]


def group_sums(inverse: np.ndarray, values: np.ndarray, n_groups: int) -> np.ndarray:
    """Column-wise sums of (N,D) ``values`` per group (bincount is far faster than add.at)."""
    return np.column_stack(
        [np.bincount(inverse, weights=values[:, d], minlength=n_groups) for d in range(values.shape[1])]
    )


def group_by_voxel(points: np.ndarray, intensity: np.ndarray, voxel_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(N,3) points and their (N,) intensities grouped by voxel: (V,) sorted unique keys
    (:func:`voxel_keys`) and (V,5) per voxel the sums of x, y, z and intensity and the count."""
    keys = voxel_keys(points, voxel_m)
    uniq, inverse, counts = key_groups(keys, counts=True)
    sums = group_sums(inverse, points, uniq.size)
    isum = np.bincount(inverse, weights=intensity, minlength=uniq.size)
    return uniq, np.column_stack([sums, isum, counts])


def _interleaved(old: np.ndarray, at_old: np.ndarray, new: np.ndarray, at_new: np.ndarray) -> np.ndarray:
    """The rows of ``old`` and ``new`` in one array, at rows ``at_old`` and ``at_new`` of it."""
    out = np.empty((len(old) + len(new), *old.shape[1:]), old.dtype)
    out[at_old] = old
    out[at_new] = new
    return out


class VoxelMap:
    """Dense map accumulated scan by scan: per voxel, the mean position and intensity.

    Insertions are buffered and merged in batches, so adding a scan costs a few array
    operations. Memory grows with the mapped volume, not with the number of scans.
    """

    def __init__(self, voxel_m: float, merge_every_points: int = 500_000) -> None:
        if voxel_m <= 0:
            raise ValueError("voxel_m must be positive")
        self.voxel_m = float(voxel_m)
        self._merge_every = merge_every_points
        self._keys = np.zeros(0, np.int64)
        self._sum_xyz = np.zeros((0, 3))
        self._sum_intensity = np.zeros(0)
        self._count = np.zeros(0, np.int64)
        self._pending: list[tuple[np.ndarray, np.ndarray]] = []
        self._pending_points = 0

    def insert(self, points_world: np.ndarray, intensity: np.ndarray) -> None:
        """Add (N,3) world-frame points with their (N,) intensities."""
        if len(points_world) == 0:
            return
        # Reduce each scan on its own first: a scan at 0.2 m shrinks about tenfold.
        self.insert_grouped(*group_by_voxel(points_world, intensity, self.voxel_m))

    def insert_grouped(self, keys: np.ndarray, sums: np.ndarray) -> None:
        """Add points already grouped by voxel of this map's size: (V,) unique ``keys`` and (V,5) per
        voxel the sums of x, y, z, intensity and the count (as :meth:`insert` reduces a scan)."""
        if len(keys) == 0:
            return
        self._pending.append((keys, sums))
        self._pending_points += keys.size
        if self._pending_points >= self._merge_every:
            self._merge()

    def insert_weighted(self, points_world: np.ndarray, intensity: np.ndarray, weight: np.ndarray) -> None:
        """Add (N,3) world-frame points that each stand for ``weight`` (N,) points (the voxel means of
        another grid, ``weight`` their counts), with their (N,) mean intensities."""
        if len(points_world) == 0:
            return
        keys = voxel_keys(points_world, self.voxel_m)
        uniq, inverse = key_groups(keys)
        weighted = np.column_stack([points_world * weight[:, None], intensity * weight, weight])
        self._pending.append((uniq, group_sums(inverse, weighted, uniq.size)))
        self._pending_points += uniq.size
        if self._pending_points >= self._merge_every:
            self._merge()

    def _merge(self) -> None:
        """Add the pending voxels into the map.

        Only the map's voxels that the pending ones touch are summed again with them (the map's sum
        first, then the pending in insertion order: the sums of merging everything at once); new
        voxels are inserted in key order. Memory: the map once more at most, not the map's
        concatenation with the pending sorted and summed again.
        """
        if not self._pending:
            return
        new_keys = np.concatenate([k for k, _ in self._pending])
        new_data = np.concatenate([d for _, d in self._pending])
        self._pending = []
        self._pending_points = 0
        at = np.minimum(np.searchsorted(self._keys, new_keys), max(self._keys.size - 1, 0))
        touched = np.unique(at[self._keys[at] == new_keys]) if self._keys.size else np.zeros(0, np.int64)
        old = np.column_stack([self._sum_xyz[touched], self._sum_intensity[touched], self._count[touched]])
        uniq, inverse = key_groups(np.concatenate([self._keys[touched], new_keys]))
        merged = group_sums(inverse, np.concatenate([old, new_data]), uniq.size)
        rows = np.searchsorted(self._keys, uniq)
        known = np.isin(uniq, self._keys[touched], assume_unique=True)
        self._sum_xyz[rows[known]] = merged[known, :3]
        self._sum_intensity[rows[known]] = merged[known, 3]
        self._count[rows[known]] = merged[known, 4].astype(np.int64)
        fresh = ~known
        if not fresh.any():
            return
        # Interleave the new voxels into the key order: where every old and every new row goes.
        fresh_keys = uniq[fresh]
        at_new = rows[fresh] + np.arange(fresh_keys.size)
        at_old = np.arange(self._keys.size) + np.searchsorted(fresh_keys, self._keys)
        self._keys = _interleaved(self._keys, at_old, fresh_keys, at_new)
        self._sum_xyz = _interleaved(self._sum_xyz, at_old, merged[fresh, :3], at_new)
        self._sum_intensity = _interleaved(self._sum_intensity, at_old, merged[fresh, 3], at_new)
        self._count = _interleaved(self._count, at_old, merged[fresh, 4].astype(np.int64), at_new)

    def __len__(self) -> int:
        self._merge()
        return int(self._keys.size)

    def points_and_intensity(self) -> tuple[np.ndarray, np.ndarray]:
        """(M,3) voxel mean positions and (M,) mean intensities."""
        self._merge()
        if self._keys.size == 0:
            return np.zeros((0, 3)), np.zeros(0)
        count = self._count[:, None].astype(np.float64)
        return self._sum_xyz / count, self._sum_intensity / count[:, 0]

    def voxel_counts(self) -> tuple[np.ndarray, np.ndarray]:
        """(M,) sorted voxel keys (:func:`voxel_keys`) and (M,) points that fell into each."""
        self._merge()
        return self._keys.copy(), self._count.copy()

    def move_voxels(self, keys: np.ndarray, other: VoxelMap) -> None:
        """Move the voxels ``keys`` (those present) with all their points into ``other`` (same voxel size)."""
        self._merge()
        if other.voxel_m != self.voxel_m:
            raise ValueError("voxel maps of different voxel sizes")
        moving = np.isin(self._keys, keys)
        if not moving.any():
            return
        data = np.column_stack([self._sum_xyz, self._sum_intensity, self._count])
        other._pending.append((self._keys[moving], data[moving]))
        other._pending_points += int(moving.sum())
        other._merge()
        stay = ~moving
        self._keys, self._sum_xyz = self._keys[stay], self._sum_xyz[stay]
        self._sum_intensity, self._count = self._sum_intensity[stay], self._count[stay]
