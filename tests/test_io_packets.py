"""Raw Velodyne packets (pcap files, VelodyneScan bags) through the scan source, on synthetic VLP-16 packets.

Every laser of the synthetic packets (tests/velodyne_synthetic.py) returns a known distance, so the
decoded ranges, rings (by elevation), point times, sweep counts and stamps are known.
"""

from __future__ import annotations

import logging
import re

import numpy as np
import pytest
from velodyne_synthetic import HOUR_NS, T0_NS, vlp16_stream, write_packet_bag, write_pcap

from lidar3d.cli.main import main
from lidar3d.config import Config, config_with
from lidar3d.errors import BagError, PacketError
from lidar3d.io.convert import convert_to_bag
from lidar3d.io.packet_info import packet_info
from lidar3d.io.packet_source import PacketScanSource, input_config
from lidar3d.io.pcap_reader import PcapReader
from lidar3d.io.scan_source import ScanSource, open_scan_source
from lidar3d.io.velodyne_packets import PacketModel, SweepCutter
from lidar3d.sensors import VLP16


def _config(**input_keys) -> Config:
    return config_with(Config(), {"input": input_keys}) if input_keys else Config()


def _scans(path, config=None):
    with open_scan_source(path, config or Config()) as source:
        return source, list(source)


@pytest.fixture(scope="module")
def pcap_35(tmp_path_factory):
    """3.5 turns from azimuth 90 deg: a partial first sweep (270 deg), two full, half a turn unfinished."""
    return write_pcap(tmp_path_factory.mktemp("pcap") / "drive.pcap", vlp16_stream(3.5))


def test_pcap_sweeps_cut_at_the_azimuth_with_known_geometry(pcap_35):
    source, scans = _scans(pcap_35)
    assert isinstance(source, PacketScanSource) and len(source) == 3 and len(scans) == 3
    assert source.sensor.model is PacketModel.VLP16 and source.sensor.detection.how == "factory bytes"
    assert abs(source.sensor.rpm - 600.0) < 1.0
    assert source.unfinished_packets > 30  # the last half turn never finished
    full = scans[1]
    assert len(full) == 16 * 24 * 75  # 75 packets of 12 blocks x 2 firings x 16 lasers
    range_m = np.linalg.norm(full.points, axis=1)
    np.testing.assert_allclose(range_m, 10.0, atol=0.005)
    elevation_deg = np.degrees(np.arcsin(full.points[:, 2] / range_m))
    # ring 0 is the lowest beam: elevations ascend with the ring, 2 deg apart, within the calibration's offsets
    np.testing.assert_allclose(elevation_deg, np.asarray(VLP16.elevation_deg)[full.ring], atol=0.1)
    assert full.time_offset_s.min() == 0.0 and 0.099 < full.time_offset_s.max() < 0.1
    # stamps: the first packet of each sweep; the first sweep starts with the capture
    assert scans[0].stamp_ns == T0_NS
    assert 0.05 < (scans[1].stamp_ns - T0_NS) * 1e-9 < 0.08  # 270 deg at 600 rpm = 0.075 s
    assert (scans[2].stamp_ns - scans[1].stamp_ns) * 1e-9 == pytest.approx(0.1, abs=0.002)


def test_cut_azimuth_moves_the_sweep_boundaries(pcap_35):
    _source, scans = _scans(pcap_35, _config(cut_azimuth_deg=180.0))
    # from 90 deg: cuts at 180, 540, 900, 1260 -> a 90 deg first sweep and 3 full ones (the rest unfinished)
    assert len(scans) == 4
    assert (scans[1].stamp_ns - T0_NS) * 1e-9 == pytest.approx(0.025, abs=0.002)


def test_sweep_cutter_counts_wraps_only():
    cutter = SweepCutter(0.0)
    azimuths = [350.0, 355.0, 359.9, 0.2, 0.2, 5.0, 359.0, 1.0]
    starts = [cutter.starts_sweep(int(a * 100).to_bytes(2, "little") * 2 + bytes(1202)) for a in azimuths]
    assert starts == [True, False, False, True, False, False, False, True]


