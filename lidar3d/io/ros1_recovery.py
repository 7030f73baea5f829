"""Sequential reading of ROS1 bags that have no usable index (a recording killed mid-write).

``rosbag record`` writes the index (connection and chunk-info records, and ``index_pos`` in the
bag header) only when it closes the bag. A recording that was killed, or a file cut short, has
``index_pos`` 0 or pointing past the end, and indexed readers (rosbags included) refuse it. The
records themselves are still there, in order (ROS bag format 2.0,
http://wiki.ros.org/Bags/Format/2.0)::

    record  = uint32 header_len, header (fields: uint32 len, b"name=value"), uint32 data_len, data
    op 0x03 bag header, 0x05 chunk (data = inner records, maybe bz2/lz4 compressed),
    op 0x07 connection, 0x02 message data, 0x04 index data, 0x06 chunk info

:class:`Ros1Recovery` walks them from the start. A finished chunk is read whole; the last,
unfinished chunk of an uncompressed recording (its size field still 0 or running past the end of
the file) is read record by record until the data stops, so every complete message is kept. An
incomplete message record at the end counts as lost; an unfinished *compressed* chunk cannot be
decompressed and is reported by size. Memory stays bounded by one chunk.
"""

from __future__ import annotations

import bz2
import logging
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import BinaryIO

__all__ = ["ROS1_MAGIC", "Ros1Connection", "Ros1Recovery"]

logger = logging.getLogger(__name__)

ROS1_MAGIC = b"#ROSBAG V2.0\n"

_OP_MSGDATA = 0x02
_OP_BAGHEADER = 0x03
_OP_CHUNK = 0x05
_OP_CONNECTION = 0x07
_UINT32 = struct.Struct("<I")


class _Truncated(Exception):
    """The data stopped in the middle of a record."""


@dataclass(slots=True)
class Ros1Connection:
    """A connection found while walking the bag."""

    conn_id: int
    topic: str
    msgtype: str  # normalised to ROS2 style, e.g. sensor_msgs/msg/PointCloud2
    count: int = 0


@dataclass(slots=True)
class _Survey:
    connections: dict[int, Ros1Connection] = field(default_factory=dict)
    start_ns: int | None = None
    end_ns: int | None = None
    n_messages: int = 0
    n_lost: int = 0
    unreadable_bytes: int = 0


def _normalise_type(msgtype: str) -> str:
    package, _, name = msgtype.partition("/")
    return f"{package}/msg/{name}" if name and "/msg/" not in msgtype else msgtype


def _parse_header(raw: bytes) -> dict[str, bytes]:
    fields: dict[str, bytes] = {}
    pos = 0
    while pos + 4 <= len(raw):
        (length,) = _UINT32.unpack_from(raw, pos)
        pos += 4
        item = raw[pos : pos + length]
        pos += length
        name, sep, value = item.partition(b"=")
        if sep:
            fields[name.decode("ascii", "replace")] = value
    return fields


def _read_exact(handle: BinaryIO, size: int) -> bytes:
    data = handle.read(size)
    if len(data) != size:
        raise _Truncated
    return data


def _read_record_header(handle: BinaryIO) -> tuple[dict[str, bytes], int] | None:
    """Header fields and data length of the next record; None at a clean end of data."""
    first = handle.read(4)
    if not first:
        return None
    if len(first) != 4:
        raise _Truncated
    (header_len,) = _UINT32.unpack(first)
    header = _parse_header(_read_exact(handle, header_len))
    (data_len,) = _UINT32.unpack(_read_exact(handle, 4))
    return header, data_len


def _time_ns(raw: bytes) -> int:
    sec, nsec = struct.unpack("<II", raw)
    return sec * 1_000_000_000 + nsec


def _decompressor(name: str):
    if name == "none":
        return lambda data: data
    if name == "bz2":
        return bz2.decompress
    if name == "lz4":
        import lz4.frame

        return lz4.frame.decompress
    return None


