"""Vehicle motion along a street route, and the places where the route revisits itself.

A route is a polyline of street-grid nodes. Its corners are rounded with circular arcs, the path is
moved ``lane_offset_m`` to the right of the centre line (driving on the right), and a C2 cubic
spline through the result gives position and heading at every instant. The speed follows the
cruise speed, slows for curvature (lateral-acceleration limit) and obeys acceleration and braking
limits; time is integrated along the path and inverted with a monotone (PCHIP) interpolant.

The vehicle frame is the SPAN vehicle/IMU frame (x right, y forward, z up), its origin the IMU. The
vehicle stands on the terrain: its z axis is the terrain normal (roll and pitch come from the slope),
its y axis the path heading projected onto the terrain plane, and the IMU sits ``imu_height_m``
above the ground along the normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline, PchipInterpolator

from lidar3d.errors import SimulationError
from lidar3d.sim.terrain import Terrain

__all__ = ["RevisitPair", "RouteParams", "VehicleMotion", "find_revisits", "group_revisits"]


@dataclass(frozen=True, slots=True)
class RouteParams:
    """How the vehicle drives a route.

    Attributes:
        corner_radius_m: radius of the arcs that round the route's corners (street centre line).
        cruise_speed_mps: speed on straight road.
        min_speed_mps: speed floor (also the speed at the start).
        max_lateral_accel_mps2: curvature speed limit, v <= sqrt(a_lat / curvature).
        max_accel_mps2: acceleration limit.
        max_decel_mps2: braking limit.
        lane_offset_m: distance of the driven path to the right of the street centre line.
        imu_height_m: height of the IMU above the ground.
    """

    corner_radius_m: float = 10.0
    cruise_speed_mps: float = 6.5
    min_speed_mps: float = 2.0
    max_lateral_accel_mps2: float = 2.5
    max_accel_mps2: float = 1.2
    max_decel_mps2: float = 2.0
    lane_offset_m: float = 1.5
    imu_height_m: float = 1.0

    def __post_init__(self) -> None:
        if not 0.0 < self.min_speed_mps <= self.cruise_speed_mps:
            raise SimulationError("route speeds must satisfy 0 < min_speed_mps <= cruise_speed_mps")
        if min(self.max_lateral_accel_mps2, self.max_accel_mps2, self.max_decel_mps2) <= 0.0:
            raise SimulationError("route acceleration limits must be positive")
        if self.corner_radius_m <= abs(self.lane_offset_m):
            raise SimulationError("route corner_radius_m must exceed |lane_offset_m|")


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
    """

    def __init__(self, nodes_m, terrain: Terrain, params: RouteParams) -> None:
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
        v = np.clip(limit, params.min_speed_mps, params.cruise_speed_mps)
        ds = np.diff(u) * 0.5 * (speed_scale[1:] + speed_scale[:-1])
        v[0] = params.min_speed_mps
        for k in range(1, len(v)):  # acceleration limit, forwards
            v[k] = min(v[k], np.sqrt(v[k - 1] ** 2 + 2.0 * params.max_accel_mps2 * ds[k - 1]))
        for k in range(len(v) - 2, -1, -1):  # braking limit, backwards
            v[k] = min(v[k], np.sqrt(v[k + 1] ** 2 + 2.0 * params.max_decel_mps2 * ds[k]))
        self.min_speed_reached_mps = float(v.min())
        self.max_speed_reached_mps = float(v.max())
        dt = ds / (0.5 * (v[1:] + v[:-1]))
        t = np.concatenate([[0.0], np.cumsum(dt)])
        self.duration_s = float(t[-1])
        self._u_of_t = PchipInterpolator(t, u)

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
        return poses

    def velocity_at(self, t_s, dt_s: float = 1e-3) -> np.ndarray:
        """(N, 3) world-frame velocity of the IMU (central difference of :meth:`pose_at`)."""
        t = np.atleast_1d(self._check_times(t_s))
        lo = np.clip(t - dt_s, 0.0, self.duration_s)
        hi = np.clip(t + dt_s, 0.0, self.duration_s)
        return (self.pose_at(hi)[:, :3, 3] - self.pose_at(lo)[:, :3, 3]) / (hi - lo)[:, None]


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
