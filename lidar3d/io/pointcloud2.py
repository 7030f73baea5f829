"""``sensor_msgs/PointCloud2`` <-> :class:`~lidar3d.records.Scan`, through NumPy structured dtypes.

Encoding writes exactly the layout of the ROS ``velodyne_pointcloud`` driver (``PointXYZIRT``)::

    field      offset  datatype   meaning
    x, y, z    0,4,8   FLOAT32    metres, lidar frame (4 bytes of padding follow z)
    intensity  16      FLOAT32    0-255
    ring       20      UINT16     laser index, 0 = lowest beam
    time       24      FLOAT32    seconds relative to header.stamp
    point_step 32, height 1, is_dense true, little-endian

Decoding builds a structured dtype from the message's own ``fields`` (honouring ``point_step``,
offsets, ``is_bigendian``, ``height``/``width`` and row padding in ``row_step``) and views the
``data`` buffer through it without copying. The field variants real drivers produce all decode:

* ``time`` float32, seconds relative to the stamp (velodyne_pointcloud), from the sweep start
  (0..T) or to the sweep end (-T..0);
* ``t`` uint32 nanoseconds relative to the stamp (Ouster); any integer time field (``t``,
  ``time_stamp``, ``offset_time``, ``time``) is read as relative nanoseconds;
* absolute times: ``timestamp`` float64 epoch seconds (Hesai, RoboSense), float64 epoch
  nanoseconds (Livox), int64/uint64 epoch nanoseconds (PointField codes 9 and 10 of ROS 2
  Rolling). A time field whose median magnitude exceeds :data:`ABSOLUTE_TIME_THRESHOLD_S`
  (read as seconds for a float field, as nanoseconds for an integer one) is absolute; its unit
  (s, ms, us or ns) is the one that puts the values nearest the header stamp, which is then
  subtracted (the bulk of the points decides, so one damaged time cannot move the others);
* no ring field: the ring is the beam of the sensor's elevation table nearest to each point's
  elevation angle (:meth:`lidar3d.sensors.SensorModel.ring_from_elevation`);
* no usable time field: the time is derived from the azimuth as LeGO-LOAM does (see
  :func:`time_from_azimuth`). That is the case without a time field, with one that holds no
  times (every finite value the same time within the sweep, e.g. all zeros from a driver that
  fills none, or none finite), and with absolute times too coarse to time a sweep (float32 epoch
  seconds resolve 128 s). :class:`TimeSource` in the :class:`DecodeStats` says which case a
  cloud was.

Points closer than ``min_range_m`` are dropped and counted in the returned :class:`DecodeStats`.
Decoding judges no point otherwise: non-finite or absurd coordinates and point times outside the
sweep are left to the sanity stage (:func:`lidar3d.io.scan_sanity.sanitize_scan`), and the
derived rings and times of the other points do not depend on them. The header is checked before
the data is touched: shape, ``point_step``, ``row_step`` and field offsets against each other and
against the data length, so a damaged header is a :class:`~lidar3d.errors.PointCloudError`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum, IntEnum
from typing import Any

import numpy as np

from lidar3d.errors import PointCloudError
from lidar3d.io.scan_sanity import TIME_WINDOW_SWEEPS, plausible_coordinates
from lidar3d.records import Scan
from lidar3d.sensors import VLP16, SensorModel

__all__ = [
    "ABSOLUTE_TIME_THRESHOLD_S",
    "INTENSITY_FIELD_NAMES",
    "MAX_POINT_STEP",
    "POINTCLOUD2_TYPE",
    "RING_FIELD_NAMES",
    "RING_ORDER_MIN_CORRELATION",
    "TIME_FIELD_NAMES",
    "TIME_RESOLUTION_SWEEP_FRACTION",
    "VELODYNE_FIELDS",
    "VELODYNE_POINT_STEP",
    "DecodeStats",
    "PointCloud2Parts",
    "PointField",
    "PointFieldType",
    "TimeSource",
    "decode_parts",
    "encode_fields",
    "encode_scan",
    "parts_from_message",
    "parts_to_message",
    "ring_table_from_elevation",
    "time_from_azimuth",
]

logger = logging.getLogger(__name__)

#: The ROS message type (ROS2 spelling) of everything this module encodes and decodes.
POINTCLOUD2_TYPE = "sensor_msgs/msg/PointCloud2"
#: A time field whose median magnitude is above this many seconds (nanoseconds for an integer field)
#: holds absolute times.
ABSOLUTE_TIME_THRESHOLD_S = 1.0e5
#: Absolute times that resolve no better than this fraction of the sweep period cannot time a sweep.
TIME_RESOLUTION_SWEEP_FRACTION = 0.01
#: The largest ``point_step`` (bytes) a cloud may declare: the largest record NumPy can describe.
MAX_POINT_STEP = 2**31 - 1
_START_TOLERANCE_RAD = 5.0e-4
#: Rank correlation between ring values and their elevations below which rings are renumbered.
RING_ORDER_MIN_CORRELATION = 0.9


class PointFieldType(IntEnum):
    """``sensor_msgs/PointField`` datatype codes (9 and 10: ROS 2 Rolling, ros2/common_interfaces#301)."""

    INT8 = 1
    UINT8 = 2
    INT16 = 3
    UINT16 = 4
    INT32 = 5
    UINT32 = 6
    FLOAT32 = 7
    FLOAT64 = 8
    INT64 = 9
    UINT64 = 10


_NUMPY_TYPE = {
    PointFieldType.INT8: "i1",
    PointFieldType.UINT8: "u1",
    PointFieldType.INT16: "i2",
    PointFieldType.UINT16: "u2",
    PointFieldType.INT32: "i4",
    PointFieldType.UINT32: "u4",
    PointFieldType.FLOAT32: "f4",
    PointFieldType.FLOAT64: "f8",
    PointFieldType.INT64: "i8",
    PointFieldType.UINT64: "u8",
}


@dataclass(frozen=True, slots=True)
class PointField:
    """One ``sensor_msgs/PointField``: ``name`` at byte ``offset`` with ``datatype`` (code 1-8)."""

    name: str
    offset: int
    datatype: int
    count: int = 1


#: The velodyne_pointcloud ``PointXYZIRT`` layout.
VELODYNE_FIELDS: tuple[PointField, ...] = (
    PointField("x", 0, PointFieldType.FLOAT32),
    PointField("y", 4, PointFieldType.FLOAT32),
    PointField("z", 8, PointFieldType.FLOAT32),
    PointField("intensity", 16, PointFieldType.FLOAT32),
    PointField("ring", 20, PointFieldType.UINT16),
    PointField("time", 24, PointFieldType.FLOAT32),
)
VELODYNE_POINT_STEP = 32


@dataclass(frozen=True, slots=True)
class PointCloud2Parts:
    """The contents of a ``sensor_msgs/PointCloud2``, independent of any ROS type system.

    Attributes:
        stamp_ns: header stamp in integer nanoseconds.
        frame_id: header frame.
        height, width: cloud shape (height 1 for unorganised clouds).
        fields: the point fields.
        is_bigendian: byte order of ``data``.
        point_step: bytes per point.
        row_step: bytes per row (>= ``width * point_step``).
        data: (height * row_step,) uint8 buffer.
        is_dense: true when no point is invalid.
    """

    stamp_ns: int
    frame_id: str
    height: int
    width: int
    fields: tuple[PointField, ...]
    is_bigendian: bool
    point_step: int
    row_step: int
    data: np.ndarray
    is_dense: bool


class TimeSource(str, Enum):
    """Where a decoded cloud's per-point times came from.

    ``relative``: the time field, relative to the header stamp. ``absolute``: the time field,
    absolute times made relative to the stamp. The other three derive the times from the azimuth
    (:func:`time_from_azimuth`): ``no_field`` (the cloud has no time field), ``no_spread`` (every
    finite value of the field is the same time within the sweep, or none is finite: a driver that
    fills none), ``coarse_absolute`` (absolute times that resolve no better than
    :data:`TIME_RESOLUTION_SWEEP_FRACTION` of a sweep, e.g. float32 epoch seconds).
    """

    RELATIVE = "relative"
    ABSOLUTE = "absolute"
    NO_FIELD = "no_field"
    NO_SPREAD = "no_spread"
    COARSE_ABSOLUTE = "coarse_absolute"

    @property
    def from_azimuth(self) -> bool:
        """Whether the times were derived from the azimuth."""
        return self not in (TimeSource.RELATIVE, TimeSource.ABSOLUTE)


@dataclass(frozen=True, slots=True)
class DecodeStats:
    """What decoding one cloud kept and dropped (all counts of points), and where its times came from."""

    n_input: int
    n_below_min_range: int
    time_source: TimeSource = TimeSource.RELATIVE

    @property
    def n_kept(self) -> int:
        return self.n_input - self.n_below_min_range


def _velodyne_dtype() -> np.dtype:
    return np.dtype(
        {
            "names": [f.name for f in VELODYNE_FIELDS],
            "formats": ["<" + _NUMPY_TYPE[PointFieldType(f.datatype)] for f in VELODYNE_FIELDS],
            "offsets": [f.offset for f in VELODYNE_FIELDS],
            "itemsize": VELODYNE_POINT_STEP,
        }
    )


_VELODYNE_DTYPE = _velodyne_dtype()


def encode_scan(scan: Scan, *, frame_id: str = "velodyne") -> PointCloud2Parts:
    """Encode ``scan`` in the velodyne_pointcloud layout (see the module docstring).

    Coordinates, intensity and time offsets are stored as float32, so a round trip returns the
    float32-rounded values. Padding bytes are zero.
    """
    n = len(scan)
    records = np.zeros(n, dtype=_VELODYNE_DTYPE)
    records["x"] = scan.points[:, 0]
    records["y"] = scan.points[:, 1]
    records["z"] = scan.points[:, 2]
    records["intensity"] = scan.intensity
    records["ring"] = scan.ring
    records["time"] = scan.time_offset_s
    return PointCloud2Parts(
        stamp_ns=scan.stamp_ns,
        frame_id=frame_id,
        height=1,
        width=n,
        fields=VELODYNE_FIELDS,
        is_bigendian=False,
        point_step=VELODYNE_POINT_STEP,
        row_step=VELODYNE_POINT_STEP * n,
        data=records.view(np.uint8).reshape(-1),
        is_dense=True,
    )


def encode_fields(
    stamp_ns: int, fields: Sequence[tuple[str, str, np.ndarray]], *, frame_id: str = "velodyne"
) -> PointCloud2Parts:
    """A little-endian cloud of any layout: ``fields`` are ``(name, numpy code, (N,) values)`` in
    order, the code one of :data:`_NUMPY_TYPE`'s (``"f4"``, ``"u2"``, ``"u8"``...); each field is
    aligned to its size and the point step to 8 bytes, as drivers lay them out. Used to build the
    layouts of other drivers (no ring, no time, absolute times) in tests and benchmarks."""
    codes = {code: datatype for datatype, code in _NUMPY_TYPE.items()}
    n = len(fields[0][2]) if fields else 0
    offsets, offset = [], 0
    for _name, code, _values in fields:
        size = np.dtype(code).itemsize
        offset = -(-offset // size) * size
        offsets.append(offset)
        offset += size
    step = -(-offset // 8) * 8
    dtype = np.dtype(
        {"names": [f[0] for f in fields], "formats": ["<" + f[1] for f in fields], "offsets": offsets, "itemsize": step}
    )
    records = np.zeros(n, dtype=dtype)
    for name, _code, values in fields:
        records[name] = values
    return PointCloud2Parts(
        stamp_ns=int(stamp_ns),
        frame_id=frame_id,
        height=1,
        width=n,
        fields=tuple(PointField(name, o, codes[code]) for (name, code, _v), o in zip(fields, offsets)),
        is_bigendian=False,
        point_step=step,
        row_step=step * n,
        data=records.view(np.uint8).reshape(-1).copy(),
        is_dense=True,
    )


def parts_to_message(parts: PointCloud2Parts, typestore: Any) -> Any:
    """Build the ``sensor_msgs/msg/PointCloud2`` object of a rosbags ``typestore`` (ROS1 or ROS2)."""
    types = typestore.types
    cloud_type = types[POINTCLOUD2_TYPE]
    field_type = types["sensor_msgs/msg/PointField"]
    header_type = types["std_msgs/msg/Header"]
    time_type = types["builtin_interfaces/msg/Time"]
    sec, nanosec = divmod(int(parts.stamp_ns), 1_000_000_000)
    stamp = time_type(sec=sec, nanosec=nanosec)
    if "seq" in header_type.__dataclass_fields__:
        header = header_type(seq=0, stamp=stamp, frame_id=parts.frame_id)
    else:
        header = header_type(stamp=stamp, frame_id=parts.frame_id)
    return cloud_type(
        header=header,
        height=parts.height,
        width=parts.width,
        fields=[
            field_type(name=f.name, offset=f.offset, datatype=int(f.datatype), count=f.count) for f in parts.fields
        ],
        is_bigendian=parts.is_bigendian,
        point_step=parts.point_step,
        row_step=parts.row_step,
        data=np.ascontiguousarray(parts.data, dtype=np.uint8).reshape(-1),
        is_dense=parts.is_dense,
    )


def parts_from_message(message: Any) -> PointCloud2Parts:
    """The parts of a deserialised rosbags PointCloud2 (ROS1 or ROS2); ``data`` is not copied."""
    stamp = message.header.stamp
    return PointCloud2Parts(
        stamp_ns=int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec),
        frame_id=message.header.frame_id,
        height=int(message.height),
        width=int(message.width),
        fields=tuple(PointField(f.name, int(f.offset), int(f.datatype), int(f.count)) for f in message.fields),
        is_bigendian=bool(message.is_bigendian),
        point_step=int(message.point_step),
        row_step=int(message.row_step),
        data=message.data,
        is_dense=bool(message.is_dense),
    )


#: Field names recognised for each role, in order of preference.
RING_FIELD_NAMES = ("ring", "channel", "laser_id", "line")
TIME_FIELD_NAMES = ("time", "t", "timestamp", "time_stamp", "offset_time", "time_offset")
INTENSITY_FIELD_NAMES = ("intensity", "reflectivity", "i")


def _structured_dtype(parts: PointCloud2Parts, wanted: dict[str, PointField]) -> np.dtype:
    order = ">" if parts.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for role, field in wanted.items():
        try:
            code = PointFieldType(field.datatype)
        except ValueError:
            raise PointCloudError(
                f"field {field.name!r} has unsupported datatype {field.datatype} "
                f"(supported PointField codes: {', '.join(f'{t.value}={t.name}' for t in PointFieldType)})"
            ) from None
        size = np.dtype(_NUMPY_TYPE[code]).itemsize
        if field.offset < 0 or field.offset + size > parts.point_step:
            raise PointCloudError(
                f"field {field.name!r} ({code.name} at offset {field.offset}) does not fit in "
                f"point_step {parts.point_step}"
            )
        if field.count != 1:
            raise PointCloudError(f"field {field.name!r} has count {field.count}; only scalar fields are supported")
        names.append(role)
        formats.append(order + _NUMPY_TYPE[code])
        offsets.append(field.offset)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": parts.point_step})


def _data_bytes(parts: PointCloud2Parts) -> np.ndarray:
    data = np.asarray(parts.data)
    if data.dtype != np.uint8:
        data = data.view(np.uint8)
    return data.reshape(-1)


def _check_header(parts: PointCloud2Parts, n_bytes: int) -> None:
    """Raise unless height, width, point_step and row_step agree with each other and with the
    ``n_bytes`` of data (see :func:`_point_records` for the layouts accepted)."""
    height, width, step, row_step = parts.height, parts.width, parts.point_step, parts.row_step
    if height < 0 or width < 0 or step < 0 or row_step < 0 or (step == 0 and height * width > 0):
        raise PointCloudError(
            f"bad cloud shape: height {height}, width {width}, point_step {step}, row_step {row_step}"
        )
    if step > MAX_POINT_STEP:
        raise PointCloudError(f"point_step {step} is larger than any point record ({MAX_POINT_STEP} bytes)")
    expected = height * width * step
    if height <= 1 or row_step == width * step:
        if n_bytes != expected and not (height == 1 and n_bytes == row_step and row_step >= expected):
            raise PointCloudError(
                f"data holds {n_bytes} bytes but width*height*point_step = {width}*{height}*{step} = {expected}"
            )
        return
    if row_step < width * step:
        raise PointCloudError(f"row_step {row_step} is smaller than width*point_step = {width * step}")
    if n_bytes != row_step * height:
        raise PointCloudError(
            f"data holds {n_bytes} bytes but height*row_step = {height}*{row_step} = {row_step * height}"
        )


def _point_records(parts: PointCloud2Parts, data: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """A structured (height*width,) view of ``data`` (checked by :func:`_check_header`).

    Dense rows, or a single row (where padding at its end is harmless), are viewed without a copy;
    padded rows (``row_step`` > ``width * point_step``) are de-padded.
    """
    height, width, step = parts.height, parts.width, parts.point_step
    if height <= 1 or parts.row_step == width * step:
        return np.frombuffer(data, dtype=dtype, count=height * width)
    rows = data.reshape(height, parts.row_step)[:, : width * step]
    return np.ascontiguousarray(rows).reshape(-1).view(dtype)


def time_from_azimuth(points: np.ndarray, sweep_period_s: float, start_index: int = 0) -> np.ndarray:
    """Per-point time offsets (s) from the azimuth, for clouds without a time field.

    Follows LeGO-LOAM (``imageProjection.cpp`` ``findStartEndAngle`` and
    ``featureAssociation.cpp`` ``adjustDistortion``, commit 896a7a95): a Velodyne turns clockwise
    seen from above, so the clockwise azimuth ``-atan2(y, x)`` grows with time. The azimuth of
    point ``start_index`` (the first point, or the first with plausible coordinates) marks the sweep
    start; a point's time is its clockwise angle past the start over a full turn, times the sweep
    period: ``t = ((ori - ori_start) mod 2 pi) / (2 pi) * period``. The
    modulo replaces LeGO-LOAM's sequential ``halfPassed`` unwrapping, which needs points in firing
    order; it differs only for points that overlap the sweep start, which get times near 0 instead
    of near the period. Angles within :data:`_START_TOLERANCE_RAD` (0.03 deg, well under one
    0.2-deg column) short of a full turn count as the start: coordinate rounding puts points of the
    first firing column on either side of it.
    """
    if points.shape[0] == 0:
        return np.zeros(0, dtype=np.float64)
    orientation = -np.arctan2(points[:, 1], points[:, 0])
    turned = np.mod(orientation - orientation[start_index], 2.0 * np.pi)
    # Points a hair counter-clockwise of the first (same firing column, rounding) belong to the
    # start of the sweep, not its end.
    turned[turned > 2.0 * np.pi - _START_TOLERANCE_RAD] = 0.0
    return turned * (sweep_period_s / (2.0 * np.pi))


def ring_table_from_elevation(ring: np.ndarray, points: np.ndarray, sensor: SensorModel) -> np.ndarray | None:
    """A lookup table renumbering a driver's ring values so that 0 is the lowest beam, or None.

    ``velodyne_pointcloud`` numbers rings from the lowest beam up, as :class:`Scan` does; Ouster
    counts from the top beam down, and some drivers use raw laser ids (interleaved elevations).
    The median elevation of each ring value's points is compared with the value: when their rank
    correlation is below :data:`RING_ORDER_MIN_CORRELATION` the numbering is not ascending, and
    each value is mapped to the sensor's beam nearest to its median elevation. A high correlation
    with a few neighbours swapped is kept as it is: at short range the beams' vertical offsets move
    closely spaced beams (VLP-32C: 0.33 deg apart) past each other in elevation seen from the
    origin, which is no reason to renumber. None when nothing needs to change.
    """
    values, inverse = np.unique(ring, return_inverse=True)
    if values.size < 3:
        return None
    elevation = np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1]))
    medians = np.array([np.median(elevation[inverse == i]) for i in range(values.size)])
    if np.all(np.diff(medians) > 0):
        return None
    ranks = np.argsort(np.argsort(medians, kind="stable"), kind="stable").astype(np.float64)
    correlation = float(np.corrcoef(np.arange(values.size, dtype=np.float64), ranks)[0, 1])
    if correlation >= RING_ORDER_MIN_CORRELATION:
        return None
    table = np.arange(int(values.max()) + 1, dtype=np.uint16)
    table[values] = sensor.ring_from_elevation(medians)
    return table


