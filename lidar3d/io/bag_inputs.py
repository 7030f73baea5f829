"""One opened input per storage: a ROS1 ``.bag`` file, or a ROS2 bag (sqlite3 / mcap folder or file).

Each input lists its topics and times and yields the raw messages of one topic in log-time order;
:class:`lidar3d.io.scan_source.ScanSource` merges several inputs into one stream. What an input is
gets sniffed from its content, not its name (:func:`open_bag_input`).

* ROS1 ``.bag`` (:class:`Ros1BagInput`): read through the bag's index with ``rosbags``. A bag
  without a usable index (a recording killed mid-write, or a file cut short) is walked record by
  record (:mod:`lidar3d.io.ros1_recovery`): every complete message is read, in file order.
* ROS2 bag (:class:`Ros2BagInput`): a folder with sqlite3 (``.db3``) or mcap storage, read
  through ``rosbags``, or a single storage file. A folder without ``metadata.yaml`` (``ros2 bag
  record`` writes it only when it stops cleanly) is read from its storage files directly. A
  ``.db3`` cut short is read up to the first missing page (:mod:`lidar3d.io.db3_recovery`); an
  ``.mcap`` without its footer is walked record by record (:mod:`lidar3d.io.mcap_recovery`).

An input read in one of these unusual ways says how in :attr:`BagInput.note`, and counts the
messages it knows were lost in :attr:`BagInput.n_lost` (all the missing ones when
``metadata.yaml`` gives the count, otherwise the one cut off at the end).
"""

from __future__ import annotations

import abc
import heapq
import logging
import operator
import struct
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any, TypeVar

from lidar3d.errors import BagError
from lidar3d.io.db3_recovery import SQLITE_MAGIC, Db3Recovery, db3_is_truncated
from lidar3d.io.mcap_recovery import McapRecovery, mcap_is_unfinished
from lidar3d.io.ros1_recovery import ROS1_MAGIC, Ros1Recovery

__all__ = [
    "BagFormat",
    "BagInput",
    "Ros1BagInput",
    "Ros2BagInput",
    "TopicInfo",
    "log_time_span",
    "merge_by_log_time",
    "merge_topics",
    "merged_messages",
    "open_bag_input",
]

logger = logging.getLogger(__name__)

_Payload = TypeVar("_Payload")
_MCAP_PREFIX = b"\x89MCAP"  # any MCAP version


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


def merge_topics(topics: Iterable[TopicInfo]) -> dict[str, TopicInfo]:
    """One :class:`TopicInfo` per name: counts summed, the last message type seen kept.

    Used wherever several parts list topics of one stream: connections of a ROS1 bag, storage
    files of a ROS2 bag, the inputs of a scan source. Names keep the order they first appear in.
    """
    merged: dict[str, TopicInfo] = {}
    for info in topics:
        old = merged.get(info.name)
        merged[info.name] = TopicInfo(info.name, info.msgtype, info.count + (old.count if old else 0))
    return merged


def merge_by_log_time(streams: Sequence[Iterator[tuple[int, _Payload]]]) -> Iterator[tuple[int, _Payload]]:
    """``(log time ns, payload)`` items of time-ordered ``streams`` as one time-ordered stream.

    Lazy (one item per stream is held); equal times keep the order of ``streams``.
    """
    if len(streams) == 1:
        return streams[0]
    return heapq.merge(*streams, key=operator.itemgetter(0))


def _damage_text(n_lost: int, unreadable_bytes: int) -> str:
    """What a recovered input lost: the message cut off at the end, an unreadable compressed chunk."""
    text = f"{n_lost} incomplete message(s) at the end lost" if n_lost else "no message was cut off"
    if unreadable_bytes:
        text += f"; an unfinished compressed chunk of {unreadable_bytes} bytes could not be read"
    return text


class BagInput(abc.ABC):
    """One opened input: topics, times, and raw messages of chosen topics in log-time order.

    Attributes:
        fmt: container format (decides how messages are deserialised).
        path: the input as given.
        topics: topic name -> :class:`TopicInfo` (counts as the index, metadata or recovery say).
        start_ns, end_ns: log times of the first and last message of any topic (None when empty).
        n_lost: messages known to be lost to truncation (0 for an intact input).
        note: how the input was read when not the normal way (for warnings and ``info``), or "".
    """

    topics: dict[str, TopicInfo]
    start_ns: int | None
    end_ns: int | None

    def __init__(self, fmt: BagFormat, path: Path) -> None:
        self.fmt = fmt
        self.path = path
        self.n_lost = 0
        self.note = ""

    @abc.abstractmethod
    def messages(self, topic: str) -> Iterator[tuple[int, bytes]]:
        """``(log time ns, serialised message)`` of ``topic`` in log-time order."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release files and database handles."""


class Ros1BagInput(BagInput):
    """A ROS1 ``.bag`` file, read through its index, or walked record by record without one."""

    def __init__(self, path: Path) -> None:
        from rosbags.rosbag1 import Reader, ReaderError

        super().__init__(BagFormat.ROS1, path)
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
        self.topics = merge_topics(
            TopicInfo(conn.topic, conn.msgtype, conn.count) for conn in survey.connections.values()
        )
        self.start_ns = survey.start_ns
        self.end_ns = survey.end_ns
        lost = _damage_text(survey.n_lost, survey.unreadable_bytes)
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
        return db3_is_truncated(path)
    if path.suffix == ".mcap":
        return mcap_is_unfinished(path)
    return False


