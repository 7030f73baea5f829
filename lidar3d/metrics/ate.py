"""Absolute trajectory error (ATE) of aligned, associated poses.

Per pose i, with reference Q_i and aligned estimate P_i in the same (ENU) world frame:
translation e_i = |p_i - q_i| (evo APE ``translation_part``, TUM ``evaluate_ate``), split into
horizontal |(dx, dy)| and vertical |dz|; rotation e_i = angle(R_q,i^T R_p,i) in degrees, with
angle(R) = arccos((tr R - 1) / 2) (evo APE ``angle_deg``, computed stably). Statistics per :class:`ErrorStatistics`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar3d.metrics.statistics import ErrorStatistics

__all__ = ["AbsoluteErrors", "AteStatistics", "absolute_errors", "rotation_angle_deg"]


def rotation_angle_deg(R: np.ndarray) -> np.ndarray:
    """Rotation angle(s) in degrees of (..., 3, 3) rotation matrices.

    theta = atan2(|vee(R - R^T)| / 2, (tr R - 1) / 2), which equals arccos((tr R - 1) / 2) but keeps
    full precision for tiny angles (arccos loses it below about 1e-7 rad).
    """
    R = np.asarray(R, float)
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    axis = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], axis=-1)
    sin = np.linalg.norm(axis, axis=-1) / 2.0
    return np.degrees(np.arctan2(sin, cos))


@dataclass(frozen=True, slots=True)
class AteStatistics:
    """ATE statistics: 3-D, horizontal and vertical translation (m) and rotation (deg)."""

    translation_3d_m: ErrorStatistics
    horizontal_m: ErrorStatistics
    vertical_m: ErrorStatistics
    rotation_deg: ErrorStatistics


@dataclass(frozen=True, slots=True)
class AbsoluteErrors:
    """Per-pose absolute errors, each (M,) float64.

    Attributes:
        translation_3d_m, horizontal_m, vertical_m: |dp|, |(dx, dy)|, |dz| in metres.
        signed_vertical_m: estimate minus reference height.
        rotation_deg: angle of R_ref^T R_est.
    """

    translation_3d_m: np.ndarray
    horizontal_m: np.ndarray
    vertical_m: np.ndarray
    signed_vertical_m: np.ndarray
    rotation_deg: np.ndarray

    def __post_init__(self) -> None:
        for name in ("translation_3d_m", "horizontal_m", "vertical_m", "signed_vertical_m", "rotation_deg"):
            value = np.array(getattr(self, name), dtype=np.float64)
            value.flags.writeable = False
            object.__setattr__(self, name, value)

    def statistics(self) -> AteStatistics:
        """Summary statistics of each error series."""
        return AteStatistics(
            translation_3d_m=ErrorStatistics.of(self.translation_3d_m),
            horizontal_m=ErrorStatistics.of(self.horizontal_m),
            vertical_m=ErrorStatistics.of(self.vertical_m),
            rotation_deg=ErrorStatistics.of(self.rotation_deg),
        )


def absolute_errors(T_world_reference: np.ndarray, T_world_estimate: np.ndarray) -> AbsoluteErrors:
    """Per-pose errors of (M, 4, 4) estimate poses against reference poses in the same frame."""
    Q = np.asarray(T_world_reference, float)
    P = np.asarray(T_world_estimate, float)
    if Q.shape != P.shape or Q.ndim != 3 or Q.shape[1:] != (4, 4):
        raise ValueError(f"absolute_errors needs two (M, 4, 4) arrays, got {Q.shape} and {P.shape}")
    d = P[:, :3, 3] - Q[:, :3, 3]
    return AbsoluteErrors(
        translation_3d_m=np.linalg.norm(d, axis=1),
        horizontal_m=np.linalg.norm(d[:, :2], axis=1),
        vertical_m=np.abs(d[:, 2]),
        signed_vertical_m=d[:, 2],
        rotation_deg=rotation_angle_deg(np.swapaxes(Q[:, :3, :3], -1, -2) @ P[:, :3, :3]),
    )
