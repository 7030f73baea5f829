"""Named simulation scenarios: a street layout, a route through it, and how the vehicle drives it.

============  ===================================================================================
name          what it exercises
============  ===================================================================================
loop          ~420 m loop around one block on gently rolling ground, back past the start (default)
long          ~1.4 km: three revisits (two against the first direction) and a 240 m feature-poor stretch
hilly         ~500 m loop over hills with slopes up to 8 degrees (roll and pitch from the slope)
fast          ~700 m at up to 10 m/s with sharp 90-degree corners (strong motion distortion)
stops         ~400 m town drive at 2-9 m/s, real braking, three 3-6 s stops, vibration, calibration error,
              jitter
blind_turn    ~520 m: 240 m of open land at a varying 4.5-8 m/s ending in a 90-degree turn on open land
              (~30 deg/s)
figure_eight  ~800 m figure eight: a 200 m open field at up to 6.5 m/s ending in a sharp right turn
              (~30 deg/s for ~3 s) with buildings ahead, then straights at a slowly varying 4.6-5.0 m/s;
              vibration, calibration error, jitter, dropped packets
city_traffic  ~515 m city loop: moving cars (a lead car pulling away, a follower, oncoming) and
              pedestrians (walking, crossing), glass facades, a 160 m canyon between two featureless
              walls (4.6 -> 6.3 -> 5.4 m/s inside it), a 4 s stop, back past the start
forest_trail  ~500 m rough trail through forest (crowns of scattered leaves that rays pass through),
              vibration 0.3 deg at 5-20 Hz, a random 2.5-6 m/s speed profile, a stop, slopes up to 4 deg,
              two hikers
============  ===================================================================================

The first four drive at the cruise speed on straights, on a rigid body, with a perfect sensor; the
others use the vehicle dynamics and sensor imperfections of
:class:`~lidar3d.sim.trajectory.RouteParams` and :class:`~lidar3d.sim.lidar.LidarParams`;
``city_traffic`` and ``forest_trail`` also the moving actors (:class:`~lidar3d.sim.actors.TrafficParams`)
and the materials and degenerate geometry of :class:`~lidar3d.sim.world.WorldParams` (glass,
foliage, forest blocks) and :class:`~lidar3d.sim.world.StreetLayout` (``wall_edges``).

Route nodes lie on the street grid (``StreetLayout``); consecutive nodes share a street. The vehicle
drives on the right, ``lane_offset_m`` from the centre line, so a street driven in the opposite
direction is seen from a lane about 3 m away.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lidar3d.errors import SimulationError
from lidar3d.sim.actors import TrafficParams
from lidar3d.sim.lidar import LidarParams
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
        lidar: measurement model (a :class:`Simulation` given its own ``lidar`` uses that instead).
        traffic: the moving road users (none by default).
    """

    name: str
    description: str
    layout: StreetLayout
    route_m: tuple[tuple[float, float], ...]
    route: RouteParams = field(default_factory=RouteParams)
    world: WorldParams = field(default_factory=WorldParams)
    lidar: LidarParams = field(default_factory=LidarParams)
    traffic: TrafficParams = field(default_factory=TrafficParams)

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
        Scenario(
            name="stops",
            description="~400 m town drive at 2-9 m/s with three stops of 3-6 s, vibration and calibration error",
            layout=StreetLayout(street_x_m=(0.0, 70.0, 140.0), street_y_m=(0.0, 60.0)),
            route_m=((20.0, 0.0), (140.0, 0.0), (140.0, 60.0), (0.0, 60.0), (0.0, 0.0), (40.0, 0.0)),
            route=RouteParams(
                cruise_speed_mps=9.0,
                random_speed_min_mps=3.0,
                speed_stretch_m=(40.0, 90.0),
                max_accel_mps2=1.5,
                max_decel_mps2=2.5,
                # Stop lines before the crossing at x = 70 m (eastbound, then westbound) and a
                # pedestrian crossing halfway down the western street.
                stops=((43.0, 4.0), (239.0, 6.0), (344.0, 3.0)),
                vibration_deg=0.1,
                vibration_heave_m=0.0005,
            ),
            lidar=LidarParams(elevation_error_sigma_deg=0.05, range_bias_sigma_m=0.004, stamp_jitter_s=0.001),
        ),
        Scenario(
            name="blind_turn",
            description="~520 m: 240 m of open land at 4.5-8 m/s ending in a 90-degree turn on open land",
            layout=StreetLayout(
                street_x_m=(0.0, 120.0, 360.0),
                street_y_m=(0.0, 50.0),
                # Open land on both sides of the southern street from x = 120 m and all around the
                # corner at x = 360 m: the turn comes at the end of the feature-poor stretch and is
                # itself blind; buildings return north of y = 50 m.
                block_kinds=((2, 0, "open"), (2, 1, "open"), (3, 0, "open"), (3, 1, "open")),
            ),
            route_m=((20.0, 0.0), (360.0, 0.0), (360.0, 50.0), (220.0, 50.0)),
            route=RouteParams(
                cruise_speed_mps=8.0,
                random_speed_min_mps=4.5,
                speed_stretch_m=(50.0, 120.0),
                max_lateral_accel_mps2=3.0,
                vibration_deg=0.05,
                vibration_heave_m=0.0003,
            ),
        ),
        Scenario(
            name="figure_eight",
            description="~800 m figure eight: a 200 m open field ending in a sharp turn, then 4.6-5.0 m/s",
            layout=StreetLayout(
                street_x_m=(0.0, 80.0, 280.0),
                street_y_m=(0.0, 70.0, 120.0),
                # Open land on both sides of the northern street between x = 80 and 280 m: the field
                # ends at the right turn at x = 280 m, where the blocks east of it are built up.
                block_kinds=((2, 2, "open"), (2, 3, "open")),
            ),
            route_m=(
                (30.0, 0.0),
                (80.0, 0.0),
                (80.0, 120.0),
                (280.0, 120.0),
                (280.0, 70.0),
                (0.0, 70.0),
                (0.0, 0.0),
                (50.0, 0.0),
            ),
            route=RouteParams(
                cruise_speed_mps=6.5,
                # Faster on the field, then a slowly varying 4.6-5.0 m/s after the turn (about
                # 370 m along the path).
                speed_targets=(
                    (1.0, 5.5),
                    (150.0, 6.5),
                    (330.0, 5.0),
                    (420.0, 4.8),
                    (520.0, 4.6),
                    (620.0, 5.0),
                    (720.0, 4.7),
                ),
                speed_transition_m=40.0,
                vibration_deg=0.1,
                vibration_heave_m=0.0005,
            ),
            lidar=LidarParams(
                elevation_error_sigma_deg=0.05,
                range_bias_sigma_m=0.004,
                stamp_jitter_s=0.001,
                dropped_wedge_probability=0.02,
            ),
        ),
        Scenario(
            name="city_traffic",
            description="~515 m city loop with traffic, pedestrians, glass facades and a 160 m walled canyon",
            layout=StreetLayout(
                street_x_m=(0.0, 186.0),
                street_y_m=(0.0, 60.0),
                block_kinds=tuple((i, j, "urban") for i in range(3) for j in range(3)),
                # The northern street between x = 13 and 173 m runs between two featureless walls.
                wall_edges=((1, 1, "north"), (1, 2, "south")),
            ),
            route_m=((30.0, 0.0), (186.0, 0.0), (186.0, 60.0), (0.0, 60.0), (0.0, 0.0), (70.0, 0.0)),
            route=RouteParams(
                cruise_speed_mps=6.3,
                # The canyon runs from about 214 to 374 m along the path.
                speed_targets=((1.0, 5.2), (190.0, 4.6), (265.0, 6.3), (330.0, 5.4), (400.0, 5.0)),
                stops=((140.0, 4.0),),  # the stop line before the crossing at x = 186 m
                max_decel_mps2=2.5,
                vibration_deg=0.08,
                vibration_heave_m=0.0004,
            ),
            world=WorldParams(glass_facade_probability=0.35, foliage=True),
            lidar=LidarParams(elevation_error_sigma_deg=0.05, range_bias_sigma_m=0.004, stamp_jitter_s=0.001),
            traffic=TrafficParams(
                lead_car=True, followers=1, oncoming_cars=8, walking_pedestrians=12, crossing_pedestrians=3
            ),
        ),
        Scenario(
            name="forest_trail",
            description="~500 m rough forest trail: scattered-leaf crowns, 0.3 deg vibration, speed changes",
            layout=StreetLayout(
                street_x_m=(0.0, 150.0),
                street_y_m=(0.0, 100.0),
                road_half_width_m=2.5,
                block_kinds=tuple((i, j, "forest") for i in range(3) for j in range(3)),
            ),
            route_m=((30.0, 0.0), (150.0, 0.0), (150.0, 100.0), (0.0, 100.0), (0.0, 0.0), (50.0, 0.0)),
            route=RouteParams(
                cruise_speed_mps=6.0,
                min_speed_mps=2.0,
                random_speed_min_mps=2.5,
                speed_stretch_m=(30.0, 80.0),
                stops=((260.0, 3.0),),
                max_lateral_accel_mps2=2.0,
                vibration_deg=0.3,
                vibration_heave_m=0.004,
            ),
            world=WorldParams(terrain=TerrainParams(max_slope_deg=4.0), foliage=True),
            lidar=LidarParams(elevation_error_sigma_deg=0.05, range_bias_sigma_m=0.004, stamp_jitter_s=0.001),
            traffic=TrafficParams(walking_pedestrians=2, sidewalk_offset_m=4.0),
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