def _expected_counts(folder: Path) -> dict[str, int]:
    """Per-topic message counts that ``metadata.yaml`` promises (empty when there is none)."""
    meta = folder / "metadata.yaml"
    if not meta.exists():
        return {}
    try:
        from ruamel.yaml import YAML

        info = YAML(typ="safe").load(meta.read_text())["rosbag2_bagfile_information"]
        return {t["topic_metadata"]["name"]: int(t["message_count"]) for t in info["topics_with_message_count"]}
    except Exception:
        return {}


class Ros2BagInput(BagInput):
    """A ROS2 bag folder (sqlite3 or mcap storage, with or without ``metadata.yaml``) or storage file.

    Intact storage is read through ``rosbags`` readers; truncated storage files through a
    :class:`~lidar3d.io.db3_recovery.Db3Recovery` or :class:`~lidar3d.io.mcap_recovery.McapRecovery`.
    """

    def __init__(self, path: Path) -> None:
        from rosbags.rosbag2 import Reader, ReaderError

        super().__init__(BagFormat.ROS2, path)
        self._readers: list[Any] = []  # rosbags readers and the recoveries, in storage file order
        recoveries: list[Db3Recovery | McapRecovery] = []
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
                self.note = (
                    "storage file is truncated: read every complete message before the damage, in recording order"
                )
        try:
            for file in files:
                if file in truncated:
                    recovery = Db3Recovery(file) if file.suffix == ".db3" else McapRecovery(file)
                    recoveries.append(recovery)
                    self._readers.append(recovery)
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
        self.topics = merge_topics(
            TopicInfo(name, info.msgtype or "?", info.msgcount)
            for reader in self._readers
            for name, info in reader.topics.items()
        )
        if truncated:
            self._count_losses(folder, recoveries)
        counted = [r for r in self._readers if r.message_count]
        self.start_ns = min(r.start_time for r in counted) if counted else None
        # rosbags reports end_time one nanosecond after the last message.
        self.end_ns = max(r.end_time for r in counted) - 1 if counted else None

    def _count_losses(self, folder: Path | None, recoveries: Sequence[Db3Recovery | McapRecovery]) -> None:
        """Set :attr:`n_lost` and finish :attr:`note` for an input with truncated storage files."""
        expected = _expected_counts(folder) if folder is not None else {}
        if expected:
            topics = self.topics
            self.n_lost = sum(max(n - topics[t].count if t in topics else n, 0) for t, n in expected.items())
            self.note += f"; {self.n_lost} message(s) lost"
        else:
            # Without metadata.yaml only the message cut off at the end is known to be lost.
            self.n_lost = sum(r.n_lost for r in recoveries)
            self.note += "; " + _damage_text(self.n_lost, sum(r.unreadable_bytes for r in recoveries))

    def messages(self, topic: str) -> Iterator[tuple[int, bytes]]:
        streams = []
        for reader in self._readers:
            connections = [c for c in reader.connections if c.topic == topic]
            if connections:
                streams.append(((log_ns, raw) for _c, log_ns, raw in reader.messages(connections=connections)))
        read = 0
        try:
            for item in merge_by_log_time(streams):
                read += 1
                yield item
        except Exception as err:  # apsw.CorruptError and friends from a damaged storage file
            raise BagError(f"{self.path}: storage is damaged after {read} message(s) on {topic}: {err}") from err

    def close(self) -> None:
        readers, self._readers = self._readers, []
        for reader in readers:
            try:
                reader.close()
            except Exception:
                logger.debug("%s: error while closing", self.path, exc_info=True)


def merged_messages(inputs: Sequence[BagInput], topic: str) -> Iterator[tuple[int, tuple[BagFormat, bytes]]]:
    """``(log time ns, (format, serialised message))`` of ``topic`` over ``inputs``, merged by log time.

    Equal log times keep the order of ``inputs``.
    """
    return merge_by_log_time([_with_format(opened, topic) for opened in inputs if topic in opened.topics])


def _with_format(opened: BagInput, topic: str) -> Iterator[tuple[int, tuple[BagFormat, bytes]]]:
    for log_ns, raw in opened.messages(topic):
        yield log_ns, (opened.fmt, raw)


def log_time_span(inputs: Sequence[BagInput]) -> tuple[int | None, int | None]:
    """Log times of the earliest and the latest message of any topic over ``inputs`` (None when empty)."""
    starts = [i.start_ns for i in inputs if i.start_ns is not None]
    ends = [i.end_ns for i in inputs if i.end_ns is not None]
    return (min(starts) if starts else None), (max(ends) if ends else None)


def open_bag_input(path: Path) -> BagInput:
    """Open one input after sniffing what it is.

    Raises:
        BagError: missing path, empty or unreadable file, not a bag, an unsupported bag version,
            or ROS2 storage that cannot be opened.
    """
    if not path.exists():
        raise BagError(f"{path}: no such file or folder")
    if path.is_dir():
        return Ros2BagInput(path)
    if path.name == "metadata.yaml":
        return Ros2BagInput(path.parent)
    try:
        with open(path, "rb") as handle:
            magic = handle.read(16)
    except OSError as err:
        raise BagError(f"{path}: cannot read: {err.strerror}") from err
    if not magic:
        raise BagError(f"{path}: file is empty (0 bytes), not a bag")
    if magic.startswith(ROS1_MAGIC):
        return Ros1BagInput(path)
    if magic.startswith((SQLITE_MAGIC, _MCAP_PREFIX)):
        if path.suffix not in (".db3", ".mcap"):
            raise BagError(f"{path}: looks like ROS2 storage but is not named .db3/.mcap")
        return Ros2BagInput(path)
    if magic.startswith(b"#ROSBAG"):
        raise BagError(f"{path}: unsupported ROS bag version {magic.splitlines()[0].decode('ascii', 'replace')!r}")
    raise BagError(f"{path}: not a bag (expected a ROS1 .bag file, a ROS2 bag folder, or a .db3/.mcap file)")
