"""Keyframe pose graph solved incrementally with iSAM2 — the only module that imports GTSAM.

Variables: one ``Pose3`` per keyframe, key ``X(k)`` = ``gtsam.symbol('x', k)``, value
``T_world_lidar`` of keyframe ``k``. Factors (LeGO-LOAM ``saveKeyFramesAndFactor`` /
``performLoopClosure``):

* a prior on keyframe 0 at its given pose (sigmas 1e-4 rad / 1e-4 m: it only fixes the gauge);
* an odometry ``BetweenFactor(X(k-1), X(k), T_prev_curr)`` per new keyframe, diagonal noise;
* a loop ``BetweenFactor(X(match), X(query), T_match_query)`` per accepted closure, Gaussian noise
  from the given 6x6 information behind a **Huber** kernel (``noiseModel.Robust.Create(
  mEstimator.Huber.Create(k), Gaussian.Information(Λ))``), so that a wrong closure costs only
  linearly once its whitened error exceeds ``k``.

**Noise order and units.** GTSAM's ``Pose3`` tangent is ``(ωx, ωy, ωz, vx, vy, vz)``: rotation
first (radians), then translation (metres), perturbation on the right (``T exp(ξ)``, body frame).
Every sigma vector and information matrix here uses that order; :func:`format_g2o` swaps the blocks
into g2o's translation-first order.

**Incremental solve.** New factors and new values are collected and handed to ``ISAM2.update``
exactly once, then cleared (DESIGN.md: iSAM2 gets only the new factors and values). After a loop,
``extra_updates`` more empty updates with forced relinearisation let the Huber weights settle
(LIO-SAM runs 5 extra updates after a loop or GPS factor). If GTSAM raises (e.g. an indeterminant
linear system), the error is logged, the new loop factors of that batch are retried one at a time
on a graph rebuilt from the factors already accepted, and every loop factor that still fails is
dropped; odometry is never dropped. iSAM2's incremental factorisation can find a well-posed graph
indeterminate after many relinearisations (`long` seed 1, at keyframe 459 of an odometry-only
update, with Cholesky; the solver factorises with QR now): the rebuilt solver factorises every
factor from scratch.

**GNSS position factors.** :func:`fuse_positions` solves a separate batch graph after a run: the
final keyframe chain as odometry factors plus ``GPSFactor`` s (position-only, on the keyframe's
lidar origin, Huber) chosen by :mod:`lidar3d.georef.gnss_factors` (LIO-SAM ``addGPSFactor``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

from lidar3d.mapping.se3 import nearest_rigid

if TYPE_CHECKING:
    import gtsam

__all__ = ["GraphEdge", "PoseGraph", "format_g2o", "fuse_positions"]

log = logging.getLogger(__name__)

_PRIOR_SIGMAS = np.array([1e-4, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4])


@dataclass(frozen=True, slots=True, eq=False)
class GraphEdge:
    """A relative-pose factor as kept for export.

    Attributes:
        source: keyframe index of the first variable (``match`` for loops, ``k-1`` for odometry).
        target: keyframe index of the second variable.
        T_source_target: (4,4) measured pose of ``target`` in ``source``'s frame.
        information: (6,6) information, GTSAM order (rot, trans).
        kind: ``"odometry"`` or ``"loop"``.
    """

    source: int
    target: int
    T_source_target: np.ndarray
    information: np.ndarray
    kind: str


def _symbol(k: int) -> int:
    import gtsam

    return gtsam.symbol("x", int(k))


def _check_pose(T: np.ndarray, name: str) -> np.ndarray:
    """A finite 4x4 transform with its rotation projected onto SO(3) (see
    :func:`lidar3d.mapping.se3.nearest_rigid`)."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise ValueError(f"{name} must be a finite (4,4) transform")
    return nearest_rigid(T)


def _check_sigmas(sigmas: np.ndarray) -> np.ndarray:
    """(6,) positive odometry sigmas, GTSAM order (rad x3, m x3), as float64."""
    sigmas = np.asarray(sigmas, dtype=np.float64)
    if sigmas.shape != (6,) or not (sigmas > 0).all():
        raise ValueError("sigmas must be six positive numbers (rot rad x3, trans m x3)")
    return sigmas


