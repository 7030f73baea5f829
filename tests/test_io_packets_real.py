"""Raw packets of real sensors (../shared/data/real, see its SOURCES.md) decoded through the scan source.

* nebula's VLP-16 (dual return) and VLP-32C packet bags against nebula's own decoded clouds;
* MRPT's VLP-16 and HDL-32E pcaps give the scan counts MRPT's tests expect (4 and 3);
* a pcap whose product byte says HDL-32E but fires as a VLP-16 is decoded as a VLP-16, with a warning;
* the moving HDL-32E pcap: its decoded sweeps, registered by an independent ICP (Open3D), move at the
  speed of its own GPRMC sentences, and ``lidar3d run`` travels the distance that speed implies within
  15 %; the stationary VLP-16 pcap stays within 5 cm under ``lidar3d run``.
"""

from __future__ import annotations

import itertools
import logging
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from lidar3d.cli.main import main
from lidar3d.config import Config, config_with
from lidar3d.io.packet_info import packet_info
from lidar3d.io.pcd import read_pcd
from lidar3d.io.scan_source import open_scan_source
from lidar3d.io.trajectory_io import read_trajectory
from lidar3d.io.velodyne_packets import PacketModel

REAL = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "real"
pytestmark = pytest.mark.skipif(
    not (REAL / "nebula").is_dir(), reason=f"real data folder {REAL} is absent (CI places shared/ beside the clone)"
)

NEBULA_VLP16 = REAL / "nebula" / "vlp16" / "1673400471837873222"
NEBULA_VLP16_PCD = REAL / "nebula" / "vlp16" / "1673400472138016708.pcd"
NEBULA_VLP32 = REAL / "nebula" / "vlp32" / "1713492677464078412"
NEBULA_VLP32_PCD = REAL / "nebula" / "vlp32" / "1713492677464078412.pcd"
MRPT_VLP16 = REAL / "mrpt" / "sample_velodyne_vlp16_gps.pcap"
MRPT_HDL32 = REAL / "mrpt" / "sample_velodyne_hdl32.pcap"
MISLABELLED = REAL / "rust-lidar-utils" / "velodyne_vlp16.pcap"
MOVING_HDL32 = REAL / "rust-lidar-utils" / "hdl32_example.pcap"

#: every return, nothing dropped by range: the clouds as the sensor sent them
RAW = config_with(Config(), {"input": {"packet_return": "both"}, "sensor": {"min_range_m": 0.0}})


def _scans(path: Path, config: Config = RAW):
    with open_scan_source(path, config) as source:
        return source, list(source)


def _best_match(scans, reference: np.ndarray) -> tuple[int, np.ndarray, np.ndarray]:
    """The scan nearest to ``reference`` as a point set: its index, and per reference point the distance
    to and index of its nearest decoded point."""
    matches = [cKDTree(scan.points).query(reference) for scan in scans]
    best = int(np.argmax([np.mean(d < 0.02) for d, _i in matches]))
    return best, matches[best][0], matches[best][1]


@pytest.mark.parametrize(
    ("bag", "pcd", "model", "n_scans", "rings", "median_range_m"),
    [
        (NEBULA_VLP16, NEBULA_VLP16_PCD, PacketModel.VLP16, 4, range(1, 16), 1.7),  # ring 0 hits nothing
        (NEBULA_VLP32, NEBULA_VLP32_PCD, PacketModel.VLP32C, 5, range(32), 3.6),
    ],
)
def test_nebula_packet_bags_match_nebulas_clouds(bag, pcd, model, n_scans, rings, median_range_m):
    source, scans = _scans(bag)
    assert source.sensor.model is model and len(scans) == n_scans
    reference, fields = read_pcd(pcd)
    best, distance_m, nearest = _best_match(scans, reference)
    # nebula's frame is the sensor frame (x forward, y left, z up), as ours: no conversion needed
    assert np.mean(distance_m < 0.02) > 0.95
    scan = scans[best]
    back, _ = cKDTree(reference).query(scan.points)
    assert np.mean(back < 0.02) > 0.95
    assert set(np.unique(scan.ring).tolist()) == set(rings)
    if "channel" in fields:  # nebula numbers channels by elevation, as our rings
        close = distance_m < 0.02
        assert np.mean(scan.ring[nearest[close]] == fields["channel"][close]) > 0.99
    assert float(np.median(scan.range_m)) == pytest.approx(median_range_m, abs=0.15)
    assert scan.time_offset_s.min() >= 0.0 and scan.time_offset_s.max() < 0.101


def test_nebula_vlp16_is_dual_return_and_keeps_the_strongest_by_default():
    source, strongest = _scans(NEBULA_VLP16, config_with(RAW, {"input": {"packet_return": "strongest"}}))
    assert source.sensor.detection.return_mode.value == "dual"
    _source, both = _scans(NEBULA_VLP16)
    _source, last = _scans(NEBULA_VLP16, config_with(RAW, {"input": {"packet_return": "last"}}))
    for s, b, la in zip(strongest, both, last):
        # returns that are both strongest and last are kept once, in each selection
        assert len(s) < len(b) and len(la) < len(b) and len(s) + len(la) > len(b)


