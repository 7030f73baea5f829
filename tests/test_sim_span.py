"""The simulated NovAtel SPAN log, read back with a small parser written here from the reference.

Independent of lidar3d.gnss: the CRC is NovAtel's bitwise algorithm, geodetic -> ENU is the closed
form through ECEF, the attitude matrix is built from elementary rotations, and the extrinsic is read
with tomllib.
"""

import datetime
import re
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar3d.sim import GeoOrigin, Simulation, SpanParams
from lidar3d.sim.output import write_simulation

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

LINE = re.compile(r"^#([A-Z]+),([^;]*);([^*]*)\*([0-9a-f]{8})\r\n$")
WGS84_A = 6378137.0
WGS84_F = 1.0 / 298.257223563


def crc32_novatel(data: bytes) -> int:
    crc = 0
    for byte in data:
        value = (crc ^ byte) & 0xFF
        for _ in range(8):
            value = (value >> 1) ^ 0xEDB88320 if value & 1 else value >> 1
        crc = ((crc >> 8) & 0x00FFFFFF) ^ value
    return crc


def parse(lines):
    """Decode lines into dicts; asserts the framing, CRC and field counts."""
    records = []
    for line in lines:
        match = LINE.match(line)
        assert match, line
        name, header, body, crc = match.groups()
        assert crc32_novatel(line[1 : line.index("*")].encode()) == int(crc, 16)
        h = header.split(",")
        assert len(h) == 9 and h[0] == "COM1" and h[3] == "FINESTEERING"
        assert re.fullmatch(r"\d+\.\d{3}", h[5]) and re.fullmatch(r"[0-9a-f]{8}", h[6])
        week, seconds = int(h[4]), float(h[5])
        f = body.split(",")
        unix = 315964800 + 604800 * week + seconds - 18
        if name == "INSPVAXA":
            assert len(f) == 23
            records.append(
                {
                    "log": name,
                    "unix": unix,
                    "ins_status": f[0],
                    "pos_type": f[1],
                    "lat": float(f[2]),
                    "lon": float(f[3]),
                    "h": float(f[4]) + float(f[5]),
                    "vel_neu": np.array([float(v) for v in f[6:9]]),
                    "rpa": np.array([float(v) for v in f[9:12]]),
                    "sigma": np.array([float(v) for v in f[12:21]]),
                    "ext": int(f[21], 16),
                }
            )
        elif name == "BESTPOSA":
            assert len(f) == 21 and f[0] == "SOL_COMPUTED" and f[6] == "WGS84"
            records.append(
                {
                    "log": name,
                    "unix": unix,
                    "pos_type": f[1],
                    "lat": float(f[2]),
                    "lon": float(f[3]),
                    "h": float(f[4]) + float(f[5]),
                    "sigma": np.array([float(v) for v in f[7:10]]),
                    "n_svs": int(f[13]),
                }
            )
        else:
            raise AssertionError(f"unexpected log {name}")
    return records


def ecef(lat_deg, lon_deg, h):
    lat, lon = np.deg2rad(lat_deg), np.deg2rad(lon_deg)
    e2 = WGS84_F * (2.0 - WGS84_F)
    n = WGS84_A / np.sqrt(1.0 - e2 * np.sin(lat) ** 2)
    return np.stack(
        [(n + h) * np.cos(lat) * np.cos(lon), (n + h) * np.cos(lat) * np.sin(lon), (n * (1.0 - e2) + h) * np.sin(lat)],
        axis=-1,
    )


def R_enu_ecef(lat_deg, lon_deg):
    lat, lon = np.deg2rad(lat_deg), np.deg2rad(lon_deg)
    return np.array(
        [
            [-np.sin(lon), np.cos(lon), 0.0],
            [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
            [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)],
        ]
    )


def to_enu(records, origin: GeoOrigin):
    lat = np.array([r["lat"] for r in records])
    lon = np.array([r["lon"] for r in records])
    h = np.array([r["h"] for r in records])
    delta = ecef(lat, lon, h) - ecef(origin.latitude_deg, origin.longitude_deg, origin.height_m)
    return delta @ R_enu_ecef(origin.latitude_deg, origin.longitude_deg).T


