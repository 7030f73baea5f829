"""Moving actors, glass, foliage, corridor walls and the scenarios built on them (lidar3d.sim)."""

import dataclasses
import hashlib

import numpy as np
import open3d as o3d
import pytest

from lidar3d.errors import SimulationError
from lidar3d.sim import (
    LidarParams,
    ObjectClass,
    RouteParams,
    Scenario,
    Simulation,
    StreetLayout,
    TrafficParams,
    WorldParams,
    get_scenario,
)
from lidar3d.sim.world import generate_world

NEW_SCENARIOS = ("figure_eight", "city_traffic", "forest_trail")

# Digest of the world, the motion, the ground truth and one ray-cast scan (seed 0, the first second) of
# every scenario that existed before the actors, materials and corridors: they must not change.
# What the old scenarios simulate, seed 0, first second: a digest of the integer arrays (triangles,
# object ids and classes, stamps, rings, columns) and, per float array (vertices, ground truth,
# motion, scan 3's points, intensities and point times), the sum of absolute values. Floats are
# compared to 1e-6 relative, not byte for byte: Open3D's ray casting and NumPy builds differ in
# the last bits (2e-8 relative between two installs of the same code, 2026-12-02), while moving one
# point of a scan by a metre changes its sum by about 1.5e-6, and a changed world, route or sensor
# model by far more.
OLD_SCENARIO_FINGERPRINTS = {
    "blind_turn": ("cd073e901daf43df", [6484815.094675, 289.630149, 48290.221153, 707125.17534, 440599.0, 1026.505167]),
    "fast": ("c1ddff984d79d7bd", [5518338.375898, 494.135233, 26552.829871, 696524.31873, 565286.0, 1336.260278]),
    "hilly": ("19e352864f5e526b", [3251779.002005, 508.579155, 23341.834968, 719185.885422, 478493.0, 1094.888944]),
    "long": ("4d50a28fd53f7750", [9656423.170712, 391.107881, 46377.343151, 646956.911925, 704324.0, 1369.470278]),
    "loop": ("b10b893c3b33164d", [2382997.548651, 391.107881, 20215.222273, 594747.786708, 728779.0, 1370.060167]),
    "stops": ("c849671faedfbdc0", [2694129.379333, 290.089453, 19813.14033, 677775.153874, 335207.0, 953.801167]),
}


def _scene(vertices, triangles):
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.ascontiguousarray(vertices, dtype=np.float32)),
        o3d.core.Tensor(np.ascontiguousarray(triangles, dtype=np.uint32)),
    )
    return scene


def _world_points(sim, simulated):
    """(N, 3) world positions of a scan's points, each from the true lidar pose at its firing time."""
    t_route = sim.route_seconds(sim.sweep_start_ns[simulated.index])[0] + sim.lidar.column_time_s[simulated.column]
    poses = sim.motion.pose_at(t_route) @ sim.T_imu_lidar
    return np.einsum("nij,nj->ni", poses[:, :3, :3], simulated.scan.points) + poses[:, :3, 3], t_route


@pytest.mark.parametrize("name", sorted(OLD_SCENARIO_FINGERPRINTS))
def test_old_scenarios_are_unchanged(name):
    sim = Simulation(name, seed=0, duration_s=1.0)
    assert sim.traffic is None and not sim.world.triangle_glass.any()
    world = sim.world
    motion = sim.motion.pose_at(np.linspace(0.0, sim.motion.duration_s, 200))
    s = sim.scan(3)
    digest = hashlib.sha256()
    for array in (world.triangles, world.triangle_object_id, world.object_class, sim.stamps_ns):
        digest.update(np.ascontiguousarray(array).tobytes())
    for array in (s.scan.ring, s.object_id, s.object_class, s.column):
        digest.update(np.ascontiguousarray(array).tobytes())
    floats = (
        world.vertices_m,
        sim.ground_truth.T_world_lidar,
        motion,
        s.scan.points,
        s.scan.intensity,
        s.scan.time_offset_s,
    )
    recorded_digest, recorded_sums = OLD_SCENARIO_FINGERPRINTS[name]
    assert digest.hexdigest()[:16] == recorded_digest
    sums = [float(np.abs(np.asarray(array, np.float64)).sum()) for array in floats]
    np.testing.assert_allclose(sums, recorded_sums, rtol=1e-6)
    assert not s.dynamic_mask.any()


