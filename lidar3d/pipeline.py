"""The SLAM pipeline: a short composition of the stages, scan by scan, into a :class:`SlamResult`.

Parts, each owning its state and answering with a record:

* :class:`~lidar3d.mapping.tracker.Tracker`: deskew, odometry, scan-to-submap refinement, motion
  model, re-registration of the previous sweep -> :class:`~lidar3d.mapping.tracker.TrackResult`;
* :class:`~lidar3d.mapping.keyframes.KeyframeSelector` and the
  :class:`~lidar3d.mapping.keyframes.Submap` of keyframes the tracker registers against;
* :class:`~lidar3d.loop.closer.LoopCloser` -> :class:`~lidar3d.loop.closer.LoopUpdate`, which this
  module applies to the scan poses, the submap, the keyframe spacing and the tracker;
* the :class:`~lidar3d.mapping.dense_map.DenseMap`, which a settled sweep enters, its moving objects
  taken out into a map of their own; with loop closure it also keeps the sweeps in pieces anchored
  to keyframes (:mod:`lidar3d.mapping.map_pieces`), and :meth:`SlamPipeline.finish` places the map
  again from them when loop closures moved the keyframes;
* :class:`~lidar3d.mapping.health.HealthMonitor`: the health of every scan (ok / degraded / lost)
  from what the tracker concluded;
* :class:`~lidar3d.run_statistics.RunStatistics`: timings, counters, warnings.

It writes nothing; adapters (``lidar3d.run``) iterate it, show progress and publish outputs. Each
pose is the lidar pose at the scan's header stamp (see :mod:`lidar3d.mapping.deskew`).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from lidar3d.config import Config
from lidar3d.features.frontend import STAGES as FRONT_END_STAGES
from lidar3d.features.frontend import PreparedScan, prepare_scan
from lidar3d.loop.closer import LoopCloser, LoopUpdate, correct_scan_poses
from lidar3d.loop.records import LoopCandidate
from lidar3d.map_process import DenseMapProcess
from lidar3d.mapping.dense_map import DenseMap, MapClouds
from lidar3d.mapping.health import HealthFlag, HealthMonitor, ScanHealth, scan_measures, summarize_health
from lidar3d.mapping.keyframes import Keyframe, KeyframeCloudStore, KeyframeSelector, Submap
from lidar3d.mapping.map_pieces import MapPieces, PieceStore
from lidar3d.mapping.moving_points import MovingPoints
from lidar3d.mapping.pose_uncertainty import PoseUncertainty
from lidar3d.mapping.step_uncertainty import StepUncertainty
from lidar3d.mapping.sweep import SweepFeatures
from lidar3d.mapping.tracker import SettledSweep, Tracker
from lidar3d.records import Scan, Trajectory
from lidar3d.run_statistics import RunStatistics
from lidar3d.summary import HealthSummary
from lidar3d.timing import StageClock

__all__ = ["STAGES", "ScanEstimate", "SlamPipeline", "SlamResult", "SpillStores", "run_slam"]

log = logging.getLogger(__name__)

STAGES = ("deskew", *FRONT_END_STAGES, "odometry", "mapping", "redeskew", "map_update")


@dataclass(frozen=True, slots=True)
class ScanEstimate:
    """The pipeline's estimate of one scan.

    Attributes:
        scan_index: position of the scan in the input stream (dropped scans keep their number).
        stamp_ns: scan stamp.
        T_world_lidar: (4,4) refined lidar pose at the stamp.
        T_world_odom: (4,4) scan-to-scan odometry pose at the stamp.
        is_keyframe: the scan became a keyframe.
        motion_model_only: features were too few, so the pose came from the motion model.
        health: how well the scan observed its pose, and its flag.
    """

    scan_index: int
    stamp_ns: int
    T_world_lidar: np.ndarray
    T_world_odom: np.ndarray
    is_keyframe: bool
    motion_model_only: bool
    health: ScanHealth


@dataclass(frozen=True, slots=True)
class SlamResult:
    """Everything a run produced.

    Attributes:
        trajectory: refined pose of every processed scan.
        odometry: scan-to-scan odometry pose of every processed scan.
        keyframes: keyframe poses (stamps of the keyframe scans).
        keyframe_scan_indices: (K,) scan index of each keyframe.
        scan_indices: (N,) scan index (position in the input stream) of each trajectory pose.
        map_points: (M,3) dense voxel map, world frame (the static map when moving objects are removed).
        map_intensity: (M,) mean intensity per voxel.
        dynamic_points: (D,3) voxel map of the points removed as moving objects, world frame (empty
            when removal is off: see ``removes_dynamic``).
        dynamic_intensity: (D,) mean intensity per voxel.
        removes_dynamic: moving objects were taken out of ``map_points`` (``dynamic.enabled``).
        timings_ms: stage name -> (N,) milliseconds per processed scan.
        counts: named counters (scans, dropped stamps, motion-model scans, degenerate scans...).
        health: the health of every processed scan, in trajectory order.
        health_summary: the health flags counted, with the lost stretches measured on ``trajectory``.
        warnings: human-readable warnings collected during the run.
        partial: the run stopped before the end of the input.
        loop_ms_total: milliseconds spent in loop detection and the pose graph.
        loop_candidates: every verified loop candidate, accepted or rejected, with its reason.
        pose_graph_g2o: the keyframe pose graph in g2o text ("" without loop closure).
        map_rebuild_s: seconds spent placing the map again after loop closures (None: not placed
            again).
    """

    trajectory: Trajectory
    odometry: Trajectory
    keyframes: Trajectory
    keyframe_scan_indices: np.ndarray
    scan_indices: np.ndarray
    map_points: np.ndarray
    map_intensity: np.ndarray
    dynamic_points: np.ndarray
    dynamic_intensity: np.ndarray
    removes_dynamic: bool
    timings_ms: dict[str, np.ndarray]
    counts: dict[str, int]
    health: tuple[ScanHealth, ...]
    health_summary: HealthSummary
    warnings: tuple[str, ...] = field(default=())
    partial: bool = False
    loop_ms_total: float = 0.0
    loop_candidates: tuple[LoopCandidate, ...] = field(default=())
    pose_graph_g2o: str = ""
    map_rebuild_s: float | None = None


@dataclass(frozen=True, slots=True)
class SpillStores:
    """Where a run's long-lived data waits (None: in memory): the dense map's pieces, kept with
    loop closure on, and the clouds of keyframes older than the submap's latest ones."""

    pieces: PieceStore | None = None
    keyframe_clouds: KeyframeCloudStore | None = None


