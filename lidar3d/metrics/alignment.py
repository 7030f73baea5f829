"""Alignment of an estimated trajectory to the reference: SE(3), 4-DoF (yaw + translation), none.

All return ``T_reference_estimate``, the rigid transform taking the estimate's world frame into the
reference world frame, chosen to minimise sum_i |p_ref,i - (R p_est,i + t)|^2 over the positions.

* SE(3): Umeyama (1991), "Least-squares estimation of transformation parameters between two point
  patterns", eqs. (34)-(42) without scale: Sigma = 1/n sum (y_i - mu_y)(x_i - mu_x)^T = U D V^T,
  S = diag(1, 1, det(U) det(V)), R = U S V^T, t = mu_y - R mu_x (as evo ``umeyama_alignment``).
* yaw (4-DoF, gravity known; rpg_trajectory_evaluation ``posyaw``): R = Rz(theta) maximises
  tr(Rz(theta) H), H = sum x'_i y'_i^T (centred), so theta = atan2(H01 - H10, H00 + H11);
  t = mu_y - R mu_x.
* none: identity (for trajectories already expressed in the reference frame).
"""

from __future__ import annotations

import enum

import numpy as np

from lidar3d.metrics.errors import EvaluationError

__all__ = ["MIN_ALIGNMENT_POSES", "AlignmentMode", "align_trajectories", "umeyama_se3", "yaw_alignment"]

MIN_ALIGNMENT_POSES = 3


class AlignmentMode(str, enum.Enum):
    """How the estimate is aligned to the reference before absolute errors are computed."""

    SE3 = "se3"
    YAW = "yaw"
    NONE = "none"

    @classmethod
    def parse(cls, value: str | AlignmentMode) -> AlignmentMode:
        """The mode named ``value``; :class:`EvaluationError` for an unknown name."""
        try:
            return cls(value)
        except ValueError:
            raise EvaluationError(f"unknown alignment {value!r} (choose {', '.join(m.value for m in cls)})") from None


def _check_points(source_m: np.ndarray, target_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(source_m, dtype=np.float64)
    y = np.asarray(target_m, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"alignment needs two (N, 3) arrays, got {x.shape} and {y.shape}")
    if x.shape[0] < MIN_ALIGNMENT_POSES:
        raise EvaluationError(f"only {x.shape[0]} associated pose(s); alignment needs at least {MIN_ALIGNMENT_POSES}")
    return x, y


def _transform(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def umeyama_se3(source_m: np.ndarray, target_m: np.ndarray) -> np.ndarray:
    """4x4 ``T_target_source`` minimising sum |target_i - T source_i|^2 (Umeyama without scale).

    Raises :class:`EvaluationError` when the points are (nearly) collinear: the rotation about the
    line is then undetermined (use the yaw alignment for straight drives).
    """
    x, y = _check_points(source_m, target_m)
    mu_x, mu_y = x.mean(axis=0), y.mean(axis=0)
    sigma = (y - mu_y).T @ (x - mu_x) / x.shape[0]
    U, D, Vt = np.linalg.svd(sigma)
    if D[1] <= 1e-12 * max(D[0], 1e-300):
        raise EvaluationError(
            "SE(3) alignment is degenerate: the associated positions are (nearly) collinear; use the yaw alignment"
        )
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    return _transform(R, mu_y - R @ mu_x)


def yaw_alignment(source_m: np.ndarray, target_m: np.ndarray) -> np.ndarray:
    """4x4 ``T_target_source`` with a rotation about z only (4-DoF), least squares in closed form."""
    x, y = _check_points(source_m, target_m)
    mu_x, mu_y = x.mean(axis=0), y.mean(axis=0)
    H = (x - mu_x).T @ (y - mu_y)
    theta = np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
    c, s = np.cos(theta), np.sin(theta)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return _transform(R, mu_y - R @ mu_x)


def align_trajectories(
    T_world_reference: np.ndarray, T_world_estimate: np.ndarray, mode: AlignmentMode | str
) -> np.ndarray:
    """``T_reference_estimate`` (4x4) aligning associated estimate poses to reference poses."""
    mode = AlignmentMode.parse(mode)
    ref = np.asarray(T_world_reference, float)[:, :3, 3]
    est = np.asarray(T_world_estimate, float)[:, :3, 3]
    if mode is AlignmentMode.SE3:
        return umeyama_se3(est, ref)
    if mode is AlignmentMode.YAW:
        return yaw_alignment(est, ref)
    if est.shape[0] == 0:
        raise EvaluationError("no associated poses to evaluate")
    return np.eye(4)
