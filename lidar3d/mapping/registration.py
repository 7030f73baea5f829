"""Point-to-line and point-to-plane pose estimation (LOAM family), vectorised.

Every correspondence becomes one or two *rows* ``r = a . q + b`` that are linear in the source
point transformed into the target frame, ``q = R(x) p + t``: a plane gives one row (its unit
normal and offset), a line gives two rows (two unit vectors perpendicular to it), so residual
and Jacobian construction is the same for both. The pose is parameterised as
``x = [tx, ty, tz, roll, pitch, yaw]`` with ``R = Rz(yaw) Ry(pitch) Rx(roll)``, which lets a
solver free only a subset of the axes (LeGO-LOAM's two-step odometry: z/roll/pitch from the
ground, then x/y/yaw from edges).

The solver is Gauss-Newton with either LOAM's robust row weights (s = 1 - 0.9 |r|, rows with
s <= 0.1 dropped; LeGO-LOAM mapOptmization.cpp:1160, 1214) or a Geman-McClure kernel (as KISS-ICP
uses). Directions the rows leave unobserved are handled in one of two ways:

* without a prior, LOAM's solution remapping (Zhang et al., "On degeneracy of optimization-based
  state estimation problems", ICRA 2016): on the first iteration, the directions the rows leave
  unobserved are projected out of every update, so they keep the initial guess;
* with a Gaussian :class:`PosePrior` (a motion model's prediction and its information), the
  maximum a posteriori pose: the rows' information ``J^T W J / sigma^2`` (``sigma^2`` the weighted
  residual variance of the current iteration) is added to the prior's, so each direction takes
  the data where the data is more certain than the prior and the prior where it is not, with no
  threshold and no switch between the two.

Which directions are unobserved is decided by :func:`unobserved_directions`: against a
*reference* belief (the vehicle model's uncertainty over one scan), a direction is unobserved when
the rows know it less well than the reference does, i.e. where the rows' information, measured in
the reference's units, is below 1. This is scale free (translations and rotations need no lever
arm) and counts what the rows tell, not how many rows there are; LeGO-LOAM's test (eigenvalues of
``J^T J`` below 100, with unit-normal rows) is kept for the scan-to-scan odometry, whose steps are
judged against a fixed row count (``degeneracy_threshold``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from lidar3d.mapping.nearest import PointTree
from lidar3d.mapping.se3 import cross, xyz_rpy_from_pose

__all__ = [
    "ALL_AXES",
    "LineMap",
    "MatchRows",
    "PlaneMap",
    "PosePrior",
    "SolveResult",
    "SweepTurn",
    "largest_variance",
    "line_rows_from_directions",
    "observed_share",
    "plane_rows_from_normals",
    "probe_return_share",
    "solve_pose",
    "unobserved_directions",
]

ALL_AXES = (0, 1, 2, 3, 4, 5)


@dataclass(frozen=True, slots=True)
class MatchRows:
    """Linear residual rows ``r_k = normal_k . q(source[source_index_k]) + offset_k`` (metres).

    Attributes:
        source_index: (K,) int index into the source point array.
        normal: (K, 3) unit vectors in the target frame.
        offset: (K,) metres.
    """

    source_index: np.ndarray
    normal: np.ndarray
    offset: np.ndarray

    def __len__(self) -> int:
        return int(self.source_index.shape[0])

    @staticmethod
    def empty() -> MatchRows:
        return MatchRows(np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0))

    @staticmethod
    def concatenate(parts: list[MatchRows], index_shifts: list[int]) -> MatchRows:
        shifted = [(p, s) for p, s in zip(parts, index_shifts) if len(p)]
        if not shifted:
            return MatchRows.empty()
        return MatchRows(
            np.concatenate([p.source_index + s for p, s in shifted]),
            np.concatenate([p.normal for p, _ in shifted]),
            np.concatenate([p.offset for p, _ in shifted]),
        )


@dataclass(frozen=True, slots=True)
class PosePrior:
    """A Gaussian belief about ``T_target_source`` before the rows are seen.

    Attributes:
        T_target_source: (4, 4) mean.
        information: (6, 6) inverse covariance over ``[tx, ty, tz, roll, pitch, yaw]`` (m, rad)
            of the pose parameterisation :func:`solve_pose` uses (translation in the target
            frame, Euler angles of ``R = Rz(yaw) Ry(pitch) Rx(roll)``).
    """

    T_target_source: np.ndarray
    information: np.ndarray

    def fused_with(self, other: PosePrior) -> PosePrior:
        """The product of this Gaussian and ``other`` (an independent belief about the same pose):
        informations added, the mean where each moves it by its information (to first order, in
        the parameterisation above, the yaw difference wrapped; a direction neither informs keeps
        this belief's mean)."""
        x_self = _xyz_rpy(self.T_target_source)
        difference = _wrapped_difference(_xyz_rpy(other.T_target_source), x_self)
        information = self.information + other.information
        x_mean = x_self + np.linalg.lstsq(information, other.information @ difference, rcond=None)[0]
        return PosePrior(_pose(x_mean, _rotation_and_derivatives(x_mean)[0]), information)

    def displacement_sigma_m(self, lever_m: float) -> float:
        """How far (1 sigma, m) the prior's uncertainty may move a point ``lever_m`` from the
        origin: the largest translation sigma plus the lever times the largest rotation sigma."""
        covariance = np.linalg.inv(self.information)
        sigma_t = float(np.sqrt(largest_variance(covariance[:3, :3])))
        sigma_r = float(np.sqrt(largest_variance(covariance[3:, 3:])))
        return sigma_t + lever_m * sigma_r

    def rotation_variance_rad2(self) -> float:
        """The largest variance of the prior's rotation (rad^2)."""
        return largest_variance(np.linalg.inv(self.information)[3:, 3:])


def largest_variance(covariance: np.ndarray) -> float:
    """The largest eigenvalue of a symmetric (3,3) covariance block (m^2 or rad^2), at least 0."""
    return max(float(np.linalg.eigvalsh(covariance).max()), 0.0)


@dataclass(frozen=True, slots=True)
class SolveResult:
    """Outcome of :func:`solve_pose`.

    Attributes:
        T_target_source: (4, 4) estimated transform.
        iterations: Gauss-Newton iterations run.
        converged: the last update was below the convergence thresholds.
        n_rows: residual rows used in the last iteration.
        degenerate_axes: number of directions the rows left unobserved: with a reference belief,
            directions where the rows' information at the last iteration is below the
            reference's (:func:`unobserved_directions`); otherwise directions of J^T J with an
            eigenvalue below the degeneracy threshold at the first iteration. Without a prior
            these were projected out of the updates.
        min_eigenvalue: smallest eigenvalue of J^T J at the first iteration.
        information: (6, 6) the rows' information ``J^T W J / sigma^2`` about
            ``[tx, ty, tz, roll, pitch, yaw]`` at the last iteration (zero rows and columns for
            axes that were not free; all zero when the solve did not run).
        residual_sigma_m: the weighted residual standard deviation ``sigma`` of the last
            iteration (NaN when the solve did not run).
        probe_return_share: how much of the rows' information along their weakest translation the
            cost really has, from :func:`probe_return_share` (1 when not probed); the
            ``information`` is already scaled by it along that direction.
        matches: the correspondences of the last iteration (rows into the source points, target
            frame), None when the solve did not run.
    """

    T_target_source: np.ndarray
    iterations: int
    converged: bool
    n_rows: int
    degenerate_axes: int
    min_eigenvalue: float
    information: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))
    residual_sigma_m: float = float("nan")
    probe_return_share: float = 1.0
    matches: MatchRows | None = None
    yaw_rate_correction_rad_s: float = 0.0


