"""PointCloud2 encoding and decoding: the velodyne layout byte for byte, field variants, bad clouds."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from synthetic_sweep import synthetic_sweep

from lidar3d.errors import PointCloudError
from lidar3d.io.pointcloud2 import (
    VELODYNE_FIELDS,
    PointCloud2Parts,
    PointField,
    PointFieldType,
    decode_parts,
    encode_scan,
    time_from_azimuth,
)
from lidar3d.io.scan_decoder import ScanDecoder
from lidar3d.records import Scan
from lidar3d.sensors import VLP16, VLP32C

STAMP_NS = 1_700_000_000_123_456_789


def vlp_scan(sensor=VLP16, n_columns=90, stamp_ns=STAMP_NS, seed=0) -> Scan:
    """A sweep consistent with ``sensor``: beams on its elevation table, time growing with the
    clockwise azimuth from the first point (so ring-less and time-less decoding can recover both)."""
    return synthetic_sweep(n_columns, stamp_ns, sensor=sensor, seed=seed, azimuth_offset=0.5)


def f32(values: np.ndarray) -> np.ndarray:
    return np.asarray(values, dtype=np.float32).astype(np.float64)


def build_parts(
    scan: Scan,
    fields: list[tuple[str, int, str]],
    point_step: int,
    *,
    bigendian=False,
    height=1,
    row_pad=0,
    values=None,
) -> PointCloud2Parts:
    """Pack ``scan`` into an arbitrary layout: fields as (name, offset, numpy type code)."""
    order = ">" if bigendian else "<"
    dtype = np.dtype(
        {
            "names": [f[0] for f in fields],
            "formats": [order + f[2] for f in fields],
            "offsets": [f[1] for f in fields],
            "itemsize": point_step,
        }
    )
    n = len(scan)
    records = np.zeros(n, dtype=dtype)
    defaults = {
        "x": scan.points[:, 0],
        "y": scan.points[:, 1],
        "z": scan.points[:, 2],
        "intensity": scan.intensity,
        "ring": scan.ring,
        "time": scan.time_offset_s,
    }
    defaults.update(values or {})
    for name, _offset, _code in fields:
        records[name] = defaults[name]
    codes = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}
    assert n % height == 0
    width = n // height
    rows = records.view(np.uint8).reshape(height, width * point_step)
    if row_pad:
        rows = np.concatenate([rows, np.full((height, row_pad), 0xAB, np.uint8)], axis=1)
    return PointCloud2Parts(
        stamp_ns=scan.stamp_ns,
        frame_id="lidar",
        height=height,
        width=width,
        fields=tuple(PointField(name, offset, codes[code]) for name, offset, code in fields),
        is_bigendian=bigendian,
        point_step=point_step,
        row_step=width * point_step + row_pad,
        data=rows.reshape(-1).copy(),
        is_dense=True,
    )


def test_encode_is_exactly_the_velodyne_layout():
    scan = vlp_scan(n_columns=4)
    parts = encode_scan(scan, frame_id="velodyne")
    assert [(f.name, f.offset, f.datatype, f.count) for f in parts.fields] == [
        ("x", 0, 7, 1),
        ("y", 4, 7, 1),
        ("z", 8, 7, 1),
        ("intensity", 16, 7, 1),
        ("ring", 20, 4, 1),
        ("time", 24, 7, 1),
    ]
    assert (parts.point_step, parts.height, parts.width, parts.is_dense, parts.is_bigendian) == (
        32,
        1,
        len(scan),
        True,
        False,
    )
    assert parts.row_step == 32 * len(scan) and parts.data.size == 32 * len(scan)
    raw = parts.data.tobytes()
    i = 5  # check one point's bytes by hand
    point = raw[32 * i : 32 * (i + 1)]
    assert np.frombuffer(point[0:12], "<f4").tolist() == scan.points[i].astype(np.float32).tolist()
    assert point[12:16] == b"\x00" * 4 and point[28:32] == b"\x00" * 4
    assert np.frombuffer(point[16:20], "<f4")[0] == scan.intensity[i]
    assert np.frombuffer(point[20:22], "<u2")[0] == scan.ring[i]
    assert np.frombuffer(point[24:28], "<f4")[0] == np.float32(scan.time_offset_s[i])
    assert parts.stamp_ns == scan.stamp_ns and parts.frame_id == "velodyne"


def assert_scan_equal(decoded: Scan, scan: Scan, *, time_atol=0.0) -> None:
    assert decoded.stamp_ns == scan.stamp_ns
    np.testing.assert_array_equal(decoded.points, f32(scan.points))
    np.testing.assert_array_equal(decoded.intensity, scan.intensity.astype(np.float32))
    np.testing.assert_array_equal(decoded.ring, scan.ring)
    if time_atol:
        np.testing.assert_allclose(decoded.time_offset_s, scan.time_offset_s, rtol=0, atol=time_atol)
    else:
        np.testing.assert_array_equal(decoded.time_offset_s, f32(scan.time_offset_s))


def test_velodyne_round_trip_is_exact():
    scan = vlp_scan()
    decoded, stats = decode_parts(encode_scan(scan))
    assert_scan_equal(decoded, scan)
    assert (stats.n_input, stats.n_below_min_range, stats.n_kept) == (len(scan), 0, len(scan))


OUSTER = [
    ("x", 0, "f4"),
    ("y", 4, "f4"),
    ("z", 8, "f4"),
    ("intensity", 16, "f4"),
    ("t", 20, "u4"),
    ("reflectivity", 24, "u2"),
    ("ring", 26, "u2"),
    ("ambient", 28, "u2"),
    ("range", 32, "u4"),
]
HESAI = [
    ("x", 0, "f4"),
    ("y", 4, "f4"),
    ("z", 8, "f4"),
    ("intensity", 12, "f4"),
    ("timestamp", 16, "f8"),
    ("ring", 24, "u2"),
]


def test_ouster_t_uint32_nanoseconds():
    scan = vlp_scan()
    t_ns = np.round(scan.time_offset_s * 1e9).astype(np.uint32)
    parts = build_parts(scan, OUSTER, 48, values={"t": t_ns, "reflectivity": 7, "ambient": 9, "range": 1})
    decoded, _ = decode_parts(parts)
    assert_scan_equal(decoded, scan, time_atol=1e-9)


def test_timestamp_float64_absolute_seconds():
    scan = vlp_scan()
    absolute = STAMP_NS * 1e-9 + scan.time_offset_s
    decoded, _ = decode_parts(build_parts(scan, HESAI, 32, values={"timestamp": absolute}))
    # float64 epoch seconds resolve about 0.24 us near 1.7e9 s
    assert_scan_equal(decoded, scan, time_atol=1e-6)


@pytest.mark.parametrize("sensor", [VLP16, VLP32C], ids=lambda s: s.name)
def test_no_ring_field_ring_from_elevation(sensor):
    scan = vlp_scan(sensor=sensor)
    fields = [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 12, "f4"), ("time", 16, "f4")]
    decoded, _ = decode_parts(build_parts(scan, fields, 20), sensor=sensor)
    assert_scan_equal(decoded, scan)


def test_no_time_field_time_from_azimuth():
    scan = vlp_scan()
    fields = [("x", 0, "f4"), ("y", 4, "f4"), ("z", 8, "f4"), ("intensity", 16, "f4"), ("ring", 20, "u2")]
    decoded, _ = decode_parts(build_parts(scan, fields, 24))
    # the first point sits half a column past 0, so the derived times are column/n_columns * period
    assert_scan_equal(decoded, scan, time_atol=1e-6)


def test_time_from_azimuth_counts_clockwise_from_first_point():
    # 90 degrees clockwise seen from above is the -y axis; a quarter turn is a quarter period.
    points = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    np.testing.assert_allclose(time_from_azimuth(points, 0.1), [0.0, 0.025, 0.05, 0.075], atol=1e-12)


def test_big_endian_and_organised_cloud_with_row_padding():
    scan = vlp_scan(n_columns=30)
    fields = [(f.name, f.offset, {7: "f4", 4: "u2"}[f.datatype]) for f in VELODYNE_FIELDS]
    parts = build_parts(scan, fields, 32, bigendian=True, height=16, row_pad=8)
    decoded, _ = decode_parts(parts)
    assert_scan_equal(decoded, scan)


def test_double_precision_coordinates():
    scan = vlp_scan()
    fields = [
        ("x", 0, "f8"),
        ("y", 8, "f8"),
        ("z", 16, "f8"),
        ("intensity", 24, "u1"),
        ("ring", 25, "u1"),
        ("time", 28, "f4"),
    ]
    decoded, _ = decode_parts(build_parts(scan, fields, 32))
    np.testing.assert_array_equal(decoded.points, scan.points)


def test_nonfinite_and_near_points_are_dropped_and_counted():
    scan = vlp_scan()
    points = scan.points.copy()
    points[3] = [np.nan, 0.0, 0.0]
    points[10] = [np.inf, 1.0, 1.0]
    points[20] = [0.3, 0.2, 0.1]
    dirty = Scan(scan.stamp_ns, points, scan.intensity, scan.ring, scan.time_offset_s)
    decoder = ScanDecoder(VLP16, 1.0, label="test", topic="/points")
    decoded, stats, counts = decoder.decode(encode_scan(dirty))
    assert (stats.n_input, stats.n_below_min_range, stats.n_kept) == (len(scan), 1, len(scan) - 1)
    assert (counts.n_nonfinite, counts.n_absurd_coordinates, counts.n_outlier_times) == (2, 0, 0)
    keep = np.ones(len(scan), bool)
    keep[[3, 10, 20]] = False
    assert_scan_equal(decoded, scan.select(keep))


def test_empty_cloud():
    empty = Scan(STAMP_NS, np.zeros((0, 3)), np.zeros(0), np.zeros(0), np.zeros(0))
    decoded, stats = decode_parts(encode_scan(empty))
    assert len(decoded) == 0 and stats.n_input == 0


def test_data_length_mismatch_is_an_error():
    parts = encode_scan(vlp_scan(n_columns=4))
    short = dataclasses.replace(parts, data=parts.data[:-5])
    with pytest.raises(
        PointCloudError, match=r"data holds 2043 bytes but width\*height\*point_step = 64\*1\*32 = 2048"
    ):
        decode_parts(short)


def test_unsupported_datatype_names_field_and_datatype():
    parts = encode_scan(vlp_scan(n_columns=4))
    fields = tuple(PointField(f.name, f.offset, 11 if f.name == "intensity" else f.datatype) for f in parts.fields)
    with pytest.raises(PointCloudError, match=r"field 'intensity' has unsupported datatype 11"):
        decode_parts(dataclasses.replace(parts, fields=fields))


def test_field_outside_point_step_and_missing_coordinates():
    parts = encode_scan(vlp_scan(n_columns=4))
    moved = tuple(PointField(f.name, 30 if f.name == "time" else f.offset, f.datatype) for f in parts.fields)
    with pytest.raises(PointCloudError, match=r"field 'time' \(FLOAT32 at offset 30\) does not fit in point_step 32"):
        decode_parts(dataclasses.replace(parts, fields=moved))
    no_z = tuple(f for f in parts.fields if f.name != "z")
    with pytest.raises(PointCloudError, match=r"cloud has no z field"):
        decode_parts(dataclasses.replace(parts, fields=no_z))


def test_row_step_smaller_than_a_row_is_an_error():
    scan = vlp_scan(n_columns=4)
    parts = build_parts(
        scan, [(f.name, f.offset, {7: "f4", 4: "u2"}[f.datatype]) for f in VELODYNE_FIELDS], 32, height=16
    )
    with pytest.raises(PointCloudError, match="row_step 100 is smaller than width"):
        decode_parts(dataclasses.replace(parts, row_step=100))


def test_point_field_type_codes_match_ros():
    # 1-8 of every ROS distribution, INT64 = 9 and UINT64 = 10 of ROS 2 Rolling
    assert [t.value for t in PointFieldType] == list(range(1, 11))


def test_ring_table_renumbers_reversed_and_interleaved_but_keeps_near_ascending():
    from lidar3d.io.pointcloud2 import ring_table_from_elevation

    scan = vlp_scan()
    assert ring_table_from_elevation(scan.ring, scan.points, VLP16) is None
    reversed_table = ring_table_from_elevation(15 - scan.ring, scan.points, VLP16)
    np.testing.assert_array_equal(reversed_table[15 - scan.ring], scan.ring)
    # raw VLP-16 laser ids 0, 1, 2, 3, ... point at -15, 1, -13, 3, ... degrees
    interleaved = np.array([0, 2, 4, 6, 8, 10, 12, 14, 1, 3, 5, 7, 9, 11, 13, 15])[scan.ring]
    table = ring_table_from_elevation(interleaved, scan.points, VLP16)
    np.testing.assert_array_equal(table[interleaved], scan.ring)
    # two neighbouring beams swapped (short-range parallax) are not a reason to renumber
    swapped = scan.ring.copy()
    swapped[scan.ring == 7], swapped[scan.ring == 8] = 8, 7
    assert ring_table_from_elevation(swapped, scan.points, VLP16) is None
