"""The vehicle motion model and how registration uses it along degenerate directions."""

import numpy as np
import pytest

from lidar3d.config import MotionConfig
from lidar3d.mapping.motion_model import MotionModel
from lidar3d.mapping.registration import PlaneMap, PosePrior, observed_share, solve_pose
from lidar3d.mapping.se3 import pose_from_xyz_rpy, xyz_rpy_from_pose

# A sensor mounted with its x axis 30 degrees to the left of the direction of travel: the
# learned direction must not assume x-forward.
HEADING = np.radians(-30.0)
FORWARD = np.array([np.cos(HEADING), np.sin(HEADING), 0.0])


def _drive(model, n, rng, lateral_noise=0.05, speed=6.0, well_constrained=True):
    for _ in range(n):
        v = speed * FORWARD + rng.normal(0.0, lateral_noise, 3)
        model.update(np.r_[v, 0.0, 0.0, 0.02], well_constrained)


def test_direction_of_travel_is_learned_in_the_sensor_frame():
    model = MotionModel()
    _drive(model, 30, np.random.default_rng(1))
    assert model.established
    assert np.degrees(np.arccos(model.forward_axis @ FORWARD)) < 1.0


def test_vehicle_twist_drops_sideways_and_vertical_velocity():
    model = MotionModel()
    _drive(model, 30, np.random.default_rng(2))
    slipping = np.r_[6.0 * FORWARD + np.array([0.4, 0.7, -0.3]), 0.01, -0.02, 0.05]
    model.update(slipping, well_constrained=False)
    twist = model.vehicle_twist()
    axis = model.forward_axis
    assert np.linalg.norm(twist[:3] - (twist[:3] @ axis) * axis) < 1e-12
    assert twist[:3] @ axis == pytest.approx(slipping[:3] @ axis)
    np.testing.assert_array_equal(twist[3:], slipping[3:])  # rotation rates are kept


def test_reversing_counts_as_the_same_axis():
    model = MotionModel()
    rng = np.random.default_rng(3)
    _drive(model, 15, rng)
    _drive(model, 15, rng, speed=-3.0)
    assert model.forward_axis is not None
    assert abs(model.forward_axis @ FORWARD) > 0.999


def test_handheld_motion_keeps_the_plain_constant_velocity_model():
    model = MotionModel()
    rng = np.random.default_rng(4)
    for _ in range(200):
        direction = rng.normal(size=3)
        model.update(np.r_[2.0 * direction / np.linalg.norm(direction), 0.0, 0.0, 0.0], True)
    assert model.forward_axis is None
    np.testing.assert_array_equal(model.vehicle_twist(), model.twist)


def test_degenerate_scans_teach_nothing_and_a_cold_start_is_not_established():
    model = MotionModel()
    _drive(model, 50, np.random.default_rng(5), well_constrained=False)
    assert not model.established
    assert model.forward_axis is None


def test_yaw_rate_decays_while_the_heading_is_unobserved():
    model = MotionModel(yaw_rate_decay=0.5)
    model.update(np.r_[5.0, 0, 0, 0, 0, 0.2], well_constrained=True)
    model.update(np.r_[5.0, 0, 0, 0, 0, 0.2], well_constrained=False, heading_observed=False)
    assert model.twist[5] == pytest.approx(0.1)
    assert model.twist[0] == pytest.approx(5.0)


def test_prediction_is_smoothed_and_drops_sideways_velocity_after_a_degenerate_scan():
    model = MotionModel(prediction_smoothing=0.5)
    _drive(model, 30, np.random.default_rng(8), lateral_noise=0.0)
    before = model.prediction()
    jumped = np.r_[10.0 * FORWARD + np.array([0.5, 1.0, 0.0]), 0.0, 0.0, 0.02]
    model.update(jumped, well_constrained=True)
    np.testing.assert_allclose(model.prediction(), 0.5 * jumped + 0.5 * before)  # well constrained: kept
    model.update(jumped, well_constrained=False)
    prediction = model.prediction()
    axis = model.forward_axis
    assert np.linalg.norm(prediction[:3] - (prediction[:3] @ axis) * axis) < 1e-12
    np.testing.assert_allclose(model.twist, jumped)  # the measured twist itself is untouched


