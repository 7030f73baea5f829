"""Association, alignment, ATE and RPE: invariances, oracles (evo, a brute-force KITTI devkit port).

evo (GPL-3.0) is a test-only dependency; its tests are skipped when it is not installed.
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar3d.metrics import (
    AlignmentMode,
    EvaluationError,
    absolute_errors,
    associate,
    distance_rpe,
    evaluate_trajectory,
    kitti_rpe,
    umeyama_se3,
    yaw_alignment,
)
from lidar3d.records import Trajectory


def _drive(n=1500, rate_hz=10.0, seed=0):
    """A smooth 3-D drive (about 1.1 km) with turns, hills and some roll/pitch; (stamps_ns, T)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate_hz
    speed = 7.0 + 2.0 * np.sin(t / 17.0)
    yaw = 0.6 * np.sin(t / 23.0) + 0.3 * np.sin(t / 7.0 + rng.uniform(0, 6))
    dt = 1.0 / rate_hz
    x = np.cumsum(speed * np.cos(yaw)) * dt
    y = np.cumsum(speed * np.sin(yaw)) * dt
    z = 3.0 * np.sin(t / 30.0)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 3] = np.c_[x, y, z]
    T[:, :3, :3] = Rotation.from_euler("ZYX", np.c_[yaw, 0.02 * np.sin(t / 5), 0.01 * np.cos(t / 3)]).as_matrix()
    stamps = 1_600_000_000_000_000_000 + np.round(t * 1e9).astype(np.int64)
    return stamps, T


def _random_se3(seed):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T[:3, 3] = np.random.default_rng(seed).uniform(-100, 100, 3)
    return T


def _perturbed(T, seed, sigma_m=0.05, sigma_rad=0.002):
    rng = np.random.default_rng(seed)
    P = T.copy()
    P[:, :3, 3] += rng.normal(0, sigma_m, (len(T), 3))
    P[:, :3, :3] = P[:, :3, :3] @ Rotation.from_rotvec(rng.normal(0, sigma_rad, (len(T), 3))).as_matrix()
    return P


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_random_se3_is_aligned_away(seed):
    stamps, T = _drive(400)
    G = _random_se3(seed)
    estimate = Trajectory(stamps, np.linalg.inv(G) @ T)
    result = evaluate_trajectory(estimate, Trajectory(stamps, T), align="se3")
    assert result.ate.translation_3d_m.max < 1e-9
    assert result.ate.rotation_deg.max < 1e-9
    assert np.allclose(result.T_reference_estimate, G, atol=1e-9)


def test_yaw_offset_is_removed_by_4dof_and_tilt_is_not():
    stamps, T = _drive(400)
    G = np.eye(4)
    G[:3, :3] = Rotation.from_euler("z", 73.0, degrees=True).as_matrix()
    G[:3, 3] = [12.0, -40.0, 3.0]
    estimate = Trajectory(stamps, np.linalg.inv(G) @ T)
    yaw = evaluate_trajectory(estimate, Trajectory(stamps, T), align="yaw")
    assert yaw.ate.translation_3d_m.max < 1e-9
    assert np.allclose(yaw.T_reference_estimate, G, atol=1e-9)
    tilt = G.copy()
    tilt[:3, :3] = Rotation.from_euler("zx", [73.0, 2.0], degrees=True).as_matrix()
    tilted = Trajectory(stamps, np.linalg.inv(tilt) @ T)
    assert evaluate_trajectory(tilted, Trajectory(stamps, T), align="yaw").ate.translation_3d_m.rmse > 0.5
    assert evaluate_trajectory(tilted, Trajectory(stamps, T), align="se3").ate.translation_3d_m.max < 1e-9
    none = evaluate_trajectory(estimate, Trajectory(stamps, T), align="none")
    assert none.ate.translation_3d_m.min > 1.0 and np.allclose(none.T_reference_estimate, np.eye(4))


def test_yaw_alignment_with_noise_is_least_squares():
    rng = np.random.default_rng(4)
    x = rng.uniform(-50, 50, (300, 3))
    theta = np.radians(-121.0)
    R = Rotation.from_euler("z", theta).as_matrix()
    y = x @ R.T + [3, 4, 5] + rng.normal(0, 0.1, (300, 3))
    T = yaw_alignment(x, y)
    assert np.degrees(np.arctan2(T[1, 0], T[0, 0])) == pytest.approx(-121.0, abs=0.02)
    # no other yaw does better
    cost = lambda M: np.sum((x @ M[:3, :3].T + M[:3, 3] - y) ** 2)  # noqa: E731
    for delta in (-1e-3, 1e-3):
        D = np.eye(4)
        D[:3, :3] = Rotation.from_euler("z", delta).as_matrix()
        M = D @ T
        M[:3, 3] = y.mean(0) - M[:3, :3] @ x.mean(0)
        assert cost(M) > cost(T)