def _pick(fields: dict[str, PointField], names: tuple[str, ...]) -> PointField | None:
    for name in names:
        if name in fields:
            return fields[name]
    return None


def decode_parts(
    parts: PointCloud2Parts,
    *,
    sensor: SensorModel = VLP16,
    min_range_m: float = 0.0,
    ring_table: np.ndarray | None = None,
    azimuth_stamp_at_end: bool = False,
) -> tuple[Scan, DecodeStats]:
    """Decode PointCloud2 parts into a :class:`Scan` and the :class:`DecodeStats` of what was dropped.

    Args:
        parts: the cloud (see :func:`parts_from_message`).
        sensor: used only when the cloud lacks a ring field (ring from elevation) or a time field
            (time from azimuth and the sensor's rotation period).
        min_range_m: points nearer than this to the origin are dropped (LeGO-LOAM drops them too).
        ring_table: renumbering of the ring field's values (see :func:`ring_table_from_elevation`);
            None keeps them.
        azimuth_stamp_at_end: for times derived from the azimuth: the stamp marks the sweep's last
            firing (times -T..0: each azimuth time minus ``(n_columns - 1) / n_columns`` of the
            period), not its first (times 0..T).

    Raises:
        PointCloudError: missing x/y/z, a data length that disagrees with the shape, a field with
            an unsupported datatype or one that does not fit in ``point_step``.
    """
    by_name = {f.name: f for f in parts.fields}
    missing = [axis for axis in ("x", "y", "z") if axis not in by_name]
    if missing:
        raise PointCloudError(f"cloud has no {'/'.join(missing)} field (fields: {', '.join(by_name) or 'none'})")
    wanted: dict[str, PointField] = {axis: by_name[axis] for axis in ("x", "y", "z")}
    roles = {"intensity": INTENSITY_FIELD_NAMES, "ring": RING_FIELD_NAMES, "time": TIME_FIELD_NAMES}
    for role, names in roles.items():
        field = _pick(by_name, names)
        if field is not None:
            wanted[role] = field
    data = _data_bytes(parts)
    _check_header(parts, data.size)
    records = _point_records(parts, data, _structured_dtype(parts, wanted))

    n_input = records.shape[0]
    # Damaged points (signalling NaN, 1e300) make no warnings here: the sanity stage drops and counts them.
    with np.errstate(over="ignore", invalid="ignore"):
        points = np.empty((n_input, 3), dtype=np.float64)
        points[:, 0] = records["x"]
        points[:, 1] = records["y"]
        points[:, 2] = records["z"]
        range_sq = np.einsum("ij,ij->i", points, points, optimize=False)
        near = range_sq < min_range_m * min_range_m
        n_near = int(np.count_nonzero(near))
        all_kept = n_near == 0
        if not all_kept:
            points = points[~near]

        def column(role: str) -> np.ndarray:
            values = records[role]
            return values if all_kept else values[~near]

        intensity = column("intensity") if "intensity" in wanted else np.zeros(points.shape[0], np.float32)
        if intensity.dtype != np.float32:
            intensity = intensity.astype(np.float32)
        ring = _ring_values(column("ring"), ring_table) if "ring" in wanted else None
        if ring is None:
            elevation = np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1]))
            ring = sensor.ring_from_elevation(elevation)
        time_s: np.ndarray | None = None
        time_source = TimeSource.NO_FIELD
        if "time" in wanted:
            time_s, time_source = _field_times(column("time"), parts.stamp_ns, sensor.sweep_period_s)
        if time_s is None:
            plausible = plausible_coordinates(points, sensor)[1]
            start = int(np.argmax(plausible)) if plausible.any() else 0
            time_s = time_from_azimuth(points, sensor.sweep_period_s, start)
            if azimuth_stamp_at_end:
                time_s -= sensor.sweep_period_s * (sensor.n_columns - 1) / sensor.n_columns

    stats = DecodeStats(n_input=n_input, n_below_min_range=n_near, time_source=time_source)
    if not all_kept:
        logger.debug(
            "cloud at %d ns: dropped %d points nearer than %.2f m of %d", parts.stamp_ns, n_near, min_range_m, n_input
        )
    scan = Scan(stamp_ns=parts.stamp_ns, points=points, intensity=intensity, ring=ring, time_offset_s=time_s)
    return scan, stats


