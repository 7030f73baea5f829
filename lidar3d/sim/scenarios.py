"""Named simulation scenarios: a street layout, a route through it, and how the vehicle drives it.

=========  ======================================================================================
name       what it exercises
=========  ======================================================================================
loop       ~420 m loop around one block on gently rolling ground, back past the start (default)
long       ~1.4 km: three revisits of earlier streets (two against the first direction) and a 240 m feature-poor stretch
hilly      ~500 m loop over hills with slopes up to 8 degrees (roll and pitch from the slope)
fast       ~700 m at up to 10 m/s with sharp 90-degree corners (strong motion distortion)
=========  ======================================================================================

Route nodes lie on the street grid (``StreetLayout``); consecutive nodes share a street. The vehicle
drives on the right, ``lane_offset_m`` from the centre line, so a street driven in the opposite
direction is seen from a lane about 3 m away.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lidar3d.errors import SimulationError
from lidar3d.sim.terrain import TerrainParams
from lidar3d.sim.trajectory import RouteParams
from lidar3d.sim.world import StreetLayout, WorldParams

__all__ = ["DEFAULT_SCENARIO", "SCENARIOS", "Scenario", "get_scenario"]


@dataclass(frozen=True, slots=True)
class Scenario:
    """A named world-plus-route.

    Attributes:
        name: key in :data:`SCENARIOS`.
        description: one line for the CLI help and the metadata.
        layout: the street grid.
        route_m: route nodes (x, y) in the world frame, on the grid.
        route: driving parameters.
        world: object parameters (including the terrain).
    """

    name: str
    description: str
    layout: StreetLayout
    route_m: tuple[tuple[float, float], ...]
    route: RouteParams = field(default_factory=RouteParams)
    world: WorldParams = field(default_factory=WorldParams)

    def __post_init__(self) -> None:
        xs, ys = set(self.layout.street_x_m), set(self.layout.street_y_m)
        for (x0, y0), (x1, y1) in zip(self.route_m[:-1], self.route_m[1:]):
            on_x_street = x0 == x1 and x0 in xs
            on_y_street = y0 == y1 and y0 in ys
            if not (on_x_street or on_y_street):
                raise SimulationError(
                    f"scenario {self.name!r}: route leg ({x0}, {y0}) -> ({x1}, {y1}) does not follow a street"
                )


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario(
            name="loop",
            description="~420 m loop around a city block, back past the start (default)",
            layout=StreetLayout(street_x_m=(0.0, 120.0), street_y_m=(0.0, 80.0)),
            route_m=((30.0, 0.0), (120.0, 0.0), (120.0, 80.0), (0.0, 80.0), (0.0, 0.0), (60.0, 0.0)),
            route=RouteParams(cruise_speed_mps=6.5),
        ),
        Scenario(
            name="long",
            description="~1.4 km, three revisits and a 240 m feature-poor stretch of open land",
            layout=StreetLayout(
                street_x_m=(0.0, 100.0, 180.0, 420.0),
                street_y_m=(0.0, 80.0),
                # Open land on both sides of the southern street between x = 180 and 420 m only:
                # the corner at x = 420 m and the way back along y = 80 m have built-up land on
                # one side, so the feature-poor stretch is the documented 240 m straight.
                block_kinds=((3, 0, "open"), (3, 1, "open")),
            ),
            route_m=(
                (30.0, 0.0),
                (420.0, 0.0),
                (420.0, 80.0),
                (100.0, 80.0),
                (100.0, 0.0),
                (0.0, 0.0),
                (0.0, 80.0),
                (180.0, 80.0),
                (180.0, 0.0),
                (260.0, 0.0),
            ),
            route=RouteParams(cruise_speed_mps=8.0),
        ),
        Scenario(
            name="hilly",
            description="~500 m loop over hills with slopes up to 8 degrees",
            layout=StreetLayout(street_x_m=(0.0, 140.0), street_y_m=(0.0, 90.0)),
            route_m=((40.0, 0.0), (140.0, 0.0), (140.0, 90.0), (0.0, 90.0), (0.0, 0.0), (80.0, 0.0)),
            route=RouteParams(cruise_speed_mps=6.0),
            world=WorldParams(terrain=TerrainParams(max_slope_deg=8.0, min_wavelength_m=110.0, max_wavelength_m=260.0)),
        ),
        Scenario(
            name="fast",
            description="~700 m at up to 10 m/s with sharp 90-degree corners",
            layout=StreetLayout(street_x_m=(0.0, 80.0, 160.0), street_y_m=(0.0, 70.0, 140.0)),
            route_m=(
                (40.0, 0.0),
                (160.0, 0.0),
                (160.0, 70.0),
                (80.0, 70.0),
                (80.0, 140.0),
                (0.0, 140.0),
                (0.0, 0.0),
                (120.0, 0.0),
            ),
            route=RouteParams(
                corner_radius_m=6.0,
                cruise_speed_mps=10.0,
                max_lateral_accel_mps2=4.5,
                max_accel_mps2=2.5,
                max_decel_mps2=3.5,
            ),
        ),
    )
}

DEFAULT_SCENARIO = "loop"


def get_scenario(name: str) -> Scenario:
    """The scenario called ``name``; raises :class:`SimulationError` listing the known names."""
    try:
        return SCENARIOS[name]
    except KeyError:
        raise SimulationError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}") from None
