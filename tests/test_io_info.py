"""``lidar3d info`` and its library twin; every bad input as one stderr line and exit code 1."""

from __future__ import annotations

import dataclasses

import pytest
from test_io_bags import STORAGES, _drop_index, _ros1_message_positions, bag_path, make_scans, write_topics_bag
from test_io_pointcloud2 import STAMP_NS, vlp_scan

from lidar3d.cli.main import main
from lidar3d.io.bag_info import bag_info, format_bag_info
from lidar3d.io.bag_writer import write_cloud_bag, write_scan_bag
from lidar3d.io.pointcloud2 import PointField, encode_scan
from lidar3d.sensors import HDL32E, VLP32C


@pytest.mark.parametrize("storage", STORAGES)
def test_bag_info_record(tmp_path, storage):
    path = bag_path(tmp_path, storage)
    write_topics_bag(
        path, storage, {"/velodyne_points": "sensor_msgs/msg/PointCloud2", "/chatter": "std_msgs/msg/String"}, n=3
    )
    info = bag_info(path)
    assert info.format == ("ros1" if storage == "ros1" else "ros2")
    assert [(t.name, t.msgtype, t.count) for t in info.topics] == [
        ("/chatter", "std_msgs/msg/String", 3),
        ("/velodyne_points", "sensor_msgs/msg/PointCloud2", 3),
    ]
    assert info.n_messages == 6 and info.n_scans == 3
    assert info.lidar_topic == "/velodyne_points"
    assert [f.name for f in info.point_fields] == ["x", "y", "z", "intensity", "ring", "time"]
    assert info.point_step == 32 and info.n_points_first == 45 * 16
    assert (info.n_rings, info.sensor_model) == (16, "vlp16")
    assert (info.first_stamp_ns, info.last_stamp_ns) == (STAMP_NS, STAMP_NS + 200_000_000)
    assert info.duration_s == pytest.approx(0.2)
    assert info.notes == ()


@pytest.mark.parametrize("sensor", [VLP32C, HDL32E], ids=lambda s: s.name)
def test_sensor_model_guessed_from_rings(tmp_path, sensor):
    write_scan_bag(tmp_path / "a.bag", [vlp_scan(sensor=sensor)])
    info = bag_info(tmp_path / "a.bag")
    assert (info.n_rings, info.sensor_model) == (32, sensor.name)


def test_no_ring_field_reports_unknown_model(tmp_path):
    parts = encode_scan(vlp_scan())
    no_ring = dataclasses.replace(parts, fields=tuple(f for f in parts.fields if f.name != "ring"))
    write_cloud_bag(tmp_path / "a.bag", [no_ring])
    info = bag_info(tmp_path / "a.bag")
    assert info.n_rings is None and info.sensor_model is None
    assert "sensor model: unknown (no ring field)" in format_bag_info(info)


def test_cli_info_prints_every_bag(tmp_path, capsys):
    write_scan_bag(tmp_path / "a.bag", make_scans(2))
    write_scan_bag(tmp_path / "b", make_scans(3), storage="ros2-mcap")
    assert main(["info", str(tmp_path / "a.bag"), str(tmp_path / "b")]) == 0
    out = capsys.readouterr().out
    assert f"bag:          {tmp_path / 'a.bag'} (ros1)" in out
    assert f"bag:          {tmp_path / 'b'} (ros2)" in out
    assert "lidar topic:  /velodyne_points (2 scans)" in out and "lidar topic:  /velodyne_points (3 scans)" in out
    assert (
        "point fields: x:FLOAT32@0 y:FLOAT32@4 z:FLOAT32@8 intensity:FLOAT32@16 ring:UINT16@20 time:FLOAT32@24 "
        "(point_step 32" in out
    )
    assert "sensor model: vlp16 (16 rings in the first cloud)" in out
    assert f"first stamp:  {STAMP_NS // 10**9}.{STAMP_NS % 10**9:09d}" in out
    assert "duration:     0.100 s" in out and "duration:     0.200 s" in out


def test_cli_info_help_has_an_example(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["info", "--help"])
    assert exit_info.value.code == 0
    assert "example:\n  lidar3d info recording.bag" in capsys.readouterr().out


def test_cli_truncated_bag_warns_and_reports(tmp_path, capsys):
    full = tmp_path / "full.bag"
    write_scan_bag(full, make_scans(30))
    cut = tmp_path / "cut.bag"
    cut.write_bytes(full.read_bytes()[: _ros1_message_positions(full)[25] + 40])
    assert main(["info", str(cut)]) == 0
    captured = capsys.readouterr()
    assert (
        f"WARNING: {cut}: bag is truncated (index unreadable: the file is cut short): read 25 complete message(s)"
        in captured.err
    )
    assert "1 incomplete message(s) at the end lost" in captured.err
    assert "lidar topic:  /velodyne_points (25 scans)" in captured.out


