"""Scans from ROS1 bags and ROS2 bag folders: a lazy, time-ordered, context-manager scan source.

Inputs (sniffed from their content, not their names):

* ROS1 ``.bag`` files. Several files given together (``rosbag record --split``) are merged by
  log time into one stream. A bag without a usable index (a recording killed mid-write, or a file
  cut short) is walked record by record (:mod:`lidar3d.io.ros1_recovery`): every complete message
  is read, in file order, and a warning says how many records were cut off.
* ROS2 bag folders with sqlite3 (``.db3``) or mcap storage, read through ``rosbags``. A folder
  without ``metadata.yaml`` (``ros2 bag record`` writes it only when it stops cleanly) is read from
  its storage files directly, with a warning. A single ``.db3``/``.mcap`` file works too. A
  ``.db3`` cut short is read up to the first missing page (a zero-padded temporary copy makes
  SQLite open it); an ``.mcap`` without its footer (killed writer, or cut short) is walked record
  by record (:mod:`lidar3d.io.mcap_recovery`). Either way every complete message before the
  damage is read, in recording order, and a warning says how many were lost (all the missing
  ones when ``metadata.yaml`` gives the count, otherwise the one cut off at the end).

Messages are deserialised with ``rosbags`` typestores (ROS1 Noetic, ROS2 Humble; PointCloud2 is the
same in every distribution) and decoded by :func:`lidar3d.io.pointcloud2.decode_parts`. Only one
message is held at a time, so memory does not grow with the bag's length.
"""

from __future__ import annotations

import abc
import contextlib
import dataclasses
import functools
import heapq
import logging
import os
import shutil
import struct
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np

from lidar3d.errors import BagError, PointCloudError
from lidar3d.io.pointcloud2 import (
    RING_FIELD_NAMES,
    DecodeStats,
    PointCloud2Parts,
    decode_parts,
    parts_from_message,
    ring_table_from_elevation,
)
from lidar3d.io.mcap_recovery import McapRecovery, mcap_is_unfinished
from lidar3d.io.ros1_recovery import ROS1_MAGIC, Ros1Recovery
from lidar3d.records import Scan
from lidar3d.sensors import VLP16, SensorModel

__all__ = [
    "BagFormat",
    "TopicInfo",
    "ReadStats",
    "ScanSource",
    "open_scan_source",
    "choose_lidar_topic",
    "deserialize_cloud",
    "header_stamp_ns",
    "bag_label",
    "POINTCLOUD2_TYPE",
]

logger = logging.getLogger(__name__)

POINTCLOUD2_TYPE = "sensor_msgs/msg/PointCloud2"
_SQLITE_MAGIC = b"SQLite format 3\x00"
_MCAP_MAGIC = b"\x89MCAP"
_STAMP = struct.Struct("<iI")


class BagFormat(str, Enum):
    """Container format of one input."""

    ROS1 = "ros1"
    ROS2 = "ros2"


@dataclass(frozen=True, slots=True)
class TopicInfo:
    """A topic of a bag: ``name``, message type (ROS2 style, ``pkg/msg/Type``) and message count."""

    name: str
    msgtype: str
    count: int


@dataclass(frozen=True, slots=True)
class ReadStats:
    """Totals over the scans read so far (counts of scans, points and messages)."""

    n_scans: int = 0
    n_points_in: int = 0
    n_points_kept: int = 0
    n_nonfinite: int = 0
    n_below_min_range: int = 0
    n_lost_messages: int = 0

    def add(self, stats: DecodeStats) -> "ReadStats":
        return ReadStats(
            n_scans=self.n_scans + 1,
            n_points_in=self.n_points_in + stats.n_input,
            n_points_kept=self.n_points_kept + stats.n_kept,
            n_nonfinite=self.n_nonfinite + stats.n_nonfinite,
            n_below_min_range=self.n_below_min_range + stats.n_below_min_range,
            n_lost_messages=self.n_lost_messages,
        )


def bag_label(paths: Sequence[Path]) -> str:
    """How error messages name the input: the path, or the first paths and a count."""
    if len(paths) == 1:
        return str(paths[0])
    shown = ", ".join(str(p) for p in paths[:3])
    return shown + (f" (+{len(paths) - 3} more)" if len(paths) > 3 else "")


