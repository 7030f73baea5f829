"""Curvature ("smoothness") of the segmented cloud and rejection of unreliable points.

LeGO-LOAM featureAssociation, in one pass over the whole segmented cloud (a compiled kernel):

* curvature (FA:621-641): c_i = (sum_{0<|j-i|<=w} r_j - 2w r_i)^2 with w = 5, the unnormalised form
  of LeGO-LOAM's code (paper Eq. 1 divides by |S| r_i); thresholds are therefore in m^2;
* occlusion (FA:643-669): for consecutive points of a ring less than ``neighbour_max_column_gap``
  columns apart whose ranges differ by more than ``occlusion_depth_m``, the w+1 points on the far
  side of the step nearest to it are rejected (i-w..i when i is farther, i+1..i+w+1 when i+1 is);
* beam-parallel surfaces (FA:671-676): point i is rejected when both |r_{i-1} - r_i| and
  |r_{i+1} - r_i| exceed ``parallel_beam_ratio`` * r_i;
* the edge threshold of the scan (ours, optional: ``edge_noise_false_rate`` > 0; off by default, see
  docs/stages/features.md for what it gains and costs): on a smooth surface, range noise of standard deviation
  sigma alone gives c_i = (2w(2w + 1)) sigma^2 chi^2_1 (the sum of 2w noisy neighbours minus 2w
  times a noisy centre). LeGO-LOAM's fixed 0.1 m^2 is exceeded by 13 % of the points of a flat wall
  at the VLP-16's sigma of 2 cm, and those random "edges" match random lines through the random
  edges of the map: along a featureless wall they pin the pose wherever it is, with an information
  that looks high (a 160 m walled street was crossed at 2.4 m/s estimated against 6.3 m/s driven).
  The scan's noise is measured on the scan itself: the median curvature of the pickable points
  (most of a scan is smooth surface) is that of the noise, 2w(2w + 1) sigma^2 times the chi^2_1
  median, and an edge must exceed the chi^2_1 quantile of ``edge_noise_false_rate``.

Curvature windows and occlusion pairs stay inside one ring (LeGO-LOAM's indices run over the whole
cloud, but only points w away from the ring ends are ever picked, so this changes nothing there).
"""

from __future__ import annotations

from functools import cache

import numpy as np

from lidar3d.config import FeatureConfig
from lidar3d.errors import ConfigError
from lidar3d.features.records import Smoothness
from lidar3d.jit import lazy_njit
from lidar3d.segmentation.segment import Segmentation

__all__ = ["compute_smoothness", "noise_edge_threshold"]


def _check(config: FeatureConfig) -> None:
    if config.curvature_half_window < 1:
        raise ConfigError(f"config features.curvature_half_window: must be >= 1, got {config.curvature_half_window}")
    if config.sections_per_ring < 1:
        raise ConfigError(f"config features.sections_per_ring: must be >= 1, got {config.sections_per_ring}")


def compute_smoothness(segmentation: Segmentation, config: FeatureConfig) -> Smoothness:
    """Curvature, ring sections and pickable flags of every point of the segmented cloud."""
    _check(config)
    range_m = segmentation.range_m
    n = range_m.shape[0]
    w = config.curvature_half_window
    if n == 0:
        none = np.zeros(0, dtype=np.int64)
        return Smoothness(
            curvature=np.zeros(0),
            in_section=none.astype(bool),
            section=none,
            pickable=none.astype(bool),
            edge_threshold=config.edge_threshold,
        )
    curvature, in_section, section, pickable = _smoothness_kernel(
        range_m,
        segmentation.row,
        segmentation.column,
        segmentation.ring_start,
        segmentation.ring_end,
        w,
        config.sections_per_ring,
        config.neighbour_max_column_gap,
        config.occlusion_depth_m,
        config.parallel_beam_ratio,
    )
    return Smoothness(
        curvature=curvature,
        in_section=in_section,
        section=section,
        pickable=pickable,
        edge_threshold=noise_edge_threshold(curvature[pickable], config),
    )


