"""voxel.key_groups gives np.unique's groups (by a stable sort), so every voxel filter built on it
keeps its output to the bit."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from lidar3d.mapping.voxel import (
    KeyedCloud,
    group_sums,
    key_groups,
    voxel_downsample,
    voxel_downsample_parts,
    voxel_keys,
)
from tests.fuzz_settings import fuzz_settings

_KEYS = hnp.arrays(np.int64, st.integers(0, 400), elements=st.integers(-(2**62), 2**62))
_FEW_KEYS = hnp.arrays(np.int64, st.integers(0, 400), elements=st.integers(-5, 5))


@fuzz_settings(200)
@given(st.one_of(_KEYS, _FEW_KEYS))
def test_key_groups_are_numpys_unique(keys: np.ndarray) -> None:
    unique, inverse, counts = key_groups(keys, counts=True)
    expected = np.unique(keys, return_inverse=True, return_counts=True)
    for got, want in zip((unique, inverse, counts), expected):
        assert got.dtype.kind == want.dtype.kind
        np.testing.assert_array_equal(got, want)
    unique_only, inverse_only = key_groups(keys)
    np.testing.assert_array_equal(unique_only, expected[0])
    np.testing.assert_array_equal(inverse_only, expected[1])


def test_voxel_centroids_unchanged_to_the_bit() -> None:
    """A scan-like cloud (rings swept in azimuth, so its keys come in runs): the centroids as
    np.unique's grouping summed them, bit for bit."""
    rng = np.random.default_rng(3)
    azimuth = np.repeat(np.linspace(0, 2 * np.pi, 1800, endpoint=False), 16)
    elevation = np.tile(np.radians(np.linspace(-15, 15, 16)), 1800)
    rng_m = rng.uniform(2.0, 60.0, azimuth.size)
    flat = rng_m * np.cos(elevation)
    points = np.column_stack([flat * np.cos(azimuth), flat * np.sin(azimuth), rng_m * np.sin(elevation)])
    _, inverse, counts = np.unique(voxel_keys(points, 0.4), return_inverse=True, return_counts=True)
    expected = group_sums(inverse, points, counts.size) / counts[:, None]
    got = voxel_downsample(points, 0.4)
    assert got.tobytes() == expected.tobytes()


def test_parts_filtered_as_their_concatenation() -> None:
    """voxel_downsample_parts over keyed parts (overlapping clouds, like a submap's keyframes,
    some empty) gives voxel_downsample of their concatenation, bit for bit."""
    rng = np.random.default_rng(5)
    clouds = [rng.normal(loc=rng.uniform(-3, 3, 3), scale=2.0, size=(n, 3)) for n in (500, 0, 1200, 7, 800)]
    parts = [KeyedCloud.of(cloud, 0.4) for cloud in clouds]
    expected = voxel_downsample(np.concatenate(clouds), 0.4)
    assert voxel_downsample_parts(parts).tobytes() == expected.tobytes()
    assert voxel_downsample_parts([]).shape == (0, 3)
    assert voxel_downsample_parts([parts[1]]).shape == (0, 3)