def _check_covariance(covariance: np.ndarray) -> np.ndarray:
    covariance = np.asarray(covariance, dtype=np.float64)
    if covariance.shape != (6, 6) or not np.isfinite(covariance).all():
        raise ValueError(f"step covariance must be a finite (6,6) matrix, got shape {covariance.shape}")
    if np.linalg.eigvalsh(0.5 * (covariance + covariance.T)).min() < 0.0:
        raise ValueError("step covariance must be positive semi-definite")
    return covariance


def _check_information(information: np.ndarray) -> np.ndarray:
    """A finite (6,6) information matrix, symmetrised, that must be positive definite."""
    information = np.asarray(information, dtype=np.float64)
    if information.shape != (6, 6) or not np.isfinite(information).all():
        raise ValueError("information must be a finite (6,6) matrix")
    information = 0.5 * (information + information.T)
    if np.linalg.eigvalsh(information).min() <= 0:
        raise ValueError("loop information must be positive definite")
    return information


# -- factors and noise models -------------------------------------------------------------------


def _prior_factor(T_world_lidar: np.ndarray) -> gtsam.NonlinearFactor:
    """The gauge prior on keyframe 0 at ``T_world_lidar`` (4,4), sigmas ``_PRIOR_SIGMAS``."""
    import gtsam

    key = _symbol(0)
    noise = gtsam.noiseModel.Diagonal.Sigmas(_PRIOR_SIGMAS)
    return gtsam.PriorFactorPose3(key, gtsam.Pose3(T_world_lidar), noise)


def _odometry_factor(
    index: int, T_prev_curr: np.ndarray, sigmas: np.ndarray, step_covariance: np.ndarray | None = None
) -> tuple[gtsam.NonlinearFactor, GraphEdge]:
    """``BetweenFactor(X(index-1), X(index), T_prev_curr)`` with noise ``diag(sigmas²)`` (GTSAM
    order) plus the (6,6) ``step_covariance`` when given, and its edge for export."""
    import gtsam

    key = _symbol(index)
    covariance = np.diag(sigmas**2)
    if step_covariance is not None:
        covariance = covariance + 0.5 * (step_covariance + step_covariance.T)
    noise = gtsam.noiseModel.Gaussian.Covariance(covariance)
    factor = gtsam.BetweenFactorPose3(_symbol(index - 1), key, gtsam.Pose3(T_prev_curr), noise)
    return factor, GraphEdge(index - 1, index, T_prev_curr, np.linalg.inv(covariance), "odometry")


def _loop_factor(
    query: int, match: int, T_match_query: np.ndarray, information: np.ndarray, huber_k: float
) -> tuple[gtsam.NonlinearFactor, GraphEdge]:
    """``BetweenFactor(X(match), X(query), T_match_query)`` with Gaussian noise of ``information``
    (6,6, GTSAM order) behind a Huber kernel of threshold ``huber_k`` sigmas, and its edge."""
    import gtsam

    noise = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(huber_k),
        gtsam.noiseModel.Gaussian.Information(information),
    )
    factor = gtsam.BetweenFactorPose3(_symbol(match), _symbol(query), gtsam.Pose3(T_match_query), noise)
    return factor, GraphEdge(int(match), int(query), T_match_query, information, "loop")


# -- iSAM2 plumbing -----------------------------------------------------------------------------


def _first_line(err: Exception) -> str:
    """The first non-empty line of an exception's message (GTSAM's run over a dozen lines)."""
    return next((line.strip() for line in str(err).splitlines() if line.strip()), type(err).__name__)


def _factor_graph(factors: Iterable[gtsam.NonlinearFactor] = ()):
    """A ``NonlinearFactorGraph`` holding ``factors`` in order."""
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    for factor in factors:
        graph.add(factor)
    return graph


def _values(poses: dict[int, np.ndarray]):
    """``gtsam.Values`` with ``Pose3(T)`` at ``X(k)`` for every ``k: T`` (4,4)."""
    import gtsam

    values = gtsam.Values()
    for k, T in poses.items():
        values.insert(_symbol(k), gtsam.Pose3(T))
    return values


