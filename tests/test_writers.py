"""Trajectory (TUM, KITTI) and PCD writers: round trips, formats other tools read, atomic writes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar3d.errors import OutputError
from lidar3d.io.atomic import atomic_path, write_text_atomic
from lidar3d.io.pcd import read_pcd, write_pcd
from lidar3d.io.trajectory_io import (
    TrajectoryFileError,
    read_kitti,
    read_trajectory,
    read_tum,
    write_kitti,
    write_tum,
)
from lidar3d.records import Trajectory


def random_trajectory(n: int = 25, seed: int = 3) -> Trajectory:
    rng = np.random.default_rng(seed)
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.random(n, random_state=seed).as_matrix()
    poses[:, :3, 3] = rng.uniform(-500.0, 500.0, (n, 3))
    stamps = 1_700_000_000_000_000_000 + np.cumsum(rng.integers(50_000_000, 150_000_000, n)) + 123
    return Trajectory(stamps, poses)


def test_tum_round_trip_keeps_nanosecond_stamps(tmp_path):
    trajectory = random_trajectory()
    write_tum(tmp_path / "t.txt", trajectory)
    back = read_tum(tmp_path / "t.txt")
    np.testing.assert_array_equal(back.stamps_ns, trajectory.stamps_ns)
    np.testing.assert_allclose(back.T_world_lidar[:, :3, 3], trajectory.T_world_lidar[:, :3, 3], atol=1e-6)
    np.testing.assert_allclose(back.T_world_lidar[:, :3, :3], trajectory.T_world_lidar[:, :3, :3], atol=1e-8)


def test_tum_format_is_what_evo_reads(tmp_path):
    """evo's TUM reader: whitespace-separated 'timestamp tx ty tz qx qy qz qw', '#' comments."""
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[1, :3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    poses[1, :3, 3] = [1.0, 2.0, 3.0]
    write_tum(tmp_path / "t.txt", Trajectory([1_000_000_000, 1_500_000_001], poses))
    lines = (tmp_path / "t.txt").read_text().splitlines()
    assert lines[0].startswith("#")
    rows = np.loadtxt(tmp_path / "t.txt")
    assert rows.shape == (2, 8)
    np.testing.assert_allclose(rows[1], [1.500000001, 1, 2, 3, 0, 0, np.sqrt(0.5), np.sqrt(0.5)], atol=1e-9)


def test_kitti_round_trip_with_times_file(tmp_path):
    trajectory = random_trajectory()
    write_kitti(tmp_path / "poses.txt", trajectory)
    rows = np.loadtxt(tmp_path / "poses.txt")
    assert rows.shape == (len(trajectory), 12)  # evo's KITTI reader: 12 numbers per line
    np.testing.assert_allclose(rows.reshape(-1, 3, 4), trajectory.T_world_lidar[:, :3, :], rtol=1e-8)
    back = read_kitti(tmp_path / "poses.txt")
    np.testing.assert_array_equal(back.stamps_ns, trajectory.stamps_ns)
    np.testing.assert_allclose(back.T_world_lidar, trajectory.T_world_lidar, rtol=1e-8, atol=1e-9)


def test_trajectory_file_errors_name_file_and_line(tmp_path):
    path = tmp_path / "bad.txt"
    path.write_text("# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n")
    with pytest.raises(TrajectoryFileError, match=r"bad\.txt:3: expected 8 TUM columns, got 7"):
        read_tum(path)
    with pytest.raises(TrajectoryFileError, match=r"missing\.txt: trajectory file not found"):
        read_tum(tmp_path / "missing.txt")
    path.write_text(" ".join(["0"] * 11) + "\n")
    with pytest.raises(TrajectoryFileError, match=r"bad\.txt:1: expected 12 KITTI columns, got 11"):
        read_kitti(path)


def test_read_trajectory_tells_tum_from_kitti_by_columns(tmp_path):
    trajectory = random_trajectory()
    write_tum(tmp_path / "t.txt", trajectory)
    write_kitti(tmp_path / "k.txt", trajectory)
    for name, reader in (("t.txt", read_tum), ("k.txt", read_kitti)):
        back, expected = read_trajectory(tmp_path / name), reader(tmp_path / name)
        np.testing.assert_array_equal(back.stamps_ns, expected.stamps_ns)
        np.testing.assert_array_equal(back.T_world_lidar, expected.T_world_lidar)
    rows = (tmp_path / "k.txt").read_text().splitlines()
    rows[4] = rows[4].replace(rows[4].split()[3], "nan?", 1)
    (tmp_path / "k.txt").write_text("\n".join(rows) + "\n")
    with pytest.raises(TrajectoryFileError, match=r"k\.txt:5: not a number \('nan\?'\)"):
        read_trajectory(tmp_path / "k.txt")
    (tmp_path / "e.txt").write_text("# only a comment\n")
    with pytest.raises(TrajectoryFileError, match=r"e\.txt: trajectory file has no poses"):
        read_trajectory(tmp_path / "e.txt")


def test_empty_trajectory_round_trips(tmp_path):
    empty = Trajectory(np.zeros(0, np.int64), np.zeros((0, 4, 4)))
    write_tum(tmp_path / "t.txt", empty)
    assert len(read_tum(tmp_path / "t.txt")) == 0
    write_kitti(tmp_path / "k.txt", empty)
    assert len(read_kitti(tmp_path / "k.txt")) == 0


def test_pcd_binary_with_intensity_reads_back_in_open3d(tmp_path):
    import open3d as o3d

    rng = np.random.default_rng(0)
    points = rng.uniform(-50, 50, (1000, 3))
    intensity = rng.uniform(0, 255, 1000).astype(np.float32)
    label = rng.integers(0, 10, 1000)
    path = tmp_path / "map.pcd"
    write_pcd(path, points, intensity=intensity, label=label)
    header = path.read_bytes()[:400].split(b"DATA ")[0].decode("ascii").splitlines()
    fields = next(line for line in header if line.startswith("FIELDS")).split()[1:]
    types = dict(zip(fields, next(line for line in header if line.startswith("TYPE")).split()[1:]))
    assert fields[:3] == ["x", "y", "z"] and sorted(fields[3:]) == ["intensity", "label"]
    assert (types["intensity"], types["label"]) == ("F", "I")
    assert path.read_bytes().split(b"DATA ", 1)[1].startswith(b"binary\n")
    cloud = o3d.t.io.read_point_cloud(str(path))
    np.testing.assert_array_equal(cloud.point.positions.numpy(), points.astype(np.float32))
    np.testing.assert_array_equal(cloud.point["intensity"].numpy().reshape(-1), intensity)
    back_points, extra = read_pcd(path)
    np.testing.assert_array_equal(back_points, points.astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(extra["label"], label.astype(np.int32))
    assert [p.name for p in tmp_path.iterdir()] == ["map.pcd"]


def _open3d_pcd_bytes(path, points, **fields) -> bytes:
    """The PCD Open3D's tensor API writes (what ``write_pcd`` wrote through it before)."""
    import open3d as o3d

    cloud = o3d.t.geometry.PointCloud()
    cloud.point.positions = o3d.core.Tensor(np.ascontiguousarray(points, dtype=np.float32))
    for name, values in fields.items():
        dtype = np.int32 if np.issubdtype(np.asarray(values).dtype, np.integer) else np.float32
        cloud.point[name] = o3d.core.Tensor(np.ascontiguousarray(np.asarray(values).reshape(-1, 1), dtype=dtype))
    assert o3d.t.io.write_point_cloud(str(path), cloud, write_ascii=False, compressed=False)
    return path.read_bytes()


@pytest.mark.parametrize(
    "fields",
    [
        {},
        {"intensity": "float64"},
        {"zeta": "float32", "label": "int64", "alpha": "uint16"},  # Open3D orders the extra fields by name
    ],
)
def test_pcd_bytes_are_those_open3d_writes(tmp_path, fields):
    rng = np.random.default_rng(2)
    points = rng.normal(size=(700, 6))[:, ::2] * 300.0  # float64, not contiguous
    values = {name: (rng.normal(size=700) * 100).astype(dtype) for name, dtype in fields.items()}
    write_pcd(tmp_path / "ours.pcd", points, **values)
    assert (tmp_path / "ours.pcd").read_bytes() == _open3d_pcd_bytes(tmp_path / "open3d.pcd", points, **values)


def test_pcd_rejects_bad_shapes(tmp_path):
    with pytest.raises(ValueError, match=r"points must be \(N, 3\)"):
        write_pcd(tmp_path / "a.pcd", np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"field intensity must be \(4,\)"):
        write_pcd(tmp_path / "a.pcd", np.zeros((4, 3)), intensity=np.zeros(3))
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(OutputError, match="point cloud file not found"):
        read_pcd(tmp_path / "none.pcd")


def test_atomic_write_keeps_old_file_on_failure(tmp_path):
    path = tmp_path / "out.txt"
    write_text_atomic(path, "old\n")
    with pytest.raises(RuntimeError), atomic_path(path) as tmp:
        tmp.write_text("half")
        raise RuntimeError("interrupted")
    assert path.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]
