"""``lidar3d run``: SLAM over one recording, its outputs published as one consistent set.

Library twin of the CLI: :func:`run_bag`. Outputs in ``out_dir``:

* ``trajectory_tum.txt`` / ``trajectory_kitti.txt`` (+ ``.times.txt``): refined pose of every scan;
* ``odometry_tum.txt``: scan-to-scan odometry; ``keyframes_tum.txt``: keyframe poses;
* ``map.pcd``: dense voxel map (deskewed scans placed with the final poses), with intensity;
* ``health.csv``: the health of every scan (ok / degraded / lost, with its measures;
  :mod:`lidar3d.mapping.health`), counted in the summary's ``health``;
* ``loops.csv``, ``pose_graph.g2o``, ``trajectory_loops.png``: the loop outputs (loop closure on);
* ``summary.json``: counts, length, runtime, per-stage timing, warnings, ``partial`` flag and the
  manifest of every other file (:class:`lidar3d.summary.RunSummary`; read it back with
  :func:`lidar3d.summary.read_summary`, or :func:`lidar3d.io.run_folder.read_run_folder` to check
  the folder too);
* ``config.toml``: the resolved configuration; ``eval/``: the GNSS report when a SPAN log is given.

Every pose is the lidar pose at the scan's header stamp, whatever instant it marks (the sweep start
for raw packets and the simulator, the sweep end for the stock ROS1 velodyne driver's clouds).
While running, trajectories and the summary are checkpointed every ``checkpoint_every_s`` and the
map every ``map_checkpoint_every_s``; an interruption or crash publishes everything finished so
far, marked ``"partial": true``. Each publication replaces the whole set in the folder
(:func:`lidar3d.io.run_folder.publish_set`): a kill at any moment leaves the previous set or the new
one, and the summary always describes exactly the files beside it.
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import logging
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lidar3d import __version__, stop_signals
from lidar3d.config import Config, config_to_toml
from lidar3d.errors import ConfigError, Lidar3dError, OutputError
from lidar3d.io.atomic import write_bytes_atomic, write_text_atomic
from lidar3d.io.health_csv import write_health_csv
from lidar3d.io.keyframe_spill import SpilledKeyframeClouds
from lidar3d.io.packet_source import input_config
from lidar3d.io.pcd import write_pcd
from lidar3d.io.piece_spill import SpilledPieceStore
from lidar3d.io.run_folder import existing_run_outputs, publish_set
from lidar3d.io.scan_source import open_scan_source
from lidar3d.io.trajectory_io import write_kitti, write_tum
from lidar3d.mapping.health import ScanHealth
from lidar3d.pipeline import SlamPipeline, SlamResult, SpillStores
from lidar3d.prefetch import open_prepared_scans
from lidar3d.records import Trajectory
from lidar3d.summary import EvaluationSummary, InputStatistics, RunCounts, RunSummary, StageMedians

if TYPE_CHECKING:
    from lidar3d.georef.georeference import Georeference, GnssFusionRecord
    from lidar3d.gnss.novatel import SpanLog
    from lidar3d.gnss.reference import InsReference

__all__ = ["RunOutcome", "run_bag"]

log = logging.getLogger(__name__)

TOP_VIEW_NAME = "trajectory_loops.png"


@dataclass(frozen=True, slots=True)
class RunOutcome:
    """What :func:`run_bag` produced: the result, the summary written, and the output folder."""

    result: SlamResult
    summary: RunSummary
    out_dir: Path


def _summary(
    result: SlamResult,
    *,
    inputs: Sequence[str],
    topic: str,
    runtime_s: float,
    read_ms: list[float],
    input_stats: InputStatistics | None = None,
) -> RunSummary:
    n = len(result.trajectory)
    stamps_ns = result.trajectory.stamps_ns
    stages = {"read": float(np.median(read_ms)) if read_ms else 0.0}
    stages.update({k: float(np.median(v)) for k, v in result.timings_ms.items() if len(v)})
    return RunSummary(
        lidar3d_version=__version__,
        inputs=tuple(inputs),
        topic=topic,
        partial=result.partial,
        scans=n,
        keyframes=len(result.keyframes),
        length_m=float(round(result.trajectory.path_length_m, 3)),
        duration_s=float(round((stamps_ns[-1] - stamps_ns[0]) * 1e-9, 3)) if n else 0.0,
        runtime_s=round(runtime_s, 3),
        scans_per_s=round(n / runtime_s, 2) if runtime_s > 0 else 0.0,
        stage_ms_median=StageMedians(**{k: round(v, 3) for k, v in stages.items()}),
        map_points=int(len(result.map_points)),
        dynamic_points=int(len(result.dynamic_points)) if result.removes_dynamic else None,
        loop_closures=int(result.counts.get("loop_closures", 0)),
        loop_candidates=len(result.loop_candidates),
        loop_ms_total=round(result.loop_ms_total, 1),
        counts=RunCounts(**result.counts),
        warnings=(*result.warnings, *_input_warnings(input_stats)),
        pose_stamp="header stamp of each scan, whatever instant it marks (sweep start for raw packets)",
        health=result.health_summary,
        input_stats=input_stats,
        map_rebuild_s=result.map_rebuild_s,
    )


def _input_warnings(input_stats: InputStatistics | None) -> tuple[str, ...]:
    """The warnings about damaged input points (when the input sanity stage dropped any) and about
    point times derived from the azimuth (when some scans had no usable time field)."""
    if input_stats is None:
        return ()
    return tuple(w for w in (input_stats.damage_warning(), input_stats.timing_warning()) if w is not None)


class _RunPublisher:
    """Publishes the outputs of one run into its folder, each time as a whole set.

    The map is written less often than the trajectories; between its publications the set keeps
    the last ``map.pcd`` (and ``dynamic.pcd``), and the summary's ``map_points`` (``dynamic_points``)
    counts the points of that file. The loop closures' top view (``trajectory_loops.png``, a
    matplotlib drawing of 0.1-0.3 s, and about a second more for the first, which imports
    matplotlib) is drawn with the map too, and kept between.
    """

    def __init__(self, out_dir: Path, config: Config) -> None:
        self.out_dir = out_dir
        self.config = config
        self.summary: RunSummary | None = None  # the summary of the set in the folder
        self._drawn: tuple[np.ndarray, bytes] | None = None  # (positions it shows, PNG) of draw_top_view

    def draw_top_view_meanwhile(self, result: SlamResult) -> threading.Thread:
        """Start drawing the loop closures' top view of ``result`` in a thread of its own (nothing
        without a pose graph) and return it; the next publication whose trajectory is the same
        uses the drawing instead of drawing again. The run starts it once the poses are final and
        then waits for the map's process (its last window of sweeps, the map placed again after
        loop closures): the drawing, matplotlib's import included, overlaps with that wait. A
        drawing that fails leaves nothing drawn: the publication draws again, and fails there."""

        def draw() -> None:
            if result.pose_graph_g2o:
                with contextlib.suppress(Exception):
                    self._drawn = (result.trajectory.positions_m.copy(), _top_view_png(result))

        thread = threading.Thread(target=draw, name="lidar3d-top-view", daemon=True)
        thread.start()
        return thread

    def _top_view_png(self, result: SlamResult) -> bytes:
        """The top view of ``result``: the one drawn ahead when it shows the same positions."""
        if self._drawn is not None and np.array_equal(self._drawn[0], result.trajectory.positions_m):
            return self._drawn[1]
        return _top_view_png(result)

    def publish(
        self, result: SlamResult, summary: RunSummary, *, with_map: bool = True, lidar_only: Trajectory | None = None
    ) -> RunSummary:
        """Publish trajectories, the loop outputs, (optionally) the map, and the summary as one set;
        ``lidar_only``: the trajectory before the GNSS factors (``trajectory_lidar_only_tum.txt``)."""
        n, map_points = len(result.trajectory), len(result.map_points)
        rows = dict.fromkeys(
            (
                "trajectory_tum.txt",
                "trajectory_kitti.txt",
                "trajectory_kitti.times.txt",
                "odometry_tum.txt",
                "health.csv",
            ),
            n,
        )
        rows.update({"keyframes_tum.txt": len(result.keyframes), "loops.csv": len(result.loop_candidates)})
        if lidar_only is not None:
            rows["trajectory_lidar_only_tum.txt"] = len(lidar_only)
        keep = [] if self.summary is None else ["config.toml"]
        if with_map:
            rows["map.pcd"] = map_points
            if result.removes_dynamic:
                rows["dynamic.pcd"] = len(result.dynamic_points)
        else:
            previous_map = self.summary.output("map.pcd") if self.summary is not None else None
            keep += ["map.pcd"] if previous_map is not None else []
            map_rows = previous_map.rows if previous_map is not None else None
            summary = dataclasses.replace(summary, map_points=map_rows or 0)
            previous_dynamic = self.summary.output("dynamic.pcd") if self.summary is not None else None
            keep += ["dynamic.pcd"] if previous_dynamic is not None else []
            dynamic_rows = previous_dynamic.rows if previous_dynamic is not None else None
            summary = dataclasses.replace(summary, dynamic_points=dynamic_rows)
            previous_view = self.summary.output(TOP_VIEW_NAME) if self.summary is not None else None
            keep += [TOP_VIEW_NAME] if previous_view is not None and result.pose_graph_g2o else []

        def write(staging: Path) -> None:
            if self.summary is None:
                write_text_atomic(staging / "config.toml", config_to_toml(self.config))
            write_tum(staging / "trajectory_tum.txt", result.trajectory)
            write_kitti(staging / "trajectory_kitti.txt", result.trajectory)
            write_tum(staging / "odometry_tum.txt", result.odometry)
            write_tum(staging / "keyframes_tum.txt", result.keyframes)
            write_health_csv(staging / "health.csv", result.scan_indices, result.health)
            if lidar_only is not None:
                write_tum(staging / "trajectory_lidar_only_tum.txt", lidar_only)
            if with_map:
                intensity = result.map_intensity.astype(np.float32)
                write_pcd(staging / "map.pcd", result.map_points, intensity=intensity)
                if result.removes_dynamic:
                    dynamic_intensity = result.dynamic_intensity.astype(np.float32)
                    write_pcd(staging / "dynamic.pcd", result.dynamic_points, intensity=dynamic_intensity)
            if result.pose_graph_g2o:
                _write_loop_outputs(staging, result, self._top_view_png(result) if with_map else None)

        self.summary = publish_set(self.out_dir, summary, write, rows=rows, keep=keep)
        return self.summary

    def publish_evaluation(self, evaluation, georef: Georeference, summary: RunSummary) -> RunSummary:
        """Add the evaluation report (``eval/``) and ``georef.json`` to the published set, with ``summary``."""
        from lidar3d.export.span_report import write_span_report

        assert self.summary is not None, "the run's outputs are published before its evaluation"
        keep = [e.path for e in self.summary.outputs if not e.path.startswith("eval/") and e.path != "georef.json"]

        def write(staging: Path) -> None:
            write_text_atomic(staging / "georef.json", georef.to_json())
            write_span_report(evaluation, staging / "eval")

        self.summary = publish_set(self.out_dir, summary, write, keep=keep)
        return self.summary


def _write_loop_outputs(out_dir: Path, result: SlamResult, top_view_png: bytes | None) -> None:
    """``loops.csv`` (every candidate), ``pose_graph.g2o`` and the top view's PNG bytes when given."""
    from lidar3d.export.loop_report import write_loops_csv, write_pose_graph_g2o

    write_loops_csv(out_dir / "loops.csv", result.loop_candidates)
    write_pose_graph_g2o(out_dir / "pose_graph.g2o", result.pose_graph_g2o)
    if top_view_png is not None:
        write_bytes_atomic(out_dir / TOP_VIEW_NAME, top_view_png)


