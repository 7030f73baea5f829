"""Bags written with rosbags' writers into tmp_path and read back: ROS1, ROS2 sqlite3 and mcap."""

from __future__ import annotations

import logging
import struct
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore
from test_io_pointcloud2 import HESAI, OUSTER, STAMP_NS, assert_scan_equal, build_parts, vlp_scan

from lidar3d.errors import BagError, OutputError, PointCloudError
from lidar3d.io.bag_writer import write_cloud_bag, write_scan_bag
from lidar3d.io.pointcloud2 import VELODYNE_FIELDS, encode_scan
from lidar3d.io.scan_source import ScanSource, open_scan_source

STORAGES = ["ros1", "ros2-sqlite3", "ros2-mcap"]
PERIOD_NS = 100_000_000


def bag_path(tmp_path: Path, storage: str, name: str = "scans") -> Path:
    return tmp_path / (f"{name}.bag" if storage == "ros1" else f"{name}_{storage}")


def make_scans(n: int, n_columns: int = 45, first: int = 0) -> list:
    return [
        vlp_scan(n_columns=n_columns, stamp_ns=STAMP_NS + (first + i) * PERIOD_NS, seed=first + i) for i in range(n)
    ]


def read_all(path, **kwargs) -> tuple[list, ScanSource]:
    with ScanSource(path, **kwargs) as source:
        return list(source), source


@pytest.mark.parametrize("storage", STORAGES)
def test_write_scan_bag_round_trip(tmp_path, storage):
    scans = make_scans(4)
    path = bag_path(tmp_path, storage)
    assert write_scan_bag(path, iter(scans), storage=storage, frame_id="velodyne") == 4
    decoded, source = read_all(path)
    assert source.topic == "/velodyne_points" and len(source) == 4
    assert len(decoded) == 4
    for got, want in zip(decoded, scans):
        assert_scan_equal(got, want)
    assert source.start_ns == scans[0].stamp_ns and source.end_ns == scans[-1].stamp_ns
    assert source.stats.n_scans == 4 and source.stats.n_points_kept == sum(len(s) for s in scans)
    # nothing but the bag is left beside it
    assert [p.name for p in tmp_path.iterdir()] == [path.name]


@pytest.mark.parametrize("storage", STORAGES)
def test_message_time_is_header_stamp_and_frame_id(tmp_path, storage):
    from rosbags.highlevel import AnyReader

    scans = make_scans(3)
    path = bag_path(tmp_path, storage)
    write_scan_bag(path, scans, storage=storage, frame_id="lidar_top", topic="/points")
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        rows = [(t, reader.deserialize(raw, c.msgtype)) for c, t, raw in reader.messages()]
    assert [t for t, _ in rows] == [s.stamp_ns for s in scans]
    for _t, msg in rows:
        assert msg.header.frame_id == "lidar_top"
        assert (msg.point_step, msg.height, msg.is_dense) == (32, 1, True)
        assert [(f.name, f.offset, f.datatype) for f in msg.fields] == [
            (f.name, f.offset, f.datatype) for f in VELODYNE_FIELDS
        ]


VARIANTS = {
    "velodyne": lambda scan: encode_scan(scan),
    "ouster_t_ns": lambda scan: build_parts(
        scan,
        OUSTER,
        48,
        values={"t": np.round(scan.time_offset_s * 1e9).astype(np.uint32), "reflectivity": 1, "ambient": 2, "range": 3},
    ),
    "timestamp_abs_s": lambda scan: build_parts(
        scan, HESAI, 32, values={"timestamp": scan.stamp_ns * 1e-9 + scan.time_offset_s}
    ),
    "no_ring": lambda scan: build_parts(
        scan, [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 12, "f4"), ("time", 16, "f4")], 20
    ),
    "no_time": lambda scan: build_parts(
        scan, [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 16, "f4"), ("ring", 20, "u2")], 24
    ),
    "big_endian_organised": lambda scan: build_parts(
        scan,
        [(f.name, f.offset, {7: "f4", 4: "u2"}[f.datatype]) for f in VELODYNE_FIELDS],
        32,
        bigendian=True,
        height=16,
        row_pad=4,
    ),
}
TIME_TOLERANCE = {
    "velodyne": 0.0,
    "ouster_t_ns": 1e-9,
    "timestamp_abs_s": 1e-6,
    "no_ring": 0.0,
    "no_time": 1e-6,
    "big_endian_organised": 0.0,
}