class SlamPipeline:
    """Call :meth:`process` per scan, :meth:`finish` at the end of the input, then :meth:`result`.
    ``stores``: where long-lived data waits (:class:`SpillStores`; default: in memory);
    ``map_in_process``: the same map built in a child process (:mod:`lidar3d.map_process`)."""

    def __init__(self, config: Config, stores: SpillStores | None = None, *, map_in_process: bool = False) -> None:
        stores = stores or SpillStores()
        self.config = config
        mp = config.mapping
        self.submap = Submap.of_config(mp, stores.keyframe_clouds)
        self.moving_points = MovingPoints.of_config(config)
        self.tracker = Tracker(config, self.submap, self.moving_points)
        self.keyframe_selector = KeyframeSelector(
            distance_m=mp.keyframe_distance_m, angle_deg=mp.keyframe_angle_deg, min_surface_points=mp.min_rows
        )
        self.loop = LoopCloser(config.loop) if config.loop.enabled else None
        self.health = HealthMonitor(config.health)
        self._step_uncertainty = StepUncertainty(config.motion)
        self._pose_uncertainty = PoseUncertainty(config.motion)
        self.stats = RunStatistics()
        self._map = _dense_map(config, self.loop is not None, stores.pieces, self.stats if map_in_process else None)
        self._estimates: list[ScanEstimate] = []
        self._n_seen = 0

    @property
    def estimates(self) -> tuple[ScanEstimate, ...]:
        """The estimate of every processed scan so far (loop closures included)."""
        return tuple(self._estimates)

    def process(self, scan: Scan | PreparedScan) -> ScanEstimate | None:
        """Track one scan; returns its estimate as known now, or None when the scan is dropped
        (stamp not after the previous one's). ``scan`` may come already through the front end
        (:func:`prepare_scan`, an adapter may run it ahead in another process). The next scan may
        still revise the returned pose and a loop closure correct it; :meth:`result` has the poses
        as they end up."""
        index = self._n_seen
        self._n_seen += 1
        stamp_ns = scan.scan.stamp_ns if isinstance(scan, PreparedScan) else scan.stamp_ns
        if self._estimates and stamp_ns <= self._estimates[-1].stamp_ns:
            kind = "duplicate" if stamp_ns == self._estimates[-1].stamp_ns else "out-of-order"
            self.stats.count(f"dropped_{kind.replace('-', '_')}_stamps")
            log.warning("scan %d: %s stamp %d dropped", index, kind, stamp_ns)
            return None
        prepared = scan if isinstance(scan, PreparedScan) else prepare_scan(scan, self.config)
        self.stats.add_timings(prepared.stage_ms)
        previous = self._estimates[-1] if self._estimates else None
        track = self.tracker.track(prepared)
        dt_s = (stamp_ns - previous.stamp_ns) * 1e-9 if previous is not None else 0.0
        rows_information = track.registration.information if track.registration is not None else None
        self._step_uncertainty.add(
            track.T_world_lidar, dt_s, rows_information, track.prior.information if track.prior is not None else None
        )
        pose_covariance = self._pose_uncertainty.add(track.T_world_lidar, dt_s, rows_information)
        if self.moving_points is not None:
            self.moving_points.note_pose_covariance(
                pose_covariance, track.prior.rotation_variance_rad2() if track.prior is not None else 0.0
            )
        health = self.health.assess(stamp_ns, scan_measures(track, previous, self.config.health, pose_covariance))
        self.stats.add_timings(track.timings_ms)
        if track.registration is not None and track.registration.degenerate_axes:
            self.stats.count("degenerate_scans")
        self.stats.scan_tracked(index, track.motion_model_only)
        sweep = SweepFeatures.of(prepared)
        is_keyframe = self.keyframe_selector.is_due(track.T_world_lidar, sweep.n_surface_points)
        if is_keyframe:
            self.keyframe_selector.anchor(track.T_world_lidar)
            if self.moving_points is not None:
                self.moving_points.add_keyframe(track.T_world_lidar)
        clock = StageClock()
        with clock("map_update"):
            T_world_lidar = track.T_world_lidar
            if track.settled is not None:
                update = self._settle(track.settled, next_is_keyframe=is_keyframe)
                if update is not None:
                    T_world_lidar = update.correction @ T_world_lidar
                    self.tracker.apply_correction(update.correction)
                if is_keyframe:
                    self.keyframe_selector.anchor(T_world_lidar)
            if is_keyframe and not len(self.submap):
                # The first keyframe enters at once (empty submap); _settle deskews it once its motion is known.
                self._add_keyframe(index, stamp_ns, T_world_lidar, sweep.deskewed(track.deskew_twist), health)
        self.stats.add_timings(clock.ms)
        estimate = ScanEstimate(
            index, stamp_ns, T_world_lidar, track.T_world_odom, is_keyframe, track.motion_model_only, health
        )
        self._estimates.append(estimate)
        self.stats.count("scans")
        return estimate

    def finish_tracking(self) -> None:
        """End of input for the poses (the last sweep settled, an open motion-model stretch
        reported): trajectory, keyframes and closures are final, the map may still be catching up."""
        self.stats.end_of_input(self._n_seen)
        settled = self.tracker.finish()
        if settled is not None:
            self._settle(settled, next_is_keyframe=False)

    def finish(self) -> None:
        """End of input: :meth:`finish_tracking`, then the map takes every sweep; after loop closures
        it is placed again from its pieces, each with its keyframe's corrected pose. Idempotent."""
        self.finish_tracking()
        self._map.finish()
        if self.stats.counts.get("loop_closures") and self.stats.map_rebuild_s is None:
            t0 = time.perf_counter()
            self._map.place_again(self.submap.poses)
            self.stats.map_rebuild_s = round(time.perf_counter() - t0, 3)
        if isinstance(self._map, DenseMapProcess):
            self._map.end()  # the map is final: its process ends

    def result(self, partial: bool = False, *, with_map: bool = True) -> SlamResult:
        """A snapshot of the result so far; changes nothing (``partial`` marks an unfinished run).

        Before :meth:`finish`, the last scan is not yet in the map (its deskewing waits for the
        next scan; with dynamic removal the last ``dynamic.window_scans`` wait for the sweeps after
        them) and an open motion-model stretch is reported up to the last scan. ``with_map`` False
        leaves the map's clouds empty: a checkpoint that does not write the map does not fetch it
        (from the map's process: the whole map copied across, tens of MB, each time).
        """
        clouds = self._map.clouds() if with_map else MapClouds.empty()
        trajectory = _trajectory_of(self._estimates)
        scan_indices = np.array([e.scan_index for e in self._estimates], dtype=np.int64)
        health = tuple(e.health for e in self._estimates)
        health_summary = summarize_health(health, scan_indices, trajectory.positions_m)
        return SlamResult(
            trajectory=trajectory,
            odometry=_trajectory_of(self._estimates, odometry=True),
            keyframes=Trajectory(self.submap.keyframes.stamps_ns, self.submap.poses.reshape(-1, 4, 4)),
            keyframe_scan_indices=self.submap.keyframes.scan_indices,
            scan_indices=scan_indices,
            map_points=clouds.points,
            map_intensity=clouds.intensity,
            dynamic_points=clouds.dynamic_points,
            dynamic_intensity=clouds.dynamic_intensity,
            removes_dynamic=self._map.removes_dynamic,
            timings_ms=self.stats.timings_ms(),
            loop_ms_total=self.stats.loop_ms,
            counts=dict(self.stats.counts),
            warnings=self.stats.warnings(self._n_seen, health_summary),
            partial=partial,
            loop_candidates=tuple(self.loop.candidates) if self.loop else (),
            pose_graph_g2o=self.loop.graph.g2o_text(self.submap.poses) if self.loop and len(self.submap) else "",
            map_rebuild_s=self.stats.map_rebuild_s,
            health=health,
            health_summary=health_summary,
        )

    def _settle(self, settled: SettledSweep, *, next_is_keyframe: bool) -> LoopUpdate | None:
        """The latest estimate's sweep is final: take its revised pose, store it as a keyframe if
        it was selected, and add it to the map. Returns the loop update its keyframe caused."""
        latest = self._estimates[-1]
        if settled.revised:
            self.stats.count("redeskewed_scans")
            self._estimates[-1] = latest = dataclasses.replace(latest, T_world_lidar=settled.T_world_lidar)
            if latest.is_keyframe and not next_is_keyframe:
                self.keyframe_selector.anchor(settled.T_world_lidar)
        update = None
        if latest.is_keyframe:
            deskewed = settled.sweep.deskewed(settled.twist)
            if len(self.submap) and self.submap.keyframes[-1].scan_index == latest.scan_index:
                self.submap.replace_clouds(len(self.submap) - 1, *deskewed.keyframe_clouds(self.config.mapping))
            else:
                update = self._add_keyframe(
                    latest.scan_index, latest.stamp_ns, settled.T_world_lidar, deskewed, latest.health
                )
        # A loop closed at this sweep's own keyframe moved the sweep with it (and the anchor).
        T_map = self._estimates[-1].T_world_lidar if update is not None else settled.T_world_lidar
        self._map.add(settled.scan, T_map, settled.twist, self.submap.anchor())
        return update

    def _add_keyframe(
        self, scan_index: int, stamp_ns: int, T_world_lidar: np.ndarray, deskewed: SweepFeatures, health: ScanHealth
    ) -> LoopUpdate | None:
        """Add a keyframe (``health``: its scan's) and look for a loop at it; an accepted loop is applied at once."""
        corner, surf = deskewed.keyframe_clouds(self.config.mapping)
        step = self._step_uncertainty.take() if len(self.submap) else None
        lost = health.flag is HealthFlag.LOST  # a scan registered against it inherits its error
        self.submap.add(Keyframe(len(self.submap), scan_index, stamp_ns, T_world_lidar, corner, surf, step, lost))
        if self.loop is None:
            return None
        t0 = time.perf_counter()
        update = self.loop.on_keyframe(self.submap.keyframes, self.submap.poses)
        self.stats.loop_ms += (time.perf_counter() - t0) * 1e3
        if update is not None:
            self._apply_loop_update(update)
        return update

    def _apply_loop_update(self, update: LoopUpdate) -> None:
        """Move the keyframes to their corrected poses and every scan pose with them."""
        self.stats.count("loop_closures", len(update.closures))
        self.submap.set_poses(update.poses)
        if self.moving_points is not None:
            self.moving_points.clear()  # the keyframes whose rays it holds moved
        keyframe_stamps = self.submap.keyframes.stamps_ns
        before = _trajectory_of(self._estimates)
        corrected = correct_scan_poses(
            before.stamps_ns, before.T_world_lidar, keyframe_stamps, update.previous_poses, update.poses
        )
        self._estimates = [dataclasses.replace(e, T_world_lidar=T) for e, T in zip(self._estimates, corrected)]
        self.keyframe_selector.anchor(update.poses[-1])


