"""GNSS position factors for the keyframe pose graph (``lidar3d run --span LOG --gnss-factors``).

After the lidar run, the INS/GNSS solutions of the log become position factors on the keyframes
(LIO-SAM ``addGPSFactor``, hdl_graph_slam's xyz prior; ``shared/reference/gnss-and-metrics.md``
section 4), and the keyframe graph is solved again in batch (:func:`lidar3d.loop.pose_graph.fuse_positions`).
Choice of the epochs, in order:

1. **Status**: only INS solutions of an accepted status are in the reference (``gnss.accepted_ins_statuses``,
   default INS_SOLUTION_GOOD); a keyframe gets the lidar position of the reference interpolated at its
   stamp, p = T_enu_imu(t) . t_imu_lidar (the lever arm of the lidar handled by the INS attitude),
   when the reference interval around it is at most ``factor_max_gap_s`` long.
2. **Quality**: the reported horizontal standard deviation at most ``factor_max_std_m`` (LIO-SAM
   gates the variance at 2 m^2); the std used is at least ``factor_std_floor_m``.
3. **Hold-out**: with ``hold_out_period_s`` P > 0, only epochs in even periods (floor(t / P) even)
   are fused, so the odd ones can score the result.
4. **Spacing**: at least ``factor_spacing_m`` of path between fused epochs.
5. **Consistency with the odometry** (the jump test): between consecutive candidates p and b, the
   GNSS displacement and the lidar's (rotated into ENU by the initial georeference) must agree within
   ``gate_floor_m + gate_sigmas * sqrt(sigma_p^2 + sigma_b^2) + gate_drift_fraction * path(p, b)``.
   A step beyond that is a jump of the GNSS (its start, or its end when it jumps back): its
   disagreement is added to the track's offset, and candidates are fused only while the offset is
   within the same allowance. A jump of metres is therefore rejected for as long as it lasts, and
   logged with its size, while a slow drift of the lidar (a degenerate canyon, where the GNSS is the
   better of the two) never accumulates. After more than ``gate_reanchor_gap_m`` of path without a
   candidate (an outage) the offset is reset: the GNSS is trusted again. A jump already present at
   the first candidate, or starting exactly at the end of an outage, is not detected.

The odometry factors between consecutive keyframes have a std of ``odometry_sigma_m +
odometry_sigma_fraction * step`` and ``odometry_sigma_rad``; the graph's GNSS factors sit behind a
Huber kernel. Scan poses follow their keyframes' corrections (:func:`lidar3d.loop.closer.correct_scan_poses`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from lidar3d.config import GeorefConfig
from lidar3d.gnss.reference import InsReference
from lidar3d.loop.closer import correct_scan_poses
from lidar3d.loop.pose_graph import fuse_positions
from lidar3d.metrics.association import associate
from lidar3d.metrics.errors import EvaluationError
from lidar3d.records import Trajectory

__all__ = ["GnssFactorSelection", "GnssFusion", "fuse_gnss", "select_gnss_factors"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class GnssFactorSelection:
    """The GNSS epochs chosen as factors.

    Attributes:
        keyframe_index: (F,) keyframes that get a factor.
        stamps_ns: (F,) their stamps.
        p_enu_m: (F, 3) measured lidar positions in ENU.
        sigma_enu_m: (F, 3) their standard deviations (east, north, up), floored.
        candidates: keyframes with a reference solution in reach.
        rejected_quality, rejected_hold_out, rejected_spacing, rejected_consistency: counts per gate.
        rejections: one line per epoch refused by the consistency test.
    """

    keyframe_index: np.ndarray
    stamps_ns: np.ndarray
    p_enu_m: np.ndarray
    sigma_enu_m: np.ndarray
    candidates: int
    rejected_quality: int
    rejected_hold_out: int
    rejected_spacing: int
    rejected_consistency: int
    rejections: tuple[str, ...]

    def __len__(self) -> int:
        return int(len(self.keyframe_index))


def _allowed(config: GeorefConfig, sigma: np.ndarray, path_m: np.ndarray, a: int, b: int) -> float:
    """The disagreement allowed between the GNSS and the odometry from epoch a to epoch b, metres."""
    combined = float(np.sqrt(np.sum(sigma[a] ** 2 + sigma[b] ** 2)))
    return config.gate_floor_m + config.gate_sigmas * combined + config.gate_drift_fraction * abs(path_m[b] - path_m[a])


def select_gnss_factors(
    keyframes: Trajectory,
    reference: InsReference,
    T_imu_lidar: np.ndarray,
    T_enu_world: np.ndarray,
    config: GeorefConfig,
) -> GnssFactorSelection:
    """Choose and gate the GNSS epochs for the keyframes (module docstring, steps 1-5)."""
    from lidar3d.georef.georeference import held_out_mask

    empty = np.zeros(0, dtype=np.int64)
    try:
        pairs = associate(keyframes, reference.trajectory, config.factor_max_gap_s)
    except EvaluationError:
        return GnssFactorSelection(empty, empty, np.zeros((0, 3)), np.zeros((0, 3)), 0, 0, 0, 0, 0, ())
    index = pairs.estimate_index
    p_gnss = (pairs.T_world_reference @ T_imu_lidar)[:, :3, 3]
    std = reference.std_enu_m[pairs.reference_index]
    std = np.where(np.isfinite(std), std, config.factor_max_std_m)
    sigma = np.maximum(std, config.factor_std_floor_m)
    p_odom = pairs.T_world_estimate[:, :3, 3] @ T_enu_world[:3, :3].T
    steps = np.linalg.norm(np.diff(keyframes.positions_m, axis=0), axis=1)
    path_kf = np.concatenate([[0.0], np.cumsum(steps)])
    path_m = path_kf[index]

    quality = np.hypot(std[:, 0], std[:, 1]) <= config.factor_max_std_m
    hold = config.hold_out_period_s > 0.0
    in_use = held_out_mask(pairs.stamps_ns, config.hold_out_period_s) if hold else np.zeros(len(pairs), dtype=bool)
    candidates = np.flatnonzero(quality & ~in_use)
    accepted: list[int] = []
    rejections: list[str] = []
    n_spacing = 0
    offset = np.zeros(3)  # the GNSS track's displacement from the trusted one, summed over its jumps
    for position, b in enumerate(candidates.tolist()):
        if position:
            p = int(candidates[position - 1])
            innovation = (p_gnss[b] - p_gnss[p]) - (p_odom[b] - p_odom[p])
            gap_m = path_m[b] - path_m[p]
            if gap_m > config.gate_reanchor_gap_m:
                offset[:] = 0.0  # after an outage the GNSS is trusted again (the lidar may have drifted)
            elif np.linalg.norm(innovation) > _allowed(config, sigma, path_m, p, b):
                offset += innovation  # a step of the GNSS that the lidar did not make: a jump starts or ends
        allowed = _allowed(config, sigma, path_m, b, b)
        if np.linalg.norm(offset) > allowed:
            rejections.append(_rejection_line(pairs.stamps_ns[b], float(np.linalg.norm(offset)), allowed))
            continue
        if accepted and path_m[b] - path_m[accepted[-1]] < config.factor_spacing_m:
            n_spacing += 1
            continue
        accepted.append(b)
    for line in rejections[:10]:
        logger.warning("%s", line)
    if len(rejections) > 10:
        logger.warning("GNSS factor: %d more epochs rejected by the consistency test", len(rejections) - 10)
    take = np.array(accepted, dtype=np.int64)
    return GnssFactorSelection(
        keyframe_index=index[take],
        stamps_ns=pairs.stamps_ns[take],
        p_enu_m=p_gnss[take],
        sigma_enu_m=sigma[take],
        candidates=len(pairs),
        rejected_quality=int((~quality).sum()),
        rejected_hold_out=int((quality & in_use).sum()),
        rejected_spacing=n_spacing,
        rejected_consistency=len(rejections),
        rejections=tuple(rejections),
    )


def _rejection_line(stamp_ns: int, offset_m: float, allowed_m: float) -> str:
    stamp = f"{int(stamp_ns) // 1_000_000_000}.{int(stamp_ns) % 1_000_000_000 // 1_000_000:03d}"
    return (
        f"GNSS factor at {stamp} s rejected: the GNSS track jumped {offset_m:.2f} m away from the odometry's "
        f"(allowed {allowed_m:.2f} m)"
    )


@dataclass(frozen=True, slots=True)
class GnssFusion:
    """The result of :func:`fuse_gnss`.

    Attributes:
        trajectory: every scan pose after the fusion, in the SLAM world frame (the initial
            georeference's inverse applied, so every file of the run keeps one frame).
        keyframes: keyframe poses after the fusion, same frame.
        selection: the GNSS epochs fused.
    """

    trajectory: Trajectory
    keyframes: Trajectory
    selection: GnssFactorSelection


def fuse_gnss(
    trajectory: Trajectory,
    keyframes: Trajectory,
    reference: InsReference,
    T_imu_lidar: np.ndarray,
    T_enu_world: np.ndarray,
    config: GeorefConfig,
) -> GnssFusion:
    """Add the gated GNSS epochs to the keyframe graph, solve, and move every scan pose with its keyframes.

    ``T_enu_world`` is the initial georeference (from the lidar-only trajectory). With fewer than 3
    epochs fused the poses are returned unchanged (and a warning logged).
    """
    selection = select_gnss_factors(keyframes, reference, T_imu_lidar, T_enu_world, config)
    if len(selection) < 3:
        logger.warning(
            "GNSS factors: only %d usable epochs; the trajectory is left as the lidar made it", len(selection)
        )
        return GnssFusion(trajectory, keyframes, selection)
    T_enu_kf = T_enu_world @ keyframes.T_world_lidar
    steps = np.linalg.norm(np.diff(keyframes.positions_m, axis=0), axis=1)
    sigma_t = config.odometry_sigma_m + config.odometry_sigma_fraction * steps
    odometry_sigmas = np.column_stack(
        [np.full((len(steps), 3), config.odometry_sigma_rad), np.repeat(sigma_t[:, None], 3, 1)]
    )
    fused_enu = fuse_positions(
        T_enu_kf, odometry_sigmas, selection.keyframe_index, selection.p_enu_m, selection.sigma_enu_m
    )
    T_world_enu = np.linalg.inv(T_enu_world)
    fused_world = T_world_enu @ fused_enu
    poses = correct_scan_poses(
        trajectory.stamps_ns, trajectory.T_world_lidar, keyframes.stamps_ns, keyframes.T_world_lidar, fused_world
    )
    logger.info(
        "GNSS factors: %d fused of %d candidates (%d by quality, %d held out, %d by spacing, %d inconsistent)",
        len(selection),
        selection.candidates,
        selection.rejected_quality,
        selection.rejected_hold_out,
        selection.rejected_spacing,
        selection.rejected_consistency,
    )
    return GnssFusion(Trajectory(trajectory.stamps_ns, poses), Trajectory(keyframes.stamps_ns, fused_world), selection)
