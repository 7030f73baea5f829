"""Input sanity (issue 21, defects 1-3): one damaged point never moves a scan's time base, absurd and
non-finite points and outlier point times are dropped and counted, a damaged header is one line."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from synthetic_sweep import synthetic_sweep

from lidar3d.cli.main import main
from lidar3d.errors import PointCloudError
from lidar3d.io.bag_writer import write_cloud_bag, write_scan_bag
from lidar3d.io.pointcloud2 import MAX_POINT_STEP, PointField, decode_parts, encode_scan, time_from_azimuth
from lidar3d.io.scan_decoder import ScanDecoder
from lidar3d.io.scan_sanity import SanityCounts, coordinate_limit_m, sanitize_scan
from lidar3d.io.scan_source import ScanSource
from lidar3d.records import Scan
from lidar3d.sensors import VLP16, VLP32C

STAMP_NS = 1_700_000_000_123_456_789


def sweep(n_columns: int = 60, *, seed: int = 0, stamp_ns: int = STAMP_NS) -> Scan:
    """A VLP-16 sweep with times 0..0.1 s growing with the clockwise azimuth."""
    return synthetic_sweep(n_columns, stamp_ns, seed=seed, azimuth_offset=0.5, time_offset=0.5)


def decoder(sensor=VLP16) -> ScanDecoder:
    return ScanDecoder(sensor, 1.0, label="test.bag", topic="/velodyne_points")


def with_times(scan: Scan, time_s: np.ndarray) -> Scan:
    return Scan(scan.stamp_ns, scan.points, scan.intensity, scan.ring, time_s)


def f32(values: np.ndarray) -> np.ndarray:
    return np.asarray(values).astype(np.float32).astype(np.float64)


# -- defect 1: the time base --------------------------------------------------------------------


def test_one_point_time_of_1e6_is_dropped_and_the_others_stay_relative():
    scan = sweep()
    time_s = scan.time_offset_s.copy()
    time_s[7] = 1.0e6
    decoded, _stats, counts = decoder().decode(encode_scan(with_times(scan, time_s)))
    assert counts == SanityCounts(n_outlier_times=1)
    keep = np.arange(len(scan)) != 7
    np.testing.assert_array_equal(decoded.time_offset_s, f32(scan.time_offset_s[keep]))
    np.testing.assert_array_equal(decoded.points, f32(scan.points[keep]))


def test_absolute_times_with_a_few_relative_ones_keep_the_absolute_base():
    scan = sweep()
    fields = (
        PointField("x", 0, 8),
        PointField("y", 8, 8),
        PointField("z", 16, 8),
        PointField("timestamp", 24, 8),
    )
    records = np.zeros(len(scan), dtype=np.dtype({"names": ["x", "y", "z", "t"], "formats": ["<f8"] * 4}))
    records["x"], records["y"], records["z"] = scan.points.T
    records["t"] = STAMP_NS * 1e-9 + scan.time_offset_s
    records["t"][[3, 4]] = 0.05  # relative values among absolute ones: damage
    parts = dataclasses.replace(
        encode_scan(scan), fields=fields, point_step=32, row_step=32 * len(scan), data=records.view(np.uint8)
    )
    decoded, _stats, counts = decoder().decode(parts)
    assert counts == SanityCounts(n_outlier_times=2)
    keep = ~np.isin(np.arange(len(scan)), [3, 4])
    np.testing.assert_allclose(decoded.time_offset_s, scan.time_offset_s[keep], rtol=0, atol=1e-6)


def test_times_relative_to_the_sweep_end_are_kept_as_they_are():
    scan = sweep()
    before_end = scan.time_offset_s - VLP16.sweep_period_s  # -0.1..0 s, the stock ROS driver's convention
    decoded, _stats, counts = decoder().decode(encode_scan(with_times(scan, before_end)))
    assert counts == SanityCounts()
    np.testing.assert_array_equal(decoded.time_offset_s, f32(before_end))


def test_without_a_time_field_one_absurd_first_point_does_not_move_the_derived_times():
    scan = sweep()
    fields = tuple(f for f in encode_scan(scan).fields if f.name != "time")
    clean, _stats, _counts = decoder().decode(dataclasses.replace(encode_scan(scan), fields=fields))
    points = scan.points.copy()
    points[0] = [3.0e38, -1.0e38, 5.0]
    damaged = Scan(scan.stamp_ns, points, scan.intensity, scan.ring, scan.time_offset_s)
    parts = dataclasses.replace(encode_scan(damaged), fields=fields)
    decoded, _stats, counts = decoder().decode(parts)
    assert counts == SanityCounts(n_absurd_coordinates=1)
    # the sweep now starts at the second point: the same times, shifted by its offset from the first
    expected = time_from_azimuth(f32(scan.points[1:]), VLP16.sweep_period_s)
    np.testing.assert_array_equal(decoded.time_offset_s, expected)
    assert np.abs(decoded.time_offset_s - clean.time_offset_s[1:]).max() <= VLP16.sweep_period_s


def test_nan_times_are_outliers():
    scan = sweep()
    time_s = scan.time_offset_s.copy()
    time_s[[0, 9]] = np.nan
    time_s[11] = -0.2  # 2 sweeps before the stamp
    _decoded, _stats, counts = decoder().decode(encode_scan(with_times(scan, time_s)))
    assert counts == SanityCounts(n_outlier_times=3)


# -- defect 2: header fields --------------------------------------------------------------------


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"point_step": 2**31}, rf"point_step 2147483648 is larger than any point record \({MAX_POINT_STEP} bytes\)"),
        ({"point_step": 2**32 - 1, "width": 0, "row_step": 0}, r"point_step 4294967295 is larger"),
        ({"width": 2**32 - 1}, r"data holds 30720 bytes but width\*height\*point_step = 4294967295\*1\*32"),
        ({"height": 2, "row_step": 2**31}, r"data holds 30720 bytes but height\*row_step = 2\*2147483648"),
        ({"point_step": 0}, r"bad cloud shape: height 1, width 960, point_step 0"),
    ],
)
def test_nonsense_header_fields_are_one_line_errors(change, message):
    parts = dataclasses.replace(encode_scan(sweep()), **change)
    with pytest.raises(PointCloudError, match=message):
        decode_parts(parts)


def test_field_offset_beyond_uint31_is_an_error():
    parts = encode_scan(sweep())
    fields = tuple(PointField(f.name, 2**31 if f.name == "ring" else f.offset, f.datatype) for f in parts.fields)
    with pytest.raises(PointCloudError, match=r"field 'ring' \(UINT16 at offset 2147483648\) does not fit"):
        decode_parts(dataclasses.replace(parts, fields=fields))


def test_point_step_2_31_in_a_bag_is_one_line_naming_file_topic_and_message(tmp_path, capsys):
    clouds = [encode_scan(sweep(stamp_ns=STAMP_NS + i * 100_000_000)) for i in range(2)]
    clouds[0] = dataclasses.replace(clouds[0], point_step=2**31)
    bag = tmp_path / "bad.bag"
    write_cloud_bag(bag, clouds)
    assert main(["run", str(bag), "--out", str(tmp_path / "out")]) == 1
    assert capsys.readouterr().err.splitlines() == [
        f"lidar3d run: error: {bag}: /velodyne_points message 0 at stamp {STAMP_NS} ns: "
        f"point_step 2147483648 is larger than any point record ({MAX_POINT_STEP} bytes)"
    ]


# -- defect 3: absurd coordinates, non-finite points ----------------------------------------------


def test_big_endian_flag_on_little_endian_data_leaves_only_plausible_points():
    parts = dataclasses.replace(encode_scan(sweep()), is_bigendian=True)
    decoded, stats, counts = decoder().decode(parts)
    assert counts.n_dropped > 0 and counts.n_dropped + len(decoded) == stats.n_kept
    assert np.isfinite(decoded.points).all() and np.abs(decoded.points).max() <= coordinate_limit_m(VLP16)
    assert np.isfinite(decoded.time_offset_s).all() and np.abs(decoded.time_offset_s).max() <= 0.15


def test_sanitize_scan_counts_each_point_under_its_first_reason():
    scan = sweep()
    points = scan.points.copy()
    time_s = scan.time_offset_s.copy()
    points[0] = [np.nan, 1.0, 1.0]
    points[1] = [1.0, np.inf, 1.0]
    points[2] = [5.0, 2000.0, 0.0]
    points[3] = [np.nan, 2000.0, 0.0]
    time_s[2] = np.nan  # counted as absurd, its first reason
    time_s[4] = 0.151
    time_s[5] = -0.149
    sane, counts = sanitize_scan(Scan(scan.stamp_ns, points, scan.intensity, scan.ring, time_s), VLP16)
    assert counts == SanityCounts(n_nonfinite=3, n_absurd_coordinates=1, n_outlier_times=1)
    assert len(sane) == len(scan) - 5 and sane.time_offset_s[0] == -0.149


def test_coordinate_limit_is_1_km_or_twice_the_sensor_range():
    assert coordinate_limit_m(VLP16) == 1000.0 and coordinate_limit_m(VLP32C) == 1000.0
    assert coordinate_limit_m(dataclasses.replace(VLP16, max_range_m=800.0)) == 1600.0


def test_a_clean_scan_is_returned_as_it_is():
    scan = sweep()
    sane, counts = sanitize_scan(scan, VLP16)
    assert sane is scan and counts == SanityCounts()


def test_a_scan_with_nothing_sane_is_an_empty_scan():
    scan = sweep(n_columns=2)
    reader = decoder()
    reader.decode(encode_scan(scan))  # the first cloud sets a relative time base
    decoded, _stats, counts = reader.decode(encode_scan(with_times(scan, np.full(len(scan), 5.0))))
    assert len(decoded) == 0 and counts.n_outlier_times == len(scan)


# -- through a bag and `lidar3d run` ------------------------------------------------------------


@pytest.fixture(scope="module")
def clean_scans(tmp_path_factory):
    sim = pytest.importorskip("lidar3d.sim")
    folder = sim.simulate("loop", tmp_path_factory.mktemp("sim") / "loop", seed=0, duration_s=0.6)
    with ScanSource(folder.bag, min_range_m=1.0) as source:
        return list(source)[:5]


def damaged_copy(scans: list[Scan]) -> list[Scan]:
    """Scan 2 with one point time 1e6 s (the flipped byte of issue 21) and one point at 3e38 m; every
    time of scan 4 two seconds out (nothing of it is left)."""
    damaged = list(scans)
    damaged[4] = with_times(scans[4], np.full(len(scans[4]), 2.0))
    scan = scans[2]
    time_s = scan.time_offset_s.copy()
    time_s[100] = 1.0e6
    points = scan.points.copy()
    points[200] = [3.0e38, 1.0, 1.0]
    damaged[2] = Scan(scan.stamp_ns, points, scan.intensity, scan.ring, time_s)
    return damaged


def test_a_damaged_sqlite_bag_reads_with_the_damage_dropped_and_counted(clean_scans, tmp_path):
    bag = tmp_path / "damaged"
    write_scan_bag(bag, damaged_copy(clean_scans), storage="ros2-sqlite3")
    with ScanSource(bag, min_range_m=1.0) as source:
        scans = list(source)
    stats = source.stats
    assert (stats.n_absurd_coordinates, stats.n_outlier_times, stats.n_nonfinite) == (1, 1 + len(clean_scans[4]), 0)
    keep = ~np.isin(np.arange(len(clean_scans[2])), [100, 200])
    np.testing.assert_array_equal(scans[2].time_offset_s, clean_scans[2].time_offset_s[keep])
    np.testing.assert_array_equal(scans[2].points, clean_scans[2].points[keep])
    assert len(scans) == 5 and len(scans[4]) == 0
    for index in (0, 1, 3):
        np.testing.assert_array_equal(scans[index].time_offset_s, clean_scans[index].time_offset_s)
        np.testing.assert_array_equal(scans[index].points, clean_scans[index].points)


def test_run_on_a_damaged_bag_warns_and_counts_in_the_summary(clean_scans, tmp_path, capsys):
    bag = tmp_path / "damaged.bag"
    write_scan_bag(bag, damaged_copy(clean_scans))
    out = tmp_path / "out"
    assert main(["-q", "run", str(bag), "--out", str(out), "--no-loop"]) == 0
    stdout = capsys.readouterr().out
    n_outliers = 1 + len(clean_scans[4])
    assert (
        f"warning: input sanity: dropped 1 points with absurd coordinates and {n_outliers} with point times "
        "outside the sweep (0 non-finite points also dropped); see input_stats in summary.json"
    ) in stdout
    assert "warning: scans 4-4: too few features, pose from the motion model" in stdout  # the emptied scan
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scans"] == 5 and summary["counts"]["motion_model_scans"] == 1
    stats = summary["input_stats"]
    assert (stats["absurd_coordinates_dropped"], stats["outlier_times_dropped"], stats["nonfinite_dropped"]) == (
        1,
        n_outliers,
        0,
    )
