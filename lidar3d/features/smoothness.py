"""Curvature ("smoothness") of the segmented cloud and rejection of unreliable points.

LeGO-LOAM featureAssociation, vectorised over the whole segmented cloud:

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
    row = segmentation.row
    index = np.arange(n)
    first = segmentation.ring_start[row]  # first index of each point's ring
    stop = segmentation.ring_end[row]  # one past its last
    in_section = (index - first >= w) & (stop - 1 - index >= w)

    prefix = np.concatenate(([0.0], np.cumsum(range_m)))
    window_sum = prefix[np.minimum(index + w + 1, n)] - prefix[np.maximum(index - w, 0)]
    curvature = np.where(in_section, (window_sum - (2 * w + 1) * range_m) ** 2, 0.0)

    # sections: the ring's pickable span [first + w, stop - w) cut into equal point counts (FA:690-694)
    span = np.maximum(stop - first - 2 * w, 1)
    sections = config.sections_per_ring
    section = np.where(in_section, row * sections + ((index - first - w) * sections) // span, -1)

    # occlusion: pairs (i, i+1) in one ring, close in column, with a depth step
    pair_ok = (row[1:] == row[:-1]) & (np.abs(np.diff(segmentation.column)) < config.neighbour_max_column_gap)
    step = np.diff(range_m)  # r_{i+1} - r_i
    far_then_near = np.zeros(n, dtype=np.int64)
    near_then_far = np.zeros(n, dtype=np.int64)
    far_then_near[:-1] = pair_ok & (-step > config.occlusion_depth_m)
    near_then_far[:-1] = pair_ok & (step > config.occlusion_depth_m)
    # point k is rejected by an event i with k in [i - w, i] (far_then_near) or [i + 1, i + w + 1]
    count_ftn = np.concatenate(([0], np.cumsum(far_then_near)))
    count_ntf = np.concatenate(([0], np.cumsum(near_then_far)))
    occluded = (count_ftn[np.minimum(index + w + 1, n)] - count_ftn[index]) > 0
    occluded |= (count_ntf[index] - count_ntf[np.maximum(index - w - 1, 0)]) > 0

    # beam nearly parallel to the surface: big range jumps on both sides
    jump_prev = np.full(n, np.inf)
    jump_next = np.full(n, np.inf)
    jump_prev[1:] = np.abs(step)
    jump_next[:-1] = np.abs(step)
    limit = config.parallel_beam_ratio * range_m
    parallel = (jump_prev > limit) & (jump_next > limit)

    pickable = in_section & ~occluded & ~parallel
    return Smoothness(
        curvature=curvature,
        in_section=in_section,
        section=section,
        pickable=pickable,
        edge_threshold=noise_edge_threshold(curvature[pickable], config),
    )


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
