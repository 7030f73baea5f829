"""The SLAM pipeline on simulated VLP-16 sweeps: accuracy, result records, bad input.

Every test works on the first seconds of the simulator's ``loop`` scenario (ray cast once per
module, about 30 sweeps), so the whole file runs in a few tens of seconds on two cores.
"""

import dataclasses
import logging

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar3d.config import Config
from lidar3d.pipeline import SlamPipeline, run_slam

sim = pytest.importorskip("lidar3d.sim")

N_SCANS = 30
STRETCH = range(10, 15)  # featureless sweeps in the bad-input tests
N_BAD_INPUT = 22


@pytest.fixture(scope="module")
def drive():
    """The first 3 s of the loop: (simulated sweeps, ground-truth lidar trajectory)."""
    simulation = sim.Simulation("loop", seed=0, duration_s=3.0)
    sweeps = list(simulation.scans())
    assert len(sweeps) == N_SCANS
    return sweeps, simulation.ground_truth


@pytest.fixture(scope="module")
def result(drive):
    sweeps, _ = drive
    return run_slam([s.scan for s in sweeps])


def _end_error(truth, trajectory) -> float:
    """Metres between the estimated and the true end of the drive, both anchored at its start."""
    T = np.linalg.inv(trajectory.T_world_lidar[0]) @ trajectory.T_world_lidar[-1]
    T_true = np.linalg.inv(truth.T_world_lidar[0]) @ truth.T_world_lidar[N_SCANS - 1]
    return float(np.linalg.norm(T[:3, 3] - T_true[:3, 3]))


@pytest.fixture
def caplog(caplog, monkeypatch):
    """caplog that sees the package's records even after a CLI test set up its own handler."""
    monkeypatch.setattr(logging.getLogger("lidar3d"), "propagate", True)
    return caplog


def _empty(simulated):
    return simulated.scan.select(np.zeros(len(simulated.scan), dtype=bool))


def _far_ground_only(simulated, min_range_m=20.0):
    """Only the ground beyond ``min_range_m``: a few hundred points, no edge, no usable plane."""
    return simulated.scan.select(simulated.ground_mask & (simulated.scan.range_m > min_range_m))


def _featureless_stretch(sweeps):
    """Sweeps 10-12 empty and 13-14 far ground only, the rest untouched."""
    scans = [s.scan for s in sweeps[:N_BAD_INPUT]]
    for i in STRETCH:
        scans[i] = _empty(sweeps[i]) if i < 13 else _far_ground_only(sweeps[i])
    return scans


@pytest.fixture(scope="module")
def featureless(drive):
    """(pipeline, result) after the sweeps with a featureless stretch."""
    sweeps, _ = drive
    pipeline = SlamPipeline(Config())
    for scan in _featureless_stretch(sweeps):
        pipeline.process(scan)
    pipeline.finish()
    return pipeline, pipeline.result()


def _first_pose_aligned(trajectory, ground_truth):
    """Estimated poses in the ground-truth frame, anchored at the first pose."""
    return ground_truth.T_world_lidar[0] @ trajectory.T_world_lidar


def _kabsch_aligned(estimate_xyz, reference_xyz):
    """Estimate positions rigidly aligned onto the reference (Umeyama without scale)."""
    mu_e, mu_r = estimate_xyz.mean(axis=0), reference_xyz.mean(axis=0)
    u, _, vt = np.linalg.svd((reference_xyz - mu_r).T @ (estimate_xyz - mu_e))
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    R = u @ d @ vt
    return (estimate_xyz - mu_e) @ R.T + mu_r


def _rotation_error_deg(T_a, T_b):
    """(N,) angle of R_a^T R_b per pose pair, degrees."""
    R = np.einsum("nji,njk->nik", T_a[:, :3, :3], T_b[:, :3, :3])
    return np.degrees(np.linalg.norm(Rotation.from_matrix(R).as_rotvec(), axis=1))


def _assert_valid_poses(poses):
    assert np.all(np.isfinite(poses))
    R = poses[:, :3, :3]
    assert np.allclose(R @ R.transpose(0, 2, 1), np.eye(3), atol=1e-6)
    assert np.allclose(np.linalg.det(R), 1.0, atol=1e-6)
    assert np.allclose(poses[:, 3, :], [0.0, 0.0, 0.0, 1.0])