class Ros1Recovery:
    """Reads the complete messages of an unindexed or truncated ROS1 bag, in file order."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._survey: _Survey | None = None

    # The survey walks the whole file once (skipping message payloads where it can) so that the
    # topics, counts and times are known before messages are read.
    def survey(self) -> _Survey:
        if self._survey is None:
            survey = _Survey()
            for conn_id, stamp_ns, _data in self._walk(survey, want_data=False):
                survey.n_messages += 1
                conn = survey.connections.get(conn_id)
                if conn is not None:
                    conn.count += 1
                survey.start_ns = stamp_ns if survey.start_ns is None else min(survey.start_ns, stamp_ns)
                survey.end_ns = stamp_ns if survey.end_ns is None else max(survey.end_ns, stamp_ns)
            self._survey = survey
        return self._survey

    @property
    def connections(self) -> dict[int, Ros1Connection]:
        return self.survey().connections

    @property
    def n_lost(self) -> int:
        """Message records that were cut off inside a chunk (complete messages are all read)."""
        return self.survey().n_lost

    @property
    def unreadable_bytes(self) -> int:
        """Bytes of an unfinished compressed chunk that could not be read."""
        return self.survey().unreadable_bytes

    def messages(self, conn_ids: set[int] | None = None) -> Iterator[tuple[int, int, bytes]]:
        """Yield ``(connection id, log time ns, serialized message)`` for complete messages."""
        for conn_id, stamp_ns, data in self._walk(_Survey(), want_data=True):
            if conn_ids is None or conn_id in conn_ids:
                yield conn_id, stamp_ns, data

    def _walk(self, survey: _Survey, want_data: bool) -> Iterator[tuple[int, int, bytes]]:
        with open(self.path, "rb") as handle:
            if handle.read(len(ROS1_MAGIC)) != ROS1_MAGIC:
                return
            file_size = os.fstat(handle.fileno()).st_size
            while True:
                try:
                    record = _read_record_header(handle)
                except _Truncated:
                    # A cut-off top-level header: an index record, or a chunk of unknown content.
                    return
                if record is None:
                    return
                header, data_len = record
                op = header.get("op", b"\x00")[0]
                data_start = handle.tell()
                if op == _OP_CHUNK:
                    compression = header.get("compression", b"none").decode("ascii", "replace")
                    available = file_size - data_start
                    unfinished = data_len == 0 or data_len > available
                    if unfinished:
                        if compression != "none":
                            survey.unreadable_bytes += max(available, 0)
                            return
                        # Finish reading the unfinished uncompressed chunk straight from the file.
                        yield from self._inner(handle, survey, want_data, limit=None)
                        return
                    decompress = _decompressor(compression)
                    if decompress is None:
                        logger.warning("%s: skipping a chunk with unknown compression %r", self.path, compression)
                        handle.seek(data_len, os.SEEK_CUR)
                        continue
                    if compression == "none" and not want_data:
                        yield from self._inner(handle, survey, want_data, limit=data_start + data_len)
                        handle.seek(data_start + data_len)
                        continue
                    inner = BytesIO(decompress(_read_exact(handle, data_len)))
                    yield from self._inner(inner, survey, want_data, limit=None)
                elif op == _OP_CONNECTION:
                    self._connection(header, _read_exact(handle, data_len), survey)
                elif op == _OP_MSGDATA:
                    # Messages outside chunks do not occur in format 2.0, but are harmless.
                    try:
                        data = _read_exact(handle, data_len)
                    except _Truncated:
                        survey.n_lost += 1
                        return
                    yield _UINT32.unpack(header["conn"])[0], _time_ns(header["time"]), data
                else:
                    if data_start + data_len > file_size:
                        return
                    handle.seek(data_len, os.SEEK_CUR)

    def _inner(
        self, handle: BinaryIO, survey: _Survey, want_data: bool, limit: int | None
    ) -> Iterator[tuple[int, int, bytes]]:
        """Walk the records inside one chunk (``limit``: absolute end offset, None = until data ends)."""
        while limit is None or handle.tell() < limit:
            op = _OP_MSGDATA  # a header cut off inside a chunk is counted as a message
            try:
                record = _read_record_header(handle)
                if record is None:
                    return
                header, data_len = record
                op = header.get("op", b"\x00")[0]
                if op == _OP_MSGDATA:
                    if want_data:
                        data = _read_exact(handle, data_len)
                    else:
                        here = handle.tell()
                        end = handle.seek(0, os.SEEK_END)
                        if here + data_len > end:
                            raise _Truncated
                        handle.seek(here + data_len)
                        data = b""
                    yield _UINT32.unpack(header["conn"])[0], _time_ns(header["time"]), data
                elif op == _OP_CONNECTION:
                    self._connection(header, _read_exact(handle, data_len), survey)
                else:
                    _read_exact(handle, data_len)
            except _Truncated:
                survey.n_lost += 1 if op == _OP_MSGDATA else 0
                return

    @staticmethod
    def _connection(header: dict[str, bytes], data: bytes, survey: _Survey) -> None:
        conn_id = _UINT32.unpack(header["conn"])[0]
        if conn_id in survey.connections:
            return
        details = _parse_header(data)
        topic = header.get("topic", details.get("topic", b"")).decode("utf-8", "replace")
        msgtype = _normalise_type(details.get("type", b"").decode("utf-8", "replace"))
        survey.connections[conn_id] = Ros1Connection(conn_id, topic, msgtype)