def _top_view_png(result: SlamResult) -> bytes:
    """PNG bytes of the trajectory's top view with its accepted loop closures."""
    from lidar3d.export.loop_report import top_view_png

    return top_view_png(
        result.trajectory.positions_m,
        result.keyframes.positions_m,
        [c for c in result.loop_candidates if c.accepted],
    )


def run_bag(
    paths: str | Path | Sequence[str | Path],
    out_dir: str | Path,
    config: Config | None = None,
    *,
    start: int = 0,
    max_scans: int | None = None,
    span_log: str | Path | None = None,
    extrinsics: str | Path | None = None,
    on_scan: Callable[[int, int | None], None] | None = None,
    on_health: Callable[[ScanHealth], None] | None = None,
    checkpoint_every_s: float = 10.0,
    map_checkpoint_every_s: float = 60.0,
    prefetch: bool = True,
    overwrite: bool = False,
    gnss_factors: bool = False,
) -> RunOutcome:
    """Run SLAM over the bag(s) ``paths`` and write every output into ``out_dir``.

    Args:
        start: skip this many scans first; ``max_scans``: stop after this many.
        span_log: a NovAtel SPAN log to evaluate the trajectory against (report in ``eval/``).
        extrinsics: lidar-to-IMU extrinsic file for that evaluation.
        on_scan: called as ``on_scan(done, total)`` after each scan (progress display).
        on_health: called with the health of each scan that got a pose, before ``on_scan``.
        prefetch: read the bag and run the front end in a second process, a few scans ahead, and
            build the dense map in a third (:mod:`lidar3d.map_process`): uses the other cores;
            turn off when several runs share the cores, as in a batch. The outputs are the same.
        overwrite: replace the outputs of an earlier run in ``out_dir`` (they stay until this run
            publishes its first set, which removes every file it does not hold).
        gnss_factors: fuse the SPAN log's good epochs into the keyframe graph after the lidar run
            (:mod:`lidar3d.georef.gnss_factors`); the lidar-only trajectory is kept as
            ``trajectory_lidar_only_tum.txt``. Needs ``span_log``.

    With ``span_log``, ``georef.json`` holds the georeference (:mod:`lidar3d.georef.georeference`).

    Raises:
        OutputError: ``out_dir`` already holds the outputs of a run and ``overwrite`` is false.
    """
    config = config or Config()
    out = Path(out_dir)
    paths = [paths] if isinstance(paths, (str, Path)) else list(paths)
    inputs = [str(p) for p in paths]
    # Check the evaluation inputs and the output folder now, not after a run of hours.
    T_imu_lidar = _check_evaluation_inputs(span_log, extrinsics)
    if gnss_factors and span_log is None:
        raise ConfigError("--gnss-factors needs --span (the log to fuse)")
    _check_output_folder(out, overwrite)
    config = input_config(paths, config)  # raw packets: the sensor model and rate they show

    # With loop closure the map is also kept in pieces (to move with the keyframes), spilled to disk
    # (by the map's own process when it has one).
    piece_store = SpilledPieceStore() if config.loop.enabled and not prefetch else None
    # The clouds of keyframes the tracking has left behind wait on disk too (read back on a revisit).
    keyframe_clouds = SpilledKeyframeClouds()
    pipeline = SlamPipeline(config, SpillStores(piece_store, keyframe_clouds), map_in_process=prefetch)
    publisher = _RunPublisher(out, config)
    read_ms: list[float] = []
    t_start = time.perf_counter()
    last_checkpoint = last_map_checkpoint = t_start
    topic = ""
    input_stats: InputStatistics | None = None
    finished = False
    drawing: threading.Thread | None = None
    try:
        with open_prepared_scans(paths, config, start=start, max_scans=max_scans, prefetch=prefetch) as stream:
            # Only a bag that opens gets an output folder (created here, with a clear error).
            _create_folder(out)
            topic = stream.topic
            total = stream.total
            done = 0
            for prepared, read_scan_ms in stream:
                read_ms.append(read_scan_ms)
                with stop_signals.deferred():  # a stop lands between scans: the pipeline stays whole
                    estimate = pipeline.process(prepared)
                if on_health is not None and estimate is not None:
                    on_health(estimate.health)
                done += 1
                if on_scan is not None:
                    on_scan(done, total)
                now = time.perf_counter()
                if now - last_checkpoint >= checkpoint_every_s:
                    with_map = now - last_map_checkpoint >= map_checkpoint_every_s
                    with stop_signals.deferred():
                        result = pipeline.result(partial=True, with_map=with_map)
                        summary = _summary(result, inputs=inputs, topic=topic, runtime_s=now - t_start, read_ms=read_ms)
                        publisher.publish(result, summary, with_map=with_map)
                    del result, summary  # a map checkpoint's clouds (tens of MB) are not kept until the next
                    last_checkpoint = now
                    if with_map:
                        last_map_checkpoint = now
        stats = stream.stats
        input_stats = InputStatistics(
            points_kept=stats.n_points_kept,
            nonfinite_dropped=stats.n_nonfinite,
            below_min_range_dropped=stats.n_below_min_range,
            messages_lost=stats.n_lost_messages,
            absurd_coordinates_dropped=stats.n_absurd_coordinates,
            outlier_times_dropped=stats.n_outlier_times,
            scans_timed_from_azimuth=stats.n_scans_times_from_azimuth,
        )
        for warning in _input_warnings(input_stats):
            log.warning("%s: %s", ", ".join(inputs), warning)
        if not pipeline.estimates:
            raise Lidar3dError(f"{', '.join(inputs)}: no scan was processed")
        pipeline.finish_tracking()  # the poses are final
        drawing = publisher.draw_top_view_meanwhile(pipeline.result(with_map=False))
        pipeline.finish()  # after loop closures, the map is placed again with the corrected keyframes
        finished = True
    finally:
        with stop_signals.deferred():  # a Ctrl-C or SIGTERM now waits until what is finished is published
            map_failed: Lidar3dError | None = None
            if not finished:
                try:
                    pipeline.finish()  # the last scan enters the map of the partial outputs
                except Lidar3dError as err:  # the map's process failed: the poses are published without it
                    map_failed = err
            if drawing is not None:
                drawing.join()
            result = pipeline.result(partial=not finished, with_map=map_failed is None)
            runtime = time.perf_counter() - t_start
            if pipeline.estimates:
                summary = _summary(
                    result,
                    inputs=inputs,
                    topic=topic,
                    runtime_s=runtime,
                    read_ms=read_ms,
                    input_stats=input_stats,
                )
                summary = publisher.publish(result, summary, with_map=map_failed is None)
                if not finished:
                    log.warning(
                        "run stopped after %d scans; partial outputs written to %s", len(result.trajectory), out
                    )
            if piece_store is not None:
                piece_store.close()
            keyframe_clouds.close()
            if map_failed is not None:
                raise map_failed

    if span_log is not None:
        span = _SpanInputs.read(span_log, T_imu_lidar, config)
        fusion = None
        if gnss_factors and finished:
            lidar_only = result.trajectory
            result, fusion = _fuse_gnss(result, span, config, paths, start, done)
            summary = _summary(
                result,
                inputs=inputs,
                topic=topic,
                runtime_s=time.perf_counter() - t_start,
                read_ms=read_ms,
                input_stats=input_stats,
            )
            if fusion.rejected_consistency:
                line = (
                    f"GNSS factors: {fusion.rejected_consistency} epoch(s) rejected as inconsistent with the odometry"
                )
                summary = dataclasses.replace(summary, warnings=(*summary.warnings, line))
            summary = publisher.publish(result, summary, lidar_only=lidar_only)
        evaluation, record = _evaluate(result, span, config, out, fusion)
        georef = dataclasses.replace(span.fit(result.trajectory, config), fusion=fusion)
        summary = dataclasses.replace(summary, evaluation=EvaluationSummary.from_dict(record))
        summary = publisher.publish_evaluation(evaluation, georef, summary)
        log.info(
            "georeference: %s fit on %d epochs, residual %.3f m",
            georef.method,
            georef.epochs_used,
            georef.residual.rmse_m,
        )
        log.info("evaluated against %s: report in %s", span_log, out / "eval")
    return RunOutcome(result, summary, out)


