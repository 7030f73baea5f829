"""Errors of trajectory evaluation."""

from __future__ import annotations

from lidar3d.errors import Lidar3dError

__all__ = ["EvaluationError"]


class EvaluationError(Lidar3dError):
    """Trajectories cannot be compared: no time overlap, too few associated poses, degenerate geometry."""
