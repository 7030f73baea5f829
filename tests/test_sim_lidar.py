"""The ray-cast sensor, checked against the world mesh independently of the SLAM code."""

import numpy as np
import open3d as o3d
import pytest
from scipy.spatial.transform import Rotation, Slerp

from lidar3d.sensors import sensor_model
from lidar3d.sim import LidarParams, ObjectClass, Simulation


@pytest.fixture(scope="module")
def fast():
    return Simulation("fast", duration_s=20.0, seed=2)  # through the first corner


def _scene(world):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(world.vertices_m.astype(np.float32)), o3d.core.Tensor(world.triangles.astype(np.uint32))
    )
    return scene


def _interpolate(trajectory, stamps_ns):
    """Ground-truth poses at arbitrary stamps: linear position, SLERP rotation (test-local)."""
    t = (trajectory.stamps_ns - trajectory.stamps_ns[0]) * 1e-9
    q = (np.asarray(stamps_ns) - trajectory.stamps_ns[0]) * 1e-9
    poses = np.tile(np.eye(4), (len(q), 1, 1))
    for k in range(3):
        poses[:, k, 3] = np.interp(q, t, trajectory.T_world_lidar[:, k, 3])
    poses[:, :3, :3] = Slerp(t, Rotation.from_matrix(trajectory.T_world_lidar[:, :3, :3]))(q).as_matrix()
    return poses


def _to_world(points, poses):
    if poses.ndim == 2:
        return points @ poses[:3, :3].T + poses[:3, 3]
    return np.einsum("nij,nj->ni", poses[:, :3, :3], points) + poses[:, :3, 3]


def test_points_lie_on_the_mesh_only_with_per_point_poses(fast):
    scene = _scene(fast.world)
    gt = fast.ground_truth
    t = fast.route_seconds(gt.stamps_ns)
    speed = np.linalg.norm(fast.motion.velocity_at(t), axis=1)
    yaw_rate = np.abs(np.diff(np.unwrap(np.arctan2(gt.T_world_lidar[:, 1, 0], gt.T_world_lidar[:, 0, 0])))) / 0.1
    moving = int(np.argmax(speed[:-1]))  # fastest scan
    turning = int(np.argmax(yaw_rate))  # sharpest turn
    assert speed[moving] > 8.0 and np.rad2deg(yaw_rate[turning]) > 25.0
    for index in (moving, turning):
        simulated = fast.scan(index)
        scan = simulated.scan
        point_stamps = scan.stamp_ns + np.rint(scan.time_offset_s * 1e9).astype(np.int64)
        per_point = _to_world(scan.points, _interpolate(gt, point_stamps))
        one_pose = _to_world(scan.points, gt.T_world_lidar[index])
        d_per_point = scene.compute_distance(o3d.core.Tensor(per_point.astype(np.float32))).numpy()
        d_one_pose = scene.compute_distance(o3d.core.Tensor(one_pose.astype(np.float32))).numpy()
        assert np.median(d_per_point) < 0.02  # noise sigma 0.02 m along the ray
        assert np.percentile(d_per_point, 90) < 0.04
        assert np.percentile(d_one_pose, 90) > 3.0 * np.percentile(d_per_point, 90)
        assert np.percentile(d_one_pose, 90) > 0.1


def test_labels_name_what_was_hit(fast):
    simulated = fast.scan(40)
    world = fast.world
    scene = _scene(world)
    stamps = simulated.scan.stamp_ns + np.rint(simulated.scan.time_offset_s * 1e9).astype(np.int64)
    points = _to_world(simulated.scan.points, fast.T_world_lidar_at(stamps))
    closest = scene.compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))
    nearest_object = world.triangle_object_id[closest["primitive_ids"].numpy()]
    assert np.mean(nearest_object == simulated.object_id) > 0.97
    np.testing.assert_array_equal(simulated.object_class, world.object_class[simulated.object_id])
    ground = simulated.ground_mask
    assert 0.2 < ground.mean() < 0.9
    height = world.terrain.height_m(points[ground, 0], points[ground, 1])
    assert np.median(np.abs(points[ground, 2] - height)) < 0.02
    seen = set(simulated.object_class.tolist())
    assert {int(ObjectClass.GROUND), int(ObjectClass.BUILDING)} <= seen
    assert len(seen) >= 4


