"""The dense map in pieces anchored to keyframes, so that it can be placed again when loop closures
move the keyframes, without reading the bag again.

Every sweep that enters the dense map (:class:`~lidar3d.mapping.dense_map.DenseMap`) also enters the
open *piece* of the keyframe it follows (the latest keyframe when it was placed: its *anchor*). A
piece holds, per voxel of the world grid at the time (``mapping.map_voxel_m``), the mean position,
expressed in the anchor's lidar frame, the mean intensity, the number of points and whether they
were judged dynamic. Once a sweep with another anchor (or with the same anchor after a loop closure
moved it) arrives, the open piece is closed and goes to a :class:`PieceStore`.

Placing the map again (:func:`place_pieces`) moves each piece with its anchor's final pose and
averages the piece voxels that fall into the same world voxel, weighted by their point counts. Each
scan thus takes its anchor keyframe's correction, where :func:`~lidar3d.loop.closer.correct_scan_poses`
interpolates between the two keyframes around it: the difference is the change of the correction
over one keyframe spacing (millimetres after a loop of hundreds of metres). The voxels of a piece
move whole, so a point can land in the voxel next to the one the rebuild from the bag would put it
in; the map stays on the same surfaces (docs/stages/dense-map.md gives the measured difference).

Frames: world = the map frame; anchor = the anchor keyframe's lidar frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lidar3d.mapping.se3 import invert, transform_points
from lidar3d.mapping.voxel import VoxelMap

__all__ = ["MapAnchor", "MapPiece", "MapPieces", "MemoryPieceStore", "PieceStore", "place_pieces"]


@dataclass(frozen=True, slots=True)
class MapAnchor:
    """The keyframe a sweep follows, as known when the sweep was placed.

    Attributes:
        keyframe: keyframe index (0, 1, ...); None before the first keyframe (the sweep stays where
            it was placed, as the first keyframe is held by the pose graph).
        T_world_keyframe: (4,4) that keyframe's pose then (the sweep's world points were placed
            consistently with it); the identity for ``keyframe`` None.
    """

    keyframe: int | None
    T_world_keyframe: np.ndarray


@dataclass(frozen=True, slots=True)
class MapPiece:
    """The voxels of the sweeps that followed one keyframe, in that keyframe's frame.

    Attributes:
        keyframe: index of the anchor keyframe (None: the world frame itself, see :class:`MapAnchor`).
        points_keyframe: (V,3) float32 metres, mean position per voxel, anchor frame.
        intensity: (V,) float32 mean intensity per voxel.
        count: (V,) int32 points per voxel.
        dynamic: (V,) bool, the voxel's points were judged dynamic (moving objects).
    """

    keyframe: int | None
    points_keyframe: np.ndarray
    intensity: np.ndarray
    count: np.ndarray
    dynamic: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.points_keyframe)
        if self.points_keyframe.shape != (n, 3) or not (
            len(self.intensity) == len(self.count) == len(self.dynamic) == n
        ):
            raise ValueError("a map piece needs (V,3) points and (V,) intensity, count and dynamic")

    @property
    def nbytes(self) -> int:
        """Bytes held by the piece's arrays."""
        return sum(a.nbytes for a in (self.points_keyframe, self.intensity, self.count, self.dynamic))


class PieceStore(Protocol):
    """Where closed pieces wait until the map is placed again (in memory, or spilled to disk by an
    adapter: :class:`lidar3d.io.piece_spill.SpilledPieceStore`)."""

    def put(self, piece: MapPiece) -> None:
        """Keep ``piece``."""

    def pieces(self):
        """Every piece kept, in the order they were put (an iterable of :class:`MapPiece`)."""

    def close(self) -> None:
        """Release what the store holds (the store is not used afterwards)."""


class MemoryPieceStore:
    """Pieces kept in a list in memory."""

    def __init__(self) -> None:
        self._pieces: list[MapPiece] = []

    def put(self, piece: MapPiece) -> None:
        """Keep ``piece``."""
        self._pieces.append(piece)

    def pieces(self) -> list[MapPiece]:
        """Every piece kept, in order."""
        return list(self._pieces)

    def close(self) -> None:
        """Drop the pieces."""
        self._pieces = []

    def __len__(self) -> int:
        return len(self._pieces)


