"""How well each scan's pose is known relative to the map: a Kalman filter of the pose error.

The health flag asks whether the estimate may be off by more than the tolerance over the last
stretch of road. Counting the travel over scans that left a direction to the motion prior answers
it in categories: a scan that knew its along-track position to 3 cm, against the vehicle model's
2 cm, counts as dead-reckoned, and on a forest trail, where that happens on two scans in five
interleaved with scans that pin every direction, the count never clears and half the good scans
were flagged (`forest_trail`: 0.14 m ATE, 50-58 % false flags). What the scans and the model know
together is a number, not a category:

* between scans the error of the pose grows as the vehicle model allows: its rate is a random
  walk of ``sigma_a dt`` per scan, ``sigma_a`` the bounded accelerations of ``[motion]`` (per
  tangent axis, the lidar's x taken as the direction of travel; the dead-reckoning model of
  :mod:`~lidar3d.mapping.step_uncertainty`), so an unobserved direction's standard deviation grows
  as ``sigma_a sqrt(dt t^3 / 3)``: 0.37 m after 1 s at 2 m/s^2 and 10 Hz, metres over a walled
  canyon or a stretch without registration;
* each registration measures the pose with the rows' information ``J^T W J / sigma^2`` (the
  same matrix the registration fused with the prior, moved to the tangent space). A direction
  measured every other scan to a few centimetres stays a few centimetres uncertain.

The state is the (12,) error of the pose and of its rate in the tangent space ``[w, v]`` of the
lidar frame (rad, m; rad/s, m/s); the small rotation between consecutive frames is neglected, as
in :mod:`~lidar3d.mapping.step_uncertainty`. The filter starts certain (the first scan defines
the map). It knows only what the registration reports: a registration whose information is
overconfident (far structure, smeared submap) keeps it small while the estimate drifts, which is
what the health monitor's consistency test against the scan-to-scan odometry is for.
"""

from __future__ import annotations

import numpy as np

from lidar3d.config import MotionConfig
from lidar3d.mapping.step_uncertainty import tangent_acceleration_sigmas, tangent_information

__all__ = ["PoseUncertainty"]


class PoseUncertainty:
    """The covariance of the pose error relative to the map, scan by scan.

    Args:
        config: the ``[motion]`` section (its accelerations drive the error between scans).
    """

    def __init__(self, config: MotionConfig) -> None:
        self._acceleration_var = tangent_acceleration_sigmas(config) ** 2
        self._covariance = np.zeros((12, 12))  # [pose error (w, v), its rate]

    def add(self, T_world_lidar: np.ndarray, dt_s: float, information_x: np.ndarray | None) -> np.ndarray:
        """Predict over ``dt_s`` seconds and update with one scan's registration; returns the
        (6,6) covariance of its pose in the tangent ``[w, v]`` of the lidar frame (rad, m).

        Args:
            T_world_lidar: (4,4) the scan's pose.
            dt_s: time since the previous scan (0 or less: no prediction).
            information_x: (6,6) the registration rows' information over the solver's
                ``[t_world (3), roll, pitch, yaw]``; None when the registration did not run.
        """
        if dt_s > 0.0:
            transition = np.eye(12)
            transition[:6, 6:] = dt_s * np.eye(6)
            q = self._acceleration_var
            noise = np.zeros((12, 12))
            noise[:6, :6] = np.diag(q * dt_s**4 / 4.0)
            noise[:6, 6:] = noise[6:, :6] = np.diag(q * dt_s**3 / 2.0)
            noise[6:, 6:] = np.diag(q * dt_s**2)
            self._covariance = transition @ self._covariance @ transition.T + noise
        if information_x is not None and np.isfinite(information_x).all():
            rows = tangent_information(information_x, T_world_lidar)
            rows = 0.5 * (rows + rows.T)
            # The Kalman update of a measurement of the pose block with information L (which may be
            # singular: a direction the rows do not see), written so that neither L nor the
            # covariance P (singular after one prediction: one acceleration drives pose and rate)
            # is inverted: P - P H^T L (I + H P H^T L)^-1 H P.
            P = self._covariance
            correction = np.linalg.solve(np.eye(6) + P[:6, :6] @ rows, P[:6, :])
            covariance = P - P[:, :6] @ rows @ correction
            self._covariance = 0.5 * (covariance + covariance.T)
        return self._covariance[:6, :6].copy()