def test_cli_unindexed_bag(tmp_path, capsys):
    path = tmp_path / "killed.bag"
    write_scan_bag(path, make_scans(3))
    _drop_index(path)
    assert main(["info", str(path)]) == 0
    assert "no index: the recording was not closed cleanly" in capsys.readouterr().err


def _bad_bags(tmp_path):
    """name -> (argv after 'info', the one expected error line, minus the 'lidar3d info: error: ' prefix)."""
    cases = {}
    missing = tmp_path / "missing.bag"
    cases["missing path"] = ([str(missing)], f"{missing}: no such file or folder")
    text = tmp_path / "notes.txt"
    text.write_text("not a bag\n")
    cases["not a bag"] = (
        [str(text)],
        f"{text}: not a bag (expected a ROS1 .bag file, a ROS2 bag folder, or a .db3/.mcap file)",
    )
    empty = tmp_path / "empty.bag"
    write_scan_bag(empty, [])
    cases["empty bag"] = ([str(empty)], f"{empty}: bag is empty (no messages)")
    empty2 = tmp_path / "empty_ros2"
    write_scan_bag(empty2, [], storage="ros2-sqlite3")
    cases["empty ros2 bag"] = ([str(empty2)], f"{empty2}: bag is empty (no messages)")
    chatter = tmp_path / "chatter.bag"
    write_topics_bag(chatter, "ros1", {"/chatter": "std_msgs/msg/String"})
    cases["no PointCloud2 topic"] = (
        [str(chatter)],
        f"{chatter}: no sensor_msgs/msg/PointCloud2 topic; topics: /chatter (std_msgs/msg/String, 2)",
    )
    one = tmp_path / "one.bag"
    write_scan_bag(one, make_scans(1))
    cases["unknown --topic"] = (
        [str(one), "--topic", "/points"],
        f"{one}: topic '/points' not found; PointCloud2 topics: /velodyne_points",
    )
    two = tmp_path / "two"
    write_topics_bag(two, "ros2-mcap", {"/a": "sensor_msgs/msg/PointCloud2", "/b": "sensor_msgs/msg/PointCloud2"})
    cases["several PointCloud2 topics"] = (
        [str(two)],
        f"{two}: several PointCloud2 topics (/a, /b); choose one with --topic",
    )
    full = tmp_path / "full.bag"
    write_scan_bag(full, make_scans(2))
    cut = tmp_path / "cut.bag"
    cut.write_bytes(full.read_bytes()[: _ros1_message_positions(full)[0] + 10])
    cases["truncated before the first message"] = (
        [str(cut)],
        f"{cut}: no complete message: bag is truncated (index unreadable: the file is cut short): read 0 complete "
        "message(s) in file order; 1 incomplete message(s) at the end lost",
    )
    scan = make_scans(1)[0]
    parts = encode_scan(scan)
    short = tmp_path / "short.bag"
    write_cloud_bag(short, [dataclasses.replace(parts, data=parts.data[:-32])])
    n = len(scan)
    cases["data length mismatch"] = (
        [str(short)],
        f"{short}: first cloud on /velodyne_points: data holds {32 * n - 32} bytes "
        f"but width*height*point_step = {n}*1*32 = {32 * n}",
    )
    odd = tmp_path / "odd.bag"
    fields = tuple(PointField(f.name, f.offset, 11 if f.name == "time" else f.datatype) for f in parts.fields)
    write_cloud_bag(odd, [dataclasses.replace(parts, fields=fields)])
    cases["unsupported datatype"] = (
        [str(odd)],
        f"{odd}: first cloud on /velodyne_points: field 'time' has unsupported datatype 11 (supported PointField "
        "codes: 1=INT8, 2=UINT8, 3=INT16, 4=UINT16, 5=INT32, 6=UINT32, 7=FLOAT32, 8=FLOAT64, 9=INT64, 10=UINT64)",
    )
    return cases


def test_cli_bad_inputs_one_line_exit_1(tmp_path, capsys):
    for name, (argv, message) in _bad_bags(tmp_path).items():
        capsys.readouterr()
        assert main(["info", *argv]) == 1, name
        captured = capsys.readouterr()
        assert captured.out == "", name
        assert captured.err.splitlines() == [f"lidar3d info: error: {message}"], name