class _Isam2:
    """An iSAM2 solver and every factor it has accepted, so that it can be rebuilt from them after
    a failed update. Keys are ``X(k)`` for keyframes ``k``; poses go in and out as (4,4) arrays."""

    def __init__(self, relinearize_threshold: float, relinearize_skip: int) -> None:
        self.relinearize_threshold = relinearize_threshold
        self.relinearize_skip = relinearize_skip
        self.isam = self._new_isam()
        self.accepted = _factor_graph()

    def _new_isam(self):
        import gtsam

        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(self.relinearize_threshold)
        params.relinearizeSkip = self.relinearize_skip
        # QR, not Cholesky: with the per-step covariances of the registration, Cholesky called
        # `long` seed 1's plain odometry chain indeterminate at keyframe 460 (batch Gauss-Newton
        # too), while QR and Levenberg-Marquardt solve it; QR costs ~10 ms more per loop update.
        params.setFactorization("QR")
        return gtsam.ISAM2(params)

    def accept(self, factors: Iterable[gtsam.NonlinearFactor]) -> None:
        """Record ``factors`` as held by the solver (after a successful update)."""
        for factor in factors:
            self.accepted.add(factor)

    def rebuild(self, factors: list[gtsam.NonlinearFactor], poses: dict[int, np.ndarray]) -> None:
        """A fresh iSAM2 holding the accepted factors plus ``factors`` (not yet accepted), with
        ``poses`` as the values."""
        graph = _factor_graph([self.accepted.at(i) for i in range(self.accepted.size())] + factors)
        self.isam = self._new_isam()
        self.isam.update(graph, _values(poses))

    def force_relinearize(self, times: int) -> None:
        """``times`` empty ``ISAM2.update`` calls with forced relinearisation."""
        import gtsam

        for _ in range(times):
            params = gtsam.ISAM2UpdateParams()
            params.force_relinearize = True
            self.isam.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), params)

    def estimates(self, n: int) -> dict[int, np.ndarray]:
        """Current estimate of every key ``X(0..n-1)`` the solver holds, as 4x4 arrays."""
        estimate = self.isam.calculateEstimate()
        return {k: estimate.atPose3(_symbol(k)).matrix() for k in range(n) if estimate.exists(_symbol(k))}

    def pose(self, k: int) -> np.ndarray:
        """Current (4,4) estimate of keyframe ``k``."""
        return self.isam.calculateEstimatePose3(_symbol(k)).matrix()

    def poses(self, n: int) -> np.ndarray:
        """Current (n,4,4) estimate of keyframes ``0..n-1``."""
        estimate = self.isam.calculateEstimate()
        return np.array([estimate.atPose3(_symbol(k)).matrix() for k in range(n)])


