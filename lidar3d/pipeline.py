"""The SLAM pipeline: drives the stages scan by scan and collects a :class:`SlamResult`.

It writes nothing; adapters (the CLI) iterate it, show progress and publish outputs.

Per scan:
1. deskew the sweep to its stamp with the constant-velocity prediction;
2. front end: range image, ground, clusters, edge/planar features;
3. scan-to-scan odometry (two-step LM) from the motion-model guess;
4. scan-to-submap refinement (6-DoF) from the odometry guess;
5. keyframe selection by travelled distance and rotation;
6. the sweep, deskewed again with the refined motion, is added to the dense voxel map.

Each pose is the lidar pose at the scan's header stamp (see :mod:`lidar3d.mapping.deskew`).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from lidar3d.config import Config
from lidar3d.loop.closer import LoopCloser, correct_scan_poses
from lidar3d.mapping.dense_map import add_scan_to_map
from lidar3d.mapping.deskew import deskew_features, deskew_points, twist_between
from lidar3d.mapping.keyframes import Keyframe, Submap
from lidar3d.mapping.motion_model import MotionModel
from lidar3d.features.frontend import STAGES as FRONT_END_STAGES
from lidar3d.features.frontend import run_front_end
from lidar3d.features.records import FeatureCloud, FeatureSet
from lidar3d.mapping.odometry import ScanToScanOdometry
from lidar3d.mapping.scan_to_map import register_to_submap
from lidar3d.mapping.se3 import exp_se3, invert
from lidar3d.mapping.voxel import VoxelMap, voxel_downsample
from lidar3d.records import Scan, Trajectory

__all__ = ["ScanEstimate", "SlamResult", "SlamPipeline", "PreparedScan", "prepare_scan", "run_slam", "STAGES"]

log = logging.getLogger(__name__)

STAGES = ("deskew", *FRONT_END_STAGES, "odometry", "mapping", "redeskew", "map_update")


@dataclass(frozen=True, slots=True)
class ScanEstimate:
    """What the pipeline concluded for one scan.

    Attributes:
        scan_index: position of the scan in the input stream (dropped scans keep their number).
        stamp_ns: scan stamp.
        T_world_lidar: (4,4) refined lidar pose at the stamp.
        T_world_odom: (4,4) scan-to-scan odometry pose at the stamp.
        is_keyframe: the scan became a keyframe.
        motion_model_only: features were too few, so the pose came from the motion model.
    """

    scan_index: int
    stamp_ns: int
    T_world_lidar: np.ndarray
    T_world_odom: np.ndarray
    is_keyframe: bool
    motion_model_only: bool


@dataclass(frozen=True, slots=True)
class SlamResult:
    """Everything a run produced.

    Attributes:
        trajectory: refined pose of every processed scan.
        odometry: scan-to-scan odometry pose of every processed scan.
        keyframes: keyframe poses (stamps of the keyframe scans).
        keyframe_scan_indices: (K,) scan index of each keyframe.
        map_points: (M,3) dense voxel map, world frame.
        map_intensity: (M,) mean intensity per voxel.
        timings_ms: stage name -> (N,) milliseconds per processed scan.
        counts: named counters (scans, dropped stamps, motion-model scans, degenerate scans...).
        warnings: human-readable warnings collected during the run.
        partial: the run stopped before the end of the input.
        loop_candidates: every verified loop candidate (``lidar3d.loop.records.LoopCandidate``),
            accepted or rejected, with its reason.
        pose_graph_g2o: the keyframe pose graph in g2o text ("" without loop closure).
        loop_ms_total: milliseconds spent in loop detection and the pose graph.
    """

    trajectory: Trajectory
    odometry: Trajectory
    keyframes: Trajectory
    keyframe_scan_indices: np.ndarray
    map_points: np.ndarray
    map_intensity: np.ndarray
    timings_ms: dict[str, np.ndarray]
    counts: dict[str, int]
    warnings: tuple[str, ...] = field(default=())
    partial: bool = False
    loop_ms_total: float = 0.0
    loop_candidates: tuple = field(default=())
    pose_graph_g2o: str = ""


class SlamPipeline:
    """Stateful driver: call :meth:`process` per scan, then :meth:`result`."""

    def __init__(self, config: Config) -> None:
        self.config = config
        self.sensor = config.sensor.resolved_model
        odo = config.odometry
        self.odometry = ScanToScanOdometry(
            n_rings=self.sensor.n_rings,
            max_iterations=odo.max_iterations,
            rematch_every=odo.rematch_every,
            min_rows=odo.min_rows,
            degeneracy_threshold=odo.degeneracy_threshold,
            search_radius_m=odo.search_radius_m,
            min_previous_edges=odo.min_previous_edges,
            min_previous_planes=odo.min_previous_planes,
        )
        mp = config.mapping
        self.submap = Submap(
            radius_m=mp.submap_radius_m,
            max_keyframes=mp.submap_max_keyframes,
            recent=mp.submap_recent_keyframes,
            corner_voxel_m=mp.corner_voxel_m,
            surf_voxel_m=mp.surf_voxel_m,
            cache_size=mp.submap_cache_keyframes,
            rebuild_every_keyframes=mp.submap_rebuild_every_keyframes,
            plane_neighbours=mp.plane_neighbours,
            plane_max_distance_m=mp.plane_max_distance_m,
        )
        self.dense_map = VoxelMap(mp.map_voxel_m)
        self.estimates: list[ScanEstimate] = []
        self.timings: dict[str, list[float]] = defaultdict(list)
        self.counts: dict[str, int] = defaultdict(int)
        self.warnings: list[str] = []
        self.motion = MotionModel()
        self._scan_index = -1
        self._fallback_run_start: int | None = None
        self._pending: _PendingScan | None = None
        self._last_keyframe_pose: np.ndarray | None = None
        self._correction = np.eye(4)
        self.loop = LoopCloser(config.loop) if config.loop.enabled else None
        self.loop_ms = 0.0

    # -- driver -------------------------------------------------------------------------------

    def process(self, scan: Scan | PreparedScan) -> ScanEstimate | None:
        """Estimate the pose of ``scan``; returns None when the scan is dropped (bad stamp).

        ``scan`` may come already through the front end (:func:`prepare_scan`, which depends on
        nothing but the scan, so an adapter may run it ahead in another process). The returned
        estimate is provisional: the next scan's pose may revise it (:meth:`_redeskewed`), and a
        loop closure corrects it; :meth:`result` has the final poses.
        """
        prepared = scan if isinstance(scan, PreparedScan) else None
        scan = prepared.scan if prepared is not None else scan
        self._scan_index += 1
        index = self._scan_index
        if self.estimates and scan.stamp_ns <= self.estimates[-1].stamp_ns:
            kind = "duplicate" if scan.stamp_ns == self.estimates[-1].stamp_ns else "out-of-order"
            self.counts[f"dropped_{kind.replace('-', '_')}_stamps"] += 1
            log.warning("scan %d: %s stamp %d dropped", index, kind, scan.stamp_ns)
            return None
        timer = _StageTimer(self.timings)
        prepared = prepared if prepared is not None else prepare_scan(scan, self.config)
        for stage, ms in prepared.stage_ms.items():
            self.timings[stage].append(ms)
        raw = _RawFeatures(prepared.features, prepared.ground)

        previous = self.estimates[-1] if self.estimates else None
        dt_s = (scan.stamp_ns - previous.stamp_ns) * 1e-9 if previous else 0.0
        predicted = self.motion.prediction()
        with timer("deskew"):
            features = raw.deskewed(predicted)
        with timer("odometry"):
            step = self.odometry.update(features.features, exp_se3(predicted * dt_s))
        T_world_odom = previous.T_world_odom @ step.T_prev_curr if previous else np.eye(4)

        with timer("mapping"):
            T_world_lidar, motion_model_only, degenerate_axes, yaw_held = self._refine(
                raw, features, previous, step, dt_s
            )
        self._track_fallback(index, motion_model_only)
        if previous is not None:
            self.motion.update(
                twist_between(previous.T_world_lidar, T_world_lidar, dt_s),
                well_constrained=degenerate_axes == 0,
                heading_observed=not yaw_held,
            )

        is_keyframe = self._is_keyframe(T_world_lidar, raw)
        if is_keyframe:
            self._last_keyframe_pose = T_world_lidar
        if self._pending is not None:
            # The sweep of the previous scan is deskewed for good now that the motion over it
            # (forward difference) is known; this scan waits for the next one.
            with timer("redeskew"):
                self._pending = self._redeskewed(self._pending, self.motion.twist)
            if self._pending.is_keyframe and not is_keyframe:
                self._last_keyframe_pose = self._pending.T_world_lidar
        with timer("map_update"):
            if self._pending is not None:
                self._correction = np.eye(4)
                self._publish(self._pending, self.motion.twist)
                T_world_lidar = self._correction @ T_world_lidar
                if is_keyframe:
                    self._last_keyframe_pose = T_world_lidar
            self._pending = _PendingScan(
                scan, raw, T_world_lidar, index, is_keyframe, predicted, registered=degenerate_axes == 0
            )
            if is_keyframe and not len(self.submap):
                self._publish_keyframe(self._pending, predicted)

        estimate = ScanEstimate(index, scan.stamp_ns, T_world_lidar, T_world_odom, is_keyframe, motion_model_only)
        self.estimates.append(estimate)
        self.counts["scans"] += 1
        return estimate

    def _redeskewed(self, pending: "_PendingScan", twist: np.ndarray) -> "_PendingScan":
        """``pending`` re-registered with its sweep deskewed by ``twist`` (its forward motion)
        when that differs enough from the prediction it was registered with; its estimate is
        revised with it. Scans that were not fully constrained keep their pose: their free
        directions came from the motion model, which the forward difference would only echo."""
        mp = self.config.mapping
        change = twist - pending.deskew_twist
        moved_m = max(np.linalg.norm(change[:3]), mp.redeskew_lever_m * np.linalg.norm(change[3:]))
        if not pending.registered or moved_m * self.sensor.sweep_period_s < mp.redeskew_threshold_m:
            return pending
        refined = self._register(pending.raw.deskewed(twist), pending.T_world_lidar, mp.redeskew_iterations)
        if refined.iterations == 0 or refined.degenerate_axes:
            return pending
        self.counts["redeskewed_scans"] += 1
        T_world_lidar = refined.T_target_source
        previous = self.estimates[-1]
        if previous.scan_index != pending.index:
            raise RuntimeError(f"pending scan {pending.index} is not the latest estimate ({previous.scan_index})")
        self.estimates[-1] = dataclasses.replace(previous, T_world_lidar=T_world_lidar)
        return dataclasses.replace(pending, T_world_lidar=T_world_lidar)

    def _publish(self, pending: "_PendingScan", twist: np.ndarray) -> None:
        """Add a finished scan to the dense map (and, if selected, to the keyframes)."""
        if pending.is_keyframe and (not len(self.submap) or self.submap.keyframes[-1].scan_index != pending.index):
            self._publish_keyframe(pending, twist)
        elif pending.is_keyframe:
            # The first keyframe was added at once (no motion known then); deskew it properly.
            self.submap.replace_clouds(len(self.submap) - 1, *self._keyframe_clouds(pending.raw, twist))
        add_scan_to_map(self.dense_map, pending.scan, pending.T_world_lidar, twist, self.config)

    def _keyframe_clouds(self, raw: "_RawFeatures", twist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A keyframe's clouds, deskewed with ``twist``; kept for the whole run, so stored in
        float32 (sub-millimetre within the lidar's range)."""
        corner, surf = self._mapping_clouds(raw.deskewed(twist))
        return corner.astype(np.float32), surf.astype(np.float32)

    def _publish_keyframe(self, pending: "_PendingScan", twist: np.ndarray) -> None:
        corner, surf = self._keyframe_clouds(pending.raw, twist)
        self.submap.add(
            Keyframe(len(self.submap), pending.index, pending.scan.stamp_ns, pending.T_world_lidar, corner, surf)
        )
        self._close_loops()

    def _close_loops(self) -> None:
        """Look for a loop at the newest keyframe; on success correct every pose so far."""
        if self.loop is None:
            return
        t0 = time.perf_counter()
        update = self.loop.on_keyframe(self.submap.keyframes, self.submap.poses)
        self.loop_ms += (time.perf_counter() - t0) * 1e3
        if update is None:
            return
        self.counts["loop_closures"] += len(update.closures)
        self.submap.set_poses(update.poses)
        keyframe_stamps = np.array([kf.stamp_ns for kf in self.submap.keyframes], dtype=np.int64)
        stamps = np.array([e.stamp_ns for e in self.estimates], dtype=np.int64)
        poses = np.array([e.T_world_lidar for e in self.estimates]).reshape(-1, 4, 4)
        corrected = correct_scan_poses(stamps, poses, keyframe_stamps, update.previous_poses, update.poses)
        self.estimates = [dataclasses.replace(e, T_world_lidar=T) for e, T in zip(self.estimates, corrected)]
        # Poses not yet in the estimates (the scan being processed) follow the newest keyframe.
        self._correction = update.correction @ self._correction
        self._last_keyframe_pose = update.poses[-1]

    def _register(
        self,
        features: "_RawFeatures",
        T_world_lidar: np.ndarray,
        iterations: int,
        T_prior: np.ndarray | None = None,
        hold_yaw: bool = False,
    ):
        """Scan-to-submap registration of deskewed ``features`` from ``T_world_lidar`` (see
        :func:`register_to_submap` for ``T_prior`` and ``hold_yaw``)."""
        mp = self.config.mapping
        corner, surf = self._mapping_clouds(features)
        surf = voxel_downsample(surf, mp.scan_surf_voxel_m)
        target = self.submap.target(T_world_lidar[:3, 3])
        return register_to_submap(target, corner, surf, T_world_lidar, mp, iterations, T_prior, hold_yaw)

    def _mapping_clouds(self, features: "_RawFeatures") -> tuple[np.ndarray, np.ndarray]:
        """Corner (less-sharp) and surface (less-flat, outliers, ground) clouds, voxel-downsampled."""
        mp = self.config.mapping
        f = features.features
        corner = voxel_downsample(f.less_sharp.points, mp.corner_voxel_m)
        surf = voxel_downsample(
            np.concatenate([f.less_flat.points, f.outliers.points, features.ground.points]), mp.surf_voxel_m
        )
        return corner, surf

    def _refine(
        self,
        raw: "_RawFeatures",
        features: "_RawFeatures",
        previous: ScanEstimate | None,
        step,
        dt_s: float,
    ) -> tuple[np.ndarray, bool, int, bool]:
        """Scan-to-submap refinement; returns (T_world_lidar, motion_model_only, degenerate
        directions of the registration (6 when it did not run), yaw held at the prediction).

        Registration starts from the odometry pose; along directions the submap leaves
        degenerate it takes the motion model's vehicle prediction instead (see
        :mod:`lidar3d.mapping.motion_model`). ``features`` are deskewed with the predicted
        motion; :meth:`_redeskewed` revisits the pose once the motion over the sweep is known.
        """
        if previous is None:
            return np.eye(4), False, 6, False
        T_world_lidar = previous.T_world_lidar @ step.T_prev_curr
        if not len(self.submap):
            return T_world_lidar, step.used_motion_model, 6, False
        mp = self.config.mapping
        straight = abs(np.degrees(self.motion.twist[5])) < mp.straight_max_yaw_rate_deg_s
        # LOAM keeps the odometry guess along degenerate directions. On a straight the vehicle's
        # constant-velocity prediction is the better value there: the odometry's edges are then
        # mostly far structure (90 m away on open land), whose azimuth-quantised edge points stay
        # put from sweep to sweep and pull the step short (2-4 cm per scan on `long`). In a turn
        # the prediction lags, so the odometry guess is kept unless its edge step was blind too.
        T_prior = None
        if self.motion.established and (straight or not step.edge_observed):
            T_prior = previous.T_world_lidar @ exp_se3(self.motion.vehicle_twist() * dt_s)
        refined = self._register(features, T_world_lidar, mp.max_iterations, T_prior=T_prior, hold_yaw=straight)
        if refined.iterations == 0:
            return T_world_lidar, step.used_motion_model, 6, False
        if refined.degenerate_axes:
            self.counts["degenerate_scans"] += 1
        yaw_held = T_prior is not None and straight and 0 < mp.hold_yaw_min_degenerate <= refined.degenerate_axes
        return refined.T_target_source, False, refined.degenerate_axes, yaw_held

    def _is_keyframe(self, T_world_lidar: np.ndarray, raw: "_RawFeatures") -> bool:
        """A scan with features becomes a keyframe after enough motion since the last one."""
        mp = self.config.mapping
        n_surface = len(raw.features.less_flat) + len(raw.features.outliers) + len(raw.ground)
        if n_surface < mp.min_rows:
            return False
        if self._last_keyframe_pose is None:
            return True
        delta = invert(self._last_keyframe_pose) @ T_world_lidar
        moved = np.linalg.norm(delta[:3, 3])
        angle = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
        return moved >= mp.keyframe_distance_m or angle >= mp.keyframe_angle_deg

    def _track_fallback(self, index: int, motion_model_only: bool) -> None:
        if motion_model_only:
            self.counts["motion_model_scans"] += 1
            if self._fallback_run_start is None:
                self._fallback_run_start = index
        elif self._fallback_run_start is not None:
            self._close_fallback_run(index)

    @staticmethod
    def _fallback_message(start: int, end_index: int) -> str:
        return f"scans {start}-{end_index - 1}: too few features, pose from the motion model"

    def _close_fallback_run(self, end_index: int) -> None:
        message = self._fallback_message(self._fallback_run_start, end_index)
        self._fallback_run_start = None
        self.warnings.append(message)
        log.warning(message)

    def finish(self) -> None:
        """End of input: publish the last scan to the map and close an open fallback stretch."""
        if self._fallback_run_start is not None:
            self._close_fallback_run(self._scan_index + 1)
        if self._pending is not None:
            self._publish(self._pending, self.motion.twist)
            self._pending = None

    def result(self, partial: bool = False) -> SlamResult:
        """A snapshot of the result so far; changes nothing (``partial`` marks an unfinished run).

        Before :meth:`finish`, the last scan is not yet in the map (its deskewing waits for the
        next scan) and an open fallback stretch is reported up to the last scan.
        """
        warnings = list(self.warnings)
        if self._fallback_run_start is not None:
            warnings.append(self._fallback_message(self._fallback_run_start, self._scan_index + 1))
        stamps = np.array([e.stamp_ns for e in self.estimates], dtype=np.int64)
        poses = np.array([e.T_world_lidar for e in self.estimates]).reshape(-1, 4, 4)
        odom = np.array([e.T_world_odom for e in self.estimates]).reshape(-1, 4, 4)
        kf_index = np.array([kf.scan_index for kf in self.submap.keyframes], dtype=np.int64)
        kf_stamps = np.array([kf.stamp_ns for kf in self.submap.keyframes], dtype=np.int64)
        map_points, map_intensity = self.dense_map.points_and_intensity()
        return SlamResult(
            trajectory=Trajectory(stamps, poses),
            odometry=Trajectory(stamps, odom),
            keyframes=Trajectory(kf_stamps, self.submap.poses.reshape(-1, 4, 4)),
            keyframe_scan_indices=kf_index,
            map_points=map_points,
            map_intensity=map_intensity,
            timings_ms={k: np.asarray(v) for k, v in self.timings.items()},
            loop_ms_total=self.loop_ms,
            counts=dict(self.counts),
            warnings=tuple(warnings),
            partial=partial,
            loop_candidates=tuple(self.loop.candidates) if self.loop else (),
            pose_graph_g2o=self.loop.graph.g2o_text(self.submap.poses) if self.loop and len(self.submap) else "",
        )


