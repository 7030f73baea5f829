"""Simulated scans with per-point truth for the front-end tests (cached per test session)."""

from __future__ import annotations

import functools

import numpy as np
from scipy.spatial import cKDTree

from lidar3d.segmentation import RangeImage, Segmentation
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


# The array definitions the front end's compiled kernels follow (oracles for the tests).


def joins_by_beta(near_m: np.ndarray, far_m: np.ndarray, alpha_rad: np.ndarray | float, tan_theta: float) -> np.ndarray:
    """beta > theta for 0 < theta < 90 deg, written without the arctangent.

    With s = d2 sin(alpha) > 0, beta = atan2(s, d1 - d2 cos(alpha)) exceeds theta exactly when
    s > tan(theta) * (d1 - d2 cos(alpha)) (a non-positive denominator means beta >= 90 deg).
    NaN ranges (empty cells) compare False.
    """
    with np.errstate(invalid="ignore"):
        return near_m * np.sin(alpha_rad) > tan_theta * (far_m - near_m * np.cos(alpha_rad))


def suppression_spans(
    segmentation: Segmentation, half_window: int, max_column_gap: int
) -> tuple[np.ndarray, np.ndarray]:
    """(M,) int64 ``lo`` and ``hi``: picking point i marks ``[lo[i], hi[i])`` as picked.

    The span reaches up to ``half_window`` points either side of i, stopping before the first pair
    of consecutive points more than ``max_column_gap`` columns apart or in different rings (FA:720-735).
    """
    n = len(segmentation)
    link = np.zeros(n, dtype=bool)  # link[k]: points k and k+1 are close neighbours
    link[:-1] = (segmentation.row[1:] == segmentation.row[:-1]) & (
        np.abs(np.diff(segmentation.column)) <= max_column_gap
    )
    forward = np.zeros(n, dtype=np.int64)
    backward = np.zeros(n, dtype=np.int64)
    reach_forward = np.ones(n, dtype=bool)
    reach_backward = np.ones(n, dtype=bool)
    for step in range(half_window):
        ahead = np.zeros(n, dtype=bool)
        ahead[: n - step] = link[step:]  # link between i+step and i+step+1
        reach_forward &= ahead
        forward += reach_forward
        behind = np.zeros(n, dtype=bool)
        behind[step + 1 :] = link[: n - step - 1]  # link between i-step-1 and i-step
        reach_backward &= behind
        backward += reach_backward
    index = np.arange(n)
    return index - backward, index + forward + 1