class PoseGraph:
    """Keyframe poses, odometry and loop factors, solved with iSAM2.

    Args:
        huber_k: Huber threshold in whitened units (sigmas) for loop factors; 1.345 is the usual
            95 %-efficiency choice, hdl_graph_slam uses 1.0.
        relinearize_threshold: iSAM2 relinearisation threshold on the tangent delta (LIO-SAM 0.1).
        relinearize_skip: relinearisation check every this many updates (LIO-SAM 1).
        extra_updates: empty iSAM2 updates after a batch containing loop factors (LIO-SAM 5).
    """

    def __init__(
        self,
        *,
        huber_k: float = 1.345,
        relinearize_threshold: float = 0.01,
        relinearize_skip: int = 1,
        extra_updates: int = 5,
    ) -> None:
        if huber_k <= 0:
            raise ValueError("huber_k must be positive")
        self.huber_k = float(huber_k)
        self.extra_updates = int(extra_updates)
        self.edges: list[GraphEdge] = []
        self.dropped_loops: list[tuple[int, int]] = []
        self._n = 0
        self._latest: dict[int, np.ndarray] = {}  # last estimate of recently added keys
        self._solver = _Isam2(float(relinearize_threshold), int(relinearize_skip))
        self._pending_factors: list[tuple[gtsam.NonlinearFactor, GraphEdge | None]] = []
        self._pending_values: dict[int, np.ndarray] = {}
        self._initial: dict[int, np.ndarray] = {}

    def __len__(self) -> int:
        return self._n

    @property
    def loop_edges(self) -> list[GraphEdge]:
        """Loop factors currently in the graph (dropped ones excluded)."""
        return [e for e in self.edges if e.kind == "loop"]

    # -- construction --------------------------------------------------------------------------

    def add_keyframe(
        self,
        index: int,
        T_world_lidar: np.ndarray,
        T_prev_curr: np.ndarray | None = None,
        sigmas: np.ndarray | None = None,
        step_covariance: np.ndarray | None = None,
    ) -> None:
        """Add keyframe ``index`` (must be ``len(self)``).

        Args:
            index: keyframe number, consecutive from 0.
            T_world_lidar: (4,4) pose estimate; the prior for keyframe 0, otherwise used only when
                no estimate of the previous keyframe is at hand.
            T_prev_curr: (4,4) odometry from keyframe ``index-1`` to this one; default
                ``inv(T_world_prev) @ T_world_lidar`` from the previous keyframe's given pose.
            sigmas: (6,) odometry sigmas, GTSAM order (rad ×3, m ×3). Required for ``index > 0``.
            step_covariance: optional (6,6) covariance of the step from the registration (GTSAM
                order), added to ``diag(sigmas²)``.
        """
        if index != self._n:
            raise ValueError(f"keyframes must be added in order: expected {self._n}, got {index}")
        T_world_lidar = _check_pose(T_world_lidar, "T_world_lidar")
        if index == 0:
            self._pending_factors.append((_prior_factor(T_world_lidar), None))
            initial = T_world_lidar
        else:
            if sigmas is None:
                raise ValueError("odometry sigmas are required for keyframes after the first")
            sigmas = _check_sigmas(sigmas)
            if T_prev_curr is None:
                T_prev_curr = np.linalg.solve(self._initial[index - 1], T_world_lidar)
            T_prev_curr = _check_pose(T_prev_curr, "T_prev_curr")
            if step_covariance is not None:
                step_covariance = _check_covariance(step_covariance)
            factor, edge = _odometry_factor(index, T_prev_curr, sigmas, step_covariance)
            self.edges.append(edge)
            self._pending_factors.append((factor, edge))
            previous = self._latest_estimate(index - 1)
            initial = previous @ T_prev_curr if previous is not None else T_world_lidar
        self._pending_values[index] = initial
        self._initial[index] = T_world_lidar
        self._n += 1

    def add_loop(self, query: int, match: int, T_match_query: np.ndarray, information: np.ndarray) -> None:
        """Queue a robust loop factor between existing keyframes ``match`` and ``query``.

        Args:
            query: newer keyframe.
            match: older keyframe.
            T_match_query: (4,4) measured pose of ``query`` in ``match``'s frame.
            information: (6,6) symmetric positive-definite information, GTSAM order (rot, trans).
        """
        for name, k in (("query", query), ("match", match)):
            if not 0 <= k < self._n:
                raise ValueError(f"loop {name} keyframe {k} is not in the graph ({self._n} keyframes)")
        if query == match:
            raise ValueError("a loop needs two different keyframes")
        T_match_query = _check_pose(T_match_query, "T_match_query")
        information = _check_information(information)
        factor, edge = _loop_factor(query, match, T_match_query, information, self.huber_k)
        self.edges.append(edge)
        self._pending_factors.append((factor, edge))

    # -- solving ---------------------------------------------------------------------------------

    def _isam_update(self, graph, values) -> None:
        """One ``ISAM2.update`` call (a seam for tests that simulate a GTSAM failure)."""
        self._solver.isam.update(graph, values)

    def update(self) -> list[tuple[int, int]]:
        """Hand the pending factors and values to iSAM2; returns the (query, match) loops dropped.

        Only the factors and values added since the last call are passed, then cleared.
        """
        if not self._pending_factors and not self._pending_values:
            return []
        factors, values = self._pending_factors, self._pending_values
        self._pending_factors, self._pending_values = [], {}
        has_loop = any(edge is not None and edge.kind == "loop" for _, edge in factors)
        snapshot = self._solver.estimates(self._n) if has_loop else {}
        graph = _factor_graph(factor for factor, _ in factors)
        try:
            self._isam_update(graph, _values(values))
        except RuntimeError as err:  # a well-posed graph found indeterminate: see the module docstring
            log.warning("pose graph: iSAM2 update failed (%s); rebuilding the solver", _first_line(err))
            if not has_loop:
                snapshot = self._estimates_after_failure()
            return self._recover(factors, values, snapshot)
        self._solver.accept(factor for factor, _ in factors)
        if has_loop:
            self._solver.force_relinearize(self.extra_updates)
        self._refresh_latest()
        return []

    def _recover(
        self, factors: list, values: dict[int, np.ndarray], snapshot: dict[int, np.ndarray]
    ) -> list[tuple[int, int]]:
        """Rebuild iSAM2 from the accepted factors plus the new odometry, then add loops singly."""
        odometry = [f for f, e in factors if e is None or e.kind != "loop"]
        loops = [(f, e) for f, e in factors if e is not None and e.kind == "loop"]
        estimate = {**self._initial, **snapshot, **values}
        every_key = {k: estimate[k] for k in range(self._n)}
        self._solver.rebuild(odometry, every_key)
        self._solver.accept(odometry)
        dropped = []
        for factor, edge in loops:
            try:
                self._isam_update(_factor_graph([factor]), _values({}))
            except RuntimeError as err:
                log.warning("pose graph: loop %d -> %d dropped: %s", edge.target, edge.source, _first_line(err))
                dropped.append((edge.target, edge.source))
                self.edges = [e for e in self.edges if e is not edge]
                self.dropped_loops.append((edge.target, edge.source))
                self._solver.rebuild([], every_key)
                continue
            self._solver.accept([factor])
        self._solver.force_relinearize(self.extra_updates)
        self._refresh_latest()
        return dropped

    def _estimates_after_failure(self) -> dict[int, np.ndarray]:
        """What the solver still holds after a failed update (a failed factorisation leaves its
        last estimate in place); nothing when it cannot even give that, so that the rebuild
        starts from the poses the keyframes were added with."""
        try:
            return self._solver.estimates(self._n)
        except RuntimeError:
            return {}

    def _refresh_latest(self) -> None:
        if self._n:
            last = self._n - 1
            self._latest = {last: self._solver.pose(last)}

    def _latest_estimate(self, k: int) -> np.ndarray | None:
        if k in self._pending_values:
            return self._pending_values[k]
        return self._latest.get(k)

    def optimize(self, extra_updates: int = 0) -> np.ndarray:
        """Flush pending factors, optionally relinearise more, and return the (K,4,4) estimate."""
        self.update()
        self._solver.force_relinearize(extra_updates)
        if self._n == 0:
            return np.zeros((0, 4, 4))
        poses = self._solver.poses(self._n)
        self._latest = {self._n - 1: poses[-1]}
        return poses

    def g2o_text(self, poses: np.ndarray | None = None) -> str:
        """The graph in g2o text (:func:`format_g2o`), vertices at ``poses`` (K,4,4) (default: the
        current estimate)."""
        poses = self.optimize() if poses is None else np.asarray(poses, dtype=np.float64)
        if poses.shape != (self._n, 4, 4):
            raise ValueError(f"expected ({self._n},4,4) poses, got {poses.shape}")
        return format_g2o(poses, self.edges)


