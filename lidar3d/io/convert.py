"""Any input lidar3d reads -> a PointCloud2 bag in the velodyne_pointcloud layout: the twin of ``lidar3d convert``.

Raw packets (pcap files, VelodyneScan bags) are decoded as every command decodes them
(:func:`lidar3d.io.scan_source.open_scan_source`), so the clouds other tools get are the scans a
``lidar3d run`` sees: x, y, z, intensity float32, ``ring`` uint16 (0 = lowest beam), ``time``
float32 seconds from the header stamp, which is the sweep start (:mod:`lidar3d.io.bag_writer`).
PointCloud2 bags of other layouts are rewritten in that layout.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lidar3d.io.bag_writer import BagStorage, write_scan_bag
from lidar3d.records import Scan

__all__ = ["ConvertSummary", "convert_to_bag", "default_storage"]


@dataclass(frozen=True, slots=True)
class ConvertSummary:
    """What :func:`convert_to_bag` wrote: the bag, its storage and topic, scans and points."""

    path: str
    storage: str
    topic: str
    n_scans: int
    n_points: int


def default_storage(out: str | Path) -> BagStorage:
    """ROS1 for a ``.bag`` path, ROS2 mcap for ``.mcap``, else a ROS2 sqlite3 bag folder."""
    suffix = Path(out).suffix
    if suffix == ".bag":
        return BagStorage.ROS1
    return BagStorage.ROS2_MCAP if suffix == ".mcap" else BagStorage.ROS2_SQLITE3


def convert_to_bag(
    inputs: str | Path | Sequence[str | Path],
    out: str | Path,
    config: Any = None,
    *,
    storage: str | BagStorage | None = None,
    topic: str = "/velodyne_points",
    frame_id: str = "velodyne",
    overwrite: bool = False,
) -> ConvertSummary:
    """Decode ``inputs`` with ``config`` (defaults when None) and write every scan to the bag ``out``.

    Raises:
        PacketError, BagError, PointCloudError: the inputs cannot be read (as for ``lidar3d run``).
        OutputError: ``out`` exists and ``overwrite`` is false, or the bag cannot be written.
    """
    from lidar3d.config import Config
    from lidar3d.io.packet_source import input_config
    from lidar3d.io.scan_source import open_scan_source

    config = input_config(inputs, config or Config())
    kind = BagStorage(storage) if storage is not None else default_storage(out)
    totals = [0, 0]

    def counted(scans: Iterator[Scan]) -> Iterator[Scan]:
        for scan in scans:
            totals[0] += 1
            totals[1] += len(scan)
            yield scan

    with open_scan_source(inputs, config) as source:
        write_scan_bag(out, counted(iter(source)), topic=topic, frame_id=frame_id, storage=kind, overwrite=overwrite)
    return ConvertSummary(str(out), kind.value, topic, totals[0], totals[1])
