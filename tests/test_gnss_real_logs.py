"""NovAtel readers against real recorded logs in ../shared/data/real (see its SOURCES.md)."""

import gzip
import json
import math
from pathlib import Path

import numpy as np
import pytest

from lidar3d.config import GnssConfig
from lidar3d.errors import GnssError
from lidar3d.gnss import (
    InsStatus,
    PositionType,
    SolutionStatus,
    TimeStatus,
    novatel_crc32,
    parse_span_bytes,
    read_span_log,
    span_reference,
)

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"
ASCII = REAL / "novatel_ascii"
SPAN_STREAMS = REAL / "novatel_span_driver" / "derived"
OEM7 = REAL / "novatel_oem7_driver"

pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason="shared/data/real is not beside the checkout")

POSITIVE_FILES = [
    "BESTGNSSPOSA.txt",
    "BESTPOSA.txt",
    "CORRIMU.txt",
    "INSPVAA.txt",
    "INSPVASA.txt",
    "INSPVAXA.txt",
    "INSSTDEVA.txt",
]


def _lines(name):
    return [ln for ln in (ASCII / name).read_bytes().splitlines() if ln.strip()]


@pytest.mark.parametrize("name", POSITIVE_FILES)
def test_every_crc_valid_ascii_line_is_accepted(name):
    lines = _lines(name)
    log = read_span_log(ASCII / name)
    stats = log.stats
    assert stats.bad_crc == 0 and stats.bad_format == 0 and stats.truncated == 0
    assert sum(stats.decoded.values()) + sum(stats.ignored.values()) == len(lines)
    # each line individually, with an independent CRC check on its bytes
    for line in lines:
        payload, _, crc = line[1:].rpartition(b"*")
        assert novatel_crc32(payload) == int(crc, 16)
        single = parse_span_bytes(line)
        assert sum(single.stats.decoded.values()) + sum(single.stats.ignored.values()) == 1


def test_known_bad_lines_are_rejected_and_counted():
    log = read_span_log(ASCII / "NEGATIVE.txt")
    assert log.stats.bad_crc == 2
    assert not log.ins and not log.positions and not log.stats.decoded
    assert log.stats.problems[0].startswith("line 1: CRC mismatch")
    assert "e370e1d9" in log.stats.problems[1]  # the recomputed CRC of the old doc example


def test_inspva_values_and_ellipsoidal_height():
    log = read_span_log(ASCII / "INSPVAA.txt")
    m = log.ins[2]  # OEM7 doc example, Calgary
    assert (m.log, m.gps_week, m.gps_seconds) == ("INSPVA", 2209, 490558.0)
    assert m.time_status is TimeStatus.FINESTEERING
    assert m.ins_status is InsStatus.INS_SOLUTION_GOOD
    assert (m.latitude_deg, m.longitude_deg, m.height_ellipsoid_m) == (51.15043714042, -114.03067871718, 1080.3548)
    assert (m.roll_deg, m.pitch_deg, m.azimuth_deg) == (-0.296402993, 0.311887972, 157.992156267)
    assert (m.north_velocity_mps, m.east_velocity_mps, m.up_velocity_mps) == (0.0051, -0.0014, -0.0012)
    assert m.undulation_m is None and m.position_type is None and math.isnan(m.latitude_std_m)
    # SPAN-SE manual line: body time differs from the header time; the body's is used
    assert log.ins[1].gps_seconds == 144088.002284950
    assert log.ins[1].ins_status is InsStatus.INS_ALIGNMENT_COMPLETE
    assert log.ins[3].ins_status is InsStatus.WAITING_AZIMUTH and log.ins[3].azimuth_deg == 0.0


def test_short_header_equals_long_header_of_same_epoch():
    long = read_span_log(ASCII / "INSPVAA.txt").ins[3]
    short = read_span_log(ASCII / "INSPVASA.txt").ins[0]
    assert short.log == "INSPVAS" and short.time_status is None
    for field in (
        "gps_week",
        "gps_seconds",
        "latitude_deg",
        "longitude_deg",
        "height_ellipsoid_m",
        "roll_deg",
        "pitch_deg",
        "azimuth_deg",
        "ins_status",
    ):
        assert getattr(short, field) == getattr(long, field)


