"""The uncertainty of each keyframe-to-keyframe step, from the registration's own information.

The pose graph's odometry factors say how far each keyframe step may be off. With one constant
sigma per step a misclosure is spread evenly over the loop, also over stretches the scans pinned
to the millimetre; the error, though, comes from where the scans did not observe the motion (a
canyon between two bare walls leaves the along-track direction to the vehicle model). LIO-SAM and
hdl_graph_slam weight odometry by the registration's information; this module does the same for
the scan-to-submap registration fused with the motion prior.

Per scan, in the tangent space of the pose (GTSAM order ``[w (rad), v (m)]``, lidar frame, right
perturbation ``T exp(xi)``):

* the posterior covariance of the registration, ``inv(rows' information + prior's information)``,
  moved from the solver's parameterisation (world translation, Euler angles) to the tangent space
  (the Euler-rate map is taken at zero tilt: roll and pitch stay a few degrees);
* a dead-reckoning term on every axis the scan left to the prior (it removed less than half of
  the prior's variance, :func:`~lidar3d.mapping.registration.observed_share`): there the error is
  that of the vehicle model's velocity, a random walk driven by the bounded accelerations of
  ``[motion]``. After ``m`` consecutive such scans the velocity is uncertain by
  ``sigma_a dt sqrt(m)`` and the step by ``sigma_a dt^2 sqrt(m)``. This is what makes a 25 m
  along-track drift over a 27 s canyon plausible to the graph, where the per-scan posterior alone
  (a few centimetres per scan, as if independent) would call it impossible.

The covariance of a keyframe step is the sum over the scans since the previous keyframe (the
small rotation between their frames is neglected). The loop closer adds it to its constant
odometry covariance (``loop.odometry_sigma_*``), which therefore stays the floor.
"""

from __future__ import annotations

import numpy as np

from lidar3d.config import MotionConfig
from lidar3d.mapping.motion_model import acceleration_sigmas
from lidar3d.mapping.registration import observed_share

__all__ = ["StepUncertainty", "tangent_acceleration_sigmas", "tangent_information"]

_UNOBSERVED_SHARE = 0.5  # an axis whose variance the scan removed less of came from the prior


def tangent_information(information_x: np.ndarray, T_world_lidar: np.ndarray) -> np.ndarray:
    """(6,6) information over the tangent ``[w, v]`` (lidar frame) from (6,6) information over the
    solver's ``[t_world (3), roll, pitch, yaw]`` at pose ``T_world_lidar`` (4,4).

    A right perturbation moves the world translation by ``R v`` and the Euler angles by about
    ``R w`` (exact at zero roll and pitch).
    """
    R = T_world_lidar[:3, :3]
    J = np.zeros((6, 6))  # d x / d [w, v]
    J[:3, 3:] = R
    J[3:, :3] = R
    return J.T @ information_x @ J


def tangent_acceleration_sigmas(config: MotionConfig) -> np.ndarray:
    """(6,) the vehicle model's acceleration bounds (:func:`~lidar3d.mapping.motion_model.acceleration_sigmas`)
    in tangent order ``[w, v]`` (rad/s^2, then m/s^2; the lidar's x taken as the direction of travel)."""
    sigmas = acceleration_sigmas(config)
    return np.r_[sigmas[3:], sigmas[:3]]


def _vehicle_sigmas(config: MotionConfig, dt_s: float) -> np.ndarray:
    """(6,) per-scan step sigmas the bounded accelerations allow, tangent order ``[w, v]``."""
    return tangent_acceleration_sigmas(config) * dt_s * dt_s


class StepUncertainty:
    """Accumulates the step covariance of the scans since the last keyframe.

    Args:
        config: the ``[motion]`` section (the accelerations that bound the vehicle model).
    """

    def __init__(self, config: MotionConfig) -> None:
        self.config = config
        self._unobserved_run = np.zeros(6)  # consecutive scans each axis was left to the prior
        self._covariance = np.zeros((6, 6))

    def add(
        self,
        T_world_lidar: np.ndarray,
        dt_s: float,
        information_x: np.ndarray | None,
        prior_information_x: np.ndarray | None,
    ) -> None:
        """One scan's step: pose (4,4), time since the previous scan, the registration's (6,6)
        information and its prior's (solver parameterisation; None when the registration did not
        run or had no prior)."""
        if dt_s <= 0.0:
            return
        vehicle = _vehicle_sigmas(self.config, dt_s)
        vehicle_information = np.diag(vehicle**-2.0)
        rows = (
            np.zeros((6, 6))
            if information_x is None or not np.isfinite(information_x).all()
            else tangent_information(information_x, T_world_lidar)
        )
        prior = (
            vehicle_information
            if prior_information_x is None
            else tangent_information(prior_information_x, T_world_lidar)
        )
        share = observed_share(rows, prior)
        unobserved = share < _UNOBSERVED_SHARE
        self._unobserved_run = np.where(unobserved, self._unobserved_run + 1.0, 0.0)
        posterior = np.linalg.inv(rows + prior)
        dead_reckoning = (vehicle * np.sqrt(self._unobserved_run)) ** 2
        self._covariance += 0.5 * (posterior + posterior.T) + np.diag(dead_reckoning)

    def take(self) -> np.ndarray:
        """(6,6) covariance of the step since the previous :meth:`take` (GTSAM order ``[w, v]``),
        and start the next step."""
        covariance, self._covariance = self._covariance, np.zeros((6, 6))
        return covariance