def _dense_map(
    config: Config, in_pieces: bool, piece_store: PieceStore | None, process_stats: RunStatistics | None
) -> DenseMap | DenseMapProcess:
    """The pipeline's dense map: here, or in a child process timing each sweep into ``process_stats``."""
    if process_stats is None:
        return DenseMap(config, MapPieces(config.mapping.map_voxel_m, piece_store) if in_pieces else None)
    return DenseMapProcess(
        config, in_pieces=in_pieces, on_sweep_ms=lambda ms: process_stats.add_timings({"dense_map": ms})
    )


def run_slam(scans: Iterable[Scan], config: Config | None = None) -> SlamResult:
    """Library twin of ``lidar3d run``: process every scan and return the result."""
    pipeline = SlamPipeline(config or Config())
    for scan in scans:
        pipeline.process(scan)
    pipeline.finish()
    return pipeline.result()


def _trajectory_of(estimates: Sequence[ScanEstimate], *, odometry: bool = False) -> Trajectory:
    """The estimates' poses (the scan-to-scan odometry's chained alone with ``odometry``) at their stamps."""
    stamps = np.array([e.stamp_ns for e in estimates], dtype=np.int64)
    poses = [e.T_world_odom if odometry else e.T_world_lidar for e in estimates]
    return Trajectory(stamps, np.array(poses).reshape(-1, 4, 4))
