"""Procedural outdoor worlds as one triangle mesh with a per-triangle object id.

A world is a grid of streets (every grid line is a street crossing the whole world) and the blocks
between them. Each block has a kind that decides what lines its street edges: ``urban`` (buildings of
varied footprints and heights close to the street), ``residential`` (gabled houses set back behind
fences or walls, trees in the yards), ``park`` (trees, low walls), ``open`` (bare ground and a pole
every ~90 m: the feature-poor stretch) or ``forest`` (trees close to the street and dense inside, no
poles or cars; never drawn at random). Every edge except open ones also gets lamp poles, street
trees and parked cars. Nothing is placed inside a street corridor, so the vehicle routes, which
follow the streets, never drive through an object.

Options, all off by default (a world without them is exactly the world this module always made):
``StreetLayout.wall_edges`` replaces chosen street edges with one long featureless wall (two facing
walls make a corridor street, a degenerate geometry along the street); ``WorldParams.glass_facade_probability``
makes the street facade of that share of buildings glass (``World.triangle_glass``: the sensor gets no
return from it); ``WorldParams.foliage`` builds tree crowns as scattered small leaf triangles with gaps
that rays pass through, instead of one closed ellipsoid. Their random draws come from streams of
their own, so switching one on leaves every other object where it was.

The world frame is the local ENU frame of the simulation (x east, y north, z up, metres). Generation
is deterministic for a given layout, parameters and seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum, IntEnum

import numpy as np

from lidar3d.errors import SimulationError
from lidar3d.sim import shapes
from lidar3d.sim.terrain import Terrain, TerrainParams, make_terrain

__all__ = [
    "DYNAMIC_CLASSES",
    "BlockKind",
    "EdgeSide",
    "ObjectClass",
    "StreetLayout",
    "World",
    "WorldParams",
    "generate_world",
]

_GLASS_STREAM = 0x61A55
_FOLIAGE_STREAM = 0xF011


class BlockKind(str, Enum):
    """What a block between streets holds."""

    URBAN = "urban"
    RESIDENTIAL = "residential"
    PARK = "park"
    OPEN = "open"
    FOREST = "forest"


class EdgeSide(str, Enum):
    """Which side of a block an edge lies on (the street bordering it runs along that side)."""

    SOUTH = "south"
    NORTH = "north"
    WEST = "west"
    EAST = "east"


class ObjectClass(IntEnum):
    """Class of what a ray hit; object id 0 is always the ground.

    ``MOVING_CAR`` and ``PEDESTRIAN`` are the moving actors of :mod:`~lidar3d.sim.actors` (not part
    of the world mesh; their ids follow the world's objects); ``CAR`` is a parked car.
    """

    GROUND = 0
    BUILDING = 1
    WALL = 2
    FENCE = 3
    POLE = 4
    TREE = 5
    CAR = 6
    MOVING_CAR = 7
    PEDESTRIAN = 8


DYNAMIC_CLASSES = frozenset({ObjectClass.MOVING_CAR, ObjectClass.PEDESTRIAN})


@dataclass(frozen=True, slots=True)
class StreetLayout:
    """A street grid.

    Attributes:
        street_x_m: x of the north-south streets, ascending.
        street_y_m: y of the east-west streets, ascending.
        margin_m: how far the world extends beyond the outermost streets.
        road_half_width_m: half the paved width (asphalt reflectivity, lane markings).
        block_kinds: ``(i, j, kind)`` overrides; cell (i, j) lies between x grid values i-1 and i
            (cell 0 is the western margin) and y grid values j-1 and j. Cells not listed get a
            seeded random kind among urban, residential and park.
        wall_edges: ``(i, j, side)`` edges of cells (``side`` an :class:`EdgeSide` value) that hold
            nothing but one featureless wall along the whole edge (no furniture, no parked cars);
            the two edges facing each other across a street make a corridor street.
    """

    street_x_m: tuple[float, ...]
    street_y_m: tuple[float, ...]
    margin_m: float = 60.0
    road_half_width_m: float = 5.0
    block_kinds: tuple[tuple[int, int, str], ...] = ()
    wall_edges: tuple[tuple[int, int, str], ...] = ()

    def __post_init__(self) -> None:
        for name in ("street_x_m", "street_y_m"):
            values = getattr(self, name)
            if len(values) < 1 or list(values) != sorted(values) or len(set(values)) != len(values):
                raise SimulationError(f"StreetLayout.{name} must be strictly ascending and non-empty")
        for i, j, kind in self.block_kinds:
            BlockKind(kind)
            if not (0 <= i <= len(self.street_x_m) and 0 <= j <= len(self.street_y_m)):
                raise SimulationError(f"StreetLayout.block_kinds: cell ({i}, {j}) is outside the grid")
        for i, j, side in self.wall_edges:
            if side not in [s.value for s in EdgeSide]:
                known = ", ".join(s.value for s in EdgeSide)
                raise SimulationError(f"StreetLayout.wall_edges: side must be one of {known}; got {side!r}")
            if not (0 <= i <= len(self.street_x_m) and 0 <= j <= len(self.street_y_m)):
                raise SimulationError(f"StreetLayout.wall_edges: cell ({i}, {j}) is outside the grid")

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(x_min, x_max, y_min, y_max) of the world."""
        return (
            self.street_x_m[0] - self.margin_m,
            self.street_x_m[-1] + self.margin_m,
            self.street_y_m[0] - self.margin_m,
            self.street_y_m[-1] + self.margin_m,
        )

    def cell_bounds_m(self, i: int, j: int) -> tuple[float, float, float, float]:
        """(x0, x1, y0, y1) of cell (i, j)."""
        x0, x1, y0, y1 = self.extent_m
        xs = (x0, *self.street_x_m, x1)
        ys = (y0, *self.street_y_m, y1)
        return xs[i], xs[i + 1], ys[j], ys[j + 1]

    def distance_to_street_m(self, x_m, y_m) -> np.ndarray:
        """Distance from world positions to the nearest street centre line."""
        x = np.asarray(x_m, float)[..., None]
        y = np.asarray(y_m, float)[..., None]
        dx = np.min(np.abs(x - np.asarray(self.street_x_m)), axis=-1)
        dy = np.min(np.abs(y - np.asarray(self.street_y_m)), axis=-1)
        return np.minimum(dx, dy)


@dataclass(frozen=True, slots=True)
class WorldParams:
    """Sizes and densities of the generated objects (ranges are uniform draws)."""

    terrain: TerrainParams = field(default_factory=TerrainParams)
    corner_clearance_m: float = 13.0  # no roadside object this close to a crossing street
    building_frontage_m: tuple[float, float] = (8.0, 24.0)
    building_depth_m: tuple[float, float] = (8.0, 18.0)
    building_height_m: tuple[float, float] = (5.0, 24.0)
    building_setback_m: tuple[float, float] = (8.5, 11.0)  # street centre line to facade
    building_gap_m: tuple[float, float] = (0.0, 6.0)
    house_frontage_m: tuple[float, float] = (9.0, 14.0)
    house_setback_m: tuple[float, float] = (13.0, 17.0)
    fence_offset_m: float = 8.5
    pole_spacing_m: float = 30.0
    pole_offset_m: float = 6.3
    tree_spacing_m: float = 14.0
    tree_offset_m: float = 7.4
    tree_probability: float = 0.55
    park_tree_area_m2: float = 220.0  # one tree per this much park area
    car_offset_m: float = 3.9
    car_probability: float = 0.3
    open_pole_spacing_m: float = 90.0
    kind_weights: tuple[float, float, float] = (0.5, 0.3, 0.2)  # urban, residential, park
    forest_tree_spacing_m: float = 6.0  # along a forest edge
    forest_edge_offset_m: tuple[float, float] = (6.5, 12.0)  # street centre line to a forest edge tree
    forest_tree_area_m2: float = 60.0  # one tree per this much forest area
    wall_edge_offset_m: float = 8.0  # street centre line to the face of a featureless edge wall
    wall_edge_height_m: tuple[float, float] = (10.0, 16.0)
    glass_facade_probability: float = 0.0  # share of buildings whose street facade is glass (no return)
    foliage: bool = False  # crowns of scattered leaf triangles instead of closed ellipsoids
    leaf_density_per_m3: float = 5.0  # leaves per cubic metre of crown
    leaf_size_m: tuple[float, float] = (0.25, 0.5)  # edge length of a leaf triangle

    def __post_init__(self) -> None:
        if not 0.0 <= self.glass_facade_probability <= 1.0:
            raise SimulationError("world glass_facade_probability must be in [0, 1]")
        if min(self.forest_tree_spacing_m, self.forest_tree_area_m2, self.forest_edge_offset_m[0]) <= 0.0:
            raise SimulationError("world forest spacing, area and edge offset must be positive")
        if self.leaf_density_per_m3 <= 0.0 or not 0.0 < self.leaf_size_m[0] <= self.leaf_size_m[1]:
            raise SimulationError("world leaf_density_per_m3 must be > 0 and leaf_size_m 0 < smallest <= largest")
        if self.wall_edge_offset_m <= 5.0 or not 0.0 < self.wall_edge_height_m[0] <= self.wall_edge_height_m[1]:
            raise SimulationError("world wall_edge_offset_m must exceed 5 m and wall_edge_height_m be 0 < low <= high")


@dataclass(frozen=True, slots=True)
class World:
    """A generated world.

    Attributes:
        vertices_m: (V, 3) float64 world-frame vertices.
        triangles: (T, 3) int32 vertex indices.
        triangle_object_id: (T,) int32 object id of each triangle (0 = ground).
        triangle_glass: (T,) bool: the triangle is glass (the sensor gets no return from it).
        object_class: (K + 1,) uint8 :class:`ObjectClass` of each object id.
        object_center_m: (K + 1, 3) float64 centroid of each object's vertices (ground: extent centre).
        block_kind: (nx + 1, ny + 1) array of :class:`BlockKind` values per cell.
        terrain: the analytic ground surface.
        layout: the street grid.
    """

    vertices_m: np.ndarray
    triangles: np.ndarray
    triangle_object_id: np.ndarray
    triangle_glass: np.ndarray
    object_class: np.ndarray
    object_center_m: np.ndarray
    block_kind: np.ndarray
    terrain: Terrain
    layout: StreetLayout

    def __post_init__(self) -> None:
        if self.vertices_m.ndim != 2 or self.vertices_m.shape[1] != 3:
            raise ValueError("World.vertices_m must be (V, 3)")
        if self.triangles.shape != (len(self.triangle_object_id), 3):
            raise ValueError("World.triangles must be (T, 3) with one object id per triangle")
        if self.triangle_glass.shape != self.triangle_object_id.shape:
            raise ValueError("World.triangle_glass must be (T,)")
        if self.object_center_m.shape != (len(self.object_class), 3):
            raise ValueError("World.object_center_m must be (K + 1, 3)")

    @property
    def n_objects(self) -> int:
        """Number of objects, not counting the ground."""
        return len(self.object_class) - 1

    def object_ids_of(self, object_class: ObjectClass) -> np.ndarray:
        """Ids of all objects of one class."""
        return np.flatnonzero(self.object_class == int(object_class))


class _Builder:
    """Accumulates object meshes and assigns object ids in insertion order."""

    def __init__(self, terrain: Terrain, params: WorldParams, seed: int) -> None:
        self.terrain = terrain
        self.meshes: list[shapes.Mesh] = []
        self.glass: list[np.ndarray | None] = []  # per mesh: (T,) bool glass triangles, None for none
        self.ids: list[int] = []
        self.classes: list[int] = [int(ObjectClass.GROUND)]
        self.centers: list[np.ndarray] = []
        self.glass_probability = params.glass_facade_probability
        self.glass_rng = np.random.default_rng([int(seed), _GLASS_STREAM])
        self.foliage_rng = np.random.default_rng([int(seed), _FOLIAGE_STREAM]) if params.foliage else None
        self.leaf_density_per_m3 = params.leaf_density_per_m3
        self.leaf_size_m = params.leaf_size_m

    def add(
        self, parts: list[shapes.Mesh], object_class: ObjectClass, glass: list[np.ndarray | None] | None = None
    ) -> None:
        object_id = len(self.classes)
        self.classes.append(int(object_class))
        for k, (vertices, triangles) in enumerate(parts):
            self.meshes.append((vertices, triangles))
            self.glass.append(None if glass is None else glass[k])
            self.ids.append(object_id)
        self.centers.append(np.mean(np.vstack([v for v, _ in parts]), axis=0))

    def ground_range(self, xy: np.ndarray) -> tuple[float, float]:
        z = self.terrain.height_m(xy[:, 0], xy[:, 1])
        return float(z.min()), float(z.max())


class _Edge:
    """One side of a street bordering a block: ``point(s, o)`` is ``s`` along, ``o`` into the block."""

    def __init__(self, side: EdgeSide, origin, direction, inward, length_m: float) -> None:
        self.side = side
        self.origin = np.asarray(origin, float)
        self.direction = np.asarray(direction, float)
        self.inward = np.asarray(inward, float)
        self.length_m = float(length_m)
        self.yaw_rad = float(np.arctan2(direction[1], direction[0]))

    def point(self, along_m, offset_m) -> np.ndarray:
        return self.origin + self.direction * along_m + self.inward * offset_m

    def footprint(self, along_m: float, offset_m: float, length_m: float, depth_m: float, yaw_rad: float) -> np.ndarray:
        """Corners (4, 2) of a rectangle centred at (along, offset), ``length`` along the edge."""
        center = self.point(along_m, offset_m)
        rotation = shapes.rotation_z(self.yaw_rad + yaw_rad)[:2, :2]
        local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * 0.5 * np.array([length_m, depth_m])
        return local @ rotation.T + center


def _edges_of_cell(layout: StreetLayout, i: int, j: int) -> list[_Edge]:
    x0, x1, y0, y1 = layout.cell_bounds_m(i, j)
    edges = []
    if j > 0:  # street along the southern side
        edges.append(_Edge(EdgeSide.SOUTH, (x0, y0), (1.0, 0.0), (0.0, 1.0), x1 - x0))
    if j < len(layout.street_y_m):  # northern side
        edges.append(_Edge(EdgeSide.NORTH, (x1, y1), (-1.0, 0.0), (0.0, -1.0), x1 - x0))
    if i > 0:  # western side
        edges.append(_Edge(EdgeSide.WEST, (x0, y1), (0.0, -1.0), (1.0, 0.0), y1 - y0))
    if i < len(layout.street_x_m):  # eastern side
        edges.append(_Edge(EdgeSide.EAST, (x1, y0), (0.0, 1.0), (-1.0, 0.0), y1 - y0))
    return edges


# The street facade of a box from :func:`shapes.box` rotated to an edge's yaw: its y- face (triangles 4 and 5).
_STREET_FACADE = np.isin(np.arange(12), (4, 5))


def _building(builder: _Builder, edge: _Edge, along: float, frontage: float, params: WorldParams, rng) -> None:
    depth = rng.uniform(*params.building_depth_m)
    setback = rng.uniform(*params.building_setback_m)
    height = rng.uniform(*params.building_height_m)
    if rng.random() < 0.1:
        height *= 1.6  # the odd tower
    yaw = rng.normal(0.0, np.deg2rad(2.0))
    offset = setback + 0.5 * depth
    corners = edge.footprint(along, offset, frontage, depth, yaw)
    z_low, z_high = builder.ground_range(np.vstack([corners, corners.mean(axis=0)]))
    z_bottom = z_low - 1.0
    z_top = z_high + height
    center = edge.point(along, offset)
    rotation = shapes.rotation_z(edge.yaw_rad + yaw)
    parts = [shapes.box((frontage, depth, z_top - z_bottom), (*center, 0.5 * (z_bottom + z_top)), rotation)]
    if rng.random() < 0.3:  # a set-back upper tier
        tier = rng.uniform(3.0, 9.0)
        scale = rng.uniform(0.45, 0.75)
        back = (1.0 - scale) * 0.5 * depth * rng.uniform(0.3, 1.0)
        tier_center = edge.point(along, offset + back)
        parts.append(shapes.box((frontage * scale, depth * scale, tier), (*tier_center, z_top + 0.5 * tier), rotation))
    glass = None
    if builder.glass_probability > 0.0 and builder.glass_rng.random() < builder.glass_probability:
        glass = [_STREET_FACADE.copy() for _ in parts]  # the local y- faces look onto the street
    builder.add(parts, ObjectClass.BUILDING, glass)


def _house(builder: _Builder, edge: _Edge, along: float, frontage: float, params: WorldParams, rng) -> None:
    depth = rng.uniform(8.0, 12.0)
    setback = rng.uniform(*params.house_setback_m)
    wall = rng.uniform(3.0, 6.0)
    rise = rng.uniform(1.8, 3.5)
    offset = setback + 0.5 * depth
    corners = edge.footprint(along, offset, frontage, depth, 0.0)
    z_low, z_high = builder.ground_range(corners)
    z_bottom = z_low - 0.5
    z_eaves = z_high + wall
    center = edge.point(along, offset)
    rotation = shapes.rotation_z(edge.yaw_rad)
    body = shapes.box((frontage, depth, z_eaves - z_bottom), (*center, 0.5 * (z_bottom + z_eaves)), rotation)
    roof = shapes.gable_roof(frontage + 0.6, depth + 0.6, rise, (*center, z_eaves), edge.yaw_rad)
    builder.add([body, roof], ObjectClass.BUILDING)


def _pole(builder: _Builder, xy: np.ndarray, rng, lamp_toward: np.ndarray | None = None) -> None:
    radius = rng.uniform(0.08, 0.14)
    height = rng.uniform(5.5, 8.0)
    z0 = float(builder.terrain.height_m(xy[0], xy[1])) - 0.3
    parts = [shapes.cylinder(radius, z0, z0 + 0.3 + height, xy, n_sides=8)]
    if lamp_toward is not None:  # a lamp arm reaching over the road
        arm = 1.6
        arm_center = xy + lamp_toward * 0.5 * arm
        yaw = float(np.arctan2(lamp_toward[1], lamp_toward[0]))
        parts.append(shapes.box((arm, 0.12, 0.12), (*arm_center, z0 + 0.3 + height - 0.1), shapes.rotation_z(yaw)))
    builder.add(parts, ObjectClass.POLE)


def _tree(builder: _Builder, xy: np.ndarray, rng) -> None:
    trunk_radius = rng.uniform(0.12, 0.3)
    trunk_height = rng.uniform(2.2, 3.6)
    crown = rng.uniform(1.6, 3.2)
    z0 = float(builder.terrain.height_m(xy[0], xy[1])) - 0.3
    top = z0 + 0.3 + trunk_height
    trunk = shapes.cylinder(trunk_radius, z0, top + 0.3 * crown, xy, n_sides=10)
    radii, center = (crown, crown, 0.8 * crown), (xy[0], xy[1], top + 0.7 * crown)
    if builder.foliage_rng is None:
        canopy = shapes.ellipsoid(radii, center)
    else:
        volume = 4.0 / 3.0 * np.pi * float(np.prod(radii))
        n_leaves = max(1, int(round(volume * builder.leaf_density_per_m3)))
        canopy = shapes.scattered_leaves(radii, center, n_leaves, builder.leaf_size_m, builder.foliage_rng)
    builder.add([trunk, canopy], ObjectClass.TREE)


def _car(builder: _Builder, xy: np.ndarray, yaw: float, rng) -> None:
    length = rng.uniform(4.0, 4.9)
    width = rng.uniform(1.7, 1.9)
    roof = rng.uniform(1.35, 1.6)
    normal = builder.terrain.normal(xy[0], xy[1])
    rotation = shapes.rotation_to_normal(normal, yaw)
    z_ground = float(builder.terrain.height_m(xy[0], xy[1]))
    base = np.array([xy[0], xy[1], z_ground])
    lower = (length, width, 0.75)
    cabin = (length * rng.uniform(0.45, 0.6), width * 0.92, roof - 1.0)
    lower_center = base + rotation @ np.array([0.0, 0.0, 0.3 + 0.5 * lower[2]])
    cabin_center = base + rotation @ np.array([-0.1 * length, 0.0, 1.05 + 0.5 * cabin[2] - 0.05])
    builder.add([shapes.box(lower, lower_center, rotation), shapes.box(cabin, cabin_center, rotation)], ObjectClass.CAR)


def _wall(builder: _Builder, edge: _Edge, start: float, stop: float, offset: float, height: float) -> None:
    length = stop - start
    if length < 1.0:
        return
    center = edge.point(0.5 * (start + stop), offset)
    ends = np.vstack([edge.point(start, offset), edge.point(stop, offset)])
    z_low, z_high = builder.ground_range(ends)
    z0 = z_low - 0.3
    z1 = z_high + height
    box = shapes.box((length, 0.25, z1 - z0), (*center, 0.5 * (z0 + z1)), shapes.rotation_z(edge.yaw_rad))
    builder.add([box], ObjectClass.WALL)


def _fence(builder: _Builder, edge: _Edge, start: float, stop: float, offset: float, height: float) -> None:
    length = stop - start
    if length < 1.0:
        return
    parts = []
    n_posts = max(2, int(np.ceil(length / 2.5)) + 1)
    rotation = shapes.rotation_z(edge.yaw_rad)
    for along in np.linspace(start, stop, n_posts):
        xy = edge.point(along, offset)
        z = float(builder.terrain.height_m(xy[0], xy[1]))
        parts.append(shapes.box((0.08, 0.08, height + 0.3), (*xy, z - 0.15 + 0.5 * height), rotation))
    ends = np.vstack([edge.point(start, offset), edge.point(stop, offset)])
    z_ends = builder.terrain.height_m(ends[:, 0], ends[:, 1])
    for level in (0.35 * height, 0.95 * height):  # two rails, following the mean ground line
        center = edge.point(0.5 * (start + stop), offset)
        z = 0.5 * float(z_ends.sum()) + level
        parts.append(shapes.box((length, 0.05, 0.06), (*center, z), rotation))
    builder.add(parts, ObjectClass.FENCE)


def _street_furniture(
    builder: _Builder, edge: _Edge, lo: float, hi: float, params: WorldParams, rng, trees: bool
) -> None:
    along = lo + rng.uniform(0.0, 0.5 * params.pole_spacing_m)
    while along < hi:
        _pole(builder, edge.point(along, params.pole_offset_m), rng, lamp_toward=-edge.inward)
        along += params.pole_spacing_m * rng.uniform(0.85, 1.15)
    if trees:
        along = lo + rng.uniform(2.0, 0.5 * params.tree_spacing_m)
        while along < hi:
            if rng.random() < params.tree_probability:
                _tree(builder, edge.point(along, params.tree_offset_m + rng.uniform(-0.3, 0.3)), rng)
            along += params.tree_spacing_m * rng.uniform(0.8, 1.2)
    along = lo + 3.0
    while along < hi - 3.0:
        if rng.random() < params.car_probability:
            yaw = edge.yaw_rad + (np.pi if rng.random() < 0.5 else 0.0) + rng.normal(0.0, 0.03)
            offset = params.car_offset_m + rng.uniform(-0.15, 0.15)
            _car(builder, edge.point(along, offset), yaw, rng)
            along += rng.uniform(5.6, 7.0)
        else:
            along += rng.uniform(4.0, 9.0)


def _urban_edge(builder: _Builder, edge: _Edge, lo: float, hi: float, params: WorldParams, rng) -> None:
    along = lo
    while True:
        frontage = rng.uniform(*params.building_frontage_m)
        if along + frontage > hi:
            frontage = hi - along
            if frontage < 6.0:
                break
        _building(builder, edge, along + 0.5 * frontage, frontage, params, rng)
        along += frontage + (0.0 if rng.random() < 0.3 else rng.uniform(*params.building_gap_m))
    _street_furniture(builder, edge, lo, hi, params, rng, trees=rng.random() < 0.6)


def _residential_edge(builder: _Builder, edge: _Edge, lo: float, hi: float, params: WorldParams, rng) -> None:
    use_wall = rng.random() < 0.4
    height = rng.uniform(1.0, 2.2) if use_wall else rng.uniform(1.0, 1.8)
    along = lo
    fence_start = lo
    while True:
        frontage = rng.uniform(*params.house_frontage_m)
        if along + frontage > hi:
            break
        center = along + 0.5 * frontage
        _house(builder, edge, center, frontage, params, rng)
        drive = center + rng.uniform(-0.3, 0.3) * frontage
        segment = _wall if use_wall else _fence
        segment(builder, edge, fence_start, drive - 2.0, params.fence_offset_m, height)
        fence_start = drive + 2.0
        if rng.random() < 0.6:
            _tree(builder, edge.point(along + rng.uniform(0.0, frontage), rng.uniform(10.0, 12.0)), rng)
        along += frontage + rng.uniform(4.0, 10.0)
    (_wall if use_wall else _fence)(builder, edge, fence_start, hi, params.fence_offset_m, height)
    _street_furniture(builder, edge, lo, hi, params, rng, trees=True)


def _park_edge(builder: _Builder, edge: _Edge, lo: float, hi: float, params: WorldParams, rng) -> None:
    if rng.random() < 0.5:
        height = rng.uniform(0.6, 1.1)
        split = rng.uniform(lo + 0.3 * (hi - lo), hi - 0.3 * (hi - lo))
        _wall(builder, edge, lo, split - 3.0, params.fence_offset_m, height)
        _wall(builder, edge, split + 3.0, hi, params.fence_offset_m, height)
    _street_furniture(builder, edge, lo, hi, params, rng, trees=False)


def _park_interior(
    builder: _Builder, layout: StreetLayout, bounds, params: WorldParams, rng, tree_area_m2: float
) -> None:
    x0, x1, y0, y1 = bounds
    inset = params.corner_clearance_m - 1.0
    if x1 - x0 <= 2 * inset or y1 - y0 <= 2 * inset:
        return
    n = int((x1 - x0 - 2 * inset) * (y1 - y0 - 2 * inset) / tree_area_m2)
    xy = np.column_stack([rng.uniform(x0 + inset, x1 - inset, n), rng.uniform(y0 + inset, y1 - inset, n)])
    keep = layout.distance_to_street_m(xy[:, 0], xy[:, 1]) > 10.0
    for point in xy[keep]:
        _tree(builder, point, rng)


def _open_edge(builder: _Builder, edge: _Edge, lo: float, hi: float, params: WorldParams, rng) -> None:
    along = lo + rng.uniform(0.0, params.open_pole_spacing_m)
    while along < hi:
        _pole(builder, edge.point(along, params.pole_offset_m), rng)
        along += params.open_pole_spacing_m * rng.uniform(0.8, 1.2)


def _forest_edge(builder: _Builder, edge: _Edge, lo: float, hi: float, params: WorldParams, rng) -> None:
    along = lo + rng.uniform(0.0, params.forest_tree_spacing_m)
    while along < hi:
        _tree(builder, edge.point(along, rng.uniform(*params.forest_edge_offset_m)), rng)
        along += params.forest_tree_spacing_m * rng.uniform(0.6, 1.4)


def _featureless_wall_edge(builder: _Builder, edge: _Edge, lo: float, hi: float, params: WorldParams, rng) -> None:
    """One wall along the whole edge, nothing else: a side of a corridor street."""
    height = rng.uniform(*params.wall_edge_height_m)
    _wall(builder, edge, lo, hi, params.wall_edge_offset_m + 0.125, height)


_EDGE_BUILDERS = {
    BlockKind.URBAN: _urban_edge,
    BlockKind.RESIDENTIAL: _residential_edge,
    BlockKind.PARK: _park_edge,
    BlockKind.OPEN: _open_edge,
    BlockKind.FOREST: _forest_edge,
}


def generate_world(layout: StreetLayout, params: WorldParams, seed: int) -> World:
    """Generate the world for ``layout``; the same arguments always give the same world."""
    rng = np.random.default_rng([int(seed), 0x5701D])
    terrain = make_terrain(params.terrain, layout.extent_m, rng)
    builder = _Builder(terrain, params, seed)
    overrides = {(i, j): BlockKind(kind) for i, j, kind in layout.block_kinds}
    walled = {(i, j, EdgeSide(side)) for i, j, side in layout.wall_edges}
    random_kinds = (BlockKind.URBAN, BlockKind.RESIDENTIAL, BlockKind.PARK)
    weights = np.asarray(params.kind_weights, float) / np.sum(params.kind_weights)
    nx, ny = len(layout.street_x_m) + 1, len(layout.street_y_m) + 1
    kinds = np.empty((nx, ny), dtype=object)
    for i in range(nx):
        for j in range(ny):
            drawn = random_kinds[int(rng.choice(3, p=weights))]
            kind = overrides.get((i, j), drawn)
            kinds[i, j] = kind.value
            for edge in _edges_of_cell(layout, i, j):
                lo, hi = params.corner_clearance_m, edge.length_m - params.corner_clearance_m
                if hi - lo < 5.0:
                    continue
                if (i, j, edge.side) in walled:
                    _featureless_wall_edge(builder, edge, lo, hi, params, rng)
                else:
                    _EDGE_BUILDERS[kind](builder, edge, lo, hi, params, rng)
            if kind is BlockKind.PARK:
                _park_interior(builder, layout, layout.cell_bounds_m(i, j), params, rng, params.park_tree_area_m2)
            elif kind is BlockKind.FOREST:
                _park_interior(builder, layout, layout.cell_bounds_m(i, j), params, rng, params.forest_tree_area_m2)
    gx, gy = terrain.grid_axes_m()
    gxx, gyy = np.meshgrid(gx, gy)
    ground = shapes.heightfield(gx, gy, terrain.height_m(gxx, gyy))
    vertices, triangles = shapes.merge([ground] + builder.meshes)
    n_ground = len(ground[1])
    object_ids = np.concatenate(
        [np.zeros(n_ground, dtype=np.int32)]
        + [np.full(len(t), object_id, dtype=np.int32) for (_, t), object_id in zip(builder.meshes, builder.ids)]
    )
    glass = np.concatenate(
        [np.zeros(n_ground, dtype=bool)]
        + [np.zeros(len(t), dtype=bool) if g is None else g for (_, t), g in zip(builder.meshes, builder.glass)]
    )
    x0, x1, y0, y1 = layout.extent_m
    ground_center = np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.0])
    centers = np.vstack([ground_center] + builder.centers)
    return World(
        vertices_m=vertices,
        triangles=triangles.astype(np.int32),
        triangle_object_id=object_ids,
        triangle_glass=glass,
        object_class=np.asarray(builder.classes, dtype=np.uint8),
        object_center_m=centers,
        block_kind=kinds,
        terrain=terrain,
        layout=layout,
    )
