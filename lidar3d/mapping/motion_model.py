"""Vehicle motion model: the prediction of the next pose, its uncertainty, and the learned
direction of travel.

The pipeline carries the body-frame twist of the last scan forward (constant velocity). Where a
scan constrains some directions poorly (open land: nothing but ground and a distant pole), the
registration keeps the prediction along those directions, so an error in the carried velocity
is integrated scan after scan: a lateral velocity of 0.1 m/s picked up from a noisy estimate
becomes metres of sideways drift over a featureless stretch.

A wheeled vehicle does not slide sideways or lift off: the velocity of its rear axle stays along
one direction fixed in the sensor frame (the non-holonomic constraint; LIO-SAM and hdl_graph_slam
users add it through wheel odometry or a vehicle model). That direction is learned here from the
scans whose registration was well constrained, as the mean direction of their velocity, and is used
only once the motion has shown it is vehicle-like (consistently along one axis). A handheld or drone
recording never passes that test and keeps the plain constant-velocity prediction.

The sensor itself is not on the rear axle: a lidar ``L`` metres ahead of it moves sideways at
``L`` times the yaw rate in a turn (0.18 m/s for the simulator's 0.35 m at 30 deg/s; nuScenes'
roof lidar sits 0.94 m ahead of the rear-axle origin of its vehicle frame, 0.5 m/s at that rate). A
vehicle model that allows no sideways velocity at the sensor drags a turn made where the scan
barely constrains the lateral position outwards by that much every scan (``blind_turn`` seed 0:
2 cm a scan through a 3 s turn on open land, 0.7 m in all). The model carries ``motion.lever_m``
times the yaw rate sideways (0 unless the mount is known) and widens the prior's sideways sigma by
``motion.lever_sigma_m`` times the yaw rate: the farther it turns, the more the scan decides the
sideways motion. The lever is not learned online: fitted to the tracker's own fused poses it
learns the prior back (0.13 m for a true 0.29 m on ``loop``, 2.6 m on ``blind_turn``), and the
feedback through the prediction made runs worse, not better (docs/stages/odometry-mapping.md).

Registration fuses the scan with this prediction as a Gaussian prior (:meth:`MotionModel.prior`):
its mean carries the twist forward, its covariance is what bounded accelerations allow over one
scan interval (a car cannot change its speed by more than a few m/s^2, cannot slide sideways,
cannot change its yaw rate instantly), so a direction the scan observes is taken from the scan
and one it does not is taken from the vehicle model, in proportion to their information.

While the scene cannot tell the heading (the prior carries most of the yaw information), the
carried yaw rate decays towards zero: a residual rate of a tenth of a degree per second, held
over a 30 s stretch of open road, would otherwise bend a straight road into a curve.

The twist used to deskew and predict the next sweep (:meth:`MotionModel.prediction`) is the
measured twist smoothed over scans (half the new, half the previous), and after a degenerate scan
its sideways and vertical velocity are dropped. The measured twist comes from two consecutive
registered poses; where registration converges slowly (a corner opening onto a street with little
cross structure) a velocity error feeds back through the next deskew and prediction and grew, on
`fast` with seed 1, into an oscillation of the along-track speed between 2 and 17 m/s. The
smoothing damps that loop (2.2 m -> 0.24 m ATE there) at the cost of about one scan of lag in the
predicted velocity, which the registration absorbs.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from lidar3d.config import MotionConfig
from lidar3d.mapping.registration import PosePrior
from lidar3d.mapping.se3 import exp_se3

__all__ = ["MotionModel", "acceleration_sigmas", "nominal_step_information"]


class MotionModel:
    """The twist to predict the next scan with, and its non-holonomic variant.

    Args:
        min_speed_mps: velocities slower than this teach nothing about the direction of travel.
        min_samples: well-constrained scans needed before the direction is trusted.
        min_consistency: length of the mean unit velocity (1: always the same direction, 0:
            random) needed to treat the platform as a vehicle. Reversing counts as the same axis.
        direction_smoothing: weight of a new sample in the running mean direction of travel.
        yaw_rate_decay: factor on the carried yaw rate per scan whose heading was unobserved.
        prediction_smoothing: weight of the newest twist in the smoothed prediction (1: none).
        lever_m: the sensor's distance ahead of the rear axle (m): the sideways velocity per
            unit yaw rate of the vehicle twist.
        change_bound: (6,) once established, a measured twist differs from the last by at most
            this times the interval (per body axis: m/s^2 along travel, sideways, up, then
            rad/s^2 about them); None: unbounded.
    """

    def __init__(
        self,
        *,
        min_speed_mps: float = 1.0,
        min_samples: int = 20,
        min_consistency: float = 0.95,
        direction_smoothing: float = 0.05,
        yaw_rate_decay: float = 0.9,
        prediction_smoothing: float = 0.5,
        lever_m: float = 0.0,
        change_bound: np.ndarray | None = None,
    ) -> None:
        self.min_speed_mps = min_speed_mps
        self.min_samples = min_samples
        self.min_consistency = min_consistency
        self.direction_smoothing = direction_smoothing
        self.yaw_rate_decay = yaw_rate_decay
        self.prediction_smoothing = prediction_smoothing
        self.twist = np.zeros(6)
        self._direction_sum = np.zeros(3)
        self._samples = 0
        self._constrained = 0
        self.last_well_constrained = False
        self._smoothed: np.ndarray | None = None
        # running mean of consecutive prior errors' products: basis x, y, z, tilt, tilt, yaw
        self._innovation_product = np.zeros(6)
        self._last_innovation: np.ndarray | None = None
        self.lever_m = lever_m
        self._change_bound = change_bound

    @classmethod
    def of_config(cls, config: MotionConfig) -> MotionModel:
        """The model of a run's ``[motion]`` section (its lever, its twist-change bound)."""
        return cls(lever_m=config.lever_m, change_bound=config.twist_change_sigmas * acceleration_sigmas(config))

    def update(
        self, twist: np.ndarray, well_constrained: bool, heading_observed: bool = True, dt_s: float = 0.0
    ) -> None:
        """Take the twist (v m/s, w rad/s, body frame) estimated for the latest scan, ``dt_s``
        after the previous one.

        ``well_constrained``: the registration had no degenerate direction (only such scans
        teach the direction of travel). ``heading_observed``: False when the yaw came mostly
        from the prior rather than the scan. Once the model is established, the change from the
        last twist is clipped per body axis at ``change_bound * dt_s``: a vehicle cannot change
        its yaw rate by 35 deg/s within one scan, a registration that jumped can (``long``
        seed 1: one such jump, carried and decayed over the next 20 scans of a stretch without
        heading, turned the trajectory by 80 degrees).
        """
        self.twist = self._bounded(np.asarray(twist, dtype=float), dt_s)
        self.last_well_constrained = bool(well_constrained)
        a = self.prediction_smoothing
        self._smoothed = self.twist.copy() if self._smoothed is None else a * self.twist + (1 - a) * self._smoothed
        if not heading_observed:
            self.twist[5] *= self.yaw_rate_decay
        if well_constrained:
            self._constrained += 1
        v = self.twist[:3]
        speed = float(np.linalg.norm(v))
        if not well_constrained or speed < self.min_speed_mps:
            return
        unit = v / speed
        if self._samples and unit @ self._direction_sum < 0:
            unit = -unit  # driving backwards: same axis
        if self._samples == 0:
            self._direction_sum = unit
        else:
            self._direction_sum = (1 - self.direction_smoothing) * self._direction_sum + self.direction_smoothing * unit
        self._samples += 1

    def _bounded(self, twist: np.ndarray, dt_s: float) -> np.ndarray:
        """(6,) ``twist`` with its change from the current one clipped at ``change_bound * dt_s``
        per body axis (a copy; unclipped before the model is established)."""
        if self._change_bound is None or not self.established or dt_s <= 0.0:
            return twist.copy()
        basis = self._basis()
        change = np.r_[basis.T @ (twist[:3] - self.twist[:3]), basis.T @ (twist[3:] - self.twist[3:])]
        limit = self._change_bound * dt_s
        clipped = np.clip(change, -limit, limit)
        return self.twist + np.r_[basis @ clipped[:3], basis @ clipped[3:]]

    @property
    def established(self) -> bool:
        """Enough well-constrained scans have been seen for the prediction to be trusted over
        a fresh scan-to-scan estimate (not at a cold start, when the velocity is unknown)."""
        return self._constrained >= self.min_samples

    @property
    def forward_axis(self) -> np.ndarray | None:
        """Unit direction of travel in the sensor frame, or None while not established."""
        norm = float(np.linalg.norm(self._direction_sum))
        if self._samples < self.min_samples or norm < self.min_consistency:
            return None
        return self._direction_sum / norm

    def prediction(self) -> np.ndarray:
        """The twist to deskew and predict the next scan with: the smoothed measured twist after
        a well-constrained scan (it keeps real sideways motion, e.g. a sensor ahead of the rear
        axle in a turn), projected on the direction of travel after a degenerate one, whose
        sideways velocity is an artefact that would feed back through deskewing."""
        twist = self.twist if self._smoothed is None else self._smoothed
        return twist.copy() if self.last_well_constrained else self._on_axis(twist)

    def vehicle_twist(self) -> np.ndarray:
        """The carried twist with its velocity projected onto the direction of travel, plus the
        sideways velocity of the sensor's lever in a turn (no sideways or vertical slip at the
        rear axle); the plain twist while that direction is not established."""
        return self._on_axis(self.twist)

    def _basis(self) -> np.ndarray:
        """(3,3) columns: direction of travel, sideways, up (sensor frame); identity while the
        direction is not established."""
        axis = self.forward_axis
        if axis is None:
            return np.eye(3)
        lateral = np.cross([0.0, 0.0, 1.0], axis)
        if np.linalg.norm(lateral) < 1e-6:  # travelling along the sensor's z: any perpendicular
            lateral = np.cross([1.0, 0.0, 0.0], axis)
        lateral /= np.linalg.norm(lateral)
        return np.column_stack([axis, lateral, np.cross(axis, lateral)])

    def learn_innovation(
        self, prior: PosePrior, T_world_registered: np.ndarray, smoothing: float, well_constrained: bool = True
    ) -> None:
        """Take how far a registration (4,4) landed from the ``prior`` mean (the innovation, per
        body axis) to widen the prior where the model has been predicting badly (entering a turn,
        braking hard), by ``smoothing`` (weight of the newest).

        The widening is the running mean of the product of consecutive innovations, clipped at
        zero, not of their square. An innovation is the model's prediction error plus the
        registration's own error. A prediction error persists over several scans (a braking or a
        turn entry lasts seconds), so consecutive innovations share its sign; a registration error
        does not (a pose off by e enters this innovation as +e and, carried in the next
        prediction, the next one as about -e), so it averages out of the product instead of
        widening the prior, which would give the next noisy registration more room still. A scan
        that is not ``well_constrained`` teaches nothing and breaks the chain."""
        if not well_constrained:
            self._last_innovation = None
            return
        delta = np.linalg.inv(prior.T_target_source) @ T_world_registered
        rotation = Rotation.from_matrix(delta[:3, :3]).as_rotvec()
        innovation = np.r_[self._basis().T @ delta[:3, 3], rotation]
        last, self._last_innovation = self._last_innovation, innovation
        if last is None:
            return
        sample = np.maximum(innovation * last, 0.0)
        tilt = 0.5 * (sample[3] + sample[4])
        sample[3] = sample[4] = tilt
        self._innovation_product = (1.0 - smoothing) * self._innovation_product + smoothing * sample

    def prior(self, T_world_previous: np.ndarray, dt_s: float, config: MotionConfig) -> PosePrior:
        """The pose ``dt_s`` after ``T_world_previous`` (4,4) under :meth:`vehicle_twist`, with the
        information its bounded accelerations allow (see :class:`~lidar3d.config.MotionConfig`),
        widened where the recent prediction errors that persisted from scan to scan are larger
        (:meth:`learn_innovation`)."""
        basis = self._basis()
        twist = self._on_axis(self.twist, basis)
        T_mean = T_world_previous @ exp_se3(twist * dt_s)
        sigma = _step_sigma(config, dt_s, self.forward_axis is not None)
        if self.forward_axis is not None:  # the sideways velocity rests on the lever's yaw rate
            sigma[1] = np.hypot(sigma[1], config.lever_sigma_m * float(twist[3:] @ basis[:, 2]) * dt_s)
        sigma = np.maximum(sigma, np.sqrt(self._innovation_product))
        return PosePrior(T_mean, _information(sigma, T_mean[:3, :3] @ basis, config))

    def _on_axis(self, twist: np.ndarray, basis: np.ndarray | None = None) -> np.ndarray:
        """``twist`` with its velocity along the direction of travel plus the sideways velocity the
        lever gives its yaw rate (no slip at the rear axle); unchanged while the direction is not
        established. ``basis``: :meth:`_basis`, when the caller has it already."""
        twist = twist.copy()
        if self.forward_axis is not None:
            axis, lateral, up = (self._basis() if basis is None else basis).T
            twist[:3] = (twist[:3] @ axis) * axis + self.lever_m * float(twist[3:] @ up) * lateral
        return twist


