"""INS solutions of a SPAN log as a reference trajectory in a local ENU frame.

Steps (``shared/reference/gnss-and-metrics.md`` section 3.5):

1. Source: the INS pose log with the most solutions (INSPVA and INSPVAS count together; a tie goes
   to INSPVAX, which carries standard deviations). Heights are ellipsoidal (INSPVAX: H + N).
2. Quality: keep solutions whose INS status is accepted (default INS_SOLUTION_GOOD only) and,
   by default, whose long-header time status is at least FINE; week 0 means no time and is dropped.
3. Time: GPS week/seconds to UNIX ns with the configured leap seconds, plus the bag clock offset.
4. Geometry: positions to ENU at the origin (given, or the first kept solution); attitude
   ``R_enu_vehicle = Rz(-azimuth) Rx(pitch) Ry(roll)`` (:mod:`lidar3d.gnss.attitude`) is relative to
   the local level at each solution, so it is rotated into the origin's ENU frame.

The result holds ``T_enu_imu``; the lidar pose is ``T_enu_lidar = T_enu_imu . T_imu_lidar``.
"""

from __future__ import annotations

import collections
import logging
from dataclasses import dataclass

import numpy as np

from lidar3d.config import GnssConfig
from lidar3d.errors import GnssError
from lidar3d.gnss.attitude import R_enu_vehicle_from_span
from lidar3d.gnss.enu import GeodeticOrigin, LocalEnu, geodetic_problem
from lidar3d.gnss.gps_time import gps_to_unix_ns
from lidar3d.gnss.novatel import (
    InsPvaMessage,
    InsStatus,
    SpanLog,
    TimeStatus,
    enum_from_name,
)
from lidar3d.records import Trajectory

__all__ = ["InsReference", "accepted_statuses", "origin_from_config", "span_reference"]

logger = logging.getLogger(__name__)

_NEAREST_POSITION_S = 0.5  # BESTPOS quality is attached to INS solutions this close in time
_NEAREST_STD_S = 1.5  # INSSTDEV (1 Hz) standard deviations likewise


@dataclass(frozen=True, slots=True)
class InsReference:
    """Reference poses of the IMU (SPAN vehicle frame: x right, y forward, z up) in local ENU.

    Attributes:
        stamps_ns: (N,) int64 strictly increasing, bag clock (UNIX ns + time offset).
        T_enu_imu: (N, 4, 4) float64 poses of the IMU in the ENU frame at ``origin``.
        origin: the ENU origin.
        ins_status: (N,) int16 INS status codes (:class:`~lidar3d.gnss.novatel.InsStatus`).
        position_type: (N,) int16 position type codes, -1 where unknown.
        std_enu_m: (N, 3) float64 position standard deviations (east, north, up), NaN where unknown.
        source_log: the log the poses came from ("INSPVAX", "INSPVA/INSPVAS").
        n_solutions: INS solutions of that log in the file; ``len(self)`` of them were kept.
    """

    stamps_ns: np.ndarray
    T_enu_imu: np.ndarray
    origin: GeodeticOrigin
    ins_status: np.ndarray
    position_type: np.ndarray
    std_enu_m: np.ndarray
    source_log: str
    n_solutions: int

    def __post_init__(self) -> None:
        trajectory = Trajectory(self.stamps_ns, self.T_enu_imu)  # validates shapes and ordering
        n = len(trajectory)
        ins_status = np.asarray(self.ins_status, dtype=np.int16)
        position_type = np.asarray(self.position_type, dtype=np.int16)
        std = np.asarray(self.std_enu_m, dtype=np.float64)
        if ins_status.shape != (n,) or position_type.shape != (n,) or std.shape != (n, 3):
            raise ValueError("InsReference quality arrays must match the number of poses")
        for name, value in (
            ("stamps_ns", trajectory.stamps_ns),
            ("T_enu_imu", trajectory.T_world_lidar),
            ("ins_status", ins_status),
            ("position_type", position_type),
            ("std_enu_m", std),
        ):
            if value.flags.writeable:
                value = value.copy()
                value.flags.writeable = False
            object.__setattr__(self, name, value)

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    @property
    def trajectory(self) -> Trajectory:
        """The IMU poses as a :class:`~lidar3d.records.Trajectory` (world = ENU)."""
        return Trajectory(self.stamps_ns, self.T_enu_imu)

    @property
    def span_s(self) -> tuple[float, float]:
        """First and last stamp in seconds."""
        return self.stamps_ns[0] / 1e9, self.stamps_ns[-1] / 1e9


