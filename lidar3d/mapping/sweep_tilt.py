"""The roll and pitch of the lidar within one sweep that its constant twist does not follow.

A sweep is deskewed with a body twist held constant over the sweep (:mod:`lidar3d.mapping.deskew`).
Suspension vibration (a few tenths of a degree at 5-20 Hz) tilts the sensor back and forth within
a sweep; the constant twist follows only the straight line through that motion, and a point fired
while the sensor was tilted by a small rotation ``eps`` from it lands ``eps x p`` away from where
it was (8 cm at 20 m for 0.25 deg). A scan registered against the map then gets a pose that
averages its distortion.

:class:`SweepTilt` is that rotation as a function of the point's time: roll and pitch in the lidar
frame, piecewise linear between knots at most ``mapping.tilt_knot_spacing_s`` apart over the sweep
(off by default: 0). Its mean and its straight line over the knots are zero: the pose holds the
sweep's mean attitude and the twist its rate. :func:`estimate_sweep_tilt` fits the knots to the
registration's rows with the pose held (Gauss-Newton, correspondences found again each iteration,
the registration's robust kernel); :class:`TiltPrior` learns each knot's prior from the drive. Yaw
is left to the pose: what would hold a knot's yaw is the vertical structure in a quarter of the
sweep, often none.

The tracker (:func:`lidar3d.mapping.tracker._register`) registers the sweep moved by its tilt
again; the keyframes and the dense map keep the sweep as deskewed (fed back into the map, the
tilts followed the map's own slope errors). The idea is the continuous-time trajectory of CT-ICP
(Dellenbach et al., ICRA 2022: a pose at the sweep's start and one at its end), reduced to the two
angles vibration moves; docs/stages/odometry-mapping.md#vibration-within-a-sweep-opt-in has what it
does to the suite's drives.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from lidar3d.config import MotionConfig
from lidar3d.mapping.registration import MatchRows

__all__ = ["SweepTilt", "TiltPrior", "estimate_sweep_tilt"]


@dataclass(frozen=True, slots=True)
class SweepTilt:
    """Roll and pitch (lidar frame) of the sensor within a sweep, beyond its constant twist.

    Attributes:
        knot_times_s: (K,) increasing times relative to the scan stamp (s), K >= 2.
        roll_pitch_rad: (K, 2) roll and pitch at each knot (rad); their mean and straight line
            over the knots are zero.
        variance_rad2: the knots' mean posterior variance (rad^2), 0 when not estimated.
    """

    knot_times_s: np.ndarray
    roll_pitch_rad: np.ndarray
    variance_rad2: float = 0.0

    def apply(self, points_lidar: np.ndarray, time_offset_s: np.ndarray) -> np.ndarray:
        """(N, 3) deskewed points fired at ``time_offset_s`` (N,), moved by the tilt at their time
        (first order: ``p + eps(t) x p``)."""
        if len(points_lidar) == 0:
            return points_lidar
        return _tilted(points_lidar, _hat_weights(time_offset_s, self.knot_times_s) @ self.roll_pitch_rad)

    @property
    def max_rad(self) -> float:
        """The largest roll or pitch at any knot (rad)."""
        return float(np.abs(self.roll_pitch_rad).max()) if self.roll_pitch_rad.size else 0.0


def _tilted(points: np.ndarray, roll_pitch_rad: np.ndarray) -> np.ndarray:
    """(N, 3) points each rotated by its own small (N, 2) roll and pitch: ``p + eps x p`` with
    ``eps = (roll, pitch, 0)``."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    roll, pitch = roll_pitch_rad[:, 0], roll_pitch_rad[:, 1]
    return np.column_stack([x + pitch * z, y - roll * z, z + roll * y - pitch * x])


def _hat_weights(times_s: np.ndarray, knot_times_s: np.ndarray) -> np.ndarray:
    """(N, K) weights of linear interpolation between the knots at each time (clamped at the ends)."""
    n, k = len(times_s), len(knot_times_s)
    t = np.clip(times_s, knot_times_s[0], knot_times_s[-1])
    left = np.clip(np.searchsorted(knot_times_s, t, side="right") - 1, 0, k - 2)
    span = knot_times_s[left + 1] - knot_times_s[left]
    share = (t - knot_times_s[left]) / span
    weights = np.zeros((n, k))
    rows = np.arange(n)
    weights[rows, left] = 1.0 - share
    weights[rows, left + 1] += share
    return weights


def knot_times(time_offset_s: np.ndarray, knot_spacing_s: float) -> np.ndarray | None:
    """(K,) knots evenly over the span of a sweep's point times, at most ``knot_spacing_s`` apart
    (K >= 3: two knots would be a straight line, which the twist already is); None when the
    span is empty."""
    if len(time_offset_s) == 0 or knot_spacing_s <= 0:
        return None
    start, end = float(time_offset_s.min()), float(time_offset_s.max())
    if end <= start:
        return None
    count = max(3, int(np.ceil((end - start) / knot_spacing_s)) + 1)
    return np.linspace(start, end, count)


