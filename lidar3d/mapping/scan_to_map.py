"""Scan-to-submap refinement: 6-DoF point-to-line and point-to-plane against the submap.

LeGO-LOAM mapOptmization.cpp 1093-1336: corners match lines and surfaces match planes fitted to
5 nearby submap points (see :class:`~lidar3d.mapping.registration.LineMap` and
:class:`~lidar3d.mapping.registration.PlaneMap`); at least 50 rows, Gauss-Newton with
degeneracy threshold 100.
"""

from __future__ import annotations

import numpy as np

from lidar3d.config import MappingConfig
from lidar3d.mapping.keyframes import SubmapTarget
from lidar3d.mapping.registration import MatchRows, PosePrior, SolveResult, solve_pose

__all__ = ["register_to_submap"]


def _median_range_m(points_lidar: np.ndarray) -> float:
    """Median distance of (N,3) points from the sensor (0 for none)."""
    return float(np.median(np.linalg.norm(points_lidar, axis=1))) if len(points_lidar) else 0.0


def register_to_submap(
    target: SubmapTarget,
    corner_lidar: np.ndarray,
    surf_lidar: np.ndarray,
    T_world_lidar_guess: np.ndarray,
    config: MappingConfig,
    max_iterations: int | None = None,
    prior: PosePrior | None = None,
) -> SolveResult:
    """Refine ``T_world_lidar`` of a scan whose features are given in its lidar frame.

    ``prior``: the motion model's belief about the pose; without one, directions the submap
    leaves degenerate keep the guess (LOAM's solution remapping). With one, the robust kernel
    and the correspondence search start as wide as the prior's uncertainty moves the corner
    points (one standard deviation at their median range), so a turn the prior did not expect
    is still matched.
    """
    source = np.concatenate([corner_lidar, surf_lidar])
    n_corner = len(corner_lidar)

    def find_matches(q_world: np.ndarray, reach_m: float | None) -> MatchRows:
        parts = []
        shifts = []
        if target.corners is not None and n_corner:
            parts.append(target.corners.rows(q_world[:n_corner], reach_m))
            shifts.append(0)
        if target.surfaces is not None and len(surf_lidar):
            parts.append(target.surfaces.rows(q_world[n_corner:], reach_m))
            shifts.append(n_corner)
        return MatchRows.concatenate(parts, shifts)

    return solve_pose(
        T_world_lidar_guess,
        source,
        find_matches,
        max_iterations=config.max_iterations if max_iterations is None else max_iterations,
        rematch_every=config.rematch_every,
        min_rows=config.min_rows,
        degeneracy_threshold=config.degeneracy_threshold,
        converge_rotation_deg=config.converge_rotation_deg,
        converge_translation_m=config.converge_translation_m,
        robust_scale_m=config.robust_scale_m,
        level_normal_z=config.level_normal_z,
        prior=prior,
        min_residual_sigma_m=config.min_residual_sigma_m,
        initial_scale_m=0.0 if prior is None else prior.displacement_sigma_m(_median_range_m(corner_lidar)),
    )