@pytest.mark.parametrize("variant", sorted(VARIANTS))
@pytest.mark.parametrize("storage", STORAGES)
def test_field_variants_read_back_exactly(tmp_path, storage, variant):
    scans = make_scans(3)
    path = bag_path(tmp_path, storage)
    write_cloud_bag(path, (VARIANTS[variant](s) for s in scans), storage=storage)
    decoded, _ = read_all(path)
    assert len(decoded) == 3
    for got, want in zip(decoded, scans):
        assert_scan_equal(got, want, time_atol=TIME_TOLERANCE[variant])


def test_split_ros1_bags_read_as_one_time_ordered_stream(tmp_path):
    scans = make_scans(9)
    parts = [tmp_path / f"run_{i}.bag" for i in range(3)]
    for i, path in enumerate(parts):
        write_scan_bag(path, scans[3 * i : 3 * i + 3])
    decoded, source = read_all(list(reversed(parts)))
    assert [s.stamp_ns for s in decoded] == [s.stamp_ns for s in scans]
    assert len(source) == 9
    for got, want in zip(decoded, scans):
        assert_scan_equal(got, want)


def test_ros1_and_ros2_inputs_merge_each_deserialised_in_its_own_format(tmp_path):
    scans = make_scans(6)
    ros1, ros2 = tmp_path / "a.bag", tmp_path / "b_mcap"
    write_scan_bag(ros1, scans[0::2])
    write_scan_bag(ros2, scans[1::2], storage="ros2-mcap")
    decoded, source = read_all([ros1, ros2])
    assert source.format.value == "ros1" and len(source) == 6
    for got, want in zip(decoded, scans, strict=True):
        assert_scan_equal(got, want)


def test_open_scan_source_uses_config_topic_and_min_range(tmp_path):
    from lidar3d.config import Config, InputConfig, SensorConfig

    scan = make_scans(1)[0]
    points = scan.points.copy()
    points[0] = [0.5, 0.0, 0.0]
    write_scan_bag(
        tmp_path / "a.bag",
        [type(scan)(scan.stamp_ns, points, scan.intensity, scan.ring, scan.time_offset_s)],
        topic="/lidar",
    )
    config = Config(sensor=SensorConfig(min_range_m=1.0), input=InputConfig(topic="/lidar"))
    with open_scan_source(tmp_path / "a.bag", config) as source:
        (decoded,) = list(source)
        assert source.topic == "/lidar"
        assert source.stats.n_below_min_range == 1 and len(decoded) == len(scan) - 1


def test_scan_source_must_be_opened(tmp_path):
    write_scan_bag(tmp_path / "a.bag", make_scans(1))
    with pytest.raises(BagError, match="scan source is not open"):
        list(ScanSource(tmp_path / "a.bag"))


# ---------------------------------------------------------------------------------------------
# The writer's atomicity


def test_writer_refuses_existing_path_unless_overwrite(tmp_path):
    path = tmp_path / "a.bag"
    write_scan_bag(path, make_scans(1))
    with pytest.raises(OutputError, match=r"a\.bag: already exists"):
        write_scan_bag(path, make_scans(2))
    write_scan_bag(path, make_scans(2), overwrite=True)
    assert len(read_all(path)[0]) == 2