@dataclass(frozen=True, slots=True)
class SweepTurn:
    """The sweep's yaw rate as a parameter of its registration, beside the pose.

    A sweep is deskewed with a predicted twist held over its 0.1 s; where the vehicle's yaw rate
    changes (a turn's entry or exit, 20-30 deg/s gained or lost within a few sweeps) the points
    fired late in the sweep are turned by up to ``T x`` the rate's error about the sensor (1.5 deg,
    50 cm at 20 m), and a pose-only registration takes the mean of that distortion into the pose.
    With a ``SweepTurn`` the registration solves for a correction ``w`` of the yaw rate too (the
    continuous-time sweep of CT-ICP, Dellenbach et al., ICRA 2022, reduced to the one rate a
    vehicle changes quickly): a point fired ``t`` after the stamp is turned by ``w t`` about the
    lidar's z axis through where the sensor was then (``t v``), to first order in the sweep's
    motion. The rows decide ``w`` as far as they observe it (vertical structure over the sweep's
    azimuths); the zero-mean prior ``information`` (the vehicle model's yaw acceleration over one
    sweep) decides it where they do not.

    The rate is kept only where the rows tell it from the prediction: a correction within
    ``min_sigmas`` of its posterior standard deviation is dropped and the pose taken with the rate
    held at the prediction (to first order from the joint solution), so a steady stretch, where
    the prediction is right, is registered as without the rate.

    Attributes:
        time_s: (N,) firing time of each source point, s from the stamp.
        velocity_mps: (3,) linear velocity the sweep was deskewed with (lidar frame).
        information: prior information of ``w``, (rad/s)^-2.
        min_sigmas: a correction is kept from this many posterior standard deviations.
    """

    time_s: np.ndarray
    velocity_mps: np.ndarray
    information: float
    min_sigmas: float = 3.0

    def turned(self, points: np.ndarray, rate_rad_s: float) -> np.ndarray:
        """(N, 3) source points with the sweep's yaw rate corrected by ``rate_rad_s``."""
        if rate_rad_s == 0.0:
            return points
        t = self.time_s
        centre = t[:, None] * self.velocity_mps
        d = points - centre
        c, s = np.cos(rate_rad_s * t), np.sin(rate_rad_s * t)
        return centre + np.column_stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]])

    def column(self, normal: np.ndarray, points: np.ndarray, index: np.ndarray, R: np.ndarray) -> np.ndarray:
        """(K,) derivative of the rows ``normal . (R p + t)`` (K unit normals, target frame) over
        the rate correction, for the (K, 3) turned source points ``points`` of source ``index``."""
        t = np.take(self.time_s, index)
        d = points - t[:, None] * self.velocity_mps
        turn = np.column_stack([-d[:, 1], d[:, 0], np.zeros(len(d))])  # e_z x d
        return t * np.einsum("ij,ij->i", normal, turn @ R.T)


