"""Velodyne data and position packets: layout, factory bytes, model detection, sweeps, NMEA.

A data packet is 1206 bytes (the UDP payload on port 2368 by default): 12 firing blocks of 100
bytes (flag ``0xFFEE``, azimuth uint16 in 0.01 deg, 32 x (distance uint16, intensity uint8)),
then the time stamp uint32 (microseconds past the top of the hour, sensor clock) and the two
factory bytes: return mode (``0x37`` strongest, ``0x38`` last, ``0x39`` dual) and product
(``0x21`` HDL-32E, ``0x22`` VLP-16, ``0x28`` VLP-32C). A position packet is 512 bytes (port 8308):
its PPS status at byte 202 and an NMEA sentence (``$GPRMC``) from byte 206.

The factory byte can be wrong (firmware, re-stamped captures), so :func:`detect_model` checks it
against the firing pattern: how often packets come, by the sensor clock. Each model fires a block
in a fixed time (VLP-16 110.592 us for two 16-laser firings, VLP-32C 55.296 us, HDL-32E 46.08 us;
Velodyne manuals), so a packet of 12 blocks (6 firing positions in dual-return mode) spans a known
time, which is independent of the rotation rate. A model whose period fits the packets is used; a
product byte that disagrees with it is said in a warning.

:class:`SweepCutter` assembles sweeps: a new sweep starts at the first packet whose first azimuth
has passed the cut azimuth (packet granularity, as the ROS velodyne driver cuts).
"""

from __future__ import annotations

import logging
import re
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np

__all__ = [
    "BLOCK_US",
    "DATA_PACKET_SIZE",
    "POSITION_PACKET_SIZE",
    "PRODUCT_IDS",
    "ModelDetection",
    "NmeaFix",
    "PacketModel",
    "ReturnMode",
    "SweepCutter",
    "detect_model",
    "is_data_packet",
    "packet_azimuth_deg",
    "packet_period_us",
    "parse_position_packet",
    "rotation_rpm",
    "sensor_time_us",
]

logger = logging.getLogger(__name__)

DATA_PACKET_SIZE = 1206
POSITION_PACKET_SIZE = 512
_BLOCKS = 12
_BLOCK_FLAG = b"\xff\xee"
_HOUR_US = 3_600_000_000


class PacketModel(str, Enum):
    """The sensor models whose packets are decoded (values are :data:`lidar3d.sensors.SENSOR_MODELS` keys)."""

    VLP16 = "vlp16"
    VLP32C = "vlp32c"
    HDL32E = "hdl32e"


class ReturnMode(str, Enum):
    """What the sensor sends per firing (factory byte 1204)."""

    STRONGEST = "strongest"
    LAST = "last"
    DUAL = "dual"


#: Product byte (1205) -> model.
PRODUCT_IDS: dict[int, PacketModel] = {0x21: PacketModel.HDL32E, 0x22: PacketModel.VLP16, 0x28: PacketModel.VLP32C}
_RETURN_BYTES = {0x37: ReturnMode.STRONGEST, 0x38: ReturnMode.LAST, 0x39: ReturnMode.DUAL}
#: Duration of one firing block (microseconds) per model, from the Velodyne manuals.
BLOCK_US: dict[PacketModel, float] = {PacketModel.VLP16: 110.592, PacketModel.VLP32C: 55.296, PacketModel.HDL32E: 46.08}
_PERIOD_TOLERANCE = 0.08


