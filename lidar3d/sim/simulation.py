"""A simulated drive: world, vehicle motion, rig and lidar put together, scans generated on demand.

Typical use from Python (nothing is written to disk)::

    from lidar3d.sim import Simulation
    sim = Simulation("loop", seed=0, duration_s=10.0)          # vlp16 by default
    for s in sim.scans():                                       # SimulatedScan, lazily
        s.scan            # lidar3d.records.Scan, exactly what the bag holds
        s.object_id       # (N,) what each point hit, 0 = ground
        s.object_class    # (N,) ObjectClass of that object
        s.dynamic_mask    # (N,) on a moving car or a pedestrian
    sim.ground_truth      # Trajectory of the lidar at every scan stamp
    sim.T_world_lidar_at(stamps_ns)  # true pose at any time, e.g. per point for deskewing checks

Stamps: sweep ``k`` starts ``k`` scan periods after ``start_time_ns``. The header stamp written
(``stamps_ns``) is that sweep start, or the firing time of the sweep's last column with
:attr:`StampMode.SWEEP_END`, plus the stamp jitter if any; the ground truth is always the true
lidar pose at the header stamp, whatever it marks. With jitter, the route starts ``stamp_jitter_s``
before the first sweep, so that every stamp lies within the drive.

Every random draw is seeded from ``(seed, purpose, index)``, so a scan does not depend on which other
scans were generated, nor in which order: the same scenario and seed give the same data.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Iterator

import numpy as np

from lidar3d.errors import SimulationError
from lidar3d.records import Trajectory
from lidar3d.sensors import SensorModel, sensor_model
from lidar3d.sim.actors import Traffic
from lidar3d.sim.lidar import LidarParams, LidarSimulator, SimulatedScan, StampMode
from lidar3d.sim.rig import RigParams
from lidar3d.sim.scenarios import DEFAULT_SCENARIO, Scenario, get_scenario
from lidar3d.sim.span import SpanParams, degraded_window_ns, span_log_lines
from lidar3d.sim.trajectory import RevisitPair, VehicleMotion, find_revisits
from lidar3d.sim.world import generate_world

__all__ = ["DEFAULT_START_TIME_NS", "Simulation"]

logger = logging.getLogger(__name__)

DEFAULT_START_TIME_NS = 1_715_677_200 * 1_000_000_000  # 2024-05-14T09:00:00Z
_SCAN_STREAM = 0x5CA9
_STAMP_STREAM = 0x57A3


class Simulation:
    """A drive through a procedural world.

    Args:
        scenario: a name from :data:`lidar3d.sim.SCENARIOS` or a :class:`Scenario`.
        seed: seeds the world, the measurement noise and the GNSS errors.
        duration_s: simulate only the first ``duration_s`` seconds (default: the whole route).
        sensor: a sensor preset name (``vlp16``, ``hdl32e``, ``vlp32c``) or a :class:`SensorModel`.
        lidar: measurement model (default: the scenario's).
        span: simulated SPAN receiver.
        rig: lidar and antenna mounting on the vehicle.
        start_time_ns: UNIX time (UTC) of the first sweep.

    Raises:
        SimulationError: unknown scenario or sensor, or a duration outside the route.
    """

    def __init__(
        self,
        scenario: str | Scenario = DEFAULT_SCENARIO,
        *,
        seed: int = 0,
        duration_s: float | None = None,
        sensor: str | SensorModel = "vlp16",
        lidar: LidarParams | None = None,
        span: SpanParams | None = None,
        rig: RigParams | None = None,
        start_time_ns: int = DEFAULT_START_TIME_NS,
    ) -> None:
        self.scenario = get_scenario(scenario) if isinstance(scenario, str) else scenario
        if isinstance(sensor, str):
            try:
                sensor = sensor_model(sensor)
            except KeyError as err:
                raise SimulationError(str(err.args[0])) from None
        self.sensor: SensorModel = sensor
        self.seed = int(seed)
        self.lidar_params = lidar or self.scenario.lidar
        self.span_params = span or SpanParams()
        self.rig = rig or RigParams()
        self.start_time_ns = int(start_time_ns)
        self.world = generate_world(self.scenario.layout, self.scenario.world, self.seed)
        self.motion = VehicleMotion(self.scenario.route_m, self.world.terrain, self.scenario.route, self.seed)
        self.traffic: Traffic | None = None
        if self.scenario.traffic.any:
            first_actor_id = len(self.world.object_class)
            self.traffic = Traffic(self.motion, self.world.terrain, self.scenario.traffic, self.seed, first_actor_id)
        self.scan_period_ns = int(round(1e9 / self.sensor.rotation_hz))
        jitter_s = self.lidar_params.stamp_jitter_s
        self._route_lead_s = jitter_s  # route time of the first sweep start
        available_s = self.motion.duration_s
        if duration_s is None:
            duration_s = available_s
        elif not 0.0 < duration_s <= available_s + 1e-9:
            raise SimulationError(
                f"scenario {self.scenario.name!r} lasts {available_s:.1f} s; duration must be in (0, {available_s:.1f}]"
            )
        # Every sweep must end within the route; integer nanoseconds avoid float floor surprises.
        n_scans = int(round(min(duration_s, available_s - 2.0 * jitter_s) * 1e9)) // self.scan_period_ns
        if n_scans < 1:
            raise SimulationError(f"duration {duration_s} s is shorter than one sweep ({self.scan_period_ns / 1e9} s)")
        self.sweep_start_ns = self.start_time_ns + self.scan_period_ns * np.arange(n_scans, dtype=np.int64)
        self.sweep_start_ns.flags.writeable = False
        self.stamps_ns = self.sweep_start_ns + self._stamp_offsets_ns(n_scans)
        self.stamps_ns.flags.writeable = False
        self.T_imu_lidar = self.rig.T_imu_lidar
        self.T_imu_lidar.flags.writeable = False
        self._lidar: LidarSimulator | None = None

    def __len__(self) -> int:
        return int(len(self.stamps_ns))

    @property
    def duration_s(self) -> float:
        """Time from the first sweep's start to the last sweep's end."""
        return len(self) * self.scan_period_ns * 1e-9

    def _stamp_offsets_ns(self, n_scans: int) -> np.ndarray:
        """(n_scans,) header stamp minus sweep start: the sweep-end offset and the jitter."""
        period_s = self.sensor.sweep_period_s
        last_column_s = (self.sensor.n_columns - 1) * (period_s / self.sensor.n_columns)
        end_ns = int(round(last_column_s * 1e9)) if self.lidar_params.stamp == StampMode.SWEEP_END else 0
        jitter_s = self.lidar_params.stamp_jitter_s
        if jitter_s == 0.0:
            return np.full(n_scans, end_ns, dtype=np.int64)
        jitter = np.random.default_rng([self.seed, _STAMP_STREAM]).uniform(-jitter_s, jitter_s, n_scans)
        return end_ns + np.rint(jitter * 1e9).astype(np.int64)

    def route_seconds(self, stamps_ns) -> np.ndarray:
        """(N,) route time (seconds since the route start, the time base of :attr:`motion`) of UNIX times in ns."""
        return (np.atleast_1d(np.asarray(stamps_ns, dtype=np.int64)) - self.start_time_ns) * 1e-9 + self._route_lead_s

    def T_world_imu_at(self, stamps_ns) -> np.ndarray:
        """(N, 4, 4) true IMU (SPAN vehicle frame) poses at UNIX times in nanoseconds."""
        return self.motion.pose_at(self.route_seconds(stamps_ns))

    def T_world_lidar_at(self, stamps_ns) -> np.ndarray:
        """(N, 4, 4) true lidar poses at UNIX times in nanoseconds (any time within the drive)."""
        return self.T_world_imu_at(stamps_ns) @ self.T_imu_lidar

    @functools.cached_property
    def ground_truth(self) -> Trajectory:
        """The true lidar pose at every header stamp (see the module docstring for what a stamp marks)."""
        return Trajectory(self.stamps_ns, self.T_world_lidar_at(self.stamps_ns))

    @property
    def lidar(self) -> LidarSimulator:
        """The ray caster (built on first use: it loads Open3D and the scene)."""
        if self._lidar is None:
            actor_classes = None if self.traffic is None else self.traffic.object_class
            self._lidar = LidarSimulator(self.world, self.sensor, self.lidar_params, self.seed, actor_classes)
        return self._lidar

    def scan(self, index: int) -> SimulatedScan:
        """Simulate sweep ``index`` (0-based; negative counts from the end)."""
        n = len(self)
        if not -n <= index < n:
            raise SimulationError(f"scan index {index} out of range for {n} scans")
        index %= n
        lidar = self.lidar
        t_s = index * self.scan_period_ns * 1e-9 + self._route_lead_s + lidar.column_time_s
        poses = self.motion.pose_at(t_s) @ self.T_imu_lidar
        rng = np.random.default_rng([self.seed, _SCAN_STREAM, index])
        stamp_ns = int(self.stamps_ns[index])
        actors = None if self.traffic is None else self.traffic.posed_at(t_s, poses[:, :3, 3], lidar.max_range_m)
        return lidar.cast(index, stamp_ns, poses, rng, self.T_world_lidar_at(stamp_ns)[0], actors)

    def points_world(self, simulated: SimulatedScan) -> np.ndarray:
        """(N,3) the points of ``simulated`` placed exactly in the world frame: each with the true
        lidar pose at its column's firing time (the oracle of a map built from exact poses)."""
        lidar = self.lidar
        t_s = simulated.index * self.scan_period_ns * 1e-9 + self._route_lead_s + lidar.column_time_s
        poses = (self.motion.pose_at(t_s) @ self.T_imu_lidar)[simulated.column]
        return np.einsum("nij,nj->ni", poses[:, :3, :3], simulated.scan.points) + poses[:, :3, 3]

    def scans(self, start: int = 0, stop: int | None = None) -> Iterator[SimulatedScan]:
        """Simulate sweeps ``start`` to ``stop - 1`` lazily, in order."""
        stop = len(self) if stop is None else min(stop, len(self))
        for index in range(start, stop):
            yield self.scan(index)

    def revisits(self, radius_m: float = 5.0, min_gap_s: float = 30.0) -> list[RevisitPair]:
        """Scans that come within ``radius_m`` of a scan at least ``min_gap_s`` older."""
        gt = self.ground_truth
        return find_revisits(gt.stamps_ns, gt.T_world_lidar, radius_m=radius_m, min_gap_s=min_gap_s)

    def stop_spans_ns(self) -> list[tuple[int, int]]:
        """UNIX (start, end) of every stop of the vehicle that begins within the simulated sweeps."""
        origin_ns = self.start_time_ns - int(round(self._route_lead_s * 1e9))
        end_ns = int(self.sweep_start_ns[-1]) + self.scan_period_ns
        spans = [
            (origin_ns + int(round(a * 1e9)), origin_ns + int(round(b * 1e9))) for a, b in self.motion.stop_intervals_s
        ]
        return [(a, b) for a, b in spans if a < end_ns]

    def span_log_lines(self) -> list[str]:
        """The NovAtel ASCII log (INSPVAXA 20 Hz, BESTPOSA 1 Hz) of the drive, one CR LF line each."""
        lead_s = self._route_lead_s
        return span_log_lines(
            lambda t_s: self.motion.pose_at(t_s + lead_s),
            lambda t_s: self.motion.velocity_at(t_s + lead_s),
            duration_s=self.duration_s,
            start_time_ns=self.start_time_ns,
            imu_to_antenna_m=self.rig.imu_to_antenna_m,
            params=self.span_params,
            seed=self.seed,
        )

    def degraded_gnss_span_ns(self) -> tuple[int, int]:
        """UNIX (start, end) of the stretch where the GNSS solution is degraded."""
        start, end = degraded_window_ns(self.duration_s, self.span_params.degraded_window)
        return self.start_time_ns + start, self.start_time_ns + end