def test_scan_fields_follow_the_driver_conventions(fast):
    simulated = fast.scan(7)
    scan = simulated.scan
    sensor = fast.sensor
    assert scan.stamp_ns == fast.stamps_ns[7]
    assert len(scan) > 15_000 and np.all(np.isfinite(scan.points))
    elevation = np.arctan2(scan.points[:, 2], np.linalg.norm(scan.points[:, :2], axis=1))
    np.testing.assert_allclose(elevation, sensor.elevation_rad[scan.ring], atol=1e-9)
    assert scan.ring.max() < sensor.n_rings and len(np.unique(scan.ring)) == sensor.n_rings
    assert scan.time_offset_s.min() >= 0.0 and scan.time_offset_s.max() < sensor.sweep_period_s
    assert np.all(np.diff(scan.time_offset_s) >= 0.0)  # firing order
    # The head turns clockwise from pointing backwards: time is proportional to the clockwise angle.
    clockwise = np.mod(np.pi - np.arctan2(scan.points[:, 1], scan.points[:, 0]), 2.0 * np.pi)
    np.testing.assert_allclose(clockwise / (2.0 * np.pi) * sensor.sweep_period_s, scan.time_offset_s, atol=1e-9)
    column = np.rint(scan.time_offset_s / sensor.sweep_period_s * sensor.n_columns)
    np.testing.assert_array_equal(simulated.column, column)
    assert scan.range_m.min() >= fast.lidar_params.min_range_m and scan.range_m.max() <= sensor.max_range_m
    assert np.all(scan.intensity == np.rint(scan.intensity))
    assert scan.intensity.min() >= 0 and scan.intensity.max() <= 255
    np.testing.assert_allclose(simulated.T_world_lidar, fast.ground_truth.T_world_lidar[7])


def test_intensity_depends_on_surface_and_incidence(fast):
    simulated = fast.scan(30)
    scan = simulated.scan
    ground = simulated.ground_mask
    road = ground & (np.abs(scan.points[:, 1]) < 2.0) & (scan.range_m < 12.0)  # the lane ahead and behind
    assert np.median(scan.intensity[road]) < 15.0
    assert scan.intensity[~ground].mean() > scan.intensity[road].mean()


def test_noise_and_dropouts_are_what_the_parameters_say():
    exact = Simulation("loop", duration_s=0.5, lidar=LidarParams(range_noise_sigma_m=0.0, dropout_probability=0.0))
    noisy = Simulation("loop", duration_s=0.5, lidar=LidarParams(range_noise_sigma_m=0.05, dropout_probability=0.0))
    sparse = Simulation("loop", duration_s=0.5, lidar=LidarParams(dropout_probability=0.5))
    a, b, c = exact.scan(2), noisy.scan(2), sparse.scan(2)
    # The same random draws are taken whatever sigma is, so the two scans keep the same returns.
    np.testing.assert_array_equal(a.scan.ring, b.scan.ring)
    residual = b.scan.range_m - a.scan.range_m
    assert 0.045 < residual.std() < 0.055 and abs(residual.mean()) < 0.005
    assert 0.45 < len(c.scan) / len(a.scan) < 0.55
    scene = _scene(exact.world)
    stamps = a.scan.stamp_ns + np.rint(a.scan.time_offset_s * 1e9).astype(np.int64)
    points = _to_world(a.scan.points, exact.T_world_lidar_at(stamps))
    assert np.max(scene.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()) < 2e-3


def test_scans_are_deterministic_and_order_independent():
    one = Simulation("loop", duration_s=1.0, seed=5)
    two = Simulation("loop", duration_s=1.0, seed=5)
    other = Simulation("loop", duration_s=1.0, seed=6)
    late_first = two.scan(8)
    early = one.scan(3)
    np.testing.assert_array_equal(one.scan(8).scan.points, late_first.scan.points)
    np.testing.assert_array_equal(early.scan.intensity, two.scan(3).scan.intensity)
    assert not np.array_equal(early.scan.points[:100], other.scan(3).scan.points[:100])


@pytest.mark.parametrize("name", ["hdl32e", "vlp32c"])
def test_other_sensor_presets(name):
    sim = Simulation("loop", duration_s=0.3, sensor=name)
    sensor = sensor_model(name)
    scan = sim.scan(1).scan
    assert scan.ring.max() < 32 and len(np.unique(scan.ring)) > 20
    elevation = np.arctan2(scan.points[:, 2], np.linalg.norm(scan.points[:, :2], axis=1))
    np.testing.assert_allclose(elevation, sensor.elevation_rad[scan.ring], atol=1e-9)
    assert len(scan) > 0.5 * sensor.n_rings * sensor.n_columns
    assert scan.range_m.max() <= sensor.max_range_m
