"""Vehicle motion: speeds, smoothness, terrain contact and attitude, revisits, scenario validation."""

import numpy as np
import pytest

from lidar3d.errors import SimulationError
from lidar3d.sim import SCENARIOS, RouteParams, Scenario, Simulation, StreetLayout
from lidar3d.sim.trajectory import group_revisits

# (length range in m, minimum number of revisit events)
EXPECTED = {
    "loop": ((380, 440), 1),
    "long": ((1200, 1500), 2),
    "hilly": ((450, 550), 1),
    "fast": ((620, 720), 1),
    "stops": ((380, 440), 1),
    "blind_turn": ((480, 560), 0),
    "figure_eight": ((700, 820), 2),  # the crossing of the eight and the start
    "city_traffic": ((480, 560), 1),
    "forest_trail": ((470, 540), 1),
}


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_route_length_speed_and_revisits(name):
    sim = Simulation(name)  # no ray casting happens here
    (lo, hi), n_events = EXPECTED[name]
    assert lo < sim.motion.length_m < hi
    t = np.arange(0.0, sim.motion.duration_s, 0.05)
    speed = np.linalg.norm(sim.motion.velocity_at(t)[:, :2], axis=1)  # horizontal: without the body's heave
    route = sim.scenario.route
    floor = 0.0 if route.stops else route.min_speed_mps
    assert speed.min() > floor - 0.05 and speed.max() < route.cruise_speed_mps + 0.05
    assert speed.max() > (0.85 if route.random_speed_min_mps else 0.95) * route.cruise_speed_mps
    events = group_revisits(sim.revisits())
    assert len(events) >= n_events
    for event in events:
        assert all(p.query_stamp_ns - p.match_stamp_ns >= 30e9 for p in event)
        assert min(p.distance_m for p in event) < 3.5


def test_long_has_opposite_direction_revisits():
    events = group_revisits(Simulation("long").revisits())
    median_turn = [np.median([p.heading_change_deg for p in e]) for e in events]
    assert sum(m > 150 for m in median_turn) >= 2
    assert sum(m < 30 for m in median_turn) >= 1


def test_stops_scenario_brakes_stands_and_varies_its_speed():
    sim = Simulation("stops")
    holds = [end - start for start, end in sim.motion.stop_intervals_s]
    assert len(holds) == 3 and min(holds) >= 3.0 and max(holds) <= 6.0
    t = np.arange(0.0, sim.motion.duration_s, 0.05)
    speed = np.linalg.norm(sim.motion.velocity_at(t)[:, :2], axis=1)
    moving = speed[speed > 0.5]
    assert moving.max() > 8.0 and np.percentile(moving, 10) < 4.0
    for start, end in sim.motion.stop_intervals_s:
        during = (t > start) & (t < end)
        np.testing.assert_array_equal(sim.motion.velocity_at(t[during]), 0.0)
    lidar = sim.lidar_params
    assert lidar.elevation_error_sigma_deg > 0 and lidar.range_bias_sigma_m > 0 and lidar.stamp_jitter_s > 0
    assert sim.scenario.route.vibrates


def test_blind_turn_comes_at_the_end_of_open_land():
    sim = Simulation("blind_turn")
    layout, kinds = sim.scenario.layout, sim.world.block_kind
    assert all(kinds[i, j] == "open" for i in (2, 3) for j in (0, 1))  # around the approach and the corner
    assert layout.street_x_m[2] - layout.street_x_m[1] == 240.0
    t = np.arange(0.0, sim.motion.duration_s, 0.05)
    poses = sim.motion.pose_at(t)
    yaw_rate = np.rad2deg(np.gradient(np.unwrap(np.arctan2(poses[:, 1, 1], poses[:, 0, 1])), t))
    corner = (poses[:, 0, 3] > 340.0) & (poses[:, 1, 3] < 20.0)  # the first turn, on open land
    assert yaw_rate[corner].max() > 25.0 and np.sum(yaw_rate[corner] > 15.0) * 0.05 > 2.5
    approach = (poses[:, 0, 3] > 130.0) & (poses[:, 0, 3] < 340.0) & (poses[:, 1, 3] < 0.0)
    speed = np.linalg.norm(sim.motion.velocity_at(t[approach])[:, :2], axis=1)
    assert speed.max() - speed.min() > 1.5  # a varying speed across the field