def test_inspvax_msl_height_plus_undulation():
    log = read_span_log(ASCII / "INSPVAXA.txt")
    m = log.ins[0]
    assert m.ins_status is InsStatus.INS_SOLUTION_GOOD and m.position_type is PositionType.INS_PPP
    assert m.undulation_m == -17.0001
    assert m.height_ellipsoid_m == pytest.approx(1097.3598 - 17.0001, abs=1e-9)
    assert m.height_msl_m == pytest.approx(1097.3598, abs=1e-9)
    assert (m.latitude_std_m, m.longitude_std_m, m.height_std_m) == (0.1816, 0.1816, 0.1808)
    assert (m.roll_std_deg, m.pitch_std_deg, m.azimuth_std_deg) == (0.0292, 0.0292, 0.0582)
    assert m.extended_status == 0x13000045
    # same static receiver, INSPVA epoch 224 s earlier: 1080.3548 ellipsoidal
    assert m.height_ellipsoid_m == pytest.approx(1080.3548, abs=0.01)
    oem6 = log.ins[1]
    assert oem6.extended_status == 3 and oem6.position_type is PositionType.INS_PSRSP
    assert oem6.height_ellipsoid_m == pytest.approx(1063.6093 - 16.9, abs=1e-9)


def test_bestpos_variants():
    log = read_span_log(ASCII / "BESTPOSA.txt")
    assert len(log.positions) == 9
    first = log.positions[0]
    assert first.solution_status is SolutionStatus.SOL_COMPUTED and first.position_type is PositionType.SINGLE
    assert first.height_ellipsoid_m == pytest.approx(261.4344 - 26.0, abs=1e-9)
    assert first.datum == "WGS84" and (first.n_satellites_tracked, first.n_satellites_used) == (8, 8)
    assert log.positions[1].height_msl_m == 1064.9520  # the 23-field line from older firmware
    assert log.positions[2].station_id == "AAAA" and log.positions[2].position_type is PositionType.NARROW_INT
    unknown = log.positions[6]
    assert unknown.time_status is TimeStatus.UNKNOWN and unknown.gps_week == 0
    assert unknown.solution_status is SolutionStatus.INSUFFICIENT_OBS
    assert log.positions[7].undulation_m == 0.0 and log.positions[7].time_status is TimeStatus.COARSESTEERING
    gnss = read_span_log(ASCII / "BESTGNSSPOSA.txt").positions[0]
    assert gnss.log == "BESTGNSSPOS" and gnss.station_id == "TSTR" and gnss.position_type is PositionType.PPP
    assert gnss.height_ellipsoid_m == pytest.approx(1097.3556 - 17.0001, abs=1e-9)


def test_insstdev_values():
    log = read_span_log(ASCII / "INSSTDEVA.txt")
    a, b = log.std_devs
    assert (a.latitude_std_m, a.longitude_std_m, a.height_std_m) == (0.4372, 0.3139, 0.7547)
    assert (a.azimuth_std_deg, a.extended_status, a.time_since_update_s) == (5.1857, 0x26000005, 0)
    assert b.extended_status == 0x13000045 and b.gps_seconds == 491004.0


def _frames():
    path = ASCII / "binary_frames_oem7_driver.json"
    return json.loads(path.read_text()) if path.is_file() else []  # the module is skipped without it


