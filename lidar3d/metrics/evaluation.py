"""Evaluate an estimated lidar trajectory against a reference: associate, align, ATE, RPE.

The reference is given as poses of its own body (for SPAN: the IMU) with ``T_imu_lidar``, the pose
of the lidar in that body frame. The reference is interpolated at the estimate stamps first and
then moved to the lidar, T_enu_lidar = T_enu_imu . T_imu_lidar, so that both trajectories are poses
of the same body before any metric (``shared/reference/gnss-and-metrics.md`` section 3.6).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from lidar3d.metrics.alignment import (
    MIN_ALIGNMENT_POSES,
    AlignmentMode,
    align_trajectories,
)
from lidar3d.metrics.association import associate
from lidar3d.metrics.ate import AbsoluteErrors, AteStatistics, absolute_errors
from lidar3d.metrics.errors import EvaluationError
from lidar3d.metrics.rpe import (
    KITTI_SEGMENT_LENGTHS_M,
    DistanceRpe,
    KittiRpe,
    distance_rpe,
    kitti_rpe,
)
from lidar3d.records import Trajectory

__all__ = ["Evaluation", "evaluate_trajectory"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class Evaluation:
    """Result of :func:`evaluate_trajectory`.

    Attributes:
        stamps_ns: (M,) stamps of the associated poses.
        estimate_index: (M,) their indices in the estimate.
        reference_index: (M,) index of the nearest reference sample of each (quality look-ups).
        T_ref_lidar: (M, 4, 4) reference lidar poses (reference world, e.g. ENU).
        T_ref_lidar_estimate: (M, 4, 4) estimate lidar poses after alignment, same frame.
        T_reference_estimate: (4, 4) the alignment (estimate world -> reference world).
        alignment: the alignment mode used (``yaw`` where ``se3`` was asked for and is ill-conditioned).
        alignment_requested: the alignment mode asked for.
        alignment_conditioning: the SE(3) conditioning kappa of the reference positions
            (:func:`~lidar3d.metrics.alignment.se3_conditioning`), NaN for ``none``.
        alignment_note: why ``alignment`` differs from ``alignment_requested`` (one line), else "".
        errors: per-pose absolute errors; ``ate`` their statistics.
        kitti: KITTI relative errors; ``distance_rpe`` RPE per fixed distance.
        n_estimate: poses in the estimate (``len(stamps_ns)`` of them were associated).
        max_gap_s: the association's interpolation limit.
        warnings: one line each, for the report (each was logged once, at WARNING).
    """

    stamps_ns: np.ndarray
    estimate_index: np.ndarray
    reference_index: np.ndarray
    T_ref_lidar: np.ndarray
    T_ref_lidar_estimate: np.ndarray
    T_reference_estimate: np.ndarray
    alignment: AlignmentMode
    alignment_requested: AlignmentMode
    alignment_conditioning: float
    alignment_note: str
    errors: AbsoluteErrors
    ate: AteStatistics
    kitti: KittiRpe
    distance_rpe: tuple[DistanceRpe, ...]
    n_estimate: int
    max_gap_s: float
    warnings: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for name in (
            "stamps_ns",
            "estimate_index",
            "reference_index",
            "T_ref_lidar",
            "T_ref_lidar_estimate",
            "T_reference_estimate",
        ):
            value = np.array(getattr(self, name))
            value.flags.writeable = False
            object.__setattr__(self, name, value)
        object.__setattr__(self, "distance_rpe", tuple(self.distance_rpe))
        object.__setattr__(self, "warnings", tuple(self.warnings))

    @property
    def n_associated(self) -> int:
        """Number of associated poses."""
        return int(self.stamps_ns.shape[0])

    @property
    def path_length_m(self) -> float:
        """Length of the reference path over the associated poses."""
        p = self.T_ref_lidar[:, :3, 3]
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


def evaluate_trajectory(
    estimate: Trajectory,
    reference: Trajectory,
    *,
    T_imu_lidar: np.ndarray | None = None,
    align: AlignmentMode | str = AlignmentMode.SE3,
    max_gap_s: float = 0.2,
    rpe_segment_lengths_m: tuple[float, ...] = KITTI_SEGMENT_LENGTHS_M,
    rpe_step_s: float = 1.0,
    rpe_distances_m: tuple[float, ...] = (10.0, 100.0),
) -> Evaluation:
    """Compare ``estimate`` (lidar poses, any world frame) with ``reference`` (body poses).

    Args:
        estimate: the estimated lidar trajectory; stamps in the reference's clock.
        reference: reference poses of its body (``T_world_lidar`` holds e.g. T_enu_imu).
        T_imu_lidar: pose of the lidar in the reference body frame (identity if ``None``).
        align: ``se3``, ``yaw`` (4-DoF) or ``none``; ``se3`` on a nearly straight reference falls
            back to ``yaw`` with a warning (:func:`~lidar3d.metrics.alignment.align_trajectories`).
        max_gap_s: longest reference interval to interpolate across.

    Raises :class:`EvaluationError` for no time overlap, too few associated poses or non-finite poses.
    """
    mode = AlignmentMode.parse(align)
    T_imu_lidar = np.eye(4) if T_imu_lidar is None else np.asarray(T_imu_lidar, dtype=np.float64)
    if T_imu_lidar.shape != (4, 4):
        raise ValueError(f"T_imu_lidar must be 4x4, got {T_imu_lidar.shape}")
    pairs = associate(estimate, reference, max_gap_s)
    needed = 1 if mode is AlignmentMode.NONE else MIN_ALIGNMENT_POSES
    if len(pairs) < needed:
        raise EvaluationError(
            f"only {len(pairs)} of {len(estimate)} poses associated with the reference (max gap "
            f"{max_gap_s:g} s); {mode.value} alignment needs at least {needed}"
        )
    T_ref_lidar = pairs.T_world_reference @ T_imu_lidar
    alignment = align_trajectories(T_ref_lidar, pairs.T_world_estimate, mode)
    warnings = (alignment.note,) if alignment.note else ()
    for line in warnings:
        logger.warning("%s", line)
    T_reference_estimate = alignment.T_reference_estimate
    T_estimate = T_reference_estimate @ pairs.T_world_estimate
    errors = absolute_errors(T_ref_lidar, T_estimate)
    return Evaluation(
        stamps_ns=pairs.stamps_ns,
        estimate_index=pairs.estimate_index,
        reference_index=pairs.reference_index,
        T_ref_lidar=T_ref_lidar,
        T_ref_lidar_estimate=T_estimate,
        T_reference_estimate=T_reference_estimate,
        alignment=alignment.mode,
        alignment_requested=alignment.requested,
        alignment_conditioning=alignment.conditioning,
        alignment_note=alignment.note,
        errors=errors,
        ate=errors.statistics(),
        kitti=kitti_rpe(pairs.stamps_ns, T_ref_lidar, T_estimate, tuple(rpe_segment_lengths_m), rpe_step_s),
        distance_rpe=tuple(distance_rpe(T_ref_lidar, T_estimate, d) for d in rpe_distances_m),
        n_estimate=len(estimate),
        max_gap_s=float(max_gap_s),
        warnings=warnings,
    )
