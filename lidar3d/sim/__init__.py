"""Simulated VLP-16 drives through procedural worlds, with exact ground truth and a SPAN-CPT log.

Modules, one concept each:

* :mod:`~lidar3d.sim.shapes`, :mod:`~lidar3d.sim.terrain`, :mod:`~lidar3d.sim.world`: the world as
  one triangle mesh with an object id per triangle;
* :mod:`~lidar3d.sim.trajectory`: vehicle motion along a street route (speed profiles, stops,
  suspension vibration), and revisit detection;
* :mod:`~lidar3d.sim.actors`: moving cars and pedestrians along the route (per-point labels);
* :mod:`~lidar3d.sim.scenarios`: the named scenarios;
* :mod:`~lidar3d.sim.rig`: where the lidar and the antenna sit relative to the IMU;
* :mod:`~lidar3d.sim.lidar`: the ray-cast sensor (per-column poses, noise, dropouts, intensity,
  calibration errors, lost packets, stamp conventions);
* :mod:`~lidar3d.sim.span`: the NovAtel SPAN ASCII log;
* :mod:`~lidar3d.sim.simulation`: everything put together, scans on demand;
* :mod:`~lidar3d.sim.output`: the output folder and :func:`simulate`.

Open3D is imported only when the first scan is ray cast.
"""

from lidar3d.sim.actors import Traffic, TrafficParams
from lidar3d.sim.lidar import LidarParams, SimulatedScan, StampMode
from lidar3d.sim.output import (
    LABELS_NAME,
    BagFormat,
    PointLabels,
    SimulationOutputs,
    read_point_labels,
    simulate,
    write_simulation,
)
from lidar3d.sim.rig import RigParams
from lidar3d.sim.scenarios import DEFAULT_SCENARIO, SCENARIOS, Scenario, get_scenario
from lidar3d.sim.simulation import DEFAULT_START_TIME_NS, Simulation
from lidar3d.sim.span import GeoOrigin, SpanParams
from lidar3d.sim.terrain import TerrainParams
from lidar3d.sim.trajectory import RevisitPair, RouteParams
from lidar3d.sim.world import DYNAMIC_CLASSES, BlockKind, EdgeSide, ObjectClass, StreetLayout, World, WorldParams

__all__ = [
    "DEFAULT_SCENARIO",
    "DEFAULT_START_TIME_NS",
    "DYNAMIC_CLASSES",
    "LABELS_NAME",
    "SCENARIOS",
    "BagFormat",
    "BlockKind",
    "EdgeSide",
    "GeoOrigin",
    "LidarParams",
    "ObjectClass",
    "PointLabels",
    "RevisitPair",
    "RigParams",
    "RouteParams",
    "Scenario",
    "SimulatedScan",
    "Simulation",
    "SimulationOutputs",
    "SpanParams",
    "StampMode",
    "StreetLayout",
    "TerrainParams",
    "Traffic",
    "TrafficParams",
    "World",
    "WorldParams",
    "get_scenario",
    "read_point_labels",
    "simulate",
    "write_simulation",
]
