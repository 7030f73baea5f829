"""Records of the loop-closure stage: the verdict on a candidate and the candidate itself."""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

__all__ = ["LoopCandidate", "Verdict"]


class Verdict(str, enum.Enum):
    """Outcome of verifying one loop candidate (the value is what ``loops.csv`` shows)."""

    ACCEPTED = "accepted"
    TOO_FEW_POINTS = "too_few_points"  # source or target cloud (nearly) empty
    NOT_CONVERGED = "not_converged"  # ICP failed, kept moving, or lost its correspondences
    LOW_FITNESS = "low_fitness"  # too few source points have a target point within the final distance
    HIGH_RMSE = "high_rmse"  # inlier RMSE above the threshold
    LOW_OVERLAP = "low_overlap"  # voxel overlap of the aligned clouds below the threshold
    LARGE_CORRECTION = "large_correction"  # ICP moved farther from the guess than the drift can explain
    GRAPH_ERROR = "graph_error"  # verified, but the pose graph could not take the factor
    INCONSISTENT = "inconsistent"  # verified, but its cycle with the closure accepted just before does not close
    UNCONFIRMED = "unconfirmed"  # a verified match that moves the estimate farther than drift explains,
    # waiting for a second closure consistent with it (the accepted pair is recorded again)


@dataclass(frozen=True, slots=True)
class LoopCandidate:
    """One verified loop candidate, accepted or not (accepted ones are the loop closures).

    Attributes:
        query: keyframe index of the newer keyframe (the one whose cloud is registered).
        match: keyframe index of the older keyframe (centre of the target submap).
        query_stamp_ns: stamp of the query keyframe.
        match_stamp_ns: stamp of the match keyframe.
        distance_m: gating distance between the two at the estimate before closure (horizontal or
            3-D, as configured).
        fitness: fraction of query points with a submap point within the final ICP distance
            (Open3D ``RegistrationResult.fitness``); NaN when ICP did not run.
        inlier_rmse_m: RMS distance of those correspondences; NaN when ICP did not run.
        overlap: voxel overlap ``|A ∩ B| / min(|A|, |B|)`` of the aligned clouds (KISS-SLAM); NaN
            when ICP did not run.
        correction_m: translation between the initial guess and the ICP result (query frame).
        correction_deg: rotation angle between the initial guess and the ICP result.
        verdict: the outcome.
        reason: one human-readable line explaining the verdict (thresholds included).
        T_match_query: (4,4) float64 query pose in the match keyframe's frame (ICP result, or the
            initial guess when ICP did not run).
        information: (6,6) float64 information of ``T_match_query`` for a GTSAM ``BetweenFactor``:
            tangent order (rx, ry, rz, tx, ty, tz), rad and m, perturbation on the right (query
            frame). Zero when not accepted (kept for an unconfirmed closure and a large correction).
        source: who proposed the candidate: ``distance`` (the gate around the estimate) or
            ``place`` (the Scan Context descriptor).
    """

    query: int
    match: int
    query_stamp_ns: int
    match_stamp_ns: int
    distance_m: float
    fitness: float
    inlier_rmse_m: float
    overlap: float
    correction_m: float
    correction_deg: float
    verdict: Verdict
    reason: str
    T_match_query: np.ndarray
    information: np.ndarray
    source: str = "distance"

    def __post_init__(self) -> None:
        if np.shape(self.T_match_query) != (4, 4):
            raise ValueError(f"T_match_query must be (4,4), got {np.shape(self.T_match_query)}")
        if np.shape(self.information) != (6, 6):
            raise ValueError(f"information must be (6,6), got {np.shape(self.information)}")

    @property
    def accepted(self) -> bool:
        return self.verdict is Verdict.ACCEPTED

    @property
    def time_gap_s(self) -> float:
        return (self.query_stamp_ns - self.match_stamp_ns) * 1e-9
