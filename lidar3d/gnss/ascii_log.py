"""NovAtel ASCII logs: long header (``#NAMEA,...;body*crc``) and short header (``%NAMEA,week,s;body*crc``).

Layouts (field order, counts) from the OEM7 firmware reference pages, checked against the real lines
in ``shared/data/real/novatel_ascii`` (``shared/reference/gnss-and-metrics.md`` sections 1.2, 1.3, 1.6):

* long header, 10 fields: name, port, sequence, idle %, time status, week, seconds, receiver status,
  reserved, software build;
* short header, 3 fields: name, week, seconds;
* INSPVA / INSPVAS body, 12 fields: week, seconds, lat, lon, ellipsoidal height, v_north, v_east,
  v_up, roll, pitch, azimuth, INS status;
* INSPVAX body, 23 fields: INS status, position type, lat, lon, height above MSL, undulation,
  v_north, v_east, v_up, roll, pitch, azimuth, 9 standard deviations, extended status (hex),
  time since update;
* BESTPOS / BESTGNSSPOS body, 21 fields on OEM6/OEM7 (23 on some older firmware, so only the first
  15 are read by position): solution status, position type, lat, lon, height above MSL, undulation,
  datum, 3 standard deviations, station id (quoted), differential age, solution age, #SVs tracked,
  #SVs in solution, ...;
* INSSTDEV body, 14 fields: 9 standard deviations, extended status (hex), time since update,
  3 reserved fields (printed inconsistently, not parsed).
"""

from __future__ import annotations

import csv

from lidar3d.errors import GnssError
from lidar3d.gnss.crc import novatel_crc32
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
    enum_from_name,
    message_problem,
)

__all__ = ["ASCII_LOGS", "MessageRejected", "decode_ascii_message"]

# ASCII log name without the trailing "A" -> canonical log name.
ASCII_LOGS = {
    "INSPVA": "INSPVA",
    "INSPVAS": "INSPVAS",
    "INSPVAX": "INSPVAX",
    "BESTPOS": "BESTPOS",
    "BESTGNSSPOS": "BESTGNSSPOS",
    "BESTGPSPOS": "BESTGNSSPOS",  # OEMV name of BESTGNSSPOS
    "INSSTDEV": "INSSTDEV",
}

_LONG_HEADER_FIELDS = 10
_SHORT_HEADER_FIELDS = 3


class MessageRejected(GnssError):
    """A message candidate that must not be used.

    ``kind`` is "crc" (checksum mismatch), "format" (CRC valid but wrong field count, a value that
    does not parse, or a non-ASCII byte), "range" (well-formed, but a value is non-finite or out of
    range: :func:`~lidar3d.gnss.novatel.message_problem`) or "truncated" (no complete
    ``*xxxxxxxx`` checksum).
    """

    def __init__(self, kind: str, detail: str) -> None:
        super().__init__(detail)
        self.kind = kind


def _split_body(body: str) -> list[str]:
    if '"' in body:
        try:
            return next(csv.reader([body], skipinitialspace=False))
        except csv.Error as err:
            raise ValueError(f"body is not a valid comma-separated list ({err})") from None
    return body.split(",")


def _checked(name_full: str, log: str, message: SpanMessage) -> tuple[str, SpanMessage]:
    problem = message_problem(message)
    if problem is not None:
        raise MessageRejected("range", f"{name_full}: {problem}")
    return log, message


def decode_ascii_message(raw: bytes) -> tuple[str, SpanMessage | None]:
    """Decode one ASCII log (``#...*crc`` or ``%...*crc``, without the line ending).

    Returns ``(log_name, message)``; ``message`` is ``None`` for a CRC-valid log we do not decode
    (its name is returned without the trailing "A"). Raises :class:`MessageRejected` (one line)
    for anything else, including non-ASCII bytes and non-finite or out-of-range values.
    """
    raw = raw.rstrip()  # trailing blanks after the checksum are harmless
    if not raw or raw[:1] not in (b"#", b"%"):
        raise MessageRejected("format", "does not start with '#' or '%'")
    star = raw.rfind(b"*")
    if star < 0 or len(raw) < star + 9:
        raise MessageRejected("truncated", "no complete '*xxxxxxxx' checksum")
    crc_text = raw[star + 1 :]
    try:
        crc_expected = int(crc_text[:8], 16)
    except ValueError:
        raise MessageRejected("crc", f"checksum {crc_text[:8]!r} is not hexadecimal") from None
    if len(crc_text) != 8 or crc_text.strip() != crc_text:
        raise MessageRejected("format", f"checksum field {crc_text!r} is not 8 hex digits")
    payload = raw[1:star]
    crc_actual = novatel_crc32(payload)
    if crc_actual != crc_expected:
        raise MessageRejected("crc", f"CRC mismatch: line says {crc_expected:08x}, computed {crc_actual:08x}")
    try:
        text = payload.decode("ascii")
    except UnicodeDecodeError as err:
        name = payload.split(b",", 1)[0].split(b";", 1)[0].decode("ascii", "replace")[:40]
        raise MessageRejected(
            "format", f"{name}: non-ASCII byte 0x{payload[err.start]:02x} at column {err.start + 2}"
        ) from None
    header_text, semicolon, body = text.partition(";")
    if not semicolon:
        raise MessageRejected("format", "no ';' between header and body")
    header = header_text.split(",")
    short = raw[:1] == b"%"
    expected_header = _SHORT_HEADER_FIELDS if short else _LONG_HEADER_FIELDS
    name_full = header[0]
    if len(header) != expected_header:
        raise MessageRejected("format", f"{name_full}: {len(header)} header fields, expected {expected_header}")
    if not name_full.endswith("A"):
        raise MessageRejected("format", f"{name_full}: not an ASCII log name (no trailing 'A')")
    name = name_full[:-1]
    log = ASCII_LOGS.get(name)
    if log is None:
        return name, None
    try:
        if short:
            week, seconds, time_status = int(header[1]), float(header[2]), None
        else:
            week, seconds = int(header[5]), float(header[6])
            time_status = enum_from_name(TimeStatus, header[4])
        fields = _split_body(body)
        message: SpanMessage
        if log in ("INSPVA", "INSPVAS"):
            message = _inspva(log, fields, time_status)
        elif log == "INSPVAX":
            message = _inspvax(fields, week, seconds, time_status)
        elif log in ("BESTPOS", "BESTGNSSPOS"):
            message = _bestpos(log, fields, week, seconds, time_status)
        else:
            message = _insstdev(fields, week, seconds, time_status)
    except ValueError as err:
        raise MessageRejected("format", f"{name_full}: {err}") from None
    return _checked(name_full, log, message)


