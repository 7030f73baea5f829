"""Sequential reading of MCAP files without a footer (a ``ros2 bag record`` killed mid-write).

An MCAP writer puts the summary section and the footer at the end when it closes the file, and
readers that start from the footer (rosbags included) refuse a file without one. The data
section before it is a plain sequence of records (MCAP specification, https://mcap.dev/spec)::

    magic b"\\x89MCAP0\\r\\n", then records: uint8 opcode, uint64 length, content
    0x03 Schema   uint16 id, string name, string encoding, uint32-prefixed data
    0x04 Channel  uint16 id, uint16 schema_id, string topic, string message_encoding, map metadata
    0x05 Message  uint16 channel_id, uint32 sequence, uint64 log_time, uint64 publish_time, data
    0x06 Chunk    uint64 start, uint64 end, uint64 uncompressed_size, uint32 crc, string compression,
                  uint64-prefixed records (schemas, channels, messages; maybe zstd/lz4 compressed)
    strings are uint32-prefixed UTF-8

:class:`McapRecovery` walks them from the start, reads every complete record, and stops at the
first record cut off by the end of the file. An uncompressed chunk cut short is read record by
record up to the cut; a compressed one cannot be and is reported by size. It presents the small
part of a rosbags storage reader's interface that :class:`lidar3d.io.bag_inputs.Ros2BagInput` uses.
"""

from __future__ import annotations

import struct
from collections.abc import Collection, Iterator
from dataclasses import dataclass
from pathlib import Path

__all__ = ["MCAP_MAGIC", "McapRecovery", "mcap_is_unfinished"]

MCAP_MAGIC = b"\x89MCAP0\r\n"
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_FOOTER, _OP_DATA_END = 0x03, 0x04, 0x05, 0x06, 0x02, 0x0F
_RECORD = struct.Struct("<BQ")
_MESSAGE = struct.Struct("<HIQQ")


def mcap_is_unfinished(path: Path) -> bool:
    """True for an MCAP file that lacks the closing magic (its writer never finished it)."""
    try:
        with open(path, "rb") as handle:
            if handle.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                return False
            handle.seek(0, 2)
            if handle.tell() < 2 * len(MCAP_MAGIC):
                return True
            handle.seek(-len(MCAP_MAGIC), 2)
            return handle.read() != MCAP_MAGIC
    except OSError:
        return False


@dataclass(frozen=True, slots=True)
class McapTopic:
    msgtype: str
    msgcount: int


@dataclass(frozen=True, slots=True)
class McapChannel:
    id: int
    topic: str


def _string(buffer: bytes | memoryview, pos: int) -> tuple[str, int]:
    (length,) = struct.unpack_from("<I", buffer, pos)
    pos += 4
    return bytes(buffer[pos : pos + length]).decode("utf-8", "replace"), pos + length


def _decompress(compression: str, data: bytes) -> bytes | None:
    if compression == "":
        return data
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    if compression == "zstd":
        try:
            from compression import zstd  # Python 3.14
        except ImportError:
            try:
                from backports import zstd
            except ImportError:
                return None
        return zstd.decompress(data)
    return None