@pytest.fixture(scope="module")
def city():
    """city_traffic without range noise, calibration error or jitter: points lie exactly on surfaces."""
    return Simulation("city_traffic", seed=0, lidar=LidarParams(range_noise_sigma_m=0.0))


def test_points_labelled_dynamic_lie_on_their_posed_actor(city):
    traffic = city.traffic
    assert traffic is not None
    classes = {int(a.object_class) for a in traffic.actors}
    assert classes == {int(ObjectClass.MOVING_CAR), int(ObjectClass.PEDESTRIAN)}
    actors = {a.object_id: a for a in traffic.actors}
    n_checked = 0
    for index in (0, 240, 700):
        simulated = city.scan(index)
        world, t_route = _world_points(city, simulated)
        dynamic = simulated.dynamic_mask
        assert set(simulated.object_id[dynamic].tolist()) <= set(actors)
        assert not np.isin(simulated.object_id[~dynamic], list(actors)).any()
        for object_id in np.unique(simulated.object_id[dynamic]):
            actor = actors[int(object_id)]
            mine = np.flatnonzero(simulated.object_id == object_id)
            assert np.all(simulated.object_class[mine] == int(actor.object_class))
            position, yaw, active = traffic.pose_at(actor, t_route[mine])
            assert active.all()
            offset = world[mine] - position
            c, s = np.cos(yaw), np.sin(yaw)
            local = np.column_stack(
                [c * offset[:, 0] + s * offset[:, 1], -s * offset[:, 0] + c * offset[:, 1], offset[:, 2]]
            )
            # Distance outside the nearest box of the actor (0 inside): every point on a face, none astray.
            outside = [
                np.linalg.norm(np.maximum(np.abs(local - center) - 0.5 * size, 0.0), axis=1)
                for center, size in zip(actor.part_center_m, actor.part_size_m)
            ]
            inside_depth = [
                np.min(0.5 * size - np.abs(local - center), axis=1)
                for center, size in zip(actor.part_center_m, actor.part_size_m)
            ]
            assert np.min(outside, axis=0).max() < 0.005
            assert np.max(inside_depth, axis=0).max() < 0.005  # on the surface, not inside
            n_checked += len(mine)
    assert n_checked > 300


def test_actors_keep_clear_of_the_vehicle(city):
    t = np.arange(0.0, city.motion.duration_s, 0.05)
    ego = city.motion.pose_at(t)
    forward = ego[:, :2, 1]
    for actor in city.traffic.actors:
        position, _, active = city.traffic.pose_at(actor, t)
        offset = (position[:, :2] - ego[:, :2, 3])[active]
        along = np.abs(np.sum(offset * forward[active], axis=1))
        across = np.abs(offset[:, 0] * forward[active, 1] - offset[:, 1] * forward[active, 0])
        assert not np.any((along < 4.0) & (across < 1.8)), actor


def test_lead_car_pulls_away_and_follower_stays_behind(city):
    t = np.arange(0.0, city.motion.duration_s, 0.1)
    ego = city.motion.path_position_at(t)
    lead, follower = (
        a for a in city.traffic.actors if a.object_class == ObjectClass.MOVING_CAR and a.knot_right_m[0] == 0
    )
    gap_lead = np.interp(t, lead.knot_time_s, lead.knot_position_m) - ego
    gap_follower = ego - np.interp(t, follower.knot_time_s, follower.knot_position_m)
    assert gap_lead.min() >= 13.0 and np.all(np.diff(gap_lead[t < lead.active_s[1]]) >= -1e-9)
    assert gap_follower.min() >= 8.9