def R_local_vehicle(roll, pitch, azimuth):
    """SPAN: R = Rz(-azimuth) Rx(pitch) Ry(roll), angles in degrees (reference section 1.9)."""
    r, p, a = np.deg2rad([roll, pitch, -azimuth])
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(p), -np.sin(p)], [0, np.sin(p), np.cos(p)]])
    ry = np.array([[np.cos(r), 0, np.sin(r)], [0, 1, 0], [-np.sin(r), 0, np.cos(r)]])
    return rz @ rx @ ry


def R_world_imu(record, origin: GeoOrigin):
    R_local = R_local_vehicle(*record["rpa"])
    R_origin_local = R_enu_ecef(origin.latitude_deg, origin.longitude_deg) @ R_enu_ecef(record["lat"], record["lon"]).T
    return R_origin_local @ R_local


@pytest.fixture(scope="module")
def exact():
    sim = Simulation("loop", duration_s=30.0, span=SpanParams(noise=False))
    return sim, parse(sim.span_log_lines())


@pytest.fixture(scope="module")
def noisy():
    sim = Simulation("loop", duration_s=30.0)
    return sim, parse(sim.span_log_lines())


def test_rates_and_gps_time(exact):
    sim, records = exact
    ins = [r for r in records if r["log"] == "INSPVAXA"]
    best = [r for r in records if r["log"] == "BESTPOSA"]
    unix = np.array([r["unix"] for r in ins])
    np.testing.assert_allclose(np.diff(unix), 0.05, atol=1e-6)
    assert unix[0] == pytest.approx(sim.stamps_ns[0] / 1e9, abs=1e-6)
    assert unix[-1] == pytest.approx(sim.start_time_ns / 1e9 + sim.duration_s, abs=1e-6)
    assert len(best) == 31 and all(r["unix"] % 1.0 == 0.0 for r in best)
    first = sim.span_log_lines()[0].split(",")
    start = datetime.datetime.fromtimestamp(sim.start_time_ns / 1e9, tz=datetime.timezone.utc)
    assert start == datetime.datetime(2024, 5, 14, 9, 0, 0, tzinfo=datetime.timezone.utc)
    assert (first[5], first[6]) == ("2314", "205218.000")  # Tuesday 09:00:00 UTC + 18 leap seconds


def test_inspvax_parses_back_to_the_true_imu_and_lidar_pose(exact, tmp_path):
    sim, records = exact
    origin = sim.span_params.origin
    ins = [r for r in records if r["log"] == "INSPVAXA"]
    stamps = np.rint(np.array([r["unix"] for r in ins]) * 1e3).astype(np.int64) * 1_000_000
    truth = sim.T_world_imu_at(stamps)
    np.testing.assert_allclose(to_enu(ins, origin), truth[:, :3, 3], atol=2e-4)  # height printed to 0.1 mm
    for record, T in zip(ins, truth):
        error = Rotation.from_matrix(R_world_imu(record, origin).T @ T[:3, :3]).magnitude()
        assert error < 1e-7
    velocity = sim.motion.velocity_at(sim.route_seconds(stamps))
    vel_neu = np.array([r["vel_neu"] for r in ins])
    np.testing.assert_allclose(vel_neu[:, [1, 0, 2]], velocity, atol=2e-3)  # local level ~ origin level here

    # Through the written extrinsic back to the lidar ground truth at the scan stamps.
    write_simulation(Simulation("loop", duration_s=0.2), tmp_path)
    table = tomllib.loads((tmp_path / "extrinsics.toml").read_text())["T_imu_lidar"]
    T_imu_lidar = np.eye(4)
    T_imu_lidar[:3, :3] = Rotation.from_quat(table["quaternion_xyzw"]).as_matrix()
    T_imu_lidar[:3, 3] = table["translation_m"]
    np.testing.assert_allclose(T_imu_lidar[:3, 3], [0.02, 0.35, 0.80])
    assert np.rad2deg(np.arccos(T_imu_lidar[1, 0])) < 2.0  # lidar x forward is vehicle y
    by_stamp = {int(s): (r, T) for s, r, T in zip(stamps, ins, truth)}
    gt = sim.ground_truth
    for stamp, T_gt in zip(gt.stamps_ns, gt.T_world_lidar):
        record, _ = by_stamp[int(stamp)]
        T_world_imu = np.eye(4)
        T_world_imu[:3, :3] = R_world_imu(record, origin)
        T_world_imu[:3, 3] = to_enu([record], origin)[0]
        T_world_lidar = T_world_imu @ T_imu_lidar
        np.testing.assert_allclose(T_world_lidar[:3, 3], T_gt[:3, 3], atol=3e-4)
        assert Rotation.from_matrix(T_world_lidar[:3, :3].T @ T_gt[:3, :3]).magnitude() < 1e-6


