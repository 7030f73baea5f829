"""The dense map built in a child process (lidar3d.map_process) against the map built in the
pipeline's process: bit-identical clouds, errors raised again in the parent, a dead child reported."""

import numpy as np
import pytest

from lidar3d.config import Config
from lidar3d.errors import Lidar3dError
from lidar3d.map_process import DenseMapProcess
from lidar3d.mapping.dense_map import DenseMap
from lidar3d.mapping.map_pieces import MapAnchor, MapPieces
from lidar3d.mapping.se3 import exp_se3
from lidar3d.pipeline import SlamPipeline
from lidar3d.sim import Simulation

KEYFRAME_EVERY = 4  # sweeps


@pytest.fixture(scope="module")
def city():
    """1.6 s of city_traffic (moving cars for the dynamic filter): (scans, true poses)."""
    sim = Simulation("city_traffic", seed=0, duration_s=1.6)
    sweeps = list(sim.scans())
    return [s.scan for s in sweeps], np.array([s.T_world_lidar for s in sweeps])


def _twist(i: int) -> np.ndarray:
    return np.array([5.0, 0.1, 0.0, 0.0, 0.0, 0.02 * (i % 3)])


def _assert_same_clouds(a, b) -> None:
    for name in ("points", "intensity", "dynamic_points", "dynamic_intensity"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def test_the_map_built_in_a_process_is_bit_identical_also_placed_again(city):
    scans, poses = city
    config = Config()
    inline = DenseMap(config, MapPieces(config.mapping.map_voxel_m))
    sweep_ms = []
    child = DenseMapProcess(config, in_pieces=True, on_sweep_ms=sweep_ms.append)
    try:
        keyframe_poses = poses[::KEYFRAME_EVERY]
        for i, (scan, T) in enumerate(zip(scans, poses)):
            anchor = MapAnchor(i // KEYFRAME_EVERY, keyframe_poses[i // KEYFRAME_EVERY])
            inline.add(scan, T, _twist(i), anchor)
            child.add(scan, T, _twist(i), anchor)
            if i == len(scans) // 2:  # a checkpoint mid-run
                _assert_same_clouds(child.clouds(), inline.clouds())
        assert len(sweep_ms) == len(scans) // 2 + 1  # the timings of the sweeps taken so far
        inline.finish()
        child.finish()
        _assert_same_clouds(child.clouds(), inline.clouds())
        assert len(inline.dynamic) > 0  # the traffic is taken out
        moved = np.array(
            [exp_se3(np.array([0.2 * k, 0.0, 0.0, 0.0, 0.0, 0.002 * k])) for k in range(len(keyframe_poses))]
        )
        inline.place_again(moved @ keyframe_poses)
        child.place_again(moved @ keyframe_poses)
        _assert_same_clouds(child.clouds(), inline.clouds())
        assert len(sweep_ms) == len(scans)
    finally:
        child.close()
    child.close()  # idempotent


def test_a_pipeline_with_its_map_in_a_process_gives_the_same_result(city):
    scans, _ = city
    results = []
    scans = scans[:10]
    for map_in_process in (False, True):
        pipeline = SlamPipeline(Config(), map_in_process=map_in_process)
        for scan in scans:
            pipeline.process(scan)
        pipeline.result()  # a checkpoint
        pipeline.finish()
        results.append(pipeline.result())
    assert not pipeline._map._process.is_alive()  # the map is final: its process ended
    inline, child = results
    np.testing.assert_array_equal(child.trajectory.T_world_lidar, inline.trajectory.T_world_lidar)
    for name in ("map_points", "map_intensity", "dynamic_points", "dynamic_intensity"):
        np.testing.assert_array_equal(getattr(child, name), getattr(inline, name), err_msg=name)
    assert "dense_map" not in inline.timings_ms
    assert len(child.timings_ms["dense_map"]) == len(scans)


def test_an_error_in_the_child_is_raised_at_the_next_request(city):
    scans, poses = city
    child = DenseMapProcess(Config(), in_pieces=True)
    try:
        child.add(scans[0], poses[0], np.zeros(6), None)  # a map in pieces needs an anchor
        child.add(scans[1], poses[1], np.zeros(6), MapAnchor(None, np.eye(4)))
        with pytest.raises(ValueError, match="needs the anchor of every sweep"):
            child.clouds()
        with pytest.raises(ValueError, match="needs the anchor of every sweep"):
            child.finish()  # the map stays without the sweeps after the error
    finally:
        child.close()


def test_a_dead_child_is_reported(city):
    scans, poses = city
    child = DenseMapProcess(Config(), in_pieces=False)
    try:
        child._process.kill()
        child._process.join(timeout=10)
        with pytest.raises(Lidar3dError, match=r"the dense map process ended unexpectedly \(exit code -9\)"):
            child.add(scans[0], poses[0], np.zeros(6))
        with pytest.raises(Lidar3dError, match="ended unexpectedly"):
            child.clouds()
    finally:
        child.close()


def test_ctrl_c_does_not_end_the_child_even_while_it_starts(city):
    import os
    import signal

    scans, poses = city
    child = DenseMapProcess(Config(), in_pieces=False)
    try:
        os.kill(child._process.pid, signal.SIGINT)  # as a terminal's Ctrl-C reaches the process group
        child.add(scans[0], poses[0], np.zeros(6))
        os.kill(child._process.pid, signal.SIGINT)
        child.finish()
        assert len(child.clouds().points) > 1000
    finally:
        child.close()


def test_an_empty_map_comes_back_as_empty_clouds():
    child = DenseMapProcess(Config(), in_pieces=False)
    try:
        clouds = child.clouds()
    finally:
        child.close()
    assert clouds.points.shape == (0, 3) and clouds.dynamic_points.shape == (0, 3)
    assert clouds.points.dtype == np.float64 and clouds.intensity.shape == (0,)


def test_the_clouds_pipe_carries_arrays_whole_and_reports_a_cut_transfer():
    import multiprocessing

    from lidar3d.map_process import _receive_arrays, _send_arrays

    arrays = [np.arange(12.0).reshape(4, 3), np.zeros((0, 3)), np.array([1.5, -2.0], np.float32)]
    receiver, sender = multiprocessing.Pipe(duplex=False)
    _send_arrays(sender, arrays)
    back = _receive_arrays(receiver, [(a.shape, a.dtype.str) for a in arrays])
    for a, b in zip(arrays, back):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)
    _send_arrays(sender, arrays[:1])
    sender.close()  # the child ended before the second array
    with pytest.raises(EOFError):
        _receive_arrays(receiver, [(arrays[0].shape, arrays[0].dtype.str)] * 2)


@pytest.mark.parametrize("signum", ["SIGINT", "SIGTERM"])
def test_a_stop_signal_during_a_request_waits_for_its_answer(signum):
    """A transfer cut half way would leave the rest of the map in the pipe (an answer left unread
    would be read as the next one's): Ctrl-C and SIGTERM are held back until the answer is read,
    then delivered, with the handlers found before."""
    import signal

    from lidar3d import stop_signals

    number = getattr(signal, signum)

    # A test run started in the background of a non-interactive shell inherits SIGINT ignored
    # (POSIX), and Python then keeps it ignored: give the test a handler that raises.
    def raising(signum, frame):
        raise KeyboardInterrupt

    inherited = signal.signal(number, raising)
    finished = False
    try:
        with pytest.raises(KeyboardInterrupt), stop_signals.deferred():
            signal.raise_signal(number)  # to this, the main, thread
            finished = True
        assert finished
        assert signal.getsignal(number) is raising
    finally:
        signal.signal(number, inherited)


def test_a_ctrl_c_ignored_from_the_start_stays_ignored_through_the_transfer():
    """Started with SIGINT ignored (nohup, a background job): the deferral neither raises nor
    leaves a handler of its own behind."""
    import signal

    from lidar3d import stop_signals

    inherited = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with stop_signals.deferred():
            signal.raise_signal(signal.SIGINT)
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, inherited)
