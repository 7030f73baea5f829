"""``lidar3d eval`` on hostile inputs (issue 21): a NaN trajectory row (defect 4), a bad first INS fix
(defect 5) and a short, nearly straight clip where SE(3) alignment is ill-conditioned (defect 10)."""

import json
import logging

import numpy as np
import pytest
from novatel_frames import WEEK, ascii_line
from scipy.spatial.transform import Rotation

from lidar3d.cli.main import main
from lidar3d.gnss import GeodeticOrigin, LocalEnu, span_from_R_enu_vehicle
from lidar3d.io.trajectory_io import write_kitti, write_tum
from lidar3d.metrics import (
    EvaluationError,
    align_trajectories,
    evaluate_trajectory,
    se3_conditioning,
    umeyama_se3,
)
from lidar3d.metrics.alignment import SE3_MIN_CONDITIONING
from lidar3d.records import Trajectory

START_S = 300000.0
LEAP_S = 18
ORIGIN = GeodeticOrigin(48.137, 11.575, 567.0)


def _unix_ns(t):
    return np.round((315964800 + 604800 * WEEK + START_S - LEAP_S + t) * 1e9).astype(np.int64)


def _drive(t, radius_m=45.0, speed_mps=6.0):
    """IMU poses in ENU (SPAN vehicle axes, y forward) on a circle of ``radius_m`` with a slope."""
    omega = speed_mps / radius_m
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, :3, 3] = np.c_[radius_m * np.sin(omega * t), radius_m * (1 - np.cos(omega * t)), 0.02 * speed_mps * t]
    heading = omega * t
    R_enu_base = Rotation.from_euler("ZYX", np.c_[heading, np.zeros_like(t), 0.01 * np.sin(t)]).as_matrix()
    R_base_vehicle = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    T[:, :3, :3] = R_enu_base @ R_base_vehicle
    return T


def _inspvas_lines(t, T_enu_imu):
    enu = LocalEnu(ORIGIN)
    lat, lon, h = enu.to_geodetic(T_enu_imu[:, :3, 3])
    R_local = np.swapaxes(enu.R_enu_local(lat, lon), -1, -2) @ T_enu_imu[:, :3, :3]
    roll, pitch, azimuth = span_from_R_enu_vehicle(R_local)
    lines = []
    for k in range(len(t)):
        seconds = f"{START_S + t[k]:.3f}"
        body = (
            f"{WEEK},{seconds},{lat[k]:.11f},{lon[k]:.11f},{h[k]:.4f},0.0,0.0,0.0,"
            f"{roll[k]:.9f},{pitch[k]:.9f},{azimuth[k]:.9f},INS_SOLUTION_GOOD"
        )
        lines.append(ascii_line("%", f"INSPVASA,{WEEK},{seconds}", body))
    return lines


def _slam_frame(T_enu, yaw_deg=30.0, offset=(5.0, -3.0, 1.0)):
    """The poses expressed in a SLAM world frame that differs from ENU by a yaw and a shift."""
    T_slam_enu = np.eye(4)
    T_slam_enu[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    T_slam_enu[:3, 3] = offset
    return T_slam_enu @ T_enu


def _write_log(path, lines):
    path.write_bytes(b"\r\n".join(lines) + b"\r\n")


def _run(capsys, args):
    code = main(args)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


@pytest.fixture()
def drive(tmp_path):
    t_ref = np.arange(0.0, 30.0, 0.05)
    log = tmp_path / "span.log"
    _write_log(log, _inspvas_lines(t_ref, _drive(t_ref)))
    t_est = np.arange(0.1, 29.0, 0.1)
    estimate = Trajectory(_unix_ns(t_est), _slam_frame(_drive(t_est)))
    return log, estimate


# --- defect 4: non-finite trajectory rows -------------------------------------------------------


def test_tum_row_with_nan_is_one_line_naming_file_and_row(tmp_path, drive, capsys):
    log, estimate = drive
    path = tmp_path / "traj_tum.txt"
    write_tum(path, estimate)
    lines = path.read_text().splitlines()
    tokens = lines[3].split()
    tokens[2] = "nan"
    lines[3] = " ".join(tokens)
    path.write_text("\n".join(lines) + "\n")
    code, _out, err = _run(capsys, ["eval", str(path), "--span", str(log), "--out", str(tmp_path / "eval")])
    assert code == 1
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"lidar3d eval: error: {path}:4: non-finite value (nan) in ")


