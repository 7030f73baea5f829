"""The pose-error Kalman filter behind the health flag's ``pose_sigma_m``: it grows as the vehicle
model allows where the scans say nothing and stays at the scans' level where they measure."""

from __future__ import annotations

import numpy as np
import pytest

from lidar3d.config import MotionConfig
from lidar3d.mapping.pose_uncertainty import PoseUncertainty
from lidar3d.mapping.se3 import pose_from_xyz_rpy

CONFIG = MotionConfig()
DT_S = 0.1


def _rows(sigmas: list[float]) -> np.ndarray:
    """(6,6) rows' information over ``[tx, ty, tz, roll, pitch, yaw]`` with these sigmas (inf: none)."""
    return np.diag([0.0 if np.isinf(s) else s**-2.0 for s in sigmas])


WELL_OBSERVED = _rows([0.002, 0.002, 0.002, 1e-4, 1e-4, 1e-4])
NO_ALONG_TRACK = _rows([np.inf, 0.002, 0.002, 1e-4, 1e-4, 1e-4])  # a walled canyon along x


def test_the_first_scan_is_certain_and_well_observed_scans_stay_at_their_own_level():
    filter_ = PoseUncertainty(CONFIG)
    assert not filter_.add(np.eye(4), 0.0, WELL_OBSERVED).any()  # the first scan defines the map
    for _ in range(50):
        covariance = filter_.add(np.eye(4), DT_S, WELL_OBSERVED)
    assert np.sqrt(covariance[3, 3]) < 0.002 and np.sqrt(covariance[2, 2]) < 1e-4


def test_an_unobserved_direction_grows_as_the_acceleration_bound_allows():
    """Along x nothing is measured for 1 s: the velocity's random walk of ``sigma_a dt`` per scan
    (2 m/s^2) makes it ``sigma_a sqrt(dt t^3 / 3)`` = 0.37 m uncertain (the discrete sum is within
    a few per cent), while the measured directions stay at millimetres."""
    filter_ = PoseUncertainty(CONFIG)
    filter_.add(np.eye(4), 0.0, WELL_OBSERVED)
    for _ in range(10):
        covariance = filter_.add(np.eye(4), DT_S, NO_ALONG_TRACK)
    expected = CONFIG.forward_accel_mps2 * np.sqrt(DT_S * 1.0**3 / 3.0)
    assert np.sqrt(covariance[3, 3]) == pytest.approx(expected, rel=0.1)
    assert np.sqrt(covariance[4, 4]) < 0.002
    # Two observed scans pin the position and its rate again.
    for _ in range(3):
        covariance = filter_.add(np.eye(4), DT_S, WELL_OBSERVED)
    assert np.sqrt(covariance[3, 3]) < 0.01


def test_a_direction_measured_every_other_scan_to_centimetres_stays_centimetres():
    """The forest trail: along x the scans know the pose about as well as the vehicle model (3 cm),
    on every other scan; the uncertainty stays bounded instead of counting as dead reckoning."""
    filter_ = PoseUncertainty(CONFIG)
    filter_.add(np.eye(4), 0.0, WELL_OBSERVED)
    weak = _rows([0.03, 0.002, 0.002, 1e-4, 1e-4, 1e-4])
    sigmas = [np.sqrt(filter_.add(np.eye(4), DT_S, weak if k % 2 else None)[3, 3]) for k in range(200)]
    assert max(sigmas) < 0.05 and sigmas[-1] == pytest.approx(sigmas[-3], rel=1e-3)  # bounded, steady


def test_the_rows_are_taken_in_the_frame_of_the_pose():
    """Rows that know only the world y (a wall along x) seen from a lidar turned 90 deg about z:
    in the lidar frame that is its x, so the lidar's y is the unobserved direction."""
    turned = pose_from_xyz_rpy(np.array([0.0, 0.0, 0.0, 0.0, 0.0, np.pi / 2]))
    filter_ = PoseUncertainty(CONFIG)
    filter_.add(turned, 0.0, WELL_OBSERVED)
    for _ in range(30):  # 3 s: the sideways bound of 0.5 m/s^2 reaches 0.47 m
        covariance = filter_.add(turned, DT_S, NO_ALONG_TRACK)
    assert np.sqrt(covariance[4, 4]) > 0.1 > 0.002 > np.sqrt(covariance[3, 3])


def test_a_scan_without_registration_only_predicts():
    filter_ = PoseUncertainty(CONFIG)
    filter_.add(np.eye(4), 0.0, WELL_OBSERVED)
    before = filter_.add(np.eye(4), DT_S, WELL_OBSERVED)
    after = filter_.add(np.eye(4), DT_S, None)
    assert (np.diag(after) > np.diag(before)).all()
    nan_rows = np.full((6, 6), np.nan)
    assert (np.diag(filter_.add(np.eye(4), DT_S, nan_rows)) > np.diag(after)).all()


def test_the_update_after_a_single_prediction_needs_no_inverse():
    """One prediction leaves a singular covariance (one acceleration drives the pose and its rate;
    with dt = 0.5 s exactly singular in floating point): the update must not invert it."""
    filter_ = PoseUncertainty(CONFIG)
    filter_.add(np.eye(4), 0.0, None)
    covariance = filter_.add(np.eye(4), 0.5, NO_ALONG_TRACK)
    assert np.isfinite(covariance).all() and np.sqrt(covariance[4, 4]) < 0.002
    assert np.sqrt(covariance[3, 3]) == pytest.approx(CONFIG.forward_accel_mps2 * 0.5**2 / 2.0)
