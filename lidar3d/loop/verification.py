"""Geometric verification of a loop candidate: ICP of the query keyframe against a submap.

This is the only module of :mod:`lidar3d.loop` that touches small_gicp (koide3/small_gicp, MIT);
clouds and transforms cross its boundary as NumPy arrays.

Procedure (LeGO-LOAM ``performLoopClosure``, LIO-SAM ``performLoopClosure``, with the checks that
their users asked for, see ``shared/reference/lego-loam-and-peers.md`` §3 row 5):

1. **Target**: the match keyframe and its ``±submap_neighbours`` neighbours (LeGO-LOAM and LIO-SAM
   fuse ±25) are put into the match keyframe's frame with the current pose estimates, fused and
   voxel-downsampled (LeGO-LOAM: 0.4 m). **Source**: the query keyframe's cloud, downsampled alike.
2. **Registration**: small_gicp's generalized ICP or point-to-plane ICP (Levenberg-Marquardt,
   one thread), started from the current estimate ``T_match_query = inv(T_world_match) @
   T_world_query`` and run through a coarse-to-fine schedule of maximum correspondence distances
   (default 4, 2, 1, 0.5 m) so that 1-2 m of drift still falls inside the first basin.
   The query cloud is coarse-to-fine too: a stage reaching ``d`` metres registers it downsampled
   at ``icp_stage_voxel_share * d`` (default 0.5: 2, 1, 0.5 and 0.4 m voxels), so the early
   stages weigh the scene's large structure evenly instead of the dense returns near the sensor,
   and a guess 14 m off along a street that drifted still converges to the revisit (measured on
   `city_traffic` seed 2's revisit after the canyon, guesses 14 m off: all 26 registrations
   ended within 0.2 m / 1° of the truth, against 10 of 26 with the 0.4 m cloud in every stage,
   at 0.6x the CPU; docs/stages/loop-closure.md). Where that descent ends below the fitness
   gate, the guess's own basin is tried as well: the stages reaching no farther than
   ``max_correction_m`` from the guess, with the full cloud; the better fit counts (a keyframe
   entering a revisit, whose cloud is half new, can slide out of a right guess's basin in the
   coarse stages: 2.7 m on held-out `hilly_fast` seed 10).
   Each point's local shape comes from its ``icp_neighbours`` nearest neighbours (small_gicp
   searches k-nearest only and takes no normals from outside): for GICP the plane-like covariance
   ``V diag(1e-3, 1, 1) Vᵀ`` of both clouds (``V`` the eigenvectors of the neighbourhood's
   scatter, smallest first; Open3D's GICP builds the same from its normals), for point-to-plane
   the target normals. Convergence is checked by running the last stage once more: if that moves
   the result by more than 2 cm or 0.1°, ICP is declared not converged.
   Fitness, inlier RMSE and the correspondences are then computed here, as Open3D defines them
   (:func:`correspondences`), with lidar3d's own k-d tree, so the gates below do not depend on
   the ICP library.
3. **Acceptance**: enough points in both clouds (LIO-SAM: 300 source, 1000 target), fitness
   (fraction of source points with a correspondence at the final distance) at or above the
   threshold, inlier RMSE at or below it, voxel overlap ``|A ∩ B| / min(|A|, |B|)`` of the aligned
   clouds at or above it (KISS-SLAM: 0.4 at its voxel size), and an ICP correction no larger than the
   drift accumulated since the match keyframe can explain. Every outcome carries a reason. A
   registration that passes every gate but the last keeps its measurement and information: the
   loop closer holds it until a second closure confirms it (:class:`lidar3d.loop.consistency.HeldClosure`).

**Covariance of the loop measurement.** Point-to-point ICP linearised at the solution has the
Gauss-Newton information ``Σ_i A_iᵀ A_i / σ²`` with ``A_i = [-[p_i]ₓ, I₃]`` (``p_i`` the matched
query points in the query frame; rotation columns first, the tangent order of GTSAM's Pose3, right
perturbation ``T exp(ξ)``). This equals Open3D's ``get_information_matrix_from_point_clouds``
(which uses the target points and a left perturbation) after the adjoint change of frame
``Λ_right = Ad(T)ᵀ Λ_left Ad(T)``; a test checks the two against each other. Taken at face value it
is far too confident: thousands of correlated points with σ = the inlier RMSE give millimetre
sigmas, and a robust kernel cannot bound a factor that stiff. So the information is computed per
point (the mean ``Σ A_iᵀ A_i / n``, which keeps the *shape*: which directions the geometry pins and
which it leaves loose, e.g. along a corridor), scaled as if only ``information_points`` independent
correspondences at σ = max(inlier RMSE, 1 cm) were available, and then a floor
``diag(σ_rot_min², σ_trans_min²)`` is added to the covariance so that no direction is trusted
below the minimum sigmas. The result goes into the GTSAM factor behind a Huber kernel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar3d.loop.records import Verdict
from lidar3d.mapping.nearest import PointTree
from lidar3d.mapping.se3 import invert, nearest_rigid, transform_points
from lidar3d.mapping.voxel import voxel_downsample, voxel_keys

__all__ = [
    "LoopVerification",
    "build_match_cloud",
    "correspondences",
    "loop_information",
    "point_information",
    "pose_change",
    "verify_loop",
    "voxel_overlap",
]

_RMSE_FLOOR_M = 0.01  # σ never below 1 cm when the inlier RMSE scales the information
_CONVERGED_M = 0.02  # last-stage re-run may move the result at most this much ...
_CONVERGED_DEG = 0.1  # ... and this much rotation
# A stage ends when a step moves the estimate less than both (small_gicp's defaults are 1 mm and
# 0.1°; a step of 0.1° would already be as large as the re-run may move the result).
_EPSILON_M = 1e-4
_EPSILON_RAD = 1e-5
# lidar3d's names of the ICP variants -> small_gicp's registration_type.
_REGISTRATION_TYPES = {"gicp": "GICP", "point_to_plane": "PLANE_ICP"}


@dataclass(frozen=True, slots=True)
class LoopVerification:
    """Result of registering a query cloud against a match submap.

    Attributes:
        verdict: outcome (``Verdict.ACCEPTED`` or why not).
        reason: one line with the numbers behind the verdict.
        T_match_query: (4,4) ICP result (the initial guess when ICP did not run).
        fitness: share of the source points with a target point within the final correspondence
            distance, at ``T_match_query`` (NaN if ICP did not run).
        inlier_rmse_m: inlier RMSE at the final distance (NaN if ICP did not run).
        overlap: voxel overlap of the aligned clouds (NaN if ICP did not run).
        correction_m: ‖translation‖ of ``inv(T_guess) @ T_match_query``.
        correction_deg: rotation angle of the same.
        information: (6,6) information of ``T_match_query`` (GTSAM order: rot, trans), zero unless
            accepted or rejected only for a large correction.
        n_source: points in the source cloud after downsampling.
        n_target: points in the target cloud.
    """

    verdict: Verdict
    reason: str
    T_match_query: np.ndarray
    fitness: float
    inlier_rmse_m: float
    overlap: float
    correction_m: float
    correction_deg: float
    information: np.ndarray
    n_source: int
    n_target: int

    @property
    def accepted(self) -> bool:
        return self.verdict is Verdict.ACCEPTED


def build_match_cloud(
    clouds: list[np.ndarray],
    T_world_lidar: np.ndarray,
    match: int,
    members: np.ndarray,
    voxel_m: float,
) -> np.ndarray:
    """Fuse the clouds of keyframes ``members`` into the frame of keyframe ``match``.

    Args:
        clouds: per keyframe, an (N_k,3) cloud in its own lidar frame.
        T_world_lidar: (K,4,4) current keyframe poses.
        match: the keyframe whose frame the result is expressed in.
        members: keyframe indices to fuse (normally ``match`` and its neighbours).
        voxel_m: voxel size of the final downsampling (centroid per voxel).

    Returns:
        (M,3) float64 points in the match keyframe's frame.
    """
    T_match_world = invert(T_world_lidar[match])
    parts = [transform_points(T_match_world @ T_world_lidar[k], clouds[k]) for k in members if len(clouds[k])]
    if not parts:
        return np.zeros((0, 3))
    return voxel_downsample(np.concatenate(parts), voxel_m)


def point_information(points: np.ndarray) -> np.ndarray:
    """Sum over points of ``A_iᵀ A_i`` with ``A_i = [-[p_i]ₓ, I₃]`` (6x6, rotation block first).

    ``points`` (N,3) are in the frame whose right perturbation is estimated (the query frame).
    Closed form per point: ``[[|p|² I - p pᵀ, [p]ₓ], [-[p]ₓ, I]]`` (since ``[p]ₓᵀ = -[p]ₓ`` and
    ``[p]ₓᵀ [p]ₓ = |p|² I - p pᵀ``).
    """
    p = np.asarray(points, dtype=np.float64)
    n = len(p)
    info = np.zeros((6, 6))
    if n == 0:
        return info
    s = p.sum(axis=0)
    sq = np.einsum("ij,ij->", p, p)
    info[:3, :3] = sq * np.eye(3) - p.T @ p
    skew_s = np.array([[0.0, -s[2], s[1]], [s[2], 0.0, -s[0]], [-s[1], s[0], 0.0]])
    info[:3, 3:] = skew_s
    info[3:, :3] = -skew_s
    info[3:, 3:] = n * np.eye(3)
    return info


def loop_information(
    matched_points: np.ndarray,
    inlier_rmse_m: float,
    *,
    effective_points: int,
    min_sigma_rotation_rad: float,
    min_sigma_translation_m: float,
) -> np.ndarray:
    """Information (6x6, GTSAM order rot/trans) of a loop measurement; see the module docstring.

    ``Λ₀ = (Σ A_iᵀ A_i / n) · effective_points / max(rmse, 1 cm)²``, then
    ``Σ = Λ₀⁻¹ + diag(σ_rot_min² ×3, σ_trans_min² ×3)`` and the result is ``Σ⁻¹``.
    """
    n = len(matched_points)
    if n < 3:
        raise ValueError(f"need at least 3 matched points for a loop information matrix, got {n}")
    sigma = max(float(inlier_rmse_m), _RMSE_FLOOR_M)
    info0 = point_information(matched_points) / n * (effective_points / sigma**2)
    # The per-point information of a cloud that is not degenerate (not all points on one line
    # through the origin) is positive definite; a tiny ridge keeps the inverse defined otherwise.
    info0 += np.eye(6) * 1e-9 * np.trace(info0)
    covariance = np.linalg.inv(info0)
    floor = np.array([min_sigma_rotation_rad] * 3 + [min_sigma_translation_m] * 3) ** 2
    covariance = covariance + np.diag(floor)
    information = np.linalg.inv(covariance)
    return 0.5 * (information + information.T)


def correspondences(
    aligned_source: np.ndarray, target: np.ndarray | PointTree, max_distance_m: float
) -> tuple[np.ndarray, float]:
    """The source points with a target point closer than ``max_distance_m``, and their RMSE.

    Open3D's definitions (``GetRegistrationResultAndCorrespondences``): each source point is paired
    with its nearest target point if that lies within the distance; fitness is the paired share of
    the source points, inlier RMSE the root mean square of the paired distances (0 when none).

    Args:
        aligned_source: (N,3) source points already moved into the target's frame.
        target: (M,3) target points, M >= 1, or a :class:`PointTree` of them (built once for
            several calls).
        max_distance_m: the correspondence distance (m).

    Returns:
        ``(indices, inlier_rmse_m)``: (K,) int64 rows of ``aligned_source`` that are paired, and the
        RMSE (m) of their distances.
    """
    tree = target if isinstance(target, PointTree) else PointTree(target)
    distance_m, _ = tree.query(aligned_source, distance_upper_bound=max_distance_m)
    paired = np.flatnonzero(np.isfinite(distance_m))
    if paired.size == 0:
        return paired, 0.0
    return paired, float(np.sqrt(np.mean(distance_m[paired] ** 2)))


def voxel_overlap(points_a: np.ndarray, points_b: np.ndarray, voxel_m: float) -> float:
    """``|A ∩ B| / min(|A|, |B|)`` over occupied voxels (KISS-SLAM ``loop_closer.py``); 0 if empty."""
    if len(points_a) == 0 or len(points_b) == 0:
        return 0.0
    a = np.unique(voxel_keys(points_a, voxel_m))
    b = np.unique(voxel_keys(points_b, voxel_m))
    common = np.intersect1d(a, b, assume_unique=True).size
    return common / min(a.size, b.size)


def _rotation_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))))


def pose_change(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(translation m, rotation deg) of ``inv(T_a) @ T_b``."""
    delta = invert(T_a) @ T_b
    return float(np.linalg.norm(delta[:3, 3])), _rotation_deg(delta[:3, :3])


