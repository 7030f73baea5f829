"""The per-scan health signal: how well each scan observed its pose, and a flag ok / degraded / lost.

Three kinds of measure, each cheap to take from what the tracker already knows about a scan
(:func:`scan_measures` is the one place that reads a :class:`~lidar3d.mapping.tracker.TrackResult`):

* **observability**: the standard deviation of the pose along the weakest direction of the scan's
  information, ``sigma = residual_sigma / sqrt(lambda_min)`` (metres; for a rotation direction, the
  shift of a point at the lever of the matched points), with ``lambda_min`` the smallest eigenvalue
  of the registration's ``J^T W J`` and ``residual_sigma`` the weighted residual standard deviation
  the registration measured (``health.residual_sigma_m`` where it reports none). Unlike the eigenvalue itself,
  which grows with every matched point, it is a length the estimate can be compared with;
* **consistency**: how far apart two independent estimates of the same step are: the refined step
  and the scan-to-scan odometry step (flagged), and the refined step and the motion model's
  prediction (reported only: a constant-velocity prediction lags every turn entry by design). A
  difference of pose ``T_a^-1 T_b`` counts as ``|dt| + lever_m * angle(dR)``, metres;
* **hard failures**: the registration did not run (too few rows, empty submap) or the pose came
  from the motion model alone.

A scan *observes* its pose when it was registered, ``sigma <= observed_sigma_m`` and the odometry
agrees within ``max_disagreement_m``; it observes *every direction* when, besides, its registration
took no direction from the prior (``prior_axes == 0``: on no axis did the motion prior decide more
than the scan, i.e. the scan removed at least half of the prior's variance on every axis; that
direction is dead-reckoned however small its sigma). A fourth measure, the **pose uncertainty**
``pose_sigma_m``, is what the scans and the vehicle model know together about the pose relative
to the map (:class:`~lidar3d.mapping.pose_uncertainty.PoseUncertainty`, a Kalman filter fed with
each registration's information; the largest translation sigma plus ``lever_m`` times the largest
rotation one). The flag is ``degraded`` from ``pose_sigma_m > degraded_sigma_m`` (0.1 m: a
three-sigma error reaches 0.3 m, the tolerance of issue 15). :class:`HealthMonitor` keeps two
distances travelled since the estimate was last fully observed: ``dead_reckoned_m`` over scans
that did not observe every direction (reported) and ``blind_m`` over scans that did not observe
their pose; each such scan adds its step length, ``clear_after_m`` of fully observed travel in a
row clears both. The flag is ``lost`` from ``blind_m >= lost_after_m`` (not observed for long), so
a single noisy scan never flags and a standstill (no travel) never accumulates.

**A step the odometry contradicts by the tolerance.** One scan whose refined step and odometry
step are ``jump_m`` apart (0.3 m, the tolerance of issue 15 itself: one of the two is that far
off) makes its own and the next ``jump_window_m`` of travel ``degraded``, the stretch whose local
drift holds that step (``blind_turn`` seed 2's turn exit: the refined step 0.64 m long, every
other measure calm).

**Consistency with the odometry over a window.** A scan-to-submap registration that is well
observed on every direction can still be biased: the submap is built from the trajectory's own
poses, and a small one-signed pull per scan bends and shortens map and trajectory together
(``blind_turn`` seed 1: each step 24 mm short and -0.04 deg turned, 35 deg in a minute, every scan
"observed"). The scan-to-scan odometry sees only the previous sweep, so it does not follow the
bent map. Two differences of the refined step from the odometry step are kept per scan: the yaw
``d_k``, with the odometry's yaw standard deviation ``s_k`` from its edge rows
(:meth:`~lidar3d.mapping.odometry.OdometryStep.yaw_information`), and the translation along the
step's direction, with the odometry's standard deviation there
(:meth:`~lidar3d.mapping.odometry.OdometryStep.xy_covariance`). Gauss-Newton from a guess far off
stops short of the optimum by a share of the way that its rows' curvature does not show (the
entry of a sharp turn; braking, where the constant-velocity guess runs long): a difference in the
direction the odometry moved from its guess, up to ``travel_share`` of that move, is put down to
it and left out. A difference against that direction is not: the odometry moved away from a
guess that the biased trajectory itself predicted. Over the last
``consistency_window_m`` of travel each gives ``z = |sum d_k| / sqrt(sum s_k^2 + floor^2)``, the
floor (``heading_sigma_floor_deg``, ``along_sigma_floor_m``) standing for the refined poses' own
noise at the window's ends (the sums telescope). Either ``z > max_consistency_z`` flags the scan
degraded: one of the two estimates drifted, and nothing else tells which. A scan whose odometry
did not observe a quantity adds nothing to its sum, nor does a standstill.

**Registered against a lost stretch.** A scan's pose is relative to the submap it is registered
against, and that submap is only as good as the keyframes in it: keyframes placed while the flag
was ``lost`` were dead-reckoned. After a blind stretch (a walled canyon, open land) the scans
register well and confidently against those keyframes, and nothing in a scan tells whether the
map under it is right: on ``city_traffic`` the stretch after the canyon ran 12-20 % short (pulled
mostly by the car that follows the vehicle) with every measure calm. So a scan whose submap
holds any keyframe placed while lost is ``degraded``, until the submap has moved on past them
(``lost_keyframes``, counted by the tracker for the scan's own registration). Only ``lost``
keyframes count, not ``degraded`` ones, so the flag cannot feed itself. Except on a later pass: a
scan that comes to such keyframes from an ``ok`` scan checks them (displaced keyframes would pull
its pose across the displacement, a step the odometry contradicts), so it and the scans after it
on them are not degraded for them until a jump or an inconsistency flags one, or a scan is lost.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from lidar3d.config import HealthConfig
from lidar3d.mapping.registration import largest_variance, observed_share
from lidar3d.mapping.se3 import exp_se3, invert, xyz_rpy_from_pose
from lidar3d.mapping.tracker import TrackResult
from lidar3d.summary import HealthStretch, HealthSummary

__all__ = [
    "HealthFlag",
    "HealthMonitor",
    "PosedScan",
    "ScanHealth",
    "ScanMeasures",
    "flag_stretches",
    "scan_measures",
    "summarize_health",
]


class HealthFlag(str, enum.Enum):
    """How far a scan's pose can be trusted."""

    OK = "ok"  # the pose known to health.degraded_sigma_m and consistent with the odometry
    DEGRADED = "degraded"  # pose more uncertain than health.degraded_sigma_m, inconsistent, or on a lost map
    LOST = "lost"  # pose not observed for health.lost_after_m or more: it may be metres wrong


