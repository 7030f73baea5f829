"""Points on moving objects, kept out of the registration: where recent keyframes' rays saw through.

A car that drives behind the vehicle in its lane at the vehicle's own speed looks parked to the
sensor. Its faces across the lane are planes like any wall's, and in a street whose walls run
along it they are the only structure that fixes the along-street position: the registration then
holds the vehicle to where the car was (measured on ``city_traffic``: 12-20 % of the speed lost over
the canyon and 75 scans after it, with the registration reporting its pose to 3 mm). The dense map
removes such points a window of sweeps later (:mod:`lidar3d.mapping.free_space`); the tracker needs
them gone before it registers.

The test is the dense map's free-space evidence (:func:`~lidar3d.mapping.free_space.voxel_evidence`),
asked of the last ``mapping.moving_probe_keyframes`` keyframes: each keeps a range image of its
deskewed features (a :class:`~lidar3d.mapping.free_space.SweepProbe`), and a point of the current
sweep, placed at the motion model's prediction, is *moving* when at least ``dynamic.min_misses`` of
those keyframes' rays passed it and returned beyond it (by ``dynamic.range_margin_m`` and the
surface's grazing slack), by ``dynamic.miss_ratio`` times as many as returned at it. The space a
moving object now fills was seen empty a keyframe ago; a static surface was seen where it is (a
hit), or was hidden (no evidence). What the test cannot see: an object moving away from the
sensor fills space that its own back hid (a lead car pulling away); new structure at the edge of
the view has no evidence and is kept. Ground points are never tested (rays skim the road).

The guess is uncertain, and the test allows for it (:meth:`MovingPoints.note_pose_covariance`),
so that a guess off by what its uncertainty allows does not take the structure that would correct
it for a moving object: a ray sees through a point only when it returns beyond it by the margin
plus three of the largest translation sigmas of the pose's uncertainty, and only beyond the
grazing slack of the surface it hit, taken with the angular error ``dynamic.pose_angle_deg`` plus
three of the largest rotation sigmas of the guess. That rotation uncertainty is the pose's relative
to the map plus one step of the vehicle model (its bounded yaw and tilt accelerations): a turn's
onset, which a prediction cannot expect, turns the whole sweep by up to that much, and a far wall
turned by it lands where a keyframe's ray went on. And a ray sees through a point only when the
rays around it went beyond it too (a :class:`~lidar3d.mapping.free_space.ProbeStack` with the
neighbourhood): at an object's silhouette the ray that just missed the object passes its edge
points.

Off by default (``moving_probe_keyframes`` = 0): over the evaluation suite it makes some drives
much better and others much worse (docs/stages/odometry-mapping.md#moving-objects).

Frames: the sweep's points in its deskewed lidar frame at the stamp; poses ``T_world_lidar``.
After a loop closure the keyframes moved, so the probes are dropped and gathered again.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from lidar3d.config import Config, DynamicConfig
from lidar3d.mapping.free_space import ProbeStack, SweepProbe, voxel_evidence
from lidar3d.mapping.registration import largest_variance
from lidar3d.mapping.sweep import SweepFeatures

__all__ = ["MovingPoints"]

# The grazing slack's angle is capped short of 90 degrees, whose tangent would turn it round: at
# 89 degrees a ray must return some 57 times the point's range beyond it, which no ray does.
_MAX_SLACK_ANGLE_DEG = 89.0


class MovingPoints:
    """The range images of the latest keyframes, and the test of a sweep's points against them.

    Args:
        config: the ``[dynamic]`` section (tolerances and vote of the free-space evidence).
        elevation_deg: the sensor's ascending beam elevations (index = ring).
        n_columns: azimuth cells per sweep (the images' columns).
        n_keyframes: keyframes whose images are kept (the oldest is replaced).
    """

    def __init__(
        self, config: DynamicConfig, elevation_deg: tuple[float, ...], n_columns: int, n_keyframes: int
    ) -> None:
        self.config = config
        self._elevation_rad = np.deg2rad(np.asarray(elevation_deg, dtype=np.float64))
        self._n_bins = int(n_columns)
        self._stack = ProbeStack(n_keyframes, len(self._elevation_rad), self._n_bins, neighbourhood=True)
        self._n_slots = int(n_keyframes)
        self._n_added = 0
        self._returns: SweepFeatures | None = None  # the latest sweep, deskewed, nothing removed
        self._pose_sigma_m = 0.0
        self._angle_sigma_rad = 0.0

    @classmethod
    def of_config(cls, config: Config) -> MovingPoints | None:
        """The test a run's configuration asks for (None when ``mapping.moving_probe_keyframes`` is 0)."""
        n_keyframes = config.mapping.moving_probe_keyframes
        if n_keyframes <= 0:
            return None
        model = config.sensor.resolved_model
        return cls(config.dynamic, model.elevation_deg, model.n_columns, n_keyframes)

    def __len__(self) -> int:
        """Keyframe images held."""
        return min(self._n_added, self._n_slots)

    def add_keyframe(self, T_world_lidar: np.ndarray) -> None:
        """The sweep last passed to :meth:`without_moving` is a keyframe at pose (4,4)
        ``T_world_lidar``: keep the range image of all its returns (moving ones too: they are where
        its rays ended), its registration clouds and coarse-ground cloud in its deskewed lidar frame."""
        if self._returns is None:
            return
        f = self._returns.features
        clouds = (f.less_sharp, f.less_flat, f.outliers, self._returns.coarse_ground)
        points = np.concatenate([c.points for c in clouds])
        rings = np.concatenate([c.ring for c in clouds])
        probe = SweepProbe.of_points(points, rings, T_world_lidar, len(self._elevation_rad), self._n_bins)
        self._stack.put(self._n_added % self._n_slots, probe)
        self._n_added += 1

    def note_pose_covariance(self, covariance: np.ndarray | None, step_rotation_variance_rad2: float = 0.0) -> None:
        """How uncertain the guess of the next sweep is: the latest pose's (6,6) ``covariance``
        relative to the map (tangent ``[w, v]``, lidar frame;
        :class:`~lidar3d.mapping.pose_uncertainty.PoseUncertainty`; None: unknown) and the largest
        rotation variance of the vehicle model over one scan (rad^2: its prior of the scan just
        tracked, :meth:`~lidar3d.mapping.registration.PosePrior.rotation_variance_rad2`, the next
        one's differs little; 0: no vehicle model yet). A ray then sees through a point only beyond
        three of the largest translation sigmas more than the margin, and beyond the grazing slack
        of ``dynamic.pose_angle_deg`` plus three rotation sigmas, sqrt(largest pose variance + step
        variance) (at most :data:`_MAX_SLACK_ANGLE_DEG`: a guess that uncertain tells nothing
        moving)."""
        if covariance is None or not np.isfinite(covariance).all():
            self._pose_sigma_m = 0.0
            self._angle_sigma_rad = float(np.sqrt(step_rotation_variance_rad2))
            return
        self._pose_sigma_m = float(np.sqrt(largest_variance(covariance[3:, 3:])))
        self._angle_sigma_rad = float(np.sqrt(largest_variance(covariance[:3, :3]) + step_rotation_variance_rad2))

    def clear(self) -> None:
        """Forget the images (the keyframes moved: a loop closure)."""
        self._n_added = 0

    def moving(self, points_lidar: np.ndarray, T_world_lidar: np.ndarray) -> np.ndarray:
        """(N,) bool: which of the (N,3) lidar-frame points, placed at pose (4,4) ``T_world_lidar``,
        lie where the kept keyframes saw through (all False while fewer than ``min_misses`` are
        kept)."""
        n = len(points_lidar)
        if n == 0 or len(self) < self.config.min_misses:
            return np.zeros(n, bool)
        world = np.asarray(points_lidar, dtype=np.float64) @ T_world_lidar[:3, :3].T + T_world_lidar[:3, 3]
        config = dataclasses.replace(
            self.config,
            range_margin_m=self.config.range_margin_m + 3.0 * self._pose_sigma_m,
            pose_angle_deg=min(
                self.config.pose_angle_deg + 3.0 * float(np.degrees(self._angle_sigma_rad)), _MAX_SLACK_ANGLE_DEG
            ),
        )
        slots = np.arange(len(self))
        hits, misses = voxel_evidence(world, self._stack, slots, self._elevation_rad, config)
        return (misses >= self.config.min_misses) & (misses >= self.config.miss_ratio * hits)

    def without_moving(
        self, sweep: SweepFeatures, deskewed: SweepFeatures, T_world_guess: np.ndarray | None
    ) -> tuple[SweepFeatures, SweepFeatures]:
        """The sweep, as fired and ``deskewed``, without the feature points (every cloud but the
        coarse-ground one) that are :meth:`moving` when placed at the (4,4) guess ``T_world_guess`` (None:
        the first sweep, nothing to test against); the sweep is remembered for :meth:`add_keyframe`."""
        self._returns = deskewed
        if T_world_guess is None:
            return sweep, deskewed
        f = deskewed.features
        names = ("sharp", "less_sharp", "flat", "less_flat", "outliers")
        clouds = [getattr(f, name).points for name in names]
        flags = self.moving(np.concatenate(clouds), T_world_guess)  # one pass over the probes
        if not flags.any():
            return sweep, deskewed
        moving = dict(zip(names, np.split(flags, np.cumsum([len(c) for c in clouds])[:-1])))
        return sweep.without(moving), deskewed.without(moving)
