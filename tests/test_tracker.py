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
    """A correction applied between two scans (a loop closure moving the submap and the latest
    pose rigidly) moves the next pose, and the settled sweep, by the same rigid motion."""
    scans, _ = prepared
    config = Config()
    submaps = [Submap.of_config(config.mapping) for _ in range(2)]
    plain, moved = (Tracker(config, submap) for submap in submaps)
    first = SweepFeatures.of(scans[0]).keyframe_clouds(config.mapping)
    for submap in submaps:
        submap.add(Keyframe(0, 0, scans[0].scan.stamp_ns, np.eye(4), *first))
    for p in scans[:4]:
        plain.track(p)
        moved.track(p)
    correction = exp_se3(np.array([0.5, -0.2, 0.0, 0.0, 0.0, 0.05]))
    moved.apply_correction(correction)
    submaps[1].set_poses(correction[None] @ submaps[0].poses)
    submaps[0].set_poses(submaps[0].poses)  # the same change of revision: both settle by a new search
    a = plain.track(scans[4])
    b = moved.track(scans[4])
    assert a.registration is not None and a.settled is not None and a.settled.revised
    # Equal to a fraction of a millimetre (the submap's nearest neighbours, searched in a rotated
    # frame, are not bit for bit the same).
    assert np.allclose(b.T_world_lidar, correction @ a.T_world_lidar, atol=2e-3)
    assert np.allclose(b.settled.T_world_lidar, correction @ a.settled.T_world_lidar, atol=2e-3)
    assert np.array_equal(a.T_world_odom, b.T_world_odom)  # odometry alone is not corrected


def _tracked_with_first_keyframe(scans, config: Config, n: int) -> tuple[Tracker, Submap]:
    """A tracker whose submap holds the first sweep as keyframe 0, after tracking ``n`` scans."""
    submap = Submap.of_config(config.mapping)
    submap.add(
        Keyframe(0, 0, scans[0].scan.stamp_ns, np.eye(4), *SweepFeatures.of(scans[0]).keyframe_clouds(config.mapping))
    )
    tracker = Tracker(config, submap)
    for p in scans[:n]:
        tracker.track(p)
    return tracker, submap


@pytest.mark.parametrize("change", ["clouds", "poses"])
def test_a_sweep_settles_on_the_submap_as_it_is_now(prepared, change):
    """The settled sweep is registered again on the correspondences its registration found, unless
    the submap changed under them since (its keyframe's clouds replaced, or its pose corrected by a
    loop closure, which moves each keyframe by its own correction): then it searches anew. Here the
    only keyframe moves 0.1 m up after the sweep was registered; the settled pose moves up with it
    (4 cm in the 4 iterations of a re-registration without a prior, which keeps part of its guess;
    on the correspondences held from before the move it went 5 cm down)."""
    scans, _ = prepared
    config = Config()
    plain, _ = _tracked_with_first_keyframe(scans, config, 4)
    shifted, submap = _tracked_with_first_keyframe(scans, config, 4)
    shift = exp_se3(np.array([0.0, 0.0, 0.1, 0.0, 0.0, 0.0]))
    if change == "poses":
        submap.set_poses(shift[None] @ submap.poses)
    else:
        corner, surf = submap.keyframes[0].corner_points, submap.keyframes[0].surf_points
        submap.replace_clouds(0, corner + np.float32([0.0, 0.0, 0.1]), surf + np.float32([0.0, 0.0, 0.1]))
    a, b = plain.track(scans[4]), shifted.track(scans[4])
    assert a.settled is not None and a.settled.revised and b.settled is not None and b.settled.revised
    moved_m = b.settled.T_world_lidar[:3, 3] - a.settled.T_world_lidar[:3, 3]
    assert moved_m[2] > 0.02


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
