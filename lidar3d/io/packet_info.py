"""What a raw-packet input holds: the library twin of ``lidar3d info`` on pcap files and VelodyneScan bags.

:func:`packet_info` opens the input as every command does (:class:`~lidar3d.io.packet_source.PacketScanSource`),
makes one pass over its packets (no decoding) and reports the sensor (model and how it was found,
factory bytes, return mode, rotation rate), the sweeps, duration, clocks, the position packets'
PPS and NMEA status, and, for pcap files, the UDP ports found.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lidar3d.io.packet_source import PacketScanSource
from lidar3d.io.velodyne_packets import NmeaFix

__all__ = ["PacketInfo", "format_packet_info", "packet_info"]


@dataclass(frozen=True, slots=True)
class PacketInfo:
    """Summary of one raw-packet input.

    Attributes:
        path: the input as given; format: ``pcap``, ``ros1`` or ``ros2``; topic: the VelodyneScan
            topic or ``udp:PORTS``.
        model: the model decoded as; how: ``factory bytes``, ``firing pattern`` or ``given``;
            product: what the product byte names; warning: a model disagreement ("" if none).
        return_mode: ``strongest``, ``last`` or ``dual``; rpm: measured rotation rate.
        n_scans: sweeps; n_packets: data packets; unfinished_packets: after the last cut (not used).
        start_ns, end_ns: host times of the first and last data packet.
        clock: the clock stamps come from (``host`` or ``sensor``); clock_offset_s: host minus sensor time.
        n_position: position packets; pps: the PPS states seen; nmea_first, nmea_last: their fixes.
        ports: pcap only, ``(destination port, datagrams, payload sizes)`` per port.
        notes: warnings (model mismatch, clock offset, truncation).
    """

    path: str
    format: str
    topic: str
    model: str
    how: str
    product: str
    warning: str
    return_mode: str
    rpm: float
    n_scans: int
    n_packets: int
    unfinished_packets: int
    start_ns: int
    end_ns: int
    clock: str
    clock_offset_s: float
    n_position: int
    pps: tuple[str, ...]
    nmea_first: NmeaFix | None
    nmea_last: NmeaFix | None
    ports: tuple[tuple[int, int, tuple[int, ...]], ...]
    notes: tuple[str, ...]

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) * 1e-9


def packet_info(path: str | Path, config: Any = None) -> PacketInfo:
    """Summarise the raw-packet input at ``path`` (see :class:`PacketInfo`) with ``config``'s ``[input]`` keys.

    Raises:
        PacketError: no data packets (the ports found are named), an unknown model.
        BagError: an unreadable bag, or one without a VelodyneScan topic.
    """
    if config is None:
        from lidar3d.config import Config

        config = Config()
    with PacketScanSource(path, config) as source:
        n_scans = source.count_sweeps()
        counts = source.counts
        start_ns, end_ns = source.start_end_ns
        detection = source.sensor.detection
        assert detection.model is not None and detection.return_mode is not None
        positions = [c for c in counts if c.n_position]
        return PacketInfo(
            path=str(path),
            format=str(getattr(source.format, "value", source.format)),
            topic=source.topic,
            model=detection.model.value,
            how=detection.how,
            product=detection.product_name,
            warning=detection.warning,
            return_mode=detection.return_mode.value,
            rpm=source.sensor.rpm,
            n_scans=n_scans,
            n_packets=sum(c.n_data for c in counts),
            unfinished_packets=source.unfinished_packets,
            start_ns=int(start_ns or 0),
            end_ns=int(end_ns or 0),
            clock=config.input.packet_clock,
            clock_offset_s=source.sensor.clock_offset_s,
            n_position=sum(c.n_position for c in counts),
            pps=tuple(sorted({s for c in counts for s in c.pps_states})),
            nmea_first=positions[0].nmea_first if positions else None,
            nmea_last=positions[-1].nmea_last if positions else None,
            ports=tuple(port for c in counts for port in c.ports),
            notes=tuple(source.notes),
        )


def _stamp(stamp_ns: int) -> str:
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return f"{sec}.{nanosec:09d}"


def _fix_text(fix: NmeaFix) -> str:
    if not fix.sentence:
        return "no NMEA sentence"
    if not fix.utc:
        return fix.sentence[:6]
    speed = "" if math.isnan(fix.speed_mps) else f", {fix.speed_mps:.1f} m/s"
    return f"{fix.sentence[1:6]} {fix.utc} UTC, {'valid fix' if fix.valid else 'no fix'}{speed}"


def format_packet_info(info: PacketInfo) -> str:
    """Human-readable text of a :class:`PacketInfo` (what ``lidar3d info`` prints)."""
    period_s = 60.0 / info.rpm if info.rpm > 0 else 0.0
    lines = [
        f"input:        {info.path} ({info.format}, raw Velodyne packets)",
        f"duration:     {info.duration_s:.3f} s ({_stamp(info.start_ns)} .. {_stamp(info.end_ns)}, host clock)",
        f"packets:      {info.n_packets} data packets on {info.topic}",
        f"sensor model: {info.model} (from the {info.how}; product byte: {info.product})",
        f"return mode:  {info.return_mode}",
        f"rotation:     {info.rpm:.1f} rpm ({period_s:.4f} s per sweep)",
        f"scans:        {info.n_scans}"
        + (f" ({info.unfinished_packets} packets after the last cut not used)" if info.unfinished_packets else ""),
        f"clock:        stamps from the {info.clock} clock; host - sensor = {info.clock_offset_s:+.3f} s",
    ]
    if info.n_position:
        first = _fix_text(info.nmea_first) if info.nmea_first else "-"
        last = _fix_text(info.nmea_last) if info.nmea_last else "-"
        lines.append(f"position:     {info.n_position} packets, PPS {', '.join(info.pps)}; first {first}; last {last}")
    else:
        lines.append("position:     no position (NMEA) packets" + ("" if info.format == "pcap" else " in a packet bag"))
    if info.format == "pcap":
        ports = ", ".join(
            f"{port} ({count} x {'/'.join(str(s) for s in sizes[:4])}{'...' if len(sizes) > 4 else ''} bytes)"
            for port, count, sizes in info.ports
        )
        lines.append(f"UDP ports:    {ports}")
    lines.extend(f"note:         {note}" for note in info.notes)
    return "\n".join(lines)
