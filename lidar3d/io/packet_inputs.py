"""Raw Velodyne data packets out of a recording: a classic pcap file, or a VelodyneScan topic of bags.

Both yield :class:`RawPacket` records in recording order, and fill a :class:`PacketCounts` while
they do (packets read, position packets and their NMEA fixes, UDP ports, losses):

* :class:`PcapPackets`: the 1206-byte UDP payloads to the data ports (``input.data_ports``, 2368)
  of a pcap (:mod:`lidar3d.io.pcap_reader`), stamped with the capture (host) time; 512-byte payloads
  to the position ports (8308) are parsed for PPS status and NMEA.
* :class:`BagPackets`: the ``velodyne_msgs/VelodyneScan`` messages of one topic over one or more
  bags (:mod:`lidar3d.io.bag_inputs`), each packet stamped as the driver stamped it (host time,
  or GPS time with the driver's ``gps_time``). ROS2 bags carry no message definitions, so
  ``VelodyneScan`` and ``VelodynePacket`` are registered in the rosbags typestores here.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lidar3d.errors import PacketError
from lidar3d.io.bag_inputs import BagFormat, BagInput, merged_messages
from lidar3d.io.pcap_reader import PcapReader
from lidar3d.io.velodyne_packets import (
    DATA_PACKET_SIZE,
    POSITION_PACKET_SIZE,
    NmeaFix,
    is_data_packet,
    parse_position_packet,
)

__all__ = ["VELODYNE_SCAN_TYPE", "BagPackets", "PacketCounts", "PcapPackets", "RawPacket", "packet_typestore"]

VELODYNE_SCAN_TYPE = "velodyne_msgs/msg/VelodyneScan"
_PACKET_TYPE = "velodyne_msgs/msg/VelodynePacket"
_DEFINITIONS = {
    BagFormat.ROS1: {
        _PACKET_TYPE: "time stamp\nuint8[1206] data\n",
        VELODYNE_SCAN_TYPE: "Header header\nvelodyne_msgs/VelodynePacket[] packets\n",
    },
    BagFormat.ROS2: {
        _PACKET_TYPE: "builtin_interfaces/Time stamp\nuint8[1206] data\n",
        VELODYNE_SCAN_TYPE: "std_msgs/Header header\nvelodyne_msgs/VelodynePacket[] packets\n",
    },
}


@functools.cache
def packet_typestore(fmt: BagFormat) -> Any:
    """The rosbags typestore of ``fmt`` (ROS1 Noetic, ROS2 Humble) with the velodyne_msgs types registered."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if fmt is BagFormat.ROS1 else Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name, text in _DEFINITIONS[fmt].items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


@dataclass(frozen=True, slots=True)
class RawPacket:
    """One 1206-byte data packet.

    Attributes:
        host_ns: host time of the packet (pcap capture time; the packet stamp in a bag), integer ns.
        data: the 1206 bytes.
        message_start: the first packet of a VelodyneScan message (always false in a pcap).
    """

    host_ns: int
    data: bytes
    message_start: bool = False


