"""Read a NovAtel log file or raw receiver stream: ASCII and binary messages, in any mix.

One scanner handles all four framings. It looks for the next sync (``#``, ``%``, ``AA 44 12``,
``AA 44 13``), checks the candidate's CRC and decodes it; anything between messages (NMEA sentences,
``<OK`` command replies, ``[COM1]`` prompts, line noise) is skipped and counted as other bytes.

* An ASCII candidate runs from its sync to the end of its printable run. When the run ends at a line
  break it is a line: a bad CRC, wrong field count, unknown log or non-finite or out-of-range value
  (:func:`~lidar3d.gnss.novatel.message_problem`) there is counted (with the line number) and the
  line skipped. A run cut off by the end of the data is a truncated last line
  (tolerated, counted). A run that ends in binary bytes and does not decode is noise.
* A binary candidate is read with the lengths from its header; a CRC mismatch means the sync was
  noise (or the frame is corrupt), so scanning resumes one byte later (resynchronisation). A frame
  cut off by the end of the data is counted as truncated. A CRC-valid frame with out-of-range values
  is counted and skipped, as an ASCII line is.
"""

from __future__ import annotations

import collections
import gzip
import logging
import re
import struct
from pathlib import Path

from lidar3d.errors import GnssError
from lidar3d.gnss.ascii_log import MessageRejected, decode_ascii_message
from lidar3d.gnss.binary_log import decode_binary_frame, frame_length
from lidar3d.gnss.crc import novatel_crc32
from lidar3d.gnss.novatel import InsPvaMessage, InsStdDevMessage, LogStats, PositionMessage, SpanLog

__all__ = ["parse_span_bytes", "read_span_log"]

logger = logging.getLogger(__name__)

_SYNC = re.compile(rb"[#%]|\xaa\x44[\x12\x13]")
_PRINTABLE_RUN = re.compile(rb"[\x20-\x7e]*")
_MAX_PROBLEMS = 20