@functools.lru_cache(maxsize=None)
def _typestore(fmt: BagFormat) -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if fmt is BagFormat.ROS1 else Stores.ROS2_HUMBLE)


def header_stamp_ns(fmt: BagFormat, raw: bytes | memoryview) -> int:
    """The ``std_msgs/Header`` stamp at the start of a serialised message, without deserialising.

    ROS1: ``uint32 seq, uint32 sec, uint32 nsec``. CDR: a 4-byte encapsulation header, then
    ``int32 sec, uint32 nanosec``. Both put the stamp at bytes 4..12.
    """
    sec, nanosec = _STAMP.unpack_from(raw, 4)
    return sec * 1_000_000_000 + nanosec


# --------------------------------------------------------------------------------------------
# One input (a ROS1 file, a ROS2 folder, or a ROS2 storage file)


class _Input(abc.ABC):
    """One opened input: topics, times, and raw messages of chosen topics in log-time order."""

    fmt: BagFormat
    path: Path
    topics: dict[str, TopicInfo]
    start_ns: int | None
    end_ns: int | None
    n_lost: int
    note: str  # how the input was read when not the normal way (for warnings and `info`)

    @abc.abstractmethod
    def messages(self, topic: str) -> Iterator[tuple[int, bytes]]:
        """``(log time ns, serialised message)`` of ``topic`` in log-time order."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release files and database handles."""


def _cut_off_text(n_lost: int) -> str:
    return f"{n_lost} incomplete message(s) at the end lost" if n_lost else "no message was cut off"


class _Ros1Input(_Input):
    def __init__(self, path: Path) -> None:
        from rosbags.rosbag1 import Reader, ReaderError

        self.fmt = BagFormat.ROS1
        self.path = path
        self.n_lost = 0
        self.note = ""
        self._reader: Any = None
        self._recovery: Ros1Recovery | None = None
        reader = Reader(path)
        try:
            reader.open()
        except ReaderError as err:
            reason = str(err)
            if "index" not in reason.lower():
                raise BagError(f"{path}: not a readable ROS1 bag: {reason}") from err
            if "not indexed" in reason:
                self._open_recovery("no index: the recording was not closed cleanly")
            else:
                self._open_recovery("index unreadable: the file is cut short")
            return
        except (OSError, struct.error, ValueError):
            self._open_recovery("index unreadable: the file is cut short")
            return
        self._reader = reader
        self.topics = {
            name: TopicInfo(name, info.msgtype or "?", info.msgcount) for name, info in reader.topics.items()
        }
        count = sum(t.count for t in self.topics.values())
        self.start_ns = reader.start_time if count else None
        # rosbags reports end_time one nanosecond after the last message.
        self.end_ns = reader.end_time - 1 if count else None

    def _open_recovery(self, reason: str) -> None:
        recovery = Ros1Recovery(self.path)
        survey = recovery.survey()
        self._recovery = recovery
        self.n_lost = survey.n_lost
        topics: dict[str, TopicInfo] = {}
        for conn in survey.connections.values():
            old = topics.get(conn.topic)
            topics[conn.topic] = TopicInfo(conn.topic, conn.msgtype, conn.count + (old.count if old else 0))
        self.topics = topics
        self.start_ns = survey.start_ns
        self.end_ns = survey.end_ns
        lost = _cut_off_text(survey.n_lost)
        if survey.unreadable_bytes:
            lost += f"; an unfinished compressed chunk of {survey.unreadable_bytes} bytes could not be read"
        self.note = f"bag is truncated ({reason}): read {survey.n_messages} complete message(s) in file order; {lost}"

    def messages(self, topic: str) -> Iterator[tuple[int, bytes]]:
        if self._recovery is not None:
            ids = {c.conn_id for c in self._recovery.connections.values() if c.topic == topic}
            for _conn_id, log_ns, raw in self._recovery.messages(ids):
                yield log_ns, raw
            return
        from rosbags.rosbag1 import ReaderError

        connections = [c for c in self._reader.connections if c.topic == topic]
        try:
            for _conn, log_ns, raw in self._reader.messages(connections=connections):
                yield log_ns, raw
        except (ReaderError, struct.error, OSError) as err:
            raise BagError(f"{self.path}: bag data is damaged: {err}") from err

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None


