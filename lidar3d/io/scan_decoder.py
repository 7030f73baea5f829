"""From a serialised lidar message to a :class:`~lidar3d.records.Scan`: the one decoding every command uses.

``lidar3d run``, ``features``, ``info`` and batch runs all read scans through :class:`ScanDecoder`
(directly, or by iterating a :class:`lidar3d.io.scan_source.ScanSource`), so a bag's points,
rings and per-point times come out the same whichever command reads it.

* :func:`deserialize_cloud`: ROS1 or CDR bytes -> :class:`~lidar3d.io.pointcloud2.PointCloud2Parts`,
  through ``rosbags`` typestores (ROS1 Noetic, ROS2 Humble; PointCloud2 is the same in every
  distribution).
* :class:`ScanDecoder`: parts -> :class:`~lidar3d.records.Scan` with
  :func:`lidar3d.io.pointcloud2.decode_parts`, then the sanity stage
  (:func:`lidar3d.io.scan_sanity.sanitize_scan`: non-finite points, absurd coordinates and outlier
  point times dropped and counted), renumbering a ring field that does not count up from the
  lowest beam (judged once per stream, on its first non-empty sane cloud). The time base is
  judged once too: point times of the first non-empty cloud that lie, for the most part, outside
  the sweep around its stamp are neither relative nor absolute, and stop the run with one line;
  times derived from the azimuth (no usable time field) are said once in the log.
* :func:`header_stamp_ns`: the header stamp of a serialised message, without deserialising it.
"""

from __future__ import annotations

import functools
import logging
import struct
from typing import Any

import numpy as np

from lidar3d.errors import PointCloudError
from lidar3d.io.bag_inputs import BagFormat
from lidar3d.io.pointcloud2 import (
    POINTCLOUD2_TYPE,
    RING_FIELD_NAMES,
    TIME_FIELD_NAMES,
    DecodeStats,
    PointCloud2Parts,
    TimeSource,
    decode_parts,
    parts_from_message,
    ring_table_from_elevation,
)
from lidar3d.io.scan_sanity import TIME_WINDOW_SWEEPS, SanityCounts, sanitize_scan
from lidar3d.records import Scan
from lidar3d.sensors import SensorModel

__all__ = ["ScanDecoder", "deserialize_cloud", "header_stamp_ns"]

logger = logging.getLogger(__name__)

_STAMP = struct.Struct("<iI")


@functools.cache
def _typestore(fmt: BagFormat) -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if fmt is BagFormat.ROS1 else Stores.ROS2_HUMBLE)


def header_stamp_ns(fmt: BagFormat, raw: bytes | memoryview) -> int:
    """The ``std_msgs/Header`` stamp at the start of a serialised message, without deserialising.

    ROS1: ``uint32 seq, uint32 sec, uint32 nsec``. CDR: a 4-byte encapsulation header, then
    ``int32 sec, uint32 nanosec``. Both put the stamp at bytes 4..12.
    """
    sec, nanosec = _STAMP.unpack_from(raw, 4)
    return sec * 1_000_000_000 + nanosec


def deserialize_cloud(fmt: BagFormat, raw: bytes | memoryview, label: str = "bag") -> PointCloud2Parts:
    """Deserialise one PointCloud2 (ROS1 or CDR bytes) into parts; the data buffer is not copied.

    Raises:
        PointCloudError: the bytes are not a PointCloud2 message (the message starts with ``label``).
    """
    store = _typestore(fmt)
    try:
        if fmt is BagFormat.ROS1:
            message = store.deserialize_ros1(raw, POINTCLOUD2_TYPE)
        else:
            message = store.deserialize_cdr(raw, POINTCLOUD2_TYPE)
    except Exception as err:  # rosbags raises assorted errors on malformed bytes
        raise PointCloudError(f"{label}: a {POINTCLOUD2_TYPE} message cannot be deserialised: {err}") from err
    return parts_from_message(message)


