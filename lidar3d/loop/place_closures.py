"""Place-recognition closures of the loop closer: Scan Context candidates, verified from the
descriptor's yaw, and the confirmation of corrections larger than drift explains.

A verified place match whose correction of the estimate is within the distance gate's drift
allowance is accepted as a distance closure would be. One beyond it (the estimate drifted
farther than the gate believes possible, or the match is wrong) is held as unconfirmed until a
closure of another keyframe (place or distance) within ``loop.consistency_keyframes`` keyframes
agrees with it (:class:`~lidar3d.loop.consistency.HeldClosure`); then both enter the graph. A
single wrong match can therefore never move the trajectory by more than the drift allowance.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from lidar3d.loop.consistency import HeldClosure
from lidar3d.loop.place import PlaceIndex, place_guess
from lidar3d.loop.records import LoopCandidate
from lidar3d.loop.verification import pose_change
from lidar3d.mapping.se3 import invert, nearest_rigid

__all__ = ["PlaceClosures"]


class PlaceClosures:
    """The Scan Context index of the keyframes and their verification.

    Args:
        config: a :class:`lidar3d.config.LoopConfig`.
        held: the loop closer's closure waiting for confirmation (shared with its distance
            candidates).
    """

    def __init__(self, config, held: HeldClosure) -> None:
        self.config = config
        self.held = held
        self.index = PlaceIndex(
            rings=config.place_rings,
            sectors=config.place_sectors,
            max_radius_m=config.place_max_radius_m,
            candidates=config.place_candidates,
            threshold=config.place_threshold,
        )

    def add(self, points_lidar: np.ndarray, T_world_lidar: np.ndarray) -> None:
        """Describe the next keyframe: its (N,3) lidar-frame cloud at pose (4,4)."""
        self.index.add(points_lidar, T_world_lidar)

    def closures(
        self,
        query: int,
        eligible: np.ndarray,
        poses: np.ndarray,
        path_m: np.ndarray,
        verify: Callable[[int, np.ndarray, float], LoopCandidate],
        drift_allowance_m: Callable[[int, int], float],
        records: list[LoopCandidate],
    ) -> list[LoopCandidate]:
        """Verify the place matches of keyframe ``query`` among the ``eligible`` earlier ones.

        Args:
            poses: (K,4,4) current keyframe poses; path_m: (K,) travelled distance at each.
            verify: ``verify(match, T_guess_match_query, max_correction_m)`` registers the query
                against the match's submap (the loop closer's ICP verification).
            drift_allowance_m: ``(query, match)`` -> the largest correction a distance closure
                between them may make.
            records: every verified candidate is appended (unconfirmed ones with that verdict).

        Returns:
            The closures to add to the graph: none, one within the drift allowance, or the earlier
            unconfirmed closure and the new one that agrees with it.
        """
        cfg = self.config
        for place in self.index.query(query, eligible)[: cfg.max_candidates]:
            guess = place_guess(poses[place.match], poses[query], place.yaw_rad)
            # the descriptor puts the two at one place, within about its first ICP stage
            record = verify(place.match, guess, float(cfg.icp_max_correspondence_m[0]))
            records.append(record)
            if not record.accepted:
                continue
            estimate = nearest_rigid(invert(poses[place.match]) @ poses[query])
            moved_m, moved_deg = pose_change(estimate, record.T_match_query)
            allowance_m = drift_allowance_m(query, place.match)
            if moved_m <= allowance_m and moved_deg <= cfg.max_correction_deg:
                return [record]
            return self.held.hold(records, poses, path_m, moved_m=moved_m, moved_deg=moved_deg, allowance_m=allowance_m)
        return []
