"""Loop candidates: time gap, radius, horizontal vs 3-D distance, nearest first, limits."""

from __future__ import annotations

import numpy as np
import pytest

from lidar3d.loop import find_candidates

S = 1_000_000_000


def _track():
    """Keyframes 0..4 at 10 s spacing; keyframe 4 returns near keyframes 0 and 1, 6 m higher."""
    positions = np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [50.0, 0.0, 0.0], [60.0, 0.0, 0.0], [1.0, 1.0, 6.0]])
    stamps = np.arange(5, dtype=np.int64) * 10 * S
    return positions, stamps


def test_nearest_first_within_radius_and_gap():
    positions, stamps = _track()
    found = find_candidates(positions, stamps, 4, radius_m=7.0, min_time_gap_s=30.0, max_candidates=5)
    # 40 s gap to 0, 30 s to 1 (boundary included); 2 and 3 are too far
    assert found.matches.tolist() == [0, 1]
    np.testing.assert_allclose(found.distances_m, [np.sqrt(2.0), np.sqrt(5.0)])


def test_time_gap_excludes_recent_keyframes():
    positions, stamps = _track()
    found = find_candidates(positions, stamps, 4, radius_m=7.0, min_time_gap_s=35.0, max_candidates=5)
    assert found.matches.tolist() == [0]
    assert len(find_candidates(positions, stamps, 4, radius_m=7.0, min_time_gap_s=45.0)) == 0


def test_horizontal_distance_ignores_height_drift():
    positions, stamps = _track()
    horizontal = find_candidates(positions, stamps, 4, radius_m=5.0, min_time_gap_s=30.0, max_candidates=5)
    spatial = find_candidates(
        positions, stamps, 4, radius_m=5.0, min_time_gap_s=30.0, horizontal=False, max_candidates=5
    )
    assert horizontal.matches.tolist() == [0, 1]
    assert len(spatial) == 0  # 6 m of height drift hides the revisit in 3-D
    wide = find_candidates(positions, stamps, 4, radius_m=7.0, min_time_gap_s=30.0, horizontal=False, max_candidates=5)
    np.testing.assert_allclose(wide.distances_m, [np.sqrt(38.0), np.sqrt(41.0)])


def test_limit_and_only_earlier_keyframes():
    positions, stamps = _track()
    assert find_candidates(positions, stamps, 4, radius_m=7.0, min_time_gap_s=30.0).matches.tolist() == [0]
    assert len(find_candidates(positions, stamps, 4, radius_m=7.0, min_time_gap_s=30.0, max_candidates=0)) == 0
    # keyframe 1 would be near keyframe 4, but 4 is later: never a candidate of 1
    assert len(find_candidates(positions, stamps, 1, radius_m=100.0, min_time_gap_s=0.0, max_candidates=5)) == 1
    assert len(find_candidates(positions, stamps, 0, radius_m=100.0, min_time_gap_s=0.0)) == 0


def test_ties_break_by_index():
    positions = np.array([[1.0, 0, 0], [-1.0, 0, 0], [0.0, 0, 0]])
    stamps = np.array([0, 1, 100], dtype=np.int64) * S
    found = find_candidates(positions, stamps, 2, radius_m=2.0, min_time_gap_s=1.0, max_candidates=2)
    assert found.matches.tolist() == [0, 1]


def test_bad_shapes_raise():
    positions, stamps = _track()
    with pytest.raises(ValueError, match="out of range"):
        find_candidates(positions, stamps, 5, radius_m=7.0, min_time_gap_s=30.0)
    with pytest.raises(ValueError, match=r"expected \(K,3\)"):
        find_candidates(positions[:, :2], stamps, 4, radius_m=7.0, min_time_gap_s=30.0)


def test_a_second_candidate_comes_from_another_pass_not_the_first_ones_neighbours():
    # keyframes 0-9 along y = 1.5 m (first pass), 10-19 far away, 20-29 along y = 0 (second pass)
    x = np.r_[np.arange(10.0), 100.0 + np.arange(10.0), np.arange(10.0) + 0.3, 4.2]
    y = np.r_[np.full(10, 1.5), np.zeros(21)]
    positions = np.column_stack([x, y, np.zeros_like(x)])
    stamps = np.arange(len(x), dtype=np.int64) * 10 * S
    near = find_candidates(positions, stamps, 30, radius_m=7.0, min_time_gap_s=30.0, max_candidates=2)
    assert near.matches.tolist() == [24, 23]  # 0.1 and 0.9 m away: one pass, nearly one submap
    apart = find_candidates(
        positions, stamps, 30, radius_m=7.0, min_time_gap_s=30.0, max_candidates=3, min_separation=5
    )
    assert apart.matches.tolist() == [24, 4]  # the first pass's nearest (1.5 m) instead
    one_pass = find_candidates(
        positions, stamps, 30, radius_m=7.0, min_time_gap_s=30.0, max_candidates=3, min_separation=25
    )
    assert one_pass.matches.tolist() == [24]