def estimate_sweep_tilt(
    T_target_lidar: np.ndarray,
    points_lidar: np.ndarray,
    time_offset_s: np.ndarray,
    find_matches: Callable[[np.ndarray, float | None], MatchRows],
    *,
    knot_spacing_s: float,
    prior_sigma_rad: float,
    robust_scale_m: float,
    min_rows: int,
    iterations: int = 3,
    converge_rad: float = np.radians(0.005),
) -> SweepTilt | None:
    """The tilt of a sweep registered at ``T_target_lidar`` (4, 4): knots fitted to the rows of its
    (N, 3) deskewed ``points_lidar`` fired at ``time_offset_s`` (N,), the pose held.

    ``find_matches`` as for :func:`~lidar3d.mapping.registration.solve_pose` (target-frame points,
    the registration's rows). Each row ``n . (R p' + t) + d`` with ``p' = p + eps(t) x p`` has the
    derivative ``(p x R^T n) . d eps``, ``eps`` interpolated between the knots; rows weigh by the
    Geman-McClure kernel of ``robust_scale_m`` (> 0) and the residual spread, each knot has the
    prior ``N(0, prior_sigma_rad^2)`` per angle, and the knots' mean and slope are held at zero
    (the pose's and the twist's). None when there are no knots (``knot_spacing_s`` 0, a sweep
    without a time span) or fewer than ``min_rows`` rows."""
    knots_s = knot_times(time_offset_s, knot_spacing_s)
    if knots_s is None or len(points_lidar) == 0:
        return None
    k = len(knots_s)
    weights = _hat_weights(time_offset_s, knots_s)
    R, t = T_target_lidar[:3, :3], T_target_lidar[:3, 3]
    # the knots' mean and slope (roll, pitch) are held at zero (the pose and the twist carry them),
    # by a penalty a million times the prior's
    centred = (knots_s - knots_s.mean()) / (knots_s[-1] - knots_s[0])
    held = np.zeros((4, 2 * k))
    held[0, :k] = held[1, k:] = 1.0
    held[2, :k] = held[3, k:] = centred
    prior_information = (np.eye(2 * k) + 1e6 * held.T @ held) / prior_sigma_rad**2
    x = np.zeros(2 * k)  # roll at the knots, then pitch
    tilt = SweepTilt(knots_s, np.zeros((k, 2)))
    c2 = robust_scale_m**2
    for _ in range(iterations):
        moved = _tilted(points_lidar, weights @ tilt.roll_pitch_rad)  # the weights computed once
        matches = find_matches(moved @ R.T + t, None)
        if len(matches) < min_rows:
            return None if not x.any() else tilt
        p = np.take(moved, matches.source_index, axis=0)
        residual = np.einsum("ij,ij->i", matches.normal, p @ R.T + t) + matches.offset
        weight = c2 / (c2 + residual**2)
        use = weight > 0.1
        lever = np.cross(p[use], matches.normal[use] @ R)  # (M, 3): d r / d eps in the lidar frame
        w_knots = np.take(weights, matches.source_index[use], axis=0)  # (M, K)
        J = np.concatenate([w_knots * lever[:, [0]], w_knots * lever[:, [1]]], axis=1)  # (M, 2K)
        w, r = weight[use], residual[use]
        sigma2 = max(float((w * r) @ r / w.sum()), 1e-6)
        Jw = J * w[:, None]
        covariance = np.linalg.inv(Jw.T @ J / sigma2 + prior_information)
        b = Jw.T @ r / sigma2 + prior_information @ x
        step = -covariance @ b
        x = x + step
        tilt = SweepTilt(knots_s, np.column_stack([x[:k], x[k:]]), float(np.mean(np.diag(covariance))))
        if np.abs(step).max() < converge_rad:
            break
    return tilt


class TiltPrior:
    """The prior of a sweep's tilt knots, learned from the drive (empirical Bayes).

    How much a sensor shakes is a property of the vehicle and the road, not known beforehand: 0.3
    deg at 5-20 Hz on a rough trail is an angular acceleration of tens of rad/s^2, a hundred times
    what the vehicle model allows the roll and pitch rates to change between sweeps, while a car on
    asphalt shakes by hundredths of a degree. Each knot's prior variance is therefore the running
    mean of what the sweeps' knots turned out to be (the EM update: the posterior mean squared
    plus the posterior variance), smoothed by ``smoothing`` per sweep. It starts at
    ``start_sigma_rad`` (wide: the first sweeps are held by their rows) and never falls below how
    far the vehicle model lets the attitude leave the straight line through a sweep of
    ``sweep_period_s`` (``a T^2 / 8`` for its ``tilt_accel_rad_s2`` ``a``, the largest gap between a parabola and
    its chord over the sweep of ``T``). On a drive that does not shake the knots' estimates are
    noise, the prior narrows to the floor and holds them near zero.
    """

    def __init__(self, *, start_sigma_rad: float, tilt_accel_rad_s2: float, sweep_period_s: float, smoothing: float):
        self._floor_rad2 = (tilt_accel_rad_s2 * sweep_period_s**2 / 8.0) ** 2
        self._variance_rad2 = max(start_sigma_rad**2, self._floor_rad2)
        self._smoothing = smoothing

    @classmethod
    def of_config(cls, motion: MotionConfig, sweep_period_s: float) -> TiltPrior:
        """The prior of a run: it starts at ``motion.cold_start_sigma_deg``, its floor from
        ``motion.tilt_accel_rad_s2``, smoothed by ``motion.innovation_smoothing``."""
        return cls(
            start_sigma_rad=np.radians(motion.cold_start_sigma_deg),
            tilt_accel_rad_s2=motion.tilt_accel_rad_s2,
            sweep_period_s=sweep_period_s,
            smoothing=motion.innovation_smoothing,
        )

    @property
    def sigma_rad(self) -> float:
        """Each knot's prior standard deviation (rad) for the next sweep."""
        return float(np.sqrt(self._variance_rad2))

    def learn(self, tilt: SweepTilt | None) -> None:
        """Move the prior towards what the knots of ``tilt`` (an estimate made with it) say;
        nothing for None (no estimate)."""
        if tilt is None:
            return
        second_moment = float(np.mean(tilt.roll_pitch_rad**2)) + tilt.variance_rad2
        self._variance_rad2 = max(
            self._floor_rad2, (1.0 - self._smoothing) * self._variance_rad2 + self._smoothing * second_moment
        )
