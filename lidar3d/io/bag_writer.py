"""Write scans to a ROS1 bag or a ROS2 bag folder (sqlite3 or mcap) as ``sensor_msgs/PointCloud2``.

Each scan becomes one message in the velodyne_pointcloud layout (:func:`lidar3d.io.pointcloud2.encode_scan`),
with the message (log) time equal to the header stamp. Scans are streamed: memory does not grow with
the number of scans. The bag is built under a temporary name in a hidden sibling folder and renamed
into place only once it is complete and closed, so an interrupted write never leaves a bag that
looks complete.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import tempfile
from collections.abc import Iterable
from enum import Enum
from pathlib import Path

from lidar3d.errors import OutputError
from lidar3d.io.pointcloud2 import POINTCLOUD2_TYPE, PointCloud2Parts, encode_scan, parts_to_message
from lidar3d.records import Scan

__all__ = ["BagStorage", "write_cloud_bag", "write_scan_bag"]

logger = logging.getLogger(__name__)


class BagStorage(str, Enum):
    """Bag formats :func:`write_scan_bag` can produce."""

    ROS1 = "ros1"
    ROS2_SQLITE3 = "ros2-sqlite3"
    ROS2_MCAP = "ros2-mcap"


def _storage(value: str | BagStorage) -> BagStorage:
    try:
        return BagStorage(value)
    except ValueError:
        known = ", ".join(s.value for s in BagStorage)
        raise OutputError(f"unknown bag storage {value!r}; choose one of: {known}") from None


def _write_ros1(path: Path, clouds: Iterable[PointCloud2Parts], topic: str) -> int:
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS1_NOETIC)
    count = 0
    with Writer(path) as writer:
        connection = writer.add_connection(topic, POINTCLOUD2_TYPE, typestore=typestore)
        for parts in clouds:
            message = parts_to_message(parts, typestore)
            writer.write(connection, parts.stamp_ns, typestore.serialize_ros1(message, POINTCLOUD2_TYPE))
            count += 1
    return count


def _write_ros2(path: Path, clouds: Iterable[PointCloud2Parts], topic: str, mcap: bool) -> int:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_HUMBLE)
    plugin = StoragePlugin.MCAP if mcap else StoragePlugin.SQLITE3
    count = 0
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        connection = writer.add_connection(topic, POINTCLOUD2_TYPE, typestore=typestore)
        for parts in clouds:
            message = parts_to_message(parts, typestore)
            writer.write(connection, parts.stamp_ns, typestore.serialize_cdr(message, POINTCLOUD2_TYPE))
            count += 1
    return count


def write_cloud_bag(
    path: str | Path,
    clouds: Iterable[PointCloud2Parts],
    *,
    topic: str = "/velodyne_points",
    storage: str | BagStorage = "ros1",
    overwrite: bool = False,
) -> int:
    """Write PointCloud2 ``clouds`` (any field layout) on ``topic``; returns the message count.

    The general form of :func:`write_scan_bag`, which it serves; the same arguments, atomicity
    and errors apply. Message (log) time = each cloud's header stamp.
    """
    kind = _storage(storage)
    path = Path(path)
    if path.exists() and not overwrite:
        raise OutputError(f"{path}: already exists (pass overwrite=True to replace it)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent))
    except OSError as err:
        raise OutputError(f"{path}: cannot create a temporary folder beside it: {err.strerror}") from err
    try:
        tmp = staging / path.name
        try:
            if kind is BagStorage.ROS1:
                count = _write_ros1(tmp, clouds, topic)
            else:
                count = _write_ros2(tmp, clouds, topic, mcap=kind is BagStorage.ROS2_MCAP)
        except OSError as err:
            raise OutputError(f"{path}: cannot write bag: {err}") from err
        if path.exists():
            os.replace(path, staging / (path.name + ".old"))
        os.replace(tmp, path)
    finally:
        with contextlib.suppress(OSError):
            shutil.rmtree(staging)
    logger.info("wrote %d clouds to %s (%s, topic %s)", count, path, kind.value, topic)
    return count


def write_scan_bag(
    path: str | Path,
    scans: Iterable[Scan],
    *,
    topic: str = "/velodyne_points",
    frame_id: str = "velodyne",
    storage: str | BagStorage = "ros1",
    overwrite: bool = False,
) -> int:
    """Write ``scans`` as PointCloud2 messages on ``topic``; returns the number of messages written.

    Args:
        path: a ``.bag`` file for ``storage="ros1"``; a bag folder for ``"ros2-sqlite3"`` and
            ``"ros2-mcap"`` (rosbags names the data file ``<folder name>.db3`` / ``.mcap``).
        scans: any iterable, consumed once, lazily.
        topic: the topic name.
        frame_id: the header frame of every cloud.
        storage: ``"ros1"``, ``"ros2-sqlite3"`` or ``"ros2-mcap"`` (or a :class:`BagStorage`).
        overwrite: replace an existing bag at ``path`` (only after the new one is complete).

    Raises:
        OutputError: unknown storage, ``path`` exists and ``overwrite`` is false, or the bag
            cannot be written.

    Example:
        >>> write_scan_bag("sim.bag", scans, storage="ros1")  # doctest: +SKIP
    """
    return write_cloud_bag(
        path,
        (encode_scan(scan, frame_id=frame_id) for scan in scans),
        topic=topic,
        storage=storage,
        overwrite=overwrite,
    )