class McapRecovery:
    """Complete messages of an unfinished MCAP file, in file order."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._schemas: dict[int, str] = {}
        self._channels: dict[int, tuple[str, int]] = {}
        self._counts: dict[int, int] = {}
        self.n_lost = 0
        self.unreadable_bytes = 0
        self.start_time = 2**63 - 1
        self.end_time = 0  # one past the last log time, as rosbags reports it
        self.message_count = 0
        for channel_id, log_ns, _data in self._walk(want_data=False):
            self._counts[channel_id] = self._counts.get(channel_id, 0) + 1
            self.start_time = min(self.start_time, log_ns)
            self.end_time = max(self.end_time, log_ns + 1)
            self.message_count += 1

    @property
    def topics(self) -> dict[str, McapTopic]:
        topics: dict[str, McapTopic] = {}
        for channel_id, (topic, schema_id) in self._channels.items():
            old = topics.get(topic)
            count = self._counts.get(channel_id, 0) + (old.msgcount if old else 0)
            topics[topic] = McapTopic(self._schemas.get(schema_id, "?"), count)
        return topics

    @property
    def connections(self) -> list[McapChannel]:
        return [McapChannel(cid, topic) for cid, (topic, _schema) in self._channels.items()]

    def messages(self, connections: Collection[McapChannel]) -> Iterator[tuple[McapChannel, int, bytes]]:
        wanted = {c.id: c for c in connections}
        for channel_id, log_ns, data in self._walk(want_data=True):
            if channel_id in wanted:
                yield wanted[channel_id], log_ns, data

    def close(self) -> None:
        """Nothing stays open between walks."""

    # -- the walk ----------------------------------------------------------------------------
    def _walk(self, want_data: bool) -> Iterator[tuple[int, int, bytes]]:
        lost = 0
        unreadable = 0
        with open(self.path, "rb") as handle:
            handle.read(len(MCAP_MAGIC))
            while True:
                head = handle.read(_RECORD.size)
                if len(head) < _RECORD.size:
                    break
                opcode, length = _RECORD.unpack(head)
                if opcode in (_OP_FOOTER, _OP_DATA_END):
                    break
                content = handle.read(length)
                complete = len(content) == length
                if opcode == _OP_CHUNK:
                    chunk = self._chunk_records(content, complete)
                    if chunk is None:
                        unreadable += len(content)
                        break
                    records, cut = chunk
                    for record in self._records(records, want_data):
                        if record is None:
                            lost += 1
                            break
                        yield record
                    if cut or not complete:
                        break
                    continue
                if not complete:
                    lost += opcode == _OP_MESSAGE
                    break
                record = self._record(opcode, content, want_data)
                if record is not None:
                    yield record
        self.n_lost, self.unreadable_bytes = lost, unreadable

    @staticmethod
    def _chunk_records(content: bytes, complete: bool) -> tuple[memoryview, bool] | None:
        """The chunk's inner records and whether they were cut short; None when unreadable."""
        header = 8 + 8 + 8 + 4
        if len(content) < header + 4:
            return None
        compression, pos = _string(content, header)
        if len(content) < pos + 8:
            return None
        (records_len,) = struct.unpack_from("<Q", content, pos)
        records = memoryview(content)[pos + 8 : pos + 8 + records_len]
        cut = len(records) < records_len
        if compression:
            if cut or not complete:
                return None
            data = _decompress(compression, bytes(records))
            return (memoryview(data), False) if data is not None else None
        return records, cut

    def _records(self, buffer: memoryview, want_data: bool) -> Iterator[tuple[int, int, bytes] | None]:
        """Records inside a chunk; yields None once for a record cut off at the end."""
        pos = 0
        while pos < len(buffer):
            if pos + _RECORD.size > len(buffer):
                yield None
                return
            opcode, length = _RECORD.unpack_from(buffer, pos)
            pos += _RECORD.size
            if pos + length > len(buffer):
                if opcode == _OP_MESSAGE:
                    yield None
                return
            record = self._record(opcode, buffer[pos : pos + length], want_data)
            pos += length
            if record is not None:
                yield record

    def _record(self, opcode: int, content: bytes | memoryview, want_data: bool) -> tuple[int, int, bytes] | None:
        if opcode == _OP_MESSAGE:
            channel_id, _sequence, log_ns, _publish_ns = _MESSAGE.unpack_from(content, 0)
            return channel_id, log_ns, bytes(content[_MESSAGE.size :]) if want_data else b""
        if opcode == _OP_SCHEMA:
            (schema_id,) = struct.unpack_from("<H", content, 0)
            name, _pos = _string(content, 2)
            self._schemas[schema_id] = name
        elif opcode == _OP_CHANNEL:
            channel_id, schema_id = struct.unpack_from("<HH", content, 0)
            topic, _pos = _string(content, 4)
            self._channels[channel_id] = (topic, schema_id)
        return None
