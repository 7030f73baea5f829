"""Property-based fuzzing of PointCloud2 decoding and the input sanity stage (issue 21).

Valid clouds (the project's own encoder, and other drivers' layouts) are mutated: header fields
(point_step, width, height, row_step, is_bigendian), field offsets, datatypes and counts, bytes of
the data flipped, data truncated or extended, and bytes of the serialised ROS1 message flipped or
cut. Whatever comes in, decoding either raises a :class:`~lidar3d.errors.Lidar3dError` or returns a
sane scan: finite points within the coordinate limit, finite times within 1.5 sweep periods of the
stamp, no NumPy warning on the way.

The search is derandomised (the same cases on every run). The number of cases per test is 150,
or ``LIDAR3D_FUZZ_EXAMPLES`` when set (``make fuzz``); figures of a large run are in
docs/reliability.md ("PointCloud2 decoding and input sanity").
"""

from __future__ import annotations

import dataclasses
import functools
import os
import re
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from lidar3d.errors import Lidar3dError
from lidar3d.io.bag_inputs import BagFormat
from lidar3d.io.pointcloud2 import PointCloud2Parts, PointField, encode_scan, parts_to_message
from lidar3d.io.scan_decoder import ScanDecoder, deserialize_cloud
from lidar3d.io.scan_sanity import TIME_WINDOW_SWEEPS, coordinate_limit_m
from lidar3d.records import Scan
from lidar3d.sensors import VLP16

settings.register_profile(
    "pointcloud2-fuzz",
    max_examples=int(os.environ.get("LIDAR3D_FUZZ_EXAMPLES", "150")),
    derandomize=True,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
FUZZ = settings(settings.get_profile("pointcloud2-fuzz"))

STAMP_NS = 1_700_000_000_123_456_789
VARIANTS = ("velodyne", "ouster", "hesai", "xyz")
BOUNDARY_VALUES = (0, 1, 2, 3, 4, 7, 8, 16, 31, 32, 33, 48, 64, 2**15, 2**16, 2**31 - 1, 2**31, 2**32 - 1)


def small_sweep(n_columns: int, seed: int) -> Scan:
    rng = np.random.default_rng(seed)
    n = n_columns * VLP16.n_rings
    azimuth = np.repeat(np.arange(n_columns), VLP16.n_rings) * 2.0 * np.pi / n_columns
    ring = np.tile(np.arange(VLP16.n_rings), n_columns)
    range_m = rng.uniform(0.5, 90.0, n)
    elevation = VLP16.elevation_rad[ring]
    points = np.stack(
        [
            range_m * np.cos(elevation) * np.cos(azimuth),
            -range_m * np.cos(elevation) * np.sin(azimuth),
            range_m * np.sin(elevation),
        ],
        axis=1,
    )
    time_s = np.repeat(np.arange(n_columns), VLP16.n_rings) / n_columns * VLP16.sweep_period_s
    return Scan(STAMP_NS, points, rng.uniform(0, 255, n), ring, time_s)


def layout_variant(parts: PointCloud2Parts, variant: str) -> PointCloud2Parts:
    """The velodyne cloud ``parts`` in another driver's layout (same points)."""
    if variant == "velodyne":
        return parts
    n = parts.width
    source = np.frombuffer(
        parts.data.tobytes(),
        dtype=np.dtype(
            {
                "names": ["x", "y", "z", "intensity", "ring", "time"],
                "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4"],
                "offsets": [0, 4, 8, 16, 20, 24],
                "itemsize": 32,
            }
        ),
    )
    if variant == "ouster":  # t uint32 ns, ring counted from the top
        dtype = np.dtype(
            {
                "names": ["x", "y", "z", "intensity", "t", "ring"],
                "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2"],
                "offsets": [0, 4, 8, 16, 20, 26],
                "itemsize": 48,
            }
        )
        records = np.zeros(n, dtype)
        records["t"] = np.round(source["time"].astype(np.float64) * 1e9).astype(np.uint32)
        records["ring"] = VLP16.n_rings - 1 - source["ring"]
        fields = (
            PointField("x", 0, 7),
            PointField("y", 4, 7),
            PointField("z", 8, 7),
            PointField("intensity", 16, 7),
            PointField("t", 20, 6),
            PointField("ring", 26, 4),
        )
    elif variant == "hesai":  # timestamp float64 absolute
        dtype = np.dtype(
            {
                "names": ["x", "y", "z", "intensity", "timestamp", "ring"],
                "formats": ["<f4", "<f4", "<f4", "<f4", "<f8", "<u2"],
                "offsets": [0, 4, 8, 12, 16, 24],
                "itemsize": 32,
            }
        )
        records = np.zeros(n, dtype)
        records["timestamp"] = STAMP_NS * 1e-9 + source["time"].astype(np.float64)
        records["ring"] = source["ring"]
        fields = (
            PointField("x", 0, 7),
            PointField("y", 4, 7),
            PointField("z", 8, 7),
            PointField("intensity", 12, 7),
            PointField("timestamp", 16, 8),
            PointField("ring", 24, 4),
        )
    else:  # "xyz": no ring, no time (both derived)
        dtype = np.dtype({"names": ["x", "y", "z"], "formats": ["<f4"] * 3, "offsets": [0, 4, 8], "itemsize": 16})
        records = np.zeros(n, dtype)
        fields = (PointField("x", 0, 7), PointField("y", 4, 7), PointField("z", 8, 7))
    for axis in ("x", "y", "z", "intensity"):
        if axis in dtype.names:
            records[axis] = source[axis]
    return dataclasses.replace(
        parts,
        fields=fields,
        point_step=dtype.itemsize,
        row_step=dtype.itemsize * n,
        data=records.view(np.uint8).reshape(-1),
    )


