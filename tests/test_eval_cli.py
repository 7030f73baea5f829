"""``lidar3d eval`` and its library twin on a synthetic SPAN ASCII log, plus every bad-input path."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar3d.cli.main import main
from lidar3d.config import GnssConfig
from lidar3d.gnss import GeodeticOrigin, LocalEnu, novatel_crc32, span_from_R_enu_vehicle
from lidar3d.io.trajectory_io import write_kitti, write_tum
from lidar3d.metrics import evaluate_span_files
from lidar3d.records import Trajectory

WEEK = 2300
START_S = 300000.0
LEAP_S = 18
ORIGIN = GeodeticOrigin(48.137, 11.575, 567.0)
UNDULATION_M = 47.4
T_IMU_LIDAR = np.array([[0.0, -1.0, 0.0, 0.1], [1.0, 0.0, 0.0, 0.3], [0.0, 0.0, 1.0, 0.8], [0, 0, 0, 1.0]])
EXTRINSIC_YAML = "T_imu_lidar:\n  translation_m: [0.1, 0.3, 0.8]\n  rpy_deg: [0.0, 0.0, 90.0]\n"


def _ascii(sync, header, body):
    payload = f"{header};{body}"
    return f"{sync}{payload}*{novatel_crc32(payload.encode('ascii')):08x}"


def _drive(rate_hz, duration_s):
    """IMU poses in ENU: 6 m/s around a 45 m circle with a slope; SPAN vehicle axes (y forward)."""
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    omega = 6.0 / 45.0
    T = np.tile(np.eye(4), (len(t), 1, 1))
    T[:, :3, 3] = np.c_[45 * np.sin(omega * t), 45 * (1 - np.cos(omega * t)), 0.02 * 6.0 * t]
    heading = omega * t  # direction of travel, counter-clockwise from east
    R_enu_base = Rotation.from_euler("ZYX", np.c_[heading, -0.02 * np.ones_like(t), 0.01 * np.sin(t)]).as_matrix()
    R_base_vehicle = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # vehicle y = base x
    T[:, :3, :3] = R_enu_base @ R_base_vehicle
    return t, T


def _inspvax_lines(t, T_enu_imu, status="INS_SOLUTION_GOOD"):
    enu = LocalEnu(ORIGIN)
    lat, lon, h = enu.to_geodetic(T_enu_imu[:, :3, 3])
    R_local = np.swapaxes(enu.R_enu_local(lat, lon), -1, -2) @ T_enu_imu[:, :3, :3]
    roll, pitch, azimuth = span_from_R_enu_vehicle(R_local)
    lines = []
    for k in range(len(t)):
        header = f"INSPVAXA,COM1,0,60.5,FINESTEERING,{WEEK},{START_S + t[k]:.3f},02000020,46eb,16809"
        body = (
            f"{status},INS_RTKFIXED,{lat[k]:.11f},{lon[k]:.11f},{h[k] - UNDULATION_M:.4f},{UNDULATION_M:.4f},"
            f"0.0000,0.0000,0.0000,{roll[k]:.9f},{pitch[k]:.9f},{azimuth[k]:.9f},"
            "0.0100,0.0100,0.0200,0.0010,0.0010,0.0010,0.0050,0.0050,0.0100,13000045,0"
        )
        lines.append(_ascii("#", header, body))
    return lines


def _bestpos_line(seconds):
    header = f"BESTPOSA,COM1,0,60.5,FINESTEERING,{WEEK},{seconds:.3f},02000020,b1f6,16809"
    body = (
        f"SOL_COMPUTED,NARROW_INT,{ORIGIN.latitude_deg:.11f},{ORIGIN.longitude_deg:.11f},519.6000,47.4000,"
        'WGS84,0.0100,0.0100,0.0200,"0",1.000,0.000,20,18,18,18,00,01,30,33'
    )
    return _ascii("#", header, body)


def _unix_ns(t):
    return np.round((315964800 + 604800 * WEEK + START_S - LEAP_S + t) * 1e9).astype(np.int64)


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("eval")
    t, T_enu_imu = _drive(20.0, 70.0)
    log = root / "span.log"
    lines = _inspvax_lines(t, T_enu_imu)
    lines.insert(5, _bestpos_line(START_S + 0.25))
    log.write_text("\r\n".join(lines) + "\r\n")
    # the SLAM estimate: 10 Hz lidar poses between the reference samples, in a SLAM world frame
    t_est, _ = _drive(10.0, 69.0)
    t_est = t_est + 0.025
    _, T_fine = _drive(40.0, 70.0)  # exact IMU poses at 40 Hz include the 0.025 s offsets
    T_imu_est = T_fine[1::4][: len(t_est)]
    rng = np.random.default_rng(0)
    T_enu_lidar = T_imu_est @ T_IMU_LIDAR
    T_enu_lidar[:, :3, 3] += rng.normal(0.0, 0.01, (len(t_est), 3))
    G = np.eye(4)
    G[:3, :3] = Rotation.from_euler("z", 37.0, degrees=True).as_matrix()
    G[:3, 3] = [4.0, -2.0, 1.5]
    estimate = Trajectory(_unix_ns(t_est), np.linalg.inv(G) @ T_enu_lidar)
    write_tum(root / "estimate_tum.txt", estimate)
    write_kitti(root / "estimate.kitti", estimate)
    (root / "extrinsic.yaml").write_text(EXTRINSIC_YAML)
    enu_estimate = Trajectory(estimate.stamps_ns, T_enu_lidar)
    return {
        "root": root,
        "log": log,
        "estimate": estimate,
        "enu_estimate": enu_estimate,
        "t": t,
        "T_enu_imu": T_enu_imu,
    }


def _run(argv, capsys):
    code = main(argv)
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def test_eval_cli_writes_report_at_noise_level(scene, capsys):
    out = scene["root"] / "out_se3"
    code, stdout, _err = _run(
        [
            "eval",
            str(scene["root"] / "estimate_tum.txt"),
            "--span",
            str(scene["log"]),
            "--extrinsics",
            str(scene["root"] / "extrinsic.yaml"),
            "--out",
            str(out),
        ],
        capsys,
    )
    assert code == 0
    assert "3-D [m]" in stdout and "KITTI RPE" in stdout and "1400 INSPVAX solutions" in stdout
    for name in (
        "report.json",
        "errors.csv",
        "top_view.png",
        "error_over_time.png",
        "rotation_error.png",
        "height_profile.png",
        "reference_lidar_tum.txt",
        "estimate_aligned_tum.txt",
    ):
        assert (out / name).stat().st_size > 0
    report = json.loads((out / "report.json").read_text())
    ate = report["ate"]["translation_3d_m"]
    assert 0.012 < ate["rmse"] < 0.022  # 1 cm per axis: sqrt(3) cm expected
    assert report["association"]["associated_poses"] == len(scene["estimate"])
    assert report["rpe_kitti"]["n"] > 0 and report["rpe_kitti"]["translation_percent"] < 0.1
    assert report["origin"]["height_ellipsoid_m"] == pytest.approx(ORIGIN.height_ellipsoid_m, abs=1e-3)
    assert report["association"]["gnss_quality"] == {"RTK fixed": len(scene["estimate"])}
    assert np.allclose(report["T_imu_lidar"], T_IMU_LIDAR, atol=1e-12)
    rows = (out / "errors.csv").read_text().splitlines()
    assert len(rows) == len(scene["estimate"]) + 1 and rows[1].endswith("INS_SOLUTION_GOOD,INS_RTKFIXED,RTK fixed")


def test_yaw_alignment_and_kitti_input(scene, capsys):
    code, stdout, _ = _run(
        [
            "eval",
            str(scene["root"] / "estimate.kitti"),
            "--span",
            str(scene["log"]),
            "--align",
            "yaw",
            "--extrinsics",
            str(scene["root"] / "extrinsic.yaml"),
            "--out",
            str(scene["root"] / "out_yaw"),
        ],
        capsys,
    )
    assert code == 0 and "alignment yaw" in stdout
    report = json.loads((scene["root"] / "out_yaw" / "report.json").read_text())
    assert report["ate"]["translation_3d_m"]["rmse"] < 0.022


def test_library_twin_matches_and_extrinsic_matters(scene):
    result = evaluate_span_files(
        scene["root"] / "estimate_tum.txt", scene["log"], extrinsics_path=scene["root"] / "extrinsic.yaml"
    )
    assert result.evaluation.ate.translation_3d_m.rmse < 0.022
    without = evaluate_span_files(scene["root"] / "estimate_tum.txt", scene["log"])
    assert without.evaluation.ate.translation_3d_m.rmse > 0.1  # the 0.3 m lever arm, unaccounted


def test_time_offset_option(scene, capsys, tmp_path):
    # an estimate in the reference's ENU frame (no alignment), stamped by a clock 0.25 s late
    # (on a circle at constant speed, SE(3) alignment would absorb a time shift)
    enu = scene["enu_estimate"]
    write_tum(tmp_path / "late.txt", Trajectory(enu.stamps_ns + 250_000_000, enu.T_world_lidar))
    args = [
        "eval",
        str(tmp_path / "late.txt"),
        "--span",
        str(scene["log"]),
        "--extrinsics",
        str(scene["root"] / "extrinsic.yaml"),
        "--align",
        "none",
        "--out",
        str(tmp_path / "o"),
    ]
    assert _run(args, capsys)[0] == 0
    late = json.loads((tmp_path / "o" / "report.json").read_text())["ate"]["translation_3d_m"]["rmse"]
    assert late > 0.5  # 0.25 s at 6 m/s
    assert _run(args + ["--time-offset", "0.25"], capsys)[0] == 0
    fixed = json.loads((tmp_path / "o" / "report.json").read_text())
    assert fixed["ate"]["translation_3d_m"]["rmse"] < 0.022 and fixed["settings"]["time_offset_s"] == 0.25


def _error_line(argv, capsys):
    code, stdout, err = _run(argv, capsys)
    assert code == 1 and stdout == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lidar3d eval: error: ")
    return lines[0]


def _eval_args(trajectory, log, out):
    return ["eval", str(trajectory), "--span", str(log), "--out", str(out)]


def test_error_log_without_usable_pose(scene, capsys, tmp_path):
    log = tmp_path / "bestpos_only.log"
    log.write_text(_bestpos_line(START_S) + "\r\n" + _bestpos_line(START_S + 1) + "\r\n")
    line = _error_line(_eval_args(scene["root"] / "estimate_tum.txt", log, tmp_path / "o"), capsys)
    assert "no usable pose" in line and "BESTPOS x2" in line
    garbage = tmp_path / "garbage.bin"
    garbage.write_bytes(bytes(range(256)) * 10)
    assert "no usable pose" in _error_line(
        _eval_args(scene["root"] / "estimate_tum.txt", garbage, tmp_path / "o"), capsys
    )


def test_error_no_time_overlap_names_both_spans(scene, capsys, tmp_path):
    early = Trajectory(scene["estimate"].stamps_ns - 3600 * 10**9, scene["estimate"].T_world_lidar)
    write_tum(tmp_path / "early.txt", early)
    line = _error_line(_eval_args(tmp_path / "early.txt", scene["log"], tmp_path / "o"), capsys)
    assert "no time overlap: trajectory spans [" in line and "reference spans [" in line
    reference_start = _unix_ns(0.0) / 1e9
    assert f"{reference_start:.3f}" in line and f"{early.stamps_ns[0] / 1e9:.3f}" in line


def test_error_ins_never_aligned(scene, capsys, tmp_path):
    log = tmp_path / "aligning.log"
    log.write_text("\r\n".join(_inspvax_lines(scene["t"][:50], scene["T_enu_imu"][:50], status="INS_ALIGNING")))
    line = _error_line(_eval_args(scene["root"] / "estimate_tum.txt", log, tmp_path / "o"), capsys)
    assert "never reached an accepted status (INS_SOLUTION_GOOD)" in line and "INS_ALIGNING x50" in line


def test_error_too_few_associated_poses(scene, capsys, tmp_path):
    est = scene["estimate"]
    few = Trajectory(
        np.r_[est.stamps_ns[:2], est.stamps_ns[-1] + np.arange(1, 4) * 10**10],
        np.r_[est.T_world_lidar[:2], est.T_world_lidar[:3]],
    )
    write_tum(tmp_path / "few.txt", few)
    line = _error_line(_eval_args(tmp_path / "few.txt", scene["log"], tmp_path / "o"), capsys)
    assert "only 2 of 5 poses associated" in line and "at least 3" in line


def test_error_malformed_trajectory_rows_name_the_line(scene, capsys, tmp_path):
    rows = (scene["root"] / "estimate_tum.txt").read_text().splitlines()
    rows[3] = rows[3].replace(" ", " x", 1)
    (tmp_path / "bad_tum.txt").write_text("\n".join(rows) + "\n")
    line = _error_line(_eval_args(tmp_path / "bad_tum.txt", scene["log"], tmp_path / "o"), capsys)
    assert "bad_tum.txt:4:" in line
    rows = (scene["root"] / "estimate.kitti").read_text().splitlines()
    rows[6] = rows[6].replace(" ", " nope ", 1)
    (tmp_path / "bad.kitti").write_text("\n".join(rows) + "\n")
    (tmp_path / "bad.times.txt").write_text((scene["root"] / "estimate.times.txt").read_text())
    line = _error_line(_eval_args(tmp_path / "bad.kitti", scene["log"], tmp_path / "o"), capsys)
    assert "bad.kitti:7:" in line
    rows[6] = "1 2 3"
    (tmp_path / "bad.kitti").write_text("\n".join(rows) + "\n")
    assert "bad.kitti:7: expected 12 KITTI columns" in _error_line(
        _eval_args(tmp_path / "bad.kitti", scene["log"], tmp_path / "o"), capsys
    )


def test_error_missing_inputs(scene, capsys, tmp_path):
    assert "trajectory file not found" in _error_line(
        _eval_args(tmp_path / "none.txt", scene["log"], tmp_path / "o"), capsys
    )
    assert "GNSS log not found" in _error_line(
        _eval_args(scene["root"] / "estimate_tum.txt", tmp_path / "none.log", tmp_path / "o"), capsys
    )
    args = _eval_args(scene["root"] / "estimate_tum.txt", scene["log"], tmp_path / "o")
    assert "extrinsic file not found" in _error_line(args + ["--extrinsics", str(tmp_path / "e.toml")], capsys)


def test_config_section_is_used(scene, tmp_path, capsys):
    config = tmp_path / "c.toml"
    config.write_text('[gnss]\naccepted_ins_statuses = ["INS_ALIGNMENT_COMPLETE"]\n')
    args = _eval_args(scene["root"] / "estimate_tum.txt", scene["log"], tmp_path / "o") + ["--config", str(config)]
    assert "INS_ALIGNMENT_COMPLETE" in _error_line(args, capsys)
    assert GnssConfig().accepted_ins_statuses == ("INS_SOLUTION_GOOD",)
    config.write_text('[gnss]\naccepted_ins_statuses = ["INS_GOOD"]\n')
    assert "unknown INS status 'INS_GOOD'" in _error_line(args, capsys)
    config.write_text("[gnss]\norigin = [48.1, 11.5]\n")
    assert "gnss.origin: a list of 2 is out of range" in _error_line(args, capsys)
    config.write_text("[gnss]\nmax_association_gap_s = 0.01\n")  # below the 0.05 s log period
    assert "only 0 of" in _error_line(args, capsys)


def test_origin_option_is_recorded(scene, tmp_path, capsys):
    o = ORIGIN
    args = [
        "eval",
        str(scene["root"] / "estimate_tum.txt"),
        "--span",
        str(scene["log"]),
        "--extrinsics",
        str(scene["root"] / "extrinsic.yaml"),
        "--out",
        str(tmp_path / "o"),
        "--origin",
        repr(o.latitude_deg),
        repr(o.longitude_deg),
        repr(o.height_ellipsoid_m + 10.0),
    ]
    assert _run(args, capsys)[0] == 0
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["settings"]["origin"] == [o.latitude_deg, o.longitude_deg, o.height_ellipsoid_m + 10.0]
    assert report["ate"]["translation_3d_m"]["rmse"] < 0.022  # SE(3) alignment absorbs the origin
    assert "latitude" in _error_line(args[:-3] + ["95", "0", "0"], capsys)


def test_eval_on_real_span_stream(tmp_path, capsys):
    from pathlib import Path

    stream = (
        Path(__file__).resolve().parents[1].parent
        / "shared"
        / "data"
        / "real"
        / "novatel_span_driver"
        / "derived"
        / "propak6-ins-ppp.receiver_stream.bin.gz"
    )
    if not stream.exists():
        pytest.skip("shared/data/real is not beside the checkout")
    from lidar3d.gnss import read_span_log, span_reference

    reference = span_reference(read_span_log(stream))
    G = np.eye(4)
    G[:3, :3] = Rotation.from_euler("z", -120.0, degrees=True).as_matrix()
    G[:3, 3] = [100.0, 50.0, -3.0]
    estimate = reference.T_enu_imu[::2] @ T_IMU_LIDAR
    write_tum(tmp_path / "est.txt", Trajectory(reference.stamps_ns[::2], np.linalg.inv(G) @ estimate))
    (tmp_path / "e.yaml").write_text(EXTRINSIC_YAML)
    code, stdout, _ = _run(
        [
            "eval",
            str(tmp_path / "est.txt"),
            "--span",
            str(stream),
            "--extrinsics",
            str(tmp_path / "e.yaml"),
            "--align",
            "yaw",
            "--out",
            str(tmp_path / "o"),
        ],
        capsys,
    )
    assert code == 0 and "2289 of 2289 INSPVAX" in stdout
    report = json.loads((tmp_path / "o" / "report.json").read_text())
    assert report["ate"]["translation_3d_m"]["max"] < 1e-4  # TUM text precision (1e-6 m, 1e-9 quaternion)
    assert report["association"]["gnss_quality"] == {"PPP": 1145}


def test_plots_draw_the_estimate_over_the_reference_coloured_by_error(scene):
    """Issue 22: at centimetre error the estimate stays visible (drawn above the reference, coloured
    by its error with a colour bar in metres); the height axis says ENU up, not ellipsoidal; a
    rotation-error plot exists."""
    from matplotlib.collections import LineCollection, PathCollection

    from lidar3d.export.span_plots import span_figures

    result = evaluate_span_files(
        scene["root"] / "estimate_tum.txt", scene["log"], extrinsics_path=scene["root"] / "extrinsic.yaml"
    )
    figures = span_figures(result)
    assert set(figures) == {"top_view.png", "error_over_time.png", "rotation_error.png", "height_profile.png"}
    top = figures["top_view.png"].axes[0]
    estimate = next(c for c in top.collections if isinstance(c, LineCollection))
    reference = [c for c in top.collections if isinstance(c, PathCollection)]
    assert reference and all(estimate.get_zorder() > c.get_zorder() for c in reference)
    errors = result.evaluation.errors.translation_3d_m
    assert len(estimate.get_array()) == len(errors) - 1 and estimate.get_array().max() <= errors.max()
    assert figures["top_view.png"].axes[1].get_ylabel() == "estimate: 3-D position error [m]"
    height = figures["height_profile.png"].axes[0]
    assert height.get_ylabel() == "ENU up, above the origin [m]" and "relative to the origin" in height.get_title()
    rotation = figures["rotation_error.png"].axes[0]
    assert rotation.get_ylabel() == "rotation error [deg]"
    assert np.allclose(rotation.get_lines()[0].get_ydata(), result.evaluation.errors.rotation_deg, equal_nan=True)
