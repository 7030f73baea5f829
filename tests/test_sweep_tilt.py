"""The roll and pitch within a sweep beyond its constant twist (lidar3d.mapping.sweep_tilt): the model,
its fit to a scene, the prior learned from the drive, and a shaking drive tracked with it."""

from __future__ import annotations

import dataclasses
import functools

import numpy as np
import pytest

from lidar3d.config import Config
from lidar3d.features.frontend import prepare_scan
from lidar3d.mapping.registration import PlaneMap
from lidar3d.mapping.se3 import invert
from lidar3d.mapping.sweep_tilt import SweepTilt, TiltPrior, estimate_sweep_tilt, knot_times
from lidar3d.pipeline import run_slam

SWEEP_S = 0.1


def _street(rng: np.random.Generator, n: int) -> np.ndarray:
    """A flat road (z = -1.8 m, 40 m x 24 m around the sensor) between two 6 m walls at y = +-12 m
    and a wall across at x = 20 m: every direction of the sensor sees ground and a wall."""
    ground = np.column_stack([rng.uniform(-20, 20, n), rng.uniform(-12, 12, n), np.full(n, -1.8)])
    left = np.column_stack([rng.uniform(-20, 20, n // 2), np.full(n // 2, 12.0), rng.uniform(-1.8, 4, n // 2)])
    right = left * np.array([1.0, -1.0, 1.0])
    front = np.column_stack([np.full(n // 2, 20.0), rng.uniform(-12, 12, n // 2), rng.uniform(-1.8, 4, n // 2)])
    back = front * np.array([-1.0, 1.0, 1.0])
    return np.concatenate([ground, left, right, front, back])


def _fired_at(points: np.ndarray) -> np.ndarray:
    """The time (s) a spinning sensor fires at each point: its azimuth over one sweep."""
    azimuth = np.mod(np.arctan2(points[:, 1], points[:, 0]), 2 * np.pi)
    return azimuth / (2 * np.pi) * SWEEP_S


def _shaken(knots_deg: np.ndarray, knot_times_s: np.ndarray) -> SweepTilt:
    """Knots without their mean and straight line (the pose's and the twist's part)."""
    basis = np.column_stack([np.ones_like(knot_times_s), knot_times_s])
    tilt = np.radians(knots_deg)
    line = basis @ np.linalg.lstsq(basis, tilt, rcond=None)[0]
    return SweepTilt(knot_times_s, tilt - line)


def test_apply_rotates_each_point_by_the_tilt_at_its_time() -> None:
    knots_s = np.array([0.0, 0.05, 0.1])
    tilt = SweepTilt(knots_s, np.radians([[0.0, 0.0], [0.2, -0.1], [-0.2, 0.1]]))
    points = np.array([[10.0, 0.0, 0.0], [0.0, 10.0, 1.0], [5.0, 5.0, -1.0]])
    times = np.array([0.0, 0.05, 0.075])
    moved = tilt.apply(points, times)
    for p, t, q in zip(points, times, moved):
        roll, pitch = np.interp(t, knots_s, tilt.roll_pitch_rad[:, 0]), np.interp(t, knots_s, tilt.roll_pitch_rad[:, 1])
        np.testing.assert_allclose(q, p + np.cross([roll, pitch, 0.0], p), atol=1e-12)
    np.testing.assert_array_equal(SweepTilt(knots_s, np.zeros((3, 2))).apply(points, times), points)


def test_knots_span_the_sweep_at_most_the_spacing_apart() -> None:
    times = np.linspace(0.0, 0.1, 1000)
    np.testing.assert_allclose(knot_times(times, 0.025), [0.0, 0.025, 0.05, 0.075, 0.1])
    assert len(knot_times(times, 0.2)) == 3  # never fewer than three: two would be the twist's line
    assert knot_times(times, 0.0) is None
    assert knot_times(np.zeros(5), 0.025) is None  # no span: a sweep without times


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_fit_recovers_the_shaking_of_a_sweep(seed: int) -> None:
    """A sweep fired while the sensor shook by a few tenths of a degree (several cm at 20 m), registered at its
    true pose against the exact scene: the knots come back within 0.03 deg, and the points moved by
    them lie on the scene again."""
    rng = np.random.default_rng(seed)
    target = PlaneMap(_street(rng, 20000), k=10, max_sq_dist=1.4**2)
    truth_points = _street(rng, 3000)
    times = _fired_at(truth_points)
    knots_s = knot_times(times, 0.025)
    truth = _shaken(rng.uniform(-0.4, 0.4, (len(knots_s), 2)), knots_s)
    # what the sensor reports: the true points seen through the tilt, i.e. moved by its inverse
    measured = SweepTilt(knots_s, -truth.roll_pitch_rad).apply(truth_points, times)
    fitted = estimate_sweep_tilt(
        np.eye(4),
        measured,
        times,
        target.rows,
        knot_spacing_s=0.025,
        prior_sigma_rad=np.radians(1.0),
        robust_scale_m=0.1,
        min_rows=100,
    )
    assert fitted is not None
    np.testing.assert_allclose(np.degrees(fitted.roll_pitch_rad), np.degrees(truth.roll_pitch_rad), atol=0.03)
    before = np.abs(measured - truth_points).max()
    after = np.abs(fitted.apply(measured, times) - truth_points).max()
    assert before > 0.05 and after < 0.2 * before, (before, after)


def test_a_still_sweep_gets_no_tilt_and_no_rows_gives_none() -> None:
    rng = np.random.default_rng(3)
    target = PlaneMap(_street(rng, 20000), k=10, max_sq_dist=1.4**2)
    points = _street(rng, 3000)
    times = _fired_at(points)
    fit = functools.partial(
        estimate_sweep_tilt, knot_spacing_s=0.025, prior_sigma_rad=np.radians(1.0), robust_scale_m=0.1, min_rows=100
    )
    still = fit(np.eye(4), points, times, target.rows)
    assert still is not None and np.degrees(still.max_rad) < 0.01
    far = np.eye(4)
    far[:3, 3] = [500.0, 0.0, 0.0]  # nothing of the scene within reach
    assert fit(far, points, times, target.rows) is None
    assert fit(np.eye(4), points, np.zeros(len(points)), target.rows) is None


def test_the_prior_learns_how_much_the_drive_shakes() -> None:
    """Knots of noise only narrow the prior to the vehicle model's floor; knots of 0.3 deg widen it
    to about that."""
    prior = functools.partial(
        TiltPrior, start_sigma_rad=np.radians(5.0), tilt_accel_rad_s2=0.5, sweep_period_s=SWEEP_S, smoothing=0.2
    )
    floor_deg = np.degrees(0.5 * SWEEP_S**2 / 8)
    still, shaking = prior(), prior()
    knots_s = np.linspace(0.0, SWEEP_S, 5)
    rng = np.random.default_rng(4)
    for _ in range(100):
        still.learn(SweepTilt(knots_s, np.zeros((5, 2)), variance_rad2=0.0))
        shaking.learn(SweepTilt(knots_s, np.radians(rng.normal(0.0, 0.3, (5, 2))), variance_rad2=np.radians(0.02) ** 2))
    assert np.degrees(still.sigma_rad) == pytest.approx(floor_deg)
    assert 0.2 < np.degrees(shaking.sigma_rad) < 0.4


def test_a_shaking_drive_is_tracked_closer_with_the_tilt() -> None:
    """The first 6 s of the rough forest trail (0.3 deg of vibration at 5-20 Hz), loop closure off:
    registering each sweep moved by its tilt keeps the track closer to the truth than without."""
    sim = pytest.importorskip("lidar3d.sim")
    simulation = sim.Simulation("forest_trail", seed=0, duration_s=6.0)
    config = Config()
    scans = [prepare_scan(s.scan, config) for s in simulation.scans()]
    truth = simulation.ground_truth.T_world_lidar
    errors = {}
    for spacing_s in (0.0, 0.025):
        run = dataclasses.replace(
            config,
            mapping=dataclasses.replace(config.mapping, tilt_knot_spacing_s=spacing_s),
            loop=dataclasses.replace(config.loop, enabled=False),
        )
        estimate = run_slam(scans, run).trajectory.T_world_lidar
        relative = np.einsum("ij,njk->nik", invert(truth[0]), truth[: len(estimate)])
        errors[spacing_s] = float(np.sqrt(np.mean(np.sum((estimate[:, :3, 3] - relative[:, :3, 3]) ** 2, axis=1))))
    assert errors[0.025] < 0.9 * errors[0.0], errors
