"""NovAtel SPAN ground truth: log readers, GPS time, local ENU, attitude, lidar extrinsic.

Typical use::

    log = read_span_log("span.gps")             # ASCII, binary or raw stream, any mix
    reference = span_reference(log, GnssConfig())  # T_enu_imu at UNIX (bag clock) stamps
"""

from lidar3d.gnss.attitude import R_enu_vehicle_from_span, span_from_R_enu_vehicle
from lidar3d.gnss.crc import novatel_crc32
from lidar3d.gnss.enu import GeodeticOrigin, LocalEnu, R_enu_ecef
from lidar3d.gnss.extrinsic import read_extrinsic, write_extrinsic
from lidar3d.gnss.gps_time import gps_to_unix_ns, unix_ns_to_gps
from lidar3d.gnss.novatel import (
    InsPvaMessage,
    InsStatus,
    InsStdDevMessage,
    LogStats,
    PositionMessage,
    PositionType,
    SolutionStatus,
    SpanLog,
    TimeStatus,
)
from lidar3d.gnss.reader import parse_span_bytes, read_span_log
from lidar3d.gnss.reference import InsReference, span_reference

__all__ = [
    "GeodeticOrigin",
    "InsPvaMessage",
    "InsReference",
    "InsStatus",
    "InsStdDevMessage",
    "LocalEnu",
    "LogStats",
    "PositionMessage",
    "PositionType",
    "R_enu_ecef",
    "R_enu_vehicle_from_span",
    "SolutionStatus",
    "SpanLog",
    "TimeStatus",
    "gps_to_unix_ns",
    "novatel_crc32",
    "parse_span_bytes",
    "read_extrinsic",
    "read_span_log",
    "span_from_R_enu_vehicle",
    "span_reference",
    "unix_ns_to_gps",
    "write_extrinsic",
]
