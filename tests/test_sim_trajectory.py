"""Vehicle motion: speeds, smoothness, terrain contact and attitude, revisits, scenario validation."""

import numpy as np
import pytest

from lidar3d.errors import SimulationError
from lidar3d.sim import SCENARIOS, RouteParams, Scenario, Simulation, StreetLayout
from lidar3d.sim.trajectory import group_revisits

# (length range in m, minimum number of revisit events)
EXPECTED = {"loop": ((380, 440), 1), "long": ((1200, 1500), 2), "hilly": ((450, 550), 1), "fast": ((620, 720), 1)}


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_route_length_speed_and_revisits(name):
    sim = Simulation(name)  # no ray casting happens here
    (lo, hi), n_events = EXPECTED[name]
    assert lo < sim.motion.length_m < hi
    t = np.arange(0.0, sim.motion.duration_s, 0.05)
    speed = np.linalg.norm(sim.motion.velocity_at(t), axis=1)
    assert speed.min() > 1.95 and speed.max() < 10.05
    assert speed.max() > 0.95 * sim.scenario.route.cruise_speed_mps
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
    with pytest.raises(SimulationError, match="unknown scenario 'nope'; known: loop, long, hilly, fast"):
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