@pytest.mark.parametrize("storage", STORAGES)
def test_interrupted_write_leaves_nothing(tmp_path, storage):
    def scans_then_crash():
        yield from make_scans(2)
        raise KeyboardInterrupt

    path = bag_path(tmp_path, storage)
    with pytest.raises(KeyboardInterrupt):
        write_scan_bag(path, scans_then_crash(), storage=storage)
    assert list(tmp_path.iterdir()) == []


def test_unknown_storage(tmp_path):
    with pytest.raises(OutputError, match="unknown bag storage 'ros3'; choose one of: ros1, ros2-sqlite3, ros2-mcap"):
        write_scan_bag(tmp_path / "a.bag", [], storage="ros3")


# ---------------------------------------------------------------------------------------------
# Truncated and unindexed bags


def _ros1_message_positions(path: Path) -> list[int]:
    """Absolute file offsets of each message record, from the bag's own index."""
    from rosbags.rosbag1 import Reader

    with Reader(path) as reader:
        entries = sorted(e for entries in reader.indexes.values() for e in entries)
        return [reader.chunks[e.chunk_pos].datapos + e.offset for e in entries]


def test_ros1_cut_short_reads_every_complete_message(tmp_path):
    scans = make_scans(30)
    full = tmp_path / "full.bag"
    write_scan_bag(full, scans)
    positions = _ros1_message_positions(full)
    cut = tmp_path / "cut.bag"
    cut.write_bytes(full.read_bytes()[: positions[25] + 40])  # inside message 25's record
    decoded, source = read_all(cut)
    assert len(decoded) == 25
    for got, want in zip(decoded, scans):
        assert_scan_equal(got, want)
    assert source.stats.n_lost_messages == 1
    assert source.notes == [
        f"{cut}: bag is truncated (index unreadable: the file is cut short): read 25 complete message(s) "
        "in file order; 1 incomplete message(s) at the end lost"
    ]


def _drop_index(path: Path) -> None:
    """Make a bag look like a killed recording: index_pos = 0 in the bag header."""
    data = bytearray(path.read_bytes())
    at = data.index(b"index_pos=") + len("index_pos=")
    data[at : at + 8] = struct.pack("<Q", 0)
    path.write_bytes(bytes(data))


def test_ros1_unindexed_killed_recording(tmp_path, caplog):
    scans = make_scans(6)
    path = tmp_path / "killed.bag"
    write_scan_bag(path, scans)
    _drop_index(path)
    with caplog.at_level(logging.WARNING, logger="lidar3d"):
        logging.getLogger("lidar3d").addHandler(caplog.handler)
        try:
            decoded, source = read_all(path)
        finally:
            logging.getLogger("lidar3d").removeHandler(caplog.handler)
    assert len(decoded) == 6 and source.stats.n_lost_messages == 0
    assert (
        "bag is truncated (no index: the recording was not closed cleanly): read 6 complete message(s)" in caplog.text
    )


@pytest.mark.parametrize("compression", ["BZ2", "LZ4"])
def test_ros1_unindexed_compressed_chunks(tmp_path, compression):
    from rosbags.rosbag1 import Writer

    from lidar3d.io.pointcloud2 import parts_to_message

    store = get_typestore(Stores.ROS1_NOETIC)
    scans = make_scans(3)
    path = tmp_path / "c.bag"
    writer = Writer(path)
    writer.set_compression(getattr(Writer.CompressionFormat, compression))
    with writer:
        conn = writer.add_connection("/velodyne_points", "sensor_msgs/msg/PointCloud2", typestore=store)
        for scan in scans:
            raw = store.serialize_ros1(parts_to_message(encode_scan(scan), store), "sensor_msgs/msg/PointCloud2")
            writer.write(conn, scan.stamp_ns, raw)
    _drop_index(path)
    decoded, _ = read_all(path)
    assert len(decoded) == 3
    assert_scan_equal(decoded[2], scans[2])


