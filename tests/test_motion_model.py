"""The vehicle motion model and how registration uses it along degenerate directions."""

import numpy as np
import pytest

from lidar3d.mapping.motion_model import MotionModel
from lidar3d.mapping.registration import PlaneMap, solve_pose
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
        target.rows,
        max_iterations=10,
        min_rows=50,
        degeneracy_threshold=100.0,
        level_normal_z=0.9,
        **kw,
    )


def test_degenerate_directions_take_the_prior_instead_of_the_guess():
    points = _ground_and_wall()
    T_init = pose_from_xyz_rpy(np.array([0.05, 0.8, 0.03, 0.0, 0.0, 0.0]))  # 0.8 m sideways
    T_prior = pose_from_xyz_rpy(np.array([0.0, 0.1, 0.0, 0.0, 0.0, 0.0]))
    loam = _solve(points, T_init)
    assert loam.degenerate_axes >= 1
    assert xyz_rpy_from_pose(loam.T_target_source)[1] == pytest.approx(0.8, abs=0.02)  # LOAM keeps the guess
    with_prior = _solve(points, T_init, T_prior=T_prior)
    x = xyz_rpy_from_pose(with_prior.T_target_source)
    assert x[1] == pytest.approx(0.1, abs=0.02)  # the prior's lateral position
    assert abs(x[0]) < 0.01 and abs(x[2]) < 0.01  # observed directions still solved from data


def test_yaw_is_held_at_the_prior_when_the_scene_is_badly_degenerate():
    """Ground plus one narrow wall patch (a pole seen on open land): lateral position and the
    rotation about the patch are both degenerate; the one observed direction mixes x and yaw."""
    rng = np.random.default_rng(7)
    g = rng.uniform(-15, 15, size=(4000, 2))
    ground = np.c_[g, np.full(len(g), -1.8)]
    p = rng.uniform([4.25, -1.5], [5.75, 8.5], size=(800, 2))
    patch = np.c_[np.full(len(p), 12.0), p]
    points = np.concatenate([ground, patch])
    T_init = pose_from_xyz_rpy(np.array([0.3, 0.0, 0.0, 0.0, 0.0, np.radians(4.0)]))
    T_prior = pose_from_xyz_rpy(np.array([0.0, 0.0, 0.0, 0.0, 0.0, np.radians(1.0)]))
    free = _solve(points, T_init, T_prior=T_prior)
    held = _solve(points, T_init, T_prior=T_prior, hold_yaw_min_degenerate=2)
    assert free.degenerate_axes == held.degenerate_axes == 2
    assert abs(np.degrees(xyz_rpy_from_pose(free.T_target_source)[5]) - 1.0) > 0.2
    x = xyz_rpy_from_pose(held.T_target_source)
    assert np.degrees(x[5]) == pytest.approx(1.0, abs=1e-9)
    # The patch is then explained by translation: its points stay on the plane x = 12.
    moved = patch @ held.T_target_source[:3, :3].T + held.T_target_source[:3, 3]
    assert np.abs(moved[:, 0] - 12.0).mean() < 0.01
