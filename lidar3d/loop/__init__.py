"""Loop closure: distance-gated candidates, ICP verification, a Huber-robust iSAM2 pose graph.

Pure computation (the algorithm layer). GTSAM is imported only by :mod:`lidar3d.loop.pose_graph`,
Open3D only by :mod:`lidar3d.loop.verification`, both lazily. File outputs (``loops.csv``,
``pose_graph.g2o``, the top-view PNG) live in the adapter module :mod:`lidar3d.export.loop_report`.
"""

from lidar3d.loop.candidates import CandidateSet, find_candidates
from lidar3d.loop.closer import LoopCloser, LoopUpdate, correct_scan_poses
from lidar3d.loop.pose_graph import GraphEdge, PoseGraph
from lidar3d.loop.records import LoopCandidate, Verdict
from lidar3d.loop.verification import LoopVerification, build_match_cloud, verify_loop

__all__ = [
    "CandidateSet",
    "GraphEdge",
    "LoopCandidate",
    "LoopCloser",
    "LoopUpdate",
    "LoopVerification",
    "PoseGraph",
    "Verdict",
    "build_match_cloud",
    "correct_scan_poses",
    "find_candidates",
    "verify_loop",
]
