"""Keyframe clouds spilled to a temporary file while a run goes (the
:class:`~lidar3d.mapping.keyframes.KeyframeCloudStore` ``lidar3d run`` uses), so that the tracking's
memory does not grow with the length of the bag.

A keyframe keeps its corner and surface clouds (float32, lidar frame, about 75 KiB on a VLP-16
drive) for as long as the run goes: the submap reads them again when the drive comes back to the
keyframe, the loop verification when a revisit is proposed near it. Only the latest few are read
often, so :class:`~lidar3d.mapping.keyframes.Submap` hands older ones to this store, which appends
them to one anonymous temporary file (``tempfile.TemporaryFile``: no name on disk, nothing left
behind whatever ends the process) and reads them back by offset (``os.preadv``: no shared file
position). The bytes read back are the bytes written, so a run's outputs do not depend on where
its clouds were. When the file cannot be created or written (a full disk), the clouds from then
on are kept in memory, with one warning: the run goes on.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from lidar3d.io.spill_file import SpillFile

__all__ = ["SpilledKeyframeClouds"]

_DTYPE = np.dtype(np.float32)


class SpilledKeyframeClouds(SpillFile):
    """Keyframe clouds in an anonymous temporary file in ``directory`` (default: the system's
    temporary folder, ``TMPDIR``); use as a context manager or call :meth:`close`.

    Attributes:
        nbytes: bytes of the clouds put (on disk or, after a failure, in memory); a cloud put
            again for the same keyframe counts again (the file only grows).
    """

    def __init__(self, directory: str | Path | None = None) -> None:
        super().__init__(directory, "keyframe clouds")
        self._where: dict[int, tuple[int, int, int]] = {}  # keyframe -> (offset, corner rows, surface rows)
        self._in_memory: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._end = 0
        self.nbytes = 0

    def __contains__(self, keyframe: int) -> bool:
        return keyframe in self._where or keyframe in self._in_memory

    def put(self, keyframe: int, corner_points: np.ndarray, surf_points: np.ndarray) -> None:
        """Keep keyframe ``keyframe``'s (M,3) corner and (K,3) surface points (stored as float32,
        the pipeline's keyframe clouds' type); a later put for the same keyframe replaces them."""
        corner = np.ascontiguousarray(corner_points, dtype=_DTYPE).reshape(-1, 3)
        surf = np.ascontiguousarray(surf_points, dtype=_DTYPE).reshape(-1, 3)
        self.nbytes += corner.nbytes + surf.nbytes
        self._where.pop(keyframe, None)
        self._in_memory.pop(keyframe, None)
        if self._file is not None and self._writing:
            size = corner.nbytes + surf.nbytes
            try:
                written = os.pwritev(self._file.fileno(), [corner.data, surf.data], self._end)  # no copy
                if written != size:
                    raise OSError(f"wrote {written} of {size} bytes")
            except OSError as err:
                self._fall_back(err)
            else:
                self._where[keyframe] = (self._end, len(corner), len(surf))
                self._end += size
                return
        self._in_memory[keyframe] = (corner, surf)

    def get(self, keyframe: int) -> tuple[np.ndarray, np.ndarray]:
        """Keyframe ``keyframe``'s (M,3) corner and (K,3) surface points (float32; new arrays).

        Raises:
            KeyError: nothing was put for ``keyframe``.
        """
        if keyframe in self._in_memory:
            corner, surf = self._in_memory[keyframe]
            return corner.copy(), surf.copy()
        offset, n_corner, n_surf = self._where[keyframe]
        assert self._file is not None
        points = np.empty((n_corner + n_surf, 3), _DTYPE)
        read = os.preadv(self._file.fileno(), [points.data], offset)  # into the array, no copy
        if read != points.nbytes:
            raise OSError(f"{self.directory}: keyframe {keyframe}'s clouds came back short ({read} of {points.nbytes})")
        return points[:n_corner], points[n_corner:]

    def close(self) -> None:
        """Close (and so delete) the file, drop the clouds."""
        super().close()
        self._where = {}
        self._in_memory = {}