@lazy_njit
def _smoothness_kernel(
    range_m: np.ndarray,
    row: np.ndarray,
    column: np.ndarray,
    ring_start: np.ndarray,
    ring_end: np.ndarray,
    w: int,
    sections: int,
    max_column_gap: int,
    occlusion_depth_m: float,
    parallel_beam_ratio: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Curvature, in-section flag, section and pickable flag of each of the (M,) points (module doc).

    ``range_m`` (M,) m, ``row``, ``column`` (M,) int64 of the segmented cloud, in ring order;
    ``ring_start``, ``ring_end`` (R,) int64, each ring's first and one-past-last index. The window
    sums are differences of the running sum of the ranges, accumulated in index order.
    """
    n = range_m.shape[0]
    prefix = np.zeros(n + 1)
    for i in range(n):
        prefix[i + 1] = prefix[i] + range_m[i]
    # occlusion events of the pairs (i, i+1) in one ring, close in column, with a depth step, counted
    far_then_near = np.zeros(n + 1, np.int64)  # far_then_near[k]: events i < k with r_i > r_{i+1} + depth
    near_then_far = np.zeros(n + 1, np.int64)
    for i in range(n):
        ftn = ntf = 0
        if i + 1 < n and row[i + 1] == row[i] and abs(column[i + 1] - column[i]) < max_column_gap:
            step = range_m[i + 1] - range_m[i]
            ftn = 1 if -step > occlusion_depth_m else 0
            ntf = 1 if step > occlusion_depth_m else 0
        far_then_near[i + 1] = far_then_near[i] + ftn
        near_then_far[i + 1] = near_then_far[i] + ntf
    curvature = np.zeros(n)
    in_section = np.zeros(n, np.bool_)
    section = np.full(n, -1, np.int64)
    pickable = np.zeros(n, np.bool_)
    for i in range(n):
        first, stop = ring_start[row[i]], ring_end[row[i]]
        if i - first < w or stop - 1 - i < w:
            continue
        in_section[i] = True
        window_sum = prefix[min(i + w + 1, n)] - prefix[max(i - w, 0)]
        curvature[i] = (window_sum - (2 * w + 1) * range_m[i]) ** 2
        section[i] = row[i] * sections + ((i - first - w) * sections) // max(stop - first - 2 * w, 1)
        # rejected by a far-then-near event in [i - w, i] or a near-then-far one in [i + 1, i + w + 1]
        occluded = far_then_near[min(i + w + 1, n)] - far_then_near[i] > 0
        occluded |= near_then_far[i] - near_then_far[max(i - w - 1, 0)] > 0
        # beam nearly parallel to the surface: big range jumps on both sides
        limit = parallel_beam_ratio * range_m[i]
        jump_prev = abs(range_m[i] - range_m[i - 1]) if i > 0 else np.inf
        jump_next = abs(range_m[i + 1] - range_m[i]) if i + 1 < n else np.inf
        pickable[i] = not occluded and not (jump_prev > limit and jump_next > limit)
    return curvature, in_section, section, pickable


@cache
def _chi2_1(false_rate: float) -> tuple[float, float]:
    """The median of chi-square with one degree of freedom and its quantile exceeded with
    probability ``false_rate``. scipy.stats is imported here, at the first scan, not with the
    package: its import (0.4-0.6 s) is wasted on the commands that only deskew (``lidar3d grid``)."""
    from scipy.stats import chi2

    return float(chi2.median(1)), float(chi2.isf(false_rate, 1))


def noise_edge_threshold(curvature_m2: np.ndarray, config: FeatureConfig) -> float:
    """m^2: the edge threshold of one scan from the (K,) curvatures of its pickable points: the
    configured ``edge_threshold``, raised to the curvature that the scan's range noise (measured by
    the median curvature) exceeds on a smooth surface with probability ``edge_noise_false_rate``."""
    if config.edge_noise_false_rate <= 0.0 or curvature_m2.size == 0:
        return config.edge_threshold
    median, exceeded = _chi2_1(config.edge_noise_false_rate)
    noise_scale_m2 = float(np.median(curvature_m2)) / median  # 2w(2w+1) sigma^2
    return max(config.edge_threshold, noise_scale_m2 * exceeded)
