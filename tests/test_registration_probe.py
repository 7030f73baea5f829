"""The probe of a registration's weakest direction (lidar3d.mapping.registration.probe_return_share):
real structure pulls a shifted pose back, random matches on a flat wall do not."""

from __future__ import annotations

import numpy as np

from lidar3d.mapping.registration import LineMap, MatchRows, PlaneMap, probe_return_share, solve_pose


def _plane_points(rng: np.random.Generator, n: int, origin, axis_a, axis_b, size_a: float, size_b: float):
    a = rng.uniform(0.0, size_a, (n, 1))
    b = rng.uniform(0.0, size_b, (n, 1))
    return np.asarray(origin) + a * np.asarray(axis_a, float) + b * np.asarray(axis_b, float)


def _corner_scene(rng: np.random.Generator) -> np.ndarray:
    """Three perpendicular walls (x = 0, y = 0, z = 0), 10 m x 10 m each, exact."""
    return np.concatenate(
        [
            _plane_points(rng, 4000, (0, 0, 0), (1, 0, 0), (0, 1, 0), 10, 10),
            _plane_points(rng, 4000, (0, 0, 0), (1, 0, 0), (0, 0, 1), 10, 10),
            _plane_points(rng, 4000, (0, 0, 0), (0, 1, 0), (0, 0, 1), 10, 10),
        ]
    )


def test_real_planes_pull_a_shifted_pose_back() -> None:
    rng = np.random.default_rng(0)
    target = PlaneMap(_corner_scene(rng), k=10, max_sq_dist=1.4**2)
    source = _corner_scene(rng)[::6]
    for direction in np.eye(3):
        share = probe_return_share(np.eye(4), source, target.rows, np.r_[0.25 * direction, 0, 0, 0], 0.5, 0.05)
        assert share > 0.9, (direction, share)


def test_noise_edges_on_a_flat_wall_do_not_hold_the_wall_direction() -> None:
    """Edge points scattered over a flat wall (range noise passing the edge threshold): lines fitted to
    any five of them point anywhere in the wall. The rows claim information along the wall; the probe
    finds none, while the wall's own normal (a plane) is held."""
    rng = np.random.default_rng(1)

    def wall_edges(n: int) -> np.ndarray:
        points = _plane_points(rng, n, (0, 5, 0), (1, 0, 0), (0, 0, 1), 40, 3)
        points[:, 1] += rng.normal(0.0, 0.02, n)
        return points

    lines = LineMap(wall_edges(3000))
    planes = PlaneMap(_plane_points(rng, 6000, (0, 5, 0), (1, 0, 0), (0, 0, 1), 40, 3), k=10, max_sq_dist=1.4**2)
    edges = wall_edges(600)
    surfaces = _plane_points(rng, 600, (0, 5, 0), (1, 0, 0), (0, 0, 1), 40, 3)
    source = np.concatenate([edges, surfaces])

    def find(q: np.ndarray, reach: float | None) -> MatchRows:
        return MatchRows.concatenate([lines.rows(q[:600], reach), planes.rows(q[600:], reach)], [0, 600])

    solved = solve_pose(np.eye(4), source, find, robust_scale_m=0.05)
    along_wall = solved.information[0, 0]
    assert along_wall > 1e4  # the random lines claim the along-wall direction, confidently
    share = probe_return_share(solved.T_target_source, source, find, np.r_[0.25, 0, 0, 0, 0, 0], 0.5, 0.05)
    assert share < 0.3, share
    normal_share = probe_return_share(solved.T_target_source, source, find, np.r_[0, 0.25, 0, 0, 0, 0], 0.5, 0.05)
    assert normal_share > 0.9, normal_share
