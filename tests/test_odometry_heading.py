"""The scan-to-scan odometry's yaw fused into the scan-to-submap registration: the Gaussian product
(PosePrior.fused_with), what the odometry's edge step knows about its yaw (the rows' marginal
information, less for a step that moved far from its guess), and a registration that takes from the
heading the yaw its rows do not hold."""

from __future__ import annotations

import numpy as np
import pytest

from lidar3d.config import MotionConfig
from lidar3d.mapping.odometry import OdometryStep, _marginal_yaw_information
from lidar3d.mapping.registration import PlaneMap, PosePrior, _xyz_rpy, solve_pose
from lidar3d.mapping.se3 import exp_se3
from lidar3d.mapping.tracker import _fused


def _pose_xyz_yaw(x: float, y: float, yaw_rad: float) -> np.ndarray:
    return exp_se3(np.array([0.0, 0.0, 0.0, 0.0, 0.0, yaw_rad])) @ _translation(x, y)


def _translation(x: float, y: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, 3] = (x, y)
    return T


def test_fused_means_weigh_each_belief_by_its_information() -> None:
    """Two beliefs about the yaw (sigmas 1 and 2 mrad) meet at 4/5 of the way to the sharper one's
    mean; the translation, informed by the first alone, stays at the first's mean."""
    first_info = np.diag([1e4, 1e4, 1e4, 1e6, 1e6, 1e6])
    second_info = np.zeros((6, 6))
    second_info[5, 5] = 0.25e6
    first = PosePrior(_translation(1.0, 2.0), first_info)
    second = PosePrior(_pose_xyz_yaw(0.0, 0.0, 0.01), second_info)
    fused = first.fused_with(second)
    x = _xyz_rpy(fused.T_target_source)
    assert x[5] == pytest.approx(0.01 * 0.25 / 1.25, abs=1e-9)
    np.testing.assert_allclose(x[:2], [1.0, 2.0], atol=1e-9)
    np.testing.assert_allclose(fused.information, first_info + second_info)


def test_fused_yaw_difference_is_wrapped() -> None:
    """Yaws of +179 and -179 degrees meet at 180, not at 0."""
    info = np.zeros((6, 6))
    info[5, 5] = 1e4
    full = np.diag([1.0, 1.0, 1.0, 1.0, 1.0, 1e4])
    fused = PosePrior(_pose_xyz_yaw(0, 0, np.radians(179.0)), full).fused_with(
        PosePrior(_pose_xyz_yaw(0, 0, np.radians(-179.0)), info)
    )
    assert abs(abs(np.degrees(_xyz_rpy(fused.T_target_source)[5])) - 180.0) < 1e-6


def _edge_information(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A random (3,3) ``J^T J`` over x, y, yaw and the (6,6) information holding it on those axes."""
    J = np.random.default_rng(seed).normal(size=(50, 3))
    h = J.T @ J
    information = np.zeros((6, 6))
    information[np.ix_([0, 1, 5], [0, 1, 5])] = h
    return h, information


def test_marginal_yaw_information_is_the_schur_complement() -> None:
    h, information = _edge_information(3)
    assert _marginal_yaw_information(information) == pytest.approx(1.0 / np.linalg.inv(h)[2, 2])
    # A corridor: nothing holds x; the yaw keeps what the rows say about it beside y.
    information[0, :] = 0.0
    information[:, 0] = 0.0
    h_y_yaw = information[np.ix_([1, 5], [1, 5])]
    assert _marginal_yaw_information(information) == pytest.approx(1.0 / np.linalg.inv(h_y_yaw)[1, 1])


def test_xy_covariance_is_the_marginal_of_the_edge_rows() -> None:
    h, information = _edge_information(4)
    observed = OdometryStep(np.eye(4), False, 100, 50, True, information, 0.0)
    covariance = observed.xy_covariance()
    assert covariance is not None
    np.testing.assert_allclose(covariance, np.linalg.inv(h)[:2, :2])
    # A degenerate edge step (edge_observed False) or none at all observes no translation.
    assert OdometryStep(np.eye(4), False, 100, 50, False, information, 0.0).xy_covariance() is None
    assert OdometryStep(np.eye(4), False, 100, 0).xy_covariance() is None
    assert OdometryStep(np.eye(4), False, 100, 50, True, np.zeros((6, 6)), 0.0).xy_covariance() is None


def test_a_step_that_travelled_far_knows_its_yaw_less() -> None:
    """Rows at sigma 0.02 deg: a step that moved 0.02 deg from its guess keeps nearly their
    information; one that had to turn 2 deg (a sharp turn its guess did not know) is worth a
    sigma of about 1 deg (half its travel); no rows on the yaw, nothing."""
    information = np.zeros((6, 6))
    information[5, 5] = np.radians(0.02) ** -2

    def step(edge_information: np.ndarray | None, travel_rad: float) -> OdometryStep:
        return OdometryStep(np.eye(4), False, 100, 100, True, edge_information, travel_rad)

    near = step(information, np.radians(0.02)).yaw_information(0.5)
    far = step(information, np.radians(2.0)).yaw_information(0.5)
    assert near == pytest.approx(1.0 / (np.radians(0.02) ** 2 + np.radians(0.01) ** 2))
    assert np.degrees(far**-0.5) == pytest.approx(1.0, abs=0.01)
    assert step(np.zeros((6, 6)), 0.1).yaw_information(0.5) == 0.0
    assert step(None, 0.1).yaw_information(0.5) == 0.0
    assert step(information, np.radians(2.0)).yaw_information(0.0) == pytest.approx(information[5, 5])


def test_registration_takes_the_yaw_the_submap_leaves_free_from_the_heading() -> None:
    """A floor and a round silo around the sensor hold the translation, roll and pitch, but hardly
    the yaw (a rotation about the silo's axis moves no point off its surface): with the odometry
    heading fused in as at a cold start (a weak belief at the guess, :func:`_fused`), the yaw is
    the heading's and the rows hold the rest."""
    rng = np.random.default_rng(4)
    floor = np.c_[rng.uniform(-20, 20, (6000, 2)), np.full(6000, -1.8)]
    angle = rng.uniform(0, 2 * np.pi, 6000)
    silo = np.c_[8.0 * np.cos(angle), 8.0 * np.sin(angle), rng.uniform(-1.8, 4.0, 6000)]
    target = PlaneMap(np.concatenate([floor, silo]), k=10, max_sq_dist=1.4**2)
    source = np.concatenate([floor[::5], silo[::5]])
    guess = _translation(0.05, -0.05)
    heading_info = np.zeros((6, 6))
    heading_info[5, 5] = np.radians(0.05) ** -2
    heading = PosePrior(_pose_xyz_yaw(0.0, 0.0, np.radians(2.0)), heading_info)
    prior = _fused(None, heading, guess, MotionConfig())
    assert prior is not None
    solved = solve_pose(guess, source, target.rows, robust_scale_m=0.05, prior=prior)
    x = _xyz_rpy(solved.T_target_source)
    assert solved.information[5, 5] < 0.2 * heading_info[5, 5]  # the rows barely see the yaw
    assert np.degrees(x[5]) == pytest.approx(2.0, abs=0.05)
    np.testing.assert_allclose(x[:3], 0.0, atol=0.02)  # the rows pull the translation to the truth
    assert _fused(None, None, guess, MotionConfig()) is None  # no heading, no prior: LOAM remapping