def _storage_truncated(path: Path) -> bool:
    """A ``.db3`` shorter than its header says, or an ``.mcap`` its writer never finished."""
    if path.suffix == ".db3":
        return _db3_truncated(path)
    if path.suffix == ".mcap":
        return mcap_is_unfinished(path)
    return False


def _db3_truncated(path: Path) -> bool:
    """True when a .db3 file is shorter than the page count its SQLite header declares."""
    try:
        with open(path, "rb") as handle:
            head = handle.read(100)
            size = os.fstat(handle.fileno()).st_size
    except OSError:
        return False
    if len(head) < 100 or not head.startswith(_SQLITE_MAGIC):
        return False
    (page_size,) = struct.unpack(">H", head[16:18])
    page_size = 65536 if page_size == 1 else page_size
    (n_pages,) = struct.unpack(">I", head[28:32])
    return size < page_size * n_pages


class _SalvagedDb3:
    """Reads the messages of a truncated ``.db3`` up to the damage, in recording (rowid) order.

    SQLite refuses a file shorter than its header's page count ("database disk image is
    malformed"). A padded temporary copy (zero pages in place of the missing tail) opens, and its
    ``messages`` table can be walked in rowid order until the first missing page. The copy costs
    disk, not memory, and is deleted on close. Mimics the parts of a rosbags reader that
    :class:`_Ros2Input` uses.
    """

    def __init__(self, path: Path) -> None:
        import sqlite3

        self.path = path
        self._tmpdir = tempfile.TemporaryDirectory(prefix="lidar3d-db3-")
        copy = Path(self._tmpdir.name) / path.name
        with open(path, "rb") as src, open(copy, "wb") as dst:
            shutil.copyfileobj(src, dst, 1 << 20)
            head_page_size, n_pages = self._geometry(path)
            dst.truncate(head_page_size * n_pages)
        self._db = sqlite3.connect(f"file:{copy}?immutable=1", uri=True)
        try:
            rows = self._db.execute("SELECT id, name, type FROM topics").fetchall()
        except sqlite3.DatabaseError as err:
            self.close()
            raise BagError(f"{path}: storage file is truncated and its topic table is lost: {err}") from err
        self._topic_ids = {int(i): str(name) for i, name, _t in rows}
        types = {str(name): str(t) for _i, name, t in rows}
        counts = dict.fromkeys(types, 0)
        self.start_time = 2**63 - 1
        self.end_time = 0
        self.message_count = 0
        try:
            for topic_id, stamp in self._db.execute("SELECT topic_id, timestamp FROM messages ORDER BY id"):
                name = self._topic_ids.get(topic_id, "?")
                counts[name] = counts.get(name, 0) + 1
                self.start_time = min(self.start_time, stamp)
                self.end_time = max(self.end_time, stamp + 1)
                self.message_count += 1
        except sqlite3.DatabaseError:
            logger.debug("%s: messages table readable up to message %d", path, self.message_count)
        self.topics = {name: _SalvagedTopic(types.get(name, "?"), count) for name, count in counts.items()}
        self.connections = [_SalvagedConnection(i, name) for i, name in self._topic_ids.items()]

    @staticmethod
    def _geometry(path: Path) -> tuple[int, int]:
        with open(path, "rb") as handle:
            head = handle.read(100)
        (page_size,) = struct.unpack(">H", head[16:18])
        return (65536 if page_size == 1 else page_size), struct.unpack(">I", head[28:32])[0]

    def messages(self, connections: Sequence[Any]) -> Iterator[tuple[Any, int, bytes]]:
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
        with contextlib.suppress(Exception):
            self._db.close()
        self._tmpdir.cleanup()


@dataclass(frozen=True, slots=True)
class _SalvagedTopic:
    msgtype: str
    msgcount: int


@dataclass(frozen=True, slots=True)
class _SalvagedConnection:
    id: int
    topic: str


