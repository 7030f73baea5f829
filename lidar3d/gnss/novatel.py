"""NovAtel (OEM4 ... OEM7, SPAN) enumerations and the decoded message records.

Values and names follow ``novatel_oem7_msgs`` (``InertialSolutionStatus.msg``,
``PositionOrVelocityType.msg``) and the OEM7 firmware reference (time status, solution status);
see ``shared/reference/gnss-and-metrics.md`` section 1.7. Older firmware spells some names
differently (SPAN-SE prints ``INSSolutionGood``); :func:`enum_from_name` accepts both spellings.

Heights: every record exposes ``height_ellipsoid_m`` (above the WGS84 ellipsoid). INSPVA and
INSPVAS print it directly; INSPVAX, BESTPOS and BESTGNSSPOS print the height above mean sea level
and the undulation N, and ``h_ellipsoid = H_msl + N`` (OEM7 INSPVAX/BESTPOS pages).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import TypeVar

from lidar3d.gnss.enu import geodetic_problem

__all__ = [
    "DATUM_NAMES",
    "MAX_GPS_WEEK",
    "QUALITY_CLASSES",
    "InsPvaMessage",
    "InsStatus",
    "InsStdDevMessage",
    "LogStats",
    "PositionMessage",
    "PositionType",
    "SolutionStatus",
    "SpanLog",
    "SpanMessage",
    "TimeStatus",
    "enum_from_name",
    "message_problem",
    "quality_class",
]


class TimeStatus(enum.IntEnum):
    """GPS reference time status of a long header (binary value)."""

    UNKNOWN = 20
    APPROXIMATE = 60
    COARSEADJUSTING = 80
    COARSE = 100
    COARSESTEERING = 120
    FREEWHEELING = 130
    FINEADJUSTING = 140
    FINE = 160
    FINEBACKUPSTEERING = 170
    FINESTEERING = 180
    SATTIME = 200


class InsStatus(enum.IntEnum):
    """Inertial solution status."""

    INS_INACTIVE = 0
    INS_ALIGNING = 1
    INS_HIGH_VARIANCE = 2
    INS_SOLUTION_GOOD = 3
    INS_SOLUTION_FREE = 6
    INS_ALIGNMENT_COMPLETE = 7
    DETERMINING_ORIENTATION = 8
    WAITING_INITIALPOS = 9
    WAITING_AZIMUTH = 10
    INITIALIZING_BIASES = 11
    MOTION_DETECT = 12


class PositionType(enum.IntEnum):
    """Position or velocity type (OEM7 list; 4-6 are older firmware's)."""

    NONE = 0
    FIXEDPOS = 1
    FIXEDHEIGHT = 2
    FLOATCONV = 4
    WIDELANE = 5
    NARROWLANE = 6
    DOPPLER_VELOCITY = 8
    SINGLE = 16
    PSRDIFF = 17
    WAAS = 18
    PROPAGATED = 19
    L1_FLOAT = 32
    NARROW_FLOAT = 34
    L1_INT = 48
    WIDE_INT = 49
    NARROW_INT = 50
    RTK_DIRECT_INS = 51
    INS_SBAS = 52
    INS_PSRSP = 53
    INS_PSRDIFF = 54
    INS_RTKFLOAT = 55
    INS_RTKFIXED = 56
    PPP_CONVERGING = 68
    PPP = 69
    OPERATIONAL = 70
    WARNING = 71
    OUT_OF_BOUNDS = 72
    INS_PPP_CONVERGING = 73
    INS_PPP = 74
    PPP_BASIC_CONVERGING = 77
    PPP_BASIC = 78
    INS_PPP_BASIC_CONVERGING = 79
    INS_PPP_BASIC = 80


class SolutionStatus(enum.IntEnum):
    """GNSS solution status (BESTPOS and friends)."""

    SOL_COMPUTED = 0
    INSUFFICIENT_OBS = 1
    NO_CONVERGENCE = 2
    SINGULARITY = 3
    COV_TRACE = 4
    TEST_DIST = 5
    COLD_START = 6
    V_H_LIMIT = 7
    VARIANCE = 8
    RESIDUALS = 9
    INTEGRITY_WARNING = 13
    PENDING = 18
    INVALID_FIX = 19
    UNAUTHORIZED = 20
    INVALID_RATE = 22


# Binary datum ids (OEM7 "Datum Transformation Parameters" table): only the two a SPAN user meets.
DATUM_NAMES: Mapping[int, str] = MappingProxyType({61: "WGS84", 63: "USER"})

# Old spellings that do not reduce to the OEM7 name by dropping underscores and case.
_ALIASES = {
    TimeStatus: {"EXACT": TimeStatus.FINESTEERING},  # SPAN-SE (OEMV): time known exactly
    PositionType: {},
    InsStatus: {},
    SolutionStatus: {},
}

_E = TypeVar("_E", bound=enum.IntEnum)


def _key(name: str) -> str:
    return name.replace("_", "").upper()


_LOOKUP: dict[type[enum.IntEnum], dict[str, enum.IntEnum]] = {
    cls: {**{_key(m.name): m for m in cls}, **{_key(k): v for k, v in _ALIASES[cls].items()}}
    for cls in (TimeStatus, InsStatus, PositionType, SolutionStatus)
}


def enum_from_name(cls: type[_E], name: str) -> _E:
    """The member of ``cls`` printed as ``name`` (OEM7 or older spelling); ``ValueError`` if unknown."""
    try:
        member = _LOOKUP[cls][_key(name.strip())]
    except KeyError:
        raise ValueError(f"unknown {cls.__name__} {name!r}") from None
    assert isinstance(member, cls)  # _LOOKUP[cls] holds members of cls only
    return member


# GNSS quality classes for reports and plots, best first.
QUALITY_CLASSES = ("RTK fixed", "RTK float", "PPP", "DGNSS/SBAS", "single", "INS only / none")
_QUALITY = {
    "RTK fixed": {"NARROW_INT", "WIDE_INT", "L1_INT", "INS_RTKFIXED", "RTK_DIRECT_INS", "FIXEDPOS"},
    "RTK float": {"L1_FLOAT", "NARROW_FLOAT", "INS_RTKFLOAT", "FLOATCONV", "WIDELANE", "NARROWLANE"},
    "PPP": {
        "PPP",
        "INS_PPP",
        "PPP_BASIC",
        "INS_PPP_BASIC",
        "PPP_CONVERGING",
        "INS_PPP_CONVERGING",
        "PPP_BASIC_CONVERGING",
        "INS_PPP_BASIC_CONVERGING",
    },
    "DGNSS/SBAS": {"PSRDIFF", "WAAS", "INS_PSRDIFF", "INS_SBAS"},
    "single": {"SINGLE", "INS_PSRSP"},
}


def quality_class(position_type: int | None) -> str:
    """One of :data:`QUALITY_CLASSES` for a position type code (``None``/-1: unknown)."""
    if position_type is None or position_type < 0:
        return QUALITY_CLASSES[-1]
    try:
        name = PositionType(position_type).name
    except ValueError:
        return QUALITY_CLASSES[-1]
    for label, names in _QUALITY.items():
        if name in names:
            return label
    return QUALITY_CLASSES[-1]


_NAN = math.nan


@dataclass(frozen=True, slots=True)
class InsPvaMessage:
    """One INS position/velocity/attitude solution (INSPVA, INSPVAS or INSPVAX).

    Position is at the IMU centre of navigation (unless SETINSTRANSLATION USER moved it).
    Attitude is of the SPAN vehicle frame (x right, y forward, z up): roll about y, pitch about x,
    azimuth clockwise from north, degrees. Standard deviations are NaN when the log has none
    (INSPVA/INSPVAS); ``position_type``, ``undulation_m`` and ``extended_status`` are ``None`` then.

    Attributes:
        log: "INSPVA", "INSPVAS" or "INSPVAX".
        gps_week, gps_seconds: solution time (INSPVA/INSPVAS: the body's time; INSPVAX: the header's).
        time_status: header time status, ``None`` for short headers.
        height_ellipsoid_m: height above the WGS84 ellipsoid (INSPVAX: H_msl + undulation).
    """

    log: str
    gps_week: int
    gps_seconds: float
    time_status: TimeStatus | None
    ins_status: InsStatus
    position_type: PositionType | None
    latitude_deg: float
    longitude_deg: float
    height_ellipsoid_m: float
    undulation_m: float | None
    north_velocity_mps: float
    east_velocity_mps: float
    up_velocity_mps: float
    roll_deg: float
    pitch_deg: float
    azimuth_deg: float
    latitude_std_m: float = _NAN
    longitude_std_m: float = _NAN
    height_std_m: float = _NAN
    roll_std_deg: float = _NAN
    pitch_std_deg: float = _NAN
    azimuth_std_deg: float = _NAN
    extended_status: int | None = None

    @property
    def height_msl_m(self) -> float | None:
        """Height above mean sea level where the log gave the undulation, else ``None``."""
        return None if self.undulation_m is None else self.height_ellipsoid_m - self.undulation_m


@dataclass(frozen=True, slots=True)
class PositionMessage:
    """A GNSS (or, on SPAN, combined GNSS+INS) position: BESTPOS, BESTGNSSPOS (OEMV: BESTGPSPOS).

    BESTGNSSPOS is at the antenna phase centre. Heights as printed: above mean sea level, with the
    undulation N; ``height_ellipsoid_m`` is H + N.
    """

    log: str
    gps_week: int
    gps_seconds: float
    time_status: TimeStatus | None
    solution_status: SolutionStatus
    position_type: PositionType
    latitude_deg: float
    longitude_deg: float
    height_msl_m: float
    undulation_m: float
    datum: str
    latitude_std_m: float
    longitude_std_m: float
    height_std_m: float
    station_id: str
    differential_age_s: float
    solution_age_s: float
    n_satellites_tracked: int
    n_satellites_used: int

    @property
    def height_ellipsoid_m(self) -> float:
        """Height above the ellipsoid, H_msl + undulation."""
        return self.height_msl_m + self.undulation_m


@dataclass(frozen=True, slots=True)
class InsStdDevMessage:
    """INSSTDEV (OEM7): standard deviations of the INS solution at the header time."""

    log: str
    gps_week: int
    gps_seconds: float
    time_status: TimeStatus | None
    latitude_std_m: float
    longitude_std_m: float
    height_std_m: float
    north_velocity_std_mps: float
    east_velocity_std_mps: float
    up_velocity_std_mps: float
    roll_std_deg: float
    pitch_std_deg: float
    azimuth_std_deg: float
    extended_status: int
    time_since_update_s: int


SpanMessage = InsPvaMessage | PositionMessage | InsStdDevMessage


# Full GPS weeks (NovAtel never rolls over at 1024); 9999 is the year 2171. Larger values are corrupt
# (and would overflow int64 nanoseconds past week 15250).
MAX_GPS_WEEK = 9999
_SECONDS_PER_WEEK = 604_800.0


# INS statuses before the INS has a position: receivers print placeholder positions then (a ProPak6
# prints lat -90, lon 0, height -6356752 m, the Earth's centre, while INS_ALIGNING).
_NO_POSITION_INS_STATUSES = frozenset({InsStatus.INS_INACTIVE, InsStatus.INS_ALIGNING, InsStatus.WAITING_INITIALPOS})


def _claims_position(message: InsPvaMessage | PositionMessage) -> bool:
    """False when the message itself says it holds no position (its values are placeholders)."""
    if message.position_type is PositionType.NONE:
        return False
    if isinstance(message, PositionMessage):
        return message.solution_status is SolutionStatus.SOL_COMPUTED
    return message.ins_status not in _NO_POSITION_INS_STATUSES


def message_problem(message: SpanMessage) -> str | None:
    """Why a decoded message's values are unusable, or ``None``.

    Unusable: GPS week outside 0..:data:`MAX_GPS_WEEK` or seconds of week not in [0, 604800); for
    INS and position messages a non-finite latitude, longitude or height, or (INS messages) a
    non-finite velocity or attitude angle; and, where the message claims a position, one that
    :func:`~lidar3d.gnss.enu.geodetic_problem` refuses (|lat| > 90, |lon| > 180, height outside
    -1000..20000 m). A message that says it has no position (position type NONE, solution status
    other than SOL_COMPUTED, INS inactive/aligning/waiting for a position) carries placeholder
    positions, which are kept as decoded: the INS status filter drops them later. A message refused
    here is CRC-valid but corrupt (or a receiver bug) and must never become a reference pose or an
    ENU origin.
    """
    if not 0 <= message.gps_week <= MAX_GPS_WEEK:
        return f"GPS week {message.gps_week} outside [0, {MAX_GPS_WEEK}]"
    if not 0.0 <= message.gps_seconds < _SECONDS_PER_WEEK:
        return f"GPS seconds {message.gps_seconds} outside [0, 604800)"
    if isinstance(message, InsStdDevMessage):
        return None
    names = ["latitude_deg", "longitude_deg", "height_ellipsoid_m"]
    if isinstance(message, InsPvaMessage):
        names += ["north_velocity_mps", "east_velocity_mps", "up_velocity_mps", "roll_deg", "pitch_deg", "azimuth_deg"]
    for name in names:
        value = getattr(message, name)
        if not math.isfinite(value):
            return f"{name} {value} is not finite"
    if _claims_position(message):
        return geodetic_problem(message.latitude_deg, message.longitude_deg, message.height_ellipsoid_m)
    return None


@dataclass(frozen=True, slots=True)
class LogStats:
    """What a reader found in a log.

    Attributes:
        decoded: messages decoded, by log name ("INSPVAX": 1280, ...).
        ignored: CRC-valid messages of logs we do not decode, by name ("CORRIMUDATA": 1280, ...).
        bad_crc: ASCII lines or binary frames whose CRC did not match (never used).
        bad_format: CRC-valid messages with a wrong field count, length or value (never used).
        out_of_range: CRC-valid, well-formed messages whose values are non-finite or out of range
            (:func:`message_problem`; never used).
        truncated: an incomplete last line or frame at the end of the data (tolerated).
        other_bytes: bytes outside any message (NMEA, command replies, prompts, noise).
        problems: the first few rejected messages, "line 12: bad CRC ..." / "byte 4711: ...".
    """

    decoded: Mapping[str, int]
    ignored: Mapping[str, int]
    bad_crc: int
    bad_format: int
    truncated: int
    other_bytes: int
    problems: tuple[str, ...]
    out_of_range: int = 0

    def __post_init__(self) -> None:
        object.__setattr__(self, "decoded", MappingProxyType(dict(self.decoded)))
        object.__setattr__(self, "ignored", MappingProxyType(dict(self.ignored)))
        object.__setattr__(self, "problems", tuple(self.problems))

    @property
    def rejected(self) -> int:
        """Messages seen but not used because they were corrupt, malformed or out of range."""
        return self.bad_crc + self.bad_format + self.out_of_range

    def summary(self) -> str:
        """One line: decoded and ignored counts and rejections."""
        decoded = ", ".join(f"{k} x{v}" for k, v in sorted(self.decoded.items())) or "nothing"
        parts = [f"decoded {decoded}"]
        if self.ignored:
            parts.append("ignored " + ", ".join(f"{k} x{v}" for k, v in sorted(self.ignored.items())))
        counts = f"{self.bad_crc} bad CRC, {self.bad_format} malformed, {self.truncated} truncated"
        if self.out_of_range:
            counts += f", {self.out_of_range} with non-finite or out-of-range values"
        parts.append(counts)
        return "; ".join(parts)


@dataclass(frozen=True, slots=True)
class SpanLog:
    """Everything decoded from one NovAtel log or receiver stream, in file order."""

    ins: tuple[InsPvaMessage, ...]
    positions: tuple[PositionMessage, ...]
    std_devs: tuple[InsStdDevMessage, ...]
    stats: LogStats
    source: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "ins", tuple(self.ins))
        object.__setattr__(self, "positions", tuple(self.positions))
        object.__setattr__(self, "std_devs", tuple(self.std_devs))
