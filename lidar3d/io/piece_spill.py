"""The dense map's pieces spilled to a temporary file while a run goes (the
:class:`~lidar3d.mapping.map_pieces.PieceStore` ``lidar3d run`` uses), so that memory does not grow
with the length of the bag.

Each closed piece is appended to one anonymous temporary file (``tempfile.TemporaryFile``: it has no
name on disk, so nothing is left behind whatever ends the process) as five ``.npy`` records; the
pieces are read back in order when the map is placed again. About 20 bytes per piece voxel: some
150 kB per keyframe at ``mapping.map_voxel_m`` 0.2 m.
"""

from __future__ import annotations

import tempfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from lidar3d.errors import OutputError
from lidar3d.mapping.map_pieces import MapPiece

__all__ = ["SpilledPieceStore"]

_NO_KEYFRAME = -1  # stands for MapPiece.keyframe None on disk


class SpilledPieceStore:
    """Pieces written to an anonymous temporary file in ``directory`` (default: the system's
    temporary folder, ``TMPDIR``); use as a context manager or call :meth:`close`.

    Raises:
        OutputError: the temporary file cannot be created or written (a full disk, say).
    """

    def __init__(self, directory: str | Path | None = None) -> None:
        try:
            self._file = tempfile.TemporaryFile(dir=directory)  # noqa: SIM115 (closed by close())
        except OSError as err:
            raise OutputError(
                f"{directory or tempfile.gettempdir()}: cannot create the map's spill file: {err}"
            ) from err
        self._n_pieces = 0
        self.nbytes = 0

    def __enter__(self) -> SpilledPieceStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __len__(self) -> int:
        return self._n_pieces

    def put(self, piece: MapPiece) -> None:
        """Append ``piece`` to the file."""
        keyframe = _NO_KEYFRAME if piece.keyframe is None else piece.keyframe
        try:
            self._file.seek(0, 2)
            for array in (
                np.array([keyframe], np.int64),
                piece.points_keyframe,
                piece.intensity,
                piece.count,
                piece.dynamic,
            ):
                np.save(self._file, array, allow_pickle=False)
        except OSError as err:
            raise OutputError(f"{self._file.name}: cannot write the map's spill file: {err}") from err
        self._n_pieces += 1
        self.nbytes += piece.nbytes

    def pieces(self) -> Iterator[MapPiece]:
        """Every piece, in the order put, read back one at a time."""
        self._file.flush()
        self._file.seek(0)
        for _ in range(self._n_pieces):
            keyframe, points, intensity, count, dynamic = (np.load(self._file, allow_pickle=False) for _ in range(5))
            yield MapPiece(None if keyframe[0] == _NO_KEYFRAME else int(keyframe[0]), points, intensity, count, dynamic)

    def close(self) -> None:
        """Close (and so delete) the file."""
        self._file.close()
