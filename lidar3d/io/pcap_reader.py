"""UDP datagrams out of a classic pcap file (libpcap format, as tcpdump, Wireshark and VeloView write).

:class:`PcapReader` walks the records of one file in order and yields :class:`UdpDatagram` records
(capture time, ports, payload) of the IPv4/UDP packets in it. Link layers: Ethernet (with 802.1Q
VLAN tags), Linux cooked capture v1 and v2, raw IPv4, BSD loopback. Anything else in the file (ARP,
TCP, IPv6, IP fragments after the first) is skipped and counted in :class:`PcapCounts`.

A file cut short (a capture killed mid-write, a partial download) is read up to its last complete
record; :attr:`PcapCounts.truncated_bytes` says how much of the cut record was there. pcapng files
are refused with the command that converts them.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from lidar3d.errors import PacketError

__all__ = ["MAX_RECORD_BYTES", "PCAPNG_MAGIC", "PCAP_MAGICS", "PcapCounts", "PcapReader", "UdpDatagram", "is_pcap"]

#: First four bytes of a classic pcap file: microsecond or nanosecond time stamps, either byte order.
PCAP_MAGICS = (b"\xd4\xc3\xb2\xa1", b"\xa1\xb2\xc3\xd4", b"\x4d\x3c\xb2\xa1", b"\xa1\xb2\x3c\x4d")
#: First four bytes of a pcapng file (section header block).
PCAPNG_MAGIC = b"\x0a\x0d\x0d\x0a"

_LINK_ETHERNET = 1
_LINK_NULL = 0
_LINK_RAW = (101, 12, 14)
_LINK_SLL = 113
_LINK_SLL2 = 276
_ETHERTYPE_IPV4 = 0x0800
_ETHERTYPE_VLAN = (0x8100, 0x88A8)
_UDP = 17
_UDP_HEADER = struct.Struct(">HHH")
#: A record longer than this (bytes) is damage, not a packet (libpcap's own limit is 256 KiB).
MAX_RECORD_BYTES = 262_144


def is_pcap(path: Path) -> bool:
    """Whether ``path`` is a file starting like a classic pcap or a pcapng file."""
    try:
        with open(path, "rb") as handle:
            magic = handle.read(4)
    except OSError:
        return False
    return magic in PCAP_MAGICS or magic == PCAPNG_MAGIC


@dataclass(frozen=True, slots=True)
class UdpDatagram:
    """One IPv4/UDP packet of a capture.

    Attributes:
        stamp_ns: capture (host) time of the record, integer nanoseconds since the UNIX epoch.
        src_port, dst_port: UDP ports.
        payload: the UDP payload (as captured: shorter than sent when the capture's snap length cut it).
    """

    stamp_ns: int
    src_port: int
    dst_port: int
    payload: bytes


@dataclass(slots=True)
class PcapCounts:
    """What walking a capture met (counts of records unless named otherwise); filled while reading.

    ``n_snapped`` records were captured shorter than sent (snap length); ``truncated_bytes`` is the
    size of the record the file ends inside (0 when the file ends on a record boundary);
    ``damaged_record`` the number of a record whose header declares an impossible length (reading
    stops there; 0 when none).
    """

    n_records: int = 0
    n_udp: int = 0
    n_other: int = 0
    n_fragments: int = 0
    n_snapped: int = 0
    truncated_bytes: int = 0
    truncated_record_bytes: int = 0
    damaged_record: int = 0
    ports: dict[tuple[int, int], int] = field(default_factory=dict)

    def note_port(self, port: int, size: int) -> None:
        """Count one datagram of ``size`` payload bytes to destination ``port`` (for the port census)."""
        key = (port, size)
        self.ports[key] = self.ports.get(key, 0) + 1

    def port_census(self) -> list[tuple[int, int, tuple[int, ...]]]:
        """``(destination port, datagrams, payload sizes)`` per port, most datagrams first."""
        by_port: dict[int, tuple[int, set[int]]] = {}
        for (port, size), count in self.ports.items():
            total, sizes = by_port.get(port, (0, set()))
            sizes.add(size)
            by_port[port] = (total + count, sizes)
        return sorted(
            ((port, total, tuple(sorted(sizes))) for port, (total, sizes) in by_port.items()),
            key=lambda item: (-item[1], item[0]),
        )


class PcapReader:
    """The UDP datagrams of one classic pcap file, in file order (a context manager).

    Args:
        path: the capture.

    Raises (on opening):
        PacketError: missing or unreadable file, a pcapng file, a file too short for the pcap header,
            or an unsupported link layer.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.counts = PcapCounts()
        try:
            self._handle: BinaryIO = open(self.path, "rb")  # noqa: SIM115 - closed by close()
        except OSError as err:
            raise PacketError(f"{self.path}: cannot read: {err.strerror}") from err
        try:
            self._read_header()
        except BaseException:
            self._handle.close()
            raise

    def _read_header(self) -> None:
        header = self._handle.read(24)
        magic = header[:4]
        if magic == PCAPNG_MAGIC:
            raise PacketError(
                f"{self.path}: a pcapng file; only classic pcap is read (convert it: "
                f"editcap -F pcap {self.path.name} out.pcap)"
            )
        if magic not in PCAP_MAGICS or len(header) < 24:
            raise PacketError(f"{self.path}: not a pcap file (or cut short inside its 24-byte header)")
        self._order = "<" if magic in (PCAP_MAGICS[0], PCAP_MAGICS[2]) else ">"
        self._ns_per_tick = 1 if magic in PCAP_MAGICS[2:] else 1000
        self._record = struct.Struct(self._order + "IIII")
        self.link_type = struct.unpack_from(self._order + "I", header, 20)[0] & 0x0FFFFFFF
        if self.link_type not in (_LINK_ETHERNET, _LINK_NULL, _LINK_SLL, _LINK_SLL2, *_LINK_RAW):
            raise PacketError(
                f"{self.path}: unsupported pcap link type {self.link_type} (Ethernet, SLL, raw IP are read)"
            )

    def __enter__(self) -> PcapReader:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def close(self) -> None:
        self._handle.close()

    def __iter__(self) -> Iterator[UdpDatagram]:
        """Every IPv4/UDP datagram of the file, in file order; other records are counted and skipped."""
        read = self._handle.read
        counts = self.counts
        while True:
            head = read(16)
            if len(head) < 16:
                if head:
                    counts.truncated_bytes, counts.truncated_record_bytes = len(head), 16
                return
            sec, frac, caplen, origlen = self._record.unpack(head)
            if caplen > MAX_RECORD_BYTES:
                counts.damaged_record = counts.n_records + 1
                return
            frame = read(caplen)
            if len(frame) < caplen:
                counts.truncated_bytes, counts.truncated_record_bytes = 16 + len(frame), 16 + caplen
                return
            counts.n_records += 1
            if caplen < origlen:
                counts.n_snapped += 1
            datagram = self._udp(frame, sec * 1_000_000_000 + frac * self._ns_per_tick)
            if datagram is not None:
                counts.n_udp += 1
                counts.note_port(datagram.dst_port, len(datagram.payload))
                yield datagram
            else:
                counts.n_other += 1

    def _ip_offset(self, frame: bytes) -> int:
        """Byte offset of the IPv4 header in ``frame``, or -1 when the frame carries no IPv4."""
        link = self.link_type
        if link == _LINK_ETHERNET:
            offset, ethertype = 14, int.from_bytes(frame[12:14], "big")
            while ethertype in _ETHERTYPE_VLAN and len(frame) >= offset + 4:
                ethertype = int.from_bytes(frame[offset + 2 : offset + 4], "big")
                offset += 4
            return offset if ethertype == _ETHERTYPE_IPV4 else -1
        if link == _LINK_SLL:
            return 16 if int.from_bytes(frame[14:16], "big") == _ETHERTYPE_IPV4 else -1
        if link == _LINK_SLL2:
            return 20 if int.from_bytes(frame[0:2], "big") == _ETHERTYPE_IPV4 else -1
        if link == _LINK_NULL:
            return 4 if frame[:4] in (b"\x02\x00\x00\x00", b"\x00\x00\x00\x02") else -1
        return 0

    def _udp(self, frame: bytes, stamp_ns: int) -> UdpDatagram | None:
        # the common case first: untagged Ethernet, IPv4, UDP, not a fragment (DF allowed)
        if (
            self.link_type == _LINK_ETHERNET
            and len(frame) >= 42
            and frame[12:14] == b"\x08\x00"
            and frame[23] == _UDP
            and not (frame[20] & 0x3F or frame[21])
            and len(frame) >= (udp := 14 + (frame[14] & 0x0F) * 4) + 8
        ):
            src, dst, length = _UDP_HEADER.unpack_from(frame, udp)
            return UdpDatagram(stamp_ns, src, dst, frame[udp + 8 : udp + max(length, 8)])
        ip = self._ip_offset(frame)
        if ip < 0 or len(frame) < ip + 20 or frame[ip] >> 4 != 4 or frame[ip + 9] != _UDP:
            return None
        flags_offset = int.from_bytes(frame[ip + 6 : ip + 8], "big")
        if flags_offset & 0x1FFF:  # a later fragment: no UDP header of its own
            self.counts.n_fragments += 1
            return None
        udp = ip + (frame[ip] & 0x0F) * 4
        if len(frame) < udp + 8:
            return None
        src, dst, length = struct.unpack_from(">HHH", frame, udp)
        end = min(len(frame), udp + max(length, 8)) if not flags_offset & 0x2000 else len(frame)
        return UdpDatagram(stamp_ns, src, dst, frame[udp + 8 : end])
