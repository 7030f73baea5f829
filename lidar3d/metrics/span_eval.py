"""Evaluate a lidar trajectory against NovAtel SPAN ground truth: the computation behind ``lidar3d eval``.

``evaluate_against_span`` takes a trajectory in memory (as ``lidar3d run --span`` has it);
``evaluate_span_files`` reads the trajectory file first (TUM, or KITTI with ``.times.txt``). Both
read the log, build the ENU reference (:mod:`lidar3d.gnss.reference`), evaluate
(:mod:`lidar3d.metrics.evaluation`) and return a :class:`SpanEvaluation`; they write nothing. The
report files are written by :func:`lidar3d.export.span_report.write_span_report`.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar3d.config import GnssConfig
from lidar3d.gnss.enu import GeodeticOrigin
from lidar3d.gnss.novatel import SpanLog
from lidar3d.gnss.reader import read_span_log
from lidar3d.gnss.reference import InsReference, origin_from_config, span_reference
from lidar3d.io.trajectory_io import read_trajectory
from lidar3d.metrics.alignment import AlignmentMode
from lidar3d.metrics.evaluation import Evaluation, evaluate_trajectory
from lidar3d.records import Trajectory

__all__ = ["FusionDisclosure", "SpanEvaluation", "evaluate_against_span", "evaluate_span_files", "fusion_disclosure"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class FusionDisclosure:
    """An evaluation of a trajectory that was fused with the log it is scored against.

    Attributes:
        fused_epochs: GNSS epochs the run fused (``georef.json`` ``gnss_factors``).
        hold_out_period_s: the run fused only even periods of this length (0: every period).
        held_out_only: the score uses only poses in the held-out (odd) periods.
        poses_scored: poses of the trajectory handed to the evaluation; ``poses_total`` all of them.
    """

    fused_epochs: int
    hold_out_period_s: float
    held_out_only: bool
    poses_scored: int
    poses_total: int

    def line(self) -> str:
        """One line for the report and the table."""
        head = f"the trajectory was fused with this log ({self.fused_epochs} GNSS epochs as factors)"
        if self.held_out_only:
            return (
                f"{head}; scored on the held-out epochs only ({self.poses_scored} of {self.poses_total} poses, "
                f"odd {self.hold_out_period_s:g} s periods; INS errors correlate over seconds: not fully independent)"
            )
        return f"{head}; the score is not independent (run with georef.hold_out_period_s > 0 to hold epochs out)"


def fusion_disclosure(
    estimate: Trajectory, fused_epochs: int, hold_out_period_s: float, *, held_out_only: bool = True
) -> tuple[FusionDisclosure, Trajectory]:
    """The disclosure and the trajectory to score: with a hold-out period (and ``held_out_only``),
    only the poses in odd periods, floor(t / period) odd."""
    use_held_out = held_out_only and hold_out_period_s > 0.0
    scored = estimate
    if use_held_out:
        period_ns = int(round(hold_out_period_s * 1e9))
        keep = (estimate.stamps_ns // period_ns) % 2 == 1
        scored = Trajectory(estimate.stamps_ns[keep], estimate.T_world_lidar[keep])
    disclosure = FusionDisclosure(int(fused_epochs), float(hold_out_period_s), use_held_out, len(scored), len(estimate))
    return disclosure, scored


@dataclass(frozen=True, slots=True)
class SpanEvaluation:
    """An evaluation against SPAN ground truth, with what it was computed from.

    Attributes:
        evaluation: metrics and associated poses (reference frame: ENU at ``reference.origin``).
        reference: the INS reference (IMU poses, quality flags) it used.
        log: the decoded log (its ``stats`` say what was read and rejected).
        T_imu_lidar: (4, 4) extrinsic applied to the reference.
        config: the resolved ``gnss`` settings.
        trajectory_source, span_source: file names where known, for the report.
        warnings: one line each for the report: log messages skipped for non-finite or
            out-of-range values, then the evaluation's (ill-conditioned alignment). Each was logged
            once where it arose (the reader, :func:`~lidar3d.metrics.evaluation.evaluate_trajectory`).
        fusion: set when the trajectory was fused with this log (``lidar3d run --gnss-factors``).
    """

    evaluation: Evaluation
    reference: InsReference
    log: SpanLog
    T_imu_lidar: np.ndarray
    config: GnssConfig
    trajectory_source: str = ""
    span_source: str = ""
    warnings: tuple[str, ...] = ()
    fusion: FusionDisclosure | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "warnings", tuple(self.warnings))


def _log_of(span_log: str | Path | SpanLog) -> SpanLog:
    return span_log if isinstance(span_log, SpanLog) else read_span_log(span_log)


def evaluate_against_span(
    estimate: Trajectory,
    span_log: str | Path | SpanLog,
    *,
    T_imu_lidar: np.ndarray | None = None,
    config: GnssConfig | None = None,
    align: AlignmentMode | str | None = None,
    origin: GeodeticOrigin | None = None,
    trajectory_source: str = "",
    reference: InsReference | None = None,
) -> SpanEvaluation:
    """Evaluate ``estimate`` (lidar poses, bag clock) against the INS solutions of a SPAN log.

    Args:
        estimate: the lidar trajectory; any world frame for ``se3``/``yaw`` alignment, ENU at the
            reference origin for ``none``.
        span_log: a log path (ASCII, binary, raw stream, optionally gzipped) or a decoded log.
        T_imu_lidar: lidar pose in the SPAN IMU frame (x right, y forward, z up); identity if None.
        config: the ``gnss`` section (leap seconds, time offset, accepted INS statuses, max gap,
            RPE lengths); defaults if None.
        align: overrides ``config.align``.
        origin: ENU origin; else ``config.origin``, else the first kept solution.
        trajectory_source: the trajectory's file name, where known, for the report.
        reference: the log's INS reference when the caller has built it already, from this log with
            this ``config`` and origin (:func:`~lidar3d.gnss.reference.span_reference`); built here
            (and its summary logged) when None.

    Raises :class:`~lidar3d.errors.GnssError` (unreadable log, no usable pose, INS never aligned),
    :class:`~lidar3d.metrics.errors.EvaluationError` (no time overlap, too few associated poses).
    """
    config = config or GnssConfig()
    mode = AlignmentMode.parse(align if align is not None else config.align)
    config = dataclasses.replace(config, align=mode.value)
    if origin is not None:  # recorded in the resolved settings, so the report can be reproduced
        config = dataclasses.replace(
            config, origin=(origin.latitude_deg, origin.longitude_deg, origin.height_ellipsoid_m)
        )
    log = _log_of(span_log)
    if reference is None:
        reference = span_reference(log, config, origin_from_config(config.origin))
    T = np.eye(4) if T_imu_lidar is None else np.asarray(T_imu_lidar, dtype=np.float64)
    evaluation = evaluate_trajectory(
        estimate,
        reference.trajectory,
        T_imu_lidar=T,
        align=mode,
        max_gap_s=config.max_association_gap_s,
        rpe_segment_lengths_m=config.rpe_segment_lengths_m,
        rpe_step_s=config.rpe_step_s,
        rpe_distances_m=config.rpe_distances_m,
    )
    warnings = list(evaluation.warnings)
    if log.stats.out_of_range:
        warnings.insert(
            0,
            f"{log.source or 'GNSS log'}: {log.stats.out_of_range} message(s) with non-finite or out-of-range values "
            "(position, velocity, attitude or GPS time) skipped",
        )
    result = SpanEvaluation(
        evaluation=evaluation,
        reference=reference,
        log=log,
        T_imu_lidar=T,
        config=config,
        trajectory_source=trajectory_source,
        span_source=log.source,
        warnings=tuple(warnings),
    )
    logger.debug(
        "ATE %s: rmse %.3f m over %d poses", mode.value, evaluation.ate.translation_3d_m.rmse, evaluation.n_associated
    )
    return result


def evaluate_span_files(
    trajectory_path: str | Path,
    span_path: str | Path,
    *,
    extrinsics_path: str | Path | None = None,
    align: AlignmentMode | str | None = None,
    time_offset_s: float | None = None,
    origin: GeodeticOrigin | None = None,
    config: GnssConfig | None = None,
    fused_epochs: int | None = None,
    hold_out_period_s: float = 0.0,
    held_out_only: bool = False,
) -> SpanEvaluation:
    """``lidar3d eval TRAJECTORY --span LOG [--extrinsics FILE] [--align] [--time-offset] [--origin]``.

    Reads the trajectory with :func:`lidar3d.io.trajectory_io.read_trajectory` (TUM or KITTI);
    ``time_offset_s`` and ``origin`` override the config's; see :func:`evaluate_against_span`.
    ``fused_epochs``: the trajectory was fused with this log (the result's ``fusion`` says so);
    with ``held_out_only`` only its poses in the held-out periods of ``hold_out_period_s`` are scored.
    ``lidar3d eval --out DIR`` then writes the report with
    :func:`lidar3d.export.span_report.write_span_report`.
    """
    from lidar3d.gnss.extrinsic import read_extrinsic

    config = config or GnssConfig()
    if time_offset_s is not None:
        config = dataclasses.replace(config, time_offset_s=float(time_offset_s))
    estimate = read_trajectory(trajectory_path)
    disclosure = None
    if fused_epochs is not None:
        disclosure, estimate = fusion_disclosure(estimate, fused_epochs, hold_out_period_s, held_out_only=held_out_only)
    T_imu_lidar = read_extrinsic(extrinsics_path) if extrinsics_path is not None else None
    result = evaluate_against_span(
        estimate,
        span_path,
        T_imu_lidar=T_imu_lidar,
        config=config,
        align=align,
        origin=origin,
        trajectory_source=str(trajectory_path),
    )
    return result if disclosure is None else dataclasses.replace(result, fusion=disclosure)