def _expected_counts(folder: Path) -> dict[str, int]:
    """Per-topic message counts that ``metadata.yaml`` promises (empty when there is none)."""
    meta = folder / "metadata.yaml"
    if not meta.exists():
        return {}
    try:
        from ruamel.yaml import YAML

        info = YAML(typ="safe").load(meta.read_text())["rosbag2_bagfile_information"]
        return {
            t["topic_metadata"]["name"]: int(t["message_count"]) for t in info["topics_with_message_count"]
        }
    except Exception:  # noqa: BLE001 - an unreadable metadata file only loses the lost-count
        return {}


class _Ros2Input(_Input):
    def __init__(self, path: Path) -> None:
        from rosbags.rosbag2 import Reader, ReaderError

        self.fmt = BagFormat.ROS2
        self.path = path
        self.n_lost = 0
        self.note = ""
        self._readers: list[Any] = []
        folder = path if path.is_dir() else None
        if folder is not None:
            files = sorted([*folder.glob("*.db3"), *folder.glob("*.mcap")])
            truncated = [f for f in files if _storage_truncated(f)]
            has_meta = (folder / "metadata.yaml").exists()
            if not files and not has_meta:
                raise BagError(f"{path}: not a bag folder (no metadata.yaml, no .db3 or .mcap files)")
            if truncated:
                self.note = (
                    f"storage file(s) {', '.join(f.name for f in truncated)} are truncated: read every "
                    f"complete message before the damage, in recording order"
                )
            elif not has_meta:
                self.note = (
                    f"no metadata.yaml (the recording was not stopped cleanly?): read {len(files)} "
                    f"storage file(s) directly"
                )
            else:
                files = [folder]
        else:
            files = [path]
            truncated = [path] if _storage_truncated(path) else []
            if truncated:
                self.note = "storage file is truncated: read every complete message before the damage, in recording order"
        try:
            for file in files:
                if file in truncated:
                    self._readers.append(_SalvagedDb3(file) if file.suffix == ".db3" else McapRecovery(file))
                    continue
                reader = Reader(file)
                reader.open()
                self._readers.append(reader)
        except BagError:
            self.close()
            raise
        except (ReaderError, OSError, KeyError, ValueError) as err:
            self.close()
            raise BagError(f"{path}: not a readable ROS2 bag: {err}") from err
        except Exception as err:  # apsw / mcap parsing errors of damaged storage files
            self.close()
            raise BagError(f"{path}: storage file is damaged and cannot be opened: {err}") from err
        topics: dict[str, TopicInfo] = {}
        for reader in self._readers:
            for name, info in reader.topics.items():
                old = topics.get(name)
                topics[name] = TopicInfo(name, info.msgtype or "?", info.msgcount + (old.count if old else 0))
        self.topics = topics
        if truncated:
            expected = _expected_counts(folder) if folder is not None else {}
            if expected:
                self.n_lost = sum(max(n - topics[t].count if t in topics else n, 0) for t, n in expected.items())
                self.note += f"; {self.n_lost} message(s) lost"
            else:
                # Without metadata.yaml only the message cut off at the end is known to be lost.
                self.n_lost = sum(getattr(r, "n_lost", 0) for r in self._readers)
                self.note += f"; {_cut_off_text(self.n_lost)}"
                unreadable = sum(getattr(r, "unreadable_bytes", 0) for r in self._readers)
                if unreadable:
                    self.note += f"; an unfinished compressed chunk of {unreadable} bytes could not be read"
        counted = [r for r in self._readers if r.message_count]
        self.start_ns = min(r.start_time for r in counted) if counted else None
        # rosbags reports end_time one nanosecond after the last message.
        self.end_ns = max(r.end_time for r in counted) - 1 if counted else None

    def messages(self, topic: str) -> Iterator[tuple[int, bytes]]:
        streams = []
        for reader in self._readers:
            connections = [c for c in reader.connections if c.topic == topic]
            if connections:
                streams.append(((log_ns, raw) for _c, log_ns, raw in reader.messages(connections=connections)))
        if len(streams) == 1:
            iterator: Iterator[tuple[int, bytes]] = streams[0]
        else:
            iterator = heapq.merge(*streams, key=lambda item: item[0])
        read = 0
        try:
            for item in iterator:
                read += 1
                yield item
        except Exception as err:  # apsw.CorruptError and friends from a damaged storage file
            raise BagError(f"{self.path}: storage is damaged after {read} message(s) on {topic}: {err}") from err

    def close(self) -> None:
        readers, self._readers = self._readers, []
        for reader in readers:
            try:
                reader.close()
            except Exception:  # noqa: BLE001 - closing a half-opened reader must not mask the cause
                logger.debug("%s: error while closing", self.path, exc_info=True)


