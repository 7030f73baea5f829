"""Reading ROS2 sqlite3 (``.db3``) storage files cut short (a recording killed or a copy interrupted).

SQLite refuses a file shorter than the page count its header declares ("database disk image is
malformed"). A padded temporary copy (zero pages in place of the missing tail) opens, and its
``messages`` table can be walked in rowid (recording) order until the first missing page.
:class:`Db3Recovery` does that; it presents the small part of a rosbags storage reader's interface
that :class:`lidar3d.io.bag_inputs.Ros2BagInput` uses, as :class:`lidar3d.io.mcap_recovery.McapRecovery`
does for MCAP files.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import struct
import tempfile
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path

from lidar3d.errors import BagError

__all__ = ["SQLITE_MAGIC", "Db3Recovery", "db3_is_truncated"]

logger = logging.getLogger(__name__)

SQLITE_MAGIC = b"SQLite format 3\x00"


def _page_geometry(head: bytes) -> tuple[int, int]:
    """``(page size in bytes, page count)`` from the first 100 bytes of an SQLite file."""
    (page_size,) = struct.unpack(">H", head[16:18])
    (n_pages,) = struct.unpack(">I", head[28:32])
    return (65536 if page_size == 1 else page_size), n_pages


def db3_is_truncated(path: Path) -> bool:
    """True when a .db3 file is shorter than the page count its SQLite header declares."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(100)
            size = os.fstat(handle.fileno()).st_size
    except OSError:
        return False
    if len(head) < 100 or not head.startswith(SQLITE_MAGIC):
        return False
    page_size, n_pages = _page_geometry(head)
    return size < page_size * n_pages


@dataclass(frozen=True, slots=True)
class Db3Topic:
    """A topic of the salvaged file: its message type and the number of readable messages."""

    msgtype: str
    msgcount: int


@dataclass(frozen=True, slots=True)
class Db3Connection:
    """A row of the ``topics`` table: its id and topic name."""

    id: int
    topic: str


class Db3Recovery:
    """The messages of a truncated ``.db3`` up to the damage, in recording (rowid) order.

    The padded copy costs disk, not memory, and is deleted on :meth:`close`.

    Attributes:
        topics: topic name -> :class:`Db3Topic` (counts of the readable messages).
        connections: one :class:`Db3Connection` per row of the ``topics`` table.
        start_time, end_time: first log time and one past the last (ns), as rosbags reports them.
        message_count: readable messages of every topic.
        n_lost: messages known to be cut off (always 0: SQLite pages hold whole rows, and without
            ``metadata.yaml`` nothing tells how many rows were in the missing pages).
        unreadable_bytes: always 0 (no compressed chunks in sqlite3 storage).
    """

    def __init__(self, path: Path) -> None:
        import sqlite3

        self.path = path
        self.n_lost = 0
        self.unreadable_bytes = 0
        self._tmpdir = tempfile.TemporaryDirectory(prefix="lidar3d-db3-")
        copy = Path(self._tmpdir.name) / path.name
        with open(path, "rb") as src, open(copy, "wb") as dst:
            shutil.copyfileobj(src, dst, 1 << 20)
            with open(path, "rb") as handle:
                page_size, n_pages = _page_geometry(handle.read(100))
            dst.truncate(page_size * n_pages)
        self._db = sqlite3.connect(f"file:{copy}?immutable=1", uri=True)
        try:
            rows = self._db.execute("SELECT id, name, type FROM topics").fetchall()
        except sqlite3.DatabaseError as err:
            self.close()
            raise BagError(f"{path}: storage file is truncated and its topic table is lost: {err}") from err
        topic_names = {int(i): str(name) for i, name, _t in rows}
        types = {str(name): str(t) for _i, name, t in rows}
        counts = dict.fromkeys(types, 0)
        self.start_time = 2**63 - 1
        self.end_time = 0
        self.message_count = 0
        try:
            for topic_id, stamp in self._db.execute("SELECT topic_id, timestamp FROM messages ORDER BY id"):
                name = topic_names.get(topic_id, "?")
                counts[name] = counts.get(name, 0) + 1
                self.start_time = min(self.start_time, stamp)
                self.end_time = max(self.end_time, stamp + 1)
                self.message_count += 1
        except sqlite3.DatabaseError:
            logger.debug("%s: messages table readable up to message %d", path, self.message_count)
        self.topics = {name: Db3Topic(types.get(name, "?"), count) for name, count in counts.items()}
        self.connections = [Db3Connection(i, name) for i, name in topic_names.items()]

    def messages(self, connections: Collection[Db3Connection]) -> Iterator[tuple[Db3Connection, int, bytes]]:
        """``(connection, log time ns, serialised message)`` of ``connections`` up to the damage."""
        import sqlite3

        wanted = {c.id: c for c in connections}
        count = 0
        query = "SELECT topic_id, timestamp, data FROM messages ORDER BY id"
        try:
            for topic_id, stamp, data in self._db.execute(query):
                if topic_id in wanted:
                    count += 1
                    yield wanted[topic_id], stamp, data
        except sqlite3.DatabaseError:
            logger.debug("%s: damaged after %d messages", self.path, count)

    def close(self) -> None:
        """Close the database and delete the padded copy."""
        with contextlib.suppress(Exception):
            self._db.close()
        self._tmpdir.cleanup()
