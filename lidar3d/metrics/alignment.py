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

Conditioning of SE(3). Linearised about the solution, the rotation part of the position least squares
has the normal matrix sum_i [y'_i]x^T [y'_i]x = n (tr(C) I - C), C = 1/n sum_i y'_i y'_i^T the
covariance of the centred reference positions, with eigenvalues l1 >= l2 >= l3. Its eigenvalues are
n (l2 + l3) (rotation about the path's main axis), n (l1 + l3) and n (l1 + l2), so

    kappa = (l2 + l3) / (l1 + l2)

is the ratio of the weakest to the strongest rotational information. A nearly straight path has
kappa -> 0: rotation about the path axis is then fixed by noise alone (a 4 s clip of a 10 m/s drive
on a 2 km radius with 2 cm noise gives kappa ~ 7e-6 and rotation errors of 4-16 deg). When kappa is
below :data:`SE3_MIN_CONDITIONING` (1e-3: lateral spread under about 3 % of the along-track spread),
the ``se3`` alignment falls back to ``yaw`` (gravity known: the estimate's z axis is taken as up),
with a warning. Above it the SE(3) result is unchanged.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from lidar3d.metrics.errors import EvaluationError

__all__ = [
    "MIN_ALIGNMENT_POSES",
    "SE3_MIN_CONDITIONING",
    "Alignment",
    "AlignmentMode",
    "align_trajectories",
    "se3_conditioning",
    "umeyama_se3",
    "yaw_alignment",
]

MIN_ALIGNMENT_POSES = 3
SE3_MIN_CONDITIONING = 1e-3


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


@dataclass(frozen=True, slots=True)
class Alignment:
    """The alignment an evaluation used.

    Attributes:
        T_reference_estimate: (4, 4) float64, estimate world frame -> reference world frame.
        requested: the mode asked for.
        mode: the mode used (``yaw`` where ``se3`` was asked for and is ill-conditioned).
        conditioning: kappa of the reference positions (module docstring); NaN for ``none``.
        note: why ``mode`` differs from ``requested`` (one line), else "".
    """

    T_reference_estimate: np.ndarray
    requested: AlignmentMode
    mode: AlignmentMode
    conditioning: float
    note: str = ""

    def __post_init__(self) -> None:
        T = np.array(self.T_reference_estimate, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"Alignment.T_reference_estimate must be (4, 4), got {T.shape}")
        T.flags.writeable = False
        object.__setattr__(self, "T_reference_estimate", T)


def _refuse_non_finite(what: str, values: np.ndarray) -> None:
    """:class:`EvaluationError` when any of the (N, ...) per-pose ``values`` is NaN or infinite."""
    finite = np.isfinite(values.reshape(len(values), -1)).all(axis=1)
    if not finite.all():
        raise EvaluationError(
            f"{what} hold non-finite values ({int((~finite).sum())} of {len(values)} poses, the first at "
            f"index {int(np.argmin(finite))}); alignment needs finite poses"
        )


def _check_points(source_m: np.ndarray, target_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = np.asarray(source_m, dtype=np.float64)
    y = np.asarray(target_m, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"alignment needs two (N, 3) arrays, got {x.shape} and {y.shape}")
    if x.shape[0] < MIN_ALIGNMENT_POSES:
        raise EvaluationError(f"only {x.shape[0]} associated pose(s); alignment needs at least {MIN_ALIGNMENT_POSES}")
    _refuse_non_finite("source positions", x)
    _refuse_non_finite("target positions", y)
    return x, y


def se3_conditioning(positions_m: np.ndarray) -> float:
    """kappa = (l2 + l3) / (l1 + l2) of the centred (N, 3) positions' covariance (module docstring).

    0 for collinear (or coincident) positions, 1 for an isotropic cloud.
    """
    p = np.asarray(positions_m, dtype=np.float64)
    centred = p - p.mean(axis=0)
    l3, l2, l1 = np.linalg.eigvalsh(centred.T @ centred / max(len(p), 1))
    if l1 + l2 <= 0.0:
        return 0.0
    return float(max(l2 + l3, 0.0) / (l1 + l2))


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
) -> Alignment:
    """Align associated estimate poses (M, 4, 4) to reference poses (M, 4, 4).

    ``se3`` falls back to ``yaw`` when the reference positions leave it ill-conditioned
    (:func:`se3_conditioning` below :data:`SE3_MIN_CONDITIONING`); the result says so in ``note``.
    Raises :class:`EvaluationError` for non-finite poses and too few poses.
    """
    mode = AlignmentMode.parse(mode)
    T_ref = np.asarray(T_world_reference, float)
    T_est = np.asarray(T_world_estimate, float)
    _refuse_non_finite("reference poses", T_ref)
    _refuse_non_finite("estimate poses", T_est)
    ref = T_ref[:, :3, 3]
    est = T_est[:, :3, 3]
    if mode is AlignmentMode.NONE:
        if est.shape[0] == 0:
            raise EvaluationError("no associated poses to evaluate")
        return Alignment(np.eye(4), mode, mode, math.nan)
    _check_points(est, ref)
    kappa = se3_conditioning(ref)
    if mode is AlignmentMode.SE3 and kappa < SE3_MIN_CONDITIONING:
        note = (
            f"se3 alignment is ill-conditioned (conditioning {kappa:.1e} < {SE3_MIN_CONDITIONING:g}: the reference "
            "path is nearly straight, rotation about it is unobservable); used yaw (4-DoF, gravity known) instead"
        )
        return Alignment(yaw_alignment(est, ref), mode, AlignmentMode.YAW, kappa, note)
    T = umeyama_se3(est, ref) if mode is AlignmentMode.SE3 else yaw_alignment(est, ref)
    return Alignment(T, mode, mode, kappa)
