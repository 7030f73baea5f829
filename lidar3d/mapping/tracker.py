"""The tracker: one verb, :meth:`Tracker.track`, from a front-end output to a pose.

Per scan (each pose is the lidar pose at the scan's header stamp, see :mod:`lidar3d.mapping.deskew`):

1. deskew the sweep to its stamp with the motion model's predicted twist;
2. scan-to-scan odometry (two-step LM, :class:`~lidar3d.mapping.odometry.ScanToScanOdometry`) from
   the motion-model guess;
3. scan-to-submap refinement (6-DoF) from the odometry guess, fused with the motion model's
   vehicle prediction and its uncertainty (:meth:`~lidar3d.mapping.motion_model.MotionModel.prior`)
   and with the odometry step's yaw (:func:`_odometry_heading`): each direction comes from the
   scan as far as the scan observes it and from the vehicle model as far as it does not, by their
   information; there is no rule on the kind of scene;
4. the motion model learns the twist between the previous pose and this one;
5. the previous sweep is settled: now that the motion over it is known (the twist to this pose),
   it is deskewed with that motion and re-registered when that moves a point by more than
   ``redeskew_threshold_m`` compared with the prediction it was registered with.

The motion model works at each sweep's *reference instant*, the firing time of its first point,
whatever instant the header stamp marks: it learns the twist between consecutive poses at those
instants and predicts the next one there (the prior), and the pose at the stamp is the pose there
moved with the sweep's motion. A sweep stamped at its start (times 0..T) has its reference at the
stamp, so nothing moves; one stamped at its end (times -T..0, the stock ROS1 velodyne driver) gets
the same predictions, priors and settled motions as the same points stamped at the start. Working
at the stamp instead ties the estimate to the stamp convention: the pose at a sweep-end stamp is a
whole sweep away from the points the prediction anchors best, a prediction error at a turn exit
then reaches the learned twist with the opposite sign, and the deskewing, registration and motion
loop rings (20 s of ``loop`` stamped at the sweep end: 22.7 mm ATE against 7.7 mm at the start,
docs/stages/input.md#per-point-times).

The tracker reads the submap (keyframes are added by the pipeline) and owns everything else it
needs: the odometry, the motion model, the latest pose and the sweep waiting to be settled.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np

from lidar3d.config import Config, MappingConfig, MotionConfig
from lidar3d.features.frontend import PreparedScan
from lidar3d.mapping.deskew import deskew_again, twist_between
from lidar3d.mapping.keyframes import Submap
from lidar3d.mapping.motion_model import MotionModel, nominal_step_information
from lidar3d.mapping.moving_points import MovingPoints
from lidar3d.mapping.odometry import OdometryStep, ScanToScanOdometry
from lidar3d.mapping.registration import MatchRows, PosePrior, SolveResult, SweepTurn, observed_share
from lidar3d.mapping.scan_to_map import register_again, register_to_submap, sweep_tilt_on_submap
from lidar3d.mapping.se3 import exp_se3
from lidar3d.mapping.sweep import SweepFeatures
from lidar3d.mapping.sweep_tilt import SweepTilt, TiltPrior
from lidar3d.mapping.voxel import voxel_downsample
from lidar3d.records import Scan
from lidar3d.timing import StageClock

__all__ = ["SettledSweep", "TrackResult", "Tracker"]


@dataclass(frozen=True, slots=True)
class SettledSweep:
    """A sweep whose pose and motion are final (until a loop closure moves the keyframes).

    Attributes:
        scan: the raw sweep.
        sweep: its features as fired (not deskewed).
        T_world_lidar: (4,4) lidar pose at its stamp, re-registered when ``revised``.
        twist: (6,) body twist over the sweep (v m/s, w rad/s) to deskew it with for the map
            and the keyframe clouds.
        revised: the pose was re-registered with the sweep deskewed by ``twist``.
    """

    scan: Scan
    sweep: SweepFeatures
    T_world_lidar: np.ndarray
    twist: np.ndarray
    revised: bool


@dataclass(frozen=True, slots=True)
class TrackResult:
    """What the tracker concluded for one scan.

    Attributes:
        stamp_ns: the scan's stamp.
        T_world_lidar: (4,4) refined lidar pose at the stamp; the next scan may revise it (it is
            then the ``settled`` sweep of the next result).
        T_world_odom: (4,4) pose from chaining the scan-to-scan odometry alone.
        motion_model_only: the features were too few, so the pose came from the motion model.
        registration: the scan-to-submap registration (iterations, rows, degenerate directions,
            smallest eigenvalue), None when it did not run (first scan, empty submap, too few
            matches).
        prior: the motion model's prior the registration was fused with (None before the model
            is established: a cold start registers from the odometry guess alone).
        heading_observed: the scan, not the prior, decided the yaw (it removed at least half
            of the prior's yaw variance).
        deskew_twist: (6,) the predicted twist the scan was deskewed and registered with.
        odometry_step: the scan-to-scan odometry step (its uncertainty and how far it moved
            from its guess, for the health signal); None only in results built by hand.
        lost_keyframes: keyframes placed while lost in the submap this scan was registered
            against (:meth:`~lidar3d.mapping.keyframes.Submap.lost_keyframes_in_target`, taken
            right after its registration, before the previous sweep's re-registration, which may
            select a submap of its own).
        settled: the previous sweep, final now (None for the first scan).
        timings_ms: wall milliseconds per stage: deskew, odometry, mapping, redeskew (the last
            only when a previous sweep was settled).
    """

    stamp_ns: int
    T_world_lidar: np.ndarray
    T_world_odom: np.ndarray
    motion_model_only: bool
    registration: SolveResult | None
    prior: PosePrior | None
    heading_observed: bool
    deskew_twist: np.ndarray
    settled: SettledSweep | None
    timings_ms: dict[str, float]
    odometry_step: OdometryStep | None = None
    lost_keyframes: int = 0

    @property
    def well_constrained(self) -> bool:
        """The registration ran and left no direction degenerate."""
        return self.registration is not None and self.registration.degenerate_axes == 0


@dataclass(frozen=True, slots=True)
class _Refinement:
    T_world_lidar: np.ndarray
    motion_model_only: bool
    registration: SolveResult | None
    prior: PosePrior | None = None
    heading_observed: bool = True
    source: _Source | None = None  # what the registration matched


@dataclass(frozen=True, slots=True)
class _Source:
    """The points a registration matched: (N,3) in the lidar frame at the stamp, deskewed with the
    twist the sweep was registered with, and (N,) when each was fired (s from the stamp; for a
    voxel's centroid, the mean of its points')."""

    points_lidar: np.ndarray
    time_s: np.ndarray


@dataclass(frozen=True, slots=True)
class _Latest:
    """The latest tracked scan: where the next one starts from; ``T_world_reference`` is its lidar
    pose at ``reference_ns``, the sweep's reference instant (:func:`_reference_offset_s`)."""

    stamp_ns: int
    T_world_lidar: np.ndarray
    T_world_odom: np.ndarray
    reference_ns: int
    T_world_reference: np.ndarray


@dataclass(frozen=True, slots=True)
class _Unsettled:
    """The latest sweep, registered deskewed with ``deskew_twist``, waiting for its forward motion."""

    scan: Scan
    sweep: SweepFeatures
    T_world_lidar: np.ndarray
    deskew_twist: np.ndarray
    registered: bool  # the pose came from a registration with no degenerate direction
    reference_offset_s: float
    reference_twist: np.ndarray  # moves the pose from the stamp to the reference instant
    reference_information: np.ndarray  # (6, 6) what its rows were judged against (the vehicle prior's)
    source: _Source | None  # the points its registration matched (None: not registered)
    matches: MatchRows | None  # their correspondences in the submap, world frame
    submap_revision: int  # Submap.revision when they were found


class Tracker:
    """Deskew, odometry, scan-to-submap refinement, motion model and re-registration, per scan.

    Args:
        config: the run's configuration (``sensor``, ``odometry`` and ``mapping`` sections).
        submap: the keyframe submap to register against (read only; the pipeline adds keyframes).
        moving: the moving-point test whose points are kept out of the registration (the pipeline
            gives it the keyframes and the pose uncertainty), None for none.
    """

    def __init__(self, config: Config, submap: Submap, moving: MovingPoints | None = None) -> None:
        self._sweep_period_s = config.sensor.resolved_model.sweep_period_s
        self._mapping = config.mapping
        self._vehicle = config.motion
        self._odometry = _scan_to_scan_odometry(config)
        self._fuse_heading = config.odometry.fuse_heading
        self._heading_shortfall = config.odometry.heading_shortfall
        self._submap = submap
        self._motion = MotionModel.of_config(config.motion)
        self._nominal_information = nominal_step_information(self._vehicle, self._sweep_period_s)
        self._tilt_prior = TiltPrior.of_config(config.motion, self._sweep_period_s)
        self._turn = _sweep_turn_prior(config, self._sweep_period_s)
        self._moving = moving
        self._latest: _Latest | None = None
        self._motion_known = False  # the motion model has learned a twist
        self._unsettled: _Unsettled | None = None

    def track(self, prepared: PreparedScan) -> TrackResult:
        """Estimate the pose of a scan stamped after the previous one; settle the previous sweep."""
        scan = prepared.scan
        sweep = SweepFeatures.of(prepared)
        clock = StageClock()
        previous = self._latest
        dt_s = (scan.stamp_ns - previous.stamp_ns) * 1e-9 if previous else 0.0
        offset_s = _reference_offset_s(scan.time_offset_s)
        reference_ns = scan.stamp_ns + round(offset_s * 1e9)
        reference_dt_s = (reference_ns - previous.reference_ns) * 1e-9 if previous else 0.0
        predicted = self._motion.prediction()
        with clock("deskew"):
            deskewed = sweep.deskewed(predicted)
        if self._moving is not None:
            with clock("mapping"):
                guess = previous.T_world_lidar @ exp_se3(predicted * dt_s) if previous else None
                sweep, deskewed = self._moving.without_moving(sweep, deskewed, guess)
        with clock("odometry"):
            step = self._odometry.update(deskewed.features, exp_se3(predicted * dt_s))
        T_world_odom = previous.T_world_odom @ step.T_prev_curr if previous else np.eye(4)
        with clock("mapping"):
            refinement = self._refine(deskewed, previous, step, reference_dt_s, offset_s, predicted)
        lost_keyframes = self._submap.lost_keyframes_in_target()
        T_world_lidar = refinement.T_world_lidar
        motion_known = self._motion_known
        sweep_twist = predicted
        if refinement.registration is not None and refinement.registration.yaw_rate_correction_rad_s:
            sweep_twist = predicted.copy()
            sweep_twist[5] += refinement.registration.yaw_rate_correction_rad_s
        T_world_reference = _moved_by(T_world_lidar, offset_s, sweep_twist)
        well_constrained = refinement.registration is not None and refinement.registration.degenerate_axes == 0
        if refinement.prior is not None:
            self._motion.learn_innovation(
                refinement.prior, T_world_lidar, self._vehicle.innovation_smoothing, well_constrained
            )
        if previous is not None:
            self._motion.update(
                twist_between(previous.T_world_reference, T_world_reference, reference_dt_s),
                well_constrained=well_constrained,
                heading_observed=refinement.heading_observed,
                dt_s=reference_dt_s,
            )
            self._motion_known = True
        # The pose at the reference instant is the stamp's moved with the motion the sweep was
        # deskewed with; a sweep deskewed before any motion was known (predicted still) takes the
        # first motion learned once there is one.
        reference_twist = sweep_twist if motion_known else self._motion.twist.copy()
        if not motion_known:
            T_world_reference = _moved_by(T_world_lidar, offset_s, reference_twist)
        settled = None
        if self._unsettled is not None:
            with clock("redeskew"):
                settled = self._settle(self._unsettled, self._motion.twist)
        self._unsettled = _Unsettled(
            scan,
            sweep,
            T_world_lidar,
            sweep_twist,
            well_constrained,
            offset_s,
            reference_twist,
            self._reference(refinement.prior),
            refinement.source,
            refinement.registration.matches if refinement.registration is not None else None,
            self._submap.revision,
        )
        self._latest = _Latest(scan.stamp_ns, T_world_lidar, T_world_odom, reference_ns, T_world_reference)
        return TrackResult(
            stamp_ns=scan.stamp_ns,
            T_world_lidar=T_world_lidar,
            T_world_odom=T_world_odom,
            motion_model_only=refinement.motion_model_only,
            registration=refinement.registration,
            prior=refinement.prior,
            heading_observed=refinement.heading_observed,
            deskew_twist=predicted,
            settled=settled,
            timings_ms=clock.ms,
            odometry_step=step,
            lost_keyframes=lost_keyframes,
        )

    def finish(self) -> SettledSweep | None:
        """End of input: the last sweep, settled with the latest motion (no re-registration);
        None when there is none left."""
        unsettled, self._unsettled = self._unsettled, None
        if unsettled is None:
            return None
        return SettledSweep(unsettled.scan, unsettled.sweep, unsettled.T_world_lidar, self._motion.twist, revised=False)

    def apply_correction(self, correction: np.ndarray) -> None:
        """A loop closure moved the world under the latest scan: left-multiply its pose (and the
        unsettled sweep's, the same scan) by the (4,4) world-frame ``correction``."""
        if (latest := self._latest) is not None:
            self._latest = replace(
                latest,
                T_world_lidar=correction @ latest.T_world_lidar,
                T_world_reference=correction @ latest.T_world_reference,
            )
        if self._unsettled is not None:
            self._unsettled = replace(self._unsettled, T_world_lidar=correction @ self._unsettled.T_world_lidar)

    def _reference(self, vehicle: PosePrior | None) -> np.ndarray:
        """(6, 6) what a scan's rows are judged against: the vehicle prior's information once the
        motion model is established, its nominal uncertainty over one sweep before."""
        return self._nominal_information if vehicle is None else vehicle.information

    def _refine(
        self,
        deskewed: SweepFeatures,
        previous: _Latest | None,
        step: OdometryStep,
        reference_dt_s: float,
        offset_s: float,
        twist: np.ndarray,
    ) -> _Refinement:
        """Scan-to-submap refinement of a sweep deskewed with the predicted motion ``twist``.

        Registration starts from the odometry pose and, once the motion model is established,
        is fused with its vehicle prior: the motion model predicts the pose at the sweep's
        reference instant (``reference_dt_s`` after the previous one's, ``offset_s`` after the
        stamp), moved to the stamp with ``twist``. :meth:`_settle` revisits the pose once the
        motion over the sweep is known.
        """
        if previous is None:
            return _Refinement(np.eye(4), False, None)
        T_world_lidar = previous.T_world_lidar @ step.T_prev_curr
        if not len(self._submap):
            return _Refinement(T_world_lidar, step.used_motion_model, None)
        prior = None
        if self._motion.established:
            at_reference = self._motion.prior(previous.T_world_reference, reference_dt_s, self._vehicle)
            prior = _moved_prior(at_reference, -offset_s, twist)
        heading = _odometry_heading(T_world_lidar, step, self._heading_shortfall) if self._fuse_heading else None
        fused = _fused(prior, heading, T_world_lidar, self._vehicle)
        refined, estimated, source = _register(
            self._submap,
            self._mapping,
            deskewed,
            T_world_lidar,
            self._mapping.max_iterations,
            fused,
            self._reference(prior),
            prior is not None,
            self._tilt_prior.sigma_rad,
            turn=None if prior is None or self._turn is None else (twist, *self._turn),
        )
        self._tilt_prior.learn(estimated)
        if refined.iterations == 0:
            return _Refinement(T_world_lidar, step.used_motion_model, None)
        measured = refined.information if heading is None else refined.information + heading.information
        heading_observed = prior is None or observed_share(measured, prior.information)[5] >= 0.5
        return _Refinement(refined.T_target_source, False, refined, prior, heading_observed, source)

    def _settle(self, unsettled: _Unsettled, twist: np.ndarray) -> SettledSweep:
        """The unsettled sweep, registered again with its points deskewed by ``twist`` (its forward
        motion, between the reference instants) when that differs enough from the prediction it
        was registered with, from its pose at the reference instant (:func:`_register_settled`).
        Scans that were not fully constrained keep their pose: their free directions came from
        the motion model, which the forward difference would only echo."""
        mp = self._mapping
        kept = SettledSweep(unsettled.scan, unsettled.sweep, unsettled.T_world_lidar, twist, revised=False)
        change = twist - unsettled.deskew_twist
        moved_m = max(np.linalg.norm(change[:3]), mp.redeskew_lever_m * np.linalg.norm(change[3:]))
        if not unsettled.registered or moved_m * self._sweep_period_s < mp.redeskew_threshold_m:
            return kept
        refined = _register_settled(self._submap, mp, unsettled, twist, self._tilt_prior.sigma_rad)
        if refined is None or refined.iterations == 0 or refined.degenerate_axes:
            return kept
        return SettledSweep(unsettled.scan, unsettled.sweep, refined.T_target_source, twist, revised=True)


def _register_settled(
    submap: Submap, mp: MappingConfig, unsettled: _Unsettled, twist: np.ndarray, tilt_sigma_rad: float
) -> SolveResult | None:
    """The registration of a sweep deskewed again with ``twist``, from its pose kept at the
    reference instant (None: its registration left nothing to start from). Its points move by a
    few centimetres, so it keeps the correspondences its registration ended with
    (:func:`register_again`: no new search of the submap), unless the submap changed under them
    since (:attr:`Submap.revision`: the first keyframe's clouds replaced, a loop closure moving
    its keyframes, each by its own correction) or the sweep's tilt is fitted
    (``mapping.tilt_knot_spacing_s``: the tilt follows the deskewing): then the sweep, deskewed
    again whole, is registered anew (:func:`_register`)."""
    source, matches = unsettled.source, unsettled.matches
    if source is None or matches is None:
        return None
    guess = _kept_at_reference(unsettled, twist)
    if unsettled.submap_revision == submap.revision and mp.tilt_knot_spacing_s <= 0:
        moved = deskew_again(source.points_lidar, source.time_s, unsettled.deskew_twist, twist)
        return register_again(matches, moved, guess, mp, reference_information=unsettled.reference_information)
    deskewed = unsettled.sweep.deskewed(twist)
    reference = unsettled.reference_information
    return _register(submap, mp, deskewed, guess, mp.redeskew_iterations, None, reference, False, tilt_sigma_rad)[0]


def _register(
    submap: Submap,
    mp: MappingConfig,
    deskewed: SweepFeatures,
    T_world_lidar: np.ndarray,
    iterations: int,
    prior: PosePrior | None,
    reference_information: np.ndarray,
    widen_search: bool,
    tilt_sigma_rad: float,
    *,
    turn: tuple[np.ndarray, float, float] | None = None,
) -> tuple[SolveResult, SweepTilt | None, _Source]:
    """Scan-to-submap registration of a deskewed sweep from ``T_world_lidar``, fused with ``prior``
    when given; a direction the rows know less well than the (6, 6) ``reference_information`` is
    degenerate (see :func:`register_to_submap`). Then, unless ``mapping.tilt_knot_spacing_s`` is
    0, the sweep's roll and pitch beyond its twist (each knot's prior ``tilt_sigma_rad``) are
    fitted with the pose held, and the sweep moved by them is registered again from that pose
    (at most ``mapping.redeskew_iterations``) when the tilt moves a point by as much as a new
    deskewing must to register again (``redeskew_threshold_m`` at ``redeskew_lever_m``). Returns
    the registration, the tilt estimated (None: none) and the points it matched. The tilt moves the registration's
    points only: the keyframes and the map keep the sweep as deskewed (fed back into the map,
    the tilts followed the map's own slope errors: ``hilly`` seed 0 0.011 -> 0.030 m).
    ``turn``: the (6,) twist the sweep was deskewed with, the prior information of its yaw rate,
    (rad/s)^-2, and the sigmas from which a correction is kept, to solve the rate beside the pose
    (:class:`~lidar3d.mapping.registration.SweepTurn`); the points returned are then turned by the
    rate found."""
    corner, corner_time_s, surf, surf_time_s = deskewed.timed_registration_clouds(mp)
    surf, surf_time_s = voxel_downsample(surf, mp.scan_surf_voxel_m, surf_time_s)
    target = submap.target(T_world_lidar[:3, 3])
    register = functools.partial(
        register_to_submap, target, config=mp, reference_information=reference_information, prior=prior
    )
    time_s = np.concatenate([corner_time_s, surf_time_s])
    sweep_turn = None if turn is None else SweepTurn(time_s, turn[0][:3], turn[1], turn[2])
    result = register(
        corner, surf, T_world_lidar, max_iterations=iterations, widen_search=widen_search, turn=sweep_turn
    )
    points = np.concatenate([corner, surf])
    if sweep_turn is not None and result.yaw_rate_correction_rad_s:
        points = sweep_turn.turned(points, result.yaw_rate_correction_rad_s)
    source = _Source(points, time_s)
    if mp.tilt_knot_spacing_s <= 0 or result.iterations == 0:
        return result, None, source
    tilt = sweep_tilt_on_submap(
        target, (corner, corner_time_s), (surf, surf_time_s), result.T_target_source, mp, tilt_sigma_rad
    )
    if tilt is None or tilt.max_rad * mp.redeskew_lever_m < mp.redeskew_threshold_m:
        return result, tilt, source  # it moves no point by as much as a new deskewing must to register again
    again = register(
        tilt.apply(corner, corner_time_s),
        tilt.apply(surf, surf_time_s),
        result.T_target_source,
        max_iterations=mp.redeskew_iterations,
        widen_search=False,
    )
    return (again if again.iterations else result), tilt, source  # a tilted sweep settles anew: source unused


def _sweep_turn_prior(config: Config, sweep_period_s: float) -> tuple[float, float] | None:
    """What the registration solves the sweep's yaw rate with (None: not solved for,
    ``mapping.solve_sweep_yaw_rate`` off): the prior information of its correction, (rad/s)^-2 (one
    sigma: what the vehicle's yaw acceleration changes over one sweep), and the sigmas a correction
    must reach to be kept (``motion.twist_change_sigmas``)."""
    if not config.mapping.solve_sweep_yaw_rate:
        return None
    return (config.motion.yaw_accel_rad_s2 * sweep_period_s) ** -2.0, config.motion.twist_change_sigmas


def _scan_to_scan_odometry(config: Config) -> ScanToScanOdometry:
    """The scan-to-scan odometry of the ``[odometry]`` section for the configured sensor."""
    odo = config.odometry
    return ScanToScanOdometry(
        n_rings=config.sensor.resolved_model.n_rings,
        max_iterations=odo.max_iterations,
        rematch_every=odo.rematch_every,
        min_rows=odo.min_rows,
        degeneracy_threshold=odo.degeneracy_threshold,
        search_radius_m=odo.search_radius_m,
        min_previous_edges=odo.min_previous_edges,
        min_previous_planes=odo.min_previous_planes,
    )


def _odometry_heading(T_world_guess: np.ndarray, step: OdometryStep, shortfall: float) -> PosePrior | None:
    """The scan-to-scan odometry's yaw as a belief about the scan's pose: the (4,4) guess it gave
    (the previous pose moved by the step), informative about the yaw only, by
    :meth:`OdometryStep.yaw_information` with ``shortfall``; None when the step measured no yaw.

    The scan-to-submap rows alone hold the pose to the submap, which was built from the estimated
    poses: a heading error the submap shares is invisible to them, and on ``blind_turn`` (seed 1)
    such an error grew at 0.5 deg/s from the first scans (the map bent with it) while the
    scan-to-scan yaw, measured against the previous sweep alone, stayed within 0.03 deg/s."""
    yaw_information = step.yaw_information(shortfall)  # 0 for a kept guess: it has no edge rows
    if yaw_information <= 0.0:
        return None
    information = np.zeros((6, 6))
    information[5, 5] = yaw_information
    return PosePrior(T_world_guess, information)


def _fused(
    prior: PosePrior | None, heading: PosePrior | None, T_world_guess: np.ndarray, vehicle: MotionConfig
) -> PosePrior | None:
    """The belief the registration is fused with: the vehicle prior and the odometry heading, each
    by its information. Before the vehicle model is established (a cold start) the heading
    stands with a weak belief at the (4,4) guess on the other axes (``vehicle.cold_start_sigma_m``
    and ``_deg``) that keeps what the rows do not observe where the guess put it."""
    if heading is None:
        return prior
    if prior is None:
        sigma = np.r_[np.full(3, vehicle.cold_start_sigma_m), np.full(3, np.radians(vehicle.cold_start_sigma_deg))]
        prior = PosePrior(T_world_guess, np.diag(sigma**-2.0))
    return prior.fused_with(heading)


def _kept_at_reference(unsettled: _Unsettled, twist: np.ndarray) -> np.ndarray:
    """The unsettled sweep's pose at its stamp once its motion is known to be ``twist``: its pose
    at the reference instant (where the prediction anchored the registration) is kept and the
    stamp's pose moved with ``twist``; the tracked pose itself when the reference is the stamp."""
    offset_s = unsettled.reference_offset_s
    at_reference = _moved_by(unsettled.T_world_lidar, offset_s, unsettled.reference_twist)
    return _moved_by(at_reference, -offset_s, twist)


def _reference_offset_s(time_offset_s: np.ndarray) -> float:
    """The sweep's reference instant (s after its stamp): the time of its first point, whatever
    instant the stamp marks (0 for a sweep stamped at its start, about -T at its end; 0 for an
    empty sweep). The motion model works with the poses at these instants."""
    if len(time_offset_s) == 0:
        return 0.0
    return float(np.min(time_offset_s))


def _moved_by(T_world_lidar: np.ndarray, dt_s: float, twist: np.ndarray) -> np.ndarray:
    """The (4,4) pose ``dt_s`` seconds after ``T_world_lidar`` under the constant body ``twist``
    (6,); the same array when ``dt_s`` is 0."""
    if dt_s == 0.0:
        return T_world_lidar
    return T_world_lidar @ exp_se3(twist * dt_s)


def _moved_prior(prior: PosePrior, dt_s: float, twist: np.ndarray) -> PosePrior:
    """The belief about the pose ``dt_s`` seconds after the one ``prior`` is about, under the constant
    body ``twist`` (6,): the mean moved, and the information carried over to first order (a world
    rotation of the first pose by d_theta moves the second's position by d_theta x lever, the lever
    being the world-frame offset between the two); ``prior`` itself when ``dt_s`` is 0."""
    if dt_s == 0.0:
        return prior
    T_mean = _moved_by(prior.T_target_source, dt_s, twist)
    lever = T_mean[:3, 3] - prior.T_target_source[:3, 3]
    back = np.eye(6)  # first-order map from the moved pose's perturbation back to the first's
    back[:3, 3:] = [[0.0, -lever[2], lever[1]], [lever[2], 0.0, -lever[0]], [-lever[1], lever[0], 0.0]]
    return PosePrior(T_mean, back.T @ prior.information @ back)