def test_glass_facades_return_nothing():
    layout = StreetLayout((0.0, 140.0), (0.0,), block_kinds=((1, 0, "urban"), (1, 1, "urban")))
    plain = Scenario("glassless", "", layout, ((20.0, 0.0), (120.0, 0.0)))
    glassy = dataclasses.replace(plain, name="glassy", world=WorldParams(glass_facade_probability=1.0))
    scans = {}
    for scenario in (plain, glassy):
        sim = Simulation(scenario, seed=1, duration_s=0.5, lidar=LidarParams(range_noise_sigma_m=0.0))
        scans[scenario.name] = (sim, [sim.scan(i) for i in range(0, 5, 2)])
    world = scans["glassy"][0].world
    np.testing.assert_array_equal(world.vertices_m, scans["glassless"][0].world.vertices_m)
    assert world.triangle_glass.sum() >= 2 * len(world.object_ids_of(ObjectClass.BUILDING))
    scene = _scene(world.vertices_m, world.triangles)
    on_glass = {}
    for name, (sim, simulated) in scans.items():
        points = np.vstack([_world_points(sim, s)[0] for s in simulated])
        closest = scene.compute_closest_points(o3d.core.Tensor(points.astype(np.float32)))
        on_glass[name] = int(world.triangle_glass[closest["primitive_ids"].numpy()].sum())
    assert on_glass["glassless"] > 1000  # the facades are in view ...
    assert on_glass["glassy"] == 0  # ... and glass gives no point
    assert sum(len(s.scan) for s in scans["glassy"][1]) < sum(len(s.scan) for s in scans["glassless"][1]) - 1000


def test_foliage_lets_a_fraction_of_rays_through():
    scenario = get_scenario("forest_trail")
    leafy = generate_world(scenario.layout, scenario.world, 0)
    solid = generate_world(scenario.layout, dataclasses.replace(scenario.world, foliage=False), 0)
    np.testing.assert_array_equal(leafy.object_class, solid.object_class)  # the same trees, other crowns
    fractions = {}
    for name, world in (("leafy", leafy), ("solid", solid)):
        passed = []
        for object_id in world.object_ids_of(ObjectClass.TREE)[:12]:
            triangles = world.triangles[world.triangle_object_id == object_id][40:]  # after the trunk's 40
            vertices = world.vertices_m[np.unique(triangles)]
            low, high = vertices.min(axis=0), vertices.max(axis=0)
            center, half = 0.5 * (low + high), 0.5 * (high - low)
            grid = np.linspace(-0.5, 0.5, 11)
            yy, zz = np.meshgrid(grid * half[1], grid * half[2])
            origins = np.column_stack([np.full(yy.size, low[0] - 5.0), center[1] + yy.ravel(), center[2] + zz.ravel()])
            rays = np.hstack([origins, np.tile([1.0, 0.0, 0.0], (len(origins), 1))])
            t_hit = _scene(world.vertices_m, triangles).cast_rays(o3d.core.Tensor(rays.astype(np.float32)))["t_hit"]
            passed.append(np.mean(~np.isfinite(t_hit.numpy())))
        fractions[name] = float(np.mean(passed))
    assert fractions["solid"] == 0.0
    assert 0.1 < fractions["leafy"] < 0.8


def test_corridor_walls_line_the_canyon():
    world = generate_world(get_scenario("city_traffic").layout, get_scenario("city_traffic").world, 0)
    walls = []
    for object_id in world.object_ids_of(ObjectClass.WALL):
        vertices = world.vertices_m[np.unique(world.triangles[world.triangle_object_id == object_id])]
        extent = vertices.max(axis=0) - vertices.min(axis=0)
        if extent[0] > 150.0:
            walls.append((vertices, (world.triangle_object_id == object_id).sum()))
    assert len(walls) == 2
    faces = sorted(float(np.abs(v[:, 1] - 60.0).min()) * np.sign(v[:, 1].mean() - 60.0) for v, _ in walls)
    np.testing.assert_allclose(faces, [-8.0, 8.0], atol=1e-6)  # both faces 8 m from the centre line
    for vertices, n_triangles in walls:
        assert n_triangles == 12  # one plain box: featureless
        assert 159.0 < np.ptp(vertices[:, 0]) < 161.0 and np.ptp(vertices[:, 2]) > 10.0
    # Nothing else stands between the walls along the canyon.
    used = np.unique(world.triangles[world.triangle_object_id > 0])
    vertices = world.vertices_m[used]
    between = (vertices[:, 0] > 20.0) & (vertices[:, 0] < 166.0) & (np.abs(vertices[:, 1] - 60.0) < 7.9)
    assert not between.any()