def _ground_and_wall():
    """Level ground plus one wall facing x: the lateral position is free, the rest is observed."""
    rng = np.random.default_rng(6)
    g = rng.uniform(-15, 15, size=(4000, 2))
    ground = np.c_[g, np.full(len(g), -1.8)]
    w = rng.uniform([-10, -1.5], [10, 6], size=(2000, 2))
    wall = np.c_[np.full(len(w), 12.0), w]
    return np.concatenate([ground, wall])


def _solve(points, T_init, **kw):
    target = PlaneMap(points, k=10, max_sq_dist=2.0)
    return solve_pose(
        T_init,
        points,
        lambda q, reach: target.rows(q, reach),
        max_iterations=10,
        min_rows=50,
        degeneracy_threshold=100.0,
        level_normal_z=0.9,
        **kw,
    )


def _prior(x, sigma_m=0.02, sigma_deg=0.5):
    information = np.diag(np.r_[np.full(3, sigma_m**-2.0), np.full(3, np.radians(sigma_deg) ** -2.0)])
    return PosePrior(pose_from_xyz_rpy(np.asarray(x, dtype=float)), information)


def test_unobserved_directions_take_the_prior_observed_ones_the_data():
    points = _ground_and_wall()
    T_init = pose_from_xyz_rpy(np.array([0.05, 0.8, 0.03, 0.0, 0.0, 0.0]))  # 0.8 m sideways
    loam = _solve(points, T_init)
    assert loam.degenerate_axes >= 1
    assert xyz_rpy_from_pose(loam.T_target_source)[1] == pytest.approx(0.8, abs=0.02)  # LOAM keeps the guess
    # The prior is 4 cm off in x, where the wall is seen: the data wins there.
    with_prior = _solve(points, T_init, prior=_prior([0.04, 0.1, 0.0, 0.0, 0.0, 0.0]))
    x = xyz_rpy_from_pose(with_prior.T_target_source)
    assert x[1] == pytest.approx(0.1, abs=0.005)  # the prior's lateral position
    assert abs(x[0]) < 0.005 and abs(x[2]) < 0.005  # observed directions solved from data
    share = observed_share(with_prior.information, _prior(np.zeros(6)).information)
    assert share[0] > 0.95 and share[2] > 0.95 and share[1] < 0.05


def test_a_turn_the_scan_sees_is_kept_against_a_prior_that_drives_straight():
    """Walls all round: a 3 degree yaw the prior does not expect (sigma 0.5 deg) is kept."""
    rng = np.random.default_rng(8)
    g = rng.uniform(-15, 15, size=(4000, 2))
    walls = [np.c_[np.full(1500, 12.0), rng.uniform([-10, -1.5], [10, 6], size=(1500, 2))]]
    walls.append(np.c_[rng.uniform(-10, 10, 1500), np.full(1500, 9.0), rng.uniform(-1.5, 6, 1500)])
    points = np.concatenate([np.c_[g, np.full(len(g), -1.8)], *walls])
    truth = pose_from_xyz_rpy(np.array([0.0, 0.0, 0.0, 0.0, 0.0, np.radians(3.0)]))
    source = (points - truth[:3, 3]) @ truth[:3, :3]  # the points as the turned sensor sees them
    target = PlaneMap(points, k=10, max_sq_dist=2.0)
    result = solve_pose(
        np.eye(4), source, target.rows, max_iterations=20, min_rows=50, level_normal_z=0.9, prior=_prior(np.zeros(6))
    )
    assert np.degrees(xyz_rpy_from_pose(result.T_target_source)[5]) == pytest.approx(3.0, abs=0.05)


def test_vehicle_prior_is_tight_sideways_and_loose_along_travel():
    model = MotionModel()
    _drive(model, 30, np.random.default_rng(2), lateral_noise=0.0)
    prior = model.prior(np.eye(4), 0.1, MotionConfig())
    covariance = np.linalg.inv(prior.information[:3, :3])
    along = FORWARD @ covariance @ FORWARD
    side = np.array([-FORWARD[1], FORWARD[0], 0.0])
    assert np.sqrt(along) == pytest.approx(MotionConfig().forward_accel_mps2 * 0.01, rel=1e-4)
    assert np.sqrt(side @ covariance @ side) == pytest.approx(MotionConfig().lateral_accel_mps2 * 0.01, rel=1e-4)
    np.testing.assert_allclose(prior.T_target_source[:3, 3], 0.1 * model.vehicle_twist()[:3], atol=1e-3)
