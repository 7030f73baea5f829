"""The solver's closed-form rotation, its derivatives and its inverse agree with scipy's Euler
convention (R = Rz(yaw) Ry(pitch) Rx(roll)) to rounding."""

from __future__ import annotations

import numpy as np
import pytest

from lidar3d.mapping.registration import _pose, _rotation_and_derivatives, _xyz_rpy
from lidar3d.mapping.se3 import pose_from_xyz_rpy, xyz_rpy_from_pose


def test_rotation_derivatives_and_inverse_match_scipy():
    rng = np.random.default_rng(11)
    step = 1e-6
    for _ in range(200):
        x = np.concatenate([rng.normal(size=3) * 10.0, rng.uniform([-3.1, -1.5, -3.1], [3.1, 1.5, 3.1])])
        R, dR = _rotation_and_derivatives(x)
        T = pose_from_xyz_rpy(x)
        np.testing.assert_allclose(_pose(x, R), T, atol=1e-14)
        for axis in range(3):  # dR/d(roll, pitch, yaw) by central differences
            plus, minus = x.copy(), x.copy()
            plus[3 + axis] += step
            minus[3 + axis] -= step
            numeric = (pose_from_xyz_rpy(plus)[:3, :3] - pose_from_xyz_rpy(minus)[:3, :3]) / (2 * step)
            np.testing.assert_allclose(dR[axis], numeric, atol=1e-8)
        np.testing.assert_allclose(_xyz_rpy(T), xyz_rpy_from_pose(T), atol=1e-12)


@pytest.mark.filterwarnings("ignore:Gimbal lock detected")
def test_inverse_near_gimbal_lock_is_scipy_s():
    T = pose_from_xyz_rpy(np.array([1.0, 2.0, 3.0, 0.2, np.pi / 2 - 1e-9, -0.4]))
    np.testing.assert_array_equal(_xyz_rpy(T), xyz_rpy_from_pose(T))