def test_umeyama_matches_evo():
    umeyama_alignment = pytest.importorskip("evo.core.geometry").umeyama_alignment

    rng = np.random.default_rng(9)
    x = rng.normal(0, 20, (100, 3))
    G = _random_se3(11)
    y = x @ G[:3, :3].T + G[:3, 3] + rng.normal(0, 0.3, (100, 3))
    R, t, _scale = umeyama_alignment(x.T, y.T, with_scale=False)
    T = umeyama_se3(x, y)
    assert np.allclose(T[:3, :3], R, atol=1e-12) and np.allclose(T[:3, 3], t, atol=1e-9)


def test_alignment_errors():
    with pytest.raises(EvaluationError, match="only 2 associated pose"):
        umeyama_se3(np.zeros((2, 3)), np.zeros((2, 3)))
    line = np.c_[np.linspace(0, 10, 20), np.zeros(20), np.zeros(20)]
    with pytest.raises(EvaluationError, match="collinear"):
        umeyama_se3(line, line)
    assert np.allclose(yaw_alignment(line, line + [1, 2, 3]), [[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]])
    with pytest.raises(EvaluationError, match="unknown alignment 'sim3'"):
        AlignmentMode.parse("sim3")


def test_association_interpolates_and_respects_gaps():
    def circle(rate_hz, n):  # analytic drive: 5 m/s on a 50 m circle, gentle hills
        t = np.arange(n) / rate_hz
        T = np.tile(np.eye(4), (n, 1, 1))
        T[:, :3, 3] = np.c_[50 * np.cos(t / 10), 50 * np.sin(t / 10), np.sin(t / 3)]
        T[:, :3, :3] = Rotation.from_euler("ZY", np.c_[t / 10 + np.pi / 2, 0.05 * np.sin(t)]).as_matrix()
        return 1_600_000_000_000_000_000 + np.round(t * 1e9).astype(np.int64), T

    stamps, T = circle(20.0, 200)
    reference = Trajectory(stamps, T)
    # estimate at mid-points; the exact pose there comes from a 40 Hz version of the same drive
    fine_stamps, fine_T = circle(40.0, 400)
    assert np.array_equal(fine_stamps[::2], stamps)
    mid = slice(1, 399, 2)
    estimate = Trajectory(fine_stamps[mid], fine_T[mid])
    pairs = associate(estimate, reference, max_gap_s=0.06)
    assert len(pairs) == 199
    position_error = np.linalg.norm(pairs.T_world_reference[:, :3, 3] - fine_T[mid][:, :3, 3], axis=1)
    assert position_error.max() < 0.01  # chord error of linear interpolation over 0.05 s
    assert absolute_errors(pairs.T_world_reference, fine_T[mid]).rotation_deg.max() < 0.01
    # drop reference samples 50..59: no estimate stamp inside the hole is associated
    keep = np.r_[0:50, 60:200]
    holed = Trajectory(stamps[keep], T[keep])
    pairs = associate(estimate, holed, max_gap_s=0.06)
    inside = (estimate.stamps_ns > stamps[49]) & (estimate.stamps_ns < stamps[60])
    assert len(pairs) == 199 - inside.sum()
    assert not np.isin(pairs.stamps_ns, estimate.stamps_ns[inside]).any()
    # exact stamps use the sample itself; stamps outside the reference are dropped
    pairs = associate(Trajectory(stamps[:5], T[:5]), reference, max_gap_s=0.06)
    assert len(pairs) == 5 and np.allclose(pairs.T_world_reference, T[:5], atol=1e-12)
    pairs = associate(Trajectory(stamps[:5] - 1, T[:5]), reference, max_gap_s=0.06)
    assert len(pairs) == 4 and np.allclose(pairs.T_world_reference, T[1:5], atol=1e-6)


def test_no_time_overlap_names_both_spans():
    stamps, T = _drive(50)
    with pytest.raises(
        EvaluationError,
        match=r"no time overlap: trajectory spans \[1600000100\.000, .*reference "
        r"spans \[1600000000\.000, 1600000004\.900\]",
    ):
        associate(Trajectory(stamps + 100_000_000_000, T), Trajectory(stamps, T), 0.2)


def test_too_few_associated_poses():
    stamps, T = _drive(50)
    estimate = Trajectory(stamps[:2], T[:2])
    with pytest.raises(EvaluationError, match=r"only 2 of 2 poses associated .* needs at least 3"):
        evaluate_trajectory(estimate, Trajectory(stamps, T), align="se3")


def _evo_trajectory(stamps, T):
    from evo.core.trajectory import PoseTrajectory3D

    return PoseTrajectory3D(poses_se3=list(T), timestamps=stamps / 1e9)


