"""Loop verification and the LoopCloser on simulated VLP-16 keyframes of the ``loop`` scenario.

Keyframe clouds are full sweeps deskewed with the true motion and voxel-downsampled (0.2 m), posed
with ground truth (exact) or with injected drift, so the correct loop transform is known.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import json
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lidar3d.config import LoopConfig
from lidar3d.errors import ConfigError
from lidar3d.loop import LoopCloser, Verdict, build_match_cloud, correct_scan_poses, verify_loop
from lidar3d.loop.verification import correspondences, loop_information, point_information, voxel_overlap
from lidar3d.mapping.deskew import deskew_scan, twist_between
from lidar3d.mapping.keyframes import Keyframe
from lidar3d.mapping.se3 import exp_se3, invert
from lidar3d.mapping.voxel import voxel_downsample
from lidar3d.sim import Simulation, simulate

CONFIG = LoopConfig()
KEYFRAME_STRIDE = 2  # a keyframe every 2 sweeps (~1.3 m at 6.5 m/s)


@functools.cache
def _sim() -> Simulation:
    return Simulation("loop", seed=0)


@functools.cache
def _cloud(scan_index: int) -> np.ndarray:
    """Sweep ``scan_index`` deskewed to its stamp with the true motion, 1-80 m, 0.2 m voxels."""
    sim = _sim()
    scan = sim.scan(scan_index).scan
    T0, T1 = sim.T_world_lidar_at([scan.stamp_ns, scan.stamp_ns + sim.scan_period_ns])
    straight = deskew_scan(scan, twist_between(T0, T1, sim.scan_period_ns * 1e-9))
    r = np.linalg.norm(straight.points, axis=1)
    return voxel_downsample(straight.points[(r > 1.0) & (r < 80.0)], 0.2)


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def _first_pass_target(match_scan: int, neighbours: int = 10):
    """Target around first-pass keyframe scan ``match_scan`` from true poses (match frame)."""
    gt = _sim().ground_truth.T_world_lidar
    scans = list(
        range(
            max(0, match_scan - neighbours * KEYFRAME_STRIDE),
            match_scan + neighbours * KEYFRAME_STRIDE + 1,
            KEYFRAME_STRIDE,
        )
    )
    clouds = [_cloud(s) for s in scans]
    poses = gt[scans]
    match = scans.index(match_scan)
    return build_match_cloud(clouds, poses, match, np.arange(len(scans)), CONFIG.voxel_m)


@pytest.mark.parametrize("method", ["point_to_plane", "gicp"])
def test_verification_recovers_a_known_offset(method):
    config = dataclasses.replace(CONFIG, icp_method=method)
    sim = _sim()
    gt = sim.ground_truth.T_world_lidar
    query_scan, match_scan = 660, 14  # second pass along the first street, ~1 m apart
    target = _first_pass_target(match_scan)
    T_true = invert(gt[match_scan]) @ gt[query_scan]
    drift = exp_se3(np.array([1.5, -1.0, 0.2, 0.01, -0.01, np.radians(4.0)]))  # 1.8 m, 4° of drift
    result = verify_loop(_cloud(query_scan), target, T_true @ drift, config, max_correction_m=3.0)
    assert result.verdict is Verdict.ACCEPTED, result.reason
    error = invert(T_true) @ result.T_match_query
    assert np.linalg.norm(error[:3, 3]) < 0.03
    assert _angle_deg(error[:3, :3]) < 0.1
    assert result.fitness > 0.9 and result.overlap > 0.9
    assert result.correction_m == pytest.approx(np.linalg.norm(drift[:3, 3]), abs=0.05)
    eigenvalues = np.linalg.eigvalsh(result.information)
    assert eigenvalues.min() > 0
    # the covariance floor: no direction trusted below 2 cm / 0.1°
    covariance = np.linalg.inv(result.information)
    assert np.all(np.sqrt(np.diag(covariance)[3:]) >= CONFIG.min_sigma_translation_m * 0.999)
    assert np.all(np.sqrt(np.diag(covariance)[:3]) >= np.radians(CONFIG.min_sigma_rotation_deg) * 0.999)


@pytest.mark.parametrize("method", ["point_to_plane", "gicp"])
def test_verification_recovers_the_offset_between_two_keyframes(method):
    """Single keyframe clouds 4 sweeps (~5 m) apart, true relative pose from the ground truth, guess
    off by 0.6 m / 2°: ICP lands within 5 mm / 0.1° of the truth (measured: GICP 1.5 mm / 0.03°,
    the same as Open3D's; point-to-plane 2.6 mm / 0.07°, Open3D's with 1.2 m radius normals 51 mm /
    0.23°: one 16-ring sweep pins roll and pitch poorly)."""
    config = dataclasses.replace(CONFIG, icp_method=method)
    gt = _sim().ground_truth.T_world_lidar
    query_scan, match_scan = 18, 14
    target = voxel_downsample(_cloud(match_scan), CONFIG.voxel_m)
    T_true = invert(gt[match_scan]) @ gt[query_scan]
    offset = exp_se3(np.array([0.5, 0.3, 0.1, 0.0, 0.0, np.radians(2.0)]))
    result = verify_loop(_cloud(query_scan), target, T_true @ offset, config)
    assert result.verdict is Verdict.ACCEPTED, result.reason
    error = invert(T_true) @ result.T_match_query
    assert np.linalg.norm(error[:3, 3]) < 0.005
    assert _angle_deg(error[:3, :3]) < 0.1
    assert result.correction_m == pytest.approx(np.linalg.norm(offset[:3, 3]), abs=0.01)


def test_each_stage_registers_a_query_cloud_as_coarse_as_its_distance(monkeypatch):
    """Stage ``d`` sees the query at ``icp_stage_voxel_share * d`` voxels (never finer than
    ``voxel_m``); the last stage and the convergence check see the full cloud; a guess 10 m and 8°
    off along the street still lands on the revisit."""
    import small_gicp

    seen: list[tuple[float, int]] = []
    align = small_gicp.align

    def spy(target, source, *args, **kwargs):
        seen.append((kwargs["max_correspondence_distance"], source.size()))
        return align(target, source, *args, **kwargs)

    monkeypatch.setattr(small_gicp, "align", spy)
    gt = _sim().ground_truth.T_world_lidar
    query_scan, match_scan = 660, 14
    target = _first_pass_target(match_scan)
    T_true = invert(gt[match_scan]) @ gt[query_scan]
    drift = exp_se3(np.array([10.0, 2.0, 0.2, 0.0, 0.0, np.radians(8.0)]))
    result = verify_loop(_cloud(query_scan), target, T_true @ drift, CONFIG, max_correction_m=20.0)
    error = invert(T_true) @ result.T_match_query
    assert result.verdict is Verdict.ACCEPTED, result.reason
    assert np.linalg.norm(error[:3, 3]) < 0.03 and _angle_deg(error[:3, :3]) < 0.1
    base = voxel_downsample(_cloud(query_scan), CONFIG.voxel_m)
    distances = list(CONFIG.icp_max_correspondence_m) + [CONFIG.icp_max_correspondence_m[-1]]
    assert [d for d, _ in seen] == distances
    for distance, size in seen:
        voxel = CONFIG.icp_stage_voxel_share * distance
        assert size == (len(voxel_downsample(base, voxel)) if voxel > CONFIG.voxel_m else len(base))
    assert seen[0][1] < len(base) / 4


def test_correspondences_follow_open3d_definitions_against_ckdtree():
    rng = np.random.default_rng(7)
    target = rng.uniform(-10, 10, (2000, 3))
    source = target[:500] + rng.normal(0, 0.3, (500, 3))
    paired, rmse = correspondences(source, target, 0.5)
    distance, _ = cKDTree(target).query(source)
    expected = np.flatnonzero(distance < 0.5)
    np.testing.assert_array_equal(paired, expected)
    assert rmse == pytest.approx(np.sqrt(np.mean(distance[expected] ** 2)), rel=1e-12)
    none, zero = correspondences(source + 100.0, target, 0.5)
    assert none.size == 0 and zero == 0.0


def test_a_run_with_loop_closure_does_not_import_open3d(tmp_path):
    """Verification runs in ``lidar3d run`` without Open3D (~170 MiB of RSS): a short drive whose
    later keyframes are candidates for its first ones, run in a fresh process."""
    bag = simulate("loop", tmp_path / "sim", seed=0, duration_s=8.0).bag
    out = tmp_path / "run"
    child = f"""
