"""Synthetic VLP-16 data packets and the files that carry them (pcap, VelodyneScan bags), for tests.

Packets follow the VLP-16 user manual's layout (section 9): 12 blocks of flag ``FF EE``, azimuth
(0.01 deg), 32 x (distance in 2 mm units, intensity); then the time stamp (us past the hour) and
the factory bytes. A block holds two firings of the 16 lasers (laser ids ordered -15, 1, -13, 3, ...
deg); in dual-return mode blocks come in pairs (last, strongest) at the same azimuth. Every laser
returns ``distance_m`` (the strongest return; the last return ``last_distance_m``), so the decoded
ranges, rings and elevations are known.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np

VLP16_LASER_ELEVATION_DEG = (-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15)
BLOCK_US = 110.592
HOUR_NS = 3_600_000_000_000
T0_NS = 1_700_000_000_000_000_000  # 2023-11-14 22:13:20 UTC


def vlp16_packet(
    azimuth_deg: float,
    sensor_us: int,
    *,
    distance_m: float = 10.0,
    last_distance_m: float = 12.0,
    dual: bool = False,
    product: int = 0x22,
    return_byte: int | None = None,
    step_deg: float = 0.4,
) -> bytes:
    """One 1206-byte packet whose first block is at ``azimuth_deg``, stamped ``sensor_us`` past the hour."""
    out = bytearray()
    near = round(distance_m / 0.002)
    far = round(last_distance_m / 0.002)
    for block in range(12):
        position = block // 2 if dual else block
        azimuth = round(((azimuth_deg + position * step_deg) % 360.0) * 100) % 36000
        units = far if dual and block % 2 == 0 else near
        out += b"\xff\xee" + struct.pack("<H", azimuth)
        for _channel in range(32):
            out += struct.pack("<HB", units, 100)
    mode = return_byte if return_byte is not None else (0x39 if dual else 0x37)
    out += struct.pack("<IBB", sensor_us % 3_600_000_000, mode, product)
    assert len(out) == 1206
    return bytes(out)


def vlp16_stream(
    turns: float,
    *,
    start_deg: float = 90.0,
    rpm: float = 600.0,
    dual: bool = False,
    product: int = 0x22,
    period_scale: float = 1.0,
    sensor_offset_s: float = 0.0,
    **packet_options: float,
) -> list[tuple[int, bytes]]:
    """``(host_ns, packet)`` of ``turns`` rotations from ``start_deg``; the sensor clock runs
    ``sensor_offset_s`` behind the host clock. ``period_scale`` stretches the packet period
    (a firing pattern no model has)."""
    period_us = BLOCK_US * (6 if dual else 12) * period_scale
    step_deg = rpm / 60.0 * 360.0 * BLOCK_US * 1e-6 * period_scale
    per_packet_deg = step_deg * (6 if dual else 12)
    n_packets = int(round(turns * 360.0 / per_packet_deg))
    packets = []
    for index in range(n_packets):
        host_ns = T0_NS + round(index * period_us * 1000)
        sensor_ns = host_ns - round(sensor_offset_s * 1e9)
        sensor_us = (sensor_ns % HOUR_NS) // 1000
        azimuth = start_deg + index * per_packet_deg
        packet = vlp16_packet(azimuth, sensor_us, dual=dual, product=product, step_deg=step_deg, **packet_options)
        packets.append((host_ns, packet))
    return packets


def _udp_frame(payload: bytes, dst_port: int, src_port: int = 2368) -> bytes:
    udp = struct.pack(">HHHH", src_port, dst_port, 8 + len(payload), 0) + payload
    ip = struct.pack(">BBHHHBBH4s4s", 0x45, 0, 20 + len(udp), 0, 0, 64, 17, 0, bytes([192, 168, 1, 201]), bytes(4))
    ethernet = b"\xff" * 6 + b"\x60\x76\x88\x00\x00\x00" + b"\x08\x00"
    return ethernet + ip + udp


def write_pcap(path: Path, packets: Sequence[tuple[int, bytes]], *, port: int = 2368, extra=()) -> Path:
    """A classic pcap (microsecond stamps, Ethernet) of ``packets`` to UDP ``port``; ``extra`` are more
    ``(host_ns, payload, port)`` datagrams, merged by time."""
    records = [(host_ns, payload, port) for host_ns, payload in packets] + list(extra)
    records.sort(key=lambda r: r[0])
    out = bytearray(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))
    for host_ns, payload, dst in records:
        frame = _udp_frame(payload, dst)
        sec, usec = divmod(host_ns // 1000, 1_000_000)
        out += struct.pack("<IIII", sec, usec, len(frame), len(frame)) + frame
    path.write_bytes(bytes(out))
    return path


def write_packet_bag(path: Path, packets: Sequence[tuple[int, bytes]], *, storage: str, per_message: int = 75) -> Path:
    """A VelodyneScan bag (``ros1`` file or ``ros2`` sqlite3 folder) on ``/velodyne_packets``,
    ``per_message`` packets per message, header stamp = first packet."""
    from lidar3d.io.bag_inputs import BagFormat
    from lidar3d.io.packet_inputs import VELODYNE_SCAN_TYPE, packet_typestore

    fmt = BagFormat.ROS1 if storage == "ros1" else BagFormat.ROS2
    store = packet_typestore(fmt)
    types = store.types
    time_type = types["builtin_interfaces/msg/Time"]
    header_type = types["std_msgs/msg/Header"]
    packet_type = types["velodyne_msgs/msg/VelodynePacket"]
    scan_type = types[VELODYNE_SCAN_TYPE]

    def stamp(ns: int):
        sec, nanosec = divmod(ns, 1_000_000_000)
        return time_type(sec=sec, nanosec=nanosec)

    messages = []
    for start in range(0, len(packets), per_message):
        chunk = packets[start : start + per_message]
        header_args = {"stamp": stamp(chunk[0][0]), "frame_id": "velodyne"}
        if fmt is BagFormat.ROS1:
            header_args["seq"] = 0
        message = scan_type(
            header=header_type(**header_args),
            packets=[packet_type(stamp=stamp(ns), data=np.frombuffer(data, np.uint8)) for ns, data in chunk],
        )
        messages.append((chunk[-1][0], message))
    if fmt is BagFormat.ROS1:
        from rosbags.rosbag1 import Writer as Ros1Writer

        with Ros1Writer(path) as writer:
            connection = writer.add_connection("/velodyne_packets", VELODYNE_SCAN_TYPE, typestore=store)
            for log_ns, message in messages:
                writer.write(connection, log_ns, store.serialize_ros1(message, VELODYNE_SCAN_TYPE))
    else:
        from rosbags.rosbag2 import Writer as Ros2Writer

        with Ros2Writer(path, version=8) as writer:
            connection = writer.add_connection("/velodyne_packets", VELODYNE_SCAN_TYPE, typestore=store)
            for log_ns, message in messages:
                writer.write(connection, log_ns, store.serialize_cdr(message, VELODYNE_SCAN_TYPE))
    return path
