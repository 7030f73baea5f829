"""The vehicle motion model and how registration uses it along degenerate directions."""

import numpy as np
import pytest

from lidar3d.config import MotionConfig
from lidar3d.mapping.motion_model import MotionModel, acceleration_sigmas, nominal_step_information
from lidar3d.mapping.registration import PlaneMap, PosePrior, observed_share, solve_pose, unobserved_directions
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
    config = MotionConfig()  # _drive turns at 0.02 rad/s: the lever's part is 0.5 m x 0.02 rad/s x 0.1 s
    expected = np.hypot(config.lateral_accel_mps2 * 0.01, config.lever_sigma_m * 0.02 * 0.1)
    assert np.sqrt(side @ covariance @ side) == pytest.approx(expected, rel=1e-4)
    np.testing.assert_allclose(prior.T_target_source[:3, 3], 0.1 * model.vehicle_twist()[:3], atol=1e-3)


def _sideways(model, prior):
    side = np.cross([0.0, 0.0, 1.0], model.forward_axis)
    side /= np.linalg.norm(side)
    return side, float(np.sqrt(side @ np.linalg.inv(prior.information[:3, :3]) @ side))


def test_in_a_turn_the_prior_leaves_the_sideways_motion_to_the_scan_by_the_lever_uncertainty():
    """A sensor ahead of the rear axle moves sideways at lever x yaw rate; the prior's sideways
    sigma grows by the lever's uncertainty times the yaw rate (0.5 m x 0.5 rad/s x 0.1 s)."""
    model = MotionModel()
    _drive(model, 30, np.random.default_rng(2), lateral_noise=0.0)
    config = MotionConfig()
    model.update(np.r_[6.0 * FORWARD, 0.0, 0.0, 0.5], well_constrained=True)
    _, sigma = _sideways(model, model.prior(np.eye(4), 0.1, config))
    assert sigma == pytest.approx(np.hypot(config.lateral_accel_mps2 * 0.01, 0.5 * 0.5 * 0.1), rel=1e-3)
    model.update(np.r_[6.0 * FORWARD, 0.0, 0.0, 0.0], well_constrained=True)
    _, straight = _sideways(model, model.prior(np.eye(4), 0.1, config))
    assert straight == pytest.approx(config.lateral_accel_mps2 * 0.01, rel=1e-3)


def test_a_known_lever_carries_its_sideways_velocity_in_a_turn():
    model = MotionModel(lever_m=0.35)
    _drive(model, 30, np.random.default_rng(2), lateral_noise=0.0)
    model.update(np.r_[6.0 * FORWARD, 0.0, 0.0, 0.5], well_constrained=False)
    side, _ = _sideways(model, model.prior(np.eye(4), 0.1, MotionConfig()))
    twist = model.vehicle_twist()
    assert twist[:3] @ side == pytest.approx(0.35 * 0.5, rel=1e-3)  # left turn: the nose swings left
    assert twist[:3] @ model.forward_axis == pytest.approx(6.0, rel=1e-3)


def test_a_twist_jump_the_vehicle_cannot_make_is_clipped_to_its_acceleration_bounds():
    bound = 3.0 * acceleration_sigmas(MotionConfig())  # 6 m/s^2 along travel, 6 rad/s^2 in yaw
    model = MotionModel(change_bound=bound)
    _drive(model, 30, np.random.default_rng(2), lateral_noise=0.0)
    steady = model.twist.copy()
    model.update(np.r_[6.0 * FORWARD, 0.0, 0.0, 0.02 + 0.61], well_constrained=True, dt_s=0.1)  # +35 deg/s
    assert model.twist[5] == pytest.approx(0.02 + 0.6)  # 6 rad/s^2 x 0.1 s
    model.update(steady, well_constrained=True, dt_s=0.1)
    model.update(np.r_[6.4 * FORWARD, 0.0, 0.0, 0.05], well_constrained=True, dt_s=0.1)  # within the bounds
    np.testing.assert_allclose(model.twist, np.r_[6.4 * FORWARD, 0.0, 0.0, 0.05], atol=1e-12)
    model.update(np.r_[9.0 * FORWARD, 0.0, 0.0, 0.05], well_constrained=True, dt_s=0.1)  # +2.6 m/s in 0.1 s
    assert model.twist[:3] @ model.forward_axis == pytest.approx(7.0, abs=1e-6)


def test_a_cold_start_takes_the_measured_twist_whole():
    model = MotionModel(change_bound=3.0 * acceleration_sigmas(MotionConfig()))
    model.update(np.r_[8.0, 0.0, 0.0, 0.0, 0.0, 0.3], well_constrained=True, dt_s=0.1)
    np.testing.assert_array_equal(model.twist, [8.0, 0.0, 0.0, 0.0, 0.0, 0.3])


