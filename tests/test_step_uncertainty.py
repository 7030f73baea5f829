"""Per-step covariances from the registration: dead reckoning grows where the scans leave an axis
to the vehicle model, and a loop's misclosure lands on those steps, not on the observed ones."""

from __future__ import annotations

import numpy as np

from lidar3d.config import MotionConfig
from lidar3d.loop import PoseGraph
from lidar3d.mapping.se3 import exp_se3, invert
from lidar3d.mapping.step_uncertainty import StepUncertainty, tangent_information

ODO_SIGMAS = np.array([np.radians(0.05)] * 3 + [0.01] * 3)
LOOP_INFO = np.diag([1 / np.radians(0.1) ** 2] * 3 + [1 / 0.02**2] * 3)
DT_S = 0.1


def _prior_information() -> np.ndarray:
    """A prior as the motion model gives it (solver order: translation, then roll, pitch, yaw)."""
    return np.diag([1 / 0.02**2, 1 / 0.005**2, 1 / 0.01**2, 1 / 0.005**2, 1 / 0.005**2, 1 / 0.02**2])


def _rows(observed_along_track: bool) -> np.ndarray:
    """Registration information: millimetres everywhere, or nothing along x (a corridor)."""
    information = np.diag([1e6] * 6)
    if not observed_along_track:
        information[0, 0] = 0.0
    return information


def test_tangent_information_swaps_the_blocks_and_rotates_the_translation():
    information = np.diag([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])  # tx, ty, tz, roll, pitch, yaw
    T = np.eye(4)
    T[:3, :3] = exp_se3(np.array([0, 0, 0, 0, 0, np.pi / 2]))[:3, :3]  # lidar x along world y
    tangent = tangent_information(information, T)
    np.testing.assert_allclose(np.diag(tangent), [5.0, 4.0, 6.0, 2.0, 1.0, 3.0], atol=1e-12)


def test_observed_scans_add_their_posterior_and_corridor_scans_dead_reckon():
    steps = StepUncertainty(MotionConfig())
    for _ in range(10):
        steps.add(np.eye(4), DT_S, _rows(True), _prior_information())
    observed = steps.take()
    assert np.sqrt(observed[3, 3]) < 1e-2  # ten millimetre-sized scans
    for _ in range(10):
        steps.add(np.eye(4), DT_S, _rows(False), _prior_information())
    corridor = steps.take()
    # along track: the prior's 2 cm per scan plus a velocity random walk over 1..10 scans
    forward_sigma = MotionConfig().forward_accel_mps2 * DT_S**2
    expected = 10 * 0.02**2 + forward_sigma**2 * sum(range(1, 11))
    assert abs(corridor[3, 3] - expected) < 0.2 * expected
    assert corridor[4, 4] < 1e-4  # sideways stays observed
    steps.add(np.eye(4), DT_S, _rows(True), _prior_information())  # observed again: the walk restarts
    assert steps.take()[3, 3] < 1e-4
    steps.add(np.eye(4), DT_S, None, None)  # no registration: every axis dead-reckoned
    assert np.all(np.diag(steps.take()) > 0)


def test_a_misclosure_lands_on_the_steps_the_scans_did_not_observe():
    """30 one-metre steps along x; steps 10-19 ran 5 % short in a corridor. A loop measures the
    truth between keyframes 0 and 30: with per-step covariances the correction goes to the corridor
    steps, with constant sigmas it is spread over all of them."""
    truth = np.array([exp_se3(np.array([float(k), 0, 0, 0, 0, 0])) for k in range(31)])
    corridor = range(11, 21)  # keyframe k's step is from k-1 to k
    odometry = [invert(truth[k - 1]) @ truth[k] for k in range(1, 31)]
    for k in corridor:
        odometry[k - 1] = exp_se3(np.array([0.95, 0, 0, 0, 0, 0]))
    step_covariance = np.zeros((6, 6))
    step_covariance[3, 3] = 0.2**2

    def solve(per_step: bool) -> np.ndarray:
        graph = PoseGraph()
        pose = truth[0]
        graph.add_keyframe(0, pose)
        for k in range(1, 31):
            pose = pose @ odometry[k - 1]
            graph.add_keyframe(
                k, pose, odometry[k - 1], ODO_SIGMAS, step_covariance if per_step and k in corridor else None
            )
        graph.update()
        graph.add_loop(30, 0, invert(truth[0]) @ truth[30], LOOP_INFO)
        graph.update()
        return graph.optimize(extra_updates=5)

    for per_step in (True, False):
        poses = solve(per_step)
        before_corridor = abs(poses[10, 0, 3] - truth[10, 0, 3])
        if per_step:
            assert before_corridor < 0.02  # the observed steps keep their length
            assert np.abs(poses[:, 0, 3] - truth[:, 0, 3]).max() < 0.05
        else:
            assert before_corridor > 0.05  # spread over every step