def accepted_statuses(names: tuple[str, ...] | list[str]) -> frozenset[InsStatus]:
    """INS statuses from their names; :class:`GnssError` for an unknown name."""
    statuses = set()
    for name in names:
        try:
            statuses.add(enum_from_name(InsStatus, name))
        except ValueError:
            known = ", ".join(s.name for s in InsStatus)
            raise GnssError(f"unknown INS status {name!r} (known: {known})") from None
    if not statuses:
        raise GnssError("no accepted INS status configured")
    return frozenset(statuses)


def origin_from_config(values: tuple[float, ...]) -> GeodeticOrigin | None:
    """The configured ENU origin (lat_deg, lon_deg, h_ellipsoid_m), or ``None`` when empty."""
    if len(values) == 0:
        return None
    if len(values) != 3:
        raise GnssError(f"gnss.origin needs 3 numbers (lat_deg, lon_deg, h_ellipsoid_m), got {len(values)}")
    try:
        return GeodeticOrigin(*values)
    except GnssError as err:
        raise GnssError(f"gnss.origin: {err}") from err


def _choose_source(messages: tuple[InsPvaMessage, ...]) -> tuple[str, list[InsPvaMessage]]:
    groups: dict[str, list[InsPvaMessage]] = {"INSPVAX": [], "INSPVA/INSPVAS": []}
    for message in messages:
        groups["INSPVAX" if message.log == "INSPVAX" else "INSPVA/INSPVAS"].append(message)
    name = max(groups, key=lambda key: (len(groups[key]), key == "INSPVAX"))
    return name, groups[name]


def _status_counts(messages: list[InsPvaMessage]) -> str:
    counts = collections.Counter(m.ins_status.name for m in messages)
    return ", ".join(f"{name} x{count}" for name, count in counts.most_common())