def test_unobserved_directions_compare_the_rows_with_the_reference_in_its_own_units():
    reference = np.diag([1.0 / 0.02**2, 1.0 / 0.02**2, 1.0 / 0.02**2, 1e4, 1e4, 1e4])
    # The rows know x to 1 cm (4x the reference), y to 4 cm (a quarter), the rest well; z and yaw
    # are coupled, so the test must work on directions, not on the diagonal.
    information = np.diag([1.0 / 0.01**2, 1.0 / 0.04**2, 1e5, 1e6, 1e6, 1e6])
    information[2, 5] = information[5, 2] = 2e5
    count, projector = unobserved_directions(information, reference)
    assert count == 1
    step = np.array([0.1, 0.2, 0.3, 0.01, 0.02, 0.03])
    kept = projector @ step
    assert kept[1] == pytest.approx(0.0, abs=1e-12)  # the unobserved lateral step is removed
    np.testing.assert_allclose(kept[[0, 2, 3, 4, 5]], step[[0, 2, 3, 4, 5]], atol=1e-12)
    # Twenty times the information along y (5x the reference) makes it observed.
    information[1, 1] *= 20.0
    assert unobserved_directions(information, reference) == (0, pytest.approx(np.eye(6)))


def test_a_wall_on_open_ground_leaves_the_lateral_direction_to_the_reference():
    points = _ground_and_wall()
    reference = nominal_step_information(MotionConfig(), 0.1)
    T_init = pose_from_xyz_rpy(np.array([0.05, 0.8, 0.03, 0.0, 0.0, 0.0]))
    result = _solve(points, T_init, reference_information=reference)
    assert result.degenerate_axes == 1
    x = xyz_rpy_from_pose(result.T_target_source)
    assert x[1] == pytest.approx(0.8, abs=0.02)  # kept at the guess (no prior)
    assert abs(x[0]) < 0.005 and abs(x[2]) < 0.005


def test_few_rows_that_pin_every_direction_are_not_degenerate():
    """LeGO-LOAM's fixed eigenvalue threshold (100 unit-normal rows) calls a scene with 60 points on
    each of two walls degenerate; their rows still know x and y to a fraction of a millimetre."""
    rng = np.random.default_rng(7)
    g = rng.uniform(-15, 15, size=(3000, 2))
    ground = np.c_[g, np.full(len(g), -1.8)]
    w = rng.uniform([-10, -1.5], [10, 6], size=(60, 2))
    walls = np.concatenate([np.c_[np.full(60, 12.0), w], np.c_[w[:, 0], np.full(60, 9.0), w[:, 1]]])
    points = np.concatenate([ground, walls])
    target = PlaneMap(np.concatenate([ground, _dense_walls(rng)]), k=10, max_sq_dist=2.0)
    common = {"max_iterations": 10, "min_rows": 50, "level_normal_z": 0.9}
    T_init = pose_from_xyz_rpy(np.array([0.03, -0.02, 0.01, 0.0, 0.0, 0.0]))
    loam = solve_pose(T_init, points, lambda q, reach: target.rows(q, reach), degeneracy_threshold=100.0, **common)
    assert loam.degenerate_axes >= 1
    reference = nominal_step_information(MotionConfig(), 0.1)
    ours = solve_pose(T_init, points, lambda q, reach: target.rows(q, reach), reference_information=reference, **common)
    assert ours.degenerate_axes == 0
    np.testing.assert_allclose(xyz_rpy_from_pose(ours.T_target_source)[:3], 0.0, atol=0.002)


def _dense_walls(rng):
    w = rng.uniform([-10, -1.5], [10, 6], size=(3000, 2))
    return np.concatenate([np.c_[np.full(len(w), 12.0), w], np.c_[w[:, 0], np.full(len(w), 9.0), w[:, 1]]])


def _forward_sigma_after(offsets_m):
    """The prior's sigma along the direction of travel after registrations that landed
    ``offsets_m`` ahead of each prior's mean."""
    model = MotionModel()
    _drive(model, 30, np.random.default_rng(9), lateral_noise=0.0)
    config = MotionConfig()
    T = np.eye(4)
    for offset in offsets_m:
        prior = model.prior(T, 0.1, config)
        T = prior.T_target_source.copy()
        T[:3, 3] += offset * model.forward_axis
        model.learn_innovation(prior, T, config.innovation_smoothing)
    prior = model.prior(T, 0.1, config)
    return float(np.sqrt(model.forward_axis @ np.linalg.inv(prior.information[:3, :3]) @ model.forward_axis))


def test_a_persistent_prediction_error_widens_the_prior_and_registration_noise_does_not():
    nominal = MotionConfig().forward_accel_mps2 * 0.1**2
    assert _forward_sigma_after([0.0] * 10) == pytest.approx(nominal, rel=1e-3)
    braking = _forward_sigma_after([-0.08] * 10)  # the model keeps predicting too far
    assert braking > 3.0 * nominal
    jitter = _forward_sigma_after([0.08, -0.08] * 5)  # a registration error and its echo
    assert jitter == pytest.approx(nominal, rel=1e-3)