def test_kitti_row_with_inf_is_one_line_naming_file_and_row(tmp_path, drive, capsys):
    log, estimate = drive
    path = tmp_path / "traj.kitti"
    write_kitti(path, estimate)
    lines = path.read_text().splitlines()
    tokens = lines[6].split()
    tokens[3] = "inf"
    lines[6] = " ".join(tokens)
    path.write_text("\n".join(lines) + "\n")
    code, _out, err = _run(capsys, ["eval", str(path), "--span", str(log), "--out", str(tmp_path / "eval")])
    assert code == 1 and err.count("\n") == 1
    assert err.startswith(f"lidar3d eval: error: {path}:7: non-finite value (inf) in ")


def test_tum_zero_quaternion_is_one_line(tmp_path, drive, capsys):
    log, _estimate = drive
    path = tmp_path / "traj_tum.txt"
    path.write_text("1.0 0 0 0 0 0 0 0\n")
    code, _out, err = _run(capsys, ["eval", str(path), "--span", str(log), "--out", str(tmp_path / "eval")])
    assert code == 1 and err == f"lidar3d eval: error: {path}:1: quaternion of zero length in '1.0 0 0 0 0 0 0 0'\n"


@pytest.mark.parametrize("mode", ["se3", "yaw", "none"])
def test_alignment_refuses_non_finite_poses(mode):
    t = np.arange(0.0, 10.0, 0.1)
    T = _drive(t)
    broken = T.copy()
    broken[7, 1, 3] = np.nan
    with pytest.raises(
        EvaluationError,
        match=r"^estimate poses hold non-finite values \(1 of 100 poses, the first at "
        r"index 7\); alignment needs finite poses$",
    ):
        align_trajectories(T, broken, mode)
    broken = T.copy()
    broken[0, 0, 0] = np.inf
    with pytest.raises(EvaluationError, match=r"^reference poses hold non-finite values"):
        align_trajectories(broken, T, mode)
    with pytest.raises(EvaluationError, match=r"^source positions hold non-finite values"):
        umeyama_se3(np.where(np.arange(300).reshape(100, 3) == 5, np.nan, T[:, :3, 3]), T[:, :3, 3])


# --- defect 5: a bad first INS fix --------------------------------------------------------------


@pytest.mark.parametrize("bad", [{"lat": "nan"}, {"h": "1e7"}, {"lat": "95.0"}, {"h": "inf"}])
def test_bad_first_fix_is_skipped_counted_and_reported(tmp_path, drive, capsys, bad):
    log, estimate = drive
    lines = log.read_bytes().split(b"\r\n")
    text = lines[0].decode()
    fields = text[: text.rindex("*")].split(";")[1].split(",")
    index = {"lat": 2, "h": 4}[next(iter(bad))]
    fields[index] = next(iter(bad.values()))
    lines[0] = ascii_line("%", text[1 : text.index(";")], ",".join(fields))
    log.write_bytes(b"\r\n".join(lines))
    traj = tmp_path / "traj_tum.txt"
    write_tum(traj, estimate)
    out = tmp_path / "eval"
    code, stdout, err = _run(capsys, ["eval", str(traj), "--span", str(log), "--out", str(out)])
    assert code == 0, err
    assert "Traceback" not in err
    warnings = [line for line in err.splitlines() if line.startswith("WARNING")]
    assert len(warnings) == 1 and "1 message(s) rejected" in warnings[0]
    assert "1 with non-finite or out-of-range values" in warnings[0]
    report = json.loads((out / "report.json").read_text())
    assert report["log"]["out_of_range"] == 1
    assert report["warnings"] == [
        f"{log}: 1 message(s) with non-finite or out-of-range values (position, velocity, attitude or GPS time) skipped"
    ]
    assert f"warning: {log}: 1 message(s) with non-finite" in stdout
    # the origin is the first good fix (0.05 s later), not the bad one
    assert report["origin"]["latitude_deg"] == pytest.approx(ORIGIN.latitude_deg, abs=1e-5)
    assert report["ate"]["translation_3d_m"]["rmse"] < 1e-3


def test_bad_origin_option_is_one_line(tmp_path, drive, capsys):
    log, estimate = drive
    traj = tmp_path / "traj_tum.txt"
    write_tum(traj, estimate)
    args = ["eval", str(traj), "--span", str(log), "--origin", "48.0", "200.0", "500.0", "--out", str(tmp_path / "e")]
    code, _out, err = _run(capsys, args)
    assert code == 1
    assert err == (
        "lidar3d eval: error: --origin: config gnss.origin[1] (longitude_deg): 200.0 is out of range [-180, 180] deg\n"
    )