@dataclass(frozen=True, slots=True)
class ScanMeasures:
    """What one scan tells about its own pose (see the module docstring).

    Attributes:
        registered: the scan-to-submap registration ran.
        motion_model_only: too few features: the pose came from the motion model.
        n_rows: residual rows of the registration (0 when it did not run).
        prior_axes: axes the motion prior decided more than the scan (6 when the registration did not run).
        weakest_sigma_m: pose standard deviation along the weakest direction of the scan's
            information, metres (inf when the registration did not run).
        step_m: length of the refined step from the previous scan, metres.
        odometry_disagreement_m: refined step against the scan-to-scan odometry step, metres
            (translation difference plus ``lever_m`` times the rotation difference in radians).
        prediction_offset_m: refined step against the motion model's prediction, in the same units.
        probe_share: the share of a move along its weakest translation the registration's rows
            pulled back (:func:`~lidar3d.mapping.registration.probe_return_share`; below
            ``mapping.probe_observed_share`` that direction was taken as degenerate), 0 when the
            registration did not run, 1 when it was not probed.
        heading_difference_rad: the refined step's yaw minus the odometry step's (wrapped), radians.
        odometry_yaw_sigma_rad: standard deviation of the odometry step's yaw from its rows,
            radians (inf: the odometry measured no yaw).
        odometry_yaw_travel_rad: the yaw the odometry step moved from its guess, radians.
        along_difference_m: the refined step's translation minus the odometry step's, along the
            refined step's direction, metres (0 below 1 cm of travel).
        odometry_along_sigma_m: standard deviation of the odometry step's translation along that
            direction from its rows, metres (inf: not observed, or no travel).
        odometry_along_travel_m: how far the odometry step moved from its guess along that
            direction, metres.
        pose_sigma_m: standard deviation of the pose relative to the map
            (:class:`~lidar3d.mapping.pose_uncertainty.PoseUncertainty`): the largest translation
            sigma plus ``lever_m`` times the largest rotation sigma, metres (NaN: not measured,
            a table of an earlier release).
        lost_keyframes: keyframes of the submap the scan was registered against that were
            placed while the tracker was lost (:meth:`~lidar3d.mapping.keyframes.Submap.lost_keyframes_in_target`).
    """

    registered: bool
    motion_model_only: bool
    n_rows: int
    prior_axes: int
    weakest_sigma_m: float
    step_m: float
    odometry_disagreement_m: float
    prediction_offset_m: float
    probe_share: float = 1.0
    heading_difference_rad: float = 0.0
    odometry_yaw_sigma_rad: float = np.inf
    odometry_yaw_travel_rad: float = 0.0
    along_difference_m: float = 0.0
    odometry_along_sigma_m: float = np.inf
    odometry_along_travel_m: float = 0.0
    pose_sigma_m: float = float("nan")
    lost_keyframes: int = 0

    def observes_pose(self, config: HealthConfig) -> bool:
        """The scan observed its pose: registered, observable enough and consistent with the odometry."""
        return (
            self.registered
            and not self.motion_model_only
            and self.weakest_sigma_m <= config.observed_sigma_m
            and self.odometry_disagreement_m <= config.max_disagreement_m
        )

    def observes_every_direction(self, config: HealthConfig) -> bool:
        """The scan observed its pose and its registration took no direction from the prior."""
        return self.observes_pose(config) and self.prior_axes == 0