@pytest.mark.parametrize("name", NEW_SCENARIOS)
def test_new_scenarios_simulate(name):
    sim = Simulation(name, seed=1, duration_s=2.0)
    simulated = sim.scan(5)
    assert len(simulated.scan) > 10_000
    assert simulated.dynamic_mask.dtype == bool and simulated.dynamic_mask.shape == (len(simulated.scan),)


def test_figure_eight_turns_sharply_where_the_open_field_ends():
    sim = Simulation("figure_eight")
    t = np.arange(0.0, sim.motion.duration_s, 0.05)
    poses = sim.motion.pose_at(t)
    heading = np.unwrap(np.arctan2(poses[:, 1, 1], poses[:, 0, 1]))
    yaw_rate = np.rad2deg(np.gradient(heading, t))
    x, y = poses[:, 0, 3], poses[:, 1, 3]
    at_turn = (x > 265.0) & (y > 105.0)  # the corner at the end of the field (280, 120)
    assert -36.0 < yaw_rate[at_turn].min() < -26.0  # a right turn of about 30 deg/s ...
    assert 2.5 < np.sum(yaw_rate[at_turn] < -20.0) * 0.05 < 3.8  # ... lasting about 3 s
    on_field = (x > 100.0) & (x < 260.0) & (y > 110.0)
    objects = sim.world.object_center_m[1:]
    in_field = (objects[:, 0] > 93.0) & (objects[:, 0] < 267.0) & (np.abs(objects[:, 1] - 120.0) < 50.0)
    assert np.sum(in_field) <= 6 and on_field.sum() * 0.05 > 20.0
    speed = np.linalg.norm(sim.motion.velocity_at(t)[:, :2], axis=1)
    after = (t > t[at_turn].max() + 20.0) & (t < t[-1] - 10.0)
    straight = after & (np.abs(yaw_rate) < 1.0)
    assert speed[straight].min() > 4.5 and speed[straight].max() < 5.1


def test_city_traffic_canyon_speeds():
    sim = Simulation("city_traffic")
    t = np.arange(0.0, sim.motion.duration_s, 0.05)
    poses = sim.motion.pose_at(t)
    speed = np.linalg.norm(sim.motion.velocity_at(t)[:, :2], axis=1)
    in_canyon = (np.abs(poses[:, 1, 3] - 60.0) < 3.0) & (poses[:, 0, 3] > 13.0) & (poses[:, 0, 3] < 173.0)
    assert 150.0 < np.sum(speed[in_canyon] * 0.05) < 170.0
    canyon_speed = speed[in_canyon]
    assert canyon_speed[:20].mean() < 4.9 and canyon_speed.max() > 6.2 and 5.2 < canyon_speed[-20:].mean() < 5.6
    assert len(sim.motion.stop_intervals_s) == 1 and sim.revisits()


def test_forest_trail_vibrates_a_few_tenths_of_a_degree():
    sim = Simulation("forest_trail")
    route = sim.scenario.route
    assert route.vibration_deg >= 0.2 and route.vibration_band_hz == (5.0, 20.0)
    assert sim.scenario.world.foliage and sim.traffic is not None


def test_validation_of_the_new_options():
    with pytest.raises(SimulationError, match="traffic counts"):
        TrafficParams(oncoming_cars=-1)
    with pytest.raises(SimulationError, match="glass_facade_probability"):
        WorldParams(glass_facade_probability=1.5)
    with pytest.raises(SimulationError, match="wall_edges: side"):
        StreetLayout((0.0,), (0.0,), wall_edges=((0, 0, "up"),))
    with pytest.raises(SimulationError, match="wall_edges: cell"):
        StreetLayout((0.0,), (0.0,), wall_edges=((4, 0, "north"),))
    with pytest.raises(SimulationError, match="acceleration limits"):
        RouteParams(max_accel_mps2=0.0)
