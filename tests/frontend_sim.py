"""Simulated scans with per-point truth for the front-end tests (cached per test session)."""

from __future__ import annotations

import functools

import numpy as np
from scipy.spatial import cKDTree

from lidar3d.segmentation import RangeImage
from lidar3d.sim import ObjectClass, SimulatedScan, Simulation

DURATION_S = 60.0


@functools.cache
def simulation(scenario: str, sensor: str = "vlp16") -> Simulation:
    return Simulation(scenario, seed=0, duration_s=DURATION_S, sensor=sensor)


@functools.cache
def sample_scans(scenario: str, sensor: str = "vlp16", count: int = 12) -> tuple[SimulatedScan, ...]:
    """``count`` scans spread evenly over the first minute of the drive."""
    sim = simulation(scenario, sensor)
    return tuple(sim.scan(int(k)) for k in np.linspace(0, len(sim) - 1, count).round())


def cell_truth(sim_scan: SimulatedScan, image: RangeImage) -> np.ndarray:
    """(R, C) int object id of each cell's point (0 ground), -1 for empty cells."""
    truth = np.full(image.shape, -1, dtype=np.int64)
    occupied = image.occupied
    truth[occupied] = sim_scan.object_id[image.point_index[occupied]]
    return truth


def scan_index_of(points: np.ndarray, sim_scan: SimulatedScan) -> np.ndarray:
    """Index in the scan of each of ``points`` (which must be scan points, e.g. features)."""
    lookup = {tuple(p): i for i, p in enumerate(sim_scan.scan.points)}
    return np.array([lookup[tuple(p)] for p in points], dtype=np.int64)


def points_in_world(sim: Simulation, sim_scan: SimulatedScan, index: np.ndarray) -> np.ndarray:
    """World-frame positions of scan points, each placed with the true pose at its firing time."""
    scan = sim_scan.scan
    stamps = scan.stamp_ns + np.round(scan.time_offset_s[index] * 1e9).astype(np.int64)
    T_world_lidar = sim.T_world_lidar_at(stamps)
    return np.einsum("nij,nj->ni", T_world_lidar[:, :3, :3], scan.points[index]) + T_world_lidar[:, :3, 3]


@functools.cache
def vertical_edge_tree(scenario: str, sensor: str = "vlp16") -> cKDTree:
    """k-d tree over the (x, y) of the world's vertical mesh edges (building and car corners)."""
    world = simulation(scenario, sensor).world
    edges = np.concatenate([world.triangles[:, [0, 1]], world.triangles[:, [1, 2]], world.triangles[:, [2, 0]]])
    object_id = np.tile(world.triangle_object_id, 3)
    a, b = world.vertices_m[edges[:, 0]], world.vertices_m[edges[:, 1]]
    vertical = (np.hypot(*(a - b)[:, :2].T) < 1e-3) & (np.abs(a[:, 2] - b[:, 2]) > 0.2) & (object_id > 0)
    return cKDTree(a[vertical, :2])


SLENDER = (int(ObjectClass.POLE), int(ObjectClass.TREE))