@pytest.mark.parametrize("storage", ["ros2-sqlite3", "ros2-mcap"])
def test_ros2_folder_without_metadata(tmp_path, storage):
    scans = make_scans(4)
    path = bag_path(tmp_path, storage)
    write_scan_bag(path, scans, storage=storage)
    (path / "metadata.yaml").unlink()
    decoded, source = read_all(path)
    assert len(decoded) == 4
    assert_scan_equal(decoded[-1], scans[-1])
    assert "no metadata.yaml" in source.notes[0]


def test_ros2_truncated_db3_reads_up_to_the_damage(tmp_path):
    scans = make_scans(30)
    path = bag_path(tmp_path, "ros2-sqlite3")
    write_scan_bag(path, scans, storage="ros2-sqlite3")
    db3 = next(path.glob("*.db3"))
    data = db3.read_bytes()
    db3.write_bytes(data[: len(data) // 2])
    decoded, source = read_all(path)
    assert 0 < len(decoded) < 30
    for got, want in zip(decoded, scans):
        assert_scan_equal(got, want)
    assert source.stats.n_lost_messages == 30 - len(decoded)
    assert f"{30 - len(decoded)} message(s) lost" in source.notes[0]
    assert sorted(path.iterdir()) == sorted([db3, path / "metadata.yaml"])  # the salvage copy is gone


@pytest.mark.parametrize("with_metadata", [True, False])
def test_ros2_unfinished_mcap_reads_every_complete_message(tmp_path, with_metadata):
    scans = make_scans(30)
    path = bag_path(tmp_path, "ros2-mcap")
    write_scan_bag(path, scans, storage="ros2-mcap")
    mcap = next(path.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    if not with_metadata:
        (path / "metadata.yaml").unlink()
    decoded, source = read_all(path)
    assert 0 < len(decoded) < 30
    for got, want in zip(decoded, scans):
        assert_scan_equal(got, want)
    if with_metadata:
        assert source.stats.n_lost_messages == 30 - len(decoded)
        assert source.notes[0].endswith(f"; {30 - len(decoded)} message(s) lost")
    else:
        assert source.stats.n_lost_messages == 1
        assert source.notes[0].endswith("; 1 incomplete message(s) at the end lost")


def test_ros2_single_storage_file_given_directly(tmp_path):
    scans = make_scans(2)
    path = bag_path(tmp_path, "ros2-mcap")
    write_scan_bag(path, scans, storage="ros2-mcap")
    decoded, _ = read_all(next(path.glob("*.mcap")))
    assert len(decoded) == 2


# ---------------------------------------------------------------------------------------------
# Bad input: each raises a BagError/PointCloudError naming the file


def write_topics_bag(path: Path, storage: str, topics: dict[str, str], n: int = 2) -> None:
    """A bag with the given topics (name -> msgtype); PointCloud2 topics get scans, others strings."""
    from lidar3d.io.pointcloud2 import parts_to_message

    ros1 = storage == "ros1"
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(
            path, version=9, storage_plugin=StoragePlugin.MCAP if storage == "ros2-mcap" else StoragePlugin.SQLITE3
        )
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    with writer:
        conns = {name: writer.add_connection(name, msgtype, typestore=store) for name, msgtype in topics.items()}
        for i, scan in enumerate(make_scans(n)):
            for name, msgtype in topics.items():
                if msgtype == "sensor_msgs/msg/PointCloud2":
                    msg = parts_to_message(encode_scan(scan), store)
                else:
                    msg = store.types["std_msgs/msg/String"](data=f"hello {i}")
                writer.write(conns[name], scan.stamp_ns, serialize(msg, msgtype))


def test_missing_path(tmp_path):
    with pytest.raises(BagError, match=r"nope\.bag: no such file or folder"):
        read_all(tmp_path / "nope.bag")


def test_not_a_bag(tmp_path):
    path = tmp_path / "notes.bag"
    path.write_text("hello\n")
    with pytest.raises(BagError, match=r"notes\.bag: not a bag \(expected a ROS1 \.bag file, a ROS2 bag folder"):
        read_all(path)


def test_zero_byte_file(tmp_path):
    path = tmp_path / "zero.bag"
    path.touch()
    with pytest.raises(BagError, match=r"zero\.bag: file is empty \(0 bytes\), not a bag"):
        read_all(path)


def test_folder_that_is_not_a_bag(tmp_path):
    (tmp_path / "folder").mkdir()
    with pytest.raises(BagError, match=r"folder: not a bag folder \(no metadata\.yaml, no \.db3 or \.mcap files\)"):
        read_all(tmp_path / "folder")


@pytest.mark.parametrize("storage", STORAGES)
def test_empty_bag(tmp_path, storage):
    path = bag_path(tmp_path, storage)
    write_scan_bag(path, [], storage=storage)
    with pytest.raises(BagError, match=rf"{path.name}: bag is empty \(no messages\)"):
        read_all(path)


@pytest.mark.parametrize("storage", STORAGES)
def test_no_pointcloud2_topic_lists_topics(tmp_path, storage):
    path = bag_path(tmp_path, storage)
    write_topics_bag(path, storage, {"/chatter": "std_msgs/msg/String", "/status": "std_msgs/msg/String"})
    with pytest.raises(
        BagError,
        match=rf"{path.name}: no sensor_msgs/msg/PointCloud2 topic; "
        r"topics: /chatter \(std_msgs/msg/String, 2\), /status \(std_msgs/msg/String, 2\)",
    ):
        read_all(path)


@pytest.mark.parametrize("storage", STORAGES)
def test_unknown_topic_lists_candidates(tmp_path, storage):
    path = bag_path(tmp_path, storage)
    write_topics_bag(
        path, storage, {"/velodyne_points": "sensor_msgs/msg/PointCloud2", "/chatter": "std_msgs/msg/String"}
    )
    with pytest.raises(
        BagError, match=rf"{path.name}: topic '/points' not found; PointCloud2 topics: /velodyne_points$"
    ):
        read_all(path, topic="/points")
    with pytest.raises(
        BagError, match=r"topic '/chatter' has type std_msgs/msg/String, not sensor_msgs/msg/PointCloud2"
    ):
        read_all(path, topic="/chatter")


@pytest.mark.parametrize("storage", STORAGES)
def test_several_pointcloud2_topics_need_a_choice(tmp_path, storage):
    path = bag_path(tmp_path, storage)
    write_topics_bag(
        path, storage, {"/front/points": "sensor_msgs/msg/PointCloud2", "/rear/points": "sensor_msgs/msg/PointCloud2"}
    )
    with pytest.raises(
        BagError,
        match=rf"{path.name}: several PointCloud2 topics \(/front/points, /rear/points\); choose one with --topic",
    ):
        read_all(path)
    decoded, source = read_all(path, topic="/rear/points")
    assert source.topic == "/rear/points" and len(decoded) == 2


def test_ros1_truncated_before_any_message(tmp_path):
    full = tmp_path / "full.bag"
    write_scan_bag(full, make_scans(2))
    cut = tmp_path / "cut.bag"
    cut.write_bytes(full.read_bytes()[: _ros1_message_positions(full)[0] + 10])
    with pytest.raises(BagError, match=r"cut\.bag: no complete message: bag is truncated"):
        read_all(cut)


@pytest.mark.parametrize("storage", STORAGES)
def test_data_length_disagreeing_with_shape(tmp_path, storage):
    import dataclasses

    scan = make_scans(1)[0]
    parts = encode_scan(scan)
    bad = dataclasses.replace(parts, data=parts.data[:-32])
    path = bag_path(tmp_path, storage)
    write_cloud_bag(path, [bad], storage=storage)
    expected = 32 * len(scan)
    with pytest.raises(
        PointCloudError,
        match=rf"{path.name}: /velodyne_points message 0 at stamp {scan.stamp_ns} ns: data holds {expected - 32} "
        rf"bytes but width\*height\*point_step = {len(scan)}\*1\*32 = {expected}",
    ):
        read_all(path)


@pytest.mark.parametrize("storage", STORAGES)
def test_unsupported_datatype(tmp_path, storage):
    import dataclasses

    from lidar3d.io.pointcloud2 import PointField

    parts = encode_scan(make_scans(1)[0])
    fields = tuple(PointField(f.name, f.offset, 0 if f.name == "ring" else f.datatype) for f in parts.fields)
    path = bag_path(tmp_path, storage)
    write_cloud_bag(path, [dataclasses.replace(parts, fields=fields)], storage=storage)
    with pytest.raises(PointCloudError, match=rf"{path.name}: .*field 'ring' has unsupported datatype 0"):
        read_all(path)


def test_ros1_damaged_magic(tmp_path):
    path = tmp_path / "old.bag"
    path.write_bytes(b"#ROSBAG V1.2\n" + b"\0" * 100)
    with pytest.raises(BagError, match=r"old\.bag: unsupported ROS bag version '#ROSBAG V1\.2'"):
        read_all(path)


def test_source_yields_lazily(tmp_path):
    """The source is a generator over the bag: it holds no list of scans."""
    path = tmp_path / "a.bag"
    write_scan_bag(path, make_scans(5))
    with ScanSource(path) as source:
        iterator = iter(source)
        first = next(iterator)
        assert first.stamp_ns == STAMP_NS
        assert source.stats.n_scans == 1
        assert next(iterator).stamp_ns == STAMP_NS + PERIOD_NS


@pytest.mark.parametrize("storage", ["ros1", "ros2-mcap"])
def test_ring_numbered_from_the_top_is_renumbered_by_elevation(tmp_path, storage):
    """Ouster counts rings from the top beam down; a Scan's ring 0 is the lowest beam."""
    scans = make_scans(3)
    path = bag_path(tmp_path, storage)
    top_down = (
        build_parts(
            s,
            OUSTER,
            48,
            values={
                "t": np.round(s.time_offset_s * 1e9).astype(np.uint32),
                "ring": 15 - s.ring,
                "reflectivity": 0,
                "ambient": 0,
                "range": 0,
            },
        )
        for s in scans
    )
    write_cloud_bag(path, top_down, storage=storage)
    decoded, _ = read_all(path)
    for got, want in zip(decoded, scans):
        assert_scan_equal(got, want, time_atol=1e-9)


def test_ros2_unfinished_mcap_with_zstd_chunks(tmp_path):
    """A killed writer leaves complete compressed chunks and no footer: all of them are read."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    from lidar3d.io.pointcloud2 import parts_to_message

    store = get_typestore(Stores.ROS2_HUMBLE)
    scans = make_scans(40, n_columns=180)
    path = tmp_path / "zstd"
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        conn = writer.add_connection("/velodyne_points", "sensor_msgs/msg/PointCloud2", typestore=store)
        for scan in scans:
            writer.write(
                conn,
                scan.stamp_ns,
                store.serialize_cdr(parts_to_message(encode_scan(scan), store), "sensor_msgs/msg/PointCloud2"),
            )
    mcap = next(path.glob("*.mcap"))
    data = mcap.read_bytes()
    # Footer: opcode, uint64 length, uint64 summary_start, ...; the 13-byte DataEnd record precedes
    # the summary. Drop DataEnd, summary and footer, which a killed writer never writes.
    (summary_start,) = struct.unpack_from("<Q", data, len(data) - 37 + 9)
    mcap.write_bytes(data[: summary_start - 13])
    (path / "metadata.yaml").unlink()
    decoded, source = read_all(path)
    assert len(decoded) == 40 and source.stats.n_lost_messages == 0
    assert source.notes[0].endswith(
        "are truncated: read every complete message before the damage, in recording order; no message was cut off"
    )
    for got, want in zip(decoded, scans):
        assert_scan_equal(got, want)