@pytest.mark.parametrize("frame", _frames(), ids=lambda f: f"{f['file']}@{f['offset']}:{f['msg']}")
def test_binary_frames_decode_to_published_values(frame):
    log = parse_span_bytes(bytes.fromhex(frame["hex"]))
    assert log.stats.bad_crc == 0 and log.stats.bad_format == 0
    d = frame["decoded"]
    if frame["msg"] in ("INSPVAS", "INSPVAX"):
        (m,) = log.ins
        assert m.log == frame["msg"] and m.ins_status.name == d["status"]
        assert m.gps_week == frame["week"]
        assert m.gps_seconds == pytest.approx(frame["ms"] / 1000.0, abs=1e-9)
        assert (m.latitude_deg, m.longitude_deg) == (d["lat"], d["lon"])
        assert (m.roll_deg, m.pitch_deg, m.azimuth_deg) == (d["roll"], d["pitch"], d["azim"])
        assert (m.north_velocity_mps, m.east_velocity_mps, m.up_velocity_mps) == (d["vn"], d["ve"], d["vu"])
        if frame["msg"] == "INSPVAS":
            assert m.height_ellipsoid_m == d["h_ell"] and m.time_status is None
        else:
            assert m.height_ellipsoid_m == pytest.approx(d["h_msl"] + d["undulation"], abs=1e-9)
            assert m.position_type == d["pos_type"] and m.time_status == frame["time_status"]
            assert m.extended_status == int(d["ext"], 16)
            std = [
                m.latitude_std_m,
                m.longitude_std_m,
                m.height_std_m,
                m.roll_std_deg,
                m.pitch_std_deg,
                m.azimuth_std_deg,
            ]
            assert std == pytest.approx(d["std"][:3] + d["std"][6:], rel=1e-7)
    elif frame["msg"] == "BESTPOS":
        (m,) = log.positions
        assert (m.solution_status, m.position_type) == (d["sol"], d["pos_type"])
        assert (m.latitude_deg, m.longitude_deg, m.height_msl_m) == (d["lat"], d["lon"], d["h_msl"])
        assert m.undulation_m == d["undulation"] and m.datum == "WGS84"
        assert [m.latitude_std_m, m.longitude_std_m, m.height_std_m] == pytest.approx(d["sd"], rel=1e-7)
    elif frame["msg"] == "INSSTDEV":
        (m,) = log.std_devs
        values = [
            m.latitude_std_m,
            m.longitude_std_m,
            m.height_std_m,
            m.north_velocity_std_mps,
            m.east_velocity_std_mps,
            m.up_velocity_std_mps,
            m.roll_std_deg,
            m.pitch_std_deg,
            m.azimuth_std_deg,
        ]
        assert values == pytest.approx(d["std"], rel=1e-7)
        assert m.extended_status == int(d["ext"], 16) and m.time_since_update_s == d["tsu"]
    else:  # CORRIMUS / IMURATECORRIMUS: CRC-valid, counted, not decoded
        assert not log.stats.decoded and sum(log.stats.ignored.values()) == 1


STREAM_COUNTS = {
    # SOURCES.md: message counts of the ProPak6 SPAN TCP captures and the OEM7 desk tests
    SPAN_STREAMS / "propak6-ins-ppp.receiver_stream.bin.gz": {"INSPVAX": 2289, "BESTPOS": 2288},
    SPAN_STREAMS / "propak6-span-fix.receiver_stream.bin.gz": {"INSPVAX": 1064},
    SPAN_STREAMS / "propak6-sbas-fix.receiver_stream.bin.gz": {"INSPVAX": 1280, "BESTPOS": 1280},
    SPAN_STREAMS / "propak6-basic-fix.receiver_stream.bin.gz": {"INSPVAX": 1988, "BESTPOS": 2187},
    OEM7 / "ins2.gps": {"INSPVAX": 6, "INSPVAS": 62},
    OEM7 / "891651d" / "ins2.gps": {"INSPVAX": 48, "INSPVAS": 48},
    OEM7 / "ins1.gps": {"INSPVAS": 243, "INSSTDEV": 29},
    OEM7 / "bestpos.gps": {"BESTPOS": 5, "INSPVAX": 2, "INSPVAS": 10},
    REAL / "novatel_gps_driver" / "derived" / "corrimudata.receiver_stream.bin": {"INSPVAX": 28, "BESTPOS": 28},
    REAL / "novatel_gps_driver" / "derived" / "gpgga-gprmc-bestpos.udp_payload.txt": {"BESTPOS": 40},
}


@pytest.mark.parametrize("path", list(STREAM_COUNTS), ids=lambda p: p.name)
def test_streams_decode_every_message(path):
    log = read_span_log(path)
    assert dict(log.stats.decoded) == STREAM_COUNTS[path]
    assert log.stats.bad_crc == 0 and log.stats.bad_format == 0 and log.stats.truncated == 0


