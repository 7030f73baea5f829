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
from lidar3d.mapping.registration import MatchRows, SolveResult, solve_pose

__all__ = ["register_to_submap"]


def register_to_submap(
    target: SubmapTarget,
    corner_lidar: np.ndarray,
    surf_lidar: np.ndarray,
    T_world_lidar_guess: np.ndarray,
    config: MappingConfig,
    max_iterations: int | None = None,
    T_prior: np.ndarray | None = None,
    hold_yaw: bool = False,
) -> SolveResult:
    """Refine ``T_world_lidar`` of a scan whose features are given in its lidar frame.

    ``T_prior``: the pose to keep along degenerate directions (default: the guess);
    ``hold_yaw``: allow holding yaw at the prior's in badly degenerate scenes
    (``config.hold_yaw_min_degenerate``).
    """
    source = np.concatenate([corner_lidar, surf_lidar])
    n_corner = len(corner_lidar)

    def find_matches(q_world: np.ndarray) -> MatchRows:
        parts = []
        shifts = []
        if target.corners is not None and n_corner:
            parts.append(target.corners.rows(q_world[:n_corner]))
            shifts.append(0)
        if target.surfaces is not None and len(surf_lidar):
            parts.append(target.surfaces.rows(q_world[n_corner:]))
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
        T_prior=T_prior,
        hold_yaw_min_degenerate=config.hold_yaw_min_degenerate if hold_yaw else 0,
    )
