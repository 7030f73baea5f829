"""Trajectory metrics: association, alignment (SE(3), yaw, none), ATE, RPE, SPAN evaluation.

Pure metric code (``association``, ``alignment``, ``ate``, ``rpe``, ``evaluation``) works on
:class:`~lidar3d.records.Trajectory` records and arrays; ``span_eval`` adds the SPAN reference. Nothing
here writes files: the report (JSON, CSV, plots, text table) is :mod:`lidar3d.export.span_report`.
"""

from lidar3d.metrics.alignment import (
    Alignment,
    AlignmentMode,
    align_trajectories,
    se3_conditioning,
    umeyama_se3,
    yaw_alignment,
)
from lidar3d.metrics.association import Association, associate, interpolate_reference
from lidar3d.metrics.ate import AbsoluteErrors, AteStatistics, absolute_errors
from lidar3d.metrics.errors import EvaluationError
from lidar3d.metrics.evaluation import Evaluation, evaluate_trajectory
from lidar3d.metrics.rpe import DistanceRpe, KittiRpe, distance_rpe, kitti_rpe
from lidar3d.metrics.span_eval import (
    SpanEvaluation,
    evaluate_against_span,
    evaluate_span_files,
)
from lidar3d.metrics.statistics import ErrorStatistics

__all__ = [
    "AbsoluteErrors",
    "Alignment",
    "AlignmentMode",
    "Association",
    "AteStatistics",
    "DistanceRpe",
    "ErrorStatistics",
    "Evaluation",
    "EvaluationError",
    "KittiRpe",
    "SpanEvaluation",
    "absolute_errors",
    "align_trajectories",
    "associate",
    "distance_rpe",
    "evaluate_against_span",
    "evaluate_span_files",
    "evaluate_trajectory",
    "interpolate_reference",
    "kitti_rpe",
    "se3_conditioning",
    "umeyama_se3",
    "yaw_alignment",
]