@pytest.mark.parametrize("storage", ["ros1", "ros2"])
def test_velodyne_scan_bags_give_the_pcap_scans(tmp_path, storage, pcap_35):
    packets = vlp16_stream(3.0, start_deg=0.0)[:225]  # 3 messages of 75 packets
    bag = write_packet_bag(tmp_path / ("p.bag" if storage == "ros1" else "p"), packets, storage=storage)
    source, scans = _scans(bag)
    assert source.topic == "/velodyne_packets" and len(source) == 3 == len(scans)
    assert [s.stamp_ns for s in scans] == [packets[i][0] for i in (0, 75, 150)]
    assert all(len(s) == 28800 for s in scans)
    # the bag's messages are the driver's sweeps; recut_sweeps cuts them at the azimuth instead
    _recut_source, recut = _scans(bag, _config(recut_sweeps=True, cut_azimuth_deg=180.0))
    # cuts at 180, 540 and 900 deg (packets 38, 114, 189); the packets after the last are unfinished
    assert [s.stamp_ns for s in recut] == [packets[i][0] for i in (0, 38, 114)]


def test_dual_return_keeps_the_return_asked_for(tmp_path):
    pcap = write_pcap(tmp_path / "dual.pcap", vlp16_stream(2.2, dual=True))
    ranges = {}
    for keep in ("strongest", "last", "both"):
        source, scans = _scans(pcap, _config(packet_return=keep))
        assert source.sensor.detection.return_mode.value == "dual" and source.sensor.model is PacketModel.VLP16
        ranges[keep] = np.unique(np.round(np.linalg.norm(scans[1].points, axis=1), 2))
    assert ranges["strongest"].tolist() == [10.0] and ranges["last"].tolist() == [12.0]
    assert ranges["both"].tolist() == [10.0, 12.0]


def test_sensor_clock_and_offset_warning(tmp_path, caplog):
    pcap = write_pcap(tmp_path / "late.pcap", vlp16_stream(2.2, sensor_offset_s=12.5))
    with caplog.at_level(logging.WARNING, logger="lidar3d"):
        host_source, host = _scans(pcap)
    assert host_source.sensor.clock_offset_s == pytest.approx(12.5, abs=1e-5)
    assert any("host clock is +12.500 s from the sensor's clock" in r.getMessage() for r in caplog.records)
    _source, sensor = _scans(pcap, _config(packet_clock="sensor"))
    assert [h.stamp_ns - s.stamp_ns for h, s in zip(host, sensor)] == [12_500_000_000] * len(host)
    np.testing.assert_array_equal(host[1].time_offset_s, sensor[1].time_offset_s)


def test_sensor_time_is_placed_in_the_nearest_hour(tmp_path):
    # the host clock is 5 s past the top of an hour, the sensor 3 s before it
    packets = vlp16_stream(1.2, sensor_offset_s=8.0)
    shift = HOUR_NS - T0_NS % HOUR_NS + 5_000_000_000
    pcap = write_pcap(
        tmp_path / "hour.pcap", [(ns + shift, _rewrite_time(p, ns + shift - 8_000_000_000)) for ns, p in packets]
    )
    _source, scans = _scans(pcap, _config(packet_clock="sensor"))
    assert scans[0].stamp_ns == T0_NS + shift - 8_000_000_000