@dataclass(frozen=True, slots=True)
class ScanHealth:
    """The health of one scan: its measures, the state after it, and the flag.

    Attributes:
        stamp_ns: the scan's stamp.
        measures: what the scan told about its pose.
        observed: the scan observed every direction of its pose
            (:meth:`ScanMeasures.observes_every_direction`).
        dead_reckoned_m: travel over scans that did not observe every direction since the estimate
            was last fully observed, including this scan's, metres.
        blind_m: travel over scans that did not observe their pose (:meth:`ScanMeasures.observes_pose`)
            in the same time, metres.
        flag: ok, degraded or lost.
        heading_z: how many standard deviations the refined and the odometry heading parted over
            the last ``consistency_window_m`` (see the module docstring).
        along_z: the same for the distance travelled along the steps.
    """

    stamp_ns: int
    measures: ScanMeasures
    observed: bool
    dead_reckoned_m: float
    blind_m: float
    flag: HealthFlag
    heading_z: float = 0.0
    along_z: float = 0.0


class PosedScan(Protocol):
    """The previous scan as the pipeline knows it when the next one is tracked (a ``ScanEstimate``)."""

    @property
    def stamp_ns(self) -> int: ...

    @property
    def T_world_lidar(self) -> np.ndarray: ...

    @property
    def T_world_odom(self) -> np.ndarray: ...


_MIN_ALONG_STEP_M = 0.01  # below this the step has no direction to compare along (a standstill)