def _ground_cloud(segmentation) -> FeatureCloud:
    """Every ground cell of the range image as a cloud (the segmented cloud keeps only every
    fifth ground column; mapping wants the ground dense, since it fixes z, roll and pitch)."""
    idx = segmentation.image.point_index[segmentation.ground_mask]
    idx = idx[idx >= 0]
    scan = segmentation.scan
    return FeatureCloud(scan.points[idx], scan.ring[idx], scan.time_offset_s[idx])


@dataclass(frozen=True, slots=True)
class PreparedScan:
    """A scan with its front-end output: what :meth:`SlamPipeline.process` needs of the front end.

    Attributes:
        scan: the raw sweep.
        features: its LeGO-LOAM feature set (lidar frame, not deskewed).
        ground: every ground cell of its range image as a cloud.
        stage_ms: front-end milliseconds per sub-stage.
    """

    scan: Scan
    features: FeatureSet
    ground: FeatureCloud
    stage_ms: dict[str, float]


def prepare_scan(scan: Scan, config: Config) -> PreparedScan:
    """Run the front end on ``scan`` (a pure function of the scan and the configuration)."""
    front = run_front_end(scan, config)
    return PreparedScan(scan, front.features, _ground_cloud(front.segmentation), front.stage_ms)


@dataclass(frozen=True, slots=True)
class _RawFeatures:
    """A scan's feature set plus its dense ground cloud, as fired (not deskewed)."""

    features: FeatureSet
    ground: FeatureCloud

    def deskewed(self, twist: np.ndarray) -> "_RawFeatures":
        ground = FeatureCloud(
            deskew_points(self.ground.points, self.ground.time_offset_s, twist), self.ground.ring, self.ground.time_offset_s
        )
        return _RawFeatures(deskew_features(self.features, twist), ground)


