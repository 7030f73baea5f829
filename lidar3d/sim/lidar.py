"""Ray-cast a spinning multi-beam lidar through a :class:`~lidar3d.sim.world.World` with Open3D.

Firing model: the head turns clockwise seen from above (as Velodyne sensors do), one column of all
beams every ``sweep_period / n_columns`` seconds. Column ``c`` fires at ``c * period / n_columns``
after the sweep start with azimuth ``atan2(y, x) = start_azimuth - 360 deg * c / n_columns`` in the
lidar frame, from the lidar pose *at that instant*: scans carry true motion distortion. Every point
keeps the firing time of its column in ``time_offset_s`` and is expressed in the lidar frame of that
instant, exactly what a real driver delivers.

Returns: Gaussian range noise, a minimum and maximum range, random dropouts, no return at grazing
incidence, and an intensity from the surface's reflectivity and the incidence angle (lane markings
on the road are bright, asphalt dark, verges brighter). Rays that hit nothing are absent. The
caller gets per point the object it hit (0 = ground) and that object's class.

Materials and moving objects (none in a world without them): a ray whose first surface is glass
(``World.triangle_glass``) returns nothing; moving actors (:mod:`~lidar3d.sim.actors`), posed at
each column's firing time, are intersected exactly and win where they are nearer than the world
(also in front of glass). A point on an actor carries the actor's object id and class
(:attr:`SimulatedScan.dynamic_mask`).

Imperfections (all off by default): a per-laser elevation error and range bias drawn once from the
seed; the rays are cast along the TRUE (perturbed) beams while the points are computed from the
measured range with the NOMINAL elevation table, as a driver with a stock calibration does. Dropped
packets: with a probability per sweep, a wedge of consecutive columns has no points. The header
stamp (sweep start or sweep end, with jitter) is made by :class:`~lidar3d.sim.simulation.Simulation`;
per-point times are relative to the true sweep start, or to the true firing time of the sweep's last
column in :attr:`StampMode.SWEEP_END`.

Open3D appears in this module only.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from lidar3d.errors import SimulationError
from lidar3d.records import Scan
from lidar3d.sensors import SensorModel
from lidar3d.sim.actors import PosedActors, cast_actor_rays
from lidar3d.sim.world import DYNAMIC_CLASSES, ObjectClass, World

__all__ = ["LidarParams", "LidarSimulator", "SimulatedScan", "StampMode"]

_CALIBRATION_STREAM = 0xCA1B
_ACTOR_REFLECTIVITY_STREAM = 0xAC70

# Reflectivity ranges (Velodyne calibrated units, 0-100 diffuse) per object class.
_REFLECTIVITY = {
    ObjectClass.BUILDING: (20.0, 70.0),
    ObjectClass.WALL: (15.0, 55.0),
    ObjectClass.FENCE: (30.0, 80.0),
    ObjectClass.POLE: (40.0, 90.0),
    ObjectClass.TREE: (10.0, 40.0),
    ObjectClass.CAR: (5.0, 100.0),
}
_ACTOR_REFLECTIVITY = {ObjectClass.MOVING_CAR: (5.0, 100.0), ObjectClass.PEDESTRIAN: (10.0, 50.0)}
_ASPHALT, _VERGE, _MARKING = 10.0, 35.0, 110.0


class StampMode(str, Enum):
    """What a sweep's header stamp marks.

    ``sweep_start``: the firing time of the first column; per-point times 0..T after it (the
    velodyne_pointcloud layout lidar3d expects). ``sweep_end``: the firing time of the last column
    (the last point's time, as the stock ROS velodyne driver stamps a sweep with its last packet);
    per-point times -T..0 relative to it.
    """

    SWEEP_START = "sweep_start"
    SWEEP_END = "sweep_end"


@dataclass(frozen=True, slots=True)
class LidarParams:
    """Measurement model of the simulated lidar.

    Attributes:
        range_noise_sigma_m: standard deviation of the Gaussian range noise.
        min_range_m: returns nearer than this are dropped.
        max_range_m: returns farther than this are dropped (0: the sensor model's rated range).
        dropout_probability: chance that any return is lost.
        max_incidence_deg: no return when the beam meets a surface more obliquely than this.
        start_azimuth_deg: ``atan2(y, x)`` of the first column of a sweep (180: pointing backwards).
        intensity_noise_sigma: standard deviation of the intensity noise (sensor units).
        elevation_error_sigma_deg: standard deviation of the per-laser elevation error (the true
            beam is the nominal one tilted by the error; points are computed with the nominal table).
        range_bias_sigma_m: standard deviation of the per-laser range bias (added to every range).
        stamp_jitter_s: header stamps are off by a uniform error in [-jitter, +jitter] (a jittery
            driver clock); point times stay relative to the true sweep start (or end), so they are
            off by the same error relative to the stamp.
        dropped_wedge_probability: chance per sweep that one packet's wedge of columns is lost.
        dropped_wedge_deg: azimuth width of a lost wedge (4.8: one VLP-16 packet at 10 Hz).
        stamp: what the header stamp marks (:class:`StampMode`).
    """

    range_noise_sigma_m: float = 0.02
    min_range_m: float = 0.5
    max_range_m: float = 0.0
    dropout_probability: float = 0.005
    max_incidence_deg: float = 88.0
    start_azimuth_deg: float = 180.0
    intensity_noise_sigma: float = 1.5
    elevation_error_sigma_deg: float = 0.0
    range_bias_sigma_m: float = 0.0
    stamp_jitter_s: float = 0.0
    dropped_wedge_probability: float = 0.0
    dropped_wedge_deg: float = 4.8
    stamp: StampMode = StampMode.SWEEP_START

    def __post_init__(self) -> None:
        if self.range_noise_sigma_m < 0.0 or not 0.0 <= self.dropout_probability < 1.0:
            raise SimulationError("lidar range_noise_sigma_m must be >= 0 and dropout_probability in [0, 1)")
        if self.min_range_m < 0.0 or self.max_range_m < 0.0:
            raise SimulationError("lidar min_range_m and max_range_m must be >= 0")
        if not 0.0 < self.max_incidence_deg <= 90.0:
            raise SimulationError("lidar max_incidence_deg must be in (0, 90]")
        if min(self.elevation_error_sigma_deg, self.range_bias_sigma_m) < 0.0 or not 0.0 <= self.stamp_jitter_s < 0.01:
            raise SimulationError("lidar calibration sigmas must be >= 0 and stamp_jitter_s in [0, 0.01) s")
        if not 0.0 <= self.dropped_wedge_probability <= 1.0 or not 0.0 < self.dropped_wedge_deg < 360.0:
            raise SimulationError("lidar dropped_wedge_probability must be in [0, 1] and dropped_wedge_deg in (0, 360)")
        if self.stamp not in [mode.value for mode in StampMode]:
            known = ", ".join(mode.value for mode in StampMode)
            raise SimulationError(f"lidar stamp must be one of: {known}; got {self.stamp!r}")


@dataclass(frozen=True, slots=True)
class SimulatedScan:
    """One simulated sweep with what each point hit.

    Attributes:
        index: scan index within the simulation.
        scan: the sweep as a real driver gives it (lidar frame at each point's firing time).
        object_id: (N,) int32 id of the object each point hit; 0 is the ground
            (see :class:`~lidar3d.sim.world.World` for the objects; ids after the world's are the
            moving actors of :class:`~lidar3d.sim.actors.Traffic`).
        object_class: (N,) uint8 :class:`~lidar3d.sim.world.ObjectClass` of that object.
        column: (N,) uint16 firing column (0 = first of the sweep).
        T_world_lidar: (4, 4) true lidar pose at the scan's header stamp.
    """

    index: int
    scan: Scan
    object_id: np.ndarray
    object_class: np.ndarray
    column: np.ndarray
    T_world_lidar: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.scan)
        for name in ("object_id", "object_class", "column"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"SimulatedScan.{name} must be ({n},)")
        if self.T_world_lidar.shape != (4, 4):
            raise ValueError("SimulatedScan.T_world_lidar must be (4, 4)")
        for name in ("object_id", "object_class", "column", "T_world_lidar"):
            getattr(self, name).flags.writeable = False

    @property
    def ground_mask(self) -> np.ndarray:
        """(N,) bool: the point lies on the ground."""
        return self.object_id == 0

    @property
    def dynamic_mask(self) -> np.ndarray:
        """(N,) bool: the point lies on a moving object (a moving car or a pedestrian)."""
        return np.isin(self.object_class, [int(c) for c in DYNAMIC_CLASSES])


class LidarSimulator:
    """Casts the sensor's beams through ``world``.

    Args:
        world: the scene.
        sensor: beam elevations, columns and rotation rate.
        params: measurement model.
        seed: seeds the per-object reflectivities and the per-laser calibration errors.
        actor_classes: (A,) :class:`ObjectClass` of the moving actors, whose object ids follow the
            world's objects (None: no actors).

    Attributes:
        directions_lidar: (n_columns, n_rings, 3) nominal unit beams (the points are computed with these).
        true_directions_lidar: (n_columns, n_rings, 3) the beams the rays are cast along.
        elevation_error_rad: (n_rings,) true minus nominal elevation per laser.
        range_bias_m: (n_rings,) range bias per laser.
        column_time_s: (n_columns,) firing time of each column after the sweep start.
        time_reference_s: instant the per-point times are relative to, after the sweep start
            (0, or the last column's firing time in sweep-end mode).
    """

    def __init__(
        self, world: World, sensor: SensorModel, params: LidarParams, seed: int, actor_classes: np.ndarray | None = None
    ) -> None:
        import open3d as o3d

        self.world = world
        self.sensor = sensor
        self.params = params
        self.max_range_m = params.max_range_m or sensor.max_range_m
        self._o3d = o3d
        self._scene = o3d.t.geometry.RaycastingScene()
        # Open3D's stubs leave out the defaults of Tensor(np_array, dtype, device): hence the type ignores.
        self._scene.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(world.vertices_m, dtype=np.float32)),  # type: ignore[call-overload]
            o3d.core.Tensor(np.ascontiguousarray(world.triangles, dtype=np.uint32)),  # type: ignore[call-overload]
        )
        rng = np.random.default_rng([int(seed), 0x4EF1])
        reflectivity = np.full(len(world.object_class), _VERGE)
        for object_class, (lo, hi) in _REFLECTIVITY.items():
            ids = world.object_ids_of(object_class)
            reflectivity[ids] = rng.uniform(lo, hi, size=len(ids))
        self._reflectivity = reflectivity
        self._object_class = world.object_class
        if actor_classes is not None and len(actor_classes):
            actor_rng = np.random.default_rng([int(seed), _ACTOR_REFLECTIVITY_STREAM])
            ranges = np.array([_ACTOR_REFLECTIVITY[ObjectClass(c)] for c in actor_classes])
            self._reflectivity = np.concatenate([reflectivity, actor_rng.uniform(ranges[:, 0], ranges[:, 1])])
            self._object_class = np.concatenate([world.object_class, np.asarray(actor_classes, dtype=np.uint8)])
        self._has_glass = bool(np.any(world.triangle_glass))
        n_columns, n_rings = sensor.n_columns, sensor.n_rings
        azimuth = np.deg2rad(params.start_azimuth_deg) - 2.0 * np.pi * np.arange(n_columns) / n_columns
        calibration = np.random.default_rng([int(seed), _CALIBRATION_STREAM])
        self.elevation_error_rad = calibration.normal(0.0, np.deg2rad(params.elevation_error_sigma_deg), n_rings)
        self.range_bias_m = calibration.normal(0.0, params.range_bias_sigma_m, n_rings)
        self.directions_lidar = _beam_directions(azimuth, sensor.elevation_rad)
        self.true_directions_lidar = _beam_directions(azimuth, sensor.elevation_rad + self.elevation_error_rad)
        self.column_time_s = np.arange(n_columns) * (sensor.sweep_period_s / n_columns)
        self.time_reference_s = float(self.column_time_s[-1]) if params.stamp == StampMode.SWEEP_END else 0.0

    def cast(
        self,
        index: int,
        stamp_ns: int,
        T_world_lidar_columns: np.ndarray,
        rng: np.random.Generator,
        T_world_lidar_stamp: np.ndarray,
        actors: PosedActors | None = None,
    ) -> SimulatedScan:
        """Simulate one sweep.

        Args:
            index: scan index (kept in the result).
            stamp_ns: the header stamp to write.
            T_world_lidar_columns: (n_columns, 4, 4) lidar pose at each column's firing time.
            rng: source of all randomness of this sweep.
            T_world_lidar_stamp: (4, 4) true lidar pose at ``stamp_ns`` (kept in the result).
            actors: the moving actors near the sensor, posed at each column's time (None: none).
        """
        n_columns, n_rings = self.sensor.n_columns, self.sensor.n_rings
        if T_world_lidar_columns.shape != (n_columns, 4, 4):
            raise SimulationError(f"need ({n_columns}, 4, 4) column poses, got {T_world_lidar_columns.shape}")
        rotation = T_world_lidar_columns[:, :3, :3]
        origin = T_world_lidar_columns[:, :3, 3]
        directions_world = self.true_directions_lidar @ rotation.transpose(0, 2, 1)  # (c, r, 3): R_c d_cr
        rays = np.empty((n_columns, n_rings, 6), dtype=np.float32)
        rays[:, :, :3] = origin[:, None, :]
        rays[:, :, 3:] = directions_world
        result = self._scene.cast_rays(self._o3d.core.Tensor(rays.reshape(-1, 6)))  # type: ignore[call-overload]
        t_hit = result["t_hit"].numpy()
        hit = np.flatnonzero(np.isfinite(t_hit))
        triangle = result["primitive_ids"].numpy()[hit]
        normals = result["primitive_normals"].numpy()[hit].astype(np.float64)
        object_id = self.world.triangle_object_id[triangle]
        if self._has_glass or actors is not None:
            t_hit, hit, normals, object_id = self._glass_and_actors(
                t_hit, hit, triangle, normals, object_id, origin, directions_world, actors
            )
        directions = directions_world.reshape(-1, 3)[hit]
        cos_incidence = np.abs(np.sum(normals * directions, axis=1))

        n = len(hit)
        range_m = t_hit[hit].astype(np.float64) + rng.normal(0.0, self.params.range_noise_sigma_m, n)
        range_m += self.range_bias_m[hit % n_rings]
        keep = (
            (range_m >= self.params.min_range_m)
            & (range_m <= self.max_range_m)
            & (cos_incidence >= np.cos(np.deg2rad(self.params.max_incidence_deg)))
            & (rng.random(n) >= self.params.dropout_probability)
        )
        reflectivity = self._reflectivity[object_id]
        ground = object_id == 0
        if np.any(ground):
            hit_world = (origin.repeat(n_rings, axis=0)[hit] + directions * t_hit[hit, None])[ground]
            reflectivity[ground] = self._ground_reflectivity(hit_world[:, 0], hit_world[:, 1])
        falloff = 1.0 - 0.3 * np.clip(range_m / self.max_range_m, 0.0, 1.0)
        intensity = reflectivity * (0.2 + 0.8 * cos_incidence) * falloff
        intensity += rng.normal(0.0, self.params.intensity_noise_sigma, n)
        intensity = np.clip(np.rint(intensity), 0.0, 255.0)

        if self.params.dropped_wedge_probability > 0.0 and rng.random() < self.params.dropped_wedge_probability:
            width = max(1, int(round(self.params.dropped_wedge_deg / 360.0 * n_columns)))
            lost = np.mod(rng.integers(n_columns) + np.arange(width), n_columns)
            keep &= ~np.isin(hit // n_rings, lost)
        keep_idx = np.flatnonzero(keep)
        flat = hit[keep_idx]
        column = flat // n_rings
        ring = flat % n_rings
        points = self.directions_lidar.reshape(-1, 3)[flat] * range_m[keep_idx, None]
        scan = Scan(
            stamp_ns=stamp_ns,
            points=points,
            intensity=intensity[keep_idx],
            ring=ring,
            time_offset_s=self.column_time_s[column] - self.time_reference_s,
        )
        kept_ids = object_id[keep_idx].astype(np.int32)
        return SimulatedScan(
            index=index,
            scan=scan,
            object_id=kept_ids,
            object_class=self._object_class[kept_ids],
            column=column.astype(np.uint16),
            T_world_lidar=np.array(T_world_lidar_stamp, dtype=float),
        )

    def _glass_and_actors(
        self,
        t_hit: np.ndarray,
        hit: np.ndarray,
        triangle: np.ndarray,
        normals: np.ndarray,
        object_id: np.ndarray,
        origin: np.ndarray,
        directions_world: np.ndarray,
        actors: PosedActors | None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The returns once glass absorbs its rays and nearer actors hide the world.

        Returns the per-ray distances (all rays, float32 as the scene's; inf: nothing) and, per
        returning ray in ascending ray order, its index, normal (float64) and object id.
        """
        n_rays = len(t_hit)
        t_all = np.array(t_hit, dtype=np.float32)
        normal_all = np.zeros((n_rays, 3))
        normal_all[hit] = normals
        id_all = np.full(n_rays, -1, dtype=np.int32)
        id_all[hit] = object_id
        if actors is not None:
            t_actor, normal_actor, id_actor = cast_actor_rays(origin, directions_world, actors)
            nearer = t_actor < t_all  # also in front of glass, which stays opaque to what lies behind it
            t_all[nearer] = t_actor[nearer]
            normal_all[nearer] = normal_actor[nearer]
            id_all[nearer] = id_actor[nearer]
        else:
            nearer = np.zeros(n_rays, dtype=bool)
        if self._has_glass:
            glass = np.zeros(n_rays, dtype=bool)
            glass[hit] = self.world.triangle_glass[triangle]
            t_all[glass & ~nearer] = np.inf
        returning = np.flatnonzero(np.isfinite(t_all))
        return t_all, returning, normal_all[returning], id_all[returning]

    def _ground_reflectivity(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Asphalt on the road, a dashed bright centre line, brighter verges elsewhere."""
        layout = self.world.layout
        dx = np.min(np.abs(x[:, None] - np.asarray(layout.street_x_m)[None, :]), axis=1)
        dy = np.min(np.abs(y[:, None] - np.asarray(layout.street_y_m)[None, :]), axis=1)
        half = layout.road_half_width_m
        on_road = (dx < half) | (dy < half)
        marking = ((dx < 0.08) & (dy > half) & (np.mod(y, 9.0) < 3.0)) | (
            (dy < 0.08) & (dx > half) & (np.mod(x, 9.0) < 3.0)
        )
        return np.where(marking, _MARKING, np.where(on_road, _ASPHALT, _VERGE))


def _beam_directions(azimuth_rad: np.ndarray, elevation_rad: np.ndarray) -> np.ndarray:
    """(n_columns, n_rings, 3) unit beam directions in the lidar frame, column-major firing order."""
    cos_el = np.cos(elevation_rad)
    return np.stack(
        [
            np.cos(azimuth_rad)[:, None] * cos_el[None, :],
            np.sin(azimuth_rad)[:, None] * cos_el[None, :],
            np.broadcast_to(np.sin(elevation_rad)[None, :], (len(azimuth_rad), len(elevation_rad))),
        ],
        axis=-1,
    )