def _ring_values(raw: np.ndarray, ring_table: np.ndarray | None) -> np.ndarray:
    """Ring field values as uint16, renumbered through ``ring_table``; a float value that is no
    ring number (NaN, negative, beyond uint16) becomes 65535, a ring no sensor has."""
    if raw.dtype.kind == "f":
        raw = np.where(np.isfinite(raw) & (raw >= 0) & (raw < 65536), raw, 65535).astype(np.uint16)
    if ring_table is None:
        return raw
    return ring_table[np.minimum(raw.astype(np.intp), ring_table.size - 1)]


def _field_times(raw: np.ndarray, stamp_ns: int, sweep_period_s: float) -> tuple[np.ndarray | None, TimeSource]:
    """Time field values as float64 seconds relative to ``stamp_ns``, and their :class:`TimeSource`;
    None for the times when the field holds none a sweep can be timed with (derive them from the
    azimuth instead).

    Integer fields hold relative nanoseconds, float fields relative seconds, unless the median
    magnitude of their finite values exceeds :data:`ABSOLUTE_TIME_THRESHOLD_S` (in those units):
    then they are absolute (:func:`_absolute_to_relative`). The bulk of the points decides the time
    base for the whole cloud, and the few points that disagree with it end far outside the sweep,
    where the sanity stage drops them. A field whose finite times are all one value within the
    sanity window (all zeros: a driver that fills none), or that holds no finite time, times
    nothing (``no_spread``); one value outside the window is left to the sanity stage.
    """
    time_s = raw.astype(np.float64) if raw.dtype.kind == "f" else raw.astype(np.float64) * 1e-9
    source = TimeSource.RELATIVE
    if time_s.size and _is_absolute(time_s):
        absolute_s, source = _absolute_to_relative(raw, stamp_ns, sweep_period_s)
        if absolute_s is None:
            return None, source
        time_s = absolute_s
    if time_s.size > 1:
        low, high = np.fmin.reduce(time_s), np.fmax.reduce(time_s)  # NaN ignored; NaN only when none is finite
        if np.isnan(low) or (low == high and abs(low) <= TIME_WINDOW_SWEEPS * sweep_period_s):
            return None, TimeSource.NO_SPREAD
    return time_s, source


