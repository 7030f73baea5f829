"""Procedural worlds: determinism, object classes, street clearance, slopes, the feature-poor stretch."""

import numpy as np
import pytest

from lidar3d.errors import SimulationError
from lidar3d.sim import DYNAMIC_CLASSES, SCENARIOS, ObjectClass, StreetLayout, WorldParams, get_scenario
from lidar3d.sim.terrain import TerrainParams
from lidar3d.sim.world import generate_world


def _world(name, seed=0):
    scenario = get_scenario(name)
    return generate_world(scenario.layout, scenario.world, seed)


def test_same_seed_same_world_other_seed_other_world():
    a, b, c = _world("loop", 3), _world("loop", 3), _world("loop", 4)
    np.testing.assert_array_equal(a.vertices_m, b.vertices_m)
    np.testing.assert_array_equal(a.triangles, b.triangles)
    np.testing.assert_array_equal(a.triangle_object_id, b.triangle_object_id)
    assert a.vertices_m.shape != c.vertices_m.shape or not np.array_equal(a.vertices_m, c.vertices_m)


def test_world_holds_every_object_class_and_consistent_ids():
    world = _world("long")
    assert set(world.object_class.tolist()) == {int(c) for c in ObjectClass if c not in DYNAMIC_CLASSES}
    assert world.object_class[0] == ObjectClass.GROUND
    ids = np.unique(world.triangle_object_id)
    np.testing.assert_array_equal(ids, np.arange(world.n_objects + 1))  # every object has triangles
    assert world.triangles.min() >= 0 and world.triangles.max() < len(world.vertices_m)


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_nothing_low_stands_in_a_street(name):
    """Below 3 m above the ground, object vertices keep clear of every street's driven lanes.

    Objects are convex parts lying within one block, so their vertices bound them."""
    world = _world(name)
    vertices = world.vertices_m[np.unique(world.triangles[world.triangle_object_id > 0])]
    above = vertices[:, 2] - world.terrain.height_m(vertices[:, 0], vertices[:, 1])
    low = vertices[above < 3.0]
    distance = world.layout.distance_to_street_m(low[:, 0], low[:, 1])
    assert distance.min() > 2.6  # lane centre 1.5 m + half a car width


def test_terrain_slopes():
    hilly, loop = _world("hilly"), _world("loop")
    x0, x1, y0, y1 = hilly.terrain.extent_m
    xx, yy = np.meshgrid(np.linspace(x0, x1, 200), np.linspace(y0, y1, 200))
    slope = np.rad2deg(np.arctan(np.linalg.norm(hilly.terrain.gradient(xx, yy), axis=-1)))
    assert 6.0 < slope.max() <= 8.01
    slope = np.rad2deg(np.arctan(np.linalg.norm(loop.terrain.gradient(xx, yy), axis=-1)))
    assert slope.max() <= 1.51
    flat_params = WorldParams(terrain=TerrainParams(max_slope_deg=0.0))
    flat = generate_world(StreetLayout((0.0, 50.0), (0.0, 50.0)), flat_params, 0)
    assert np.all(flat.terrain.height_m(xx, yy) == 0.0)


def test_long_scenario_has_a_feature_poor_stretch():
    world = _world("long")
    centers = world.object_center_m[1:]
    classes = world.object_class[1:]
    in_open = (centers[:, 0] > 200.0) & (centers[:, 0] < 400.0) & (np.abs(centers[:, 1]) < 40.0)
    assert set(classes[in_open].tolist()) <= {int(ObjectClass.POLE)}
    assert in_open.sum() <= 8
    in_town = (centers[:, 0] > 0.0) & (centers[:, 0] < 180.0) & (np.abs(centers[:, 1]) < 40.0)
    assert in_town.sum() > 40


def test_layout_validation():
    with pytest.raises(SimulationError, match="strictly ascending"):
        StreetLayout((10.0, 0.0), (0.0,))
    with pytest.raises(SimulationError, match="outside the grid"):
        StreetLayout((0.0,), (0.0,), block_kinds=((5, 0, "open"),))
    with pytest.raises(ValueError):
        StreetLayout((0.0,), (0.0,), block_kinds=((0, 0, "swamp"),))