def _check_output_folder(out: Path, overwrite: bool) -> None:
    """Refuse a folder holding an earlier run's outputs, unless they are to be replaced."""
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    existing = existing_run_outputs(out)
    if existing and not overwrite:
        raise OutputError(
            f"{out}: already holds the outputs of a run ({existing[0]}); pass --overwrite to replace them"
        )


def _create_folder(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"{out}: cannot create output folder: {err.strerror or err}") from err


def _check_evaluation_inputs(span_log, extrinsics) -> np.ndarray | None:
    """Fail fast on a missing SPAN log or a bad extrinsic file; returns ``T_imu_lidar`` (or None)."""
    from lidar3d.errors import GnssError
    from lidar3d.gnss.extrinsic import read_extrinsic

    if extrinsics is not None and span_log is None:
        raise GnssError(f"{extrinsics}: an extrinsic file is only used with a SPAN log to evaluate against")
    if span_log is not None and not Path(span_log).is_file():
        raise GnssError(f"{span_log}: GNSS log not found")
    return read_extrinsic(extrinsics) if extrinsics is not None else None


@dataclass(frozen=True, slots=True)
class _SpanInputs:
    """The SPAN log of a run, read once: the decoded log, its INS reference in ENU, the extrinsic."""

    path: Path
    log: SpanLog
    reference: InsReference
    T_imu_lidar: np.ndarray
    sha256: str

    @classmethod
    def read(cls, span_log, T_imu_lidar: np.ndarray | None, config: Config) -> _SpanInputs:
        from lidar3d.georef.georeference import file_sha256
        from lidar3d.gnss.reader import read_span_log
        from lidar3d.gnss.reference import origin_from_config, span_reference

        log_record = read_span_log(span_log)
        reference = span_reference(log_record, config.gnss, origin_from_config(config.gnss.origin))
        T = np.eye(4) if T_imu_lidar is None else np.asarray(T_imu_lidar, dtype=np.float64)
        return cls(Path(span_log), log_record, reference, T, file_sha256(span_log))

    def fit(self, trajectory: Trajectory, config: Config) -> Georeference:
        """The georeference of ``trajectory`` (:func:`lidar3d.georef.georeference.fit_georeference`)."""
        from lidar3d.georef.georeference import fit_georeference

        return fit_georeference(
            trajectory,
            self.reference,
            T_imu_lidar=self.T_imu_lidar,
            method=config.georef.method,
            max_gap_s=config.gnss.max_association_gap_s,
            max_fit_residual_m=config.georef.max_fit_residual_m,
            span_source=str(self.path),
            span_sha256=self.sha256,
        )


