"""Loop closure façade: candidates, verification and the pose graph behind one verb per keyframe.

Typical use from the pipeline (poses cross as (K,4,4) float64 arrays)::

    closer = LoopCloser(config.loop)
    ...after a keyframe was added to the submap:
    update = closer.on_keyframe(submap.keyframes, submap.poses)
    if update is not None:
        submap.set_poses(update.poses)                       # rebuilds the submap cache
        T_world_lidar = update.correction @ T_world_lidar    # the running pose follows
        scan_poses = correct_scan_poses(stamps, scan_poses, kf_stamps, update.previous_poses, update.poses)

:func:`correct_scan_poses` carries a keyframe correction over to every scan: a scan between
keyframes ``a`` and ``b`` gets the world-frame correction ``C = T_new @ inv(T_old)`` interpolated
in time between ``C_a`` and ``C_b`` (translation linearly, rotation by slerp), so a keyframe scan
lands exactly on its corrected keyframe pose and the scans between follow smoothly.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lidar3d.loop.candidates import find_candidates
from lidar3d.loop.consistency import HeldClosure, keep_consistent
from lidar3d.loop.place_closures import PlaceClosures
from lidar3d.loop.pose_graph import PoseGraph
from lidar3d.loop.records import LoopCandidate, Verdict
from lidar3d.loop.verification import build_match_cloud, verify_loop
from lidar3d.mapping.se3 import interpolate_poses, invert, nearest_rigid

__all__ = ["LoopCloser", "LoopUpdate", "correct_scan_poses"]

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class LoopUpdate:
    """What an accepted loop changed.

    Attributes:
        poses: (K,4,4) corrected keyframe poses ``T_world_lidar`` (all keyframes so far).
        previous_poses: (K,4,4) the poses passed in, before the correction.
        closures: the loop candidates accepted by this call (at least one).
        candidates: every candidate verified by this call, accepted or not.
    """

    poses: np.ndarray
    previous_poses: np.ndarray
    closures: tuple[LoopCandidate, ...]
    candidates: tuple[LoopCandidate, ...]

    @property
    def correction(self) -> np.ndarray:
        """(4,4) world-frame correction of the latest keyframe, ``poses[-1] @ inv(previous_poses[-1])``.

        Left-multiply the pipeline's running pose (and anything else expressed relative to the
        latest keyframe) by it.
        """
        return nearest_rigid(self.poses[-1] @ invert(self.previous_poses[-1]))


def correct_scan_poses(
    scan_stamps_ns: np.ndarray,
    scan_poses: np.ndarray,
    keyframe_stamps_ns: np.ndarray,
    old_keyframe_poses: np.ndarray,
    new_keyframe_poses: np.ndarray,
) -> np.ndarray:
    """Correct every scan pose by interpolating the keyframe corrections in time.

    Each keyframe ``k`` has the world-frame correction ``C_k = new_k @ inv(old_k)``. A scan at time
    ``t`` between keyframes ``a`` and ``b`` gets ``C(t)`` interpolated between ``C_a`` and ``C_b``
    (translation linearly, rotation by slerp, :func:`lidar3d.mapping.se3.interpolate_poses`), and
    its pose becomes ``C(t) @ T_old``. Scans before the first / after the last keyframe take that
    keyframe's correction. A scan whose stamp is a keyframe's stamp (and whose old pose is that
    keyframe's old pose) lands exactly on the keyframe's new pose.

    Args:
        scan_stamps_ns: (N,) increasing scan stamps.
        scan_poses: (N,4,4) scan poses ``T_world_lidar`` consistent with ``old_keyframe_poses``.
        keyframe_stamps_ns: (K,) increasing keyframe stamps (the keyframe scans' stamps; stamps
            rather than scan indices, because the pipeline numbers dropped scans too).
        old_keyframe_poses: (K,4,4) keyframe poses before the correction.
        new_keyframe_poses: (K,4,4) keyframe poses after it.

    Returns:
        (N,4,4) corrected scan poses (a new array).
    """
    scan_stamps_ns = np.asarray(scan_stamps_ns, dtype=np.int64)
    keyframe_stamps_ns = np.asarray(keyframe_stamps_ns, dtype=np.int64)
    scan_poses = np.asarray(scan_poses, dtype=np.float64)
    old = np.asarray(old_keyframe_poses, dtype=np.float64)
    new = np.asarray(new_keyframe_poses, dtype=np.float64)
    n, k = len(scan_stamps_ns), len(keyframe_stamps_ns)
    if scan_poses.shape != (n, 4, 4):
        raise ValueError(f"scan_poses must be ({n},4,4), got {scan_poses.shape}")
    if old.shape != (k, 4, 4) or new.shape != (k, 4, 4):
        raise ValueError(f"keyframe poses must be ({k},4,4), got {old.shape} and {new.shape}")
    if k == 0:
        return scan_poses.copy()
    if np.any(np.diff(keyframe_stamps_ns) <= 0):
        raise ValueError("keyframe stamps must be strictly increasing")
    corrections = new @ invert(old)
    if n == 0:
        return scan_poses.copy()
    C = interpolate_poses(keyframe_stamps_ns, corrections, scan_stamps_ns)
    out = C @ scan_poses
    # Exact at keyframes (interpolation at alpha = 0 or 1 is exact up to rounding already).
    at = np.searchsorted(keyframe_stamps_ns, scan_stamps_ns)
    hit = (at < k) & (keyframe_stamps_ns[np.minimum(at, k - 1)] == scan_stamps_ns)
    out[hit] = corrections[at[hit]] @ scan_poses[hit]
    return nearest_rigid(out)


class LoopCloser:
    """Loop candidates (distance gate and place recognition), ICP verification and an iSAM2 pose
    graph.

    Call :meth:`on_keyframe` after every keyframe; it adds the new keyframes to the pose graph
    (odometry factors from the poses given), looks for candidates of the latest keyframe, verifies
    them, and when one is accepted returns the corrected poses of all keyframes.

    Candidates come from the distance gate (``loop.source`` ``distance`` or ``both``) and, when it
    accepts none, from place recognition (``place`` or ``both``, :mod:`lidar3d.loop.place_closures`).

    Attributes:
        candidates: every verified candidate so far, in order (for ``loops.csv``).
        graph: the pose graph (for ``pose_graph.g2o``).
    """

    def __init__(self, config) -> None:
        self.config = config
        self.graph = PoseGraph(
            huber_k=config.huber_k,
            relinearize_threshold=config.relinearize_threshold,
            extra_updates=config.extra_updates,
        )
        self.candidates: list[LoopCandidate] = []
        self._odometry_sigmas = np.array(
            [np.radians(config.odometry_sigma_rotation_deg)] * 3 + [config.odometry_sigma_translation_m] * 3
        )
        self._path_m: list[float] = []  # travelled distance at each keyframe (given poses)
        self._stamps_ns: list[int] = []
        self._last_accepted_query = -(10**9)
        self._recent_closure: LoopCandidate | None = None
        self.held = HeldClosure(config)
        self.places = PlaceClosures(config, self.held) if config.source != "distance" else None

    @property
    def closures(self) -> list[LoopCandidate]:
        """The accepted candidates (the loop closures)."""
        return [c for c in self.candidates if c.accepted]

    def _add_keyframes(self, keyframes: Sequence, poses: np.ndarray) -> None:
        for k in range(len(self.graph), len(keyframes)):
            if keyframes[k].index != k:
                raise ValueError(f"keyframe at position {k} has index {keyframes[k].index}")
            self._stamps_ns.append(int(keyframes[k].stamp_ns))
            if self.places is not None:
                self.places.add(_keyframe_cloud(keyframes[k]), poses[k])
            if k == 0:
                self.graph.add_keyframe(0, poses[0])
                self._path_m.append(0.0)
            else:
                step = invert(poses[k - 1]) @ poses[k]
                self.graph.add_keyframe(k, poses[k], step, self._odometry_sigmas, keyframes[k].step_covariance)
                self._path_m.append(self._path_m[-1] + float(np.linalg.norm(poses[k, :3, 3] - poses[k - 1, :3, 3])))

    def on_keyframe(self, keyframes: Sequence, poses: np.ndarray) -> LoopUpdate | None:
        """Process the latest keyframe; returns the correction when a loop was accepted.

        Args:
            keyframes: all keyframes so far (``lidar3d.mapping.keyframes.Keyframe``: ``index``,
                ``stamp_ns``, ``corner_points``, ``surf_points`` in the lidar frame), index ``k``
                at position ``k``.
            poses: (K,4,4) current keyframe poses ``T_world_lidar`` (already corrected by earlier
                updates: pass ``Submap.poses`` after ``set_poses``).

        Returns:
            None when no loop was accepted, otherwise a :class:`LoopUpdate` with all K corrected
            poses.
        """
        poses = np.asarray(poses, dtype=np.float64)
        if poses.shape != (len(keyframes), 4, 4):
            raise ValueError(f"expected ({len(keyframes)},4,4) poses, got {poses.shape}")
        if not len(keyframes):
            return None
        self._add_keyframes(keyframes, poses)
        self.graph.update()
        cfg = self.config
        query = len(keyframes) - 1
        if not cfg.enabled or query - self._last_accepted_query <= cfg.cooldown_keyframes:
            return None
        stamps = np.array(self._stamps_ns, dtype=np.int64)
        records: list[LoopCandidate] = []
        accepted: list[LoopCandidate] = []
        tried: set[int] = set()
        path_m = np.asarray(self._path_m)
        self.held.expire(query)
        if cfg.source != "place":
            found = find_candidates(
                poses[:, :3, 3],
                stamps,
                query,
                radius_m=cfg.search_radius_m,
                min_time_gap_s=cfg.min_time_gap_s,
                horizontal=cfg.horizontal_distance,
                max_candidates=cfg.max_candidates,
                min_separation=cfg.submap_neighbours,
            )
            for match, distance in zip(found.matches.tolist(), found.distances_m.tolist()):
                tried.add(match)
                limit_m = self._drift_allowance_m(query, match)
                record = _verify(cfg, keyframes, poses, stamps, (query, match), distance, limit_m)
                records.append(record)
                if record.verdict is Verdict.LARGE_CORRECTION:
                    # a good registration farther from the estimate than the allowance: held until
                    # a closure of another keyframe agrees (this keyframe's evidence is used)
                    accepted = self.held.hold(
                        records,
                        poses,
                        path_m,
                        moved_m=record.correction_m,
                        moved_deg=record.correction_deg,
                        allowance_m=limit_m,
                    )
                    break
                if record.accepted:
                    accepted.append(record)
                    break
        accepted = keep_consistent(poses, path_m, self._recent_closure, accepted, records, cfg)
        held_here = self.held.pending is not None and self.held.pending.query == query
        if not accepted and not held_here and self.places is not None:
            gap_ns = int(round(cfg.min_time_gap_s * 1e9))
            eligible = np.flatnonzero(stamps[:query] <= stamps[query] - gap_ns)
            eligible = eligible[~np.isin(eligible, sorted(tried))]

            def verify(match: int, guess: np.ndarray, limit_m: float) -> LoopCandidate:
                distance = float(np.linalg.norm(poses[query, :2, 3] - poses[match, :2, 3]))
                return _verify(cfg, keyframes, poses, stamps, (query, match), distance, limit_m, guess, "place")

            accepted = self.places.closures(query, eligible, poses, path_m, verify, self._drift_allowance_m, records)
            accepted = keep_consistent(poses, path_m, self._recent_closure, accepted, records, cfg)
        for record in accepted:
            self.graph.add_loop(record.query, record.match, record.T_match_query, record.information)
        if accepted:
            dropped = set(self.graph.update())
            if dropped:
                records = [_graph_rejected(r) if (r.query, r.match) in dropped else r for r in records]
                accepted = [r for r in accepted if (r.query, r.match) not in dropped]
        self.candidates.extend(records)
        if not accepted:
            return None
        self._last_accepted_query = query
        self._recent_closure = accepted[-1]
        new_poses = nearest_rigid(self.graph.optimize())
        for record in accepted:
            log.info(
                "loop closed: keyframe %d -> %d (%.1f s apart), %s",
                record.query,
                record.match,
                record.time_gap_s,
                record.reason,
            )
        return LoopUpdate(new_poses, poses.copy(), tuple(accepted), tuple(records))

    def _drift_allowance_m(self, query: int, match: int) -> float:
        """The largest correction of ``query`` relative to ``match`` a distance closure may make."""
        return self.config.max_correction_m + self.config.correction_per_distance * (
            self._path_m[query] - self._path_m[match]
        )

    def final_poses(self, extra_updates: int = 10) -> np.ndarray:
        """(K,4,4) keyframe poses after ``extra_updates`` more relinearising iSAM2 steps."""
        return nearest_rigid(self.graph.optimize(extra_updates))


def _graph_rejected(record: LoopCandidate) -> LoopCandidate:
    return dataclasses.replace(
        record,
        verdict=Verdict.GRAPH_ERROR,
        reason=f"pose graph rejected the factor ({record.reason})",
        information=np.zeros((6, 6)),
    )


def _keyframe_cloud(keyframe) -> np.ndarray:
    """The keyframe's corner and surface points, fused (lidar frame, float64).

    Made on demand rather than cached: only the query and one match neighbourhood are needed per
    verification, while a cache would double the keyframes' memory on long drives.
    """
    return np.concatenate(
        [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in (keyframe.corner_points, keyframe.surf_points)]
    )


def _verify(
    config,
    keyframes: Sequence,
    poses: np.ndarray,
    stamps: np.ndarray,
    pair: tuple[int, int],
    distance: float,
    limit_m: float,
    T_guess: np.ndarray | None = None,
    source: str = "distance",
) -> LoopCandidate:
    """Register keyframe ``pair[0]`` (the query) against the submap around ``pair[1]`` (the match)
    from ``T_guess`` (the current estimate when None), ICP allowed to move it ``limit_m``."""
    query, match = pair
    gap_ns = int(round(config.min_time_gap_s * 1e9))
    lo = max(0, match - config.submap_neighbours)
    hi = min(query, match + config.submap_neighbours + 1)
    members = np.arange(lo, hi)
    members = members[stamps[members] <= stamps[query] - gap_ns]
    clouds = {int(k): _keyframe_cloud(keyframes[k]) for k in members}
    target = build_match_cloud(
        [clouds.get(k, np.zeros((0, 3))) for k in range(hi)], poses, match, members, config.voxel_m
    )
    if T_guess is None:
        T_guess = nearest_rigid(invert(poses[match]) @ poses[query])
    result = verify_loop(_keyframe_cloud(keyframes[query]), target, T_guess, config, max_correction_m=limit_m)
    return LoopCandidate(
        query=query,
        match=match,
        query_stamp_ns=int(stamps[query]),
        match_stamp_ns=int(stamps[match]),
        distance_m=float(distance),
        fitness=result.fitness,
        inlier_rmse_m=result.inlier_rmse_m,
        overlap=result.overlap,
        correction_m=result.correction_m,
        correction_deg=result.correction_deg,
        verdict=result.verdict,
        reason=result.reason,
        T_match_query=result.T_match_query,
        information=result.information,
        source=source,
    )
