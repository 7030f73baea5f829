"""Scan-to-scan odometry in LeGO-LOAM's two steps (featureAssociation.cpp 1270-1478, 1666-1695).

1. The current scan's flat ground features are matched point-to-plane against the previous
   scan's less-flat features; only z, roll and pitch are free.
2. The current scan's sharp edge features are matched point-to-line against the previous scan's
   less-sharp features; only x, y and yaw are free.

Both clouds are deskewed to their stamps beforehand, so ``T_prev_curr`` relates the lidar at the
previous stamp to the lidar at the current stamp. Correspondences use LOAM's ring-aware search
(:mod:`lidar3d.mapping.ring_matching`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from lidar3d.features.records import FeatureSet
from lidar3d.mapping.registration import _wrapped_difference, solve_pose
from lidar3d.mapping.ring_matching import RingIndexedCloud
from lidar3d.mapping.se3 import xyz_rpy_from_pose

__all__ = ["OdometryStep", "ScanToScanOdometry"]

PLANAR_AXES = (2, 3, 4)  # z, roll, pitch
EDGE_AXES = (0, 1, 5)  # x, y, yaw


@dataclass(frozen=True, slots=True)
class OdometryStep:
    """Result of one scan-to-scan update.

    Attributes:
        T_prev_curr: (4,4) motion from the previous scan's stamp to this one's.
        used_motion_model: True when features were too few and the guess was kept.
        planar_rows / edge_rows: residual rows used by each step.
        edge_observed: the edge step ran and none of x, y, yaw was degenerate (so the step is
            a measurement of the horizontal motion, not the motion-model guess carried along).
        edge_information: (6,6) the edge step's rows' information (``J^T W J / sigma^2`` over
            ``[tx, ty, tz, roll, pitch, yaw]``, free axes x, y, yaw); None when it did not run
            (always so when ``used_motion_model``).
        yaw_travel_rad: the yaw the edge step moved from its guess (wrapped to [-pi, pi)).
        xy_travel_m: (2,) the x, y the step moved from its guess (previous scan's frame), metres.
    """

    T_prev_curr: np.ndarray
    used_motion_model: bool
    planar_rows: int
    edge_rows: int
    edge_observed: bool = False
    edge_information: np.ndarray | None = None
    yaw_travel_rad: float = 0.0
    xy_travel_m: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def yaw_information(self, shortfall: float) -> float:
        """How much the step knows about its yaw (rad^-2): the inverse of the edge rows' yaw
        variance (marginalised over x and y) plus ``(shortfall * yaw_travel_rad)^2``. Gauss-Newton
        from a guess far off (the motion before a sharp turn, on ``blind_turn`` 3 deg a scan) can
        stop short in a flat stretch of the cost, by a share of the way that the rows' curvature at
        the end does not show. 0 when the edge step did not run or its rows hold no yaw."""
        if self.edge_information is None:
            return 0.0
        rows_information = _marginal_yaw_information(self.edge_information)
        if rows_information <= 0.0:
            return 0.0
        return 1.0 / (1.0 / rows_information + (shortfall * self.yaw_travel_rad) ** 2)

    def yaw_sigma_rad(self) -> float:
        """Standard deviation (rad) of the step's yaw as its edge rows give it (no shortfall); inf
        when it measured none (a kept guess has no edge information)."""
        information = self.yaw_information(0.0)
        return float(1.0 / np.sqrt(information)) if information > 0.0 else float(np.inf)

    def xy_covariance(self) -> np.ndarray | None:
        """(2,2) covariance (m^2) of the step's x, y (previous scan's frame) as its edge rows give
        it, marginalised over the yaw; None when the edge step did not observe all of x, y, yaw
        (a kept guess has no edge information)."""
        if self.edge_information is None or not self.edge_observed:
            return None
        free = list(EDGE_AXES)
        try:
            covariance = np.linalg.inv(self.edge_information[np.ix_(free, free)])
        except np.linalg.LinAlgError:  # singular to machine precision despite the eigenvalue test
            return None
        return covariance[:2, :2]


class ScanToScanOdometry:
    """Keeps the previous scan's less-sharp and less-flat clouds and matches the next one."""

    def __init__(
        self,
        *,
        n_rings: int,
        max_iterations: int = 25,
        rematch_every: int = 5,
        min_rows: int = 10,
        degeneracy_threshold: float = 10.0,
        search_radius_m: float = 5.0,
        min_previous_edges: int = 10,
        min_previous_planes: int = 100,
    ) -> None:
        self.n_rings = n_rings
        self.max_iterations = max_iterations
        self.rematch_every = rematch_every
        self.min_rows = min_rows
        self.degeneracy_threshold = degeneracy_threshold
        self.search_radius_m = search_radius_m
        self.min_previous_edges = min_previous_edges
        self.min_previous_planes = min_previous_planes
        self._prev_edges: RingIndexedCloud | None = None
        self._prev_planes: RingIndexedCloud | None = None

    def update(self, features: FeatureSet, T_prev_curr_guess: np.ndarray) -> OdometryStep:
        """Estimate the motion since the previous scan, then remember this scan."""
        step = OdometryStep(T_prev_curr_guess.copy(), True, 0, 0)
        edges, planes = self._prev_edges, self._prev_planes
        if (
            edges is not None
            and planes is not None
            and len(edges) >= self.min_previous_edges
            and len(planes) >= self.min_previous_planes
        ):
            step = self._match(features, T_prev_curr_guess, edges, planes)
        self._prev_edges = RingIndexedCloud(features.less_sharp.points, features.less_sharp.ring, self.n_rings)
        self._prev_planes = RingIndexedCloud(features.less_flat.points, features.less_flat.ring, self.n_rings)
        return step

    def _match(
        self,
        features: FeatureSet,
        T_guess: np.ndarray,
        edges: RingIndexedCloud,
        planes: RingIndexedCloud,
    ) -> OdometryStep:
        radius = self.search_radius_m
        solve = functools.partial(
            solve_pose,
            max_iterations=self.max_iterations,
            rematch_every=self.rematch_every,
            min_rows=self.min_rows,
            degeneracy_threshold=self.degeneracy_threshold,
            converge_rotation_deg=0.1,
            converge_translation_m=0.001,
        )
        planar = solve(
            T_guess, features.flat.points, lambda q, _reach: planes.match_planes(q, radius), free_axes=PLANAR_AXES
        )
        edge = solve(
            planar.T_target_source,
            features.sharp.points,
            lambda q, _reach: edges.match_lines(q, radius),
            free_axes=EDGE_AXES,
        )
        used_model = planar.iterations == 0 and edge.iterations == 0
        edge_observed = edge.iterations > 0 and edge.degenerate_axes == 0
        if edge.iterations == 0:
            return OdometryStep(edge.T_target_source, used_model, planar.n_rows, edge.n_rows, edge_observed)
        travel = _wrapped_difference(xyz_rpy_from_pose(edge.T_target_source), xyz_rpy_from_pose(T_guess))[5]
        return OdometryStep(
            edge.T_target_source,
            used_model,
            planar.n_rows,
            edge.n_rows,
            edge_observed,
            edge.information,
            float(travel),
            edge.T_target_source[:2, 3] - T_guess[:2, 3],
        )


def _marginal_yaw_information(information: np.ndarray) -> float:
    """The information (rad^-2) about the yaw alone in a (6,6) information over ``[tx, ty, tz, roll,
    pitch, yaw]`` whose free axes are x, y, yaw: the Schur complement over x and y (a pseudo-inverse,
    so a direction the rows do not hold, such as the along-track one in a corridor, takes nothing
    from the yaw)."""
    h_yaw = information[5, 5]
    cross = information[[0, 1], 5]
    h_xy = information[np.ix_([0, 1], [0, 1])]
    return max(float(h_yaw - cross @ np.linalg.pinv(h_xy) @ cross), 0.0)