def _open_input(path: Path) -> _Input:
    """Open one input after sniffing what it is."""
    if not path.exists():
        raise BagError(f"{path}: no such file or folder")
    if path.is_dir():
        return _Ros2Input(path)
    if path.name == "metadata.yaml":
        return _Ros2Input(path.parent)
    try:
        with open(path, "rb") as handle:
            magic = handle.read(16)
    except OSError as err:
        raise BagError(f"{path}: cannot read: {err.strerror}") from err
    if not magic:
        raise BagError(f"{path}: file is empty (0 bytes), not a bag")
    if magic.startswith(ROS1_MAGIC):
        return _Ros1Input(path)
    if magic.startswith(_SQLITE_MAGIC) or magic.startswith(_MCAP_MAGIC):
        if path.suffix not in (".db3", ".mcap"):
            raise BagError(f"{path}: looks like ROS2 storage but is not named .db3/.mcap")
        return _Ros2Input(path)
    if magic.startswith(b"#ROSBAG"):
        raise BagError(f"{path}: unsupported ROS bag version {magic.splitlines()[0].decode('ascii', 'replace')!r}")
    raise BagError(f"{path}: not a bag (expected a ROS1 .bag file, a ROS2 bag folder, or a .db3/.mcap file)")


# --------------------------------------------------------------------------------------------


def _describe_topics(topics: dict[str, TopicInfo]) -> str:
    return ", ".join(f"{t.name} ({t.msgtype}, {t.count})" for t in sorted(topics.values(), key=lambda t: t.name))


def choose_lidar_topic(topics: dict[str, TopicInfo], topic: str | None, label: str) -> str:
    """The PointCloud2 topic to read: ``topic`` if given (checked), else the only PointCloud2 topic.

    Raises:
        BagError: the bag is empty, has no PointCloud2 topic, several and no choice, or the
            chosen topic does not exist or is not a PointCloud2 topic.
    """
    if not topics or sum(t.count for t in topics.values()) == 0:
        raise BagError(f"{label}: bag is empty (no messages)")
    clouds = sorted(name for name, t in topics.items() if t.msgtype == POINTCLOUD2_TYPE)
    if topic:
        if topic not in topics:
            candidates = ", ".join(clouds) if clouds else "none; topics: " + _describe_topics(topics)
            raise BagError(f"{label}: topic {topic!r} not found; PointCloud2 topics: {candidates}")
        if topics[topic].msgtype != POINTCLOUD2_TYPE:
            raise BagError(f"{label}: topic {topic!r} has type {topics[topic].msgtype}, not {POINTCLOUD2_TYPE}")
        return topic
    if not clouds:
        raise BagError(f"{label}: no {POINTCLOUD2_TYPE} topic; topics: {_describe_topics(topics)}")
    if len(clouds) > 1:
        raise BagError(f"{label}: several PointCloud2 topics ({', '.join(clouds)}); choose one with --topic")
    return clouds[0]


