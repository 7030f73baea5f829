"""A NovAtel SPAN-CPT ASCII log of the simulated drive: ``#INSPVAXA`` at 20 Hz, ``#BESTPOSA`` at 1 Hz.

Formats follow ``shared/reference/gnss-and-metrics.md`` sections 1.2 and 1.6-1.11 and the real lines
in ``shared/data/real/novatel_ascii``:

* long ASCII header ``#NAME,port,sequence,idle%,time status,GPS week,seconds of week,receiver
  status,reserved,software build;`` then the body, ``*`` and the CRC-32 (8 lower-case hex digits)
  over everything between ``#`` and ``*``; lines end in CR LF as a receiver writes them;
* INSPVAX body (23 fields): INS status, position type, latitude, longitude, height above mean sea
  level, undulation, north/east/up velocity, roll, pitch, azimuth, nine standard deviations,
  extended solution status (hex), time since update;
* BESTPOS body (21 fields): solution status, position type, latitude, longitude, height above MSL,
  undulation, datum, three standard deviations, station id, differential age, solution age, four
  satellite counts, reserved, extended solution status, two signal masks.

Geometry: the simulation world is the local ENU frame at the geographic origin. INSPVAX positions
are the IMU's, BESTPOS positions the antenna's (IMU + R * lever arm); ellipsoidal heights are
converted to MSL with the origin's undulation (h = H + N). Attitude is the SPAN vehicle frame's
roll/pitch/azimuth relative to the local level frame *at the IMU's own position* (not the origin's;
the two differ by about 0.01 degree per kilometre). Time: GPS week and seconds from UNIX time plus
the leap seconds (18 since 2017).

Errors: a first-order Gauss-Markov error per axis, scaled by the standard deviation the line
reports, so the numbers printed are honest. One stretch of the drive is degraded: RTK float on its
edges and single-point (INS_PSRSP, INS_HIGH_VARIANCE) in its middle, with matching standard
deviations.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from lidar3d.errors import SimulationError
from lidar3d.gnss.attitude import span_from_R_enu_vehicle
from lidar3d.gnss.crc import novatel_crc32
from lidar3d.gnss.enu import R_enu_ecef

__all__ = [
    "GPS_EPOCH_UNIX_S",
    "GeoOrigin",
    "SpanParams",
    "SpanQuality",
    "degraded_window_ns",
    "enu_to_geodetic",
    "gps_week_seconds",
    "shift_positions",
    "span_log_lines",
]

GPS_EPOCH_UNIX_S = 315_964_800  # 1980-01-06T00:00:00Z
_WEEK_NS = 604_800 * 1_000_000_000


@dataclass(frozen=True, slots=True)
class GeoOrigin:
    """The geographic position of the world frame's origin.

    Attributes:
        latitude_deg: WGS84 latitude.
        longitude_deg: WGS84 longitude.
        height_m: WGS84 ellipsoidal height.
        undulation_m: geoid undulation N (geoid above ellipsoid); MSL height H = h - N.
    """

    latitude_deg: float = 49.01135
    longitude_deg: float = 8.41650
    height_m: float = 163.0
    undulation_m: float = 47.9

    def __post_init__(self) -> None:
        if not (-89.0 < self.latitude_deg < 89.0 and -180.0 <= self.longitude_deg <= 180.0):
            raise SimulationError("geographic origin must have |latitude| < 89 and longitude in [-180, 180]")


@dataclass(frozen=True, slots=True)
class SpanQuality:
    """What a solution of one quality level reports (and how large its errors are)."""

    ins_status: str
    position_type: str
    horizontal_sigma_m: float
    vertical_sigma_m: float
    velocity_sigma_mps: float
    roll_pitch_sigma_deg: float
    azimuth_sigma_deg: float
    extended_status: int
    satellites: int
    differential_age_s: float


RTK_FIXED = SpanQuality("INS_SOLUTION_GOOD", "INS_RTKFIXED", 0.012, 0.020, 0.010, 0.008, 0.025, 0x0B000043, 16, 1.0)
RTK_FLOAT = SpanQuality("INS_HIGH_VARIANCE", "INS_RTKFLOAT", 0.15, 0.25, 0.030, 0.015, 0.05, 0x0B000043, 11, 2.0)
SINGLE = SpanQuality("INS_HIGH_VARIANCE", "INS_PSRSP", 0.9, 1.6, 0.10, 0.03, 0.12, 0x0B000141, 6, 0.0)


@dataclass(frozen=True, slots=True)
class SpanParams:
    """The simulated SPAN-CPT receiver.

    Attributes:
        origin: geographic position of the world origin.
        leap_seconds: GPS - UTC.
        inspvax_rate_hz: INSPVAXA rate (must divide 1 s evenly into milliseconds).
        bestpos_rate_hz: BESTPOSA rate.
        noise: add the solution errors (False: the log carries the exact truth, rounded).
        degraded_window: (start, end) fractions of the drive's duration with degraded GNSS.
        correlation_time_s: correlation time of the position and attitude errors.
        port: receiver port printed in the header.
        seed_stream: mixed into the seed so the log noise is independent of the scans'.
    """

    origin: GeoOrigin = field(default_factory=GeoOrigin)
    leap_seconds: int = 18
    inspvax_rate_hz: float = 20.0
    bestpos_rate_hz: float = 1.0
    noise: bool = True
    degraded_window: tuple[float, float] = (0.55, 0.70)
    correlation_time_s: float = 20.0
    port: str = "COM1"
    seed_stream: int = 0x5BA1

    def __post_init__(self) -> None:
        for rate in (self.inspvax_rate_hz, self.bestpos_rate_hz):
            if rate <= 0.0 or abs(1000.0 / rate - round(1000.0 / rate)) > 1e-9:
                raise SimulationError(f"SPAN log rate {rate} Hz must give a whole number of milliseconds")
        lo, hi = self.degraded_window
        if not 0.0 <= lo <= hi <= 1.0:
            raise SimulationError("SPAN degraded_window must be fractions 0 <= start <= end <= 1")


def gps_week_seconds(unix_ns: np.ndarray, leap_seconds: int) -> tuple[np.ndarray, np.ndarray]:
    """GPS week and nanoseconds of week for UNIX (UTC) times in integer nanoseconds."""
    gps_ns = np.asarray(unix_ns, dtype=np.int64) - GPS_EPOCH_UNIX_S * 1_000_000_000 + leap_seconds * 1_000_000_000
    return gps_ns // _WEEK_NS, gps_ns % _WEEK_NS


@functools.lru_cache(maxsize=8)
def _topocentric(origin: GeoOrigin):
    from pyproj import Transformer

    return Transformer.from_pipeline(
        "+proj=pipeline +step +proj=axisswap +order=2,1 +step +proj=unitconvert +xy_in=deg +xy_out=rad "
        "+step +proj=cart +ellps=WGS84 "
        f"+step +proj=topocentric +ellps=WGS84 +lat_0={origin.latitude_deg!r} +lon_0={origin.longitude_deg!r} "
        f"+h_0={origin.height_m!r}"
    )


def enu_to_geodetic(enu_m: np.ndarray, origin: GeoOrigin) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(latitude deg, longitude deg, ellipsoidal height m) of (N, 3) ENU positions relative to ``origin``."""
    from pyproj.enums import TransformDirection

    enu = np.asarray(enu_m, float).reshape(-1, 3)
    lat, lon, h = _topocentric(origin).transform(enu[:, 0], enu[:, 1], enu[:, 2], direction=TransformDirection.INVERSE)
    return np.asarray(lat), np.asarray(lon), np.asarray(h)


