"""The sweep's yaw rate solved beside its pose (registration.SweepTurn)."""

import numpy as np
from test_register_again import PLANES as STREET  # ground, two facades, a wall ahead and one behind
from test_register_again import street_points_world

from lidar3d.config import MappingConfig
from lidar3d.mapping.deskew import deskew_again, deskew_points
from lidar3d.mapping.registration import PosePrior, SweepTurn, solve_pose
from lidar3d.mapping.se3 import exp_se3, invert, transform_points

RNG = np.random.default_rng(11)
CONFIG = MappingConfig()
RATE_INFORMATION = (2.0 * 0.1) ** -2.0  # the vehicle model's yaw acceleration over one sweep


def _turning_sweep(planes: list, true_rate: float, predicted_rate: float):
    """A sweep fired while turning at ``true_rate`` (rad/s) at 6 m/s, deskewed with
    ``predicted_rate``: (pose at the stamp, points, firing times, rows, predicted twist)."""
    T_world_lidar = exp_se3(np.r_[2.0, 0.5, 0.0, 0.0, 0.0, 0.2])
    world, rows = street_points_world(planes)
    time_s = RNG.uniform(0.0, 0.1, len(world))
    true_twist, predicted = np.r_[6.0, 0.0, 0.0, 0.0, 0.0, true_rate], np.r_[6.0, 0.0, 0.0, 0.0, 0.0, predicted_rate]
    fired = deskew_points(transform_points(invert(T_world_lidar), world), time_s, -true_twist)
    return T_world_lidar, deskew_points(fired, time_s, predicted), time_s, rows, predicted


def _yaw_error_deg(T: np.ndarray, T_true: np.ndarray) -> float:
    R = T[:3, :3].T @ T_true[:3, :3]
    return float(np.rad2deg(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def _solve(T_true, points, rows, turn, *, with_prior: bool = True):
    """Registration from a guess 0.3 deg and 11 cm off, with a weak vehicle prior there (0.5 m and
    2 deg, also the reference of the degeneracy test) or none."""
    guess = T_true @ exp_se3(np.r_[0.1, -0.05, 0.0, 0.0, 0.0, np.radians(0.3)])
    prior = PosePrior(guess, np.diag(np.r_[np.full(3, 0.5**-2), np.full(3, np.radians(2.0) ** -2)]))
    return solve_pose(
        guess,
        points,
        lambda _q, _reach: rows,
        max_iterations=10,
        robust_scale_m=CONFIG.robust_scale_m,
        prior=prior if with_prior else None,
        reference_information=prior.information,
        turn=turn,
    )


def test_the_rate_column_is_the_derivative_of_the_rows():
    points = RNG.normal(size=(40, 3)) * 10.0
    time_s = RNG.uniform(0.0, 0.1, 40)
    turn = SweepTurn(time_s, np.r_[5.0, 0.3, 0.1], 1.0)
    normal = RNG.normal(size=(40, 3))
    normal /= np.linalg.norm(normal, axis=1)[:, None]
    R = exp_se3(np.r_[0.0, 0.0, 0.0, 0.1, -0.05, 0.5])[:3, :3]

    def rows(rate: float) -> np.ndarray:
        return np.einsum("ij,ij->i", normal, turn.turned(points, rate) @ R.T)

    h = 1e-6
    numeric = (rows(0.3 + h) - rows(0.3 - h)) / (2 * h)
    assert np.allclose(turn.column(normal, turn.turned(points, 0.3), np.arange(40), R), numeric, atol=1e-6)


def test_turning_the_points_is_deskewing_them_with_the_corrected_rate():
    """To first order in the sweep's motion: 6 m/s, 0.3 rad/s more, points up to 30 m away."""
    points = RNG.uniform(-30.0, 30.0, (500, 3))
    time_s = RNG.uniform(0.0, 0.1, 500)
    twist = np.r_[6.0, 0.1, 0.0, 0.0, 0.0, 0.4]
    corrected = twist + np.r_[0.0, 0.0, 0.0, 0.0, 0.0, 0.3]
    exact = deskew_again(points, time_s, twist, corrected)
    turned = SweepTurn(time_s, twist[:3], 1.0).turned(points, 0.3)
    assert np.abs(exact - points).max() > 0.5  # the correction itself is large ...
    assert np.abs(turned - exact).max() < 0.01  # ... its approximation within a centimetre


def test_a_turn_exit_the_prediction_missed_is_solved_with_the_rate():
    """The yaw rate fell from 0.5 to 0.2 rad/s (28 -> 11 deg/s) before the sweep; deskewed with
    the old rate, the pose-only registration takes the distortion into the yaw, the rate solved
    beside it gives the pose and the rate back."""
    T_true, points, time_s, rows, predicted = _turning_sweep(STREET, true_rate=0.2, predicted_rate=0.5)
    plain = _solve(T_true, points, rows, None)
    assert _yaw_error_deg(plain.T_target_source, T_true) > 0.3
    turned = _solve(T_true, points, rows, SweepTurn(time_s, predicted[:3], RATE_INFORMATION))
    assert turned.degenerate_axes == 0
    assert abs(turned.yaw_rate_correction_rad_s - (0.2 - 0.5)) < 0.01
    assert _yaw_error_deg(turned.T_target_source, T_true) < 0.02
    assert np.linalg.norm(turned.T_target_source[:3, 3] - T_true[:3, 3]) < 0.01


def test_a_scan_that_leaves_a_direction_to_the_prior_keeps_the_predicted_rate():
    """Between two long walls (no wall across the street) the position along it is the prior's:
    the rows' claim on the rate is not taken either."""
    T_true, points, time_s, rows, predicted = _turning_sweep(STREET[:3], true_rate=0.2, predicted_rate=0.5)
    turned = _solve(T_true, points, rows, SweepTurn(time_s, predicted[:3], RATE_INFORMATION))
    assert turned.degenerate_axes >= 1
    assert turned.yaw_rate_correction_rad_s == 0.0


def test_without_a_prior_the_rate_is_not_solved():
    T_true, points, time_s, rows, predicted = _turning_sweep(STREET, true_rate=0.2, predicted_rate=0.5)
    result = _solve(T_true, points, rows, SweepTurn(time_s, predicted[:3], RATE_INFORMATION), with_prior=False)
    assert result.iterations > 0 and result.yaw_rate_correction_rad_s == 0.0


def test_a_steady_sweep_is_registered_as_without_the_rate():
    """The prediction was right (both 0.3 rad/s): the correction the rows find is within the noise
    and dropped, and the pose is the pose-only registration's."""
    T_true, points, time_s, rows, predicted = _turning_sweep(STREET, true_rate=0.3, predicted_rate=0.3)
    noisy = points + RNG.normal(0.0, 0.01, points.shape)
    plain = _solve(T_true, noisy, rows, None)
    turned = _solve(T_true, noisy, rows, SweepTurn(time_s, predicted[:3], RATE_INFORMATION))
    assert turned.yaw_rate_correction_rad_s == 0.0
    assert np.allclose(turned.T_target_source, plain.T_target_source, atol=2e-4)
    assert np.allclose(turned.information, plain.information, rtol=0.05)
