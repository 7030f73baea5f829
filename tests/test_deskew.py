"""The motion a sweep is deskewed with, from a trajectory, whatever instant its stamp marks."""

import numpy as np
import pytest

from lidar3d.mapping.deskew import share_after_stamp, sweep_twist, trajectory_sweep_twist
from lidar3d.mapping.se3 import exp_se3

T_S = 0.1
FIRING_S = np.linspace(0.0, T_S, 1800, endpoint=False)  # one sweep, 0..T after its start


@pytest.mark.parametrize(
    ("times_s", "share"),
    [
        (FIRING_S, 1.0),  # stamped at the sweep start (raw packets, the simulator)
        (FIRING_S - T_S, 0.0),  # stamped at the sweep end (the stock ROS1 velodyne driver)
        (FIRING_S - T_S / 2, 0.5),  # stamped in the middle
        (np.zeros(0), 1.0),  # empty
        (np.zeros(5), 1.0),  # all at the stamp
        (np.full(5, -0.01), 0.0),  # all before it
    ],
)
def test_share_of_the_sweep_after_its_stamp(times_s, share):
    assert share_after_stamp(times_s) == pytest.approx(share, abs=1e-3)


def test_sweep_twist_takes_the_interval_the_points_lie_in():
    before, after = np.r_[1.0, 0, 0, 0, 0, 0], np.r_[3.0, 0, 0, 0, 0, 0.5]
    assert sweep_twist(1.0, before, after) is not after and np.array_equal(sweep_twist(1.0, before, after), after)
    assert np.array_equal(sweep_twist(0.0, before, after), before)
    assert np.allclose(sweep_twist(0.25, before, after), 0.25 * after + 0.75 * before)
    assert np.array_equal(sweep_twist(0.0, None, after), after)  # the first sweep
    assert np.array_equal(sweep_twist(1.0, before, None), before)  # the last sweep
    assert np.array_equal(sweep_twist(0.5, None, None), np.zeros(6))


def test_a_trajectory_deskews_each_sweep_with_the_motion_over_its_own_points():
    """Three poses 0.1 s apart, the motion changing between them: a sweep stamped at its start
    takes the motion to the next pose, one stamped at its end the motion from the previous pose."""
    first, second = np.r_[2.0, 0, 0, 0, 0, 0.1], np.r_[6.0, 0.5, 0, 0, 0, 0.4]
    poses = np.array([np.eye(4), exp_se3(first * T_S), exp_se3(first * T_S) @ exp_se3(second * T_S)])
    stamps_ns = np.array([0, 100_000_000, 200_000_000])
    assert np.allclose(trajectory_sweep_twist(stamps_ns, poses, 1, FIRING_S), second)
    assert np.allclose(trajectory_sweep_twist(stamps_ns, poses, 1, FIRING_S - T_S), first)
    assert np.allclose(trajectory_sweep_twist(stamps_ns, poses, 0, FIRING_S - T_S), first)  # none before
    assert np.allclose(trajectory_sweep_twist(stamps_ns, poses, 2, FIRING_S), second)  # none after
    assert np.array_equal(trajectory_sweep_twist(stamps_ns[:1], poses[:1], 0, FIRING_S), np.zeros(6))
