"""Scans of one lidar topic from one or more bags: a lazy, time-ordered, context-manager scan source.

:class:`ScanSource` opens each input (:mod:`lidar3d.io.bag_inputs`: ROS1 ``.bag`` files, ROS2
bag folders or storage files, truncated ones included), chooses the lidar topic
(:func:`choose_lidar_topic`), merges the inputs by log time into one stream (several files given
together, e.g. ``rosbag record --split``, read as one recording) and decodes each message with a
:class:`~lidar3d.io.scan_decoder.ScanDecoder`. Only one message is held at a time, so memory does
not grow with the bag's length. :func:`open_scan_source` configures one from a
:class:`lidar3d.config.Config`.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from lidar3d.errors import BagError, PointCloudError
from lidar3d.io.bag_inputs import (
    BagFormat,
    BagInput,
    TopicInfo,
    log_time_span,
    merge_topics,
    merged_messages,
    open_bag_input,
)
from lidar3d.io.pointcloud2 import PointCloud2Parts
from lidar3d.io.scan_decoder import ScanDecoder, deserialize_cloud
from lidar3d.io.scan_reading import ReadStats, bag_label, choose_lidar_topic
from lidar3d.records import Scan
from lidar3d.sensors import VLP16, SensorModel

if TYPE_CHECKING:
    from lidar3d.io.packet_source import PacketScanSource

__all__ = ["ScanSource", "open_scan_source"]

logger = logging.getLogger(__name__)


class ScanSource:
    """Scans of one lidar topic from one or more bags, lazily and in log-time order.

    Use as a context manager::

        with ScanSource(["run_0.bag", "run_1.bag"]) as source:
            print(source.topic, len(source))
            for scan in source:
                ...
        print(source.stats)

    Args:
        paths: a bag path or several (ROS1 split files, or ROS2 folders); read as one stream.
        topic: the PointCloud2 topic; None or "" picks the only one.
        sensor: for ring renumbering and clouds without ring or time fields (see :class:`ScanDecoder`).
        min_range_m: points nearer than this are dropped (counted in :attr:`stats`, as are the points
            the sanity stage drops: :mod:`lidar3d.io.scan_sanity`).
        azimuth_stamp_at_end: clouds whose point times come from the azimuth are stamped at the
            sweep end (``input.azimuth_stamp = "sweep_end"``), see :class:`ScanDecoder`.

    Raises (from ``open``/``__enter__``):
        BagError: missing path, not a bag, empty bag, no/ambiguous/unknown lidar topic.
    Iterating raises:
        PointCloudError: a cloud that cannot be decoded (the message names the bag, topic, message index
            and stamp).
    """

    def __init__(
        self,
        paths: str | Path | Sequence[str | Path],
        *,
        topic: str | None = None,
        sensor: SensorModel = VLP16,
        min_range_m: float = 0.0,
        azimuth_stamp_at_end: bool = False,
    ) -> None:
        if isinstance(paths, (str, Path)):
            paths = [paths]
        self.paths: tuple[Path, ...] = tuple(Path(p) for p in paths)
        if not self.paths:
            raise BagError("no bag given")
        self.label = bag_label(list(self.paths))
        self._requested_topic = topic or None
        self.sensor = sensor
        self.min_range_m = float(min_range_m)
        self.azimuth_stamp_at_end = azimuth_stamp_at_end
        self._inputs: list[BagInput] = []
        self._topic: str | None = None
        self._topics: dict[str, TopicInfo] = {}
        self._format = BagFormat.ROS1
        self._start_ns: int | None = None
        self._end_ns: int | None = None
        self._notes: list[str] = []
        self._stats = ReadStats()

    # -- lifecycle -----------------------------------------------------------------------------
    def open(self) -> ScanSource:
        """Open every input and choose the lidar topic. Idempotent while open."""
        if self._inputs:
            return self
        try:
            for path in self.paths:
                self._inputs.append(open_bag_input(path))
            topics = merge_topics(info for opened in self._inputs for info in opened.topics.values())
            if sum(t.count for t in topics.values()) == 0:
                damaged = [i for i in self._inputs if i.note]
                if damaged:
                    raise BagError(f"{damaged[0].path}: no complete message: {damaged[0].note}")
            self._topic = choose_lidar_topic(topics, self._requested_topic, self.label)
        except BaseException:
            self.close()
            raise
        self._topics = topics
        self._format = self._inputs[0].fmt
        self._start_ns, self._end_ns = log_time_span(self._inputs)
        self._notes = [f"{i.path}: {i.note}" for i in self._inputs if i.note]
        for note in self._notes:
            logger.warning("%s", note)
        return self

    def close(self) -> None:
        """Close every input; logs a summary of what was dropped. What was learnt stays readable."""
        self._stats = self.stats
        inputs, self._inputs = self._inputs, []
        for opened in inputs:
            opened.close()
        if self._stats.n_scans:
            _log_read_totals(self._stats, self.label, self.min_range_m)

    def __enter__(self) -> ScanSource:
        return self.open()

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- what is in the input (available once opened, also after closing) --------------------
    def _require_opened(self, *, still_open: bool = False) -> None:
        """Raise unless opened once (and, with ``still_open``, not closed since)."""
        if self._topic is None or (still_open and not self._inputs):
            raise BagError(f"{self.label}: scan source is not open (use it in a with-block)")

    @property
    def topics(self) -> dict[str, TopicInfo]:
        """All topics over all inputs (counts summed)."""
        self._require_opened()
        return dict(self._topics)

    @property
    def topic(self) -> str:
        """The lidar topic being read."""
        self._require_opened()
        assert self._topic is not None
        return self._topic

    @property
    def format(self) -> BagFormat:
        """Container format of the (first) input."""
        self._require_opened()
        return self._format

    @property
    def start_ns(self) -> int | None:
        """Log time of the earliest message of any topic (None for an empty input)."""
        self._require_opened()
        return self._start_ns

    @property
    def end_ns(self) -> int | None:
        """Log time of the latest message of any topic."""
        self._require_opened()
        return self._end_ns

    @property
    def notes(self) -> list[str]:
        """Warnings about how inputs were read (truncated bags, missing metadata)."""
        return list(self._notes)

    @property
    def stats(self) -> ReadStats:
        """Totals so far: scans, points kept and dropped, messages lost to truncation."""
        lost = sum(i.n_lost for i in self._inputs)
        return dataclasses.replace(self._stats, n_lost_messages=max(lost, self._stats.n_lost_messages))

    def __len__(self) -> int:
        """Number of messages on the lidar topic (as the bag's index or metadata says)."""
        return self.topics[self.topic].count

    # -- reading -------------------------------------------------------------------------------
    def raw_messages(self) -> Iterator[tuple[BagFormat, int, bytes]]:
        """``(format, log time ns, serialised message)`` of the lidar topic, merged by log time."""
        self._require_opened(still_open=True)
        for log_ns, (fmt, raw) in merged_messages(self._inputs, self.topic):
            yield fmt, log_ns, raw

    def clouds(self) -> Iterator[PointCloud2Parts]:
        """The lidar topic's messages as :class:`PointCloud2Parts` (no decoding)."""
        for fmt, _log_ns, raw in self.raw_messages():
            yield deserialize_cloud(fmt, raw, self.label)

    def make_decoder(self) -> ScanDecoder:
        """A fresh :class:`ScanDecoder` for this source's topic, as iterating the source uses."""
        return ScanDecoder(
            self.sensor,
            self.min_range_m,
            label=self.label,
            topic=self.topic,
            azimuth_stamp_at_end=self.azimuth_stamp_at_end,
        )

    def scans(self, start: int = 0, stop: int | None = None) -> Iterator[tuple[int, Scan]]:
        """``(index, scan)`` of the lidar topic's messages ``start <= index < stop`` (None: to the end).

        Every scan is decoded as a full pass decodes it: messages before ``start`` are decoded
        only while they may settle the ring numbering, and are not counted in :attr:`stats`.
        """
        decoder = self.make_decoder()
        for index, parts in enumerate(self.clouds()):
            if stop is not None and index >= stop:
                return
            if index < start and not decoder.may_judge_rings(parts):
                continue
            try:
                scan, stats, counts = decoder.decode(parts)
            except PointCloudError as err:
                raise PointCloudError(
                    f"{self.label}: {self.topic} message {index} at stamp {parts.stamp_ns} ns: {err}"
                ) from err
            if index >= start:
                self._stats = self._stats.add(stats, counts)
                yield index, scan

    def __iter__(self) -> Iterator[Scan]:
        """Every scan of the lidar topic in log-time order (see :meth:`scans`)."""
        for _index, scan in self.scans():
            yield scan


def _log_read_totals(stats: ReadStats, label: str, min_range_m: float) -> None:
    """The info line about what reading ``label`` kept and dropped."""
    logger.info(
        "read %d scans from %s: %d points kept; dropped %d nearer than %.2f m, %d non-finite, "
        "%d with absurd coordinates, %d with outlier times; %d scans timed from the azimuth",
        stats.n_scans,
        label,
        stats.n_points_kept,
        stats.n_below_min_range,
        min_range_m,
        stats.n_nonfinite,
        stats.n_absurd_coordinates,
        stats.n_outlier_times,
        stats.n_scans_times_from_azimuth,
    )


def open_scan_source(paths: str | Path | Sequence[str | Path], config: Any = None) -> ScanSource | PacketScanSource:
    """The scan source of ``paths`` configured from a :class:`lidar3d.config.Config` (defaults when None).

    Raw packets (pcap files, a bag whose lidar topic is a VelodyneScan topic:
    :func:`lidar3d.io.packet_source.is_packet_input`) give a
    :class:`~lidar3d.io.packet_source.PacketScanSource`; PointCloud2 bags a :class:`ScanSource` with
    ``config.input.topic``, ``config.input.azimuth_stamp``, ``config.sensor.resolved_model`` and
    ``config.sensor.min_range_m``. Not yet opened: use it in a ``with`` block.
    """
    from lidar3d.io.packet_source import PacketScanSource, is_packet_input

    if config is None:
        from lidar3d.config import Config

        config = Config()
    listed = [paths] if isinstance(paths, (str, Path)) else list(paths)
    if is_packet_input(listed, config.input.topic or None):
        return PacketScanSource(listed, config)
    return ScanSource(
        paths,
        topic=config.input.topic or None,
        sensor=config.sensor.resolved_model,
        min_range_m=config.sensor.min_range_m,
        azimuth_stamp_at_end=config.input.azimuth_stamp == "sweep_end",
    )