def _fuse_gnss(
    result: SlamResult, span: _SpanInputs, config: Config, paths, start: int, done: int
) -> tuple[SlamResult, GnssFusionRecord]:
    """The result with the GNSS factors fused and the map placed again, and the fusion's record."""
    from lidar3d.georef.georeference import GnssFusionRecord
    from lidar3d.georef.gnss_factors import fuse_gnss
    from lidar3d.mapping.dense_map import build_dense_map

    initial = span.fit(result.trajectory, config)
    fusion = fuse_gnss(
        result.trajectory,
        result.keyframes,
        span.reference,
        span.T_imu_lidar,
        initial.T_enu_world,
        config.georef,
    )
    with open_scan_source(paths, config) as source:
        voxel_map = build_dense_map(itertools.islice(source, start, start + done), fusion.trajectory, config)
    map_points, map_intensity = voxel_map.static.points_and_intensity()
    dynamic_points, dynamic_intensity = voxel_map.dynamic.points_and_intensity()
    fused = dataclasses.replace(
        result,
        trajectory=fusion.trajectory,
        keyframes=fusion.keyframes,
        map_points=map_points,
        map_intensity=map_intensity,
        dynamic_points=dynamic_points,
        dynamic_intensity=dynamic_intensity,
    )
    s = fusion.selection
    record = GnssFusionRecord(
        span_source=str(span.path),
        span_sha256=span.sha256,
        fused_stamps_ns=s.stamps_ns,
        candidates=s.candidates,
        rejected_quality=s.rejected_quality,
        rejected_consistency=s.rejected_consistency,
        rejected_hold_out=s.rejected_hold_out,
        hold_out_period_s=config.georef.hold_out_period_s,
    )
    return fused, record


def _evaluate(result: SlamResult, span: _SpanInputs, config: Config, out: Path, fusion: GnssFusionRecord | None):
    """The evaluation against the SPAN log and its summary record (as a dict); writes nothing.

    A trajectory fused with the log is scored on the held-out periods only when there are any
    (``georef.hold_out_period_s``), and the report says it was fused.
    """
    from lidar3d.export.span_report import format_span_table, span_report_dict
    from lidar3d.metrics import evaluate_against_span
    from lidar3d.metrics.span_eval import fusion_disclosure

    estimate = result.trajectory
    disclosure = None
    if fusion is not None:
        disclosure, estimate = fusion_disclosure(estimate, len(fusion.fused_stamps_ns), fusion.hold_out_period_s)
    evaluation = evaluate_against_span(
        estimate,
        span.log,
        T_imu_lidar=span.T_imu_lidar,
        config=config.gnss,
        trajectory_source=str(out / "trajectory_tum.txt"),
        reference=span.reference,
    )
    evaluation = dataclasses.replace(evaluation, fusion=disclosure)
    report = span_report_dict(evaluation)
    return evaluation, {"report": str(out / "eval"), "table": format_span_table(evaluation), "ate": report.get("ate")}