def test_vehicle_stands_on_the_terrain_with_slope_attitude():
    sim = Simulation("hilly")
    t = np.linspace(0.0, sim.motion.duration_s, 2000)
    poses = sim.motion.pose_at(t)
    R = poses[:, :3, :3]
    np.testing.assert_allclose(np.einsum("nji,njk->nik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    up = R[:, :, 2]
    ground = poses[:, :3, 3] - sim.scenario.route.imu_height_m * up
    np.testing.assert_allclose(ground[:, 2], sim.world.terrain.height_m(ground[:, 0], ground[:, 1]), atol=1e-9)
    np.testing.assert_allclose(up, sim.world.terrain.normal(ground[:, 0], ground[:, 1]), atol=1e-9)
    velocity = sim.motion.velocity_at(t)
    forward = R[:, :, 1]  # SPAN vehicle y axis
    heading_cos = np.sum(forward * velocity, axis=1) / np.linalg.norm(velocity, axis=1)
    assert heading_cos.min() > 0.999
    pitch = np.rad2deg(np.arcsin(forward[:, 2]))
    roll = np.rad2deg(np.arcsin(R[:, 2, 0]))
    assert np.abs(pitch).max() > 4.0 and np.abs(roll).max() > 2.0
    assert np.abs(pitch).max() < 8.1 and np.abs(roll).max() < 8.1


def test_motion_is_smooth_and_turns_are_sharp_in_fast():
    sim = Simulation("fast")
    dt = 0.01
    t = np.arange(0.0, sim.motion.duration_s, dt)
    R = sim.motion.pose_at(t)[:, :3, :3]
    step = np.arccos(np.clip((np.einsum("nij,nij->n", R[1:], R[:-1]) - 1.0) / 2.0, -1.0, 1.0))
    yaw_rate_deg_s = np.rad2deg(step) / dt
    assert yaw_rate_deg_s.max() < 90.0  # no jumps
    assert yaw_rate_deg_s.max() > 35.0  # but sharp corners
    speed = np.linalg.norm(np.diff(sim.motion.pose_at(t)[:, :3, 3], axis=0), axis=1) / dt
    assert np.abs(np.diff(speed)).max() / dt < 6.0  # bounded acceleration (limits 2.5 / 3.5 m/s^2 plus interpolation)


def test_duration_and_lookup_errors():
    sim = Simulation("loop", duration_s=2.05)
    assert len(sim) == 20
    np.testing.assert_array_equal(np.diff(sim.stamps_ns), 100_000_000)
    with pytest.raises(SimulationError, match=r"lasts .* s; duration must be in"):
        Simulation("loop", duration_s=10_000.0)
    with pytest.raises(SimulationError, match="shorter than one sweep"):
        Simulation("loop", duration_s=0.05)
    with pytest.raises(
        SimulationError,
        match="unknown scenario 'nope'; known: loop, long, hilly, fast, stops, blind_turn, figure_eight, "
        "city_traffic, forest_trail",
    ):
        Simulation("nope")
    with pytest.raises(SimulationError, match="unknown sensor model 'vlp64'"):
        Simulation("loop", sensor="vlp64")
    with pytest.raises(SimulationError, match="out of range"):
        sim.scan(20)


def test_route_validation_errors():
    layout = StreetLayout((0.0, 100.0), (0.0, 100.0))
    with pytest.raises(SimulationError, match="does not follow a street"):
        Scenario("bad", "", layout, ((0.0, 0.0), (100.0, 100.0)))
    corner = ((0.0, 0.0), (100.0, 0.0), (100.0, 100.0))
    short = Scenario("short", "", layout, corner, RouteParams(corner_radius_m=150.0))
    with pytest.raises(SimulationError, match="too short for corner radius"):
        Simulation(short)
    with pytest.raises(SimulationError, match="U-turns"):
        Simulation(Scenario("u", "", layout, ((0.0, 0.0), (100.0, 0.0), (50.0, 0.0))))
    with pytest.raises(SimulationError, match="min_speed_mps"):
        RouteParams(min_speed_mps=5.0, cruise_speed_mps=3.0)