# -- export ------------------------------------------------------------------------------------


def format_g2o(poses: np.ndarray, edges: list[GraphEdge]) -> str:
    """A pose graph in g2o text format (``VERTEX_SE3:QUAT``, ``EDGE_SE3:QUAT``, ``FIX 0``).

    Vertices carry ``poses`` (K,4,4), ``T_world_lidar`` of keyframe k. Edge information is written
    as the upper triangle of the 6x6 matrix in g2o's order (x, y, z, then rotation), i.e. the GTSAM
    blocks swapped, as GTSAM's own ``writeG2o`` does; the robust kernel of loop edges is not
    representable in the format and is omitted.
    """
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4):
        raise ValueError(f"expected (K,4,4) poses, got {poses.shape}")
    n = len(poses)
    if any(max(edge.source, edge.target) >= n for edge in edges):
        raise ValueError(f"an edge refers to a keyframe beyond the {n} poses")
    lines = []
    for k, T in enumerate(poses):
        lines.append(f"VERTEX_SE3:QUAT {k} " + " ".join(_pose_fields(T)))
    if n:
        lines.append("FIX 0")
    order = [3, 4, 5, 0, 1, 2]
    upper = np.triu_indices(6)
    for edge in edges:
        info = edge.information[np.ix_(order, order)][upper]
        lines.append(
            f"EDGE_SE3:QUAT {edge.source} {edge.target} "
            + " ".join(_pose_fields(edge.T_source_target))
            + " "
            + " ".join(f"{v:.9g}" for v in info)
        )
    return "\n".join(lines) + "\n"


