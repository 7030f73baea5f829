"""A settled sweep is registered again on the correspondences its first registration ended with."""

import numpy as np

from lidar3d.config import MappingConfig
from lidar3d.mapping.deskew import deskew_again, deskew_points
from lidar3d.mapping.registration import MatchRows, solve_pose
from lidar3d.mapping.scan_to_map import register_again
from lidar3d.mapping.se3 import exp_se3, invert, transform_points

RNG = np.random.default_rng(7)
# A street: ground, two facades along x, a wall across it ahead and one behind (normal, offset).
PLANES = [
    (np.array([0.0, 0.0, 1.0]), 1.8),
    (np.array([0.0, 1.0, 0.0]), -6.0),
    (np.array([0.0, -1.0, 0.0]), -5.0),
    (np.array([-1.0, 0.0, 0.0]), 30.0),
    (np.array([1.0, 0.0, 0.0]), 25.0),
]


def rotation_angle(R: np.ndarray) -> float:
    """The angle (rad) of a (3,3) rotation."""
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def street_points_world(planes: list = PLANES, n_per_plane: int = 300) -> tuple[np.ndarray, MatchRows]:
    """(N,3) world points on ``planes`` ((normal, offset) pairs) and the rows matching each to its plane."""
    points, normals, offsets = [], [], []
    for normal, offset in planes:
        p = RNG.uniform(-20.0, 20.0, (n_per_plane, 3))
        p -= np.outer(p @ normal + offset, normal)  # onto the plane n . q + d = 0
        points.append(p)
        normals.append(np.repeat(normal[None], n_per_plane, axis=0))
        offsets.append(np.full(n_per_plane, offset))
    world = np.concatenate(points)
    return world, MatchRows(np.arange(len(world)), np.concatenate(normals), np.concatenate(offsets))


def test_deskew_again_is_deskewing_the_raw_points_with_the_new_twist():
    raw = RNG.uniform(-30.0, 30.0, (500, 3))
    time_s = RNG.uniform(0.0, 0.1, 500)
    old, new = np.r_[5.0, 0.2, 0.0, 0.01, 0.0, 0.1], np.r_[6.0, -0.1, 0.05, 0.0, 0.02, 0.4]
    again = deskew_again(deskew_points(raw, time_s, old), time_s, old, new)
    assert np.allclose(again, deskew_points(raw, time_s, new), atol=1e-9)


def test_a_sweep_deskewed_with_its_true_motion_lands_on_the_true_pose():
    """The sweep was registered deskewed with the prediction (no turn) while the vehicle turned:
    its points, deskewed again with the true twist and solved on the rows it ended with, give the
    true pose back, without a search in the map; the first registration on the wrong deskewing was
    off by more than half a degree."""
    T_world_lidar = exp_se3(np.r_[2.0, 0.5, 0.0, 0.0, 0.0, 0.2])
    world, rows = street_points_world()
    at_stamp = transform_points(invert(T_world_lidar), world)  # where each point is, seen from the stamp
    time_s = RNG.uniform(0.0, 0.1, len(world))
    true_twist, predicted = np.r_[6.0, 0.0, 0.0, 0.0, 0.0, 0.5], np.r_[6.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    fired = deskew_points(at_stamp, time_s, -true_twist)  # the raw sweep the sensor measured
    as_predicted = deskew_points(fired, time_s, predicted)
    config = MappingConfig()
    first = solve_pose(
        T_world_lidar,
        as_predicted,
        lambda _q, _reach: rows,
        max_iterations=10,
        robust_scale_m=config.robust_scale_m,
    )
    first_error_deg = np.rad2deg(rotation_angle(first.T_target_source[:3, :3].T @ T_world_lidar[:3, :3]))
    assert first.matches is rows and first_error_deg > 0.5
    again = register_again(
        first.matches,
        deskew_again(as_predicted, time_s, predicted, true_twist),
        first.T_target_source,
        config,
        reference_information=np.eye(6),  # a weak belief: the rows know every direction better
    )
    assert again.iterations > 0 and again.degenerate_axes == 0
    assert np.allclose(again.T_target_source, T_world_lidar, atol=1e-6)
