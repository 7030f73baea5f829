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
  lowest beam (judged once per stream, on its first non-empty sane cloud).
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
    DecodeStats,
    PointCloud2Parts,
    decode_parts,
    parts_from_message,
    ring_table_from_elevation,
)
from lidar3d.io.scan_sanity import SanityCounts, sanitize_scan
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
    """

    def __init__(self, sensor: SensorModel, min_range_m: float, *, label: str, topic: str) -> None:
        self.sensor = sensor
        self.min_range_m = float(min_range_m)
        self.label = label
        self.topic = topic
        self._ring_table: np.ndarray | None = None
        self._rings_judged = False

    def may_judge_rings(self, parts: PointCloud2Parts) -> bool:
        """Whether decoding ``parts`` may settle the ring numbering (not settled yet, and a ring field)."""
        return not self._rings_judged and any(f.name in RING_FIELD_NAMES for f in parts.fields)

    def decode(self, parts: PointCloud2Parts) -> tuple[Scan, DecodeStats, SanityCounts]:
        """The sane scan of the next cloud of the stream, what decoding dropped from it and what
        the sanity stage dropped.

        Raises:
            PointCloudError: the cloud cannot be decoded (see :func:`~lidar3d.io.pointcloud2.decode_parts`).
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
        return scan, stats, counts

    def _decode(self, parts: PointCloud2Parts) -> tuple[Scan, DecodeStats, SanityCounts]:
        decoded, stats = decode_parts(
            parts, sensor=self.sensor, min_range_m=self.min_range_m, ring_table=self._ring_table
        )
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