def test_ascii_and_nmea_mix_keeps_only_novatel_logs():
    log = read_span_log(REAL / "novatel_gps_driver" / "derived" / "gpgga-gprmc-bestpos.udp_payload.txt")
    assert dict(log.stats.ignored) == {"TIME": 2}
    assert log.stats.other_bytes > 0  # the $GPGGA / $GPRMC sentences
    assert all(p.gps_week == 1957 and p.position_type is PositionType.SINGLE for p in log.positions)


def test_inspvax_height_plus_undulation_equals_inspvas_height_same_epoch():
    log = read_span_log(OEM7 / "891651d" / "ins2.gps")
    inspvas = {(m.gps_week, round(m.gps_seconds, 3)): m for m in log.ins if m.log == "INSPVAS"}
    inspvax = {(m.gps_week, round(m.gps_seconds, 3)): m for m in log.ins if m.log == "INSPVAX"}
    common = sorted(set(inspvas) & set(inspvax))
    assert len(common) >= 40
    for key in common:
        x, s = inspvax[key], inspvas[key]
        assert x.height_msl_m == pytest.approx(1096.7, abs=0.2)  # MSL, as printed
        assert x.height_ellipsoid_m == pytest.approx(s.height_ellipsoid_m, abs=1e-3)
        assert x.latitude_deg == pytest.approx(s.latitude_deg, abs=1e-9)


def test_oem7_reference_heights_documented_in_sources():
    log = read_span_log(OEM7 / "ins2.gps")
    inspvas = [m for m in log.ins if m.log == "INSPVAS" and m.gps_seconds == pytest.approx(600118.4)]
    inspvax = [m for m in log.ins if m.log == "INSPVAX" and m.gps_seconds == pytest.approx(600119.0)]
    assert inspvas[0].height_ellipsoid_m == pytest.approx(1080.7653, abs=1e-4)
    assert inspvax[0].height_ellipsoid_m == pytest.approx(1080.7656, abs=1e-4)


def test_excerpt_capture_matches_the_long_capture():
    # corrimudata.pcap is the first 1.4 s of propak6-ins-ppp: the decoded INSPVAX must be identical
    short = read_span_log(REAL / "novatel_gps_driver" / "derived" / "corrimudata.receiver_stream.bin")
    long = read_span_log(SPAN_STREAMS / "propak6-ins-ppp.receiver_stream.bin.gz")
    first = {(m.gps_week, m.gps_seconds): m for m in long.ins}
    matched = [first[(m.gps_week, m.gps_seconds)] == m for m in short.ins if (m.gps_week, m.gps_seconds) in first]
    assert len(matched) == 28 and all(matched)


def test_resynchronises_in_a_corrupted_stream():
    data = gzip.decompress((SPAN_STREAMS / "propak6-sbas-fix.receiver_stream.bin.gz").read_bytes())
    data = data[: data.find(b"\xaa\x44\x12", 60000)]  # ends at a frame boundary
    clean = parse_span_bytes(data)
    assert clean.stats.truncated == 0 and clean.stats.bad_crc == 0
    n_clean = sum(clean.stats.decoded.values()) + sum(clean.stats.ignored.values())
    rng = np.random.default_rng(7)
    sync = data.find(b"\xaa\x44\x12", 5000)
    frame_length = data[sync + 3] + int.from_bytes(data[sync + 8 : sync + 10], "little") + 4
    corrupted = bytearray(data[:sync])
    corrupted += rng.integers(0, 256, 333, dtype=np.uint8).tobytes()  # noise
    corrupted += b"\xaa\x44\x12\x1c" + b"\x00" * 40  # a false sync
    corrupted += b"#INSPVAXA,junk\x00\x01"  # a text fragment inside binary noise
    broken = bytearray(data[sync : sync + frame_length])
    broken[40] ^= 0xFF  # one corrupted frame
    corrupted += broken
    corrupted += data[sync + frame_length : -30]  # and a truncated last frame
    log = parse_span_bytes(bytes(corrupted))
    # every message but the corrupted one and the cut-off last one is recovered
    assert sum(log.stats.decoded.values()) + sum(log.stats.ignored.values()) == n_clean - 2
    assert log.stats.bad_crc >= 2  # the false sync and the corrupted frame
    assert log.stats.truncated == 1