class ScanSource:
    """Scans of one lidar topic from one or more bags, lazily and in log-time order.

    Use as a context manager::

        with ScanSource(["run_0.bag", "run_1.bag"]) as source:
            print(source.topic, len(source))
            for scan in source:
                ...
        print(source.stats)

    Args:
        paths: a bag path or several (ROS1 split files, or ROS2 folders); read as one stream.
        topic: the PointCloud2 topic; None or "" picks the only one.
        sensor: for clouds without ring or time fields (see :mod:`lidar3d.io.pointcloud2`).
        min_range_m: points nearer than this are dropped (counted in :attr:`stats`).

    Raises (from ``open``/``__enter__``):
        BagError: missing path, not a bag, empty bag, no/ambiguous/unknown lidar topic.
    Iterating raises:
        PointCloudError: a cloud that cannot be decoded (message names the bag and stamp).
    """

    def __init__(
        self,
        paths: str | Path | Sequence[str | Path],
        *,
        topic: str | None = None,
        sensor: SensorModel = VLP16,
        min_range_m: float = 0.0,
    ) -> None:
        if isinstance(paths, (str, Path)):
            paths = [paths]
        self.paths: tuple[Path, ...] = tuple(Path(p) for p in paths)
        if not self.paths:
            raise BagError("no bag given")
        self.label = bag_label(list(self.paths))
        self._requested_topic = topic or None
        self.sensor = sensor
        self.min_range_m = float(min_range_m)
        self._inputs: list[_Input] = []
        self._opened_once = False
        self._topic: str | None = None
        self._topics: dict[str, TopicInfo] = {}
        self._format = BagFormat.ROS1
        self._start_ns: int | None = None
        self._end_ns: int | None = None
        self._notes: list[str] = []
        self._stats = ReadStats()

    # -- lifecycle -----------------------------------------------------------------------------
    def open(self) -> "ScanSource":
        """Open every input and choose the lidar topic. Idempotent while open."""
        if self._inputs:
            return self
        try:
            for path in self.paths:
                self._inputs.append(_open_input(path))
            topics: dict[str, TopicInfo] = {}
            for opened in self._inputs:
                for name, info in opened.topics.items():
                    old = topics.get(name)
                    topics[name] = TopicInfo(name, info.msgtype, info.count + (old.count if old else 0))
            if sum(t.count for t in topics.values()) == 0:
                damaged = [i for i in self._inputs if i.note]
                if damaged:
                    raise BagError(f"{damaged[0].path}: no complete message: {damaged[0].note}")
            self._topic = choose_lidar_topic(topics, self._requested_topic, self.label)
        except BaseException:
            self.close()
            raise
        self._topics = topics
        self._format = self._inputs[0].fmt
        starts = [i.start_ns for i in self._inputs if i.start_ns is not None]
        ends = [i.end_ns for i in self._inputs if i.end_ns is not None]
        self._start_ns = min(starts) if starts else None
        self._end_ns = max(ends) if ends else None
        self._notes = [f"{i.path}: {i.note}" for i in self._inputs if i.note]
        for note in self._notes:
            logger.warning("%s", note)
        self._opened_once = True
        return self

    def close(self) -> None:
        """Close every input; logs a summary of what was dropped. What was learnt stays readable."""
        inputs, self._inputs = self._inputs, []
        lost = sum(i.n_lost for i in inputs)
        self._stats = dataclasses.replace(self._stats, n_lost_messages=max(lost, self._stats.n_lost_messages))
        for opened in inputs:
            opened.close()
        if self._stats.n_scans:
            logger.info(
                "read %d scans from %s: %d points kept, %d non-finite and %d nearer than %.2f m dropped",
                self._stats.n_scans, self.label, self._stats.n_points_kept, self._stats.n_nonfinite,
                self._stats.n_below_min_range, self.min_range_m,
            )

    def __enter__(self) -> "ScanSource":
        return self.open()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- what is in the input (available once opened, also after closing) --------------------
    def _require_opened(self) -> None:
        if not self._opened_once:
            raise BagError(f"{self.label}: scan source is not open (use it in a with-block)")

    def _require_open(self) -> None:
        if not self._inputs:
            raise BagError(f"{self.label}: scan source is not open (use it in a with-block)")

    @property
    def topics(self) -> dict[str, TopicInfo]:
        """All topics over all inputs (counts summed)."""
        self._require_opened()
        return dict(self._topics)

    @property
    def topic(self) -> str:
        """The lidar topic being read."""
        self._require_opened()
        assert self._topic is not None
        return self._topic

    @property
    def format(self) -> BagFormat:
        """Container format of the (first) input."""
        self._require_opened()
        return self._format

    @property
    def start_ns(self) -> int | None:
        """Log time of the earliest message of any topic (None for an empty input)."""
        self._require_opened()
        return self._start_ns

    @property
    def end_ns(self) -> int | None:
        """Log time of the latest message of any topic."""
        self._require_opened()
        return self._end_ns

    @property
    def notes(self) -> list[str]:
        """Warnings about how inputs were read (truncated bags, missing metadata)."""
        return list(self._notes)

    @property
    def stats(self) -> ReadStats:
        """Totals so far: scans, points kept and dropped, messages lost to truncation."""
        lost = sum(i.n_lost for i in self._inputs)
        return dataclasses.replace(self._stats, n_lost_messages=max(lost, self._stats.n_lost_messages))

    def __len__(self) -> int:
        """Number of messages on the lidar topic (as the bag's index or metadata says)."""
        return self.topics[self.topic].count

    # -- reading -------------------------------------------------------------------------------
    def raw_messages(self) -> Iterator[tuple[BagFormat, int, bytes]]:
        """``(format, log time ns, serialised message)`` of the lidar topic, merged by log time."""
        self._require_open()
        topic = self.topic
        streams = []
        for index, opened in enumerate(self._inputs):
            if topic in opened.topics:
                streams.append(((log_ns, index, opened.fmt, raw) for log_ns, raw in opened.messages(topic)))
        merged = heapq.merge(*streams, key=lambda item: (item[0], item[1])) if len(streams) > 1 else streams[0]
        for log_ns, _index, fmt, raw in merged:
            yield fmt, log_ns, raw

    def clouds(self) -> Iterator[PointCloud2Parts]:
        """The lidar topic's messages as :class:`PointCloud2Parts` (no decoding)."""
        for fmt, _log_ns, raw in self.raw_messages():
            yield deserialize_cloud(fmt, raw, self.label)

    def __iter__(self) -> Iterator[Scan]:
        ring_table: np.ndarray | None = None
        ring_checked = False
        for parts in self.clouds():
            try:
                scan, stats = decode_parts(
                    parts, sensor=self.sensor, min_range_m=self.min_range_m, ring_table=ring_table
                )
                if not ring_checked and len(scan) and any(f.name in RING_FIELD_NAMES for f in parts.fields):
                    # Judge the driver's ring numbering once, on the first non-empty cloud.
                    ring_checked = True
                    ring_table = ring_table_from_elevation(scan.ring, scan.points, self.sensor)
                    if ring_table is not None:
                        logger.info(
                            "%s: the ring field of %s does not count up from the lowest beam; "
                            "renumbering it by elevation with the %s table", self.label, self.topic, self.sensor.name,
                        )
                        scan, stats = decode_parts(
                            parts, sensor=self.sensor, min_range_m=self.min_range_m, ring_table=ring_table
                        )
            except PointCloudError as err:
                raise PointCloudError(f"{self.label}: {self.topic} at stamp {parts.stamp_ns} ns: {err}") from err
            self._stats = self._stats.add(stats)
            yield scan


