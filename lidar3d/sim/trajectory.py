"""Vehicle motion along a street route, and the places where the route revisits itself.

A route is a polyline of street-grid nodes. Its corners are rounded with circular arcs, the path is
moved ``lane_offset_m`` to the right of the centre line (driving on the right), and a C2 cubic
spline through the result gives position and heading at every instant. The speed follows a target
(the cruise speed by default; optionally a target per stretch of road, explicit or drawn from the
seed, with smooth transitions), slows for curvature (lateral-acceleration limit), comes to 0 m/s at
stops and obeys acceleration and braking limits; time is integrated along the path and inverted
with a monotone interpolant (PCHIP for the plain cruise-speed drive; with a speed profile or stops,
a cubic Hermite spline whose knot slopes are the planned speeds, exact under constant acceleration).
A stop is a pair of knots at the same path position: the pose is exactly still for the hold.

The vehicle frame is the SPAN vehicle/IMU frame (x right, y forward, z up), its origin the IMU. The
vehicle stands on the terrain: its z axis is the terrain normal (roll and pitch come from the slope),
its y axis the path heading projected onto the terrain plane, and the IMU sits ``imu_height_m``
above the ground along the normal. Optionally the body vibrates on its suspension: pitch (about the
vehicle x axis), roll (about y) and heave (along the terrain normal) from a band-limited random
process (a sum of sinusoids at random frequencies within ``vibration_band_hz``), on top of the slope
attitude, scaled down at walking pace and zero while the vehicle stands.

Every new behaviour is off by default: ``RouteParams()`` drives exactly as before.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicHermiteSpline, CubicSpline, PchipInterpolator
from scipy.spatial.transform import Rotation

from lidar3d.errors import SimulationError
from lidar3d.sim.terrain import Terrain

__all__ = ["RevisitPair", "RouteParams", "VehicleMotion", "find_revisits", "group_revisits"]

_MOTION_STREAM = 0x5BEED


@dataclass(frozen=True, slots=True)
class RouteParams:
    """How the vehicle drives a route.

    Attributes:
        corner_radius_m: radius of the arcs that round the route's corners (street centre line).
        cruise_speed_mps: speed on straight road; with a speed profile, its upper bound.
        min_speed_mps: speed floor except at stops (also the speed at the start).
        max_lateral_accel_mps2: curvature speed limit, v <= sqrt(a_lat / curvature).
        max_accel_mps2: acceleration limit.
        max_decel_mps2: braking limit.
        lane_offset_m: distance of the driven path to the right of the street centre line.
        imu_height_m: height of the IMU above the ground.
        speed_targets: ``(path position m, speed m/s)`` pairs, ascending positions: from each
            position on, the vehicle aims at that speed (before the first one: the cruise speed).
            Each speed must lie in [min_speed_mps, cruise_speed_mps]. Path positions are distances
            along the driven path from the route start.
        random_speed_min_mps: when > 0, the route is cut into stretches of random length within
            ``speed_stretch_m``; the target speed at each stretch end is drawn uniformly in
            [random_speed_min_mps, cruise_speed_mps] from the simulation seed and the target varies
            linearly in between, so the speed is never constant for long (exclusive with
            ``speed_targets``).
        speed_stretch_m: (shortest, longest) stretch of the random speed profile.
        speed_transition_m: the target is smoothed with a raised-cosine window this long (explicit
            targets change over this length); the acceleration and braking limits still apply.
        stops: ``(path position m, hold s)`` pairs: the vehicle brakes to 0 m/s at that position,
            stands exactly still for the hold and pulls away again.
        vibration_deg: RMS of the suspension pitch and of the roll (each), in degrees (0: none).
        vibration_heave_m: RMS of the vertical suspension motion along the terrain normal.
        vibration_band_hz: (lowest, highest) frequency of the vibration.
        vibration_full_speed_mps: below this speed the vibration amplitude shrinks in proportion to
            the speed (zero at a stop).
    """

    corner_radius_m: float = 10.0
    cruise_speed_mps: float = 6.5
    min_speed_mps: float = 2.0
    max_lateral_accel_mps2: float = 2.5
    max_accel_mps2: float = 1.2
    max_decel_mps2: float = 2.0
    lane_offset_m: float = 1.5
    imu_height_m: float = 1.0
    speed_targets: tuple[tuple[float, float], ...] = ()
    random_speed_min_mps: float = 0.0
    speed_stretch_m: tuple[float, float] = (40.0, 120.0)
    speed_transition_m: float = 30.0
    stops: tuple[tuple[float, float], ...] = ()
    vibration_deg: float = 0.0
    vibration_heave_m: float = 0.0
    vibration_band_hz: tuple[float, float] = (5.0, 20.0)
    vibration_full_speed_mps: float = 3.0

    def __post_init__(self) -> None:
        if not 0.0 < self.min_speed_mps <= self.cruise_speed_mps:
            raise SimulationError("route speeds must satisfy 0 < min_speed_mps <= cruise_speed_mps")
        speeds = [v for _, v in self.speed_targets]
        if self.random_speed_min_mps > 0.0:
            if self.speed_targets:
                raise SimulationError("route: give speed_targets or random_speed_min_mps, not both")
            speeds.append(self.random_speed_min_mps)
        if any(not self.min_speed_mps <= v <= self.cruise_speed_mps for v in speeds):
            raise SimulationError("route target speeds must lie in [min_speed_mps, cruise_speed_mps]")
        for name, pairs in (("speed_targets", self.speed_targets), ("stops", self.stops)):
            positions = [p for p, _ in pairs]
            if any(b <= a for a, b in itertools.pairwise(positions)) or any(p < 0.0 for p in positions):
                raise SimulationError(f"route {name} positions must be >= 0 and ascending")
        if any(hold <= 0.0 for _, hold in self.stops):
            raise SimulationError("route stop holds must be positive")
        if not 0.0 < self.speed_stretch_m[0] <= self.speed_stretch_m[1] or self.speed_transition_m <= 0.0:
            raise SimulationError("route speed_stretch_m must be 0 < shortest <= longest and speed_transition_m > 0")
        if min(self.vibration_deg, self.vibration_heave_m) < 0.0 or self.vibration_full_speed_mps <= 0.0:
            raise SimulationError("route vibration amplitudes must be >= 0 and vibration_full_speed_mps > 0")
        if not 0.0 < self.vibration_band_hz[0] < self.vibration_band_hz[1]:
            raise SimulationError("route vibration_band_hz must be 0 < lowest < highest")
        if min(self.max_lateral_accel_mps2, self.max_accel_mps2, self.max_decel_mps2) <= 0.0:
            raise SimulationError("route acceleration limits must be positive")
        if self.corner_radius_m <= abs(self.lane_offset_m):
            raise SimulationError("route corner_radius_m must exceed |lane_offset_m|")

    @property
    def vibrates(self) -> bool:
        """Whether the body moves on its suspension."""
        return self.vibration_deg > 0.0 or self.vibration_heave_m > 0.0


def _rounded_polyline(nodes_m: np.ndarray, radius_m: float) -> np.ndarray:
    """Dense points (about 0.5 m apart) along the polyline with every corner replaced by an arc."""
    directions = np.diff(nodes_m, axis=0)
    lengths = np.linalg.norm(directions, axis=1)
    if np.any(lengths < 1e-6):
        raise SimulationError("route has two identical consecutive nodes")
    units = directions / lengths[:, None]
    # Tangent distance of the arc at each interior node: R tan(turn / 2).
    cos_turn = np.clip(np.sum(units[:-1] * units[1:], axis=1), -1.0, 1.0)
    turn = np.arccos(cos_turn)
    if np.any(turn > np.deg2rad(170.0)):
        raise SimulationError("route turns back on itself (U-turns are not supported)")
    cut = np.concatenate([[0.0], radius_m * np.tan(0.5 * turn), [0.0]])
    for k, length in enumerate(lengths):
        if cut[k] + cut[k + 1] > length + 1e-9:
            raise SimulationError(f"route segment {k} ({length:.1f} m) is too short for corner radius {radius_m} m")
    pieces = []
    for k in range(len(lengths)):
        start = nodes_m[k] + units[k] * cut[k]
        stop = nodes_m[k + 1] - units[k] * cut[k + 1]
        n = max(2, int(np.ceil(np.linalg.norm(stop - start) / 0.5)) + 1)
        pieces.append(start + np.linspace(0.0, 1.0, n)[:, None] * (stop - start))
        if k + 1 < len(lengths) and turn[k] > 1e-9:
            a, b = units[k], units[k + 1]
            left = a[0] * b[1] - a[1] * b[0] > 0.0  # turning left (counter-clockwise)
            normal = np.array([-a[1], a[0]]) if left else np.array([a[1], -a[0]])
            center = stop + normal * radius_m
            phi0 = np.arctan2(stop[1] - center[1], stop[0] - center[0])
            sweep = turn[k] if left else -turn[k]
            n_arc = max(3, int(np.ceil(radius_m * turn[k] / 0.5)) + 1)
            phi = phi0 + np.linspace(0.0, sweep, n_arc)[1:-1]
            pieces.append(center + radius_m * np.column_stack([np.cos(phi), np.sin(phi)]))
    points = np.vstack(pieces)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(points, axis=0), axis=1) > 1e-6])
    return points[keep]


class VehicleMotion:
    """The vehicle's pose as a function of time since the start of the route.

    Args:
        nodes_m: (M, 2) route nodes in the world frame.
        terrain: the ground the vehicle drives on.
        params: driving parameters.
        seed: seeds the random speed profile and the vibration (unused when neither is on).

    Attributes:
        length_m: length of the driven path.
        duration_s: time to drive it, stops included.
        stop_intervals_s: (start, end) route times of each stop, in order.
    """

    def __init__(self, nodes_m, terrain: Terrain, params: RouteParams, seed: int = 0) -> None:
        nodes = np.asarray(nodes_m, dtype=float)
        if nodes.ndim != 2 or nodes.shape[1] != 2 or len(nodes) < 2:
            raise SimulationError("a route needs at least two (x, y) nodes")
        self.params = params
        self.terrain = terrain
        centre = _rounded_polyline(nodes, params.corner_radius_m)
        tangent = np.gradient(centre, axis=0)
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
        right = np.column_stack([tangent[:, 1], -tangent[:, 0]])
        lane = centre + params.lane_offset_m * right
        # Resample about every metre and fit a C2 spline parameterised by chord length.
        chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(lane, axis=0), axis=1))])
        u_knots = np.linspace(0.0, chord[-1], max(4, int(np.ceil(chord[-1] / 1.0)) + 1))
        knots = np.column_stack([np.interp(u_knots, chord, lane[:, 0]), np.interp(u_knots, chord, lane[:, 1])])
        self._path = CubicSpline(u_knots, knots, bc_type="natural")
        self._path_d1 = self._path.derivative(1)
        self._path_d2 = self._path.derivative(2)
        self.length_m = float(u_knots[-1])

        u = np.linspace(0.0, self.length_m, max(8, int(np.ceil(self.length_m / 0.25)) + 1))
        d1, d2 = self._path_d1(u), self._path_d2(u)
        speed_scale = np.linalg.norm(d1, axis=1)
        curvature = np.abs(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]) / speed_scale**3
        limit = np.sqrt(params.max_lateral_accel_mps2 / np.maximum(curvature, 1e-9))
        ds = np.diff(u) * 0.5 * (speed_scale[1:] + speed_scale[:-1])
        position = np.concatenate([[0.0], np.cumsum(ds)])  # distance along the path at each sample
        rng = np.random.default_rng([int(seed), _MOTION_STREAM])
        v = np.clip(limit, params.min_speed_mps, self._target_speed(position, rng))
        v[0] = params.min_speed_mps
        stop_index = self._stop_indices(position)
        v[stop_index] = 0.0
        for k in range(1, len(v)):  # acceleration limit, forwards
            v[k] = min(v[k], np.sqrt(v[k - 1] ** 2 + 2.0 * params.max_accel_mps2 * ds[k - 1]))
        for k in range(len(v) - 2, -1, -1):  # braking limit, backwards
            v[k] = min(v[k], np.sqrt(v[k + 1] ** 2 + 2.0 * params.max_decel_mps2 * ds[k]))
        self.min_speed_reached_mps = float(v.min())
        self.max_speed_reached_mps = float(v.max())
        dt = ds / (0.5 * (v[1:] + v[:-1]))
        t = np.concatenate([[0.0], np.cumsum(dt)])
        # A stop is a second knot at the same path position, the hold later: the interpolant is flat between.
        holds = np.zeros(len(u))
        holds[stop_index] = [hold for _, hold in params.stops]
        arrive = t + np.concatenate([[0.0], np.cumsum(holds)[:-1]])
        t = np.insert(arrive, stop_index + 1, arrive[stop_index] + holds[stop_index])
        u = np.insert(u, stop_index + 1, u[stop_index])
        self._t_knots = t
        self._u_knots = u
        self._v_knots = np.insert(v, stop_index + 1, 0.0)
        self.stop_intervals_s = tuple((float(arrive[k]), float(arrive[k] + holds[k])) for k in stop_index)
        self.duration_s = float(t[-1])
        if params.stops or params.speed_targets or params.random_speed_min_mps > 0.0:
            # Knot slopes from the planned speeds: exact on constant-acceleration stretches (PCHIP's own
            # slope estimates make acceleration spikes of several m/s^2 when braking into a stop).
            du_dt = self._v_knots / np.insert(speed_scale, stop_index + 1, 1.0)
            self._u_of_t = CubicHermiteSpline(t, u, du_dt)
        else:  # the cruise-speed drive, exactly as it always was
            self._u_of_t = PchipInterpolator(t, u)
        self._vibration = _Vibration(params, rng, self.duration_s) if params.vibrates else None

    def _target_speed(self, position_m: np.ndarray, rng: np.random.Generator) -> float | np.ndarray:
        """The speed the driver aims at: the cruise speed, or a smoothed per-stretch profile along ``position_m``."""
        params = self.params
        if params.speed_targets:  # held from each position on
            starts = np.array([0.0] + [p for p, _ in params.speed_targets])
            speeds = np.array([params.cruise_speed_mps] + [v for _, v in params.speed_targets])
            target = speeds[np.searchsorted(starts, position_m, side="right") - 1]
        elif params.random_speed_min_mps > 0.0:  # linear between random speeds at random stretch ends
            ends = [0.0]
            while ends[-1] < position_m[-1]:
                ends.append(ends[-1] + rng.uniform(*params.speed_stretch_m))
            speeds = rng.uniform(params.random_speed_min_mps, params.cruise_speed_mps, len(ends))
            target = np.interp(position_m, ends, speeds)
        else:
            return params.cruise_speed_mps
        spacing = position_m[-1] / (len(position_m) - 1)
        half = max(1, int(round(0.5 * params.speed_transition_m / spacing)))
        window = np.hanning(2 * half + 1)
        padded = np.concatenate([np.full(half, target[0]), target, np.full(half, target[-1])])
        return np.convolve(padded, window / window.sum(), mode="valid")

    def _stop_indices(self, position_m: np.ndarray) -> np.ndarray:
        """Path sample index of each stop (ascending); raises for stops off the route or too close together."""
        stops = np.array([p for p, _ in self.params.stops], dtype=float)
        if stops.size and (stops.max() > position_m[-1] - 1.0 or stops.min() < 1.0):
            raise SimulationError(f"route stops must lie between 1 m and {position_m[-1] - 1.0:.1f} m along the path")
        index = np.searchsorted(position_m, stops).astype(np.int64)
        if np.any(np.diff(index) < 2):
            raise SimulationError("route stops must be at least 1 m apart")
        return index

    def _check_times(self, t_s: np.ndarray) -> np.ndarray:
        t = np.asarray(t_s, dtype=float)
        if t.size and (t.min() < -1e-9 or t.max() > self.duration_s + 1e-9):
            raise SimulationError(
                f"time {float(t.min()):.3f}..{float(t.max()):.3f} s is outside the route's 0..{self.duration_s:.3f} s"
            )
        return np.clip(t, 0.0, self.duration_s)

    def pose_at(self, t_s) -> np.ndarray:
        """(N, 4, 4) ``T_world_imu`` at the times ``t_s`` (seconds since the route start)."""
        t = np.atleast_1d(self._check_times(t_s))
        u = self._u_of_t(t)
        xy = self._path(u)
        heading = self._path_d1(u)
        heading /= np.linalg.norm(heading, axis=1, keepdims=True)
        gradient = self.terrain.gradient(xy[:, 0], xy[:, 1])
        up = np.column_stack([-gradient, np.ones(len(t))])
        up /= np.linalg.norm(up, axis=1, keepdims=True)
        forward = np.column_stack([heading, np.sum(gradient * heading, axis=1)])
        forward /= np.linalg.norm(forward, axis=1, keepdims=True)
        right = np.cross(forward, up)
        poses = np.zeros((len(t), 4, 4))
        poses[:, :3, 0] = right
        poses[:, :3, 1] = forward
        poses[:, :3, 2] = up
        ground = np.column_stack([xy, self.terrain.height_m(xy[:, 0], xy[:, 1])])
        poses[:, :3, 3] = ground + self.params.imu_height_m * up
        poses[:, 3, 3] = 1.0
        if self._vibration is not None:
            scale = np.clip(self.profile_speed_at(t) / self.params.vibration_full_speed_mps, 0.0, 1.0)
            pitch, roll, heave = self._vibration.at(t) * scale
            body = Rotation.from_rotvec(np.column_stack([pitch, roll, np.zeros(len(t))])).as_matrix()
            poses[:, :3, :3] = poses[:, :3, :3] @ body
            poses[:, :3, 3] += heave[:, None] * up
        return poses

    def path_position_at(self, t_s) -> np.ndarray:
        """(N,) path position (m along the driven lane from the route start) at route times ``t_s``."""
        return np.asarray(self._u_of_t(np.atleast_1d(self._check_times(t_s))), dtype=float)

    def time_at_path_position(self, position_m) -> np.ndarray:
        """(N,) first route time at which the vehicle reaches each path position (clipped to the path)."""
        return np.interp(np.clip(np.atleast_1d(position_m), 0.0, self.length_m), self._u_knots, self._t_knots)

    def lane_xy(self, position_m, right_m=0.0) -> tuple[np.ndarray, np.ndarray]:
        """Points beside the driven lane, for other road users.

        Args:
            position_m: (N,) path positions; beyond either end of the path the lane runs on straight.
            right_m: distance to the right of the driven lane (negative: to the left), scalar or (N,).

        Returns:
            (N, 2) world positions and (N, 2) unit headings of the lane there.
        """
        u = np.atleast_1d(np.asarray(position_m, dtype=float))
        inside = np.clip(u, 0.0, self.length_m)
        heading = self._path_d1(inside)
        heading /= np.linalg.norm(heading, axis=1, keepdims=True)
        xy = self._path(inside) + heading * (u - inside)[:, None]
        right = np.column_stack([heading[:, 1], -heading[:, 0]])
        return xy + np.asarray(right_m, dtype=float)[..., None] * right, heading

    def profile_speed_at(self, t_s) -> np.ndarray:
        """(N,) speed of the planned profile (m/s) at route times ``t_s``, linear between path samples; 0 at stops."""
        return np.interp(np.atleast_1d(self._check_times(t_s)), self._t_knots, self._v_knots)

    def velocity_at(self, t_s, dt_s: float = 1e-3) -> np.ndarray:
        """(N, 3) world-frame velocity of the IMU (central difference of :meth:`pose_at`)."""
        t = np.atleast_1d(self._check_times(t_s))
        lo = np.clip(t - dt_s, 0.0, self.duration_s)
        hi = np.clip(t + dt_s, 0.0, self.duration_s)
        return (self.pose_at(hi)[:, :3, 3] - self.pose_at(lo)[:, :3, 3]) / (hi - lo)[:, None]


class _Vibration:
    """Body pitch, roll (rad) and heave (m) on the suspension: per axis a sum of sinusoids of equal
    amplitude at random frequencies uniform in the band and random phases (band-limited, nearly
    Gaussian), sampled every ``SAMPLE_S`` over the drive and interpolated with a C2 cubic spline
    (relative error about 1e-5 at 20 Hz; ray casting a sweep evaluates 1800 instants)."""

    N_COMPONENTS = 48
    SAMPLE_S = 0.002

    def __init__(self, params: RouteParams, rng: np.random.Generator, duration_s: float) -> None:
        shape = (3, self.N_COMPONENTS)
        frequency_hz = rng.uniform(*params.vibration_band_hz, size=shape)
        phase = rng.uniform(0.0, 2.0 * np.pi, size=shape)
        rms = np.array([np.deg2rad(params.vibration_deg)] * 2 + [params.vibration_heave_m])
        amplitude = rms * np.sqrt(2.0 / self.N_COMPONENTS)  # RMS of K sinusoids: a sqrt(K / 2)
        t = np.arange(0.0, duration_s + 2.0 * self.SAMPLE_S, self.SAMPLE_S)
        values = np.empty((len(t), 3))
        for start in range(0, len(t), 4096):
            chunk = t[start : start + 4096]
            angle = 2.0 * np.pi * frequency_hz[:, None, :] * chunk[None, :, None] + phase[:, None, :]
            values[start : start + 4096] = (amplitude[:, None] * np.sin(angle).sum(axis=2)).T
        self._spline = CubicSpline(t, values, axis=0)

    def at(self, t_s: np.ndarray) -> np.ndarray:
        """(3, N) pitch, roll, heave at route times ``t_s``."""
        return self._spline(t_s).T


@dataclass(frozen=True, slots=True)
class RevisitPair:
    """A scan that comes back to where an earlier scan was.

    Attributes:
        query_index: index of the later scan.
        match_index: index of the nearest earlier scan at least ``min_gap_s`` older.
        query_stamp_ns: stamp of the later scan.
        match_stamp_ns: stamp of the earlier scan.
        distance_m: 3-D distance between the two lidar positions.
        heading_change_deg: absolute heading difference (about 180 for an opposite-direction pass).
        query_position_m: (3,) lidar position of the later scan, world frame.
        match_position_m: (3,) lidar position of the earlier scan, world frame.
    """

    query_index: int
    match_index: int
    query_stamp_ns: int
    match_stamp_ns: int
    distance_m: float
    heading_change_deg: float
    query_position_m: tuple[float, float, float]
    match_position_m: tuple[float, float, float]


def _xyz(position: np.ndarray) -> tuple[float, float, float]:
    """A (3,) position as a tuple of floats."""
    x, y, z = (float(v) for v in position)
    return x, y, z


def find_revisits(
    stamps_ns: np.ndarray,
    T_world_lidar: np.ndarray,
    *,
    radius_m: float = 5.0,
    min_gap_s: float = 30.0,
) -> list[RevisitPair]:
    """Every scan within ``radius_m`` of a scan at least ``min_gap_s`` older, with its nearest such scan."""
    positions = T_world_lidar[:, :3, 3]
    headings = np.arctan2(T_world_lidar[:, 1, 0], T_world_lidar[:, 0, 0])  # lidar x axis, world yaw
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    pairs = []
    gap_ns = int(round(min_gap_s * 1e9))
    for i in range(len(stamps)):
        older = np.flatnonzero(stamps <= stamps[i] - gap_ns)
        if older.size == 0:
            continue
        distance = np.linalg.norm(positions[older] - positions[i], axis=1)
        best = int(np.argmin(distance))
        if distance[best] > radius_m:
            continue
        j = int(older[best])
        change = np.rad2deg(np.abs(np.angle(np.exp(1j * (headings[i] - headings[j])))))
        pairs.append(
            RevisitPair(
                query_index=i,
                match_index=j,
                query_stamp_ns=int(stamps[i]),
                match_stamp_ns=int(stamps[j]),
                distance_m=float(distance[best]),
                heading_change_deg=float(change),
                query_position_m=_xyz(positions[i]),
                match_position_m=_xyz(positions[j]),
            )
        )
    return pairs


def group_revisits(pairs: list[RevisitPair], max_index_gap: int = 5) -> list[list[RevisitPair]]:
    """Split revisit pairs into events: runs of query scans no more than ``max_index_gap`` apart whose
    matches also stay close in index (one continuous pass over an earlier stretch)."""
    events: list[list[RevisitPair]] = []
    for pair in pairs:
        if events:
            last = events[-1][-1]
            if (
                pair.query_index - last.query_index <= max_index_gap
                and abs(pair.match_index - last.match_index) <= 4 * max_index_gap
            ):
                events[-1].append(pair)
                continue
        events.append([pair])
    return events