class ScanDecoder:
    """Decodes the clouds of one lidar topic, in stream order, into scans.

    The ring field of drivers other than ``velodyne_pointcloud`` may not count up from the lowest
    beam (Ouster counts from the top, some drivers use raw laser ids). The first non-empty cloud
    with a ring field decides, once for the stream, whether and how to renumber the rings by
    elevation (:func:`lidar3d.io.pointcloud2.ring_table_from_elevation`); every cloud after it is
    decoded with that renumbering. Use one decoder per pass over a stream.

    Args:
        sensor: elevation table and sweep period, for ring renumbering and for clouds without
            ring or time fields.
        min_range_m: points nearer than this are dropped (counted in the returned stats).
            The sensor's maximum range and sweep period set the sanity limits.
        label, topic: how the log line about renumbering names the input and topic.
        azimuth_stamp_at_end: clouds whose times come from the azimuth are stamped at the sweep end
            (see :func:`~lidar3d.io.pointcloud2.decode_parts`).
    """

    def __init__(
        self, sensor: SensorModel, min_range_m: float, *, label: str, topic: str, azimuth_stamp_at_end: bool = False
    ) -> None:
        self.sensor = sensor
        self.min_range_m = float(min_range_m)
        self.azimuth_stamp_at_end = azimuth_stamp_at_end
        self.label = label
        self.topic = topic
        self._ring_table: np.ndarray | None = None
        self._rings_judged = False
        self._times_judged = False
        self._azimuth_noted = False

    def may_judge_rings(self, parts: PointCloud2Parts) -> bool:
        """Whether decoding ``parts`` may settle the ring numbering (not settled yet, and a ring field)."""
        return not self._rings_judged and any(f.name in RING_FIELD_NAMES for f in parts.fields)

    def decode(self, parts: PointCloud2Parts) -> tuple[Scan, DecodeStats, SanityCounts]:
        """The sane scan of the next cloud of the stream, what decoding dropped from it and what
        the sanity stage dropped.

        Raises:
            PointCloudError: the cloud cannot be decoded (see :func:`~lidar3d.io.pointcloud2.decode_parts`),
                or it is the stream's first non-empty cloud and the median of its point times lies
                outside the sanity window around the stamp (a time base that is neither relative
                nor absolute).
        """
        scan, stats, counts = self._decode(parts)
        if len(scan) and self.may_judge_rings(parts):
            self._rings_judged = True
            self._ring_table = ring_table_from_elevation(scan.ring, scan.points, self.sensor)
            if self._ring_table is not None:
                logger.info(
                    "%s: the ring field of %s does not count up from the lowest beam; "
                    "renumbering it by elevation with the %s table",
                    self.label,
                    self.topic,
                    self.sensor.name,
                )
                scan, stats, counts = self._decode(parts)
        if stats.time_source.from_azimuth and not self._azimuth_noted:
            self._azimuth_noted = True
            note = _azimuth_note(parts, stats.time_source, self.azimuth_stamp_at_end)
            logger.info("%s: %s: %s", self.label, self.topic, note)
        return scan, stats, counts

    def _decode(self, parts: PointCloud2Parts) -> tuple[Scan, DecodeStats, SanityCounts]:
        decoded, stats = decode_parts(
            parts,
            sensor=self.sensor,
            min_range_m=self.min_range_m,
            ring_table=self._ring_table,
            azimuth_stamp_at_end=self.azimuth_stamp_at_end,
        )
        if not self._times_judged and len(decoded):
            self._times_judged = True
            self._judge_time_base(decoded, parts, stats.time_source)
        scan, counts = sanitize_scan(decoded, self.sensor)
        if counts.n_dropped:
            logger.debug(
                "%s: %s at stamp %d ns: dropped %d non-finite points, %d with absurd coordinates, "
                "%d with outlier times of %d",
                self.label,
                self.topic,
                parts.stamp_ns,
                counts.n_nonfinite,
                counts.n_absurd_coordinates,
                counts.n_outlier_times,
                stats.n_input,
            )
        return scan, stats, counts

    def _judge_time_base(self, decoded: Scan, parts: PointCloud2Parts, source: TimeSource) -> None:
        """Raise unless the median finite point time of ``decoded`` lies within the sanity window."""
        if source.from_azimuth:
            return
        times = decoded.time_offset_s[np.isfinite(decoded.time_offset_s)]
        window_s = TIME_WINDOW_SWEEPS * self.sensor.sweep_period_s
        if not times.size:
            return
        median_s = float(np.median(times))
        if abs(median_s) <= window_s:
            return
        field = next(f for f in parts.fields if f.name in TIME_FIELD_NAMES)
        base = "absolute (made relative to the stamp)" if source is TimeSource.ABSOLUTE else "relative to the stamp"
        raise PointCloudError(
            f"point times of field {field.name!r} read as {base} have a median of {median_s:.6g} s, outside the "
            f"sweep (within {window_s:g} s of the header stamp): neither relative to the stamp nor absolute "
            "times near it, so the sweep cannot be deskewed"
        )


def _azimuth_note(parts: PointCloud2Parts, source: TimeSource, stamp_at_end: bool) -> str:
    """The one log line about point times derived from the azimuth."""
    names = {f.name for f in parts.fields}
    field = next((f.name for f in parts.fields if f.name in TIME_FIELD_NAMES), "")
    why = {
        TimeSource.NO_FIELD: "no per-point time field",
        TimeSource.NO_SPREAD: f"time field {field!r} holds the same value for every point (no times)",
        TimeSource.COARSE_ABSOLUTE: f"time field {field!r} holds absolute times too coarse to time a sweep",
    }[source]
    rings = "" if names & set(RING_FIELD_NAMES) else "; no ring field either: rings from the elevation table"
    stamp = "end (input.azimuth_stamp = sweep_end)" if stamp_at_end else "start (input.azimuth_stamp)"
    return (
        f"{why}; point times derived from the azimuth (clockwise from the first point over one rotation "
        f"period), taking the header stamp as the sweep {stamp}{rings}; counted in input_stats"
    )