def _pose_fields(T: np.ndarray) -> list[str]:
    """x y z qx qy qz qw of a 4x4 transform."""
    q = Rotation.from_matrix(T[:3, :3]).as_quat()  # (x, y, z, w)
    return [f"{v:.9f}" for v in T[:3, 3]] + [f"{v:.9f}" for v in q]


def fuse_positions(
    T_world_keyframes: np.ndarray,
    odometry_sigmas: np.ndarray,
    keyframe_index: np.ndarray,
    p_world_m: np.ndarray,
    sigma_m: np.ndarray,
    huber_k: float = 1.345,
) -> np.ndarray:
    """Keyframe poses moved onto position measurements: a batch solve of odometry + GNSS factors.

    The graph holds a ``BetweenFactor(X(k-1), X(k))`` per consecutive pair of ``T_world_keyframes``
    (their relative pose as the measurement; it carries the loop closures already applied) and a
    ``GPSFactor(X(k), p)`` per measurement (the keyframe origin, i.e. the lidar, at ``p``) with
    diagonal sigmas behind a Huber kernel of ``huber_k``. No prior: the measurements fix the gauge.
    Solved by Levenberg-Marquardt from the given poses.

    Args:
        T_world_keyframes: (K, 4, 4) initial keyframe poses (the frame of the measurements).
        odometry_sigmas: (K-1, 6) sigmas per odometry factor, GTSAM order (rad x3, m x3).
        keyframe_index: (F,) keyframe of each measurement (F >= 3).
        p_world_m: (F, 3) measured positions; ``sigma_m``: (F, 3) their standard deviations.

    Returns:
        (K, 4, 4) optimised poses.
    """
    import gtsam

    poses = np.asarray(T_world_keyframes, dtype=np.float64)
    index = np.asarray(keyframe_index, dtype=np.int64)
    points = np.asarray(p_world_m, dtype=np.float64).reshape(-1, 3)
    sigmas = np.asarray(sigma_m, dtype=np.float64).reshape(-1, 3)
    odometry = np.asarray(odometry_sigmas, dtype=np.float64)
    if poses.ndim != 3 or poses.shape[1:] != (4, 4) or odometry.shape != (len(poses) - 1, 6):
        raise ValueError("fuse_positions needs (K,4,4) poses and (K-1,6) odometry sigmas")
    if len(index) < 3 or points.shape != (len(index), 3) or sigmas.shape != points.shape:
        raise ValueError("fuse_positions needs at least 3 measurements, (F,3) positions and sigmas")
    if not (sigmas > 0).all() or index.min() < 0 or index.max() >= len(poses):
        raise ValueError("measurement sigmas must be positive and keyframe indices in range")
    graph = gtsam.NonlinearFactorGraph()
    for k in range(1, len(poses)):
        T_prev_curr = np.linalg.inv(poses[k - 1]) @ poses[k]
        graph.add(_odometry_factor(k, nearest_rigid(T_prev_curr), _check_sigmas(odometry[k - 1]))[0])
    huber = gtsam.noiseModel.mEstimator.Huber.Create(huber_k)
    for k, p, s in zip(index, points, sigmas):
        noise = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Diagonal.Sigmas(s))
        graph.add(gtsam.GPSFactor(_symbol(int(k)), gtsam.Point3(*p), noise))
    initial = _values({k: _check_pose(T, f"keyframe {k}") for k, T in enumerate(poses)})
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
    return np.array([result.atPose3(_symbol(k)).matrix() for k in range(len(poses))])