def test_bestpos_reports_the_antenna_position(exact):
    sim, records = exact
    best = [r for r in records if r["log"] == "BESTPOSA"]
    stamps = np.rint(np.array([r["unix"] for r in best])).astype(np.int64) * 1_000_000_000
    truth = sim.T_world_imu_at(stamps)
    antenna = truth[:, :3, 3] + truth[:, :3, :3] @ np.asarray(sim.rig.imu_to_antenna_m)
    np.testing.assert_allclose(to_enu(best, sim.span_params.origin), antenna, atol=2e-4)


def test_noisy_log_is_honest_and_has_one_degraded_stretch(noisy):
    sim, records = noisy
    origin = sim.span_params.origin
    ins = [r for r in records if r["log"] == "INSPVAXA"]
    stamps = np.rint(np.array([r["unix"] for r in ins]) * 1e3).astype(np.int64) * 1_000_000
    truth = sim.T_world_imu_at(stamps)
    error = to_enu(ins, origin) - truth[:, :3, 3]
    sigma = np.array([r["sigma"] for r in ins])
    sigma_enu = sigma[:, [1, 0, 2]]  # lat sigma is north, lon sigma is east
    assert np.all(np.abs(error) < 5.0 * sigma_enu + 2e-4)
    attitude_error = np.array(
        [Rotation.from_matrix(R_world_imu(r, origin).T @ T[:3, :3]).magnitude() for r, T in zip(ins, truth)]
    )
    assert np.all(np.rad2deg(attitude_error) < 5.0 * np.linalg.norm(sigma[:, 6:9], axis=1))

    good = np.array([r["ins_status"] == "INS_SOLUTION_GOOD" for r in ins])
    fixed = np.array([r["pos_type"] == "INS_RTKFIXED" for r in ins])
    np.testing.assert_array_equal(good, fixed)
    degraded_start, degraded_end = sim.degraded_gnss_span_ns()
    inside = (stamps >= degraded_start) & (stamps < degraded_end)
    np.testing.assert_array_equal(~good, inside)  # exactly one stretch, where the metadata says
    assert {r["pos_type"] for r, bad in zip(ins, ~good) if bad} == {"INS_RTKFLOAT", "INS_PSRSP"}
    assert sigma[~good, 0].min() > 5.0 * sigma[good, 0].max()
    rms_good = np.sqrt(np.mean(np.sum(error[good] ** 2, axis=1)))
    assert 0.003 < rms_good < 0.06  # RTK level, 2-3 cm
    assert np.abs(error[~good]).max() > 0.1
    best = [r for r in records if r["log"] == "BESTPOSA"]
    assert {r["pos_type"] for r in best} >= {"INS_RTKFIXED", "INS_PSRSP"}


def test_other_seed_other_errors_same_truth():
    a = Simulation("loop", duration_s=2.0, seed=1).span_log_lines()
    b = Simulation("loop", duration_s=2.0, seed=2, span=SpanParams(noise=False)).span_log_lines()
    assert len(a) == len(b) and a != b
    assert a == Simulation("loop", duration_s=2.0, seed=1).span_log_lines()
