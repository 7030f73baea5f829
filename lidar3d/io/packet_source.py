"""Scans from raw Velodyne packets: pcap files or VelodyneScan bags, with the interface of :class:`ScanSource`.

:class:`PacketScanSource` reads the packets (:mod:`lidar3d.io.packet_inputs`), learns the sensor
from the first few hundred (:func:`lidar3d.io.velodyne_packets.detect_model`: model, return mode,
rotation rate; the host-sensor clock offset), assembles sweeps and decodes each through
:class:`~lidar3d.io.packet_decoder.PacketDecoder`. Sweeps: in a pcap (and in a bag with
``input.recut_sweeps``) a sweep starts where the azimuth passes ``input.cut_azimuth_deg``; the
first sweep of a recording is partial (the capture began mid-turn) and is kept, as a live driver
publishes it; the packets after the last cut belong to a sweep that never finished and are not
used. In a bag each VelodyneScan message is one sweep, as the driver cut it.

:func:`lidar3d.io.scan_source.open_scan_source` returns one of these for packet inputs, so every
command reads packets through the same path.
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lidar3d.errors import PacketError
from lidar3d.io.bag_inputs import BagFormat, BagInput, TopicInfo, log_time_span, merge_topics, open_bag_input
from lidar3d.io.packet_decoder import PacketDecoder, sensor_stamp_ns
from lidar3d.io.packet_inputs import VELODYNE_SCAN_TYPE, BagPackets, PacketCounts, PcapPackets, RawPacket
from lidar3d.io.pcap_reader import is_pcap
from lidar3d.io.scan_reading import ReadStats, bag_label, choose_lidar_topic
from lidar3d.io.velodyne_packets import ModelDetection, PacketModel, SweepCutter, detect_model, rotation_rpm
from lidar3d.records import Scan
from lidar3d.sensors import SENSOR_MODELS, SensorModel

__all__ = [
    "CLOCK_OFFSET_WARN_S",
    "PEEK_PACKETS",
    "PacketScanSource",
    "PacketSensor",
    "PcapFormat",
    "input_config",
    "is_packet_input",
    "learn_sensor",
]

logger = logging.getLogger(__name__)

#: Data packets read on opening to learn the sensor (about a quarter turn of a VLP-16).
PEEK_PACKETS = 300
#: A host-sensor clock difference above this is said in a warning (transmission delay is ~1 ms).
CLOCK_OFFSET_WARN_S = 0.1
#: A measured rotation rate this far (relative) from the preset's replaces it.
_RATE_TOLERANCE = 0.05
PcapFormat = "pcap"


@dataclass(frozen=True, slots=True)
class PacketSensor:
    """What the first packets of an input say about its sensor.

    Attributes:
        detection: model, return mode, factory bytes, firing period (:class:`ModelDetection`).
        rpm: rotation rate from the azimuth advance over sensor time (revolutions per minute).
        clock_offset_s: median host time minus sensor time (seconds).
    """

    detection: ModelDetection
    rpm: float
    clock_offset_s: float

    @property
    def model(self) -> PacketModel:
        model = self.detection.model
        assert model is not None
        return model

    def sensor_model(self) -> SensorModel:
        """The detected model's geometry; when the measured rotation rate is off the preset's, with that
        rate and the range-image columns scaled to it (the firing rate is fixed, so a faster turn fires
        fewer times per sweep: columns = preset columns x preset rate / rate)."""
        base = SENSOR_MODELS[self.model.value]
        hz = self.rpm / 60.0
        if hz > 0 and abs(hz / base.rotation_hz - 1.0) > _RATE_TOLERANCE:
            columns = round(base.n_columns * base.rotation_hz / hz)
            return dataclasses.replace(base, rotation_hz=round(hz, 3), n_columns=columns)
        return base

    def pipeline_config(self, config: Any) -> Any:
        """``config`` with ``sensor.model`` of the packets and, when their rotation rate is off the
        preset's (:meth:`sensor_model`) and ``sensor.rotation_override_hz`` is not set, that rate and
        its columns (unless ``sensor.n_columns_override`` is set), for the pipeline."""
        model = self.sensor_model()
        sensor = config.sensor
        preset = SENSOR_MODELS[model.name]
        rate, columns = sensor.rotation_override_hz, sensor.n_columns_override
        if not rate and model.rotation_hz != preset.rotation_hz:
            rate = model.rotation_hz
            columns = columns or model.n_columns
        return dataclasses.replace(
            config,
            sensor=dataclasses.replace(sensor, model=model.name, rotation_override_hz=rate, n_columns_override=columns),
        )


def learn_sensor(first: Sequence[RawPacket], given: PacketModel | None, label: str) -> PacketSensor:
    """The :class:`PacketSensor` of a stream from its first data packets (``given``: ``--sensor``).

    Raises:
        PacketError: no model fits (and none is given), or the return mode byte is unknown.
    """
    detection = detect_model([p.data for p in first], given)
    if detection.model is None:
        raise PacketError(
            f"{label}: unknown Velodyne model: product byte {detection.product_name}, return byte "
            f"0x{detection.return_byte:02x}, packets every {detection.measured_period_us:.1f} us (no model fits); "
            f"give the model with --sensor ({', '.join(m.value for m in PacketModel)})"
        )
    if detection.return_mode is None:
        raise PacketError(
            f"{label}: unknown return mode byte 0x{detection.return_byte:02x} (0x37 strongest, 0x38 last, 0x39 dual)"
        )
    offset_s = float(np.median([(p.host_ns - sensor_stamp_ns(p)) * 1e-9 for p in first]))
    return PacketSensor(detection, rotation_rpm([p.data for p in first]), offset_s)


def _sensor_warnings(sensor: PacketSensor, label: str, clock: str, pps: Sequence[str]) -> list[str]:
    """The model disagreement and a large host-sensor clock offset, as warning lines."""
    warnings = []
    detection = sensor.detection
    if detection.warning:
        advice = "; give another with --sensor" if detection.how != "given" else ""
        warnings.append(f"{label}: {detection.warning}; decoding as {sensor.model.value}{advice}")
    if abs(sensor.clock_offset_s) > CLOCK_OFFSET_WARN_S:
        warnings.append(
            f"{label}: the host clock is {sensor.clock_offset_s:+.3f} s from the sensor's clock "
            f"(sensor PPS: {', '.join(pps) if pps else 'no position packets'}); stamps from the {clock} clock "
            "(input.packet_clock); evaluate against GNSS with the clock that was synchronised to it"
        )
    return warnings


def _no_data_text(label: str, streams: Sequence[PcapPackets | BagPackets], topic: str, ports: Sequence[int]) -> str:
    """The error line of an input without data packets (for pcap files: the UDP ports it holds)."""
    if not isinstance(streams[0], PcapPackets):
        return f"{label}: {topic} holds no Velodyne data packets"
    census = [port for stream in streams for port in stream.counts.ports]
    found = ", ".join(
        f"{port} ({count} datagrams of {sizes[0]}{'-' + str(sizes[-1]) if len(sizes) > 1 else ''} bytes)"
        for port, count, sizes in census[:6]
    )
    wanted = ", ".join(str(p) for p in ports)
    held = f"UDP ports found: {found}" if census else "it holds no IPv4/UDP packets"
    return (
        f"{label}: no Velodyne data packets (1206-byte UDP payloads to port {wanted}); {held}; "
        "other ports: input.data_ports or --ports"
    )


def _all_pcap(paths: Sequence[Path], label: str) -> bool:
    """Whether every path is a pcap file (none: bags); raises on a mix of both."""
    pcaps = [is_pcap(p) for p in paths]
    if any(pcaps) and not all(pcaps):
        raise PacketError(f"{label}: pcap files and bags cannot be read as one recording")
    return all(pcaps)


class PacketScanSource:
    """Scans from raw packets, lazily, in recording order (a context manager, as :class:`ScanSource`).

    Args:
        paths: pcap files (read in the order given) or bags with a VelodyneScan topic.
        config: a :class:`lidar3d.config.Config` (``input`` keys; ``sensor.min_range_m``).
        quiet: warnings are logged at debug level (still in :attr:`notes`): for a second opening.

    Raises (on opening):
        PacketError: no data packets (the UDP ports found are listed), an unknown model, a bad calibration.
        BagError: a bag that cannot be read, or without a (single) VelodyneScan topic.
    """

    def __init__(self, paths: str | Path | Sequence[str | Path], config: Any, *, quiet: bool = False) -> None:
        if isinstance(paths, (str, Path)):
            paths = [paths]
        self.paths: tuple[Path, ...] = tuple(Path(p) for p in paths)
        if not self.paths:
            raise PacketError("no input given")
        self.label = bag_label(list(self.paths))
        self.config = config
        self._quiet = quiet
        self._inputs: list[BagInput] = []
        self._streams: list[PcapPackets | BagPackets] = []
        self._topic = ""
        self._topics: dict[str, TopicInfo] = {}
        self._sensor: PacketSensor | None = None
        self._notes: list[str] = []
        self._length: int | None = None
        self._stats = ReadStats()
        self._lost = 0
        self._unfinished = 0

    # -- lifecycle -----------------------------------------------------------------------------
    def open(self) -> PacketScanSource:
        """Open the inputs and learn the sensor from the first packets. Idempotent while open."""
        if self._streams:
            return self
        try:
            self._open_streams()
            self._learn_sensor()
        except BaseException:
            self.close()
            raise
        return self

    def _open_streams(self) -> None:
        inputs = self.config.input
        if _all_pcap(self.paths, self.label):
            self._streams = [PcapPackets(p, inputs.data_ports, inputs.position_ports) for p in self.paths]
            self._topic = "udp:" + ",".join(str(p) for p in inputs.data_ports)
            return
        for path in self.paths:
            self._inputs.append(open_bag_input(path))
        self._topics = merge_topics(info for opened in self._inputs for info in opened.topics.values())
        self._topic = choose_lidar_topic(self._topics, inputs.topic or None, self.label, packets=True)
        self._streams = [BagPackets(self._inputs, self._topic, self.label)]
        self._notes = [f"{i.path}: {i.note}" for i in self._inputs if i.note]

    def _packets(self) -> Iterator[RawPacket]:
        for stream in self._streams:
            yield from stream

    def _learn_sensor(self) -> None:
        first = list(itertools.islice(self._packets(), PEEK_PACKETS))
        inputs = self.config.input
        if not first:
            raise PacketError(_no_data_text(self.label, self._streams, self._topic, inputs.data_ports))
        given = None if inputs.packet_model == "auto" else PacketModel(inputs.packet_model)
        self._sensor = learn_sensor(first, given, self.label)
        pps = sorted({state for counts in self.counts for state in counts.pps_states})
        for warning in _sensor_warnings(self._sensor, self.label, inputs.packet_clock, pps):
            self._warn(warning)
        self.make_decoder()  # fail now on a bad calibration

    def _warn(self, text: str) -> None:
        logger.log(logging.DEBUG if self._quiet else logging.WARNING, "%s", text)
        self._notes.append(text)

    def close(self) -> None:
        """Close the bag inputs (pcap files are opened per pass)."""
        self._stats = self.stats
        inputs, self._inputs, self._streams = self._inputs, [], []
        for opened in inputs:
            opened.close()

    def __enter__(self) -> PacketScanSource:
        return self.open()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- what is in the input ------------------------------------------------------------------
    @property
    def sensor(self) -> PacketSensor:
        """What the first packets say about the sensor (see :class:`PacketSensor`)."""
        if self._sensor is None:
            raise PacketError(f"{self.label}: packet source is not open (use it in a with-block)")
        return self._sensor

    @property
    def topic(self) -> str:
        """The VelodyneScan topic, or ``udp:PORTS`` for pcap files."""
        return self._topic

    @property
    def format(self) -> BagFormat | str:
        """The bags' container format, or ``"pcap"``."""
        return self._inputs[0].fmt if self._inputs else PcapFormat

    @property
    def counts(self) -> list[PacketCounts]:
        """What the last pass over each stream met (ports, NMEA, losses)."""
        return [stream.counts for stream in self._streams]

    @property
    def start_end_ns(self) -> tuple[int | None, int | None]:
        """Log times (bags) or host times of the first and last data packet (pcap, after a pass)."""
        if self._inputs:
            return log_time_span(self._inputs)
        firsts = [c.first_host_ns for c in self.counts if c.first_host_ns is not None]
        lasts = [c.last_host_ns for c in self.counts if c.last_host_ns is not None]
        return (min(firsts) if firsts else None), (max(lasts) if lasts else None)

    @property
    def notes(self) -> list[str]:
        return list(self._notes)

    @property
    def stats(self) -> ReadStats:
        return dataclasses.replace(self._stats, n_lost_messages=max(self._lost, self._stats.n_lost_messages))

    @property
    def unfinished_packets(self) -> int:
        """Packets after the last cut of the last pass (a sweep that never finished; not used)."""
        return self._unfinished

    def __len__(self) -> int:
        """Number of sweeps (for pcap files and re-cut bags a pass over the packets, made once)."""
        if self._length is None:
            self._length = self.count_sweeps() if self._recut() else self._topics[self._topic].count
        return self._length

    def count_sweeps(self) -> int:
        """A pass over every packet (no decoding): the number of sweeps; fills :attr:`counts`."""
        return sum(1 for _sweep in self._sweeps())

    # -- reading -------------------------------------------------------------------------------
    def _recut(self) -> bool:
        return not self._inputs or bool(self.config.input.recut_sweeps)

    def make_decoder(self) -> PacketDecoder:
        inputs = self.config.input
        return PacketDecoder(
            self.sensor.model,
            return_mode=self.sensor.detection.return_mode,
            keep=inputs.packet_return,
            clock=inputs.packet_clock,
            sensor=self.sensor.sensor_model(),
            min_range_m=self.config.sensor.min_range_m,
            calibration=inputs.calibration or None,
        )

    def _sweeps(self) -> Iterator[list[RawPacket]]:
        """The packets of each sweep (see the module docstring)."""
        cutter = SweepCutter(self.config.input.cut_azimuth_deg) if self._recut() else None
        group: list[RawPacket] = []
        for packet in self._packets():
            starts = cutter.starts_sweep(packet.data) if cutter is not None else packet.message_start
            if starts and group:
                yield group
                group = []
            group.append(packet)
        self._lost = sum(c.n_lost for c in self.counts)
        for note in (note for counts in self.counts for note in counts.notes if note not in self._notes):
            self._warn(note)
        if cutter is None and group:
            yield group
            group = []
        self._unfinished = len(group)

    def scans(self, start: int = 0, stop: int | None = None) -> Iterator[tuple[int, Scan]]:
        """``(index, scan)`` of sweeps ``start <= index < stop``; skipped sweeps are not decoded."""
        decoder = self.make_decoder()
        for index, packets in enumerate(self._sweeps()):
            if stop is not None and index >= stop:
                return
            if index < start:
                continue
            try:
                scan, stats, counts = decoder.decode(packets)
            except PacketError as err:
                raise PacketError(f"{self.label}: sweep {index} at {packets[0].host_ns} ns: {err}") from err
            self._stats = self._stats.add(stats, counts)
            yield index, scan

    def __iter__(self) -> Iterator[Scan]:
        for _index, scan in self.scans():
            yield scan