@pytest.mark.parametrize(("pcap", "model", "n_scans"), [(MRPT_VLP16, "vlp16", 4), (MRPT_HDL32, "hdl32e", 3)])
def test_mrpt_pcaps_give_the_scan_counts_mrpt_expects(pcap, model, n_scans):
    source, scans = _scans(pcap)
    assert source.sensor.model.value == model and len(scans) == n_scans == len(source)
    assert all(scan.ring.max() == (15 if model == "vlp16" else 31) for scan in scans)


def test_mislabelled_product_byte_is_detected(caplog):
    with caplog.at_level(logging.WARNING, logger="lidar3d"):
        source, scans = _scans(MISLABELLED)
    assert source.sensor.model is PacketModel.VLP16 and source.sensor.detection.how == "firing pattern"
    assert any(
        "the product byte says hdl32e (0x21), but packets come every 1327.0 us" in r.getMessage()
        for r in caplog.records
    )
    assert {int(r) for scan in scans for r in np.unique(scan.ring)} == set(range(16))
    forced, _ = _scans(MISLABELLED, config_with(RAW, {"input": {"packet_model": "hdl32e"}}))
    assert forced.sensor.model is PacketModel.HDL32E and forced.sensor.detection.how == "given"


def test_info_on_real_packet_inputs(capsys):
    info = packet_info(MRPT_VLP16)
    assert (info.model, info.return_mode, info.n_scans, info.n_position) == ("vlp16", "strongest", 4, 57)
    assert info.pps == ("locked",) and info.nmea_first.valid and info.nmea_first.utc == "081802"
    assert info.ports == ((2368, 293, (1206,)), (8308, 57, (512,)))
    assert info.clock_offset_s == pytest.approx(0.368, abs=0.002)  # host clock behind GPS-disciplined sensor time
    assert main(["info", str(NEBULA_VLP16)]) == 0
    out = capsys.readouterr().out
    assert "sensor model: vlp16 (from the factory bytes; product byte: vlp16)" in out
    assert "return mode:  dual" in out and "scans:        4" in out


def test_moving_hdl32_sweeps_register_at_the_gprmc_speed():
    """Decoding check independent of our SLAM: Open3D ICP between consecutive decoded sweeps."""
    import open3d as o3d

    info = packet_info(MOVING_HDL32)
    gprmc_mps = info.nmea_first.speed_mps
    assert gprmc_mps == pytest.approx(14.8, abs=0.1)
    _source, scans = _scans(MOVING_HDL32, Config())

    def cloud(scan):
        keep = scan.range_m > 3.0
        points = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan.points[keep])).voxel_down_sample(0.3)
        points.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=1.0, max_nn=30))
        return points

    speeds = []
    for a, b in itertools.pairwise(scans[1:]):  # the first sweep is partial
        method = o3d.pipelines.registration.TransformationEstimationPointToPlane()
        fit = o3d.pipelines.registration.registration_icp(cloud(b), cloud(a), 2.0, np.eye(4), method)
        speeds.append(np.linalg.norm(fit.transformation[:3, 3]) / ((b.stamp_ns - a.stamp_ns) * 1e-9))
    assert np.median(speeds) == pytest.approx(gprmc_mps, rel=0.05)


def _run(tmp_path: Path, pcap: Path, model: str) -> np.ndarray:
    out = tmp_path / "run"
    assert main(["-q", "run", str(pcap), "--out", str(out), "--no-loop"]) == 0
    config = (out / "config.toml").read_text()
    assert f'model = "{model}"' in config  # the sensor the packets show
    if model == "hdl32e":  # 703 rpm: the rate measured, the columns scaled from 2250 at 10 Hz
        assert "rotation_override_hz = 11.7" in config and "n_columns_override = 1919" in config
    return read_trajectory(out / "trajectory_tum.txt").positions_m


def test_stationary_vlp16_pcap_stays_within_5_cm(tmp_path):
    positions = _run(tmp_path, MRPT_VLP16, "vlp16")
    assert len(positions) == 4
    assert np.linalg.norm(positions - positions[0], axis=1).max() < 0.05


def test_moving_hdl32_run_travels_the_gprmc_distance(tmp_path):
    positions = _run(tmp_path, MOVING_HDL32, "hdl32e")
    info = packet_info(MOVING_HDL32)
    travelled = np.linalg.norm(np.diff(positions, axis=0), axis=1).sum()
    expected = info.nmea_first.speed_mps * 0.376  # the 6 scans span 0.376 s
    assert travelled == pytest.approx(expected, rel=0.15)
    assert np.linalg.norm(positions[-1] - positions[0]) == pytest.approx(travelled, rel=0.02)  # a straight drive
