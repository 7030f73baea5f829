"""What every scan source shares: the read totals, how inputs are named, the choice of the lidar topic.

:class:`ReadStats` counts what reading kept and dropped (both :class:`lidar3d.io.scan_source.ScanSource`
and :class:`lidar3d.io.packet_source.PacketScanSource` report one); :func:`bag_label` names the inputs
in error messages; :func:`choose_lidar_topic` picks the PointCloud2 (or VelodyneScan) topic of a bag.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from lidar3d.errors import BagError
from lidar3d.io.bag_inputs import TopicInfo
from lidar3d.io.packet_inputs import VELODYNE_SCAN_TYPE
from lidar3d.io.pointcloud2 import POINTCLOUD2_TYPE, DecodeStats
from lidar3d.io.scan_sanity import SanityCounts

__all__ = ["ReadStats", "bag_label", "choose_lidar_topic"]


@dataclass(frozen=True, slots=True)
class ReadStats:
    """Totals over the scans read so far (counts of scans, points and messages).

    ``n_points_kept`` entered the front end; the drops are by decoding (``n_below_min_range``) and
    by the sanity stage (``n_nonfinite``, ``n_absurd_coordinates``, ``n_outlier_times``: see
    :mod:`lidar3d.io.scan_sanity`). ``n_scans_times_from_azimuth`` scans had no usable time field
    (:class:`~lidar3d.io.pointcloud2.TimeSource`): their point times were derived from the azimuth.
    """

    n_scans: int = 0
    n_points_in: int = 0
    n_points_kept: int = 0
    n_nonfinite: int = 0
    n_below_min_range: int = 0
    n_absurd_coordinates: int = 0
    n_outlier_times: int = 0
    n_lost_messages: int = 0
    n_scans_times_from_azimuth: int = 0

    def add(self, stats: DecodeStats, counts: SanityCounts) -> ReadStats:
        return ReadStats(
            n_scans=self.n_scans + 1,
            n_points_in=self.n_points_in + stats.n_input,
            n_points_kept=self.n_points_kept + stats.n_kept - counts.n_dropped,
            n_nonfinite=self.n_nonfinite + counts.n_nonfinite,
            n_below_min_range=self.n_below_min_range + stats.n_below_min_range,
            n_absurd_coordinates=self.n_absurd_coordinates + counts.n_absurd_coordinates,
            n_outlier_times=self.n_outlier_times + counts.n_outlier_times,
            n_lost_messages=self.n_lost_messages,
            n_scans_times_from_azimuth=self.n_scans_times_from_azimuth + stats.time_source.from_azimuth,
        )


def bag_label(paths: Sequence[Path]) -> str:
    """How error messages name the input: the path, or the first paths and a count."""
    if len(paths) == 1:
        return str(paths[0])
    shown = ", ".join(str(p) for p in paths[:3])
    return shown + (f" (+{len(paths) - 3} more)" if len(paths) > 3 else "")


def _describe_topics(topics: dict[str, TopicInfo]) -> str:
    return ", ".join(f"{t.name} ({t.msgtype}, {t.count})" for t in sorted(topics.values(), key=lambda t: t.name))


def choose_lidar_topic(topics: dict[str, TopicInfo], topic: str | None, label: str, *, packets: bool = False) -> str:
    """The lidar topic to read: ``topic`` if given (checked), else the only PointCloud2 topic (with
    ``packets``: the only ``velodyne_msgs/msg/VelodyneScan`` topic).

    Raises:
        BagError: the bag is empty, has no such topic, several and no choice, or the chosen topic
            does not exist or is not of that type.
    """
    msgtype, kind = (VELODYNE_SCAN_TYPE, "VelodyneScan") if packets else (POINTCLOUD2_TYPE, "PointCloud2")
    if not topics or sum(t.count for t in topics.values()) == 0:
        raise BagError(f"{label}: bag is empty (no messages)")
    clouds = sorted(name for name, t in topics.items() if t.msgtype == msgtype)
    if topic:
        if topic not in topics:
            candidates = ", ".join(clouds) if clouds else "none; topics: " + _describe_topics(topics)
            raise BagError(f"{label}: topic {topic!r} not found; {kind} topics: {candidates}")
        if topics[topic].msgtype != msgtype:
            raise BagError(f"{label}: topic {topic!r} has type {topics[topic].msgtype}, not {msgtype}")
        return topic
    if not clouds:
        raise BagError(f"{label}: no {msgtype} topic; topics: {_describe_topics(topics)}")
    if len(clouds) > 1:
        raise BagError(f"{label}: several {kind} topics ({', '.join(clouds)}); choose one with --topic")
    return clouds[0]
