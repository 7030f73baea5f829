"""Pairwise consistency of two loop measurements with the odometry between them.

Two closures ``(q1, m1, T_m1q1)`` and ``(q2, m2, T_m2q2)`` and the estimated trajectory between
their ends form a cycle: the pose of ``q2`` in ``m1``'s frame follows both from
``T_m1q1 @ T_q1q2`` (first closure, then odometry along the query side) and from
``T_m1m2 @ T_m2q2`` (odometry along the match side, then the second closure). Two correct
closures agree up to the drift over the short odometry spans; a wrong one disagrees by its own
error. This is the pairwise test of pairwise consistency maximisation (J. Mangelson et al.,
"Pairwise Consistent Measurement Set Maximization for Robust Multi-robot Map Merging", ICRA
2018), used here to let a verified match that moves the trajectory by more than its drift
allowance into the graph only when a second closure confirms it (:class:`HeldClosure`), and to keep
a closure out of it when it disagrees with the one accepted just before (:func:`keep_consistent`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from lidar3d.loop.records import LoopCandidate, Verdict
from lidar3d.mapping.se3 import invert

__all__ = ["HeldClosure", "closures_agree", "cycle_error", "keep_consistent", "pairwise_consistent"]


def cycle_error(
    poses: np.ndarray, first: tuple[int, int, np.ndarray], second: tuple[int, int, np.ndarray]
) -> tuple[float, float]:
    """(metres, degrees) of the cycle through two closures ``(query, match, T_match_query)``
    and the (K,4,4) keyframe ``poses`` (current estimate) between their ends."""
    q1, m1, T_m1q1 = first
    q2, m2, T_m2q2 = second
    T_q1q2 = invert(poses[q1]) @ poses[q2]
    T_m1m2 = invert(poses[m1]) @ poses[m2]
    error = invert(T_m1m2 @ T_m2q2) @ (T_m1q1 @ T_q1q2)
    angle = np.degrees(np.arccos(np.clip((np.trace(error[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
    return float(np.linalg.norm(error[:3, 3])), float(angle)


def pairwise_consistent(
    poses: np.ndarray,
    path_m: np.ndarray,
    first: tuple[int, int, np.ndarray],
    second: tuple[int, int, np.ndarray],
    *,
    tolerance_m: float,
    tolerance_deg: float,
    drift_per_distance: float,
) -> tuple[bool, float, float]:
    """Whether two closures agree: the cycle error within ``tolerance_m`` plus
    ``drift_per_distance`` of the path travelled along both odometry spans (``path_m``: (K,)
    travelled distance at each keyframe), and within ``tolerance_deg``. Returns the verdict and
    the error (m, deg)."""
    moved_m, moved_deg = cycle_error(poses, first, second)
    span_m = abs(path_m[second[0]] - path_m[first[0]]) + abs(path_m[second[1]] - path_m[first[1]])
    ok = moved_m <= tolerance_m + drift_per_distance * span_m and moved_deg <= tolerance_deg
    return bool(ok), moved_m, moved_deg


def closures_agree(
    poses: np.ndarray, path_m: np.ndarray, first: LoopCandidate, second: LoopCandidate, config
) -> tuple[bool, float, float]:
    """:func:`pairwise_consistent` of two loop candidates with the tolerances of the
    :class:`lidar3d.config.LoopConfig` ``config``."""
    return pairwise_consistent(
        poses,
        path_m,
        (first.query, first.match, first.T_match_query),
        (second.query, second.match, second.T_match_query),
        tolerance_m=config.consistency_m,
        tolerance_deg=config.consistency_deg,
        drift_per_distance=config.correction_per_distance,
    )


def keep_consistent(
    poses: np.ndarray,
    path_m: np.ndarray,
    recent: LoopCandidate | None,
    accepted: list[LoopCandidate],
    records: list[LoopCandidate],
    config,
) -> list[LoopCandidate]:
    """``accepted`` unless its first closure disagrees with ``recent`` (the closure accepted last,
    when at most ``config.consistency_keyframes`` keyframes older): then none, and the matching
    entries of ``records`` become ``Verdict.INCONSISTENT`` with the cycle error in the reason."""
    if not accepted or recent is None or accepted[0].query - recent.query > config.consistency_keyframes:
        return accepted
    ok, error_m, error_deg = closures_agree(poses, path_m, recent, accepted[0], config)
    if ok:
        return accepted
    why = f"cycle with keyframe {recent.query}'s closure open by {error_m:.2f} m / {error_deg:.2f} deg"
    for k, record in enumerate(records):
        if any(record is a for a in accepted):
            records[k] = dataclasses.replace(
                record, verdict=Verdict.INCONSISTENT, reason=f"{why}; {record.reason}", information=np.zeros((6, 6))
            )
    return []


class HeldClosure:
    """The verified closure that moves the estimate farther than drift explains, held until a
    closure of another query keyframe agrees with it.

    Either candidate source may hold or confirm: a distance candidate whose ICP slid farther than
    the gate's drift allowance (along a corridor the estimate may have drifted farther than the
    allowance assumes) and a place match far from the estimate are the same evidence, a good
    registration that the estimate cannot vouch for. Two of them from different query keyframes
    that close a consistent cycle (:func:`closures_agree`) both enter the graph; a single one never
    does, so one wrong match cannot move the trajectory by more than the drift allowance.

    Args:
        config: a :class:`lidar3d.config.LoopConfig` (``consistency_keyframes``: how long a closure
            is held; the cycle tolerances).
    """

    def __init__(self, config) -> None:
        self.config = config
        self.pending: LoopCandidate | None = None

    def expire(self, query: int) -> None:
        """Forget the held closure when it is more than ``consistency_keyframes`` keyframes older."""
        if self.pending is not None and query - self.pending.query > self.config.consistency_keyframes:
            self.pending = None

    def hold(
        self,
        records: list[LoopCandidate],
        poses: np.ndarray,
        path_m: np.ndarray,
        *,
        moved_m: float,
        moved_deg: float,
        allowance_m: float,
    ) -> list[LoopCandidate]:
        """Hold ``records[-1]`` (verified, its measurement and information set), or confirm the
        held one with it.

        Args:
            records: the call's verified candidates; the last one is replaced by its held
                (``Verdict.UNCONFIRMED``) or accepted version, and an accepted earlier closure is
                appended.
            poses: (K,4,4) current keyframe poses; path_m: (K,) travelled distance at each.
            moved_m, moved_deg: how far the closure moves the estimate; allowance_m: the drift
                allowance it exceeds (for the reason).

        Returns:
            ``[earlier, this]`` when the held closure and this one agree, else ``[]`` (this one is
            now the held closure).
        """
        record = records[-1]
        held = dataclasses.replace(
            record,
            verdict=Verdict.UNCONFIRMED,
            reason=f"moves the estimate {moved_m:.2f} m / {moved_deg:.1f} deg (drift allowance "
            f"{allowance_m:.2f} m / {self.config.max_correction_deg:g} deg): needs a consistent second "
            f"closure; {record.reason}",
        )
        records[-1] = held
        pending = self.pending
        if pending is not None and pending.query != held.query:
            ok, error_m, error_deg = closures_agree(poses, path_m, pending, held, self.config)
            if ok:
                self.pending = None
                note = f"cycle error {error_m:.2f} m / {error_deg:.2f} deg"
                first = dataclasses.replace(
                    pending,
                    verdict=Verdict.ACCEPTED,
                    reason=f"confirmed by keyframe {held.query} ({note}); {pending.reason}",
                )
                second = dataclasses.replace(
                    held,
                    verdict=Verdict.ACCEPTED,
                    reason=f"consistent with keyframe {pending.query} ({note}); {held.reason}",
                )
                records[-1] = second
                records.append(first)
                return [first, second]
        self.pending = held
        return []
