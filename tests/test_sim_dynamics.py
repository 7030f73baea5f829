"""Vehicle dynamics (speed profiles, stops, suspension vibration) and sensor imperfections (calibration
errors, stamp conventions, lost packets) of the simulator, and that the defaults keep the old drives."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar3d.errors import SimulationError
from lidar3d.sensors import sensor_model
from lidar3d.sim import (
    LidarParams,
    ObjectClass,
    RouteParams,
    Scenario,
    Simulation,
    StampMode,
    StreetLayout,
    TerrainParams,
    World,
    WorldParams,
    simulate,
)
from lidar3d.sim.lidar import LidarSimulator
from lidar3d.sim.terrain import make_terrain
from lidar3d.sim.trajectory import VehicleMotion

STRAIGHT = StreetLayout(street_x_m=(0.0, 300.0), street_y_m=(0.0, 100.0))
FLAT = WorldParams(terrain=TerrainParams(max_slope_deg=0.0))


def _straight(route: RouteParams, world: WorldParams = FLAT, lidar: LidarParams | None = None) -> Scenario:
    return Scenario(
        "straight", "a 280 m straight", STRAIGHT, ((10.0, 0.0), (290.0, 0.0)), route, world, lidar or LidarParams()
    )


def _horizontal_speed(motion: VehicleMotion, t: np.ndarray) -> np.ndarray:
    return np.linalg.norm(np.diff(motion.pose_at(t)[:, :2, 3], axis=0), axis=1) / np.diff(t)


# ---------------------------------------------------------------- vehicle dynamics


def test_stop_holds_the_pose_exactly_still_with_braking_before_and_pulling_away_after():
    route = RouteParams(cruise_speed_mps=8.0, stops=((120.0, 4.0),), vibration_deg=0.3, vibration_heave_m=0.001)
    sim = Simulation(_straight(route))
    motion = sim.motion
    ((start, end),) = motion.stop_intervals_s
    assert end - start == pytest.approx(4.0)
    t_stop = np.linspace(start, end, 400)
    poses = motion.pose_at(t_stop)
    np.testing.assert_array_equal(poses, np.broadcast_to(poses[0], poses.shape))  # vibration stops too
    np.testing.assert_array_equal(motion.velocity_at(t_stop[1:-1]), 0.0)
    # 120 m along the path from the start (10, 0), in the right-hand lane.
    np.testing.assert_allclose(poses[0, :2, 3], [130.0, -1.5], atol=0.3)
    # Braking into the stop and pulling away after it, within the limits (2.0 / 1.2 m/s^2).
    t = np.arange(start - 6.0, end + 8.0, 0.02)
    speed = _horizontal_speed(motion, t)
    accel = np.diff(speed) / 0.02
    assert speed[0] > 5.5 and speed[-1] > 6.0
    assert accel.min() > -1.05 * route.max_decel_mps2 and accel.max() < 1.05 * route.max_accel_mps2
    assert accel.min() < -0.95 * route.max_decel_mps2 and accel.max() > 0.95 * route.max_accel_mps2
    # The scans during the stop all have the same true pose.
    stamps = sim.ground_truth.stamps_ns
    ((stop_start_ns, stop_end_ns),) = sim.stop_spans_ns()
    inside = (stamps >= stop_start_ns) & (stamps + sim.scan_period_ns <= stop_end_ns)
    assert inside.sum() >= 38
    held = sim.ground_truth.T_world_lidar[inside]
    np.testing.assert_array_equal(held, np.broadcast_to(held[0], held.shape))


def test_random_speed_profile_varies_within_bounds_and_limits():
    route = RouteParams(
        cruise_speed_mps=9.0, random_speed_min_mps=3.0, speed_stretch_m=(30.0, 60.0), max_accel_mps2=1.5
    )
    motion = Simulation(_straight(route), seed=3).motion
    t = np.arange(0.0, motion.duration_s, 0.02)
    speed = _horizontal_speed(motion, t)
    accel = np.diff(speed) / 0.02
    assert speed.min() > route.min_speed_mps - 0.01 and speed.max() < route.cruise_speed_mps + 0.01
    assert accel.min() > -1.05 * route.max_decel_mps2 and accel.max() < 1.05 * route.max_accel_mps2
    cruising = speed[t[1:] > 8.0]
    assert cruising.max() - cruising.min() > 2.0  # not clipped to one cruise speed
    assert np.mean(np.abs(accel) < 0.02) < 0.3  # and hardly ever constant
    other = Simulation(_straight(route), seed=4).motion
    assert abs(other.duration_s - motion.duration_s) > 0.1  # the profile comes from the seed


def test_explicit_speed_targets_are_reached():
    route = RouteParams(cruise_speed_mps=8.0, speed_targets=((80.0, 4.0), (180.0, 7.0)), speed_transition_m=10.0)
    motion = VehicleMotion(((10.0, 0.0), (290.0, 0.0)), Simulation(_straight(route)).world.terrain, route)
    position = {}
    t = np.arange(0.0, motion.duration_s, 0.05)
    x = motion.pose_at(t)[:, 0, 3] - 10.0
    speed = np.linalg.norm(motion.velocity_at(t)[:, :2], axis=1)
    for where in (55.0, 150.0, 260.0):
        position[where] = float(speed[np.argmin(np.abs(x - where))])
    assert position[55.0] == pytest.approx(8.0, abs=0.05)  # the cruise speed before the first target
    assert position[150.0] == pytest.approx(4.0, abs=0.05)
    assert position[260.0] == pytest.approx(7.0, abs=0.05)


def test_vibration_has_the_requested_amplitude_in_the_5_to_20_hz_band():
    rough = RouteParams(cruise_speed_mps=6.0, vibration_deg=0.3, vibration_heave_m=0.0005)
    smooth = RouteParams(cruise_speed_mps=6.0)
    terrain = Simulation(_straight(smooth)).world.terrain
    nodes = ((10.0, 0.0), (290.0, 0.0))
    rate_hz = 1000.0
    t = np.arange(10.0, 40.0, 1.0 / rate_hz)  # at cruise speed
    base = VehicleMotion(nodes, terrain, smooth).pose_at(t)
    body = VehicleMotion(nodes, terrain, rough, seed=1).pose_at(t)
    relative = Rotation.from_matrix(np.einsum("nji,njk->nik", base[:, :3, :3], body[:, :3, :3])).as_rotvec()
    pitch, roll, yaw = relative.T  # about the vehicle x (right) and y (forward) axes
    assert np.rad2deg(np.sqrt(np.mean(pitch**2))) == pytest.approx(0.3, rel=0.15)
    assert np.rad2deg(np.sqrt(np.mean(roll**2))) == pytest.approx(0.3, rel=0.15)
    np.testing.assert_allclose(yaw, 0.0, atol=1e-6)
    heave = np.sum((body[:, :3, 3] - base[:, :3, 3]) * base[:, :3, 2], axis=1)
    assert np.sqrt(np.mean(heave**2)) == pytest.approx(0.0005, rel=0.15)
    np.testing.assert_allclose(body[:, :2, 3], base[:, :2, 3], atol=1e-12)  # heave is along the (vertical) normal
    pitch_rate = np.gradient(pitch, 1.0 / rate_hz)
    power = np.abs(np.fft.rfft(pitch_rate * np.hanning(len(t)))) ** 2
    frequency = np.fft.rfftfreq(len(t), 1.0 / rate_hz)
    in_band = (frequency >= 5.0) & (frequency <= 20.0)
    assert power[in_band].sum() / power.sum() > 0.99
    assert power[frequency < 4.0].sum() / power.sum() < 0.005


def test_route_params_validation():
    with pytest.raises(SimulationError, match="target speeds must lie in"):
        RouteParams(cruise_speed_mps=6.0, speed_targets=((50.0, 7.0),))
    with pytest.raises(SimulationError, match="not both"):
        RouteParams(speed_targets=((50.0, 4.0),), random_speed_min_mps=3.0)
    with pytest.raises(SimulationError, match="stops positions must be >= 0 and ascending"):
        RouteParams(stops=((80.0, 3.0), (40.0, 3.0)))
    with pytest.raises(SimulationError, match="stop holds must be positive"):
        RouteParams(stops=((80.0, 0.0),))
    with pytest.raises(SimulationError, match="vibration_band_hz"):
        RouteParams(vibration_band_hz=(20.0, 5.0))
    with pytest.raises(SimulationError, match="route stops must lie between 1 m and"):
        Simulation(_straight(RouteParams(stops=((500.0, 3.0),))))


# ---------------------------------------------------------------- sensor imperfections


def _wall_world(distance_m: float) -> World:
    """One vertical wall, the plane x = distance_m, facing the origin; no ground."""
    y, z = 200.0, 60.0
    vertices = np.array([[distance_m, -y, -z], [distance_m, y, -z], [distance_m, y, z], [distance_m, -y, z]])
    layout = StreetLayout(street_x_m=(0.0,), street_y_m=(0.0,))
    terrain = make_terrain(TerrainParams(max_slope_deg=0.0), (-10.0, 10.0, -10.0, 10.0), np.random.default_rng(0))
    return World(
        vertices_m=vertices,
        triangles=np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32),
        triangle_object_id=np.array([1, 1], dtype=np.int32),
        triangle_glass=np.zeros(2, dtype=bool),
        object_class=np.array([int(ObjectClass.GROUND), int(ObjectClass.WALL)], dtype=np.uint8),
        object_center_m=np.array([[0.0, 0.0, 0.0], [distance_m, 0.0, 0.0]]),
        block_kind=np.array([["urban"]]),
        terrain=terrain,
        layout=layout,
    )


def _cast_at_origin(lidar: LidarSimulator):
    n_columns = lidar.sensor.n_columns
    poses = np.broadcast_to(np.eye(4), (n_columns, 4, 4)).copy()
    simulated = lidar.cast(0, 0, poses, np.random.default_rng(0), np.eye(4))
    return simulated.scan, simulated.column


def test_elevation_error_casts_along_the_true_beam_and_reports_the_nominal_one():
    distance = 10.0
    sensor = sensor_model("vlp16")
    exact = LidarParams(range_noise_sigma_m=0.0, dropout_probability=0.0, max_incidence_deg=90.0)
    params = LidarParams(
        range_noise_sigma_m=0.0, dropout_probability=0.0, max_incidence_deg=90.0, elevation_error_sigma_deg=0.5
    )
    lidar = LidarSimulator(_wall_world(distance), sensor, params, seed=4)
    error = lidar.elevation_error_rad
    assert np.all(np.abs(error) > 0.0) and np.std(error) < np.deg2rad(1.5)
    scan, column = _cast_at_origin(lidar)
    ahead = np.abs(np.arctan2(scan.points[:, 1], scan.points[:, 0])) < np.deg2rad(10.0)
    points, ring, r = scan.points[ahead], scan.ring[ahead], scan.range_m[ahead]
    # The points carry the nominal elevations, as a driver with the stock table computes them ...
    nominal = np.arctan2(points[:, 2], np.linalg.norm(points[:, :2], axis=1))
    np.testing.assert_allclose(nominal, sensor.elevation_rad[ring], atol=1e-9)
    # ... while the ray went along the true beam and hit the wall there.
    true_hit = lidar.true_directions_lidar[column[ahead], ring] * r[:, None]
    np.testing.assert_allclose(true_hit[:, 0], distance, atol=2e-4)
    # So a point is off its true hit by the angle error at its range; up on the wall by about r tan(error).
    np.testing.assert_allclose(
        np.linalg.norm(true_hit - points, axis=1), 2.0 * r * np.sin(0.5 * np.abs(error[ring])), atol=2e-5
    )
    level = np.abs(sensor.elevation_rad[ring]) < np.deg2rad(4.0)
    np.testing.assert_allclose(
        (true_hit - points)[level, 2], r[level] * np.tan(error[ring[level]]), rtol=0.01, atol=1e-4
    )
    # Without the error the same beams land where the points say.
    plain, _ = _cast_at_origin(LidarSimulator(_wall_world(distance), sensor, exact, seed=4))
    front = np.abs(np.arctan2(plain.points[:, 1], plain.points[:, 0])) < np.deg2rad(10.0)
    np.testing.assert_allclose(plain.points[front, 0], distance, atol=2e-4)


def test_range_bias_shifts_each_lasers_ranges():
    distance = 12.0
    sensor = sensor_model("vlp16")
    params = LidarParams(range_noise_sigma_m=0.0, dropout_probability=0.0, range_bias_sigma_m=0.004)
    lidar = LidarSimulator(_wall_world(distance), sensor, params, seed=9)
    bias = lidar.range_bias_m
    assert 0.001 < np.std(bias) < 0.008 and np.all(bias != 0.0)
    scan, column = _cast_at_origin(lidar)
    expected = distance / lidar.directions_lidar[column, scan.ring, 0]  # nominal beam to the plane x = d
    ahead = lidar.directions_lidar[column, scan.ring, 0] > 0.5
    np.testing.assert_allclose((scan.range_m - expected)[ahead], bias[scan.ring[ahead]], atol=3e-5)


def test_sweep_end_stamps_mark_the_last_point_and_ground_truth_follows():
    start = Simulation("loop", duration_s=1.0)
    end = Simulation("loop", duration_s=1.0, lidar=LidarParams(stamp=StampMode.SWEEP_END))
    period = start.sensor.sweep_period_s
    last_column_s = (start.sensor.n_columns - 1) * period / start.sensor.n_columns
    np.testing.assert_array_equal(end.stamps_ns - start.stamps_ns, round(last_column_s * 1e9))
    np.testing.assert_array_equal(end.sweep_start_ns, start.sweep_start_ns)
    for index in (0, 6):
        a, b = start.scan(index), end.scan(index)
        assert b.scan.stamp_ns == end.stamps_ns[index]
        assert b.scan.time_offset_s.max() == 0.0  # the stamp is the last point's time
        assert b.scan.time_offset_s.min() >= -period
        np.testing.assert_array_equal(b.scan.points, a.scan.points)  # the same sweep, stamped differently
        point_ns = b.scan.stamp_ns + np.rint(b.scan.time_offset_s * 1e9)
        np.testing.assert_allclose(point_ns, a.scan.stamp_ns + np.rint(a.scan.time_offset_s * 1e9), atol=1.0)
        np.testing.assert_allclose(b.T_world_lidar, end.ground_truth.T_world_lidar[index], rtol=0.0, atol=1e-12)
    np.testing.assert_allclose(
        end.ground_truth.T_world_lidar, start.T_world_lidar_at(end.stamps_ns), rtol=0.0, atol=1e-12
    )
    np.testing.assert_array_equal(end.ground_truth.stamps_ns, end.stamps_ns)


def test_stamp_jitter_moves_the_stamp_not_the_point_times(tmp_path):
    params = LidarParams(stamp_jitter_s=0.001)
    sim = Simulation("loop", duration_s=3.0, lidar=params)
    jitter_s = (sim.stamps_ns - sim.sweep_start_ns) * 1e-9
    assert np.abs(jitter_s).max() <= 0.001 and 0.0004 < jitter_s.std() < 0.0008
    np.testing.assert_array_equal(sim.ground_truth.stamps_ns, sim.stamps_ns)
    scan = sim.scan(4)
    assert scan.scan.stamp_ns == sim.stamps_ns[4]
    np.testing.assert_array_equal(np.unique(scan.scan.time_offset_s), sim.lidar.column_time_s[np.unique(scan.column)])
    # The route starts a jitter earlier, so that every stamp lies within it; the truth is at the stamp.
    np.testing.assert_allclose(sim.ground_truth.T_world_lidar[4], scan.T_world_lidar, rtol=0.0, atol=1e-12)
    metadata_path = simulate("loop", tmp_path / "sim", duration_s=0.3, lidar=params).metadata
    stamps = json.loads(metadata_path.read_text())["stamps"]
    assert stamps["mode"] == "sweep_start" and stamps["jitter_s"] == 0.001


def test_lost_packets_leave_one_wedge_empty():
    clean = Simulation("loop", duration_s=0.5, lidar=LidarParams(dropout_probability=0.0))
    lossy = Simulation(
        "loop", duration_s=0.5, lidar=LidarParams(dropout_probability=0.0, dropped_wedge_probability=1.0)
    )
    n_columns = clean.sensor.n_columns
    for index in (1, 3):
        a, b = clean.scan(index), lossy.scan(index)
        lost = set(np.setdiff1d(np.unique(a.column), np.unique(b.column)).tolist())
        width = round(4.8 / 360.0 * n_columns)
        assert len(lost) == width
        assert any(lost == {(c + k) % n_columns for k in range(width)} for c in lost)  # consecutive columns
        lost = np.array(sorted(lost))
        kept = ~np.isin(a.column, lost)
        np.testing.assert_array_equal(b.scan.points, a.scan.points[kept])


def test_lidar_params_validation():
    with pytest.raises(SimulationError, match="stamp_jitter_s in"):
        LidarParams(stamp_jitter_s=0.5)
    with pytest.raises(SimulationError, match="dropped_wedge_probability"):
        LidarParams(dropped_wedge_probability=1.5)
    with pytest.raises(SimulationError, match="lidar stamp must be one of: sweep_start, sweep_end"):
        LidarParams(stamp="sweep_middle")


# ---------------------------------------------------------------- the defaults keep the old drives


def test_default_parameters_reproduce_the_old_simulation():
    """Values recorded from the simulator before dynamics and imperfections existed (seed 0)."""
    recorded = {
        "loop": (69.06330003505408, 422.24939987131745, [121.5131220507561, 48.64520002192836, 0.7118157757878171]),
        "long": (186.66993450238743, 1355.651092106103, [419.77095152424596, 76.07047964865214, 0.8356256221398295]),
        "hilly": (84.72602125097168, 492.2493998713176, [141.50094319913228, 62.331116195450576, -2.0730821979456437]),
        "fast": (77.66423240396763, 673.9547760803155, [132.4218319846857, 71.4963932968102, 0.6109523162898661]),
    }
    for name, (duration_s, length_m, third) in recorded.items():
        motion = Simulation(name).motion
        assert motion.duration_s == pytest.approx(duration_s, rel=1e-13)
        assert motion.length_m == pytest.approx(length_m, rel=1e-13)
        at = 0.01 * (int(np.ceil(duration_s / 0.01)) // 3)
        np.testing.assert_allclose(motion.pose_at([at])[0, :3, 3], third, rtol=0, atol=1e-9)
    sim = Simulation("loop", duration_s=3.0)
    scan = sim.scan(5).scan
    assert len(scan) == 27269
    # 1e-6, not closer: ray casting differs in the last bits between library builds (2e-8 seen).
    np.testing.assert_allclose(
        scan.points.sum(axis=0), [-12424.37866424915, 27495.9515537361, 14169.772319129794], rtol=1e-6
    )
    assert float(scan.intensity.sum()) == 731591.0
    np.testing.assert_allclose(
        sim.ground_truth.T_world_lidar[-1, :3, 3],
        [41.178053266127165, -1.4884649072265632, 2.2440042608789303],
        rtol=0,
        atol=1e-9,
    )
    np.testing.assert_array_equal(sim.stamps_ns, sim.sweep_start_ns)
    assert sim.lidar.time_reference_s == 0.0 and np.all(sim.lidar.range_bias_m == 0.0)