def packet_period_us(model: PacketModel, mode: ReturnMode) -> float:
    """Time one data packet spans: 12 blocks, or 6 firing positions (two returns each) in dual mode."""
    return BLOCK_US[model] * (_BLOCKS // 2 if mode is ReturnMode.DUAL else _BLOCKS)


def packet_azimuth_deg(data: bytes) -> float:
    """Azimuth (deg, 0..360) of the first block of a data packet."""
    return ((data[2] | data[3] << 8) % 36000) * 0.01


def sensor_time_us(data: bytes) -> int:
    """The packet's sensor time stamp: microseconds past the top of the hour (bytes 1200..1203)."""
    return int(struct.unpack_from("<I", data, 1200)[0])


@dataclass(frozen=True, slots=True)
class ModelDetection:
    """What the packets of a stream say about the sensor.

    Attributes:
        model: the model decoded as (None: nothing fits; the caller must be told the model).
        return_mode: from factory byte 1204 (None for an unknown byte).
        product_byte, return_byte: the factory bytes of the first packet.
        measured_period_us: median sensor-clock interval between consecutive packets (0: unknown).
        pattern_model: the model whose packet period fits ``measured_period_us`` (None: none fits).
        how: ``"factory bytes"``, ``"firing pattern"`` or ``"given"`` (``--sensor``).
        warning: a disagreement between the product byte and the firing pattern, or "" when none.
    """

    model: PacketModel | None
    return_mode: ReturnMode | None
    product_byte: int
    return_byte: int
    measured_period_us: float
    pattern_model: PacketModel | None
    how: str
    warning: str = ""

    @property
    def product_name(self) -> str:
        """The model the product byte names, or its hex value."""
        named = PRODUCT_IDS.get(self.product_byte)
        return named.value if named else f"0x{self.product_byte:02x}"


def _median_period_us(packets: Sequence[bytes]) -> float:
    """Median sensor-clock interval between consecutive packets (us), hour wrap undone; 0 if unknown."""
    if len(packets) < 2:
        return 0.0
    times = np.array([sensor_time_us(p) for p in packets], dtype=np.int64)
    steps = np.diff(times) % _HOUR_US
    steps = steps[(steps > 0) & (steps < 100_000)]
    return float(np.median(steps)) if steps.size else 0.0


def _fitting_model(period_us: float, mode: ReturnMode) -> PacketModel | None:
    if period_us <= 0:
        return None
    fits = [m for m in PacketModel if abs(period_us / packet_period_us(m, mode) - 1.0) < _PERIOD_TOLERANCE]
    return fits[0] if len(fits) == 1 else None


def detect_model(packets: Sequence[bytes], given: PacketModel | None = None) -> ModelDetection:
    """The model and return mode of a stream from its first data packets (a few hundred suffice).

    The firing pattern decides when the packets' period fits exactly one model; otherwise the
    product byte. ``given`` (``--sensor``) overrides both; a disagreement is still said.
    """
    first = packets[0]
    product, return_byte = first[1205], first[1204]
    mode = _RETURN_BYTES.get(return_byte)
    period = _median_period_us(packets)
    pattern = _fitting_model(period, mode or ReturnMode.STRONGEST)
    named = PRODUCT_IDS.get(product)
    warning = ""
    if named is not None and pattern is not None and named is not pattern:
        warning = (
            f"the product byte says {named.value} (0x{product:02x}), but packets come every {period:.1f} us, "
            f"as a {pattern.value}'s do ({packet_period_us(pattern, mode or ReturnMode.STRONGEST):.1f} us)"
        )
    if given is not None:
        return ModelDetection(given, mode, product, return_byte, period, pattern, "given", warning)
    if pattern is not None:
        how = "factory bytes" if named is pattern else "firing pattern"
        return ModelDetection(pattern, mode, product, return_byte, period, pattern, how, warning)
    return ModelDetection(named, mode, product, return_byte, period, None, "factory bytes", warning)


def rotation_rpm(packets: Sequence[bytes]) -> float:
    """Rotation rate (revolutions per minute) from the azimuth advance over sensor time; 0 if unknown."""
    if len(packets) < 2:
        return 0.0
    azimuth = np.array([packet_azimuth_deg(p) for p in packets])
    times = np.array([sensor_time_us(p) for p in packets], dtype=np.int64)
    dt_us = np.diff(times) % _HOUR_US
    turn = np.diff(azimuth) % 360.0
    keep = (dt_us > 0) & (dt_us < 100_000) & (turn < 90.0)
    if not np.any(keep) or dt_us[keep].sum() == 0:
        return 0.0
    return float(turn[keep].sum() / 360.0 / (dt_us[keep].sum() * 1e-6) * 60.0)


class SweepCutter:
    """Says where sweeps start in a stream of data packets, by the packets' first azimuths.

    ``starts_sweep(packet)`` is true for the first packet of the stream and for every packet whose
    first azimuth, counted clockwise from ``cut_azimuth_deg``, is smaller than its predecessor's by
    more than half a turn (the azimuth passed the cut). Dual-return packets repeat azimuths, which
    never passes the cut.
    """

    def __init__(self, cut_azimuth_deg: float) -> None:
        self.cut_azimuth_deg = float(cut_azimuth_deg)
        self._previous: float | None = None

    def starts_sweep(self, data: bytes) -> bool:
        past_cut = (packet_azimuth_deg(data) - self.cut_azimuth_deg) % 360.0
        previous, self._previous = self._previous, past_cut
        return previous is None or past_cut < previous - 180.0


@dataclass(frozen=True, slots=True)
class NmeaFix:
    """What one position packet says: the PPS status and its NMEA sentence (GPRMC fields when present).

    Attributes:
        pps: ``absent``, ``synchronizing``, ``locked``, ``error`` (byte 202), or ``unknown``.
        sentence: the NMEA sentence as sent ("" when the packet holds none).
        valid: the GPRMC status is ``A`` (a fix).
        utc: ``hhmmss`` of the GPRMC sentence ("" without one).
        speed_mps: ground speed (GPRMC knots x 0.514444), NaN without one.
    """

    pps: str
    sentence: str
    valid: bool
    utc: str
    speed_mps: float


_PPS = {0: "absent", 1: "synchronizing", 2: "locked", 3: "error"}
_NMEA = re.compile(rb"\$G[PN][A-Z]{3}[^\r\n\x00]*")


def parse_position_packet(data: bytes) -> NmeaFix:
    """The PPS status and NMEA sentence of a 512-byte position packet."""
    pps = _PPS.get(data[202], "unknown") if len(data) > 202 else "unknown"
    match = _NMEA.search(data)
    sentence = match.group(0).decode("ascii", "replace") if match else ""
    fields = sentence.split(",")
    if not fields[0].endswith("RMC") or len(fields) < 8:
        return NmeaFix(pps, sentence, False, "", float("nan"))
    try:
        speed_mps = float(fields[7]) * 0.514444
    except ValueError:
        speed_mps = float("nan")
    return NmeaFix(pps, sentence, fields[2] == "A", fields[1][:6], speed_mps)


def is_data_packet(payload: bytes) -> bool:
    """Whether a UDP payload has the size and block flags of a Velodyne data packet."""
    return len(payload) == DATA_PACKET_SIZE and payload[0:2] == _BLOCK_FLAG and payload[100:102] == _BLOCK_FLAG