@dataclass(slots=True)
class PacketCounts:
    """What reading a packet input met; filled while its packets are read.

    ``ports`` is the pcap's census ``(destination port, datagrams, payload sizes)``; ``nmea_first``
    and ``nmea_last`` the first and last position packets' fixes; ``notes`` say what was lost.
    """

    n_data: int = 0
    n_position: int = 0
    n_skipped_payloads: int = 0
    n_lost: int = 0
    first_host_ns: int | None = None
    last_host_ns: int | None = None
    nmea_first: NmeaFix | None = None
    nmea_last: NmeaFix | None = None
    pps_states: set[str] = field(default_factory=set)
    ports: list[tuple[int, int, tuple[int, ...]]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def note_data(self, host_ns: int) -> None:
        self.n_data += 1
        if self.first_host_ns is None:
            self.first_host_ns = host_ns
        self.last_host_ns = host_ns

    def note_position(self, fix: NmeaFix) -> None:
        self.n_position += 1
        self.pps_states.add(fix.pps)
        if self.nmea_first is None:
            self.nmea_first = fix
        self.nmea_last = fix


class PcapPackets:
    """The data packets of one pcap file (see the module docstring); iterate as often as needed."""

    def __init__(self, path: Path, data_ports: Sequence[int], position_ports: Sequence[int]) -> None:
        self.path = Path(path)
        self.data_ports = frozenset(data_ports)
        self.position_ports = frozenset(position_ports)
        self.counts = PacketCounts()
        PcapReader(self.path).close()  # fail now on a file that is not a pcap

    @property
    def label(self) -> str:
        return str(self.path)

    def __iter__(self) -> Iterator[RawPacket]:
        counts = self.counts = PacketCounts()
        with PcapReader(self.path) as reader:
            for datagram in reader:
                payload = datagram.payload
                if datagram.dst_port in self.data_ports and is_data_packet(payload):
                    counts.note_data(datagram.stamp_ns)
                    yield RawPacket(datagram.stamp_ns, payload)
                elif datagram.dst_port in self.position_ports and len(payload) == POSITION_PACKET_SIZE:
                    counts.note_position(parse_position_packet(payload))
                elif datagram.dst_port in self.data_ports:
                    counts.n_skipped_payloads += 1
            pcap = reader.counts
            counts.ports = pcap.port_census()
            if pcap.truncated_bytes:
                counts.n_lost += 1
                counts.notes.append(
                    f"{self.path}: file cut short inside record {pcap.n_records + 1} "
                    f"({pcap.truncated_bytes} of {pcap.truncated_record_bytes} bytes): 1 packet lost"
                )
            if pcap.damaged_record:
                counts.notes.append(
                    f"{self.path}: record {pcap.damaged_record} declares an impossible length (damaged file); "
                    "the records after it are not read"
                )
            if pcap.n_snapped:
                counts.notes.append(
                    f"{self.path}: {pcap.n_snapped} packets were captured shorter than sent (snap length)"
                )
        if counts.n_skipped_payloads:
            counts.notes.append(
                f"{self.path}: {counts.n_skipped_payloads} payloads to the data ports are not {DATA_PACKET_SIZE}-byte "
                "Velodyne data packets; skipped"
            )


class BagPackets:
    """The data packets of one VelodyneScan topic over opened bag inputs, in log-time order."""

    def __init__(self, inputs: Sequence[BagInput], topic: str, label: str) -> None:
        self.inputs = list(inputs)
        self.topic = topic
        self.label = label
        self.counts = PacketCounts()

    def __iter__(self) -> Iterator[RawPacket]:
        counts = self.counts = PacketCounts()
        counts.n_lost = sum(i.n_lost for i in self.inputs)
        for index, (_log_ns, (fmt, raw)) in enumerate(merged_messages(self.inputs, self.topic)):
            store = packet_typestore(fmt)
            try:
                message = (
                    store.deserialize_ros1(raw, VELODYNE_SCAN_TYPE)
                    if fmt is BagFormat.ROS1
                    else store.deserialize_cdr(raw, VELODYNE_SCAN_TYPE)
                )
            except Exception as err:  # rosbags raises assorted errors on malformed bytes
                raise PacketError(f"{self.label}: {self.topic} message {index} is not a VelodyneScan: {err}") from err
            first = True
            for packet in message.packets:
                data = packet.data.tobytes()
                if not is_data_packet(data):
                    counts.n_skipped_payloads += 1
                    continue
                host_ns = int(packet.stamp.sec) * 1_000_000_000 + int(packet.stamp.nanosec)
                counts.note_data(host_ns)
                yield RawPacket(host_ns, data, first)
                first = False
        if counts.n_skipped_payloads:
            counts.notes.append(
                f"{self.label}: {counts.n_skipped_payloads} packets without Velodyne block flags skipped"
            )
