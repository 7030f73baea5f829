"""NovAtel binary logs: long header (sync ``AA 44 12``) and short header (sync ``AA 44 13``).

Header layouts (all little-endian; ``shared/reference/gnss-and-metrics.md`` section 1.4, from swri
``binary_header.h`` and NovAtel EDIE ``common.hpp``):

* long: sync(3) header_length(u8, read it: it may grow) message_id(u16) message_type(u8) port(u8)
  body_length(u16) sequence(u16) idle(u8) time_status(u8) week(u16) milliseconds(u32)
  receiver_status(u32) reserved(u16) sw_build(u16) = 28 bytes;
* short: sync(3) body_length(u8) message_id(u16) week(u16) milliseconds(u32) = 12 bytes.

A 32-bit CRC (:func:`lidar3d.gnss.crc.novatel_crc32`) over header and body follows, little-endian.
Body layouts (offsets from the body start; section 1.6, OEM7 log pages): INSPVA/INSPVAS (88 bytes),
INSPVAX (126), BESTPOS/BESTGNSSPOS (72), INSSTDEV (52).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from lidar3d.gnss.ascii_log import MessageRejected
from lidar3d.gnss.novatel import (
    DATUM_NAMES,
    InsPvaMessage,
    InsStatus,
    InsStdDevMessage,
    PositionMessage,
    PositionType,
    SolutionStatus,
    SpanMessage,
    TimeStatus,
    message_problem,
)

__all__ = ["BINARY_LOGS", "LONG_SYNC", "SHORT_SYNC", "BinaryHeader", "decode_binary_frame", "frame_length"]

LONG_SYNC = b"\xaa\x44\x12"
SHORT_SYNC = b"\xaa\x44\x13"
LONG_HEADER_MIN_BYTES = 28
SHORT_HEADER_BYTES = 12
CRC_BYTES = 4

# message id -> (canonical log name, body length in bytes)
BINARY_LOGS = {
    507: ("INSPVA", 88),
    508: ("INSPVAS", 88),
    1465: ("INSPVAX", 126),
    42: ("BESTPOS", 72),
    1429: ("BESTGNSSPOS", 72),
    2051: ("INSSTDEV", 52),
}

# Names of other logs a SPAN stream carries, so that counts of ignored logs are readable.
_OTHER_LOG_NAMES = {
    99: "BESTVEL",
    101: "TIME",
    241: "BESTXYZ",
    264: "INSCOV",
    320: "INSCOVS",
    726: "BESTUTM",
    812: "CORRIMUDATA",
    813: "CORRIMUDATAS",
    1163: "PSRDOP2",
    1335: "HEADING2",
    1362: "IMURATECORRIMUS",
    1945: "INSCONFIG",
    2264: "CORRIMUS",
}

_INSPVA = struct.Struct("<Id3d3d3dI")  # week, seconds, lat lon h, vn ve vu, roll pitch azimuth, status
_INSPVAX = struct.Struct("<II3df3d3d9fIH")
_BESTPOS = struct.Struct("<II3dfI3f4s2f8B")
_INSSTDEV = struct.Struct("<9fIHHII")


@dataclass(frozen=True, slots=True)
class BinaryHeader:
    """The fields of a binary header that decoding needs."""

    short: bool
    header_length: int
    message_id: int
    message_type: int  # long header only (0 for short): bits 5-6 format, bit 7 response
    body_length: int
    time_status: TimeStatus | None
    gps_week: int
    gps_milliseconds: int


def frame_length(data: bytes | memoryview, start: int) -> int | None:
    """Total length (header + body + CRC) of the frame whose sync starts at ``start``.

    ``None`` when the header itself is cut off by the end of ``data``; 0 when the header length
    field is implausible (shorter than the 28 bytes every long header has), i.e. a false sync.
    """
    if data[start + 2] == 0x12:
        if start + LONG_HEADER_MIN_BYTES > len(data):
            return None
        header_length = data[start + 3]
        if header_length < LONG_HEADER_MIN_BYTES:
            return 0
        (body_length,) = struct.unpack_from("<H", data, start + 8)
        return header_length + body_length + CRC_BYTES
    if start + SHORT_HEADER_BYTES > len(data):
        return None
    return SHORT_HEADER_BYTES + data[start + 3] + CRC_BYTES


def _header(frame: bytes) -> BinaryHeader:
    if frame[2] == 0x12:
        message_id, message_type, _port, body_length = struct.unpack_from("<HBBH", frame, 4)
        time_status_value, week, milliseconds = struct.unpack_from("<xBHI", frame, 12)
        try:
            time_status = TimeStatus(time_status_value)
        except ValueError:
            raise MessageRejected("format", f"unknown time status {time_status_value}") from None
        return BinaryHeader(False, frame[3], message_id, message_type, body_length, time_status, week, milliseconds)
    body_length = frame[3]
    message_id, week, milliseconds = struct.unpack_from("<HHI", frame, 4)
    return BinaryHeader(True, SHORT_HEADER_BYTES, message_id, 0, body_length, None, week, milliseconds)


def decode_binary_frame(frame: bytes) -> tuple[str, SpanMessage | None]:
    """Decode one complete binary frame (sync to CRC inclusive) whose CRC was already checked.

    Returns ``(log_name, message)``; ``message`` is ``None`` for logs we do not decode (the name is
    then the log's name where we know it, else ``"ID<n>"``) and for command responses. Raises
    :class:`MessageRejected` for a frame whose length disagrees with its header, a known log with
    the wrong body length or an invalid enum value ("format"), and for non-finite or out-of-range
    values (:func:`~lidar3d.gnss.novatel.message_problem`, "range").
    """
    frame = bytes(frame)
    if frame[:3] not in (LONG_SYNC, SHORT_SYNC):
        raise MessageRejected("format", "binary frame does not start with a NovAtel sync (AA 44 12 or AA 44 13)")
    length = frame_length(frame, 0)
    if not length or length != len(frame):
        raise MessageRejected(
            "format", f"binary frame of {len(frame)} bytes, its header says {length or 'an implausible length'}"
        )
    header = _header(frame)
    known = BINARY_LOGS.get(header.message_id)
    if known is None:
        return _OTHER_LOG_NAMES.get(header.message_id, f"ID{header.message_id}"), None
    log, expected_length = known
    if header.message_type & 0x80 or (header.message_type >> 5) & 0x3:
        return f"{log} (response/non-binary)", None
    if header.body_length != expected_length:
        raise MessageRejected("format", f"{log}: body of {header.body_length} bytes, expected {expected_length}")
    body = frame[header.header_length : header.header_length + header.body_length]
    seconds = header.gps_milliseconds / 1000.0
    message: SpanMessage
    try:
        if log in ("INSPVA", "INSPVAS"):
            message = _inspva(log, body, header.time_status)
        elif log == "INSPVAX":
            message = _inspvax(body, header.gps_week, seconds, header.time_status)
        elif log in ("BESTPOS", "BESTGNSSPOS"):
            message = _bestpos(log, body, header.gps_week, seconds, header.time_status)
        else:
            message = _insstdev(body, header.gps_week, seconds, header.time_status)
    except ValueError as err:
        raise MessageRejected("format", f"{log}: {err}") from None
    problem = message_problem(message)
    if problem is not None:
        raise MessageRejected("range", f"{log}: {problem}")
    return log, message


def _inspva(log: str, body: bytes, time_status: TimeStatus | None) -> InsPvaMessage:
    week, seconds, lat, lon, h, vn, ve, vu, roll, pitch, azimuth, status = _INSPVA.unpack(body)
    return InsPvaMessage(
        log=log,
        gps_week=week,
        gps_seconds=seconds,
        time_status=time_status,
        ins_status=InsStatus(status),
        position_type=None,
        latitude_deg=lat,
        longitude_deg=lon,
        height_ellipsoid_m=h,
        undulation_m=None,
        north_velocity_mps=vn,
        east_velocity_mps=ve,
        up_velocity_mps=vu,
        roll_deg=roll,
        pitch_deg=pitch,
        azimuth_deg=azimuth,
    )


def _inspvax(body: bytes, week: int, seconds: float, time_status: TimeStatus | None) -> InsPvaMessage:
    values = _INSPVAX.unpack(body)
    ins_status, position_type, lat, lon, h_msl, undulation, vn, ve, vu, roll, pitch, azimuth = values[:12]
    std = values[12:21]
    extended_status, _time_since_update = values[21:23]
    return InsPvaMessage(
        log="INSPVAX",
        gps_week=week,
        gps_seconds=seconds,
        time_status=time_status,
        ins_status=InsStatus(ins_status),
        position_type=PositionType(position_type),
        latitude_deg=lat,
        longitude_deg=lon,
        height_ellipsoid_m=h_msl + undulation,
        undulation_m=undulation,
        north_velocity_mps=vn,
        east_velocity_mps=ve,
        up_velocity_mps=vu,
        roll_deg=roll,
        pitch_deg=pitch,
        azimuth_deg=azimuth,
        latitude_std_m=std[0],
        longitude_std_m=std[1],
        height_std_m=std[2],
        roll_std_deg=std[6],
        pitch_std_deg=std[7],
        azimuth_std_deg=std[8],
        extended_status=extended_status,
    )


def _bestpos(log: str, body: bytes, week: int, seconds: float, time_status: TimeStatus | None) -> PositionMessage:
    (
        sol,
        pos_type,
        lat,
        lon,
        h_msl,
        undulation,
        datum,
        lat_sd,
        lon_sd,
        h_sd,
        station,
        diff_age,
        sol_age,
        n_tracked,
        n_used,
        *_rest,
    ) = _BESTPOS.unpack(body)
    return PositionMessage(
        log=log,
        gps_week=week,
        gps_seconds=seconds,
        time_status=time_status,
        solution_status=SolutionStatus(sol),
        position_type=PositionType(pos_type),
        latitude_deg=lat,
        longitude_deg=lon,
        height_msl_m=h_msl,
        undulation_m=undulation,
        datum=DATUM_NAMES.get(datum, str(datum)),
        latitude_std_m=lat_sd,
        longitude_std_m=lon_sd,
        height_std_m=h_sd,
        station_id=station.rstrip(b"\x00").decode("ascii", "replace"),
        differential_age_s=diff_age,
        solution_age_s=sol_age,
        n_satellites_tracked=n_tracked,
        n_satellites_used=n_used,
    )


def _insstdev(body: bytes, week: int, seconds: float, time_status: TimeStatus | None) -> InsStdDevMessage:
    # The first 11 body fields (nine standard deviations, extended status, time since update) are in
    # InsStdDevMessage's field order after the header fields; reserved fields follow.
    return InsStdDevMessage("INSSTDEV", week, seconds, time_status, *_INSSTDEV.unpack(body)[:11])
