"""Scan-to-submap refinement: 6-DoF point-to-line and point-to-plane against the submap.

LeGO-LOAM mapOptmization.cpp 1093-1336: corners match lines and surfaces match planes fitted to
5 nearby submap points (see :class:`~lidar3d.mapping.registration.LineMap` and
:class:`~lidar3d.mapping.registration.PlaneMap`); at least ``mapping.min_rows`` rows (120: LIO-SAM
maps a scan with more than 10 edge and 100 flat points), Gauss-Newton. LeGO-LOAM calls a
direction degenerate below a fixed eigenvalue of ``J^T J`` (100, a count of unit-normal rows);
here it is one the rows know less well than the vehicle model does over the scan interval
(:func:`~lidar3d.mapping.registration.unobserved_directions`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from lidar3d.config import MappingConfig
from lidar3d.mapping.keyframes import SubmapTarget
from lidar3d.mapping.registration import (
    MatchRows,
    PosePrior,
    SolveResult,
    SweepTurn,
    probe_return_share,
    solve_pose,
)
from lidar3d.mapping.sweep_tilt import SweepTilt, estimate_sweep_tilt

__all__ = ["register_again", "register_to_submap", "sweep_tilt_on_submap"]

Matcher = Callable[[np.ndarray, float | None], MatchRows]
"""``find_matches`` of :func:`solve_pose`: target-frame source points and a reach (m) -> rows."""


def _median_range_m(points_lidar: np.ndarray) -> float:
    """Median distance of (N,3) points from the sensor (0 for none)."""
    return float(np.median(np.linalg.norm(points_lidar, axis=1))) if len(points_lidar) else 0.0


def _solver_settings(config: MappingConfig, reference_information: np.ndarray) -> dict[str, Any]:
    """The keyword arguments of :func:`solve_pose` that every scan-to-submap registration takes
    from the ``[mapping]`` section, with the (6, 6) reference its directions are judged against."""
    return {
        "min_rows": config.min_rows,
        "reference_information": reference_information,
        "converge_rotation_deg": config.converge_rotation_deg,
        "converge_translation_m": config.converge_translation_m,
        "robust_scale_m": config.robust_scale_m,
        "level_normal_z": config.level_normal_z,
        "min_residual_sigma_m": config.min_residual_sigma_m,
    }


def register_to_submap(
    target: SubmapTarget,
    corner_lidar: np.ndarray,
    surf_lidar: np.ndarray,
    T_world_lidar_guess: np.ndarray,
    config: MappingConfig,
    max_iterations: int | None = None,
    prior: PosePrior | None = None,
    *,
    reference_information: np.ndarray,
    widen_search: bool = True,
    turn: SweepTurn | None = None,
) -> SolveResult:
    """Refine ``T_world_lidar`` of a scan whose features are given in its lidar frame.

    ``prior``: the belief about the pose before the rows (the motion model's, the odometry's
    heading); without one, directions the submap leaves degenerate keep the guess (LOAM's
    solution remapping). With one and ``widen_search``, the robust kernel and the correspondence
    search start as wide as the prior's uncertainty moves the corner points (one standard
    deviation at their median range), so a turn the prior did not expect is still matched;
    without ``widen_search`` they start at their final width (a prior that only keeps the guess
    where the rows are silent). ``reference_information``: (6, 6) the vehicle model's information
    over the scan interval; a direction the rows know less well than that is degenerate
    (``degenerate_axes``; without a prior it keeps the guess). ``turn``: the sweep's yaw rate
    solved for beside the pose (:class:`~lidar3d.mapping.registration.SweepTurn`, its times in
    the order corners then surfaces; only with a prior); the probe then moves the points as
    turned by the rate found, and a scan the probe finds degenerate keeps the predicted rate.
    """
    source = np.concatenate([corner_lidar, surf_lidar])
    find_matches = _matcher(target, len(corner_lidar), len(surf_lidar))
    settings = _solver_settings(config, reference_information)

    def solve(T_guess: np.ndarray, points: np.ndarray, matcher: Matcher, **options: Any) -> SolveResult:
        return solve_pose(
            T_guess, points, matcher, rematch_every=config.rematch_every, prior=prior, **settings, **options
        )

    result = solve(
        T_world_lidar_guess,
        source,
        find_matches,
        max_iterations=config.max_iterations if max_iterations is None else max_iterations,
        initial_scale_m=prior.displacement_sigma_m(_median_range_m(corner_lidar)) if prior and widen_search else 0.0,
        turn=turn,
    )
    if config.probe_shift_m <= 0 or result.iterations == 0:
        return result
    probed = corner_lidar, surf_lidar
    if turn is not None and result.yaw_rate_correction_rad_s:
        turned = turn.turned(source, result.yaw_rate_correction_rad_s)
        probed = turned[: len(corner_lidar)], turned[len(corner_lidar) :]
    stride = config.probe_point_stride
    probe_corner, probe_surf = probed[0][::stride], probed[1][::stride]
    probe = (np.concatenate([probe_corner, probe_surf]), _matcher(target, len(probe_corner), len(probe_surf)))
    return _solve_probed(result, source, find_matches, probe, config, solve)


def register_again(
    matches: MatchRows,
    source_lidar: np.ndarray,
    T_world_lidar_guess: np.ndarray,
    config: MappingConfig,
    *,
    reference_information: np.ndarray,
) -> SolveResult:
    """A registration by :func:`register_to_submap` done again once its (N,3) source points are
    deskewed with a better motion (they move by a few centimetres, in the same order): the
    correspondences it ended with (``matches``, world frame) are held, so nothing is searched in
    the submap, and the pose is solved again from ``T_world_lidar_guess`` (4,4) for at most
    ``config.redeskew_iterations``, the robust kernel annealed from four times its scale (started
    at its final scale, the rows the old deskewing had put farther off than that were rejected
    instead of pulling: ``loop`` seed 0 0.0136 -> 0.0186 m ATE). The basin is not probed again
    (only a sweep the first registration found fully constrained is registered again). The caller
    makes sure the submap has not changed under ``matches`` since. No prior: directions the rows
    know less well than ``reference_information`` (6,6) keep the guess and count in
    ``degenerate_axes``."""
    return solve_pose(
        T_world_lidar_guess,
        source_lidar,
        lambda _q_world, _reach_m: matches,
        max_iterations=config.redeskew_iterations,
        rematch_every=config.redeskew_iterations,
        **_solver_settings(config, reference_information),
    )


def sweep_tilt_on_submap(
    target: SubmapTarget,
    corner: tuple[np.ndarray, np.ndarray],
    surf: tuple[np.ndarray, np.ndarray],
    T_world_lidar: np.ndarray,
    config: MappingConfig,
    prior_sigma_rad: float,
) -> SweepTilt | None:
    """The roll and pitch of a sweep registered at ``T_world_lidar`` beyond its constant twist
    (:func:`~lidar3d.mapping.sweep_tilt.estimate_sweep_tilt`), from its rows against the submap:
    ``corner`` and ``surf`` are (N, 3) deskewed points in the lidar frame and (N,) their times
    (s from the stamp); knots every ``config.tilt_knot_spacing_s``, each with the prior
    ``prior_sigma_rad``. None when off (spacing 0) or too few rows."""
    points = np.concatenate([corner[0], surf[0]])
    return estimate_sweep_tilt(
        T_world_lidar,
        points,
        np.concatenate([corner[1], surf[1]]),
        _matcher(target, len(corner[0]), len(surf[0])),
        knot_spacing_s=config.tilt_knot_spacing_s,
        prior_sigma_rad=prior_sigma_rad,
        robust_scale_m=config.robust_scale_m,
        min_rows=config.min_rows,
    )


def _matcher(target: SubmapTarget, n_corner: int, n_surf: int) -> Matcher:
    """``find_matches`` of :func:`solve_pose` for a source of ``n_corner`` corner points (lines in
    the submap) followed by ``n_surf`` surface points (planes)."""

    def find_matches(q_world: np.ndarray, reach_m: float | None) -> MatchRows:
        parts = []
        shifts = []
        if target.corners is not None and n_corner:
            parts.append(target.corners.rows(q_world[:n_corner], reach_m))
            shifts.append(0)
        if target.surfaces is not None and n_surf:
            parts.append(target.surfaces.rows(q_world[n_corner:], reach_m))
            shifts.append(n_corner)
        return MatchRows.concatenate(parts, shifts)

    return find_matches


def _solve_probed(
    result: SolveResult,
    source: np.ndarray,
    find_matches: Matcher,
    probe: tuple[np.ndarray, Matcher],
    config: MappingConfig,
    solve: Callable[..., SolveResult],
) -> SolveResult:
    """``result`` checked along the rows' weakest translation (:func:`probe_return_share`). When its
    rows pull a moved pose back by less than ``probe_observed_share`` of the move, the cost does not
    hold that direction, whatever the rows' information claims: it is degenerate, so the rows'
    Jacobian loses it (LOAM's solution remapping, with the basin as the test instead of an
    eigenvalue) and the pose is solved again from ``result`` (a warm start): with a prior that
    direction is the prior's, without one it keeps the guess. ``solve``: :func:`solve_pose` with
    the registration's settings. ``probe``: the (M, 3) source points the probe moves (every
    ``probe_point_stride``-th corner and surface point, turned by the yaw rate ``result`` found)
    and their matcher. The second solve keeps the predicted rate (a scan with a degenerate
    direction does not solve for it): ``source`` is as deskewed with the prediction."""
    direction = np.zeros(6)
    direction[:3] = np.linalg.eigh(result.information[:3, :3])[1][:, 0]
    share = probe_return_share(
        result.T_target_source,
        *probe,
        config.probe_shift_m * direction,
        2.0 * config.probe_shift_m,
        config.robust_scale_m,
        config.level_normal_z,
    )
    if share >= config.probe_observed_share:
        return dataclasses.replace(result, probe_return_share=share)
    again = solve(
        result.T_target_source,
        source,
        find_matches,
        max_iterations=config.probe_iterations,
        data_scaling=np.eye(6) - np.outer(direction, direction),
        anneal=False,
    )
    if again.iterations == 0:
        return dataclasses.replace(result, probe_return_share=share)
    return dataclasses.replace(again, probe_return_share=share, degenerate_axes=max(again.degenerate_axes, 1))