def _rewrite_time(packet: bytes, sensor_ns: int) -> bytes:
    return packet[:1200] + ((sensor_ns % HOUR_NS) // 1000).to_bytes(4, "little") + packet[1204:]


def test_a_faster_turn_sets_the_rate_and_scales_the_columns(tmp_path):
    pcap = write_pcap(tmp_path / "fast.pcap", vlp16_stream(3.5, rpm=900.0))
    config = input_config(pcap, Config())
    assert (config.sensor.model, config.sensor.rotation_override_hz, config.sensor.n_columns_override) == (
        "vlp16",
        15.0,
        1200,  # 1800 columns at 10 Hz: the firing rate is fixed, so 1200 firings per turn at 15 Hz
    )
    kept = input_config(pcap, config_with(Config(), {"sensor": {"n_columns_override": 1000}}))
    assert kept.sensor.n_columns_override == 1000
    assert input_config(write_pcap(tmp_path / "600.pcap", vlp16_stream(2.2)), Config()) == Config()


def test_product_byte_that_disagrees_with_the_firing_pattern_is_warned(tmp_path, caplog):
    pcap = write_pcap(tmp_path / "says_hdl32.pcap", vlp16_stream(2.2, product=0x21))
    with caplog.at_level(logging.WARNING, logger="lidar3d"):
        source, scans = _scans(pcap)
    assert source.sensor.model is PacketModel.VLP16 and source.sensor.detection.how == "firing pattern"
    assert any("product byte says hdl32e (0x21), but packets come every 1327" in r.getMessage() for r in caplog.records)
    assert scans[1].ring.max() == 15
    config = input_config(pcap, Config())
    assert config.sensor.model == "vlp16"


@pytest.mark.parametrize("container", ["pcap", "ros2 bag"])
def test_unknown_model_is_one_line_and_sensor_overrides(tmp_path, container, capsys):
    packets = vlp16_stream(2.2, product=0x99, period_scale=1.5)
    if container == "pcap":
        path = write_pcap(tmp_path / "odd.pcap", packets)
    else:
        path = write_packet_bag(tmp_path / "odd", packets, storage="ros2")
    with pytest.raises(
        PacketError,
        match=r"odd(.pcap)?: unknown Velodyne model: product byte 0x99, return byte 0x37, packets every 1991.0 us "
        r"\(no model fits\); give the model with --sensor \(vlp16, vlp32c, hdl32e\)$",
    ):
        _scans(path)
    source, scans = _scans(path, config_with(Config(), {"input": {"packet_model": "vlp16"}}))
    assert source.sensor.detection.how == "given" and len(scans) >= 1
    assert main(["info", str(path)]) == 1
    assert capsys.readouterr().err.startswith(f"lidar3d info: error: {path}: unknown Velodyne model")


def test_pcap_without_velodyne_data_names_its_ports(tmp_path):
    other = [(T0_NS + i * 10**8, b"$GPRMC,1" + bytes(60), 3001) for i in range(5)]
    pcap = write_pcap(tmp_path / "gnss.pcap", [], extra=other)
    with pytest.raises(
        PacketError,
        match=r"gnss.pcap: no Velodyne data packets \(1206-byte UDP payloads to port 2368\); "
        r"UDP ports found: 3001 \(5 datagrams of 68 bytes\); other ports: input.data_ports or --ports$",
    ):
        _scans(pcap)


def test_other_data_ports(tmp_path):
    pcap = write_pcap(tmp_path / "p2369.pcap", vlp16_stream(2.2), port=2369)
    with pytest.raises(PacketError, match=r"UDP ports found: 2369 \("):
        _scans(pcap)
    _source, scans = _scans(pcap, _config(data_ports=[2369]))
    assert len(scans) == 2


def test_truncated_pcap_keeps_the_complete_sweeps(tmp_path, caplog):
    whole = write_pcap(tmp_path / "whole.pcap", vlp16_stream(3.5))
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(whole.read_bytes()[: whole.stat().st_size - 700])
    with caplog.at_level(logging.WARNING, logger="lidar3d"):
        source, scans = _scans(cut)
    assert len(scans) == 3 and source.stats.n_lost_messages == 1
    assert any(
        re.search(r"cut.pcap: file cut short inside record \d+ \(\d+ of 1264 bytes\): 1 packet lost", r.getMessage())
        for r in caplog.records
    )


def test_pcapng_and_garbage_are_one_line(tmp_path):
    pcapng = tmp_path / "x.pcap"
    pcapng.write_bytes(b"\x0a\x0d\x0d\x0a" + bytes(60))
    with pytest.raises(PacketError, match=r"x.pcap: a pcapng file; only classic pcap is read \(convert it: editcap"):
        _scans(pcapng)
    short = tmp_path / "short.pcap"
    short.write_bytes(b"\xd4\xc3\xb2\xa1" + bytes(8))
    with pytest.raises(PacketError, match=r"short.pcap: not a pcap file \(or cut short inside its 24-byte header\)$"):
        PcapReader(short)


def test_calibration_of_another_laser_count_is_one_line(tmp_path, pcap_35):
    yaml_path = tmp_path / "hdl32.yaml"
    yaml_path.write_text(
        "num_lasers: 32\nlasers:\n" + "".join(f"  - {{laser_id: {i}, vert_correction: 0.0}}\n" for i in range(32))
    )
    with pytest.raises(
        PacketError, match=r"hdl32.yaml: calibration has 32 lasers \(num_lasers 32\), the vlp16 has 16$"
    ):
        _scans(pcap_35, _config(calibration=str(yaml_path)))
    (tmp_path / "bad.yaml").write_text("lasers: [\n")
    with pytest.raises(PacketError, match=r"bad.yaml: calibration is not YAML"):
        _scans(pcap_35, _config(calibration=str(tmp_path / "bad.yaml")))


def test_user_calibration_is_used(tmp_path, pcap_35):
    lasers = "".join(
        f"  - {{laser_id: {i}, rot_correction: 0.0, vert_correction: {np.radians(e + 0.5):.8f}, dist_correction: 0.0,"
        " dist_correction_x: 0.0, dist_correction_y: 0.0, vert_offset_correction: 0.0, horiz_offset_correction: 0.0,"
        " focal_distance: 0.0, focal_slope: 0.0, min_intensity: 0, max_intensity: 255}\n"
        for i, e in enumerate((-15, 1, -13, 3, -11, 5, -9, 7, -7, 9, -5, 11, -3, 13, -1, 15))
    )
    yaml_path = tmp_path / "vlp16_tilted.yaml"
    yaml_path.write_text(f"num_lasers: 16\ndistance_resolution: 0.002\nlasers:\n{lasers}")
    _source, scans = _scans(pcap_35, _config(calibration=str(yaml_path)))
    full = scans[1]
    elevation_deg = np.degrees(np.arcsin(full.points[:, 2] / np.linalg.norm(full.points, axis=1)))
    np.testing.assert_allclose(elevation_deg, np.asarray(VLP16.elevation_deg)[full.ring] + 0.5, atol=0.01)


def test_convert_writes_the_scans_as_velodyne_pointcloud(tmp_path, pcap_35):
    summary = convert_to_bag(pcap_35, tmp_path / "out.bag")
    assert summary.n_scans == 3 and summary.storage == "ros1"
    _source, packets = _scans(pcap_35)
    with ScanSource(tmp_path / "out.bag") as source:
        clouds = list(source)
    assert [c.stamp_ns for c in clouds] == [s.stamp_ns for s in packets]
    np.testing.assert_allclose(clouds[1].points, packets[1].points, atol=1e-5)
    np.testing.assert_array_equal(clouds[1].ring, packets[1].ring)
    np.testing.assert_allclose(clouds[1].time_offset_s, packets[1].time_offset_s, atol=1e-7)


def test_cli_convert_and_info(tmp_path, pcap_35, capsys):
    assert main(["-q", "convert", str(pcap_35), "--out", str(tmp_path / "c"), "--storage", "ros2-mcap"]) == 0
    assert "wrote 3 scans (" in capsys.readouterr().out
    assert main(["info", str(pcap_35)]) == 0
    out = capsys.readouterr().out
    for line in (
        "sensor model: vlp16 (from the factory bytes; product byte: vlp16)",
        "return mode:  strongest",
        "rotation:     600.0 rpm (0.1000 s per sweep)",
        "scans:        3 (",
        "clock:        stamps from the host clock; host - sensor = +0.000 s",
        "position:     no position (NMEA) packets",
        "UDP ports:    2368 (264 x 1206 bytes)",
    ):
        assert line in out, line


def test_cli_info_says_nmea_status(tmp_path, capsys):
    fix = b"$GPRMC,220243,A,3708.5809,N,12139.7813,W,028.8,158.3,111212,013.8,E,D*03\r\n"
    position = bytes(202) + b"\x02" + bytes(3) + fix
    position += bytes(512 - len(position))
    extra = [(T0_NS + i * 10**8, position, 8308) for i in range(3)]
    pcap = write_pcap(tmp_path / "gps.pcap", vlp16_stream(2.2), extra=extra)
    info = packet_info(pcap)
    assert info.n_position == 3 and info.pps == ("locked",)
    assert info.nmea_first.valid and info.nmea_first.utc == "220243"
    assert info.nmea_first.speed_mps == pytest.approx(28.8 * 0.514444)
    assert main(["info", str(pcap), "--sensor", "vlp16"]) == 0
    assert "position:     3 packets, PPS locked; first GPRMC 220243 UTC, valid fix, 14.8 m/s" in capsys.readouterr().out


def test_cli_bad_packet_input_is_one_line(tmp_path, capsys):
    pcap = write_pcap(tmp_path / "empty.pcap", [])
    assert main(["info", str(pcap)]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"lidar3d info: error: {pcap}: no Velodyne data packets (1206-byte UDP payloads to port 2368); "
        "it holds no IPv4/UDP packets; other ports: input.data_ports or --ports"
    ]


def test_unknown_topic_of_a_packet_bag_is_one_line(tmp_path):
    bag = write_packet_bag(tmp_path / "p.bag", vlp16_stream(2.0, start_deg=0.0), storage="ros1")
    assert isinstance(open_scan_source(bag, Config()), PacketScanSource)
    with (
        pytest.raises(
            BagError, match=r"p.bag: topic '/nope' not found; PointCloud2 topics: none; topics: /velodyne_packets"
        ),
        open_scan_source(bag, _config(topic="/nope")),
    ):
        pass


def test_batch_finds_pcap_files_and_their_time_span(tmp_path):
    from lidar3d.batch.discovery import discover_bags
    from lidar3d.batch.span_match import bag_time_range

    packets = vlp16_stream(2.2)
    (tmp_path / "drives").mkdir()
    pcap = write_pcap(tmp_path / "drives" / "a.pcap", packets)
    (found,) = discover_bags([tmp_path / "drives"])
    assert (found.path, found.kind, found.stem) == (pcap, "pcap", "a")
    assert bag_time_range(pcap) == (packets[0][0], packets[-1][0] // 1000 * 1000)  # pcap: microseconds


def test_damaged_record_length_stops_reading_with_a_note(tmp_path, caplog):
    whole = write_pcap(tmp_path / "whole.pcap", vlp16_stream(3.5))
    data = bytearray(whole.read_bytes())
    record = 24 + 200 * (16 + 1248)  # the 201st record's header: declare 4 GiB
    data[record + 8 : record + 12] = (0xFFFFFFFF).to_bytes(4, "little")
    damaged = tmp_path / "damaged.pcap"
    damaged.write_bytes(bytes(data))
    with caplog.at_level(logging.WARNING, logger="lidar3d"):
        _source, scans = _scans(damaged)
    assert len(scans) == 2  # the sweeps finished before record 201
    assert any("record 201 declares an impossible length" in r.getMessage() for r in caplog.records)


def test_pcap_and_bag_together_is_one_line(tmp_path, pcap_35):
    bag = write_packet_bag(tmp_path / "p.bag", vlp16_stream(2.0), storage="ros1")
    with pytest.raises(PacketError, match="pcap files and bags cannot be read as one recording"):
        _scans([pcap_35, bag])


def test_pcap_reader_survives_garbage_frames(tmp_path):
    import struct

    rng = np.random.default_rng(0)
    frames = [bytes(rng.integers(0, 256, size=int(n), dtype=np.uint8)) for n in rng.integers(0, 120, size=300)]
    out = bytearray(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1))
    for index, frame in enumerate(frames):
        out += struct.pack("<IIII", 1_700_000_000, index, len(frame), len(frame)) + frame
    path = tmp_path / "garbage.pcap"
    path.write_bytes(bytes(out))
    with PcapReader(path) as reader:
        datagrams = list(reader)
    assert reader.counts.n_records == 300 and reader.counts.n_udp == len(datagrams)
    with pytest.raises(PacketError, match="no Velodyne data packets"):
        _scans(path)


def test_linux_cooked_capture_is_read(tmp_path):
    import struct

    ethernet = write_pcap(tmp_path / "eth.pcap", vlp16_stream(2.2)).read_bytes()
    out = bytearray(ethernet[:20] + struct.pack("<I", 113))  # LINKTYPE_LINUX_SLL
    offset = 24
    while offset < len(ethernet):
        sec, usec, caplen, _origlen = struct.unpack_from("<IIII", ethernet, offset)
        frame = ethernet[offset + 16 : offset + 16 + caplen]
        cooked = bytes(14) + b"\x08\x00" + frame[14:]  # 16-byte SLL header, protocol IPv4
        out += struct.pack("<IIII", sec, usec, len(cooked), len(cooked)) + cooked
        offset += 16 + caplen
    sll = tmp_path / "sll.pcap"
    sll.write_bytes(bytes(out))
    assert len(_scans(sll)[1]) == len(_scans(tmp_path / "eth.pcap")[1]) == 2