@pytest.mark.parametrize("delta_m", [10.0, 100.0])
def test_distance_rpe_agrees_with_evo(delta_m):
    metrics = pytest.importorskip("evo.core.metrics")

    stamps, T = _drive()
    P = np.linalg.inv(_random_se3(21)) @ _perturbed(T, 5)
    ours = distance_rpe(T, P, delta_m)
    for relation, stats in (
        (metrics.PoseRelation.translation_part, ours.translation_m),
        (metrics.PoseRelation.rotation_angle_deg, ours.rotation_deg),
    ):
        rpe = metrics.RPE(
            relation, delta=delta_m, delta_unit=metrics.Unit.meters, all_pairs=False, pairs_from_reference=True
        )
        rpe.process_data((_evo_trajectory(stamps, T), _evo_trajectory(stamps, P)))
        assert len(rpe.error) == stats.n > 5
        for name in ("rmse", "mean", "median", "max"):
            expected = rpe.get_statistic(getattr(metrics.StatisticsType, name))
            assert getattr(stats, name) == pytest.approx(expected, rel=1e-4)


def test_ate_agrees_with_evo_ape():
    metrics = pytest.importorskip("evo.core.metrics")

    stamps, T = _drive(600)
    P = np.linalg.inv(_random_se3(8)) @ _perturbed(T, 6, sigma_m=0.2)
    ours = evaluate_trajectory(Trajectory(stamps, P), Trajectory(stamps, T), align="se3")
    reference, estimate = _evo_trajectory(stamps, T), _evo_trajectory(stamps, P)
    estimate.align(reference, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((reference, estimate))
    assert ours.ate.translation_3d_m.rmse == pytest.approx(ape.get_statistic(metrics.StatisticsType.rmse), rel=1e-9)
    ape = metrics.APE(metrics.PoseRelation.rotation_angle_deg)
    ape.process_data((reference, estimate))
    assert ours.ate.rotation_deg.median == pytest.approx(ape.get_statistic(metrics.StatisticsType.median), rel=1e-6)


def _kitti_devkit(Q, P, step=10, lengths=(100, 200, 300, 400, 500, 600, 700, 800)):
    """Straight port of the KITTI devkit's calcSequenceErrors loop (frame step 10)."""
    dist = [0.0]
    for i in range(1, len(Q)):
        dist.append(dist[-1] + np.linalg.norm(Q[i, :3, 3] - Q[i - 1, :3, 3]))
    t_err, r_err = [], []
    for first in range(0, len(Q), step):
        for length in lengths:
            last = next((i for i in range(first, len(dist)) if dist[i] > dist[first] + length), -1)
            if last == -1:
                continue
            delta_gt = np.linalg.inv(Q[first]) @ Q[last]
            delta_est = np.linalg.inv(P[first]) @ P[last]
            error = np.linalg.inv(delta_est) @ delta_gt
            r_err.append(np.arccos(np.clip((np.trace(error[:3, :3]) - 1) / 2, -1, 1)) / length)
            t_err.append(np.linalg.norm(error[:3, 3]) / length)
    return 100 * np.mean(t_err), np.degrees(np.mean(r_err)) * 100, len(t_err)


def test_kitti_rpe_matches_devkit_port_and_ignores_alignment():
    stamps, T = _drive()
    P = _perturbed(T, 7, sigma_m=0.3, sigma_rad=0.01)
    expected_t, expected_r, expected_n = _kitti_devkit(T, P)
    ours = kitti_rpe(stamps, T, P, step_s=1.0)
    assert ours.n == expected_n > 20
    assert ours.translation_percent == pytest.approx(expected_t, rel=1e-9)
    assert ours.rotation_deg_per_100m == pytest.approx(expected_r, rel=1e-6)
    moved = kitti_rpe(stamps, T, _random_se3(3) @ P, step_s=1.0)
    assert moved.translation_percent == pytest.approx(ours.translation_percent, rel=1e-9)
    assert sum(length.n for length in ours.per_length) == ours.n


def test_rpe_on_a_short_drive_is_empty_not_an_error():
    stamps, T = _drive(100)  # about 70 m
    result = evaluate_trajectory(Trajectory(stamps, T), Trajectory(stamps, T), align="none")
    assert result.kitti.n == 0 and np.isnan(result.kitti.translation_percent)
    assert result.distance_rpe[1].translation_m.n == 0 and result.distance_rpe[0].translation_m.n > 0


def test_extrinsic_moves_reference_to_the_lidar():
    stamps, T_enu_imu = _drive(300)
    T_imu_lidar = np.eye(4)
    T_imu_lidar[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    T_imu_lidar[:3, 3] = [0.1, 0.3, 0.8]
    lidar = Trajectory(stamps, T_enu_imu @ T_imu_lidar)
    with_extrinsic = evaluate_trajectory(lidar, Trajectory(stamps, T_enu_imu), T_imu_lidar=T_imu_lidar, align="none")
    assert with_extrinsic.ate.translation_3d_m.max < 1e-9 and with_extrinsic.ate.rotation_deg.max < 1e-9
    without = evaluate_trajectory(lidar, Trajectory(stamps, T_enu_imu), align="se3")
    assert without.ate.translation_3d_m.rmse > 0.05