def _check_count(log: str, fields: list[str], expected: int, at_least: bool = False) -> None:
    n = len(fields)
    if n < expected or (n != expected and not at_least):
        wanted = f"at least {expected}" if at_least else str(expected)
        raise ValueError(f"{n} body fields, expected {wanted} for {log}")


def _inspva(log: str, f: list[str], time_status: TimeStatus | None) -> InsPvaMessage:
    _check_count(log, f, 12)
    return InsPvaMessage(
        log=log,
        gps_week=int(f[0]),
        gps_seconds=float(f[1]),
        time_status=time_status,
        ins_status=enum_from_name(InsStatus, f[11]),
        position_type=None,
        latitude_deg=float(f[2]),
        longitude_deg=float(f[3]),
        height_ellipsoid_m=float(f[4]),
        undulation_m=None,
        north_velocity_mps=float(f[5]),
        east_velocity_mps=float(f[6]),
        up_velocity_mps=float(f[7]),
        roll_deg=float(f[8]),
        pitch_deg=float(f[9]),
        azimuth_deg=float(f[10]),
    )


def _inspvax(f: list[str], week: int, seconds: float, time_status: TimeStatus | None) -> InsPvaMessage:
    _check_count("INSPVAX", f, 23)
    height_msl_m = float(f[4])
    undulation_m = float(f[5])
    return InsPvaMessage(
        log="INSPVAX",
        gps_week=week,
        gps_seconds=seconds,
        time_status=time_status,
        ins_status=enum_from_name(InsStatus, f[0]),
        position_type=enum_from_name(PositionType, f[1]),
        latitude_deg=float(f[2]),
        longitude_deg=float(f[3]),
        height_ellipsoid_m=height_msl_m + undulation_m,
        undulation_m=undulation_m,
        north_velocity_mps=float(f[6]),
        east_velocity_mps=float(f[7]),
        up_velocity_mps=float(f[8]),
        roll_deg=float(f[9]),
        pitch_deg=float(f[10]),
        azimuth_deg=float(f[11]),
        latitude_std_m=float(f[12]),
        longitude_std_m=float(f[13]),
        height_std_m=float(f[14]),
        roll_std_deg=float(f[18]),
        pitch_std_deg=float(f[19]),
        azimuth_std_deg=float(f[20]),
        extended_status=int(f[21], 16),
    )


def _datum(text: str) -> str:
    text = text.strip()
    if text.isdigit():
        return DATUM_NAMES.get(int(text), text)
    return text


def _bestpos(log: str, f: list[str], week: int, seconds: float, time_status: TimeStatus | None) -> PositionMessage:
    _check_count(log, f, 21, at_least=True)
    return PositionMessage(
        log=log,
        gps_week=week,
        gps_seconds=seconds,
        time_status=time_status,
        solution_status=enum_from_name(SolutionStatus, f[0]),
        position_type=enum_from_name(PositionType, f[1]),
        latitude_deg=float(f[2]),
        longitude_deg=float(f[3]),
        height_msl_m=float(f[4]),
        undulation_m=float(f[5]),
        datum=_datum(f[6]),
        latitude_std_m=float(f[7]),
        longitude_std_m=float(f[8]),
        height_std_m=float(f[9]),
        station_id=f[10].strip('"'),
        differential_age_s=float(f[11]),
        solution_age_s=float(f[12]),
        n_satellites_tracked=int(f[13]),
        n_satellites_used=int(f[14]),
    )


def _insstdev(f: list[str], week: int, seconds: float, time_status: TimeStatus | None) -> InsStdDevMessage:
    _check_count("INSSTDEV", f, 14)
    lat, lon, height, north, east, up, roll, pitch, azimuth = (float(x) for x in f[:9])
    # Body fields in record order: nine standard deviations, extended status, time since update.
    return InsStdDevMessage(
        "INSSTDEV",
        week,
        seconds,
        time_status,
        lat,
        lon,
        height,
        north,
        east,
        up,
        roll,
        pitch,
        azimuth,
        int(f[9], 16),
        int(f[10]),
    )