def is_packet_input(paths: Sequence[str | Path], topic: str | None) -> bool:
    """Whether ``paths`` are pcap files, or bags whose lidar topic is a VelodyneScan topic.

    A bag's lidar topic is ``topic`` when given; otherwise its only PointCloud2 topic, or, without
    one, its only VelodyneScan topic.
    """
    listed = [Path(p) for p in paths]
    if any(is_pcap(p) for p in listed):
        return True
    inputs: list[BagInput] = []
    try:
        for path in listed:
            if not path.exists():
                return False
            inputs.append(open_bag_input(path))
        topics = merge_topics(info for opened in inputs for info in opened.topics.values())
    except Exception:  # a bag that cannot be opened: ScanSource says why
        return False
    finally:
        for opened in inputs:
            opened.close()
    if topic:
        return topic in topics and topics[topic].msgtype == VELODYNE_SCAN_TYPE
    types = {t.msgtype for t in topics.values()}
    from lidar3d.io.pointcloud2 import POINTCLOUD2_TYPE

    return POINTCLOUD2_TYPE not in types and VELODYNE_SCAN_TYPE in types


def input_config(paths: str | Path | Sequence[str | Path], config: Any) -> Any:
    """The configuration a run over ``paths`` uses: ``config`` itself for PointCloud2 bags; for raw
    packets with the sensor model and rotation rate the packets show
    (:meth:`PacketSensor.pipeline_config`)."""
    listed = [paths] if isinstance(paths, (str, Path)) else list(paths)
    if not is_packet_input(listed, config.input.topic or None):
        return config
    with PacketScanSource(listed, config, quiet=True) as source:
        sensor = source.sensor
    if sensor.model.value != config.sensor.model:
        logger.info("%s: decoding as %s (%s)", source.label, sensor.model.value, sensor.detection.how)
    return sensor.pipeline_config(config)
