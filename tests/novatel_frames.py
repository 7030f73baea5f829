"""NovAtel messages for tests: ASCII lines and binary frames encoded here from the OEM7 layouts.

Binary layouts (little-endian) as in ``shared/reference/gnss-and-metrics.md`` section 1.4/1.6: a
28-byte long header or a 12-byte short header, the body, then the CRC-32 of header and body. The
bodies are packed here independently of :mod:`lidar3d.gnss.binary_log`.
"""

import functools
import struct

from lidar3d.gnss import novatel_crc32

__all__ = [
    "SECONDS",
    "WEEK",
    "ascii_line",
    "bestpos_body",
    "binary_frame",
    "inspva_body",
    "inspva_line",
    "inspvax_body",
    "inspvax_body_fields",
    "insstdev_body",
    "sample_ascii_lines",
    "sample_binary_frames",
]

WEEK = 2300
SECONDS = 300000.0
LAT, LON, H = 48.137, 11.575, 567.0


def ascii_line(sync: str, header: str, body: str) -> bytes:
    """``sync + header;body*crc`` (no line ending) with the NovAtel CRC over header;body."""
    payload = f"{header};{body}".encode("latin-1")
    return sync.encode() + payload + f"*{novatel_crc32(payload):08x}".encode()


def inspva_line(lat="48.137", lon="11.575", h="567.0", seconds=SECONDS, short=False) -> bytes:
    """An INSPVA (long header) or INSPVAS (short header) line with the given position fields."""
    body = f"{WEEK},{seconds:.3f},{lat},{lon},{h},0.1,5.0,0.0,0.5,-0.3,45.0,INS_SOLUTION_GOOD"
    if short:
        return ascii_line("%", f"INSPVASA,{WEEK},{seconds:.3f}", body)
    return ascii_line("#", f"INSPVAA,COM1,0,70.0,FINESTEERING,{WEEK},{seconds:.3f},02000020,54e2,16809", body)


def inspvax_body_fields(lat="48.137", lon="11.575", h_msl="519.6", undulation="47.4") -> list[str]:
    """The 23 INSPVAX body fields."""
    return [
        "INS_SOLUTION_GOOD",
        "INS_RTKFIXED",
        lat,
        lon,
        h_msl,
        undulation,
        "0.1",
        "5.0",
        "0.0",
        "0.5",
        "-0.3",
        "45.0",
        "0.01",
        "0.01",
        "0.02",
        "0.001",
        "0.001",
        "0.001",
        "0.005",
        "0.005",
        "0.01",
        "13000045",
        "0",
    ]


def binary_frame(
    message_id: int,
    body: bytes,
    *,
    short: bool = False,
    week: int = WEEK,
    milliseconds: int = int(SECONDS * 1000),
    time_status: int = 180,
) -> bytes:
    """A complete binary frame (long or short header, body, CRC)."""
    if short:
        header = struct.pack("<3sBHHI", b"\xaa\x44\x13", len(body), message_id, week, milliseconds)
    else:
        header = struct.pack(
            "<3sBHBBHHBBHIIHH",
            b"\xaa\x44\x12",
            28,
            message_id,
            0,
            0x20,
            len(body),
            0,
            120,
            time_status,
            week,
            milliseconds,
            0x02000020,
            0x54E2,
            16809,
        )
    frame = header + body
    return frame + struct.pack("<I", novatel_crc32(frame))


def inspva_body(
    lat=LAT,
    lon=LON,
    h=H,
    vn=0.1,
    ve=5.0,
    vu=0.0,
    roll=0.5,
    pitch=-0.3,
    azimuth=45.0,
    status=3,
    week=WEEK,
    seconds=SECONDS,
) -> bytes:
    """INSPVA/INSPVAS body (88 bytes)."""
    return struct.pack("<Id3d3d3dI", week, seconds, lat, lon, h, vn, ve, vu, roll, pitch, azimuth, status)


def inspvax_body(lat=LAT, lon=LON, h_msl=H - 47.4, undulation=47.4, status=3, position_type=56) -> bytes:
    """INSPVAX body (126 bytes)."""
    std = [0.01, 0.01, 0.02, 0.001, 0.001, 0.001, 0.005, 0.005, 0.01]
    return struct.pack(
        "<II3df3d3d9fIH",
        status,
        position_type,
        lat,
        lon,
        h_msl,
        undulation,
        0.1,
        5.0,
        0.0,
        0.5,
        -0.3,
        45.0,
        *std,
        0x13000045,
        0,
    )


def bestpos_body(lat=LAT, lon=LON, h_msl=H - 47.4, undulation=47.4) -> bytes:
    """BESTPOS body (72 bytes): SOL_COMPUTED, NARROW_INT, WGS84 (61)."""
    return struct.pack(
        "<II3dfI3f4s2f8B",
        0,
        50,
        lat,
        lon,
        h_msl,
        undulation,
        61,
        0.01,
        0.01,
        0.02,
        b"0\x00\x00\x00",
        1.0,
        0.0,
        20,
        18,
        18,
        18,
        0,
        1,
        0x30,
        0x33,
    )


def insstdev_body() -> bytes:
    """INSSTDEV body (52 bytes)."""
    return struct.pack("<9fIHHII", 0.4, 0.3, 0.7, 0.01, 0.01, 0.02, 0.05, 0.05, 0.2, 0x26000005, 0, 0, 0, 0)


@functools.lru_cache(maxsize=1)
def sample_ascii_lines() -> tuple[bytes, ...]:
    """Valid ASCII lines: the simulator's INSPVAXA/BESTPOSA, plus INSPVA, INSPVAS and INSSTDEV."""
    from lidar3d.sim import Simulation

    sim_lines = Simulation("loop", duration_s=2.0).span_log_lines()
    lines = [line.rstrip("\r\n").encode("ascii") for line in sim_lines[:6]]
    lines.append(inspva_line())
    lines.append(inspva_line(short=True))
    lines.append(
        ascii_line(
            "#",
            f"INSPVAXA,COM1,0,60.5,FINESTEERING,{WEEK},{SECONDS:.3f},02000020,46eb,16809",
            ",".join(inspvax_body_fields()),
        )
    )
    lines.append(
        ascii_line(
            "#",
            f"INSSTDEVA,COM1,0,70.0,FINESTEERING,{WEEK},{SECONDS:.3f},02000020,a4b1,16809",
            "0.4,0.3,0.7,0.01,0.01,0.02,0.05,0.05,0.2,26000005,0,0,0,0",
        )
    )
    return tuple(lines)


def sample_binary_frames() -> tuple[bytes, ...]:
    """Valid binary frames of every decoded log, long and short headers."""
    return (
        binary_frame(507, inspva_body()),
        binary_frame(508, inspva_body(), short=True),
        binary_frame(1465, inspvax_body()),
        binary_frame(42, bestpos_body()),
        binary_frame(1429, bestpos_body()),
        binary_frame(2051, insstdev_body()),
    )