def span_reference(
    log: SpanLog,
    config: GnssConfig | None = None,
    origin: GeodeticOrigin | None = None,
) -> InsReference:
    """Build the ENU reference from a decoded SPAN log.

    Raises :class:`GnssError` when the log has no INS pose, when the INS never reached an accepted
    status, or when no accepted solution has a usable time.
    """
    config = config or GnssConfig()
    name = log.source or "GNSS log"
    source, messages = _choose_source(log.ins)
    if not messages:
        raise GnssError(
            f"{name}: no usable pose: no INS solution (INSPVA, INSPVAS or INSPVAX) in the log ({log.stats.summary()})"
        )
    accepted = accepted_statuses(config.accepted_ins_statuses)
    good_status = [m for m in messages if m.ins_status in accepted]
    if not good_status:
        wanted = ", ".join(sorted(s.name for s in accepted))
        raise GnssError(
            f"{name}: the INS never reached an accepted status ({wanted}); "
            f"{len(messages)} {source} solutions have {_status_counts(messages)}"
        )
    kept = [
        m
        for m in good_status
        if m.gps_week > 0
        and not (config.require_fine_time and m.time_status is not None and m.time_status < TimeStatus.FINE)
    ]
    if not kept:
        raise GnssError(
            f"{name}: no usable pose: none of the {len(good_status)} accepted {source} solutions has a "
            "fine GPS time (time status below FINE or week 0)"
        )
    # Only with statuses such as INS_ALIGNING accepted: their positions are placeholders (an ENU
    # origin must never come from one).
    usable = [m for m in kept if geodetic_problem(m.latitude_deg, m.longitude_deg, m.height_ellipsoid_m) is None]
    if len(usable) < len(kept):
        if not usable:
            raise GnssError(f"{name}: no usable pose: no accepted {source} solution has a usable position")
        logger.warning(
            "%s: %d accepted %s solutions without a usable position dropped", name, len(kept) - len(usable), source
        )
        kept = usable
    stamps = gps_to_unix_ns(
        [m.gps_week for m in kept], [m.gps_seconds for m in kept], config.leap_seconds, config.time_offset_s
    )
    order = np.argsort(stamps, kind="stable")
    stamps = stamps[order]
    unique = np.concatenate([[True], np.diff(stamps) > 0])
    if not unique.all():
        logger.info("%s: %d duplicate %s epochs dropped", name, int((~unique).sum()), source)
    index = order[unique]
    stamps = stamps[unique]
    kept = [kept[i] for i in index]

    lat = np.array([m.latitude_deg for m in kept])
    lon = np.array([m.longitude_deg for m in kept])
    h = np.array([m.height_ellipsoid_m for m in kept])
    if origin is None:
        origin = GeodeticOrigin(lat[0], lon[0], h[0])
    enu = LocalEnu(origin)
    T = np.tile(np.eye(4), (len(kept), 1, 1))
    T[:, :3, 3] = enu.to_enu(lat, lon, h)
    R_local_vehicle = R_enu_vehicle_from_span(
        [m.roll_deg for m in kept], [m.pitch_deg for m in kept], [m.azimuth_deg for m in kept]
    )
    T[:, :3, :3] = enu.R_enu_local(lat, lon) @ R_local_vehicle

    position_type = np.array([-1 if m.position_type is None else int(m.position_type) for m in kept])
    nearest = _nearest_index(stamps, log.positions, config, _NEAREST_POSITION_S)
    fill = (position_type < 0) & (nearest >= 0)
    if fill.any():
        position_type[fill] = [int(log.positions[j].position_type) for j in nearest[fill]]
    std = np.array([[m.longitude_std_m, m.latitude_std_m, m.height_std_m] for m in kept], dtype=float)
    nearest = _nearest_index(stamps, log.std_devs, config, _NEAREST_STD_S)
    fill = np.isnan(std).any(axis=1) & (nearest >= 0)
    if fill.any():
        std[fill] = [
            [log.std_devs[j].longitude_std_m, log.std_devs[j].latitude_std_m, log.std_devs[j].height_std_m]
            for j in nearest[fill]
        ]
    if len(kept) < len(messages):
        logger.info(
            "%s: %d of %d %s solutions kept (%s)", name, len(kept), len(messages), source, _status_counts(messages)
        )
    return InsReference(
        stamps_ns=stamps,
        T_enu_imu=T,
        origin=origin,
        ins_status=np.array([int(m.ins_status) for m in kept]),
        position_type=position_type,
        std_enu_m=std,
        source_log=source,
        n_solutions=len(messages),
    )


def _nearest_index(stamps_ns: np.ndarray, messages, config: GnssConfig, max_dt_s: float) -> np.ndarray:
    """For each stamp, the index of the message nearest in time within ``max_dt_s``, else -1."""
    result = np.full(len(stamps_ns), -1, dtype=np.int64)
    if not messages:
        return result
    other = gps_to_unix_ns(
        [m.gps_week for m in messages], [m.gps_seconds for m in messages], config.leap_seconds, config.time_offset_s
    )
    order = np.argsort(other, kind="stable")
    other = other[order]
    after = np.clip(np.searchsorted(other, stamps_ns), 0, len(other) - 1)
    before = np.clip(after - 1, 0, len(other) - 1)
    take_after = np.abs(other[after] - stamps_ns) < np.abs(other[before] - stamps_ns)
    nearest = np.where(take_after, after, before)
    close = np.abs(other[nearest] - stamps_ns) <= int(max_dt_s * 1e9)
    result[close] = order[nearest[close]]
    return result
