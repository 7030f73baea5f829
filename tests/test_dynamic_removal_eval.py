"""``eval/dynamic_removal.py``'s scoring: removal and keeping on the true voxels, by range."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "eval"))
from dynamic_removal import VOXEL_M, _score


def test_removal_is_scored_per_voxel_and_by_the_nearest_range_it_was_seen_from():
    # Four moving voxels (one point each, but the first seen twice), two static ones; one voxel
    # shared by a moving and a static point counts as static only.
    centres = VOXEL_M * (np.arange(7)[:, None] * np.array([[10.0, 0.0, 0.0]]) + 0.5)
    points = centres[[0, 0, 1, 2, 3, 4, 5, 6, 6]]
    moving = np.array([1, 1, 1, 1, 1, 0, 0, 1, 0], bool)
    seen_from_m = np.array([45.0, 19.999, 20.0, 39.9, 40.0, 5.0, 5.0, 10.0, 10.0])
    removed = np.array([1, 1, 1, 0, 1, 0, 1, 1, 0], bool)  # voxel 2 left; a static point of voxel 5 removed
    score = _score(points, moving, removed, seen_from_m)
    assert score["dynamic_only_voxels"] == 4 and score["static_voxels"] == 3
    assert score["dynamic_removed"] == 0.75
    assert score["static_kept"] == round(2 / 3, 4)  # voxel 5 lost its only static point
    # Voxel 0 was seen from 19.999 m at the nearest: 0-20; voxels 1 and 2 at 20 and 39.9 m: 20-40.
    assert score["dynamic_removed_by_range_m"] == {"0-20": [1, 1.0], "20-40": [2, 0.5], "40+": [1, 1.0]}
    far_only = _score(points[:2], moving[:2], removed[:2], np.array([50.0, 60.0]))
    assert far_only["dynamic_removed_by_range_m"] == {"0-20": [0, None], "20-40": [0, None], "40+": [1, 1.0]}
    assert far_only["static_voxels"] == 0 and far_only["static_kept"] is None  # no static voxel: nothing to keep
