"""``lidar3d simulate`` end to end: the folder, the bag read back, determinism, formats, errors."""

import json

import numpy as np
import pytest

from lidar3d.cli.cmd_simulate import SCENARIO_HELP
from lidar3d.cli.main import main
from lidar3d.errors import OutputError, SimulationError
from lidar3d.io.scan_source import ScanSource
from lidar3d.io.trajectory_io import read_tum
from lidar3d.sim import SCENARIOS, Simulation, simulate

FILES = ("scans.bag", "ground_truth_tum.txt", "novatel_span.log", "extrinsics.toml", "metadata.json")


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("sim") / "loop"
    assert main(["-q", "simulate", "loop", "--out", str(out), "--duration", "1.5", "--seed", "3"]) == 0
    return out


def test_folder_holds_every_output_and_metadata(folder):
    assert sorted(p.name for p in folder.iterdir()) == sorted(FILES)
    meta = json.loads((folder / "metadata.json").read_text())
    assert meta["scenario"] == "loop" and meta["seed"] == 3 and meta["sensor"] == "vlp16"
    assert meta["n_scans"] == 15 and meta["duration_s"] == pytest.approx(1.5)
    assert meta["files"]["bag"] == "scans.bag" and meta["files"]["topic"] == "/velodyne_points"
    assert meta["origin"]["latitude_deg"] == pytest.approx(49.01135)
    assert 2.0 <= meta["speed_mps"]["min"] <= meta["speed_mps"]["max"] <= 10.0
    assert meta["revisits"] == []  # 1.5 s never comes back
    assert meta["parameters"]["lidar"]["range_noise_sigma_m"] == 0.02


def test_bag_reads_back_through_the_scan_source(folder):
    sim = Simulation("loop", duration_s=1.5, seed=3)
    with ScanSource(folder / "scans.bag") as source:
        assert source.topic == "/velodyne_points" and len(source) == 15
        scans = list(source)
    for index in (0, 14):
        expected = sim.scan(index).scan
        got = scans[index]
        assert got.stamp_ns == expected.stamp_ns == sim.stamps_ns[index]
        np.testing.assert_allclose(got.points, expected.points, atol=1e-4)  # float32 in the bag
        np.testing.assert_array_equal(got.ring, expected.ring)
        np.testing.assert_array_equal(got.intensity, expected.intensity)
        np.testing.assert_allclose(got.time_offset_s, expected.time_offset_s, atol=1e-7)


def test_bag_has_the_velodyne_pointcloud_layout(folder):
    from rosbags.rosbag1 import Reader
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS1_NOETIC)
    with Reader(folder / "scans.bag") as reader:
        connection, log_time, raw = next(iter(reader.messages()))
        message = typestore.deserialize_ros1(raw, connection.msgtype)
    assert connection.topic == "/velodyne_points" and connection.msgtype == "sensor_msgs/msg/PointCloud2"
    assert message.header.frame_id == "velodyne"
    assert message.header.stamp.sec * 10**9 + message.header.stamp.nanosec == log_time
    layout = {f.name: (f.offset, f.datatype, f.count) for f in message.fields}
    assert layout == {
        "x": (0, 7, 1),
        "y": (4, 7, 1),
        "z": (8, 7, 1),
        "intensity": (16, 7, 1),
        "ring": (20, 4, 1),
        "time": (24, 7, 1),
    }
    assert message.point_step == 32 and message.height == 1 and not message.is_bigendian


def test_ground_truth_file_matches_the_simulation(folder):
    gt = read_tum(folder / "ground_truth_tum.txt")
    sim = Simulation("loop", duration_s=1.5, seed=3)
    np.testing.assert_array_equal(gt.stamps_ns, sim.stamps_ns)
    np.testing.assert_allclose(gt.T_world_lidar, sim.ground_truth.T_world_lidar, atol=1e-6)


def test_same_seed_gives_byte_identical_outputs(folder, tmp_path):
    again = tmp_path / "again"
    other = tmp_path / "other"
    simulate("loop", again, seed=3, duration_s=1.5)
    simulate("loop", other, seed=4, duration_s=1.5)
    for name in FILES:
        assert (again / name).read_bytes() == (folder / name).read_bytes(), name
    for name in ("scans.bag", "novatel_span.log", "metadata.json"):
        assert (other / name).read_bytes() != (folder / name).read_bytes(), name


def test_ros2_and_other_sensor(tmp_path):
    out = tmp_path / "ros2"
    argv = ["-q", "simulate", "hilly", "--out", str(out), "--duration", "0.3", "--format", "ros2", "--sensor", "vlp32c"]
    assert main(argv) == 0
    assert (out / "scans" / "metadata.yaml").is_file()
    meta = json.loads((out / "metadata.json").read_text())
    assert meta["files"]["bag"] == "scans" and meta["sensor"] == "vlp32c" and meta["n_scans"] == 3
    with ScanSource(out / "scans") as source:
        scans = list(source)
    assert len(scans) == 3 and scans[0].ring.max() == 31


def test_refuses_to_overwrite_unless_asked(folder, tmp_path, capsys):
    out = tmp_path / "twice"
    simulate("loop", out, duration_s=0.2)
    with pytest.raises(OutputError, match="already holds simulation outputs"):
        simulate("loop", out, duration_s=0.2)
    assert main(["simulate", "loop", "--out", str(out), "--duration", "0.2"]) == 1
    assert "already holds simulation outputs" in capsys.readouterr().err
    assert main(["-q", "simulate", "loop", "--out", str(out), "--duration", "0.3", "--overwrite"]) == 0
    assert json.loads((out / "metadata.json").read_text())["n_scans"] == 3


def test_bad_arguments(tmp_path, capsys):
    assert main(["simulate", "loop", "--out", str(tmp_path / "x"), "--duration", "1000"]) == 1
    assert "lasts" in capsys.readouterr().err
    assert not (tmp_path / "x" / "metadata.json").exists()
    with pytest.raises(SystemExit) as exit_info:
        main(["simulate", "nowhere", "--out", str(tmp_path / "y")])
    assert exit_info.value.code == 2
    with pytest.raises(SimulationError, match="unknown bag format 'ros3'"):
        simulate("loop", tmp_path / "z", duration_s=0.2, bag_format="ros3")


def test_help_lists_every_scenario_with_an_example(capsys):
    assert set(SCENARIO_HELP) == set(SCENARIOS)
    for name, text in SCENARIO_HELP.items():
        assert text == SCENARIOS[name].description
    with pytest.raises(SystemExit) as exit_info:
        main(["simulate", "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert all(name in out for name in SCENARIOS)
    assert "example:" in out and "lidar3d simulate loop --out" in out
