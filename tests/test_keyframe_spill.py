"""Keyframe clouds kept on disk (``SpilledKeyframeClouds``) and the submap that reads them back."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from lidar3d.config import Config
from lidar3d.features.frontend import prepare_scan
from lidar3d.io.keyframe_spill import SpilledKeyframeClouds
from lidar3d.mapping.keyframes import Keyframe, Submap
from lidar3d.pipeline import SlamPipeline, SpillStores


def _clouds(k: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(k)
    n_corner, n_surf = (0, 7) if k == 3 else (20 + k, 300 + 10 * k)
    return (
        rng.normal(scale=30.0, size=(n_corner, 3)).astype(np.float32),
        rng.normal(scale=30.0, size=(n_surf, 3)).astype(np.float32),
    )


def _assert_same(back: tuple[np.ndarray, np.ndarray], put: tuple[np.ndarray, np.ndarray]) -> None:
    for b, p in zip(back, put, strict=True):
        assert b.dtype == np.float32 and b.shape == p.shape
        np.testing.assert_array_equal(b, p)


def test_spilled_clouds_read_back_as_put_in_any_order(tmp_path):
    clouds = {k: _clouds(k) for k in range(6)}
    with SpilledKeyframeClouds(tmp_path) as store:
        for k, (corner, surf) in clouds.items():
            store.put(k, corner, surf)
        assert not list(tmp_path.iterdir())  # the file has no name on disk
        assert store.nbytes == sum(c.nbytes + s.nbytes for c, s in clouds.values())
        for k in (5, 0, 3, 0, 2):
            _assert_same(store.get(k), clouds[k])
        replaced = _clouds(40)
        store.put(2, *replaced)  # a keyframe deskewed again
        _assert_same(store.get(2), replaced)
        _assert_same(store.get(1), clouds[1])
        back = store.get(4)[1]
        back[0] = 0.0  # the caller's own array: the store keeps its copy
        _assert_same(store.get(4), clouds[4])
        assert 4 in store and 9 not in store
        with pytest.raises(KeyError):
            store.get(9)


def test_a_spill_folder_that_cannot_hold_the_file_keeps_the_clouds_in_memory(tmp_path, caplog):
    with SpilledKeyframeClouds(tmp_path / "missing") as store:
        for k in range(3):
            store.put(k, *_clouds(k))
        for k in range(3):
            _assert_same(store.get(k), _clouds(k))
    assert "keeping them in memory" in caplog.text


def test_a_spill_file_that_fails_midway_keeps_what_it_holds_and_the_rest_in_memory(tmp_path, caplog, monkeypatch):
    real_pwritev = os.pwritev
    calls = []

    def full_disk(fd, buffers, offset):
        calls.append(1)
        if len(calls) == 3:
            raise OSError(28, "No space left on device")
        return real_pwritev(fd, buffers, offset)

    with SpilledKeyframeClouds(tmp_path) as store:
        monkeypatch.setattr(os, "pwritev", full_disk)
        for k in range(5):
            store.put(k, *_clouds(k))
        monkeypatch.setattr(os, "pwritev", real_pwritev)
        assert len(calls) == 3  # after the failure nothing more is written
        for k in range(5):
            _assert_same(store.get(k), _clouds(k))
    assert "No space left on device" in caplog.text


def _submap(store=None, resident: int = 2) -> Submap:
    return Submap(
        radius_m=50.0,
        max_keyframes=20,
        recent=2,
        corner_voxel_m=0.2,
        surf_voxel_m=0.4,
        cache_size=0,  # every target reads the clouds again
        rebuild_every_keyframes=1,
        cloud_store=store,
        resident=resident,
    )


def test_a_submap_with_a_cloud_store_keeps_only_its_resident_keyframes_points(tmp_path):
    with SpilledKeyframeClouds(tmp_path) as store:
        in_memory, spilled = _submap(), _submap(store)
        for k in range(6):
            T = np.eye(4)
            T[0, 3] = 2.0 * k
            for submap in (in_memory, spilled):
                submap.add(Keyframe(k, 10 * k, 1000 * k, T, *_clouds(k)))
        assert [k in store for k in range(6)] == [True] * 4 + [False] * 2
        assert all(len(spilled.keyframes.record(k).surf_points) == 0 for k in range(4))  # records hold no points
        for k in range(6):
            _assert_same(
                (spilled.keyframes[k].corner_points, spilled.keyframes[k].surf_points),
                (in_memory.keyframes[k].corner_points, in_memory.keyframes[k].surf_points),
            )
        assert len(spilled.keyframes[1:4]) == 3 and spilled.keyframes[-1].index == 5
        np.testing.assert_array_equal(spilled.keyframes.stamps_ns, in_memory.keyframes.stamps_ns)
        np.testing.assert_array_equal(spilled.keyframes.scan_indices, [0, 10, 20, 30, 40, 50])
        for submap in (in_memory, spilled):
            submap.replace_clouds(1, *_clouds(41))
        _assert_same((spilled.keyframes[1].corner_points, spilled.keyframes[1].surf_points), _clouds(41))
        a, b = in_memory.target(np.array([4.0, 0.0, 0.0])), spilled.target(np.array([4.0, 0.0, 0.0]))
        assert a.keyframe_indices == b.keyframe_indices
        assert a.surfaces is not None and b.surfaces is not None
        np.testing.assert_array_equal(a.surfaces.points, b.surfaces.points)
        with pytest.raises(ValueError, match="added as number"):
            spilled.add(Keyframe(9, 90, 9000, np.eye(4), *_clouds(9)))


sim = pytest.importorskip("lidar3d.sim")


def test_a_pipeline_whose_keyframe_clouds_wait_on_disk_gives_the_same_poses(tmp_path):
    config = Config()
    mapping = dataclasses.replace(config.mapping, submap_recent_keyframes=1, submap_cache_keyframes=0)
    config = dataclasses.replace(config, mapping=mapping)
    scans = [prepare_scan(s.scan, config) for s in sim.Simulation("loop", seed=0, duration_s=3.0).scans()]
    poses = []
    with SpilledKeyframeClouds(tmp_path) as store:
        for keyframe_clouds in (None, store):
            pipeline = SlamPipeline(config, SpillStores(keyframe_clouds=keyframe_clouds))
            for scan in scans:
                pipeline.process(scan)
            pipeline.finish()
            poses.append(pipeline.result().trajectory.T_world_lidar)
        n_keyframes = len(pipeline.submap)
        assert n_keyframes > 5 and all(k in store for k in range(n_keyframes - 1))
    np.testing.assert_array_equal(poses[0], poses[1])