def _is_absolute(time_s: np.ndarray) -> bool:
    """Whether the median magnitude of the finite ``time_s`` exceeds :data:`ABSOLUTE_TIME_THRESHOLD_S`."""
    magnitude = np.abs(time_s)
    # The largest finite magnitude first (NaN ignored): the median is needed only when some time is large.
    return bool(
        np.fmax.reduce(magnitude) > ABSOLUTE_TIME_THRESHOLD_S
        and np.median(magnitude[np.isfinite(magnitude)]) > ABSOLUTE_TIME_THRESHOLD_S
    )


#: Units (s) absolute times may be counted in: seconds, milliseconds, microseconds, nanoseconds.
_ABSOLUTE_UNITS_S = (1.0, 1e-3, 1e-6, 1e-9)


def _absolute_to_relative(
    raw: np.ndarray, stamp_ns: int, sweep_period_s: float
) -> tuple[np.ndarray | None, TimeSource]:
    """Absolute time field values as seconds relative to ``stamp_ns`` (``absolute``), or None when
    they resolve no better than :data:`TIME_RESOLUTION_SWEEP_FRACTION` of the sweep period
    (``coarse_absolute``).

    The unit is the one of :data:`_ABSOLUTE_UNITS_S` that puts the median value nearest the stamp
    (by ratio); with no positive stamp to compare, seconds for a float field and nanoseconds for
    an integer one. Integer values are made relative in integer nanoseconds (exact).
    """
    values = raw.astype(np.float64)
    median = float(np.median(np.abs(values[np.isfinite(values)])))
    if stamp_ns > 0:
        stamp_s = stamp_ns * 1e-9
        unit_s = min(_ABSOLUTE_UNITS_S, key=lambda unit: abs(np.log10(median * unit / stamp_s)))
    else:
        unit_s = 1.0 if raw.dtype.kind == "f" else 1e-9
    step = float(np.spacing(raw.dtype.type(median))) if raw.dtype.kind == "f" else 1.0
    if step * unit_s > TIME_RESOLUTION_SWEEP_FRACTION * sweep_period_s:
        return None, TimeSource.COARSE_ABSOLUTE
    if raw.dtype.kind != "f":
        ns_per_unit = round(unit_s * 1e9)
        return (raw.astype(np.int64) * ns_per_unit - stamp_ns).astype(np.float64) * 1e-9, TimeSource.ABSOLUTE
    if unit_s == 1.0:
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
        return (values - float(sec)) - nanosec * 1e-9, TimeSource.ABSOLUTE
    return (values - stamp_ns * (1e-9 / unit_s)) * unit_s, TimeSource.ABSOLUTE
