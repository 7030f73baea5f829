"""Real recorded data from ../shared/data/real (see its SOURCES.md).

The nebula ROS2 sqlite3 bags hold raw ``velodyne_msgs/VelodyneScan`` packets, not PointCloud2: the
PointCloud2 :class:`ScanSource` reads their storage and refuses them with the topics they have
(``open_scan_source`` hands them to the packet source: tests/test_io_packets_real.py). The
nebula PCDs beside them are that driver's decoded clouds (binary PCD, nebula's ``PointXYZIRCAEDT``
fields); packed into PointCloud2 in nebula's own layout they are a real-driver field variant
(``channel`` uint16 ring, ``time_stamp`` uint32 ns, uint8 intensity) with real VLP-16 and VLP-32C
beam geometry, which checks the ring-from-elevation tables against a physical sensor.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from lidar3d.errors import BagError
from lidar3d.io.bag_writer import write_cloud_bag
from lidar3d.io.pcd import read_pcd
from lidar3d.io.pointcloud2 import PointCloud2Parts, PointField, PointFieldType, decode_parts
from lidar3d.io.scan_source import ScanSource
from lidar3d.sensors import VLP16, VLP32C, guess_sensor_model

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real"
NEBULA = REAL / "nebula"
pytestmark = pytest.mark.skipif(
    not NEBULA.is_dir(), reason=f"real data folder {NEBULA} is absent (CI places shared/ beside the clone)"
)

VLP16_BAG = NEBULA / "vlp16" / "1673400471837873222"
VLP16_PCD = NEBULA / "vlp16" / "1673400472138016708.pcd"
VLP32_BAG = NEBULA / "vlp32" / "1713492677464078412"
VLP32_PCD = NEBULA / "vlp32" / "1713492677464078412.pcd"

# nebula_common PointXYZIRCAEDT, as the driver publishes it
NEBULA_LAYOUT = [
    ("x", 0, "f4"),
    ("y", 4, "f4"),
    ("z", 8, "f4"),
    ("intensity", 12, "u1"),
    ("return_type", 13, "u1"),
    ("channel", 14, "u2"),
    ("azimuth", 16, "f4"),
    ("elevation", 20, "f4"),
    ("distance", 24, "f4"),
    ("time_stamp", 28, "u4"),
]
CODES = {
    "u1": PointFieldType.UINT8,
    "u2": PointFieldType.UINT16,
    "u4": PointFieldType.UINT32,
    "f4": PointFieldType.FLOAT32,
}


def nebula_parts(pcd: Path, stamp_ns: int, layout=NEBULA_LAYOUT) -> tuple[PointCloud2Parts, np.ndarray, dict]:
    points, fields = read_pcd(pcd)
    dtype = np.dtype(
        {
            "names": [n for n, _o, _c in layout],
            "formats": ["<" + c for _n, _o, c in layout],
            "offsets": [o for _n, o, _c in layout],
            "itemsize": 32,
        }
    )
    records = np.zeros(points.shape[0], dtype)
    for axis, name in enumerate("xyz"):
        records[name] = points[:, axis]
    for name, _o, _c in layout[3:]:
        records[name] = fields[name]
    parts = PointCloud2Parts(
        stamp_ns=stamp_ns,
        frame_id="velodyne_top",
        height=1,
        width=points.shape[0],
        fields=tuple(PointField(n, o, CODES[c]) for n, o, c in layout),
        is_bigendian=False,
        point_step=32,
        row_step=32 * points.shape[0],
        data=records.view(np.uint8).reshape(-1),
        is_dense=True,
    )
    return parts, points, fields


@pytest.mark.parametrize(
    ("bag", "listing"),
    [
        (VLP16_BAG, "/velodyne_packets (velodyne_msgs/msg/VelodyneScan, 4)"),
        (VLP32_BAG, "/sensing/lidar/front/velodyne_packets (velodyne_msgs/msg/VelodyneScan, 5)"),
    ],
)
def test_real_packet_bags_are_read_and_refused_with_their_topics(bag, listing):
    with pytest.raises(
        BagError, match=rf"{bag.name}: no sensor_msgs/msg/PointCloud2 topic; topics: {re.escape(listing)}$"
    ):
        ScanSource(bag).open()


def test_real_bag_without_metadata_is_read_from_its_db3(tmp_path):
    copy = tmp_path / "rec"
    copy.mkdir()
    for db3 in VLP16_BAG.glob("*.db3"):
        shutil.copy(db3, copy / db3.name)
    with pytest.raises(
        BagError,
        match=r"no sensor_msgs/msg/PointCloud2 topic; topics: /velodyne_packets \(velodyne_msgs/msg/VelodyneScan, 4\)",
    ):
        ScanSource(copy).open()


def test_real_db3_truncated_keeps_what_precedes_the_damage(tmp_path):
    copy = tmp_path / "rec"
    shutil.copytree(VLP16_BAG, copy)
    db3 = next(copy.glob("*.db3"))
    data = db3.read_bytes()
    db3.write_bytes(data[: int(len(data) * 0.6)])
    with pytest.raises(BagError, match=r"topics: /velodyne_packets \(velodyne_msgs/msg/VelodyneScan, [0-3]\)"):
        ScanSource(copy).open()


@pytest.mark.parametrize("storage", ["ros1", "ros2-sqlite3"])
def test_nebula_vlp16_cloud_round_trips_in_nebula_layout(tmp_path, storage):
    stamp_ns = 1673400472138016708
    parts, points, fields = nebula_parts(VLP16_PCD, stamp_ns)
    path = tmp_path / ("n.bag" if storage == "ros1" else "n")
    write_cloud_bag(path, [parts], topic="/sensing/lidar/top/pointcloud_raw_ex", storage=storage)
    with ScanSource(path) as source:
        (scan,) = list(source)
    assert scan.stamp_ns == stamp_ns and len(scan) == 14831
    np.testing.assert_array_equal(scan.points, points.astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(scan.intensity, fields["intensity"].astype(np.float32))
    np.testing.assert_array_equal(scan.ring, fields["channel"])  # nebula numbers channels by elevation
    np.testing.assert_array_equal(scan.time_offset_s, fields["time_stamp"].astype(np.float64) * 1e-9)


def test_vlp16_ring_from_elevation_matches_the_real_channels():
    layout = [f for f in NEBULA_LAYOUT if f[0] != "channel"]
    parts, _points, fields = nebula_parts(VLP16_PCD, 0, layout)
    scan, stats = decode_parts(parts, sensor=VLP16)
    assert stats.n_kept == 14831
    np.testing.assert_array_equal(scan.ring, fields["channel"])
    assert guess_sensor_model(len(np.unique(scan.ring))) is None  # 15 of 16 beams hit something
    assert set(np.unique(scan.ring)) == set(range(1, 16))


def test_min_range_drops_the_real_near_points():
    parts, points, _fields = nebula_parts(VLP16_PCD, 0)
    scan, stats = decode_parts(parts, min_range_m=1.0)
    near = int(np.count_nonzero(np.linalg.norm(points.astype(np.float32).astype(np.float64), axis=1) < 1.0))
    assert near > 0 and stats.n_below_min_range == near and len(scan) == 14831 - near


def test_vlp32c_elevation_table_fits_the_real_sensor():
    points, extra = read_pcd(VLP32_PCD)
    assert points.shape == (26216, 3) and extra == {}
    layout = [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4")]
    parts, _points, _fields = nebula_parts(VLP32_PCD, 0, layout)
    scan, _stats = decode_parts(parts, sensor=VLP32C)
    elevation_deg = np.degrees(np.arctan2(scan.points[:, 2], np.hypot(scan.points[:, 0], scan.points[:, 1])))
    residual = elevation_deg - np.asarray(VLP32C.elevation_deg)[scan.ring]
    # nebula corrects the beams' vertical offsets; every point lies within 0.1 deg of its beam
    assert np.abs(residual).max() < 0.1
    assert len(np.unique(scan.ring)) == 32
    assert guess_sensor_model(32, float(np.median(elevation_deg[scan.ring == 0]))) is VLP32C