def _gauss_markov(rng: np.random.Generator, n: int, dims: int, dt_s: float, tau_s: float) -> np.ndarray:
    """(n, dims) stationary first-order Gauss-Markov sequences with unit variance."""
    a = np.exp(-dt_s / tau_s)
    innovations = rng.standard_normal((n, dims))
    out = np.empty((n, dims))
    out[0] = innovations[0]
    scale = np.sqrt(1.0 - a * a)
    for k in range(1, n):
        out[k] = a * out[k - 1] + scale * innovations[k]
    return out


def degraded_window_ns(duration_s: float, window: tuple[float, float]) -> tuple[int, int]:
    """(start, end) of the degraded stretch in nanoseconds since the drive's start."""
    duration_ns = int(round(duration_s * 1e9))
    return int(round(window[0] * duration_ns)), int(round(window[1] * duration_ns))


def _quality_per_sample(offsets_ns: np.ndarray, duration_s: float, window: tuple[float, float]) -> np.ndarray:
    """Quality level per sample: 0 RTK fixed, 1 RTK float (edges of the window), 2 single (middle)."""
    start, end = degraded_window_ns(duration_s, window)
    edge = (end - start) // 4
    level = np.zeros(len(offsets_ns), dtype=np.int64)
    level[(offsets_ns >= start) & (offsets_ns < end)] = 1
    level[(offsets_ns >= start + edge) & (offsets_ns < end - edge)] = 2
    return level