@dataclass(frozen=True, slots=True)
class _PendingScan:
    """A scan whose pose is known but whose deskewing waits for the next scan's pose."""

    scan: Scan
    raw: _RawFeatures
    T_world_lidar: np.ndarray
    index: int
    is_keyframe: bool
    deskew_twist: np.ndarray  # the motion its features were registered deskewed with
    registered: bool  # the pose came from a registration with no degenerate direction


class _StageTimer:
    """Context-manager factory that appends elapsed milliseconds per stage."""

    def __init__(self, sink: dict[str, list[float]]) -> None:
        self._sink = sink

    def __call__(self, stage: str) -> "_StageTimer._Span":
        return _StageTimer._Span(self._sink, stage)

    class _Span:
        __slots__ = ("_sink", "_stage", "_t0")

        def __init__(self, sink: dict[str, list[float]], stage: str) -> None:
            self._sink = sink
            self._stage = stage

        def __enter__(self) -> None:
            self._t0 = time.perf_counter()

        def __exit__(self, *exc: object) -> None:
            self._sink[self._stage].append((time.perf_counter() - self._t0) * 1e3)


def run_slam(scans: Iterable[Scan], config: Config | None = None) -> SlamResult:
    """Library twin of ``lidar3d run``: process every scan and return the result."""
    pipeline = SlamPipeline(config or Config())
    for scan in scans:
        pipeline.process(scan)
    pipeline.finish()
    return pipeline.result()