@st.composite
def base_clouds(draw) -> PointCloud2Parts:
    scan = small_sweep(draw(st.integers(0, 12)), draw(st.integers(0, 3)))
    parts = encode_scan(scan)
    return layout_variant(parts, draw(st.sampled_from(VARIANTS)))


def header_value(original: int):
    return st.one_of(
        st.sampled_from(BOUNDARY_VALUES),
        st.integers(-8, 8).map(lambda d: max(0, original + d)),
        st.integers(0, 2**32 - 1),
    )


@st.composite
def mutated_parts(draw) -> PointCloud2Parts:
    parts = draw(base_clouds())
    data = bytearray(parts.data.tobytes())
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "flip", "header", "endian", "field", "truncate", "extend", "drop"]))
        if kind == "flip" and data:
            for _ in range(draw(st.integers(1, 8))):
                data[draw(st.integers(0, len(data) - 1))] ^= draw(st.integers(1, 255))
        elif kind == "header":
            name = draw(st.sampled_from(["point_step", "width", "height", "row_step"]))
            parts = dataclasses.replace(parts, **{name: draw(header_value(getattr(parts, name)))})
        elif kind == "endian":
            parts = dataclasses.replace(parts, is_bigendian=not parts.is_bigendian)
        elif kind == "field" and parts.fields:
            index = draw(st.integers(0, len(parts.fields) - 1))
            field = parts.fields[index]
            change = draw(st.sampled_from(["offset", "datatype", "count", "name"]))
            if change == "offset":
                field = dataclasses.replace(field, offset=draw(header_value(field.offset)))
            elif change == "datatype":
                field = dataclasses.replace(field, datatype=draw(st.integers(0, 10)))
            elif change == "count":
                field = dataclasses.replace(field, count=draw(st.sampled_from([0, 2, 3, 2**31])))
            else:
                field = dataclasses.replace(field, name=draw(st.sampled_from(["x", "ring", "time", "t", "timestamp"])))
            parts = dataclasses.replace(parts, fields=(*parts.fields[:index], field, *parts.fields[index + 1 :]))
        elif kind == "truncate":
            del data[draw(st.integers(0, len(data))) :]
        elif kind == "extend":
            data.extend(bytes(draw(st.integers(1, 64))))
        elif kind == "drop" and parts.fields:
            index = draw(st.integers(0, len(parts.fields) - 1))
            parts = dataclasses.replace(parts, fields=parts.fields[:index] + parts.fields[index + 1 :])
    return dataclasses.replace(parts, data=np.frombuffer(bytes(data), dtype=np.uint8))


def assert_sane_or_own_error(decode) -> None:
    """``decode()`` raises a Lidar3dError, or returns a sane scan; any NumPy warning fails."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            scan, stats, counts = decode()
        except Lidar3dError as err:
            event(f"{type(err).__name__}: {re.sub(r'[0-9]+', 'N', str(err))[:60]}")
            return
    event("scan with points dropped by the sanity stage" if counts.n_dropped else "scan, nothing dropped")
    assert len(scan) == stats.n_kept - counts.n_dropped
    assert np.isfinite(scan.points).all()
    assert (np.abs(scan.points) <= coordinate_limit_m(VLP16)).all()
    assert np.isfinite(scan.time_offset_s).all()
    assert (np.abs(scan.time_offset_s) <= TIME_WINDOW_SWEEPS * VLP16.sweep_period_s).all()
    assert scan.ring.dtype == np.uint16 and scan.intensity.dtype == np.float32


def new_decoder() -> ScanDecoder:
    return ScanDecoder(VLP16, 1.0, label="fuzz.bag", topic="/velodyne_points")


@FUZZ
@given(parts=mutated_parts())
def test_mutated_clouds_decode_to_sane_scans_or_one_line_errors(parts):
    assert_sane_or_own_error(lambda: new_decoder().decode(parts))


@functools.cache
def serialised_cloud(n_columns: int, seed: int, variant: str) -> bytes:
    store = get_typestore(Stores.ROS1_NOETIC)
    parts = layout_variant(encode_scan(small_sweep(n_columns, seed)), variant)
    return bytes(store.serialize_ros1(parts_to_message(parts, store), "sensor_msgs/msg/PointCloud2"))


@st.composite
def mutated_messages(draw) -> bytes:
    variant = draw(st.sampled_from(VARIANTS))
    raw = bytearray(serialised_cloud(draw(st.integers(0, 12)), draw(st.integers(0, 3)), variant))
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["flip", "flip", "flip_header", "cut"]))
        if not raw:
            break
        if kind == "flip":
            raw[draw(st.integers(0, len(raw) - 1))] ^= draw(st.integers(1, 255))
        elif kind == "flip_header":  # the header, the field list and the shape: the first ~150 bytes
            raw[draw(st.integers(0, min(len(raw), 160) - 1))] ^= draw(st.integers(1, 255))
        else:
            del raw[draw(st.integers(0, len(raw) - 1)) :]
    return bytes(raw)


@FUZZ
@given(raw=mutated_messages())
def test_mutated_serialised_messages_decode_to_sane_scans_or_one_line_errors(raw):
    def decode():
        return new_decoder().decode(deserialize_cloud(BagFormat.ROS1, raw, "fuzz.bag"))

    assert_sane_or_own_error(decode)


@pytest.mark.parametrize("variant", VARIANTS)
def test_unmutated_variants_decode_without_drops(variant):
    parts = layout_variant(encode_scan(small_sweep(12, 0)), variant)
    scan, stats, counts = new_decoder().decode(parts)
    assert counts.n_dropped == 0 and len(scan) == stats.n_kept > 0