def _rejected(
    verdict: Verdict, reason: str, T: np.ndarray, n_source: int, n_target: int, /, **metrics: float
) -> LoopVerification:
    values = {
        "fitness": np.nan,
        "inlier_rmse_m": np.nan,
        "overlap": np.nan,
        "correction_m": np.nan,
        "correction_deg": np.nan,
    }
    values.update(metrics)
    return LoopVerification(
        verdict=verdict,
        reason=reason,
        T_match_query=np.array(T, dtype=np.float64),
        information=np.zeros((6, 6)),
        n_source=n_source,
        n_target=n_target,
        **values,
    )


def verify_loop(
    source_points: np.ndarray,
    target_points: np.ndarray,
    T_guess_match_query: np.ndarray,
    config,
    *,
    max_correction_m: float | None = None,
) -> LoopVerification:
    """Register ``source_points`` (query frame) onto ``target_points`` (match frame) and judge it.

    Args:
        source_points: (N,3) query keyframe cloud, query lidar frame (downsampled here at
            ``config.voxel_m``).
        target_points: (M,3) fused submap around the match keyframe, match frame (already
            downsampled, see :func:`build_match_cloud`).
        T_guess_match_query: (4,4) initial guess from the current pose estimates.
        config: a :class:`lidar3d.config.LoopConfig` (ICP schedule, thresholds, information).
        max_correction_m: largest accepted translation between guess and result; ``None`` uses
            ``config.max_correction_m``.

    Returns:
        The verification record; never raises on bad geometry (a rejection says why).
    """
    import small_gicp

    T_guess = np.asarray(T_guess_match_query, dtype=np.float64)
    if T_guess.shape != (4, 4):
        raise ValueError(f"T_guess_match_query must be (4,4), got {T_guess.shape}")
    source = voxel_downsample(np.asarray(source_points, dtype=np.float64), config.voxel_m)
    target = np.asarray(target_points, dtype=np.float64)
    n_source, n_target = len(source), len(target)
    if n_source < config.min_source_points or n_target < config.min_target_points:
        return _rejected(
            Verdict.TOO_FEW_POINTS,
            f"{n_source} source / {n_target} target points "
            f"(need {config.min_source_points} / {config.min_target_points})",
            T_guess,
            n_source,
            n_target,
        )
    if not (np.isfinite(source).all() and np.isfinite(target).all() and np.isfinite(T_guess).all()):
        return _rejected(Verdict.NOT_CONVERGED, "non-finite points or initial guess", T_guess, n_source, n_target)
    T_guess = nearest_rigid(T_guess)

    method = config.icp_method
    if method not in _REGISTRATION_TYPES:
        raise ValueError(f"unknown icp_method {method!r} (known: {', '.join(_REGISTRATION_TYPES)})")
    target_cloud = small_gicp.PointCloud(target)
    target_tree = small_gicp.KdTree(target_cloud)
    # Local shape from the k nearest neighbours (small_gicp has no radius search and no way to hand
    # it normals): GICP's plane-like covariances V diag(1e-3, 1, 1) Vᵀ on both clouds, as Open3D's
    # GICP builds them from its normals; point-to-plane's target normals.
    if method == "gicp":
        small_gicp.estimate_covariances(target_cloud, target_tree, num_neighbors=config.icp_neighbours)
    else:
        small_gicp.estimate_normals(target_cloud, target_tree, num_neighbors=config.icp_neighbours)
    source_clouds: dict[float, object] = {}

    def source_at(voxel: float):
        """The query cloud at ``voxel`` (the base cloud at ``voxel_m`` or where a coarser one
        would keep fewer than ``min_source_points``), with its GICP covariances."""
        voxel = max(config.voxel_m, voxel)
        if voxel not in source_clouds:
            points = source if voxel == config.voxel_m else voxel_downsample(source, voxel)
            if len(points) < config.min_source_points:
                return source_at(config.voxel_m)
            cloud = small_gicp.PointCloud(points)
            if method == "gicp":
                small_gicp.estimate_covariances(cloud, num_neighbors=config.icp_neighbours)
            source_clouds[voxel] = cloud
        return source_clouds[voxel]

    def run(distance: float, T: np.ndarray, voxel: float = 0.0):
        return small_gicp.align(
            target_cloud,
            source_at(voxel),
            target_tree,
            init_T_target_source=T,
            registration_type=_REGISTRATION_TYPES[method],
            max_correspondence_distance=distance,
            max_iterations=config.icp_max_iterations,
            rotation_epsilon=_EPSILON_RAD,
            translation_epsilon=_EPSILON_M,
        )

    def descend(distances: tuple[float, ...], share: float) -> tuple[np.ndarray | None, np.ndarray, float]:
        """The stages ``distances`` from the guess, each stage's query at ``share`` of its
        distance as voxel: the result (None when a stage lost its correspondences), and the full
        query cloud's points paired there at the final distance with their RMSE
        (:func:`correspondences`)."""
        T = T_guess.copy()
        for distance in distances:
            result = run(float(distance), T, share * float(distance))
            if result.num_inliers < 3 or not np.isfinite(result.T_target_source).all():
                return None, np.zeros(0, dtype=np.int64), 0.0
            T = nearest_rigid(np.array(result.T_target_source))
        return T, *correspondences(transform_points(T, source), fitness_tree, final_distance)

    fitness_tree = PointTree(target)  # the gates' own nearest neighbours, built once
    schedule = tuple(float(d) for d in config.icp_max_correspondence_m)
    final_distance = schedule[-1]
    found, matched_source, rmse = descend(schedule, config.icp_stage_voxel_share)
    if config.icp_stage_voxel_share > 0.0 and matched_source.size < config.min_fitness * n_source:
        # The coarse stages can leave the basin of a guess that was right where the query sees
        # much the match did not (a keyframe entering the revisit): the guess's own basin, the
        # stages reaching no farther than an unconfirmed correction may go, with the full cloud,
        # gets its chance; the better fit counts.
        near = tuple(d for d in schedule if d <= config.max_correction_m) or schedule[-1:]
        fine, fine_matched, fine_rmse = descend(near, 0.0)
        if fine_matched.size > matched_source.size:
            found, matched_source, rmse = fine, fine_matched, fine_rmse
    if found is None:
        return _rejected(
            Verdict.NOT_CONVERGED,
            f"ICP lost its correspondences (fewer than 3 within {final_distance:g} m or more)",
            T_guess,
            n_source,
            n_target,
        )
    T = found
    check = run(final_distance, T)
    moved_m, moved_deg = pose_change(T, np.array(check.T_target_source))
    correction_m, correction_deg = pose_change(T_guess, T)
    aligned = transform_points(T, source)
    fitness = matched_source.size / n_source
    overlap = voxel_overlap(aligned, target, config.overlap_voxel_m)
    metrics = {
        "fitness": fitness,
        "inlier_rmse_m": rmse,
        "overlap": overlap,
        "correction_m": correction_m,
        "correction_deg": correction_deg,
    }
    limit_m = config.max_correction_m if max_correction_m is None else max_correction_m
    if moved_m > _CONVERGED_M or moved_deg > _CONVERGED_DEG:
        return _rejected(
            Verdict.NOT_CONVERGED,
            f"ICP still moving: {moved_m:.3f} m / {moved_deg:.2f} deg in a last pass",
            T,
            n_source,
            n_target,
            **metrics,
        )
    sizes = (T, n_source, n_target)
    if fitness < config.min_fitness:
        return _rejected(Verdict.LOW_FITNESS, f"fitness {fitness:.3f} < {config.min_fitness:g}", *sizes, **metrics)
    if rmse > config.max_rmse_m:
        return _rejected(Verdict.HIGH_RMSE, f"inlier RMSE {rmse:.3f} m > {config.max_rmse_m:g} m", *sizes, **metrics)
    if overlap < config.min_overlap:
        return _rejected(Verdict.LOW_OVERLAP, f"overlap {overlap:.3f} < {config.min_overlap:g}", *sizes, **metrics)
    quality = f"fitness {fitness:.3f}, RMSE {rmse:.3f} m, overlap {overlap:.3f}"
    information = loop_information(
        source[matched_source],
        rmse,
        effective_points=config.information_points,
        min_sigma_rotation_rad=np.radians(config.min_sigma_rotation_deg),
        min_sigma_translation_m=config.min_sigma_translation_m,
    )
    if correction_m > limit_m or correction_deg > config.max_correction_deg:
        # A good registration the estimate cannot vouch for: its measurement and information are
        # kept, so that the loop closer can hold it until a second closure confirms it.
        verdict = Verdict.LARGE_CORRECTION
        reason = (
            f"ICP moved {correction_m:.2f} m / {correction_deg:.1f} deg from the guess "
            f"(limit {limit_m:.2f} m / {config.max_correction_deg:g} deg); {quality}"
        )
    else:
        verdict = Verdict.ACCEPTED
        reason = f"{quality}, correction {correction_m:.2f} m / {correction_deg:.1f} deg"
    return LoopVerification(
        verdict=verdict,
        reason=reason,
        T_match_query=T,
        information=information,
        n_source=n_source,
        n_target=n_target,
        **metrics,
    )
