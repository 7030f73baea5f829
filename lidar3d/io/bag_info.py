"""What a bag holds: the library twin of ``lidar3d info``.

:func:`bag_info` opens one bag (a ROS1 file or a ROS2 folder), lists its topics, picks the lidar
topic as the scan source would, and inspects that topic: the point fields of its first cloud, the
sensor model guessed from the rings, and the first/last header stamps (read straight from the
serialised headers, so the pass over the topic costs little more than reading the file).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar3d.errors import PointCloudError
from lidar3d.io.bag_inputs import TopicInfo
from lidar3d.io.pointcloud2 import RING_FIELD_NAMES, PointField, PointFieldType
from lidar3d.io.scan_decoder import deserialize_cloud, header_stamp_ns
from lidar3d.io.scan_source import ScanSource
from lidar3d.sensors import VLP16, SensorModel, guess_sensor_model

__all__ = ["BagInfo", "bag_info", "format_bag_info"]


@dataclass(frozen=True, slots=True)
class BagInfo:
    """Summary of one bag.

    Attributes:
        path: the bag as given.
        format: ``ros1`` or ``ros2``.
        topics: every topic with its message type and count, sorted by name.
        start_ns, end_ns: log times of the first and last message of any topic.
        lidar_topic: the PointCloud2 topic a scan source reads.
        point_fields: the fields of its first cloud.
        point_step: bytes per point of the first cloud.
        n_points_first: points (height*width) in the first cloud.
        n_rings: distinct rings in the first cloud (None without a ring field).
        sensor_model: preset guessed from the rings (None when nothing fits).
        n_scans: messages on the lidar topic.
        first_stamp_ns, last_stamp_ns: smallest and largest header stamps on the lidar topic.
        notes: warnings about how the bag was read (truncation, missing metadata).
    """

    path: str
    format: str
    topics: tuple[TopicInfo, ...]
    start_ns: int
    end_ns: int
    lidar_topic: str
    point_fields: tuple[PointField, ...]
    point_step: int
    n_points_first: int
    n_rings: int | None
    sensor_model: str | None
    n_scans: int
    first_stamp_ns: int
    last_stamp_ns: int
    notes: tuple[str, ...]

    @property
    def duration_s(self) -> float:
        """Seconds from the first to the last message of any topic."""
        return (self.end_ns - self.start_ns) * 1e-9

    @property
    def n_messages(self) -> int:
        return sum(t.count for t in self.topics)


def _guess_from_rings(ring: np.ndarray, points: np.ndarray) -> tuple[int, str | None]:
    """Distinct rings, and the preset they fit (the lowest beam's elevation tells 32-beam models apart)."""
    values, inverse = np.unique(ring, return_inverse=True)
    elevation_deg = np.degrees(np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1])))
    lowest_deg = min(float(np.median(elevation_deg[inverse == i])) for i in range(values.size))
    model = guess_sensor_model(int(values.size), lowest_deg)
    return int(values.size), model.name if model else None


def bag_info(
    path: str | Path, *, topic: str | None = None, sensor: SensorModel = VLP16, min_range_m: float = 0.0
) -> BagInfo:
    """Summarise the bag at ``path`` (see :class:`BagInfo`).

    The first cloud is decoded as ``lidar3d run`` decodes it (:class:`~lidar3d.io.scan_decoder.ScanDecoder`
    with ``sensor`` and ``min_range_m``), so the rings counted are the rings a run assigns.

    Raises:
        BagError: missing path, not a bag, empty bag, no / several / unknown PointCloud2 topic.
        PointCloudError: the first cloud cannot be decoded.
    """
    with ScanSource(path, topic=topic, sensor=sensor, min_range_m=min_range_m) as source:
        first_parts = None
        first_stamp = last_stamp = None
        n_scans = 0
        for fmt, _log_ns, raw in source.raw_messages():
            stamp = header_stamp_ns(fmt, raw)
            if first_parts is None:
                first_parts = deserialize_cloud(fmt, raw, source.label)
            first_stamp = stamp if first_stamp is None else min(first_stamp, stamp)
            last_stamp = stamp if last_stamp is None else max(last_stamp, stamp)
            n_scans += 1
        assert first_parts is not None and first_stamp is not None and last_stamp is not None
        names = {f.name for f in first_parts.fields}
        n_rings = model = None
        try:
            scan, _stats, _counts = source.make_decoder().decode(first_parts)
        except PointCloudError as err:
            raise PointCloudError(f"{source.label}: first cloud on {source.topic}: {err}") from err
        if names & set(RING_FIELD_NAMES) and len(scan):
            n_rings, model = _guess_from_rings(scan.ring, scan.points)
        return BagInfo(
            path=str(path),
            format=source.format.value,
            topics=tuple(sorted(source.topics.values(), key=lambda t: t.name)),
            start_ns=int(source.start_ns or 0),
            end_ns=int(source.end_ns or 0),
            lidar_topic=source.topic,
            point_fields=first_parts.fields,
            point_step=first_parts.point_step,
            n_points_first=first_parts.height * first_parts.width,
            n_rings=n_rings,
            sensor_model=model,
            n_scans=n_scans,
            first_stamp_ns=first_stamp,
            last_stamp_ns=last_stamp,
            notes=tuple(source.notes),
        )


def _stamp(stamp_ns: int) -> str:
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return f"{sec}.{nanosec:09d}"


def _field_text(field: PointField) -> str:
    try:
        type_name = PointFieldType(field.datatype).name
    except ValueError:
        type_name = f"datatype {field.datatype}"
    count = f"[{field.count}]" if field.count != 1 else ""
    return f"{field.name}:{type_name}{count}@{field.offset}"


def format_bag_info(info: BagInfo) -> str:
    """Human-readable text of a :class:`BagInfo` (what ``lidar3d info`` prints)."""
    width = max(len(t.name) for t in info.topics)
    type_width = max(len(t.msgtype) for t in info.topics)
    lines = [
        f"bag:          {info.path} ({info.format})",
        f"duration:     {info.duration_s:.3f} s ({_stamp(info.start_ns)} .. {_stamp(info.end_ns)})",
        f"messages:     {info.n_messages}",
        "topics:",
        *(f"  {t.name:<{width}}  {t.msgtype:<{type_width}}  {t.count}" for t in info.topics),
        f"lidar topic:  {info.lidar_topic} ({info.n_scans} scans)",
        f"point fields: {' '.join(_field_text(f) for f in info.point_fields)} "
        f"(point_step {info.point_step}, {info.n_points_first} points in the first cloud)",
    ]
    if info.n_rings is None:
        lines.append("sensor model: unknown (no ring field)")
    else:
        lines.append(f"sensor model: {info.sensor_model or 'unknown'} ({info.n_rings} rings in the first cloud)")
    lines.append(f"first stamp:  {_stamp(info.first_stamp_ns)}")
    lines.append(f"last stamp:   {_stamp(info.last_stamp_ns)}")
    lines.extend(f"note:         {note}" for note in info.notes)
    return "\n".join(lines)