# -- accuracy smoke ----------------------------------------------------------------------------


def test_every_scan_gets_a_pose(drive, result):
    _, truth = drive
    assert len(result.trajectory) == N_SCANS and len(result.odometry) == N_SCANS
    assert np.array_equal(result.trajectory.stamps_ns, truth.stamps_ns)
    assert np.array_equal(result.odometry.stamps_ns, truth.stamps_ns)
    for trajectory in (result.trajectory, result.odometry):
        _assert_valid_poses(trajectory.T_world_lidar)
        assert np.allclose(trajectory.T_world_lidar[0], np.eye(4))  # the world is the first lidar pose
    assert result.counts["scans"] == N_SCANS
    assert result.counts.get("motion_model_scans", 0) == 0 and not result.warnings
    assert not result.partial


def test_refined_trajectory_matches_ground_truth(drive, result):
    _, truth = drive
    true_xyz = truth.positions_m
    aligned = _kabsch_aligned(result.trajectory.positions_m, true_xyz)
    error = np.linalg.norm(aligned - true_xyz, axis=1)
    assert np.sqrt(np.mean(error**2)) < 0.03 and error.max() < 0.06, error
    anchored = _first_pose_aligned(result.trajectory, truth)
    drift = np.linalg.norm(anchored[:, :3, 3] - true_xyz, axis=1)
    assert drift.max() < 0.10, drift  # about 11 m driven
    assert _rotation_error_deg(anchored, truth.T_world_lidar).max() < 0.5
    assert result.trajectory.path_length_m == pytest.approx(truth.path_length_m, rel=0.02)


def test_sweeps_are_redeskewed_with_the_motion_over_them(drive, result):
    """The drive starts from rest: while the car speeds up, the prediction (the motion before a
    sweep) lags the motion over it, so sweeps are re-registered once the next pose is known, and
    the drift is smaller than without that pass."""
    sweeps, truth = drive
    config = Config()
    without = dataclasses.replace(config, mapping=dataclasses.replace(config.mapping, redeskew_threshold_m=np.inf))
    plain = run_slam([s.scan for s in sweeps], without)
    assert result.counts["redeskewed_scans"] >= N_SCANS // 2
    assert "redeskewed_scans" not in plain.counts

    assert _end_error(truth, result.trajectory) < 0.7 * _end_error(truth, plain.trajectory)


def test_odometry_trajectory_is_sane(drive, result):
    _, truth = drive
    assert result.odometry.path_length_m == pytest.approx(truth.path_length_m, rel=0.05)
    anchored = _first_pose_aligned(result.odometry, truth)
    drift = np.linalg.norm(anchored[:, :3, 3] - truth.positions_m, axis=1)
    assert drift.max() < 0.05 * truth.path_length_m, drift
    assert _rotation_error_deg(anchored, truth.T_world_lidar).max() < 5.0  # scan-to-scan drifts; refinement fixes it


def test_keyframes_are_scans_of_the_trajectory(result):
    indices = result.keyframe_scan_indices
    assert len(result.keyframes) == len(indices) >= 2
    assert indices[0] == 0 and np.all(np.diff(indices) > 0)
    assert np.array_equal(result.keyframes.stamps_ns, result.trajectory.stamps_ns[indices])
    assert np.allclose(result.keyframes.T_world_lidar, result.trajectory.T_world_lidar[indices])


def test_keyframes_are_spaced_by_the_selection_rule(result):
    """Each keyframe lies at least keyframe_distance_m or keyframe_angle_deg from the one before."""
    mapping = Config().mapping
    poses = result.keyframes.T_world_lidar
    moved_m = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    turned_deg = _rotation_error_deg(poses[:-1], poses[1:])
    too_close = (moved_m < mapping.keyframe_distance_m) & (turned_deg < mapping.keyframe_angle_deg)
    assert not too_close.any(), (
        f"keyframes {result.keyframe_scan_indices.tolist()} at steps {np.round(moved_m, 2).tolist()} m"
    )
    assert len(poses) <= result.trajectory.path_length_m / mapping.keyframe_distance_m + 1


