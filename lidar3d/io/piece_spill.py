"""The dense map's pieces spilled to a temporary file while a run goes (the
:class:`~lidar3d.mapping.map_pieces.PieceStore` ``lidar3d run`` uses), so that memory does not grow
with the length of the bag.

Each closed piece is appended to one anonymous temporary file (``tempfile.TemporaryFile``: it has no
name on disk, so nothing is left behind whatever ends the process) as five ``.npy`` records; the
pieces are read back in order when the map is placed again. About 20 bytes per piece voxel: some
0.35 MB per keyframe at ``mapping.map_voxel_m`` 0.2 m. When the file cannot be created or written
(a full disk), the pieces from then on are kept in memory, with one warning: the run goes on.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np

from lidar3d.io.spill_file import SpillFile
from lidar3d.mapping.map_pieces import MapPiece

__all__ = ["SpilledPieceStore"]

_NO_KEYFRAME = -1  # stands for MapPiece.keyframe None on disk


class SpilledPieceStore(SpillFile):
    """Pieces written to an anonymous temporary file in ``directory`` (default: the system's
    temporary folder, ``TMPDIR``); use as a context manager or call :meth:`close`.

    Attributes:
        nbytes: bytes of the pieces put (on disk or, after a failure, in memory).
    """

    def __init__(self, directory: str | Path | None = None) -> None:
        super().__init__(directory, "the dense map's pieces")
        self._in_memory: list[MapPiece] = []
        self._n_on_disk = 0
        self.nbytes = 0

    def __len__(self) -> int:
        return self._n_on_disk + len(self._in_memory)

    def put(self, piece: MapPiece) -> None:
        """Append ``piece`` to the file (to memory once the file has failed)."""
        self.nbytes += piece.nbytes
        if self._file is not None and self._writing:
            keyframe = _NO_KEYFRAME if piece.keyframe is None else piece.keyframe
            end = self._file.seek(0, 2)
            try:
                for array in (np.array([keyframe], np.int64), *_arrays(piece)):
                    np.save(self._file, array, allow_pickle=False)
                self._n_on_disk += 1
                return
            except OSError as err:
                self._file.truncate(end)  # the pieces written before stay readable
                self._fall_back(err)
        self._in_memory.append(piece)

    def pieces(self) -> Iterator[MapPiece]:
        """Every piece, in the order put, read back one at a time."""
        if self._file is not None:
            self._file.flush()
            self._file.seek(0)
        for _ in range(self._n_on_disk):
            assert self._file is not None
            keyframe, points, intensity, count, dynamic = (np.load(self._file, allow_pickle=False) for _ in range(5))
            yield MapPiece(None if keyframe[0] == _NO_KEYFRAME else int(keyframe[0]), points, intensity, count, dynamic)
        yield from self._in_memory

    def close(self) -> None:
        """Close (and so delete) the file, drop the pieces."""
        super().close()
        self._in_memory = []


def _arrays(piece: MapPiece) -> tuple[np.ndarray, ...]:
    return piece.points_keyframe, piece.intensity, piece.count, piece.dynamic