def nominal_step_information(config: MotionConfig, dt_s: float) -> np.ndarray:
    """(6, 6) information over ``[tx, ty, tz, roll, pitch, yaw]`` (m, rad) of the vehicle model
    over ``dt_s`` before it knows the direction of travel: every translation axis with the forward
    acceleration's sigma, rotations with the tilt and yaw ones (the yardstick a registration
    without a vehicle prior is judged against, :func:`~lidar3d.mapping.registration.unobserved_directions`)."""
    return _information(_step_sigma(config, dt_s, vehicle=False), np.eye(3), config)


def acceleration_sigmas(config: MotionConfig) -> np.ndarray:
    """(6,) the vehicle model's acceleration bounds: along the direction of travel, sideways, up
    (m/s^2), then roll, pitch, yaw (rad/s^2)."""
    tilt = config.tilt_accel_rad_s2
    translation = [config.forward_accel_mps2, config.lateral_accel_mps2, config.vertical_accel_mps2]
    return np.array([*translation, tilt, tilt, config.yaw_accel_rad_s2])


def _step_sigma(config: MotionConfig, dt_s: float, vehicle: bool) -> np.ndarray:
    """(6,) sigmas of one step of ``dt_s`` under bounded accelerations: along the body basis
    (direction of travel, sideways, up) when ``vehicle``, the forward value on every axis
    otherwise, then tilt, tilt, yaw."""
    sigma = acceleration_sigmas(config) * dt_s * dt_s
    if not vehicle:
        sigma[1:3] = sigma[0]
    return sigma


def _information(sigma: np.ndarray, axes_world: np.ndarray, config: MotionConfig) -> np.ndarray:
    """(6, 6) information of (6,) sigmas (translations along the columns of the (3, 3)
    ``axes_world``, then rotations), each raised to the configured minimum first."""
    sigma = sigma.copy()
    sigma[:3] = np.maximum(sigma[:3], config.min_sigma_m)
    sigma[3:] = np.maximum(sigma[3:], np.radians(config.min_sigma_deg))
    information = np.zeros((6, 6))
    information[:3, :3] = axes_world @ np.diag(sigma[:3] ** -2.0) @ axes_world.T
    information[3:, 3:] = np.diag(sigma[3:] ** -2.0)
    return information