def plane_rows_from_normals(source_index: np.ndarray, normal: np.ndarray, offset: np.ndarray) -> MatchRows:
    """Rows for point-to-plane matches with planes ``normal . q + offset = 0``."""
    return MatchRows(np.asarray(source_index, np.int64), normal, offset)


def line_rows_from_directions(source_index: np.ndarray, line_point: np.ndarray, direction: np.ndarray) -> MatchRows:
    """Two rows per point-to-line match: the two components of the perpendicular offset."""
    u = direction / np.linalg.norm(direction, axis=1, keepdims=True)
    helper = np.where(np.abs(u[:, [0]]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
    b1 = cross(u, helper)
    b1 /= np.linalg.norm(b1, axis=1, keepdims=True)
    b2 = cross(u, b1)
    normal = np.concatenate([b1, b2])
    offset = -np.einsum("ij,ij->i", normal, np.concatenate([line_point, line_point]))
    index = np.concatenate([source_index, source_index]).astype(np.int64)
    return MatchRows(index, normal, offset)


def _fit_planes(nbrs: np.ndarray, max_plane_residual_m: float, min_spread_m: float):
    """Least-squares planes through (M,k,3) neighbourhoods: (normal, offset, valid)."""
    centroid = nbrs.mean(axis=1)
    centered = nbrs - centroid[:, None, :]
    cov = np.einsum("mki,mkj->mij", centered, centered) / nbrs.shape[1]
    vals, vecs = np.linalg.eigh(cov)
    normal = vecs[:, :, 0]
    offset = -np.einsum("ij,ij->i", normal, centroid)
    spread = np.abs(np.einsum("mkj,mj->mk", nbrs, normal) + offset[:, None]).max(axis=1)
    valid = (spread < max_plane_residual_m) & (vals[:, 1] >= min_spread_m**2)
    return normal, offset, valid


def _fit_lines(nbrs: np.ndarray, min_eigen_ratio: float):
    """Principal lines through (M,k,3) neighbourhoods: (point, direction, valid)."""
    centroid = nbrs.mean(axis=1)
    centered = nbrs - centroid[:, None, :]
    cov = np.einsum("mki,mkj->mij", centered, centered) / nbrs.shape[1]
    vals, vecs = np.linalg.eigh(cov)
    valid = vals[:, 2] > min_eigen_ratio * vals[:, 1]
    return centroid, vecs[:, :, 2], valid


class _LocalGeometryMap:
    """Target points whose local geometry (around each target point's k neighbours) is fitted
    lazily, the first time a query lands nearest to that point, then reused.

    LOAM fits a line or plane to the k nearest neighbours of every query at every iteration;
    fitting it once per *target* point instead (the query's nearest target point's
    neighbourhood) gives the same kind of correspondence and makes repeated iterations and
    scans against an unchanged submap cost one nearest-neighbour query each.
    """

    def __init__(self, points: np.ndarray, *, k: int, max_sq_dist: float) -> None:
        self.points = np.asarray(points, dtype=np.float64)
        self.tree = PointTree(self.points) if len(self.points) else None
        self.k = k
        self.max_dist = float(np.sqrt(max_sq_dist))
        n = len(self.points)
        self._state = np.zeros(n, np.int8)  # 0 not fitted, 1 valid, -1 invalid
        self._a = np.zeros((n, 3))
        self._b = np.zeros((n, 3))

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def _fit(self, nbrs: np.ndarray):
        raise TypeError("subclasses fit their own geometry")

    def nearest_fitted(self, query: np.ndarray, reach_m: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(query rows, target index) of queries whose nearest target point has valid geometry,
        looked for within ``reach_m`` (at least the fit radius)."""
        if len(query) == 0 or len(self.points) < self.k or self.tree is None:
            return np.zeros(0, np.int64), np.zeros(0, np.int64)
        bound = self.max_dist if reach_m is None else max(self.max_dist, reach_m)
        dist, idx = self.tree.query(query, k=1, distance_upper_bound=bound)
        rows = np.flatnonzero(np.isfinite(dist))
        idx = idx[rows]
        todo = np.unique(idx[self._state[idx] == 0])
        if todo.size:
            nd, ni = self.tree.query(np.take(self.points, todo, axis=0), k=self.k)
            close = nd[:, -1] <= self.max_dist
            a, b, valid = self._fit(np.take(self.points, ni, axis=0))  # (M, k, 3)
            good = close & valid
            self._state[todo] = np.where(good, 1, -1)
            self._a[todo[good]] = a[good]
            self._b[todo[good]] = b[good]
        keep = self._state[idx] == 1
        return rows[keep], idx[keep]


class PlaneMap(_LocalGeometryMap):
    """Surface points with lazily fitted local planes (LeGO-LOAM mapOptmization 1176-1227:
    5 neighbours, the 5th within 1 m, all within 0.2 m of the plane).

    Ours in addition: the neighbours must spread at least ``min_spread_m`` (standard deviation)
    along the plane's second axis. Neighbours along one scan line are nearly collinear, and the
    smallest-eigenvalue "normal" of a noisy line is tilted at random about it, which biases
    pitch and height when such lines lie on the ground ahead.
    """

    def __init__(
        self,
        points: np.ndarray,
        *,
        k: int = 5,
        max_sq_dist: float = 1.0,
        max_plane_residual_m: float = 0.05,
        min_spread_m: float = 0.1,
    ) -> None:
        super().__init__(points, k=k, max_sq_dist=max_sq_dist)
        self.max_plane_residual_m = max_plane_residual_m
        self.min_spread_m = min_spread_m

    def _fit(self, nbrs: np.ndarray):
        normal, offset, valid = _fit_planes(nbrs, self.max_plane_residual_m, self.min_spread_m)
        return normal, np.repeat(offset[:, None], 3, axis=1), valid

    def rows(self, query: np.ndarray, reach_m: float | None = None) -> MatchRows:
        """Point-to-plane rows for ``query`` points (target frame) whose nearest fitted target
        point is within ``reach_m`` (default: the fit radius)."""
        rows, idx = self.nearest_fitted(query, reach_m)
        return MatchRows(rows.astype(np.int64), np.take(self._a, idx, axis=0), self._b[idx, 0])


class LineMap(_LocalGeometryMap):
    """Edge points with lazily fitted local lines (LeGO-LOAM mapOptmization 1093-1174:
    5 neighbours, the 5th within 1 m, largest covariance eigenvalue > 3x the second)."""

    def __init__(
        self, points: np.ndarray, *, k: int = 5, max_sq_dist: float = 1.0, min_eigen_ratio: float = 3.0
    ) -> None:
        super().__init__(points, k=k, max_sq_dist=max_sq_dist)
        self.min_eigen_ratio = min_eigen_ratio

    def _fit(self, nbrs: np.ndarray):
        return _fit_lines(nbrs, self.min_eigen_ratio)

    def rows(self, query: np.ndarray, reach_m: float | None = None) -> MatchRows:
        """Point-to-line rows (two per match) for ``query`` points (target frame), as
        :meth:`PlaneMap.rows`."""
        rows, idx = self.nearest_fitted(query, reach_m)
        return line_rows_from_directions(rows, np.take(self._a, idx, axis=0), np.take(self._b, idx, axis=0))


def _rotation_and_derivatives(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R = Rz(yaw) Ry(pitch) Rx(roll) of ``x`` (3, 3) and dR/d(roll, pitch, yaw) (3, 3, 3), written
    out from one set of sines and cosines (scipy's ``Rotation`` and the products of the elementary
    matrices cost several times more per call, and the solver needs both every iteration; they
    agree to rounding)."""
    cr, sr = math.cos(x[3]), math.sin(x[3])
    cp, sp = math.cos(x[4]), math.sin(x[4])
    cy, sy = math.cos(x[5]), math.sin(x[5])
    out = np.array(
        [
            [
                [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                [-sp, cp * sr, cp * cr],
            ],
            [
                [0.0, sy * sr + cy * sp * cr, sy * cr - cy * sp * sr],
                [0.0, sy * sp * cr - cy * sr, -cy * cr - sy * sp * sr],
                [0.0, cp * cr, -cp * sr],
            ],
            [
                [-cy * sp, cy * cp * sr, cy * cp * cr],
                [-sy * sp, sy * cp * sr, sy * cp * cr],
                [-cp, -sp * sr, -sp * cr],
            ],
            [
                [-sy * cp, -sy * sp * sr - cy * cr, cy * sr - sy * sp * cr],
                [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                [0.0, 0.0, 0.0],
            ],
        ]
    )
    return out[0], out[1:]


def _xyz_rpy(T: np.ndarray) -> np.ndarray:
    """(6,) ``[x, y, z, roll, pitch, yaw]`` of a 4x4 transform, the inverse of the rotation above,
    in closed form; within 1e-6 of gimbal lock (pitch +-90 deg) it leaves it to scipy."""
    R = T[:3, :3]
    if abs(R[2, 0]) > 1.0 - 1e-6:
        return xyz_rpy_from_pose(T)
    rpy = (math.atan2(R[2, 1], R[2, 2]), math.asin(-R[2, 0]), math.atan2(R[1, 0], R[0, 0]))
    return np.array([T[0, 3], T[1, 3], T[2, 3], *rpy])


def _pose(x: np.ndarray, R: np.ndarray) -> np.ndarray:
    """4x4 transform with rotation ``R`` and the translation ``x[:3]``."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = x[:3]
    return T


def observed_share(information: np.ndarray, prior_information: np.ndarray) -> np.ndarray:
    """(6,) per axis of ``[tx, ty, tz, roll, pitch, yaw]``, the share of the prior's variance the
    rows removed: ``1 - var_posterior / var_prior`` from the (6,6) rows' and prior's information
    (1: the data alone decides that axis, 0: it told nothing about it)."""
    prior_var = np.diag(np.linalg.inv(prior_information))
    posterior_var = np.diag(np.linalg.inv(information + prior_information))
    return np.clip(1.0 - posterior_var / prior_var, 0.0, 1.0)


def unobserved_directions(information: np.ndarray, reference_information: np.ndarray) -> tuple[int, np.ndarray]:
    """The directions of the pose the rows observe less well than a reference belief does.

    Solves ``information v = lambda reference_information v`` (both (n, n) over the same
    parameters, the reference positive definite): ``lambda`` is how many times the reference's
    information the rows hold along ``v``, in the reference's own units, so translations and
    rotations are compared without a lever arm and a direction counts by what the rows tell
    about it, not by how many rows there are.

    Returns ``(unobserved, projector)``: the number of directions with ``lambda < 1`` and the
    (n, n) projector that removes them from an update and keeps the observed ones (with the
    directions ``V`` normalised so that ``V^T reference V = I``, ``V diag(kept) V^T reference``;
    the identity when every direction is observed).
    """
    lower = np.linalg.cholesky(reference_information)
    lower_inv = np.linalg.inv(lower)
    whitened = lower_inv @ information @ lower_inv.T
    values, vectors = np.linalg.eigh(0.5 * (whitened + whitened.T))
    kept = values >= 1.0
    unobserved = int(np.count_nonzero(~kept))
    if not unobserved:
        return 0, np.eye(len(values))
    directions = lower_inv.T @ vectors
    return unobserved, directions @ np.diag(kept.astype(float)) @ directions.T @ reference_information


def _wrapped_difference(x: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``x - reference`` over ``[tx, ty, tz, roll, pitch, yaw]``, angles wrapped to [-pi, pi)."""
    d = x - reference
    d[3:] = (d[3:] + np.pi) % (2 * np.pi) - np.pi
    return d


def _jacobian(normal: np.ndarray, points: np.ndarray, dR: np.ndarray, level_normal_z: float) -> np.ndarray:
    """(K, 6) derivatives of the rows ``normal . (R p + t)`` over ``[tx, ty, tz, roll, pitch, yaw]``
    for (K, 3) unit normals and source points, with ``dR`` (3, 3, 3) from
    :func:`_rotation_and_derivatives`; rows as level as ``level_normal_z`` (> 0) inform only z,
    roll and pitch (see :func:`solve_pose`)."""
    J = np.empty((len(normal), 6))
    J[:, :3] = normal
    for a in range(3):
        J[:, 3 + a] = np.einsum("ij,ij->i", normal, points @ dR[a].T)
    if level_normal_z > 0:
        level = np.abs(normal[:, 2]) >= level_normal_z
        J[np.ix_(level, (0, 1, 5))] = 0.0
    return J


def _rows_along(matches: MatchRows, source: np.ndarray, x: np.ndarray, step: np.ndarray, level_normal_z: float):
    """(q, along) at the pose ``x``: the matched source points in the target frame (K, 3) and each
    row's derivative along the parameter step ``step`` (6,) (the Jacobian of :func:`solve_pose`,
    level rows informing only z, roll and pitch)."""
    R, dR = _rotation_and_derivatives(x)
    p = np.take(source, matches.source_index, axis=0)
    return p @ R.T + x[:3], _jacobian(matches.normal, p, dR, level_normal_z) @ step


def probe_return_share(
    T_target_source: np.ndarray,
    source: np.ndarray,
    find_matches: Callable[[np.ndarray, float | None], MatchRows],
    step: np.ndarray,
    kernel_m: float,
    robust_scale_m: float,
    level_normal_z: float = 0.0,
) -> float:
    """The share of the rows' information along a pose change ``step`` (6,) of ``[tx, ty, tz, roll,
    pitch, yaw]`` (m, rad: the probe's size, e.g. 0.25 m along one translation or 0.25 m over a
    point's lever as an angle) that the cost function really has near the pose ``T_target_source``
    (4, 4); ``source`` (N, 3) in the source frame, ``find_matches`` as in :func:`solve_pose`.

    The Gauss-Newton information ``J^T W J`` is the cost's curvature with the correspondences
    held fixed. Where the matches themselves are random (range noise on a flat wall passing the
    edge threshold: the lines fitted to such "edges" point anywhere in the wall), every fixed set
    of matches is curved, but the cost with correspondences found again is flat: the data would
    hold any pose. This tells the two apart by the basin the rows form: the pose is moved by
    ``+-step``, the matches are found again, and one Newton step along ``step`` says how far they
    pull it back. Each source point weighs as its rows did at the pose (Geman-McClure of
    ``robust_scale_m``, 0: LOAM's weight), and its rows after the move by a kernel of scale
    ``kernel_m`` (about twice the points' displacement). Rows on real structure pull the pose back
    the whole way (share 1); random matches pull it nowhere (share 0); a mix pulls back by the real
    rows' share of the information. The points must move more than the submap's point spacing so
    that the matches change. Rows as level as ``level_normal_z`` inform only z, roll and pitch (as
    in :func:`solve_pose`). Returns the mean of the two sides, in [0, 1]; 1 when there is nothing to
    probe.
    """
    x0 = _xyz_rpy(T_target_source)
    R0 = T_target_source[:3, :3]
    at_pose = find_matches(source @ R0.T + T_target_source[:3, 3], None)
    if len(at_pose) == 0:
        return 1.0
    q0 = np.take(source, at_pose.source_index, axis=0) @ R0.T + T_target_source[:3, 3]
    residual0 = np.einsum("ij,ij->i", at_pose.normal, q0) + at_pose.offset
    if robust_scale_m > 0:
        row_weight = (robust_scale_m**2 / (robust_scale_m**2 + residual0**2)) ** 2
    else:
        row_weight = np.clip(1.0 - 0.9 * np.abs(residual0), 0.0, None) ** 2
    point_weight = np.zeros(len(source))
    point_weight[at_pose.source_index] = 1.0
    np.minimum.at(point_weight, at_pose.source_index, row_weight)
    c2 = kernel_m**2
    shares = []
    for sign in (1.0, -1.0):
        x = x0 + sign * step
        R = _rotation_and_derivatives(x)[0]
        matches = find_matches(source @ R.T + x[:3], None)
        if len(matches) == 0:
            return 1.0
        q, along = _rows_along(matches, source, x, step, level_normal_z)
        residual = np.einsum("ij,ij->i", matches.normal, q) + matches.offset
        weight = point_weight[matches.source_index] * (c2 / (c2 + residual**2)) ** 2
        curvature = float(weight @ along**2)
        if curvature <= 0.0:
            return 1.0
        # One Newton step along the probe (in units of the step): -g / H; a full return is -sign.
        shares.append(-float((weight * along) @ residual) / curvature / -sign)
    return float(np.clip(np.mean(shares), 0.0, 1.0))


def solve_pose(
    T_init: np.ndarray,
    source: np.ndarray,
    find_matches: Callable[[np.ndarray, float | None], MatchRows],
    *,
    free_axes: tuple[int, ...] = ALL_AXES,
    max_iterations: int = 10,
    rematch_every: int = 1,
    min_rows: int = 50,
    degeneracy_threshold: float = 100.0,
    converge_rotation_deg: float = 0.05,
    converge_translation_m: float = 0.0005,
    robust_scale_m: float = 0.0,
    row_weights: np.ndarray | None = None,
    level_normal_z: float = 0.0,
    prior: PosePrior | None = None,
    min_residual_sigma_m: float = 0.01,
    initial_scale_m: float = 0.0,
    data_scaling: np.ndarray | None = None,
    anneal: bool = True,
    reference_information: np.ndarray | None = None,
    turn: SweepTurn | None = None,
) -> SolveResult:
    """Estimate ``T_target_source`` minimising the matched rows' residuals.

    Args:
        T_init: (4,4) initial guess.
        source: (N,3) source points in the source frame.
        find_matches: given the source points transformed into the target frame with the current
            estimate and a reach (m, or None for the matcher's own), returns the residual rows
            (called every ``rematch_every`` iterations). The reach is the robust kernel's support
            (three scales) while that is wider than the matcher's radius.
        free_axes: indices into [tx, ty, tz, roll, pitch, yaw] that may change.
        robust_scale_m: 0 for LOAM's weight s = 1 - 0.9 |r| (rows with s <= 0.1 dropped); a
            positive value c selects the Geman-McClure kernel with scale c, whose rows with
            weight <= 0.1 (|r| > 3c) are dropped.
        row_weights: optional (N,) per-source-point multiplier of the robust weight.
        level_normal_z: rows whose unit normal has ``|n_z|`` at or above this (level ground,
            roofs) inform only z, roll and pitch: their x, y and yaw derivatives are dropped.
            A level plane carries no information on those axes, but the small random tilts of
            planes fitted to noisy scan lines turn thousands of ground rows into confident,
            spurious x/y/yaw constraints that outvote a few real ones (a pole on open ground)
            and that the eigenvalue test cannot flag. 0 disables it.
        prior: optional Gaussian prior on the pose; with it the estimate is the maximum a
            posteriori pose (rows and prior together) and nothing is projected out.
        min_residual_sigma_m: lower bound of the residual standard deviation that scales the
            rows' information (a near-perfect fit must not make the rows infinitely certain).
        initial_scale_m: with the Geman-McClure kernel, its scale at the first iteration when
            that is wider than ``4 * robust_scale_m`` (how far the points may be off at the start,
            e.g. from a prior's uncertainty); it halves every iteration down to the scale.
        data_scaling: (6, 6) ``M`` applied to the rows' Jacobian (``J M``): the rows' information
            becomes ``M^T H M`` (:func:`~lidar3d.mapping.scan_to_map.register_to_submap` scales
            a direction whose information the cost does not hold, see :func:`probe_return_share`).
        anneal: False starts the Geman-McClure kernel at its final scale (a warm start).
        reference_information: (6, 6) the belief a direction is judged against: the rows leave a
            direction unobserved when they know it less well than this
            (:func:`unobserved_directions`; at the first iteration for the projection, at the
            last for ``degenerate_axes``); None selects the eigenvalue test with
            ``degeneracy_threshold``.
        turn: the sweep's yaw rate solved for beside the pose (:class:`SweepTurn`; only with a
            ``prior``); the rows' ``information`` is then the pose's with the rate marginalised.

    Returns a :class:`SolveResult`; when there are fewer than ``min_rows`` rows on the first
    iteration, the initial guess is returned with ``iterations == 0``.
    """
    x = _xyz_rpy(T_init)
    free = np.asarray(free_axes, dtype=np.int64)
    x_prior = None if prior is None else _xyz_rpy(prior.T_target_source)
    prior_information = None if prior is None else prior.information[np.ix_(free, free)]
    reference = None if reference_information is None else reference_information[np.ix_(free, free)]
    projector = None
    degenerate = 0
    min_eig = float("nan")
    information = np.zeros((6, 6))
    sigma_m = float("nan")
    matches = MatchRows.empty()
    converged = False
    iteration = 0
    n_rows = 0
    k = len(free)
    turning = turn if prior is not None else None  # None once the rate is not solved for
    rate_rad_s = 0.0
    while iteration < max_iterations:
        R, dR = _rotation_and_derivatives(x)  # (3,3), (3,3,3)
        T = _pose(x, R)
        q_all = None
        # Geman-McClure scale: it starts wide and halves each iteration down to robust_scale_m,
        # so a poor initial guess still finds rows while the final estimate ignores off-surface
        # matches.
        scale_m = (
            max(robust_scale_m, max(4.0 * robust_scale_m, initial_scale_m) * 0.5**iteration)
            if anneal
            else robust_scale_m
        )
        points = turning.turned(source, rate_rad_s) if turning is not None else source
        if iteration % rematch_every == 0:
            q_all = points @ T[:3, :3].T + T[:3, 3]
            matches = find_matches(q_all, 3.0 * scale_m if robust_scale_m > 0 else None)
        if len(matches) < min_rows:
            if iteration == 0:
                return SolveResult(T_init.copy(), 0, False, len(matches), 0, min_eig)
            break
        # np.take gathers rows 5x faster than fancy indexing
        p = np.take(points, matches.source_index, axis=0)
        q = p @ T[:3, :3].T + T[:3, 3] if q_all is None else np.take(q_all, matches.source_index, axis=0)
        residual = np.einsum("ij,ij->i", matches.normal, q) + matches.offset
        if robust_scale_m > 0:
            # Geman-McClure: IRLS weight (c^2 / (c^2 + r^2))^2, rows scaled by its square root.
            c2 = scale_m**2
            weight = c2 / (c2 + residual**2)
        else:
            weight = 1.0 - 0.9 * np.abs(residual)
        if row_weights is not None:
            weight = weight * row_weights[matches.source_index]
        use = np.flatnonzero(weight > 0.1)
        n_rows = int(use.size)
        if n_rows < min_rows:
            if iteration == 0:
                return SolveResult(T_init.copy(), 0, False, n_rows, 0, min_eig)
            break
        n = np.take(matches.normal, use, axis=0)
        J = _jacobian(n, np.take(p, use, axis=0), dR, level_normal_z)
        w = weight[use]
        Jf = J[:, free] * w[:, None]
        if data_scaling is not None:
            Jf = Jf @ data_scaling[np.ix_(free, free)]
        if turning is not None:
            rate_column = turning.column(n, np.take(p, use, axis=0), np.take(matches.source_index, use), R)
            if level_normal_z > 0:
                rate_column[np.abs(n[:, 2]) >= level_normal_z] = 0.0  # level rows hold no yaw
            Jf = np.column_stack([Jf, rate_column * w])
        rf = residual[use] * w
        H_all = Jf.T @ Jf
        g_all = Jf.T @ rf
        sigma_m = max(float(np.sqrt(rf @ rf / (w @ w))), min_residual_sigma_m)
        H, g = H_all[:k, :k], g_all[:k]
        information[np.ix_(free, free)] = H / sigma_m**2
        if iteration == 0:
            vals, vecs = np.linalg.eigh(H)
            min_eig = float(vals[0])
            if reference is not None:
                degenerate, reference_projector = unobserved_directions(information[np.ix_(free, free)], reference)
                if degenerate and prior is None:
                    projector = reference_projector
            else:
                keep = vals >= degeneracy_threshold
                degenerate = int((~keep).sum())
                if degenerate and prior is None:
                    projector = vecs @ np.diag(keep.astype(float)) @ vecs.T
            if turning is not None:
                # The rate is solved for only in a scan that observes every direction of its pose
                # and knows the rate better than the vehicle model does (its information with the
                # pose unknown above the prior's: the test of unobserved_directions); elsewhere it
                # keeps the prediction (on open land the rows' claim on it is not to be trusted).
                coupling = H_all[:k, k]
                rate_information = H_all[k, k] - coupling @ np.linalg.solve(H + 1e-9 * np.eye(k), coupling)
                if degenerate or rate_information / sigma_m**2 < turning.information:
                    turning = None
        if turning is not None:
            # The pose's information with the rate unknown (its prior included): the Schur complement.
            coupling = H_all[:k, k]
            H = H - np.outer(coupling, coupling) / (H_all[k, k] + turning.information * sigma_m**2)
            information[np.ix_(free, free)] = H / sigma_m**2
        rate_step_deg = 0.0
        if prior_information is not None and x_prior is not None:
            # Maximum a posteriori step: rows and prior, each weighted by its information.
            if turning is not None:
                A = H_all / sigma_m**2
                A[:k, :k] += prior_information
                A[k, k] += turning.information
                b = g_all / sigma_m**2
                b[:k] += prior_information @ _wrapped_difference(x, x_prior)[free]
                b[k] += turning.information * rate_rad_s
            else:
                A = H / sigma_m**2 + prior_information
                b = g / sigma_m**2 + prior_information @ _wrapped_difference(x, x_prior)[free]
        else:
            A, b = H, g
        try:
            step = -np.linalg.solve(A + 1e-9 * np.eye(len(b)), b)
        except np.linalg.LinAlgError:
            break
        dx = step[:k]
        if turning is not None:
            rate_rad_s += float(step[k])
            rate_step_deg = np.rad2deg(abs(float(step[k])) * float(np.max(np.abs(turning.time_s), initial=0.0)))
        if projector is not None:
            dx = projector @ dx
        x[free] += dx
        full = np.zeros(6)
        full[free] = dx
        annealing = robust_scale_m > 0 and scale_m > robust_scale_m
        if (
            not annealing
            and np.rad2deg(np.linalg.norm(full[3:])) < converge_rotation_deg
            and rate_step_deg < converge_rotation_deg
            and np.linalg.norm(full[:3]) < converge_translation_m
        ):
            converged = True
            iteration += 1
            break
        iteration += 1
    if rate_rad_s and turning is not None:
        # Keep the rate only where the rows tell it from the prediction (|w| above min_sigmas of its
        # posterior sigma); otherwise the pose with the rate held at the prediction, to first
        # order from the joint solution (x + A_pp^-1 A_pr w), and the pose-only information.
        coupling = A[:k, k]
        moved = np.linalg.solve(A[:k, :k] + 1e-9 * np.eye(k), coupling)
        rate_variance = 1.0 / max(float(A[k, k] - coupling @ moved), 1e-12)
        if abs(rate_rad_s) < turning.min_sigmas * math.sqrt(rate_variance):
            x[free] += moved * rate_rad_s
            rate_rad_s = 0.0
            information[np.ix_(free, free)] = H_all[:k, :k] / sigma_m**2
    if reference is not None:
        degenerate = unobserved_directions(information[np.ix_(free, free)], reference)[0]
    return SolveResult(
        _pose(x, _rotation_and_derivatives(x)[0]),
        iteration,
        converged,
        n_rows,
        degenerate,
        min_eig,
        information,
        sigma_m,
        matches=matches,
        yaw_rate_correction_rad_s=rate_rad_s,
    )