def _difference_m(delta: np.ndarray, lever_m: float) -> float:
    """``|dt| + lever_m * angle(dR)`` of the (4,4) relative pose ``delta``, metres."""
    cos_angle = np.clip((np.trace(delta[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(delta[:3, 3]) + lever_m * np.arccos(cos_angle))


def _prior_axes(track: TrackResult) -> int:
    """Axes of ``[tx, ty, tz, roll, pitch, yaw]`` the motion prior decided more than the scan (the
    scan removed less than half of the prior's variance there); without a prior, the directions
    the rows knew less well than the vehicle model's nominal uncertainty (kept at the guess,
    :func:`~lidar3d.mapping.registration.unobserved_directions`); 6 when the registration did not run."""
    registration = track.registration
    if registration is None:
        return 6
    if track.prior is None:
        return registration.degenerate_axes
    return int(np.count_nonzero(observed_share(registration.information, track.prior.information) < 0.5))


def scan_measures(
    track: TrackResult, previous: PosedScan | None, config: HealthConfig, pose_covariance: np.ndarray | None = None
) -> ScanMeasures:
    """The health measures of the scan ``track`` concluded on.

    This is the only reader of :class:`TrackResult` here: a field the registration adds (its
    information matrix, a measured residual variance, the correction from its prior) enters here.

    Args:
        track: the tracker's result for the scan.
        previous: the previous scan, with its poses as the tracker started from them (corrected by
            any loop closure since); None for the first scan.
        config: the ``[health]`` section (``residual_sigma_m``, ``lever_m``).
        pose_covariance: (6,6) covariance of the pose in the tangent ``[w, v]`` (rad, m), from
            :class:`~lidar3d.mapping.pose_uncertainty.PoseUncertainty`; None: not measured.
    """
    registration = track.registration
    registered = registration is not None
    # an eigenvalue within rounding of zero (the sum over the rows of unit-normal products) is a
    # direction the rows do not see at all: its sigma is infinite, not 1e148 m
    if (
        registration is None
        or not np.isfinite(registration.min_eigenvalue)
        or registration.min_eigenvalue <= max(registration.n_rows, 1) * np.finfo(float).eps
    ):
        weakest_sigma_m = np.inf
    else:
        sigma_m = registration.residual_sigma_m
        if not np.isfinite(sigma_m):
            sigma_m = config.residual_sigma_m
        weakest_sigma_m = sigma_m / np.sqrt(registration.min_eigenvalue)
    heading_difference_rad = along_difference_m = along_travel_m = 0.0
    along_sigma_m = np.inf
    if previous is None:
        step_m = odometry_disagreement_m = prediction_offset_m = 0.0
    else:
        dt_s = (track.stamp_ns - previous.stamp_ns) * 1e-9
        step = invert(previous.T_world_lidar) @ track.T_world_lidar
        odometry_step = invert(previous.T_world_odom) @ track.T_world_odom
        step_m = float(np.linalg.norm(step[:3, 3]))
        refined_from_odometry = invert(odometry_step) @ step
        odometry_disagreement_m = _difference_m(refined_from_odometry, config.lever_m)
        heading_difference_rad = float(xyz_rpy_from_pose(refined_from_odometry)[5])
        odometry = track.odometry_step
        if step_m >= _MIN_ALONG_STEP_M and odometry is not None:
            direction = step[:3, 3] / step_m
            along_difference_m = float(direction @ (step[:3, 3] - odometry_step[:3, 3]))
            along_travel_m = float(direction[:2] @ odometry.xy_travel_m)
            covariance = odometry.xy_covariance()
            if covariance is not None:
                along_sigma_m = float(np.sqrt(max(direction[:2] @ covariance @ direction[:2], 0.0)))
        prediction_offset_m = _difference_m(invert(step) @ exp_se3(track.deskew_twist * dt_s), config.lever_m)
    return ScanMeasures(
        registered=registered,
        motion_model_only=track.motion_model_only,
        n_rows=registration.n_rows if registration is not None else 0,
        prior_axes=_prior_axes(track),
        weakest_sigma_m=float(weakest_sigma_m),
        step_m=step_m,
        odometry_disagreement_m=odometry_disagreement_m,
        prediction_offset_m=prediction_offset_m,
        probe_share=registration.probe_return_share if registration is not None else 0.0,
        heading_difference_rad=heading_difference_rad,
        odometry_yaw_sigma_rad=np.inf if track.odometry_step is None else track.odometry_step.yaw_sigma_rad(),
        odometry_yaw_travel_rad=0.0 if track.odometry_step is None else track.odometry_step.yaw_travel_rad,
        along_difference_m=along_difference_m,
        odometry_along_sigma_m=along_sigma_m,
        odometry_along_travel_m=along_travel_m,
        pose_sigma_m=float("nan") if pose_covariance is None else _sigma_m(pose_covariance, config.lever_m),
        lost_keyframes=track.lost_keyframes,
    )


def _sigma_m(covariance: np.ndarray, lever_m: float) -> float:
    """The largest translation standard deviation plus ``lever_m`` times the largest rotation one
    of a (6,6) covariance over ``[w, v]``, metres."""
    return float(
        np.sqrt(largest_variance(covariance[3:, 3:])) + lever_m * np.sqrt(largest_variance(covariance[:3, :3]))
    )


def _beyond_shortfall(difference: float, shortfall: float) -> float:
    """The part of a refined-minus-odometry ``difference`` that the odometry stopping short of
    its target cannot explain: a difference in the direction the odometry moved from its guess
    (the sign of ``shortfall``), up to ``|shortfall|``, is put down to it."""
    if difference * shortfall <= 0.0:
        return difference
    return float(np.sign(difference) * max(abs(difference) - abs(shortfall), 0.0))


class _Channel:
    """One difference summed over the window, with its variance."""

    def __init__(self, floor: float) -> None:
        self.floor_var = floor**2
        self.difference = self.variance = 0.0

    def add(self, difference: float, variance: float, sign: float = 1.0) -> None:
        self.difference += sign * difference
        self.variance += sign * variance

    def z(self) -> float:
        return abs(self.difference) / float(np.sqrt(max(self.variance, 0.0) + self.floor_var + 1e-30))


class _ConsistencyWindow:
    """The refined-minus-odometry heading and along-track distance summed over the last
    ``config.consistency_window_m`` of travel, with the odometry's variances (module docstring)."""

    def __init__(self, config: HealthConfig) -> None:
        self._window_m = config.consistency_window_m
        self._travel_share = config.travel_share
        self.heading = _Channel(float(np.radians(config.heading_sigma_floor_deg)))
        self.along = _Channel(config.along_sigma_floor_m)
        self._entries: deque[tuple[float, float, float, float, float]] = deque()
        self._travel_m = 0.0

    def _entry(self, m: ScanMeasures) -> tuple[float, float, float, float, float]:
        """``(step_m, yaw difference, its variance, along difference, its variance)``; a quantity
        the odometry did not observe enters as 0, 0, and so does a standstill (both estimates
        see the same still scene: no evidence, and a long stop must not add up noise)."""
        yaw, yaw_var, along, along_var = 0.0, 0.0, 0.0, 0.0
        if m.step_m < _MIN_ALONG_STEP_M:
            return m.step_m, yaw, yaw_var, along, along_var
        if np.isfinite(m.odometry_yaw_sigma_rad):
            yaw = _beyond_shortfall(m.heading_difference_rad, self._travel_share * m.odometry_yaw_travel_rad)
            yaw_var = m.odometry_yaw_sigma_rad**2
        if np.isfinite(m.odometry_along_sigma_m):
            along = _beyond_shortfall(m.along_difference_m, self._travel_share * m.odometry_along_travel_m)
            along_var = m.odometry_along_sigma_m**2
        return m.step_m, yaw, yaw_var, along, along_var

    def _apply(self, entry: tuple[float, float, float, float, float], sign: float) -> None:
        self._travel_m += sign * entry[0]
        self.heading.add(entry[1], entry[2], sign)
        self.along.add(entry[3], entry[4], sign)

    def add(self, measures: ScanMeasures) -> tuple[float, float]:
        """Add a scan; returns the window's ``(heading_z, along_z)``."""
        entry = self._entry(measures)
        self._entries.append(entry)
        self._apply(entry, 1.0)
        while len(self._entries) > 1 and self._travel_m - self._entries[0][0] >= self._window_m:
            self._apply(self._entries.popleft(), -1.0)
        return self.heading.z(), self.along.z()


class HealthMonitor:
    """Turns each scan's measures into its health; one verb, :meth:`assess`, per scan in order.

    Args:
        config: the ``[health]`` section.
    """

    def __init__(self, config: HealthConfig) -> None:
        self._config = config
        self._dead_reckoned_m = 0.0  # travel with some direction from the prior, since last fully observed
        self._blind_m = 0.0  # travel with the pose not observed, in the same time
        self._observed_m = 0.0  # fully observed travel in a row
        self._consistency = _ConsistencyWindow(config)
        self._since_jump_m = math.inf  # travel since the last step the odometry contradicted by jump_m
        self._previous_flag = HealthFlag.OK
        # registered against keyframes placed while lost since a scan the health trusted, with every
        # step since consistent with the odometry: the keyframes agree with the map it came from
        self._lost_map_checked = False

    def assess(self, stamp_ns: int, measures: ScanMeasures) -> ScanHealth:
        """The health of the next scan (stamp ``stamp_ns``) from its measures."""
        config = self._config
        observed = measures.observes_every_direction(config)
        if observed:
            self._observed_m += measures.step_m
            if self._observed_m >= config.clear_after_m:
                self._dead_reckoned_m = self._blind_m = 0.0
        else:
            self._observed_m = 0.0
            self._dead_reckoned_m += measures.step_m
            if not measures.observes_pose(config):
                self._blind_m += measures.step_m
        heading_z, along_z = self._consistency.add(measures)
        inconsistent = max(heading_z, along_z) > config.max_consistency_z
        if measures.odometry_disagreement_m >= config.jump_m:
            self._since_jump_m = 0.0
        else:
            self._since_jump_m += measures.step_m
        inconsistent |= self._since_jump_m <= config.jump_window_m
        if not measures.lost_keyframes:
            self._lost_map_checked = False
        elif not self._lost_map_checked:
            self._lost_map_checked = self._previous_flag is HealthFlag.OK  # the first scan on them
        self._lost_map_checked &= not inconsistent
        on_unchecked_map = measures.lost_keyframes > 0 and not self._lost_map_checked
        if self._blind_m >= config.lost_after_m:
            flag = HealthFlag.LOST
        elif measures.pose_sigma_m > config.degraded_sigma_m or inconsistent or on_unchecked_map:
            flag = HealthFlag.DEGRADED
        else:
            flag = HealthFlag.OK
        if flag is HealthFlag.LOST:
            self._lost_map_checked = False  # keyframes placed from here on are lost too: unchecked
        self._previous_flag = flag
        return ScanHealth(stamp_ns, measures, observed, self._dead_reckoned_m, self._blind_m, flag, heading_z, along_z)


def flag_stretches(flags: Sequence[HealthFlag], flag: HealthFlag) -> list[tuple[int, int]]:
    """``(first, last)`` positions (inclusive) of every run of consecutive ``flag`` in ``flags``."""
    is_flag = np.array([f is flag for f in flags], dtype=bool)
    edges = np.diff(np.concatenate([[False], is_flag, [False]]).astype(np.int8))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    return [(int(a), int(b)) for a, b in zip(starts, ends)]


def summarize_health(
    health: Sequence[ScanHealth], scan_indices: Sequence[int] | np.ndarray, positions_m: np.ndarray
) -> HealthSummary:
    """The flags of a run counted, with its lost and degraded stretches measured along the trajectory.

    Args:
        health: the health of every scan of the trajectory, in order.
        scan_indices: (N,) input scan number of each.
        positions_m: (N,3) their positions in the final trajectory (after loop closures).
    """
    flags = [h.flag for h in health]
    n = len(flags)
    counts = {flag: sum(f is flag for f in flags) for flag in HealthFlag}
    positions = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])

    def stretches_of(flag: HealthFlag) -> tuple[HealthStretch, ...]:
        return tuple(
            HealthStretch(
                first_scan=int(scan_indices[first]),
                last_scan=int(scan_indices[last]),
                start_stamp_ns=int(health[first].stamp_ns),
                end_stamp_ns=int(health[last].stamp_ns),
                length_m=round(float(travelled[last] - travelled[max(first - 1, 0)]), 3),
            )
            for first, last in flag_stretches(flags, flag)
        )

    lost = stretches_of(HealthFlag.LOST)
    degraded = stretches_of(HealthFlag.DEGRADED)
    return HealthSummary(
        ok_scans=counts[HealthFlag.OK],
        degraded_scans=counts[HealthFlag.DEGRADED],
        lost_scans=counts[HealthFlag.LOST],
        ok_fraction=round(counts[HealthFlag.OK] / n, 4) if n else 1.0,
        lost_m=round(float(sum(s.length_m for s in lost)), 3),
        lost_stretches=lost,
        degraded_m=round(float(sum(s.length_m for s in degraded)), 3),
        degraded_stretches=degraded,
    )