def deserialize_cloud(fmt: BagFormat, raw: bytes | memoryview, label: str = "bag") -> PointCloud2Parts:
    """Deserialise one PointCloud2 (ROS1 or CDR bytes) into parts; the data buffer is not copied."""
    store = _typestore(fmt)
    try:
        if fmt is BagFormat.ROS1:
            message = store.deserialize_ros1(raw, POINTCLOUD2_TYPE)
        else:
            message = store.deserialize_cdr(raw, POINTCLOUD2_TYPE)
    except Exception as err:  # rosbags raises assorted errors on malformed bytes
        raise PointCloudError(f"{label}: a {POINTCLOUD2_TYPE} message cannot be deserialised: {err}") from err
    return parts_from_message(message)


def open_scan_source(paths: str | Path | Sequence[str | Path], config: Any = None) -> ScanSource:
    """A :class:`ScanSource` configured from a :class:`lidar3d.config.Config` (defaults when None).

    Uses ``config.input.topic``, ``config.sensor.resolved_model`` and ``config.sensor.min_range_m``.
    Not yet opened: use it in a ``with`` block.
    """
    if config is None:
        from lidar3d.config import Config

        config = Config()
    return ScanSource(
        paths,
        topic=config.input.topic or None,
        sensor=config.sensor.resolved_model,
        min_range_m=config.sensor.min_range_m,
    )
