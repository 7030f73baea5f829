"""The dense map kept in pieces anchored to keyframes (lidar3d.mapping.map_pieces) and placed again
when the keyframes move, against the map built with the moved poses."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lidar3d.config import Config
from lidar3d.io.piece_spill import SpilledPieceStore
from lidar3d.loop.closer import correct_scan_poses
from lidar3d.mapping.dense_map import DenseMap
from lidar3d.mapping.map_pieces import MapAnchor, MapPiece, MapPieces, MemoryPieceStore
from lidar3d.mapping.se3 import exp_se3
from lidar3d.records import Scan
from lidar3d.sim import Simulation

KEYFRAME_EVERY = 4  # sweeps


@pytest.fixture(scope="module")
def city():
    """3.5 s of city_traffic, every sweep exactly deskewed: (scans, true poses)."""
    sim = Simulation("city_traffic", seed=0, duration_s=3.5)
    scans, poses = [], []
    for simulated in sim.scans():
        world = sim.points_world(simulated)
        T = simulated.T_world_lidar
        local = (world - T[:3, 3]) @ T[:3, :3]
        scans.append(
            Scan(simulated.scan.stamp_ns, local, simulated.scan.intensity, simulated.scan.ring, np.zeros(len(local)))
        )
        poses.append(T)
    return scans, np.array(poses)


def _corrections(n_keyframes: int) -> np.ndarray:
    """A loop-closure-like correction per keyframe, growing along the drive (0.3 m and 0.3 degrees at
    the end: a few times the step per keyframe a closure after a few hundred metres makes)."""
    s = np.linspace(0.0, 1.0, n_keyframes)
    return np.array([exp_se3(np.array([0.3 * t, -0.15 * t, 0.03 * t, 0.0, 0.0, np.radians(0.3) * t])) for t in s])


def _maps(scans, poses, corrections=None):
    """(the map in pieces, its keyframe poses moved by ``corrections``, the map built with every sweep at
    its pose corrected as the pipeline corrects scan poses: interpolated between the keyframes)."""
    config = Config()
    pieces = MapPieces(config.mapping.map_voxel_m)
    dense_map = DenseMap(config, pieces)
    keyframe_poses = poses[::KEYFRAME_EVERY]
    corrections = np.tile(np.eye(4), (len(keyframe_poses), 1, 1)) if corrections is None else corrections
    stamps = np.array([scan.stamp_ns for scan in scans])
    corrected = correct_scan_poses(
        stamps, poses, stamps[::KEYFRAME_EVERY], keyframe_poses, corrections @ keyframe_poses
    )
    reference = DenseMap(config)
    for i, (scan, T) in enumerate(zip(scans, poses)):
        k = i // KEYFRAME_EVERY
        dense_map.add(scan, T, np.zeros(6), MapAnchor(k, keyframe_poses[k]))
        reference.add(scan, corrected[i], np.zeros(6))
    dense_map.finish()
    reference.finish()
    assert pieces.n_pieces == len(keyframe_poses)
    return dense_map, corrections @ keyframe_poses, reference


def test_unmoved_keyframes_give_back_the_map_as_placed(city):
    scans, poses = city
    dense_map, keyframe_poses, _ = _maps(scans, poses)
    live = [m.points_and_intensity() for m in (dense_map.static, dense_map.dynamic)]
    live_counts = [m.voxel_counts() for m in (dense_map.static, dense_map.dynamic)]
    dense_map.place_again(keyframe_poses)
    for (points, intensity), (keys, counts), voxel_map in zip(live, live_counts, (dense_map.static, dense_map.dynamic)):
        again_keys, again_counts = voxel_map.voxel_counts()
        again_points, again_intensity = voxel_map.points_and_intensity()
        # Placing again composes the same poses in another order: a point within rounding
        # (1e-12 m) of a voxel face may land in the neighbouring voxel (one in 70,000 did, with
        # another NumPy build); every other voxel holds the same points.
        _, here, there = np.intersect1d(again_keys, keys, assume_unique=True, return_indices=True)
        assert max(len(keys), len(again_keys)) - len(here) <= max(2, len(keys) // 10_000)
        assert again_counts.sum() == counts.sum()
        same = again_counts[here] == counts[there]
        assert np.count_nonzero(~same) <= max(4, len(keys) // 5_000)
        np.testing.assert_allclose(again_points[here][same], points[there][same], atol=1e-4)
        np.testing.assert_allclose(again_intensity[here][same], intensity[there][same], atol=1e-3)
    assert len(dense_map.dynamic) > 100  # the traffic is still taken out


def test_moved_keyframes_move_the_map_as_a_rebuild_with_the_moved_poses(city):
    scans, poses = city
    n_keyframes = -(-len(scans) // KEYFRAME_EVERY)
    dense_map, keyframe_poses, reference = _maps(scans, poses, _corrections(n_keyframes))
    live_dynamic = len(dense_map.dynamic)
    before = dense_map.static.points_and_intensity()[0]
    dense_map.place_again(keyframe_poses)
    placed = dense_map.static.points_and_intensity()[0]
    expected = reference.static.points_and_intensity()[0]
    # Piece voxels move whole: the placed map lies on the rebuild's surfaces within about a voxel.
    to_expected = cKDTree(expected).query(placed)[0]
    to_placed = cKDTree(placed).query(expected)[0]
    assert np.median(to_expected) < 0.05 and np.quantile(to_expected, 0.99) < 0.25, np.quantile(
        to_expected, [0.5, 0.99]
    )
    assert np.median(to_placed) < 0.05 and np.quantile(to_placed, 0.99) < 0.25, np.quantile(to_placed, [0.5, 0.99])
    assert np.median(cKDTree(expected).query(before)[0]) > 2 * np.median(to_expected)  # the correction moved it
    # Moving objects stay out of the placed map, where the rebuild takes them out.
    moved = dense_map.dynamic.points_and_intensity()[0]
    assert abs(len(moved) / live_dynamic - 1.0) < 0.2
    assert np.median(cKDTree(reference.dynamic.points_and_intensity()[0]).query(moved)[0]) < 0.1


def test_a_piece_closes_when_its_keyframe_moves():
    store = MemoryPieceStore()
    pieces = MapPieces(0.2, store)
    points = np.array([[1.0, 2.0, 3.0], [1.05, 2.05, 3.05], [5.0, 0.0, 0.0]])
    intensity = np.array([10.0, 20.0, 30.0])
    dynamic = np.array([False, False, True])
    moved = np.eye(4)
    moved[0, 3] = 1.0
    pieces.add_points(MapAnchor(0, np.eye(4)), points, intensity, dynamic)
    pieces.add_points(MapAnchor(0, np.eye(4)), points, intensity, dynamic)
    pieces.add_points(MapAnchor(0, moved), points, intensity, dynamic)  # a loop closure moved keyframe 0
    pieces.close()
    first, second = store.pieces()
    assert first.keyframe == second.keyframe == 0
    np.testing.assert_array_equal(first.count, [4, 2])
    np.testing.assert_array_equal(first.dynamic, [False, True])
    np.testing.assert_allclose(first.points_keyframe[0], [1.025, 2.025, 3.025], atol=1e-6)
    np.testing.assert_allclose(second.points_keyframe[0], [0.025, 2.025, 3.025], atol=1e-6)  # in the keyframe's frame
    np.testing.assert_allclose(first.intensity, [15.0, 30.0])


def test_a_map_in_pieces_needs_anchors_and_one_without_cannot_be_placed_again(city):
    scans, poses = city
    config = Config()
    with pytest.raises(ValueError, match="anchor"):
        DenseMap(config, MapPieces(config.mapping.map_voxel_m)).add(scans[0], poses[0], np.zeros(6))
    with pytest.raises(ValueError, match="not kept in pieces"):
        DenseMap(config).place_again(poses[:1])


def test_spilled_pieces_read_back_as_put(tmp_path):
    rng = np.random.default_rng(0)
    pieces = [
        MapPiece(
            keyframe,
            rng.normal(size=(n, 3)).astype(np.float32),
            rng.random(n).astype(np.float32),
            rng.integers(1, 50, n).astype(np.int32),
            rng.random(n) < 0.1,
        )
        for keyframe, n in ((None, 5), (0, 100), (7, 0), (8, 3000))
    ]
    with SpilledPieceStore(tmp_path) as store:
        for piece in pieces:
            store.put(piece)
        assert len(store) == 4 and store.nbytes == sum(p.nbytes for p in pieces)
        assert not list(tmp_path.iterdir())  # the file has no name on disk
        for _ in range(2):  # readable more than once
            for back, piece in zip(store.pieces(), pieces, strict=True):
                assert back.keyframe == piece.keyframe
                for field in ("points_keyframe", "intensity", "count", "dynamic"):
                    np.testing.assert_array_equal(getattr(back, field), getattr(piece, field))
                    assert getattr(back, field).dtype == getattr(piece, field).dtype


def _pieces(n_pieces: int) -> list[MapPiece]:
    rng = np.random.default_rng(n_pieces)
    return [
        MapPiece(
            k,
            rng.normal(size=(50, 3)).astype(np.float32),
            rng.random(50).astype(np.float32),
            np.ones(50, np.int32),
            np.zeros(50, bool),
        )
        for k in range(n_pieces)
    ]


def _assert_same(back, pieces):
    assert len(back) == len(pieces)
    for b, p in zip(back, pieces, strict=True):
        assert b.keyframe == p.keyframe
        np.testing.assert_array_equal(b.points_keyframe, p.points_keyframe)


def test_a_spill_folder_that_cannot_hold_the_file_keeps_the_pieces_in_memory(tmp_path, caplog):
    pieces = _pieces(3)
    with SpilledPieceStore(tmp_path / "missing") as store:
        for piece in pieces:
            store.put(piece)
        _assert_same(list(store.pieces()), pieces)
    assert "keeping them in memory" in caplog.text


def test_a_spill_file_that_fails_midway_keeps_what_it_holds_and_the_rest_in_memory(tmp_path, caplog, monkeypatch):
    pieces = _pieces(4)
    with SpilledPieceStore(tmp_path) as store:
        store.put(pieces[0])
        store.put(pieces[1])
        real_save = np.save
        calls = []

        def full_disk(file, array, **kwargs):
            calls.append(1)
            if len(calls) == 3:  # halfway through the third piece
                raise OSError(28, "No space left on device")
            real_save(file, array, **kwargs)

        monkeypatch.setattr(np, "save", full_disk)
        store.put(pieces[2])
        store.put(pieces[3])
        monkeypatch.setattr(np, "save", real_save)
        _assert_same(list(store.pieces()), pieces)
    assert "No space left on device" in caplog.text


class _UnreadableStore(MemoryPieceStore):
    def pieces(self):
        raise OSError(5, "Input/output error")


def test_pieces_that_cannot_be_read_back_leave_the_map_as_placed(city, caplog):
    scans, poses = city
    config = Config()
    dense_map = DenseMap(config, MapPieces(config.mapping.map_voxel_m, _UnreadableStore()))
    for scan, T in zip(scans[:5], poses[:5]):
        dense_map.add(scan, T, np.zeros(6), MapAnchor(0, poses[0]))
    dense_map.finish()
    as_placed = dense_map.static.voxel_counts()
    dense_map.place_again(poses[:1] @ _corrections(2)[1])
    np.testing.assert_array_equal(dense_map.static.voxel_counts()[0], as_placed[0])
    assert "cannot be read back" in caplog.text