# --- defect 10: SE(3) alignment on a short, nearly straight clip --------------------------------


def _straight_clip(seed=3):
    """4 s at 10 m/s on a 2 km radius: IMU reference at 20 Hz, an estimate at 10 Hz with 2 cm noise."""
    t_ref = np.arange(0.0, 4.0001, 0.05)
    t_est = np.arange(0.05, 3.96, 0.1)
    T_est = _slam_frame(_drive(t_est, radius_m=2000.0, speed_mps=10.0))
    T_est[:, :3, 3] += np.random.default_rng(seed).normal(0.0, 0.02, (len(t_est), 3))
    return t_ref, _drive(t_ref, radius_m=2000.0, speed_mps=10.0), t_est, T_est


def test_straight_clip_falls_back_to_yaw_with_one_warning(caplog):
    t_ref, T_ref, t_est, T_est = _straight_clip()
    reference = Trajectory(_unix_ns(t_ref), T_ref)
    estimate = Trajectory(_unix_ns(t_est), T_est)
    # without the fallback, SE(3) turns the estimate about the path axis: a rotation ATE of degrees
    plain = umeyama_se3(T_est[:, :3, 3], T_ref[np.searchsorted(t_ref, t_est - 1e-9)][:, :3, 3])
    assert np.degrees(Rotation.from_matrix(plain[:3, :3]).magnitude()) > 5.0
    with caplog.at_level(logging.WARNING, logger="lidar3d"):
        result = evaluate_trajectory(estimate, reference, align="se3")
    assert result.alignment.value == "yaw" and result.alignment_requested.value == "se3"
    assert result.alignment_conditioning < SE3_MIN_CONDITIONING
    assert result.alignment_note.startswith("se3 alignment is ill-conditioned (conditioning ")
    assert result.alignment_note.endswith("used yaw (4-DoF, gravity known) instead")
    assert result.warnings == (result.alignment_note,)
    assert [r.getMessage() for r in caplog.records] == [result.alignment_note]
    assert result.ate.rotation_deg.max < 0.5


def test_straight_clip_report_says_which_alignment_was_used(tmp_path, capsys):
    t_ref, T_ref, t_est, T_est = _straight_clip()
    log = tmp_path / "span.log"
    _write_log(log, _inspvas_lines(t_ref, T_ref))
    traj = tmp_path / "traj_tum.txt"
    write_tum(traj, Trajectory(_unix_ns(t_est), T_est))
    out = tmp_path / "eval"
    code, stdout, err = _run(capsys, ["eval", str(traj), "--span", str(log), "--out", str(out)])
    assert code == 0, err
    assert err.count("se3 alignment is ill-conditioned") == 1
    report = json.loads((out / "report.json").read_text())
    assert report["alignment"]["mode"] == "yaw" and report["alignment"]["requested"] == "se3"
    assert report["alignment"]["note"].startswith("se3 alignment is ill-conditioned")
    assert report["warnings"] == [report["alignment"]["note"]]
    assert "alignment yaw" in stdout and "warning: se3 alignment is ill-conditioned" in stdout
    assert report["ate"]["rotation_deg"]["max"] < 0.5


def test_well_conditioned_drive_keeps_the_se3_result_unchanged():
    t = np.arange(0.0, 30.0, 0.1)
    T_ref = _drive(t)
    T_est = _slam_frame(T_ref)
    T_est[:, :3, 3] += np.random.default_rng(1).normal(0.0, 0.05, (len(t), 3))
    assert se3_conditioning(T_ref[:, :3, 3]) > SE3_MIN_CONDITIONING
    result = evaluate_trajectory(Trajectory(_unix_ns(t), T_est), Trajectory(_unix_ns(t), T_ref), align="se3")
    assert result.alignment.value == "se3" and result.alignment_note == "" and result.warnings == ()
    assert np.array_equal(result.T_reference_estimate, umeyama_se3(T_est[:, :3, 3], T_ref[:, :3, 3]))


def test_conditioning_of_simple_shapes():
    line = np.c_[np.linspace(0, 10, 20), np.zeros(20), np.zeros(20)]
    assert se3_conditioning(line) == 0.0
    assert se3_conditioning(np.zeros((5, 3))) == 0.0
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    assert se3_conditioning(square) == pytest.approx(0.5)  # planar: l3 = 0, l1 = l2
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
    assert se3_conditioning(cube) == pytest.approx(1.0)