def test_ascii_bad_lines_are_skipped_and_counted(tmp_path):
    good = (ASCII / "INSPVAXA.txt").read_bytes().splitlines()[0]
    payload = good[1 : good.rindex(b"*")]
    fields = payload.split(b";")[1].split(b",")
    short_body = b"#" + payload.split(b";")[0] + b";" + b",".join(fields[:-1])
    short_line = short_body + b"*" + f"{novatel_crc32(short_body[1:]):08x}".encode()
    bad_value = payload.replace(b"INS_SOLUTION_GOOD", b"INS_SOLUTION_GREAT")
    bad_value_line = b"#" + bad_value + b"*" + f"{novatel_crc32(bad_value):08x}".encode()
    flipped = good.replace(b"51.15", b"51.16")
    text = b"\r\n".join([good, short_line, bad_value_line, flipped, b"$GPGGA,1,2,3*00", good, good[:90]])
    path = tmp_path / "log.txt"
    path.write_bytes(text)
    log = read_span_log(path)
    assert len(log.ins) == 2
    assert (log.stats.bad_format, log.stats.bad_crc, log.stats.truncated) == (2, 1, 1)
    assert log.stats.problems[0].startswith("line 2: INSPVAXA: 22 body fields, expected 23")
    assert log.stats.problems[1].startswith("line 3:") and "INS_SOLUTION_GREAT" in log.stats.problems[1]
    assert log.stats.problems[2].startswith("line 4: CRC mismatch")
    assert "truncated last line" in log.stats.problems[3]


def test_real_span_stream_reference_is_consistent():
    log = read_span_log(SPAN_STREAMS / "propak6-ins-ppp.receiver_stream.bin.gz")
    ref = span_reference(log)
    assert len(ref) == 2289 and ref.source_log == "INSPVAX"
    assert set(ref.position_type.tolist()) == {int(PositionType.INS_PPP)}
    # velocity from ENU positions and stamps agrees with the logged velocities (independent fields)
    dt = np.diff(ref.stamps_ns) / 1e9
    velocity = np.diff(ref.T_enu_imu[:, :3, 3], axis=0) / dt[:, None]
    logged = np.array([[m.east_velocity_mps, m.north_velocity_mps, m.up_velocity_mps] for m in log.ins])
    mid = 0.5 * (logged[1:] + logged[:-1])
    assert np.median(np.linalg.norm(velocity - mid, axis=1)) < 0.03
    # the vehicle's forward (y) axis points along the horizontal velocity while it moves
    forward = ref.T_enu_imu[1:, :2, 1]
    speed = np.linalg.norm(mid[:, :2], axis=1)
    moving = speed > 0.5
    cos = np.sum(forward[moving] * mid[moving, :2], axis=1) / (np.linalg.norm(forward[moving], axis=1) * speed[moving])
    assert moving.sum() > 200 and np.median(cos) > 0.98


def test_ins_never_aligned_in_real_stream():
    log = read_span_log(SPAN_STREAMS / "propak6-basic-fix.receiver_stream.bin.gz")
    with pytest.raises(GnssError, match=r"never reached an accepted status .*INS_ALIGNING x1988"):
        span_reference(log)


def test_insstdev_fills_inspvas_standard_deviations():
    config = GnssConfig(accepted_ins_statuses=("INS_ALIGNMENT_COMPLETE", "INS_SOLUTION_GOOD"))
    ref = span_reference(read_span_log(OEM7 / "ins1.gps"), config)
    assert ref.source_log == "INSPVA/INSPVAS"
    assert np.isfinite(ref.std_enu_m).all()
    assert ref.std_enu_m[0] == pytest.approx([2.2953, 2.2995, 2.2703], abs=1e-3)  # lon, lat, hgt sigma