class _Scan:
    def __init__(self, data: bytes) -> None:
        self.data = data
        self.ins: list[InsPvaMessage] = []
        self.positions: list[PositionMessage] = []
        self.std_devs: list[InsStdDevMessage] = []
        self.decoded: collections.Counter[str] = collections.Counter()
        self.ignored: collections.Counter[str] = collections.Counter()
        self.bad_crc = 0
        self.bad_format = 0
        self.out_of_range = 0
        self.truncated = 0
        self.other_bytes = 0
        self.problems: list[str] = []
        self.cut_candidate: int | None = None
        self.last_message_end = 0

    def where(self, offset: int, ascii_line: bool) -> str:
        if ascii_line:
            line = self.data.count(b"\n", 0, offset) + 1
            return f"line {line}"
        return f"byte {offset}"

    def reject(self, err: MessageRejected, offset: int, ascii_line: bool) -> None:
        if err.kind == "crc":
            self.bad_crc += 1
        elif err.kind == "truncated":
            self.truncated += 1
        elif err.kind == "range":
            self.out_of_range += 1
        else:
            self.bad_format += 1
        if len(self.problems) < _MAX_PROBLEMS:
            self.problems.append(f"{self.where(offset, ascii_line)}: {err}")

    def keep(self, name: str, message) -> None:
        if message is None:
            self.ignored[name] += 1
            return
        self.decoded[name] += 1
        if isinstance(message, InsPvaMessage):
            self.ins.append(message)
        elif isinstance(message, PositionMessage):
            self.positions.append(message)
        else:
            self.std_devs.append(message)

    def ascii_candidate(self, start: int) -> int:
        data = self.data
        printable = _PRINTABLE_RUN.match(data, start)
        assert printable is not None  # the pattern also matches an empty run
        end = printable.end()
        at_eof = end == len(data)
        line_end = at_eof or data[end] in b"\r\n"
        try:
            name, message = decode_ascii_message(data[start:end])
        except MessageRejected as err:
            if not line_end:  # a '#' or '%' byte inside binary data or noise
                self.other_bytes += 1
                return start + 1
            if err.kind == "truncated":
                if at_eof:
                    err = MessageRejected("truncated", f"truncated last line ({err})")
                else:
                    err = MessageRejected("format", f"line without a complete checksum ({err})")
            self.reject(err, start, ascii_line=True)
            return end
        self.keep(name, message)
        self.last_message_end = end
        return end

    def binary_candidate(self, start: int) -> int:
        data = self.data
        length = frame_length(data, start)
        if length == 0:  # implausible header: a false sync in noise
            self.other_bytes += 1
            return start + 1
        if length is None or start + length > len(data):
            # Header or frame runs past the end of the data: a truncated last frame, or a false
            # sync whose length field is noise. Resume one byte later; :meth:`run` decides which.
            self.cut_candidate = start
            self.other_bytes += 1
            return start + 1
        body_end = start + length - 4
        (crc_expected,) = struct.unpack_from("<I", data, body_end)
        if novatel_crc32(data[start:body_end]) != crc_expected:
            self.bad_crc += 1
            if len(self.problems) < _MAX_PROBLEMS:
                self.problems.append(f"byte {start}: binary frame with bad CRC (resynchronising)")
            self.other_bytes += 1
            return start + 1
        try:
            name, message = decode_binary_frame(data[start : start + length])
        except MessageRejected as err:
            self.reject(err, start, ascii_line=False)
            return start + length
        self.keep(name, message)
        self.last_message_end = start + length
        return start + length

    def run(self) -> None:
        data = self.data
        position = 0
        while True:
            match = _SYNC.search(data, position)
            if match is None:
                self.other_bytes += len(data) - position
                if self.cut_candidate is not None and self.cut_candidate >= self.last_message_end:
                    self.truncated += 1
                    if len(self.problems) < _MAX_PROBLEMS:
                        self.problems.append(f"byte {self.cut_candidate}: truncated binary frame at the end")
                return
            start = match.start()
            self.other_bytes += start - position
            position = self.ascii_candidate(start) if data[start] in b"#%" else self.binary_candidate(start)


def parse_span_bytes(data: bytes, source: str = "") -> SpanLog:
    """Decode every NovAtel message in ``data`` (a log file's or receiver stream's bytes)."""
    scan = _Scan(bytes(data))
    scan.run()
    stats = LogStats(
        decoded=scan.decoded,
        ignored=scan.ignored,
        bad_crc=scan.bad_crc,
        bad_format=scan.bad_format,
        out_of_range=scan.out_of_range,
        truncated=scan.truncated,
        other_bytes=scan.other_bytes,
        problems=tuple(scan.problems),
    )
    name = source or "log"
    for problem in scan.problems:
        logger.debug("%s: %s", name, problem)
    if stats.rejected:
        logger.warning("%s: %d message(s) rejected (%s)", name, stats.rejected, stats.summary())
    ins, positions, std_devs = tuple(scan.ins), tuple(scan.positions), tuple(scan.std_devs)
    return SpanLog(ins=ins, positions=positions, std_devs=std_devs, stats=stats, source=source)


def read_span_log(path: str | Path) -> SpanLog:
    """Read a NovAtel ASCII log, binary log (``.gps``) or raw receiver stream; ``.gz`` is unpacked.

    Raises :class:`~lidar3d.errors.GnssError` when the file cannot be read. A file without any
    decodable message is returned empty (the caller decides whether that is an error).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise GnssError(f"{path}: GNSS log not found") from None
    except OSError as err:
        raise GnssError(f"{path}: cannot read GNSS log: {err.strerror}") from err
    if raw[:2] == b"\x1f\x8b":
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError) as err:
            raise GnssError(f"{path}: corrupt gzip file: {err}") from err
    return parse_span_bytes(raw, source=str(path))