class MapPieces:
    """Collects placed sweeps into pieces by anchor; call :meth:`add` per sweep (in the order they
    enter the map), :meth:`close` at the end of input, then :func:`place_pieces` on :attr:`store`.

    Args:
        voxel_m: the map's voxel (``mapping.map_voxel_m``).
        store: where closed pieces go (default in memory).
    """

    def __init__(self, voxel_m: float, store: PieceStore | None = None) -> None:
        self.voxel_m = float(voxel_m)
        self.store: PieceStore = store if store is not None else MemoryPieceStore()
        self._anchor: MapAnchor | None = None
        self._static = VoxelMap(self.voxel_m)
        self._dynamic = VoxelMap(self.voxel_m)
        self.n_pieces = 0

    def add(self, anchor: MapAnchor, keys: np.ndarray, sums: np.ndarray, dynamic: np.ndarray) -> None:
        """Add a sweep grouped by world voxel of :attr:`voxel_m`: (V,) unique keys, (V,5) sums of x, y, z,
        intensity and count per voxel (world frame, placed consistently with ``anchor``), (V,) bool
        dynamic flags."""
        self._follow(anchor)
        self._static.insert_grouped(keys[~dynamic], sums[~dynamic])
        self._dynamic.insert_grouped(keys[dynamic], sums[dynamic])

    def add_points(self, anchor: MapAnchor, points_world: np.ndarray, intensity: np.ndarray, dynamic: np.ndarray):
        """Add a sweep as (N,3) world points (placed consistently with ``anchor``), (N,) intensities and
        (N,) bool dynamic flags."""
        self._follow(anchor)
        self._static.insert(points_world[~dynamic], intensity[~dynamic])
        self._dynamic.insert(points_world[dynamic], intensity[dynamic])

    def close(self) -> None:
        """End of input: the open piece goes to the store."""
        if self._anchor is None:
            return
        anchor, self._anchor = self._anchor, None
        T_keyframe_world = invert(anchor.T_world_keyframe)
        parts = []
        for voxel_map, dynamic in ((self._static, False), (self._dynamic, True)):
            _, count = voxel_map.voxel_counts()
            points, intensity = voxel_map.points_and_intensity()
            parts.append((transform_points(T_keyframe_world, points), intensity, count, np.full(len(count), dynamic)))
        self.store.put(
            MapPiece(
                anchor.keyframe,
                np.concatenate([p[0] for p in parts]).astype(np.float32),
                np.concatenate([p[1] for p in parts]).astype(np.float32),
                np.concatenate([p[2] for p in parts]).astype(np.int32),
                np.concatenate([p[3] for p in parts]),
            )
        )
        self.n_pieces += 1
        self._static = VoxelMap(self.voxel_m)
        self._dynamic = VoxelMap(self.voxel_m)

    def _follow(self, anchor: MapAnchor) -> None:
        """Close the open piece when ``anchor`` is another keyframe, or the same one moved since."""
        open_ = self._anchor
        if open_ is not None and (
            open_.keyframe != anchor.keyframe or not np.array_equal(open_.T_world_keyframe, anchor.T_world_keyframe)
        ):
            self.close()
        if self._anchor is None:
            self._anchor = anchor


def place_pieces(pieces, keyframe_poses: np.ndarray, voxel_m: float) -> tuple[VoxelMap, VoxelMap]:
    """The static and the dynamic voxel map of ``pieces`` (an iterable of :class:`MapPiece`), each moved
    with its anchor's pose in ``keyframe_poses`` (K,4,4); piece voxels falling into one world voxel
    of ``voxel_m`` are averaged, weighted by their counts."""
    static, dynamic = VoxelMap(voxel_m), VoxelMap(voxel_m)
    for piece in pieces:
        points_world = piece.points_keyframe.astype(np.float64)
        if piece.keyframe is not None:
            points_world = transform_points(keyframe_poses[piece.keyframe], points_world)
        count = piece.count.astype(np.float64)
        for voxel_map, rows in ((static, ~piece.dynamic), (dynamic, piece.dynamic)):
            voxel_map.insert_weighted(points_world[rows], piece.intensity[rows].astype(np.float64), count[rows])
    return static, dynamic