import json, sys
from lidar3d.config import Config, config_with
from lidar3d.run import run_bag
config = config_with(Config(), {{"loop": {{"min_time_gap_s": 2.0, "search_radius_m": 40.0}}}})
run_bag({str(bag)!r}, {str(out)!r}, config, prefetch=False)
print(json.dumps({{"open3d": "open3d" in sys.modules, "small_gicp": "small_gicp" in sys.modules}}))
"""
    done = subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, check=True)
    imported = json.loads(done.stdout.strip().splitlines()[-1])
    rows = (out / "loops.csv").read_text().splitlines()[1:]
    assert rows, "no loop candidate was verified"
    assert imported == {"open3d": False, "small_gicp": True}


def test_verification_rejects_a_different_street_with_a_reason():
    sim = _sim()
    gt = sim.ground_truth.T_world_lidar
    target = _first_pass_target(40)  # first street, near (56, -1.5)
    for query_scan in (250, 420):  # the far street and the left street of the block
        guess = np.eye(4)
        guess[:3, :3] = (invert(gt[40]) @ gt[query_scan])[:3, :3]  # as if drift had put it there
        result = verify_loop(_cloud(query_scan), target, guess, CONFIG, max_correction_m=3.0)
        assert not result.accepted
        assert result.verdict in (
            Verdict.LOW_FITNESS,
            Verdict.LOW_OVERLAP,
            Verdict.HIGH_RMSE,
            Verdict.LARGE_CORRECTION,
            Verdict.NOT_CONVERGED,
        )
        assert result.reason
        assert not np.any(result.information)


def test_verification_rejects_empty_clouds_and_large_corrections():
    target = _first_pass_target(14)
    few = verify_loop(np.arange(30.0).reshape(10, 3), target, np.eye(4), CONFIG)
    assert few.verdict is Verdict.TOO_FEW_POINTS and "10 source" in few.reason
    assert np.isnan(few.fitness)
    gt = _sim().ground_truth.T_world_lidar
    T_true = invert(gt[14]) @ gt[660]
    guess = T_true @ exp_se3(np.array([1.5, 0.5, 0, 0, 0, 0]))
    large = verify_loop(_cloud(660), target, guess, CONFIG, max_correction_m=0.5)
    assert large.verdict is Verdict.LARGE_CORRECTION and "limit 0.50 m" in large.reason


def test_information_matches_open3d_after_the_adjoint():
    import open3d as o3d

    rng = np.random.default_rng(3)
    source = rng.uniform(-20, 20, (400, 3))
    T = exp_se3(np.array([2.0, -1.0, 0.3, 0.1, -0.05, 0.4]))
    target = source @ T[:3, :3].T + T[:3, 3]
    left = o3d.pipelines.registration.get_information_matrix_from_point_clouds(
        o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source)),
        o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target)),
        0.01,
        T,
    )
    R, t = T[:3, :3], T[:3, 3]
    skew_t = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    adjoint = np.block([[R, np.zeros((3, 3))], [skew_t @ R, R]])  # GTSAM order (rot, trans)
    np.testing.assert_allclose(point_information(source), adjoint.T @ left @ adjoint, rtol=1e-9, atol=1e-6)
    info = loop_information(
        source, 0.05, effective_points=100, min_sigma_rotation_rad=1e-3, min_sigma_translation_m=0.02
    )
    sigmas = np.sqrt(np.diag(np.linalg.inv(info)))
    assert np.all(sigmas[3:] >= 0.02) and np.all(sigmas[3:] < 0.03)


def test_config_rejects_unknown_icp_method():
    with pytest.raises(ConfigError, match=r"loop\.icp_method"):
        LoopConfig(icp_method="ndt")
    with pytest.raises(ConfigError, match="icp_max_correspondence_m"):
        LoopConfig(icp_max_correspondence_m=())


def test_voxel_overlap():
    a = np.array([[0.1, 0.1, 0.1], [1.1, 0.1, 0.1], [2.1, 0.1, 0.1]])
    assert voxel_overlap(a, a, 1.0) == 1.0
    assert voxel_overlap(a, a[:1], 1.0) == 1.0  # min(|A|, |B|) in the denominator
    assert voxel_overlap(a, a + 10.0, 1.0) == 0.0
    assert voxel_overlap(a, np.zeros((0, 3)), 1.0) == 0.0


def _drifting_keyframes():
    """The whole loop as keyframes with drifting odometry; clouds only where loops can happen."""
    sim = _sim()
    gt = sim.ground_truth.T_world_lidar
    scans = list(range(0, len(sim), KEYFRAME_STRIDE))
    bias = exp_se3(np.array([0.002, 0.0, 0.0, 0.0, np.radians(0.003), np.radians(0.01)]))
    raw = [gt[scans[0]]]
    for a, b in itertools.pairwise(scans):
        raw.append(raw[-1] @ invert(gt[a]) @ gt[b] @ bias)
    keyframes = []
    for k, s in enumerate(scans):
        needed = s < 80 or s > 600
        cloud = _cloud(s) if needed else np.zeros((0, 3))
        keyframes.append(Keyframe(k, s, int(sim.stamps_ns[s]), raw[k], cloud[:0], cloud))
    return keyframes, np.array(raw), gt[scans]


def test_loop_closer_finds_the_revisit_and_corrects_the_drift():
    keyframes, raw, truth = _drifting_keyframes()
    closer = LoopCloser(CONFIG)
    correction = np.eye(4)
    poses = []
    updates = 0
    for k in range(len(keyframes)):
        poses.append(correction @ raw[k])  # the pipeline's running pose follows each correction
        update = closer.on_keyframe(keyframes[: k + 1], np.array(poses))
        if update is not None:
            updates += 1
            assert update.poses.shape == (k + 1, 4, 4)
            np.testing.assert_allclose(update.previous_poses, np.array(poses))
            correction = update.correction @ correction
            poses = list(update.poses)
    final = closer.final_poses()
    closures = closer.closures
    assert updates >= 1 and len(closures) == updates
    assert len(closer.candidates) >= len(closures)
    for c in closures:  # every accepted closure is right
        T_true = invert(truth[c.match]) @ truth[c.query]
        assert np.linalg.norm((invert(T_true) @ c.T_match_query)[:3, 3]) < 0.1
        assert c.time_gap_s >= CONFIG.min_time_gap_s
    end_before = np.linalg.norm(raw[-1, :3, 3] - truth[-1, :3, 3])
    end_after = np.linalg.norm(final[-1, :3, 3] - truth[-1, :3, 3])
    assert end_before > 1.0
    assert end_after < 0.1 * end_before
    revisit = [k for k, kf in enumerate(keyframes) if kf.scan_index > 640]
    err_before = np.linalg.norm(raw[revisit, :3, 3] - truth[revisit, :3, 3], axis=1)
    err_after = np.linalg.norm(final[revisit, :3, 3] - truth[revisit, :3, 3], axis=1)
    assert err_after.max() < 0.1 * err_before.max()


def test_disabled_closer_keeps_the_graph_but_closes_nothing():
    keyframes, raw, _ = _drifting_keyframes()
    closer = LoopCloser(dataclasses.replace(CONFIG, enabled=False))
    for k in range(0, len(keyframes), 40):
        assert closer.on_keyframe(keyframes[: k + 1], raw[: k + 1]) is None
    assert closer.candidates == [] and len(closer.graph) == len(keyframes[: k + 1])


def test_correct_scan_poses_is_exact_at_keyframes_and_interpolates_between():
    stamps = np.arange(0, 100, 10, dtype=np.int64) * 1_000_000  # 10 scans, 10 ms apart
    scan_poses = np.array([exp_se3(np.array([0.5 * i, 0.0, 0.0, 0.0, 0.0, 0.01 * i])) for i in range(10)])
    keyframe_rows = [1, 5, 8]
    old = scan_poses[keyframe_rows]
    corrections = [
        exp_se3(np.array([0.1, 0.0, 0.0, 0.0, 0.0, 0.0])),
        exp_se3(np.array([0.3, 0.2, 0.0, 0.0, 0.0, 0.02])),
        exp_se3(np.array([0.3, 0.2, 0.1, 0.0, 0.0, 0.02])),
    ]
    new = np.array([C @ T for C, T in zip(corrections, old)])
    out = correct_scan_poses(stamps, scan_poses, stamps[keyframe_rows], old, new)
    np.testing.assert_allclose(out[keyframe_rows], new, atol=1e-12)
    # before the first / after the last keyframe: that keyframe's correction
    np.testing.assert_allclose(out[0], corrections[0] @ scan_poses[0], atol=1e-12)
    np.testing.assert_allclose(out[9], corrections[2] @ scan_poses[9], atol=1e-12)
    # halfway between keyframes 1 (t=10 ms) and 5 (t=50 ms): scan 3 gets half of each correction
    C3 = out[3] @ invert(scan_poses[3])
    np.testing.assert_allclose(C3[:3, 3], 0.5 * (corrections[0][:3, 3] + corrections[1][:3, 3]), atol=1e-12)
    assert _angle_deg(C3[:3, :3]) == pytest.approx(np.degrees(0.01), abs=1e-9)
    # the input is untouched and the result stays rigid
    assert not np.shares_memory(out, scan_poses)
    R = out[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    with pytest.raises(ValueError, match="strictly increasing"):
        correct_scan_poses(stamps, scan_poses, stamps[[5, 1, 8]], old, new)


def test_the_injection_harness_sees_and_corrupts_the_closers_verifications(monkeypatch):
    """eval/loop_injection.py stands in for the closer's verification: on the drifting loop its
    injector counts the accepted verifications and shifts the chosen one (it once counted none
    and reported "no closure to corrupt" for every drive, after the verification moved)."""
    import sys
    from pathlib import Path

    import lidar3d.loop.closer as closer_module

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "eval"))
    from loop_injection import Injector

    offset = np.array([5.0, 0.0, 0.0])
    injector = Injector({0: offset})
    monkeypatch.setattr(closer_module, "_verify", injector)
    keyframes, raw, truth = _drifting_keyframes()
    closer = LoopCloser(CONFIG)
    for k in range(len(keyframes)):
        closer.on_keyframe(keyframes[: k + 1], raw[: k + 1])
    assert injector.n_verified_accepted >= 1
    (query, match, length), *_ = injector.injected
    assert length == pytest.approx(5.0)
    first = next(c for c in closer.candidates if (c.query, c.match) == (query, match))
    T_true = invert(truth[match]) @ truth[query]
    assert np.linalg.norm(first.T_match_query[:3, 3] - T_true[:3, 3]) > 4.0  # the closer saw the shifted one