def _line(name: str, port: str, time_fields: list[str], reserved: str, body_fields: list[str]) -> str:
    """One long-header ASCII log line: name, port, sequence 0, idle, time status, week, seconds,
    receiver status, reserved (message-definition CRC), software build; body; CRC; CR LF."""
    header = [name, port, "0", *time_fields, "00000000", reserved, "15823"]
    content = ",".join(header) + ";" + ",".join(body_fields)
    return f"#{content}*{novatel_crc32(content.encode('ascii')):08x}\r\n"


def span_log_lines(
    pose_fn,
    velocity_fn,
    *,
    duration_s: float,
    start_time_ns: int,
    imu_to_antenna_m,
    params: SpanParams,
    seed: int,
) -> list[str]:
    """The log's lines (each ending in CR LF), in time order.

    Args:
        pose_fn: ``t_s -> (N, 4, 4) T_world_imu``, times in seconds since ``start_time_ns``.
        velocity_fn: ``t_s -> (N, 3)`` world-frame IMU velocity.
        duration_s: the log covers GPS epochs on the rate grid within [0, duration_s].
        start_time_ns: UNIX time (UTC) of t = 0.
        imu_to_antenna_m: (3,) antenna position in the IMU frame.
        params: receiver parameters.
        seed: simulation seed.
    """
    rng = np.random.default_rng([int(seed), params.seed_stream])
    period_ns = int(round(1e9 / params.inspvax_rate_hz))
    bestpos_period_ns = int(round(1e9 / params.bestpos_rate_hz))
    _, start_sow_ns = gps_week_seconds(np.array([start_time_ns]), params.leap_seconds)
    first_offset_ns = (-int(start_sow_ns[0])) % period_ns  # first epoch on the receiver's rate grid
    n = int((int(round(duration_s * 1e9)) - first_offset_ns) // period_ns) + 1
    if n < 1:
        raise SimulationError(f"a {duration_s:.3f} s drive holds no {params.inspvax_rate_hz:g} Hz SPAN epoch")
    offsets_ns = first_offset_ns + period_ns * np.arange(n, dtype=np.int64)
    t_s = offsets_ns * 1e-9
    unix_ns = start_time_ns + offsets_ns
    week, sow_ns = gps_week_seconds(unix_ns, params.leap_seconds)

    poses = pose_fn(t_s)
    velocity_world = velocity_fn(t_s)
    level = _quality_per_sample(offsets_ns, duration_s, params.degraded_window)
    qualities = (RTK_FIXED, RTK_FLOAT, SINGLE)
    h_sigma = np.array([q.horizontal_sigma_m for q in qualities])[level]
    v_sigma = np.array([q.vertical_sigma_m for q in qualities])[level]
    vel_sigma = np.array([q.velocity_sigma_mps for q in qualities])[level]
    rp_sigma = np.array([q.roll_pitch_sigma_deg for q in qualities])[level]
    az_sigma = np.array([q.azimuth_sigma_deg for q in qualities])[level]

    dt = period_ns * 1e-9
    position_error = _gauss_markov(rng, n, 3, dt, params.correlation_time_s)
    attitude_error = _gauss_markov(rng, n, 3, dt, params.correlation_time_s)
    velocity_error = _gauss_markov(rng, n, 3, dt, 1.0)
    idle = np.round(rng.uniform(55.0, 80.0, size=n) * 2.0) / 2.0
    if not params.noise:
        position_error[:] = attitude_error[:] = velocity_error[:] = 0.0
    position_error *= np.column_stack([h_sigma, h_sigma, v_sigma])
    attitude_error *= np.column_stack([rp_sigma, rp_sigma, az_sigma])
    velocity_error *= vel_sigma[:, None]

    origin = params.origin
    imu_enu = poses[:, :3, 3] + position_error
    lat, lon, h_ell = enu_to_geodetic(imu_enu, origin)
    R_local_origin = R_enu_ecef(lat, lon) @ R_enu_ecef(origin.latitude_deg, origin.longitude_deg).T
    roll, pitch, azimuth = span_from_R_enu_vehicle(R_local_origin @ poses[:, :3, :3])
    roll = roll + attitude_error[:, 0]
    pitch = pitch + attitude_error[:, 1]
    azimuth = np.mod(azimuth + attitude_error[:, 2], 360.0)
    velocity_local = np.einsum("nij,nj->ni", R_local_origin, velocity_world) + velocity_error

    antenna_enu = imu_enu + np.einsum("nij,j->ni", poses[:, :3, :3], np.asarray(imu_to_antenna_m, float))
    ant_lat, ant_lon, ant_h = enu_to_geodetic(antenna_enu, origin)
    undulation = origin.undulation_m

    lines = []
    for k in range(n):
        sow_ms = int(sow_ns[k]) // 1_000_000
        time_fields = [f"{idle[k]:.1f}", "FINESTEERING", str(int(week[k])), f"{sow_ms // 1000}.{sow_ms % 1000:03d}"]
        q = qualities[level[k]]
        body = [
            q.ins_status,
            q.position_type,
            f"{lat[k]:.11f}",
            f"{lon[k]:.11f}",
            f"{h_ell[k] - undulation:.4f}",
            f"{undulation:.4f}",
            f"{velocity_local[k, 1]:.4f}",
            f"{velocity_local[k, 0]:.4f}",
            f"{velocity_local[k, 2]:.4f}",
            f"{roll[k]:.9f}",
            f"{pitch[k]:.9f}",
            f"{azimuth[k]:.9f}",
            f"{h_sigma[k]:.4f}",
            f"{h_sigma[k]:.4f}",
            f"{v_sigma[k]:.4f}",
            f"{vel_sigma[k]:.4f}",
            f"{vel_sigma[k]:.4f}",
            f"{vel_sigma[k]:.4f}",
            f"{rp_sigma[k]:.4f}",
            f"{rp_sigma[k]:.4f}",
            f"{az_sigma[k]:.4f}",
            f"{q.extended_status:08x}",
            "0",
        ]
        lines.append(_line("INSPVAXA", params.port, time_fields, "4e77", body))
        if int(sow_ns[k]) % bestpos_period_ns == 0:
            rtk = q.position_type != "INS_PSRSP"
            body = [
                "SOL_COMPUTED",
                q.position_type,
                f"{ant_lat[k]:.11f}",
                f"{ant_lon[k]:.11f}",
                f"{ant_h[k] - undulation:.4f}",
                f"{undulation:.4f}",
                "WGS84",
                f"{h_sigma[k]:.4f}",
                f"{h_sigma[k]:.4f}",
                f"{v_sigma[k]:.4f}",
                '"0"' if rtk else '""',
                f"{q.differential_age_s:.3f}",
                "0.000",
                str(q.satellites + 2),
                str(q.satellites),
                str(q.satellites),
                str(q.satellites if rtk else 0),
                "0",
                "01" if q.position_type == "INS_RTKFIXED" else "00",
                "0",
                "33",
            ]
            lines.append(_line("BESTPOSA", params.port, time_fields, "6145", body))
    return lines


def shift_positions(lines: list[str], start_gps_s: float, end_gps_s: float, east_m: float, north_m: float) -> list[str]:
    """The log ``lines`` with the INSPVAX and BESTPOS positions in [start, end) (GPS seconds of week)
    moved by (east_m, north_m), their status left as it was and their CRC recomputed: a position jump
    the receiver does not flag (a test of the GNSS factors' consistency gate). Other lines are kept.
    The shift uses a sphere of the WGS84 semi-major axis (0.3 % of the shift at most)."""
    radius_m = 6_378_137.0
    out = []
    for line in lines:
        content = line[1 : line.index("*")] if line.startswith("#") else ""
        header, _, body = content.partition(";")
        fields = header.split(",")
        if fields[0] not in ("INSPVAXA", "BESTPOSA") or not start_gps_s <= float(fields[6]) < end_gps_s:
            out.append(line)
            continue
        values = body.split(",")
        latitude = float(values[2])
        values[2] = f"{latitude + np.degrees(north_m / radius_m):.11f}"
        values[3] = f"{float(values[3]) + np.degrees(east_m / (radius_m * np.cos(np.radians(latitude)))):.11f}"
        content = header + ";" + ",".join(values)
        out.append(f"#{content}*{novatel_crc32(content.encode('ascii')):08x}\r\n")
    return out
