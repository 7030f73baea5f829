"""Property-based (fuzz) tests of the NovAtel decoders: only the project's own errors ever come out.

Valid messages (the simulator's INSPVAXA/BESTPOSA lines, lines and binary frames encoded in
tests/novatel_frames.py, and the real OEM7 frames in ../shared when present) are mutated: bytes
flipped or overwritten, cut, inserted, deleted, fields replaced by hostile values (NaN, inf, 1e400,
non-ASCII bytes, huge integers), and often the checksum recomputed so the mutation reaches the
decoding code behind the CRC. Budget: tests/fuzz_settings.py (``make fuzz`` for the big one).
"""

import json
import math
import struct
from pathlib import Path

from fuzz_settings import fuzz_settings
from hypothesis import given
from hypothesis import strategies as st
from novatel_frames import sample_ascii_lines, sample_binary_frames

from lidar3d.config import GnssConfig
from lidar3d.errors import Lidar3dError
from lidar3d.gnss import novatel_crc32, parse_span_bytes, span_reference
from lidar3d.gnss.ascii_log import decode_ascii_message
from lidar3d.gnss.binary_log import decode_binary_frame
from lidar3d.gnss.enu import geodetic_problem

REAL_FRAMES = (
    Path(__file__).resolve().parents[1].parent
    / "shared"
    / "data"
    / "real"
    / "novatel_ascii"
    / "binary_frames_oem7_driver.json"
)

_ASCII_TOKENS = [
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e400",
    "-1e400",
    "",
    "-",
    "+",
    ".",
    "9" * 40,
    "9" * 5000,
    "0x1F",
    "1_0",
    "-90.0000001",
    "90.5",
    "180.0001",
    "-181",
    "1e7",
    "-6356752.3",
    "604800",
    "-1",
    "99999",
    '"',
    '""',
    '"a,b"',
    "INS_SOLUTION_GOOD",
    "INS_ALIGNING",
    "NONE",
    "FINESTEERING",
    "SOL_COMPUTED",
    "ffffffff",
    "zz",
    "\xe9",
    "\xff\xfe",
    "\x00",
    "\t",
    ";",
    "*",
    ",",
    "#",
    "%",
]
_BINARY_VALUES = (
    [struct.pack("<d", v) for v in (math.nan, math.inf, -math.inf, 1e308, -1e308, 91.0, -181.0, 3e4, 0.0)]
    + [struct.pack("<f", v) for v in (math.nan, math.inf, 3.4e38)]
    + [
        b"\xff\xff\xff\xff",
        b"\x00\x00\x00\x00",
        b"\xff\xff",
        b"\x00",
        b"\xff",
    ]
)


def _ascii_pool() -> list[bytes]:
    return list(sample_ascii_lines())


def _binary_pool() -> list[bytes]:
    frames = list(sample_binary_frames())
    if REAL_FRAMES.is_file():
        frames += [bytes.fromhex(f["hex"]) for f in json.loads(REAL_FRAMES.read_text())]
    return frames


def _fix_ascii_crc(line: bytearray) -> bytearray:
    star = line.rfind(b"*")
    if star < 1 or line[:1] not in (b"#", b"%"):
        return line
    return bytearray(line[: star + 1] + f"{novatel_crc32(bytes(line[1:star])):08x}".encode() + line[star + 9 :])


def _fix_binary_crc(frame: bytearray) -> bytearray:
    if len(frame) < 8:
        return frame
    return bytearray(frame[:-4] + struct.pack("<I", novatel_crc32(bytes(frame[:-4]))))


@st.composite
def _mutate(draw, data: bytes, binary: bool) -> bytearray:
    out = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "set", "cut", "insert", "delete", "field"]))
        at = draw(st.integers(0, max(len(out) - 1, 0)))
        if op == "flip" and out:
            out[at] ^= 1 << draw(st.integers(0, 7))
        elif op == "set" and out:
            out[at] = draw(st.integers(0, 255))
        elif op == "cut":
            out = out[:at]
        elif op == "insert":
            out[at:at] = draw(st.binary(min_size=1, max_size=12))
        elif op == "delete":
            del out[at : at + draw(st.integers(1, 16))]
        elif binary:
            value = draw(st.sampled_from(_BINARY_VALUES))
            out[at : at + len(value)] = value
        else:
            fields = out.split(b",")
            k = draw(st.integers(0, len(fields) - 1))
            fields[k] = draw(st.sampled_from(_ASCII_TOKENS)).encode("latin-1")
            out = bytearray(b",".join(fields))
    return out


@st.composite
def ascii_messages(draw) -> bytes:
    line = draw(_mutate(draw(st.sampled_from(_ascii_pool())), binary=False))
    if draw(st.booleans()) or draw(st.booleans()):  # 3 in 4: recompute the CRC to get past it
        line = _fix_ascii_crc(line)
    return bytes(line)


@st.composite
def binary_messages(draw) -> bytes:
    frame = draw(_mutate(draw(st.sampled_from(_binary_pool())), binary=True))
    if draw(st.booleans()) or draw(st.booleans()):
        frame = _fix_binary_crc(frame)
    return bytes(frame)


@st.composite
def streams(draw) -> bytes:
    """A receiver stream: a few messages, ASCII lines (CR LF) and binary frames, some mutated."""
    parts = []
    for _ in range(draw(st.integers(1, 6))):
        if draw(st.booleans()):
            line = draw(ascii_messages()) if draw(st.booleans()) else draw(st.sampled_from(_ascii_pool()))
            parts.append(line + b"\r\n")
        else:
            parts.append(draw(binary_messages()) if draw(st.booleans()) else draw(st.sampled_from(_binary_pool())))
    return b"".join(parts)


@fuzz_settings(400)
@given(ascii_messages())
def test_fuzz_ascii_decoder_raises_only_project_errors(line):
    try:
        name, _message = decode_ascii_message(line)
    except Lidar3dError as err:
        assert str(err)
    else:
        assert isinstance(name, str)


@fuzz_settings(400)
@given(binary_messages())
def test_fuzz_binary_decoder_raises_only_project_errors(frame):
    try:
        name, _message = decode_binary_frame(frame)
    except Lidar3dError as err:
        assert str(err)
    else:
        assert isinstance(name, str)


@fuzz_settings(150)
@given(streams())
def test_fuzz_reader_and_reference_raise_only_project_errors(data):
    log = parse_span_bytes(data, source="fuzz.log")  # the reader counts, it never raises
    for problem in log.stats.problems:
        assert "\n" not in problem
    try:
        reference = span_reference(log, GnssConfig())
    except Lidar3dError as err:
        assert "\n" not in str(err)
    else:
        origin = reference.origin
        assert geodetic_problem(origin.latitude_deg, origin.longitude_deg, origin.height_ellipsoid_m) is None
        assert all(math.isfinite(v) for v in reference.T_enu_imu.reshape(-1))