def test_map_is_dense_and_z_up(result):
    points, intensity = result.map_points, result.map_intensity
    assert points.ndim == 2 and points.shape[1] == 3 and len(points) > 10_000
    assert intensity.shape == (len(points),) and np.all(np.isfinite(intensity)) and np.ptp(intensity) > 0
    # The world is the first lidar pose: the ground lies about one mounting height below it.
    near = np.linalg.norm(points[:, :2], axis=1) < 5.0
    assert -3.0 < np.median(points[near, 2]) < -0.5
    assert np.ptp(points[:, 2]) < 0.5 * min(np.ptp(points[:, 0]), np.ptp(points[:, 1]))


# -- bad input ---------------------------------------------------------------------------------


def test_featureless_stretch_falls_back_to_the_motion_model(drive, featureless):
    _, truth = drive
    pipeline, result = featureless
    assert len(result.trajectory) == N_BAD_INPUT  # every sweep, empty ones included, has a pose
    assert np.array_equal(result.trajectory.stamps_ns, truth.stamps_ns[:N_BAD_INPUT])
    _assert_valid_poses(result.trajectory.T_world_lidar)
    flagged = [e.scan_index for e in pipeline.estimates if e.motion_model_only]
    assert flagged == list(STRETCH)
    assert result.counts["motion_model_scans"] == len(STRETCH)
    fallback, *health = result.warnings
    assert fallback == "scans 10-14: too few features, pose from the motion model"
    # The health may call scans near the stretch degraded, in a line of its own; none is lost.
    assert all(line.startswith("health: degraded on ") for line in health)

    # No jump: each step stays close to the true step, and the pose error stays bounded.
    poses = result.trajectory.T_world_lidar
    step = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
    true_step = np.linalg.norm(np.diff(truth.positions_m[:N_BAD_INPUT], axis=0), axis=1)
    assert np.abs(step - true_step).max() < 0.2, step - true_step
    # Across the stretch the motion is one constant velocity: the motion model's prediction from
    # the last good sweeps (their smoothed twist). The step into the stretch may differ: the last
    # good sweep is re-registered once the motion over it is known, after the first blind one
    # was placed from its earlier pose.
    first = np.linalg.inv(poses[STRETCH.start]) @ poses[STRETCH.start + 1]
    for i in STRETCH[1:]:
        delta = np.linalg.inv(poses[i - 1]) @ poses[i]
        assert np.allclose(delta, first, atol=1e-6), i
    anchored = _first_pose_aligned(result.trajectory, truth)
    error = np.linalg.norm(anchored[:, :3, 3] - truth.positions_m[:N_BAD_INPUT], axis=1)
    assert error.max() < 0.3, error  # the vehicle accelerates; constant velocity lags behind
    assert error[STRETCH.stop + 3 :].max() < 0.1, error  # back on the map after the stretch


def test_featureless_stretch_is_logged(drive, caplog):
    sweeps, _ = drive
    pipeline = SlamPipeline(Config())
    with caplog.at_level(logging.WARNING, logger="lidar3d"):
        for scan in _featureless_stretch(sweeps)[8:17]:  # sweeps 8-16: the stretch is 2-6 here
            pipeline.process(scan)
    messages = [r.getMessage() for r in caplog.records if r.name == "lidar3d.run_statistics"]
    assert messages == ["scans 2-6: too few features, pose from the motion model"]


def test_result_mid_run_changes_nothing(drive, featureless):
    """result() is a snapshot (checkpoints call it): the run after it goes on exactly as without."""
    sweeps, _ = drive
    _, reference = featureless
    pipeline = SlamPipeline(Config())
    for k, scan in enumerate(_featureless_stretch(sweeps), start=1):
        pipeline.process(scan)
        snapshot = pipeline.result(partial=True)
        assert snapshot.partial and len(snapshot.trajectory) == k
    pipeline.finish()
    final = pipeline.result()
    assert not final.partial
    assert final.warnings == reference.warnings
    assert final.counts == reference.counts
    assert np.array_equal(final.keyframe_scan_indices, reference.keyframe_scan_indices)
    assert np.allclose(final.trajectory.T_world_lidar, reference.trajectory.T_world_lidar, atol=1e-9)
    assert len(final.map_points) == len(reference.map_points)


