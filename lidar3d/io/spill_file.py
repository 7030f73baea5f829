"""One anonymous temporary file that a run spills long-lived arrays to (the dense map's pieces,
keyframe clouds), and what happens when it cannot: the shared part of
:class:`~lidar3d.io.piece_spill.SpilledPieceStore` and
:class:`~lidar3d.io.keyframe_spill.SpilledKeyframeClouds`.

The file is a ``tempfile.TemporaryFile``: it has no name on disk, so nothing is left behind
whatever ends the process. When it cannot be created or written (a full disk), the store keeps
what comes next in memory, with one warning naming the folder: the run goes on.
"""

from __future__ import annotations

import logging
import tempfile
from pathlib import Path
from typing import IO, TypeVar

__all__ = ["SpillFile"]

log = logging.getLogger(__name__)

_Store = TypeVar("_Store", bound="SpillFile")


class SpillFile:
    """Base of the spill stores: the file in ``directory`` (default: the system's temporary
    folder, ``TMPDIR``), whether it is still written to, and :meth:`close`. Use as a context
    manager or call :meth:`close`. ``what``: what the store holds, for the warning."""

    def __init__(self, directory: str | Path | None, what: str) -> None:
        self.directory = str(directory) if directory is not None else tempfile.gettempdir()
        self._what = what
        self._writing = True
        self._file: IO[bytes] | None = None
        try:
            self._file = tempfile.TemporaryFile(dir=directory)  # noqa: SIM115 (closed by close())
        except OSError as err:
            self._fall_back(err)

    def __enter__(self: _Store) -> _Store:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close (and so delete) the file."""
        if self._file is not None:
            self._file.close()
            self._file = None

    def _fall_back(self, err: OSError) -> None:
        """Keep the next arrays in memory (those in the file stay there)."""
        log.warning(
            "%s: cannot spill %s to a temporary file (%s); keeping them in memory",
            self.directory,
            self._what,
            err.strerror or err,
        )
        self._writing = False
