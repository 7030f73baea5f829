"""The Tracker on its own, and the keyframe selector: one verb, a record out, state kept small.

Works on the first 2 s of the simulator's ``loop`` scenario (20 sweeps).
"""

import numpy as np
import pytest

from lidar3d.config import Config
from lidar3d.features.frontend import prepare_scan
from lidar3d.mapping.keyframes import Keyframe, KeyframeSelector, Submap
from lidar3d.mapping.se3 import exp_se3, invert
from lidar3d.mapping.sweep import SweepFeatures
from lidar3d.mapping.tracker import Tracker
from lidar3d.pipeline import run_slam

sim = pytest.importorskip("lidar3d.sim")


@pytest.fixture(scope="module")
def prepared():
    simulation = sim.Simulation("loop", seed=0, duration_s=2.0)
    config = Config()
    return [prepare_scan(s.scan, config) for s in simulation.scans()], simulation.ground_truth


def test_track_records_and_settling(prepared):
    """Each result is a frozen record; from the second scan on it settles the previous sweep; the
    first scan sits at the origin and a registration runs once the submap has a keyframe."""
    scans, truth = prepared
    config = Config()
    submap = Submap.of_config(config.mapping)
    tracker = Tracker(config, submap)
    results = []
    for k, p in enumerate(scans):
        result = tracker.track(p)
        results.append(result)
        if k == 0:
            assert result.settled is None and result.registration is None
            assert np.array_equal(result.T_world_lidar, np.eye(4))
            deskewed = SweepFeatures.of(p).deskewed(result.deskew_twist)
            corner, surf = deskewed.keyframe_clouds(config.mapping)
            submap.add(Keyframe(0, 0, p.scan.stamp_ns, result.T_world_lidar, corner, surf))
        else:
            assert result.settled is not None
            assert result.settled.scan is scans[k - 1].scan
            assert {"deskew", "odometry", "mapping", "redeskew"} <= set(result.timings_ms)
    with pytest.raises(AttributeError):
        results[1].T_world_lidar = np.eye(4)  # frozen
    assert all(r.registration is not None for r in results[1:])
    last = tracker.finish()
    assert last is not None and last.scan is scans[-1].scan and not last.revised
    assert tracker.finish() is None  # the last sweep is handed out once
    # Against one keyframe only, 2 s of driving still stays within a few centimetres.
    truth_rel = invert(truth.T_world_lidar[0]) @ truth.T_world_lidar[len(scans) - 1]
    assert np.linalg.norm(results[-1].T_world_lidar[:3, 3] - truth_rel[:3, 3]) < 0.1


def test_apply_correction_moves_where_tracking_continues(prepared):
    """A correction applied between two scans moves the next pose by the same rigid motion."""
    scans, _ = prepared
    config = Config()
    plain, moved = (Tracker(config, Submap.of_config(config.mapping)) for _ in range(2))
    for p in scans[:3]:
        plain.track(p)
        moved.track(p)
    correction = exp_se3(np.array([0.5, -0.2, 0.0, 0.0, 0.0, 0.05]))
    moved.apply_correction(correction)
    a = plain.track(scans[3])
    b = moved.track(scans[3])
    assert np.allclose(b.T_world_lidar, correction @ a.T_world_lidar, atol=1e-6)
    assert np.allclose(b.settled.T_world_lidar, correction @ a.settled.T_world_lidar, atol=1e-9)
    assert np.array_equal(a.T_world_odom, b.T_world_odom)  # odometry alone is not corrected


def test_pipeline_is_the_tracker_plus_keyframes(prepared):
    """The pipeline's poses are the tracker's, settled: run_slam on prepared scans equals raw scans."""
    scans, _ = prepared
    from_prepared = run_slam(scans)
    from_raw = run_slam([p.scan for p in scans])
    assert np.array_equal(from_prepared.trajectory.T_world_lidar, from_raw.trajectory.T_world_lidar)
    assert from_raw.counts["scans"] == len(scans)


def test_keyframe_selector_spacing():
    selector = KeyframeSelector(distance_m=1.0, angle_deg=10.0, min_surface_points=50)
    assert not selector.is_due(np.eye(4), n_surface_points=49)  # too little to match against
    assert selector.is_due(np.eye(4), n_surface_points=50)  # nothing selected yet
    selector.anchor(np.eye(4))
    step = np.eye(4)
    step[0, 3] = 0.99
    assert not selector.is_due(step, 500)
    step[0, 3] = 1.0
    assert selector.is_due(step, 500)
    turn = exp_se3(np.array([0.0, 0.0, 0.0, 0.0, 0.0, np.radians(10.5)]))
    assert selector.is_due(turn, 500)
    selector.anchor(turn)
    assert not selector.is_due(turn, 500)