def test_a_snapshot_without_the_map_does_not_fetch_it(featureless, monkeypatch):
    """Checkpoints that do not write the map take their snapshot without it: nothing is asked of the
    map (in ``lidar3d run`` it lives in another process and comes back pickled whole)."""
    pipeline, reference = featureless
    assert len(reference.map_points) > 0

    def refuse():
        raise AssertionError("the map was fetched")

    monkeypatch.setattr(pipeline._map, "clouds", refuse)
    snapshot = pipeline.result(partial=True, with_map=False)
    assert snapshot.map_points.shape == (0, 3) and snapshot.dynamic_points.shape == (0, 3)
    assert len(snapshot.map_intensity) == 0 and len(snapshot.dynamic_intensity) == 0
    assert np.array_equal(snapshot.trajectory.T_world_lidar, reference.trajectory.T_world_lidar)


def test_featureless_start_recovers_once_features_appear(drive):
    """A bag whose first sweeps are empty: once features come, SLAM works as from a fresh start."""
    sweeps, truth = drive
    first_good, n = 3, 18
    pipeline = SlamPipeline(Config())
    for i, simulated in enumerate(sweeps[:n]):
        pipeline.process(_empty(simulated) if i < first_good else simulated.scan)
    pipeline.finish()
    result = pipeline.result()
    assert len(result.trajectory) == n
    flagged = [e.scan_index for e in pipeline.estimates if e.motion_model_only]
    assert all(i <= first_good for i in flagged), flagged
    # From the first sweep with features on, the motion is the true motion.
    est = np.linalg.inv(result.trajectory.T_world_lidar[first_good]) @ result.trajectory.T_world_lidar[first_good:]
    ref = np.linalg.inv(truth.T_world_lidar[first_good]) @ truth.T_world_lidar[first_good:n]
    error = np.linalg.norm(est[:, :3, 3] - ref[:, :3, 3], axis=1)
    assert error.max() < 0.1, error


def test_duplicate_and_out_of_order_stamps_are_dropped(drive, caplog):
    sweeps, _ = drive
    scans = [s.scan for s in sweeps[:8]]

    def restamped(scan, stamp_ns):
        return type(scan)(stamp_ns, scan.points, scan.intensity, scan.ring, scan.time_offset_s)

    # Other sweeps' points under a stale stamp: fed through, they would bend the trajectory.
    duplicate = restamped(scans[6], scans[2].stamp_ns)
    stale = restamped(scans[7], scans[1].stamp_ns)
    stream = [scans[0], scans[1], scans[2], duplicate, scans[3], stale, scans[4], scans[5]]
    pipeline = SlamPipeline(Config())
    with caplog.at_level(logging.WARNING, logger="lidar3d"):
        returned = [pipeline.process(scan) for scan in stream]
    assert [r is None for r in returned] == [False, False, False, True, False, True, False, False]
    assert [r.scan_index for r in returned if r is not None] == [0, 1, 2, 4, 6, 7]
    pipeline.finish()
    result = pipeline.result()
    assert result.counts["dropped_duplicate_stamps"] == 1
    assert result.counts["dropped_out_of_order_stamps"] == 1
    assert result.counts["scans"] == 6
    assert np.array_equal(result.trajectory.stamps_ns, [s.stamp_ns for s in scans[:6]])
    text = caplog.text
    assert "scan 3: duplicate stamp" in text and "scan 5: out-of-order stamp" in text

    clean = run_slam(scans[:6])
    assert np.allclose(result.trajectory.T_world_lidar, clean.trajectory.T_world_lidar, atol=1e-9)
    assert np.allclose(result.odometry.T_world_lidar, clean.odometry.T_world_lidar, atol=1e-9)
    assert len(result.map_points) == len(clean.map_points)


def test_the_moving_point_test_runs_in_the_pipeline_and_keeps_a_static_drive(drive, result):
    """With ``mapping.moving_probe_keyframes`` set, a drive through a static town is tracked as
    well as without it (the test finds next to nothing to remove there)."""
    sweeps, truth = drive
    config = Config()
    on = dataclasses.replace(config, mapping=dataclasses.replace(config.mapping, moving_probe_keyframes=8))
    with_test = run_slam([s.scan for s in sweeps], on)

    assert len(with_test.trajectory) == N_SCANS
    assert _end_error(truth, with_test.trajectory) < max(0.05, 1.5 * _end_error(truth, result.trajectory))
