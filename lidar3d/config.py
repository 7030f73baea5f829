"""Configuration: one frozen dataclass section per stage, TOML in and out.

Defaults are LeGO-LOAM's VLP-16 values (``utility.h`` at commit 896a7a95, see
``shared/reference/lego-loam-and-peers.md``). A TOML file may override any subset; unknown keys,
wrongly typed values and values outside a key's range are rejected with the dotted path that is
wrong, as one line. Every key declares its range and meaning once, in its field's metadata
(:func:`key_specs` lists them); :func:`config_from_dict` checks them, and :func:`config_to_toml`
writes each range as a trailing comment.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import typing
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lidar3d.errors import ConfigError
from lidar3d.sensors import SENSOR_MODELS, SensorModel

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

__all__ = [
    "Choices",
    "Config",
    "DynamicConfig",
    "FeatureConfig",
    "GeorefConfig",
    "GnssConfig",
    "HealthConfig",
    "InputConfig",
    "KeySpec",
    "ListRange",
    "LoopConfig",
    "MappingConfig",
    "MotionConfig",
    "OdometryConfig",
    "Range",
    "SegmentationConfig",
    "SensorConfig",
    "config_from_dict",
    "config_to_toml",
    "config_with",
    "key_specs",
    "load_config",
]


def _number(value: float) -> str:
    """A bound as written in a range: ``5``, ``0.2``, ``4000000000``."""
    return str(int(value)) if float(value).is_integer() else repr(float(value))


@dataclass(frozen=True, slots=True)
class Range:
    """The allowed values of a numeric key: an interval from ``low`` to ``high`` (closed unless
    ``low_open``/``high_open``), in ``unit``; with ``zero_keeps_preset`` the value 0 is allowed too
    and means "the sensor preset's value"."""

    low: float
    high: float
    low_open: bool = False
    high_open: bool = False
    unit: str = ""
    zero_keeps_preset: bool = False

    def contains(self, value: float) -> bool:
        if self.zero_keeps_preset and value == 0:
            return True
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def interval(self) -> str:
        """The interval alone, e.g. ``(0, 10]``."""
        opening = "(" if self.low_open else "["
        closing = ")" if self.high_open else "]"
        return f"{opening}{_number(self.low)}, {_number(self.high)}{closing}"

    def __str__(self) -> str:
        text = self.interval() + (f" {self.unit}" if self.unit else "")
        return f"0 (preset) or {text}" if self.zero_keeps_preset else text


@dataclass(frozen=True, slots=True)
class ListRange:
    """The allowed values of a list of numbers: ``min_length``..``max_length`` entries, each in
    ``entry``; or, when ``entry`` is a tuple of ranges, exactly one entry per range (position i in
    ``entry[i]``, called ``entry_names[i]``). A non-empty ``empty_meaning`` allows [] too and says
    what it means."""

    entry: Range | tuple[Range, ...]
    min_length: int = 0
    max_length: int = 0
    empty_meaning: str = ""
    entry_names: tuple[str, ...] = ()

    def length_ok(self, n: int) -> bool:
        if n == 0 and self.empty_meaning:
            return True
        if isinstance(self.entry, tuple):
            return n == len(self.entry)
        return self.min_length <= n <= self.max_length

    def entry_range(self, i: int) -> Range:
        return self.entry[i] if isinstance(self.entry, tuple) else self.entry

    def entry_label(self, i: int) -> str:
        """``[i]``, with the entry's name where it has one: ``[0] (latitude_deg)``."""
        return f"[{i}] ({self.entry_names[i]})" if i < len(self.entry_names) else f"[{i}]"

    def __str__(self) -> str:
        empty = f"[] ({self.empty_meaning}) or " if self.empty_meaning else ""
        if isinstance(self.entry, tuple):
            names = self.entry_names or ("",) * len(self.entry)
            return empty + "[" + ", ".join(f"{n} {r}".lstrip() for n, r in zip(names, self.entry)) + "]"
        return f"{empty}{self.min_length} to {self.max_length} entries, each in {self.entry}"


@dataclass(frozen=True, slots=True)
class Choices:
    """The allowed values of a string key."""

    names: tuple[str, ...]

    def __str__(self) -> str:
        return ", ".join(self.names)


@dataclass(frozen=True, slots=True)
class KeySpec:
    """One configuration key as documented: dotted ``path`` (``mapping.map_voxel_m``), the
    ``default`` value, the allowed values (``valid``: None for booleans and free strings) and its
    ``meaning``."""

    path: str
    default: Any
    valid: Range | ListRange | Choices | None
    meaning: str

    def default_text(self) -> str:
        """The default as written in TOML, e.g. ``0.2``, ``[]``, ``"vlp16"``."""
        return _toml_value(self.default)

    def valid_text(self) -> str:
        """The allowed values as one line, for comments and the manual."""
        if self.valid is not None:
            return str(self.valid)
        if isinstance(self.default, bool):
            return "true or false"
        return "list of strings" if isinstance(self.default, tuple) else "any string"


def _key(default: Any, valid: Range | ListRange | Choices | None, meaning: str) -> Any:
    """A config field: its default, allowed values and meaning (read by :func:`key_specs`)."""
    return field(default=default, metadata={"valid": valid, "meaning": meaning})


def _closed(low: float, high: float, unit: str = "") -> Range:
    return Range(low, high, unit=unit)


def _positive(high: float, unit: str = "") -> Range:
    """(0, high]: sizes and distances where 0 would divide by zero or select nothing."""
    return Range(0.0, high, low_open=True, unit=unit)


_VOXEL_M = _positive(10.0, "m")
_FRACTION = _closed(0.0, 1.0)
_ITERATIONS = _closed(1, 1000)
_ACUTE_DEG = Range(0.0, 90.0, low_open=True, high_open=True, unit="deg")


@dataclass(frozen=True, slots=True)
class SensorConfig:
    """Sensor geometry: ``model`` names a preset of :data:`lidar3d.sensors.SENSOR_MODELS`; the
    ``*_override*`` fields replace single values of that preset, and their zero/empty default means
    "keep the preset's value". :attr:`resolved_model` is the geometry in force."""

    model: str = _key("vlp16", Choices(tuple(SENSOR_MODELS)), "sensor preset: beam table, columns, rate, range")
    elevation_override_deg: tuple[float, ...] = _key(
        (),
        ListRange(_closed(-90.0, 90.0, "deg"), 2, 256, empty_meaning="preset"),
        "beam elevation table, strictly ascending (ring r is the r-th lowest beam)",
    )
    n_columns_override: int = _key(
        0, Range(16, 36000, zero_keeps_preset=True), "azimuth cells per sweep in the range image"
    )
    rotation_override_hz: float = _key(0.0, Range(0.1, 100.0, unit="Hz", zero_keeps_preset=True), "sweeps per second")
    max_range_override_m: float = _key(
        0.0, Range(0.0, 2000.0, low_open=True, unit="m", zero_keeps_preset=True), "farthest return kept"
    )
    min_range_m: float = _key(
        1.0, Range(0.0, 2000.0, high_open=True, unit="m"), "nearest return kept (LeGO-LOAM sensorMinimumRange)"
    )
    mount_pitch_deg: float = _key(0.0, _closed(-180.0, 180.0, "deg"), "mount pitch (LeGO-LOAM sensorMountAngle)")
    mount_roll_deg: float = _key(0.0, _closed(-180.0, 180.0, "deg"), "mount roll")

    @property
    def resolved_model(self) -> SensorModel:
        """The preset called ``model`` with the overrides applied: the geometry every stage uses."""
        base = SENSOR_MODELS[self.model]
        return SensorModel(
            name=base.name,
            elevation_deg=tuple(self.elevation_override_deg) or base.elevation_deg,
            n_columns=self.n_columns_override or base.n_columns,
            rotation_hz=self.rotation_override_hz or base.rotation_hz,
            max_range_m=self.max_range_override_m or base.max_range_m,
        )


@dataclass(frozen=True, slots=True)
class InputConfig:
    """How scans are read from bags, pcap files and raw packets."""

    topic: str = _key("", None, "PointCloud2 topic; empty: auto-detect the only one")
    azimuth_stamp: str = _key(
        "sweep_start",
        Choices(("sweep_start", "sweep_end")),
        "what the header stamp marks in clouds whose point times come from the azimuth (no usable time field)",
    )
    packet_model: str = _key(
        "auto",
        Choices(("auto", *SENSOR_MODELS)),
        "raw packets: the model decoded as; auto: from the firing pattern and factory bytes (--sensor)",
    )
    packet_return: str = _key(
        "strongest",
        Choices(("strongest", "last", "both")),
        "raw packets in dual-return mode: the return kept (both: every return); single-return data keeps all",
    )
    packet_clock: str = _key(
        "host",
        Choices(("host", "sensor")),
        "raw packets: stamps from the host capture clock or the sensor's own (top-of-hour, PPS) clock",
    )
    calibration: str = _key(
        "", None, "raw packets: velodyne_pointcloud calibration YAML; empty: the model's built-in table"
    )
    cut_azimuth_deg: float = _key(
        0.0, Range(0.0, 360.0, high_open=True, unit="deg"), "raw packets: a sweep starts where the azimuth passes this"
    )
    recut_sweeps: bool = _key(
        False, None, "packet bags: cut sweeps at cut_azimuth_deg (false: one sweep per VelodyneScan message)"
    )
    data_ports: tuple[int, ...] = _key(
        (2368,), ListRange(_closed(1, 65535), 1, 64), "pcap: UDP destination ports of data packets"
    )
    position_ports: tuple[int, ...] = _key(
        (8308,), ListRange(_closed(1, 65535), 0, 64), "pcap: UDP destination ports of position (NMEA) packets"
    )


@dataclass(frozen=True, slots=True)
class SegmentationConfig:
    """Range-image ground segmentation and clustering (LeGO-LOAM imageProjection)."""

    ground_rows: int = _key(
        0, _closed(0, 256), "rows 0..n-1 may be ground; 0: every beam below the horizon (VLP-16: rows 0..7)"
    )
    ground_angle_threshold_deg: float = _key(10.0, _ACUTE_DEG, "steepest slope between stacked points taken as ground")
    ground_continuity: bool = _key(
        True, None, "continuity tests on top of the pairwise angle test (false: LeGO-LOAM's)"
    )
    ground_max_angle_change_deg: float = _key(5.0, _ACUTE_DEG, "continuity: slope change between stacked pairs")
    ground_height_slope_deg: float = _key(
        5.0,
        Range(0.0, 90.0, high_open=True, unit="deg"),
        "continuity: a column's first run starts within margin + distance * tan(slope) of the scan's ground level",
    )
    ground_height_margin_m: float = _key(0.2, _closed(0.0, 10.0, "m"), "continuity: the margin of that test")
    ground_support_margin_m: float = _key(
        0.04, _closed(0.0, 1.0, "m"), "contact: ground this close to its run's line stays ground"
    )
    ground_noise_m: float = _key(0.05, _closed(0.0, 1.0, "m"), "continuity: height steps this small pass at any angle")
    # Ground precision 0.972 -> 0.984 on the realistic scenarios. A label only: the cells it lifts
    # stay coarse ground for the features, mapping and the grid (docs/stages/segmentation.md).
    ground_surface_sector_deg: float = _key(
        2.0,
        _closed(0.0, 90.0, "deg"),
        "surface: ground must lie on the ground below it in a sector this wide (0: off)",
    )
    ground_surface_rows: int = _key(3, _closed(2, 256), "surface: the local line is fitted to this many rows below")
    ground_surface_margin_m: float = _key(
        0.1, _closed(0.0, 10.0, "m"), "surface: height above the local line allowed at zero distance"
    )
    ground_surface_range_slope_deg: float = _key(
        0.1,
        Range(0.0, 90.0, high_open=True, unit="deg"),
        "surface: the allowed height grows by range * tan(this) (beam elevation error)",
    )
    cluster_angle_deg: float = _key(60.0, _ACUTE_DEG, "neighbours join a cluster above this angle (segmentTheta)")
    min_cluster_points: int = _key(30, _closed(1, 1_000_000), "a cluster this big is kept")
    min_cluster_points_multi_ring: int = _key(
        5, _closed(1, 1_000_000), "... or this big over min_cluster_rings rings (segmentValidPointNum)"
    )
    min_cluster_rings: int = _key(3, _closed(1, 256), "rings of that rule (segmentValidLineNum)")
    ground_column_stride: int = _key(5, _closed(1, 36000), "ground kept on every n-th column in the segmented cloud")
    outlier_column_stride: int = _key(
        5, _closed(1, 36000), "outlier cloud for mapping: every n-th column, rows >= ground rows"
    )
    use_ring_field: bool = _key(True, None, "rows from the ring field (useCloudRing); false: from elevation")


@dataclass(frozen=True, slots=True)
class FeatureConfig:
    """Curvature features (LeGO-LOAM featureAssociation)."""

    curvature_half_window: int = _key(5, _closed(1, 100), "points each side in the curvature sum")
    edge_threshold: float = _key(
        0.1, _closed(0.0, 1000.0, "m^2"), "edge candidates above this (unnormalised) curvature"
    )
    edge_noise_false_rate: float = _key(
        0.0, _closed(0.0, 0.5), "range noise on a smooth surface passes the edge test this rarely (0: fixed threshold)"
    )
    planar_threshold: float = _key(0.1, _closed(0.0, 1000.0, "m^2"), "flat candidates below this curvature")
    sections_per_ring: int = _key(6, _closed(1, 360), "each ring is split into this many sections for picking")
    sharp_per_section: int = _key(2, _closed(0, 10000), "sharp edges per section (the first less-sharp picks)")
    less_sharp_per_section: int = _key(20, _closed(0, 10000), "less-sharp edges per section")
    flat_per_section: int = _key(4, _closed(0, 10000), "flat points per section")
    less_flat_voxel_m: float = _key(0.2, _VOXEL_M, "voxel of the less-flat cloud (per ring)")
    occlusion_depth_m: float = _key(0.3, _positive(100.0, "m"), "range step marking an occlusion edge")
    parallel_beam_ratio: float = _key(0.02, _FRACTION, "neighbour range jumps above this share of range: beam parallel")
    neighbour_max_column_gap: int = _key(
        10, _closed(1, 36000), "occlusion test and pick suppression stop at wider gaps"
    )


@dataclass(frozen=True, slots=True)
class OdometryConfig:
    """Scan-to-scan two-step odometry (LeGO-LOAM featureAssociation)."""

    max_iterations: int = _key(25, _ITERATIONS, "Gauss-Newton iterations per step")
    rematch_every: int = _key(5, _ITERATIONS, "correspondences recomputed every n iterations")
    min_rows: int = _key(10, _closed(6, 1_000_000), "fewer residual rows: the step fails (6 unknowns)")
    degeneracy_threshold: float = _key(10.0, _closed(0.0, 1e9), "Hessian eigenvalues below this are degenerate")
    search_radius_m: float = _key(
        5.0, _positive(100.0, "m"), "correspondence search radius (nearestFeatureSearchSqDist)"
    )
    min_previous_edges: int = _key(10, _closed(0, 1_000_000), "the previous scan needs this many edges ...")
    min_previous_planes: int = _key(100, _closed(0, 1_000_000), "... and this many planar points")
    fuse_heading: bool = _key(
        False, None, "fuse each step's yaw into the scan-to-submap registration (experimental, see the docs)"
    )
    heading_shortfall: float = _key(
        2.0, _closed(0.0, 100.0), "its yaw travel from the guess times this is added to a step's yaw sigma"
    )


@dataclass(frozen=True, slots=True)
class MappingConfig:
    """Scan-to-submap refinement and keyframes (LeGO-LOAM mapOptmization, LIO-SAM keyframe rule)."""

    corner_voxel_m: float = _key(0.2, _VOXEL_M, "voxel of keyframe and submap corner clouds")
    surf_voxel_m: float = _key(0.4, _VOXEL_M, "voxel of keyframe and submap surface clouds")
    scan_surf_voxel_m: float = _key(0.8, _VOXEL_M, "voxel of the current scan's surface points matched to the submap")
    max_iterations: int = _key(10, _ITERATIONS, "Gauss-Newton iterations per scan")
    rematch_every: int = _key(
        2, _ITERATIONS, "correspondences recomputed every n iterations (LeGO-LOAM: 1; 2 costs 25 % less)"
    )
    min_rows: int = _key(
        120, _closed(6, 1_000_000), "fewer rows: not registered (LIO-SAM: 10 edge, 100 flat points); keyframe minimum"
    )
    converge_rotation_deg: float = _key(0.05, _closed(0.0, 10.0, "deg"), "converged below this rotation step ...")
    converge_translation_m: float = _key(0.0005, _closed(0.0, 1.0, "m"), "... and this translation step")
    # Submap planes: LeGO-LOAM fits 5 neighbours within 1 m; on a 16-beam scan those lie on one
    # or two ring lines, and the tilt noise of such small fits, shared by every scan matched
    # against the same keyframes, leaves a pitch offset of 0.2-0.5 deg (ours, loop and long).
    # 10 neighbours within 1.4 m cut it to 0.04-0.1 deg.
    plane_neighbours: int = _key(10, _closed(3, 100), "neighbours of a submap plane fit")
    plane_max_distance_m: float = _key(1.4, _positive(50.0, "m"), "farthest neighbour of a plane fit")
    level_normal_z: float = _key(0.9, _FRACTION, "planes this level inform only z, roll, pitch (0: off)")
    min_residual_sigma_m: float = _key(
        0.01, _positive(1.0, "m"), "the rows' residual sigma scaling their information is at least this"
    )
    robust_scale_m: float = _key(
        0.05, _closed(0.0, 10.0, "m"), "Geman-McClure scale; 0 selects LeGO-LOAM's 1 - 0.9|r| weight"
    )
    keyframe_distance_m: float = _key(
        1.0, _closed(0.0, 1000.0, "m"), "new keyframe after this distance (surroundingkeyframeAddingDistThreshold)"
    )
    keyframe_angle_deg: float = _key(11.46, _closed(0.0, 180.0, "deg"), "... or this rotation (LIO-SAM 0.2 rad)")
    moving_probe_keyframes: int = _key(
        0, _closed(0, 1000), "points this many latest keyframes saw through are not registered (0: off; try 8)"
    )
    submap_radius_m: float = _key(50.0, _positive(10000.0, "m"), "keyframes this near form the submap")
    submap_max_keyframes: int = _key(60, _closed(1, 100_000), "nearest keyframes in the submap at most")
    submap_recent_keyframes: int = _key(
        10, _closed(0, 100_000), "latest keyframes always in the submap (a run keeps only their clouds in memory)"
    )
    # a submap holds at most max + recent keyframes (70): a cache beyond that keeps clouds a rebuild
    # does not ask for (0.1 MB each) to save a transform (~30 us) when the drive comes back to them
    submap_cache_keyframes: int = _key(100, _closed(0, 1_000_000), "world-frame keyframe clouds kept in memory")
    submap_rebuild_every_keyframes: int = _key(3, _closed(1, 100_000), "submap rebuilt after this many new keyframes")
    map_voxel_m: float = _key(0.2, _VOXEL_M, "voxel of the dense output map (map.pcd)")
    # A scan is registered deskewed with the motion model's prediction (the motion before it).
    # Once the next scan's pose is known, the motion over its own sweep is (forward difference);
    # when that moves some point of the sweep by redeskew_threshold_m more than the prediction did
    # (the angular part measured at redeskew_lever_m), the scan is deskewed again and re-registered
    # before it enters the map. Turn entries and exits, where the prediction lags a whole sweep.
    redeskew_threshold_m: float = _key(
        0.01, _closed(0.0, 1000.0, "m"), "re-deskew a scan when its sweep motion moves a point this much more"
    )
    redeskew_lever_m: float = _key(10.0, _closed(0.0, 10000.0, "m"), "lever arm of that test's rotation part")
    redeskew_iterations: int = _key(4, _ITERATIONS, "iteration limit of the second registration")
    solve_sweep_yaw_rate: bool = _key(
        False, None, "solve the sweep's yaw rate beside its pose (prior: motion.yaw_accel_rad_s2 over one sweep)"
    )
    tilt_knot_spacing_s: float = _key(
        0.0, _closed(0.0, 1.0, "s"), "roll/pitch knots within a sweep (vibration) this far apart at most (0: off)"
    )
    # The Gauss-Newton information holds the correspondences fixed; where matches are random
    # (range noise on flat walls passing the edge threshold) it claims a direction the cost does
    # not hold. The registration is probed along its weakest translation by this shift (more than
    # the submap's point spacing) with the matches found again; see docs/stages/scan-to-map.md.
    probe_shift_m: float = _key(0.25, _closed(0.0, 10.0, "m"), "probe shift of the weakest translation (0: off)")
    probe_observed_share: float = _key(
        0.5, _FRACTION, "a probe pulled back by less than this share of the shift: that direction is degenerate"
    )
    probe_iterations: int = _key(4, _ITERATIONS, "iteration limit of the solve without the directions the probe lost")
    probe_point_stride: int = _key(4, _closed(1, 1000), "the probe moves every n-th corner and surface point")


@dataclass(frozen=True, slots=True)
class HealthConfig:
    """The per-scan health signal (lidar3d.mapping.health, docs/stages/health.md).

    A scan *observes* its pose when its registration ran, the pose's standard deviation along the
    weakest direction of the scan's information is at most ``observed_sigma_m``, and its refined step
    agrees with the scan-to-scan odometry step within ``max_disagreement_m``; it observes every
    direction when its registration also took none from the prior. A scan is ``degraded`` when
    the standard deviation of its pose (:mod:`lidar3d.mapping.pose_uncertainty`: the vehicle
    model's accelerations between scans, the registration's information at each; translation plus
    ``lever_m`` times rotation) is above ``degraded_sigma_m``; after ``lost_after_m`` of travel with
    the pose not observed the scans are ``lost``, until ``clear_after_m`` of fully observed travel
    in a row. A scan whose refined step and odometry step are ``jump_m`` or more apart (the
    tolerance itself: one of the two is that far off) starts ``jump_window_m`` of ``degraded``
    travel, the stretch over which that step's error is the tolerance's. Besides, a scan is
    ``degraded`` while the refined trajectory and the
    scan-to-scan odometry parted over the last ``consistency_window_m``, in heading or in distance
    along the steps, by more than ``max_consistency_z`` standard deviations of the odometry's own
    (its rows', and the floors ``heading_sigma_floor_deg`` and ``along_sigma_floor_m``); a difference
    in the direction the odometry moved from its guess, up to ``travel_share`` of that move, is put
    down to the odometry stopping short.
    """

    residual_sigma_m: float = _key(
        0.05, _positive(1.0, "m"), "residual std behind the pose uncertainty, where the registration reports none"
    )
    observed_sigma_m: float = _key(
        0.01, _positive(10.0, "m"), "a scan observes its pose when the std along its weakest direction is at most this"
    )
    lever_m: float = _key(10.0, _closed(0.0, 1000.0, "m"), "a rotation counts as the shift of a point this far away")
    max_disagreement_m: float = _key(
        0.2, _positive(100.0, "m"), "refined and odometry steps farther apart than this: the scan is inconsistent"
    )
    degraded_sigma_m: float = _key(
        0.1, _positive(100.0, "m"), "pose std (vehicle model between scans, the rows at each) above which degraded"
    )
    jump_m: float = _key(
        0.3, _positive(100.0, "m"), "refined and odometry steps this far apart: the travel from there is degraded ..."
    )
    jump_window_m: float = _key(10.0, _closed(0.0, 1e5, "m"), "... for this far")
    clear_after_m: float = _key(
        2.0, _positive(1e5, "m"), "fully observed travel in a row that clears the dead-reckoned and blind travel"
    )
    lost_after_m: float = _key(10.0, _positive(1e6, "m"), "travel with the pose not observed before scans are lost")
    consistency_window_m: float = _key(
        20.0, _positive(1e4, "m"), "travel over which the refined steps are compared with the odometry's"
    )
    max_consistency_z: float = _key(
        4.0, _positive(1e6), "heading or distance parted by more standard deviations than this: degraded"
    )
    heading_sigma_floor_deg: float = _key(
        0.3, _closed(0.0, 90.0, "deg"), "std added to the window's heading difference (the refined poses' own noise)"
    )
    along_sigma_floor_m: float = _key(
        0.15, _closed(0.0, 100.0, "m"), "std added to the window's along-track difference (the same)"
    )
    travel_share: float = _key(
        1.0,
        _closed(0.0, 100.0),
        "a difference the way the odometry moved, up to this share of its move, is its shortfall",
    )


_GEODETIC_NAMES = ("latitude_deg", "longitude_deg", "height_ellipsoid_m")
_GEODETIC_ORIGIN = (_closed(-90.0, 90.0, "deg"), _closed(-180.0, 180.0, "deg"), _closed(-1000.0, 20000.0, "m"))


@dataclass(frozen=True, slots=True)
class GnssConfig:
    """NovAtel SPAN ground truth and trajectory evaluation (lidar3d.gnss, lidar3d.metrics)."""

    leap_seconds: int = _key(18, _closed(0, 100, "s"), "GPS - UTC; 18 s since 2017-01-01")
    time_offset_s: float = _key(
        0.0, _closed(-4e9, 4e9, "s"), "bag clock minus GPS-derived UNIX time (a clock left at 1970 included)"
    )
    accepted_ins_statuses: tuple[str, ...] = _key(("INS_SOLUTION_GOOD",), None, "INS statuses kept")
    require_fine_time: bool = _key(True, None, "drop long-header solutions whose time status is below FINE")
    max_association_gap_s: float = _key(0.2, _positive(60.0, "s"), "longest reference interval interpolated across")
    origin: tuple[float, ...] = _key(
        (),
        ListRange(_GEODETIC_ORIGIN, empty_meaning="first good fix", entry_names=_GEODETIC_NAMES),
        "ENU origin: WGS84 latitude, longitude and ellipsoidal height",
    )
    align: str = _key("se3", Choices(("se3", "yaw", "none")), "alignment: se3 (Umeyama), yaw (4-DoF) or none")
    rpe_segment_lengths_m: tuple[float, ...] = _key(
        (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0),
        ListRange(_positive(1e6, "m"), 0, 100),
        "KITTI RPE segment lengths",
    )
    rpe_step_s: float = _key(1.0, _positive(3600.0, "s"), "a KITTI segment start every this many seconds")
    rpe_distances_m: tuple[float, ...] = _key(
        (10.0, 100.0), ListRange(_positive(1e6, "m"), 0, 100), "per fixed distance RPE (evo -d D -u m)"
    )


@dataclass(frozen=True, slots=True)
class GeorefConfig:
    """Georeference of a run and the optional GNSS position factors (lidar3d.georef; docs/georeference.md)."""

    method: str = _key(
        "yaw", Choices(("yaw", "se3")), "SLAM -> ENU fit: yaw (roll/pitch from the INS attitude) or se3 (positions)"
    )
    max_fit_residual_m: float = _key(
        5.0, _positive(1e6, "m"), "fit epochs whose residual exceeds this and 5x the median are dropped (jumps)"
    )
    factor_max_std_m: float = _key(
        1.0, _positive(1000.0, "m"), "GNSS epochs reporting a horizontal std above this are not fused"
    )
    factor_std_floor_m: float = _key(0.05, _positive(100.0, "m"), "a fused epoch's std is at least this")
    factor_spacing_m: float = _key(
        2.0, _closed(0.0, 1e4, "m"), "fused epochs at least this far apart along the path (LIO-SAM: 5)"
    )
    factor_max_gap_s: float = _key(0.2, _positive(60.0, "s"), "longest INS interval interpolated to a keyframe stamp")
    gate_floor_m: float = _key(1.0, _positive(1e4, "m"), "consistency gate: allowed disagreement with the odometry")
    gate_sigmas: float = _key(4.0, _positive(100.0), "... plus this many combined GNSS stds")
    gate_drift_fraction: float = _key(
        0.25, _closed(0.0, 10.0), "... plus this fraction of the path between the two epochs (lidar drift)"
    )
    gate_reanchor_gap_m: float = _key(
        20.0, _positive(1e6, "m"), "after this much path without a GNSS candidate, a confirmed epoch re-anchors"
    )
    odometry_sigma_m: float = _key(0.02, _positive(100.0, "m"), "keyframe-to-keyframe odometry factor std")
    odometry_sigma_fraction: float = _key(
        0.02, _closed(0.0, 1.0), "... plus this fraction of the keyframe step (drift per metre)"
    )
    odometry_sigma_rad: float = _key(0.002, _positive(1.0, "rad"), "odometry factor rotation std")
    hold_out_period_s: float = _key(
        0.0, _closed(0.0, 3600.0, "s"), "fuse only even periods of this length, so eval can score the odd ones (0: all)"
    )


@dataclass(frozen=True, slots=True)
class LoopConfig:
    """Loop closure and pose graph (lidar3d.loop). Sources: LeGO-LOAM/LIO-SAM mapOptmization,
    hdl_graph_slam loop_detector, KISS-SLAM loop_closer (shared/reference/lego-loam-and-peers.md)."""

    enabled: bool = _key(True, None, "loop closure on")
    source: str = _key(
        "both", Choices(("distance", "place", "both")), "candidates from the distance gate, place recognition or both"
    )
    search_radius_m: float = _key(
        7.0, _positive(10000.0, "m"), "candidates within this distance (historyKeyframeSearchRadius; LIO-SAM 15)"
    )
    horizontal_distance: bool = _key(True, None, "(x, y) distance, blind to height drift (hdl_graph_slam)")
    min_time_gap_s: float = _key(
        30.0, _closed(0.0, 1e7, "s"), "candidates at least this much older (historyKeyframeSearchTimeDiff)"
    )
    max_candidates: int = _key(
        2, _closed(1, 1000), "verified per query keyframe, nearest first, until one is accepted (one per submap)"
    )
    cooldown_keyframes: int = _key(5, _closed(0, 1_000_000), "after an accepted loop, skip this many query keyframes")
    submap_neighbours: int = _key(
        10, _closed(0, 10000), "target = match +- this many keyframes (LeGO-LOAM +-25 at 0.3 m spacing)"
    )
    voxel_m: float = _key(0.4, _VOXEL_M, "loop source and target downsampling")
    icp_method: str = _key(
        "gicp", Choices(("gicp", "point_to_plane")), "small_gicp ICP; GICP rotations were 10x closer on `long`"
    )
    icp_max_correspondence_m: tuple[float, ...] = _key(
        (4.0, 2.0, 1.0, 0.5), ListRange(_positive(100.0, "m"), 1, 20), "coarse-to-fine stage distances"
    )
    icp_stage_voxel_share: float = _key(
        0.5, _closed(0.0, 10.0), "each stage's query cloud at this share of its distance as voxel (>= voxel_m)"
    )
    icp_max_iterations: int = _key(30, _closed(1, 10000), "ICP iterations per stage")
    icp_neighbours: int = _key(
        20, _closed(5, 1000), "nearest neighbours behind each GICP covariance and point-to-plane target normal"
    )
    min_source_points: int = _key(300, _closed(1, 100_000_000), "fewer query points: no check (LIO-SAM)")
    min_target_points: int = _key(1000, _closed(1, 100_000_000), "fewer target points: no check (LIO-SAM)")
    min_fitness: float = _key(0.7, _FRACTION, "share of query points with a target point within the final distance")
    max_rmse_m: float = _key(0.3, _positive(100.0, "m"), "inlier RMSE at the final distance (~0.15 typical)")
    min_overlap: float = _key(0.5, _FRACTION, "voxel overlap |A & B| / min(|A|, |B|) (KISS-SLAM: 0.4)")
    overlap_voxel_m: float = _key(1.0, _VOXEL_M, "voxel of the overlap test")
    max_correction_m: float = _key(1.0, _closed(0.0, 10000.0, "m"), "ICP may move the guess this far ...")
    correction_per_distance: float = _key(0.01, _FRACTION, "... plus this share of the path between the keyframes")
    max_correction_deg: float = _key(10.0, _closed(0.0, 180.0, "deg"), "... and rotate it this much")
    information_points: int = _key(
        100, _closed(1, 100_000_000), "effective independent correspondences behind the loop information"
    )
    min_sigma_translation_m: float = _key(0.02, _positive(100.0, "m"), "floor added to the loop covariance")
    min_sigma_rotation_deg: float = _key(0.5, _positive(180.0, "deg"), "floor of the loop rotation sigma")
    huber_k: float = _key(1.345, _positive(1000.0), "Huber threshold on loop factors, in sigmas (hdl_graph_slam: 1.0)")
    odometry_sigma_translation_m: float = _key(
        0.01, _positive(100.0, "m"), "per keyframe step (LeGO-LOAM/LIO-SAM variance 1e-4)"
    )
    odometry_sigma_rotation_deg: float = _key(
        0.05, _positive(180.0, "deg"), "per keyframe step (LeGO-LOAM/LIO-SAM variance 1e-6 rad^2)"
    )
    place_rings: int = _key(20, _closed(1, 1000), "Scan Context rings (Kim & Kim 2018: 20)")
    place_sectors: int = _key(60, _closed(4, 3600), "Scan Context sectors (60: 6 degrees each)")
    place_max_radius_m: float = _key(80.0, _positive(1000.0, "m"), "Scan Context radius (80 m)")
    place_candidates: int = _key(10, _closed(1, 1000), "ring-key neighbours compared in full (10)")
    place_threshold: float = _key(
        0.2, _FRACTION, "descriptor distance below which a keyframe is the same place (SC reference: 0.13-0.2)"
    )
    consistency_keyframes: int = _key(
        10,
        _closed(1, 1_000_000),
        "closures this many keyframes apart are checked against each other (a large place match waits as long)",
    )
    consistency_m: float = _key(
        1.0, _positive(1000.0, "m"), "two closures agree: cycle error within this plus correction_per_distance ..."
    )
    consistency_deg: float = _key(2.0, _positive(180.0, "deg"), "... of the spans' path, and this rotation")
    relinearize_threshold: float = _key(0.01, _closed(0.0, 100.0), "iSAM2 relinearization threshold (LIO-SAM 0.1)")
    extra_updates: int = _key(5, _closed(0, 1000), "iSAM2 updates after a loop (LIO-SAM 5)")

    def __post_init__(self) -> None:
        # Checked on construction too: the ICP stages are read by code that builds a LoopConfig itself.
        for name in ("icp_method", "icp_max_correspondence_m"):
            _check_value(f"loop.{name}", getattr(self, name), _spec_of(LoopConfig, name))


@dataclass(frozen=True, slots=True)
class MotionConfig:
    """The vehicle motion prior of scan-to-submap registration (:mod:`lidar3d.mapping.motion_model`).

    The prediction carries the last twist forward; these bound how far the true motion may
    depart from it over one scan interval dt: a translation sigma of ``accel * dt^2`` along each
    body axis and a rotation sigma of ``angular_accel * dt^2`` about each. Sideways and vertical
    apply once the motion has shown it is a vehicle's (driving along one body axis); until then
    every translation axis takes the forward value. Where the recent prediction errors of
    well-constrained scans are larger, and persist from one scan to the next (the root of the
    running mean of consecutive errors' products, per axis), they are used instead.
    """

    forward_accel_mps2: float = _key(2.0, _positive(100.0, "m/s^2"), "speed change along the direction of travel")
    lateral_accel_mps2: float = _key(0.5, _positive(100.0, "m/s^2"), "sideways velocity change (non-holonomic)")
    vertical_accel_mps2: float = _key(1.0, _positive(100.0, "m/s^2"), "vertical velocity change (suspension)")
    yaw_accel_rad_s2: float = _key(2.0, _positive(1000.0, "rad/s^2"), "yaw rate change (steering into a turn)")
    tilt_accel_rad_s2: float = _key(0.5, _positive(1000.0, "rad/s^2"), "roll and pitch rate change (vibration)")
    lever_m: float = _key(0.0, _closed(-100.0, 100.0, "m"), "the sensor's distance ahead of the rear axle, if known")
    lever_sigma_m: float = _key(
        0.5, _closed(0.0, 100.0, "m"), "its uncertainty: the sideways sigma grows by this times the yaw rate"
    )
    twist_change_sigmas: float = _key(
        3.0, _positive(1000.0), "a learned twist changes per scan by at most this many acceleration sigmas x dt"
    )
    min_sigma_m: float = _key(0.002, _positive(1.0, "m"), "translation sigma of one step is at least this")
    min_sigma_deg: float = _key(0.02, _positive(10.0, "deg"), "rotation sigma of one step is at least this")
    cold_start_sigma_m: float = _key(1.0, _positive(1000.0, "m"), "before the model is established: guess sigma ...")
    cold_start_sigma_deg: float = _key(5.0, _positive(180.0, "deg"), "... and rotation sigma beside the odometry yaw")
    innovation_smoothing: float = _key(
        0.2, _FRACTION, "weight of the newest product of consecutive prediction errors in the prior's widening"
    )


@dataclass(frozen=True, slots=True)
class DynamicConfig:
    """Dynamic-object removal from the dense map by free-space evidence (:mod:`lidar3d.mapping.free_space`,
    docs/stages/dynamic-removal.md): a voxel of a sweep that the probes of the window around it saw
    through is dynamic; its points go to ``dynamic.pcd`` instead of ``map.pcd``."""

    enabled: bool = _key(True, None, "remove points in space later seen through (false: lidar3d run --keep-dynamic)")
    voxel_m: float = _key(0.2, _positive(5.0, "m"), "voxel of the hit/miss evidence")
    window_scans: int = _key(90, _closed(1, 10_000), "sweeps before and after a sweep whose rays test its voxels")
    probe_every: int = _key(6, _closed(1, 1000), "every n-th sweep of the window is a probe")
    reuse_scans: int = _key(5, _closed(1, 1000), "a voxel tested this few sweeps ago keeps that decision")
    max_range_m: float = _key(100.0, _positive(1000.0, "m"), "voxels farther from a probe get no evidence from it")
    pass_tolerance_m: float = _key(0.2, _positive(5.0, "m"), "a ray passes a voxel within this of its centroid")
    range_margin_m: float = _key(0.4, _positive(10.0, "m"), "a ray sees through when it returns this far beyond")
    min_misses: int = _key(2, _closed(1, 1000), "a dynamic voxel was seen through by at least this many probes")
    miss_ratio: float = _key(1.0, _closed(0.0, 1000.0), "... and by this many times more probes than hit it")
    ground_band_m: float = _key(
        0.2, _closed(0.0, 10.0, "m"), "voxels this close above the lowest point around them are kept (0: off)"
    )
    ground_band_per_m: float = _key(
        0.0, _closed(0.0, 1.0), "... plus this much per metre of range from their sweep's sensor (pose tilt errors)"
    )
    vote_ratio: float = _key(
        3.0,
        _closed(0.0, 1000.0),
        "at the end a map voxel with more dynamic points than this times its static ones moves",
    )
    grazing_slack: bool = _key(
        True, None, "a ray sees through a voxel only beyond the slack of the surface it hit at a grazing angle"
    )
    pose_angle_deg: float = _key(0.5, _closed(0.0, 10.0, "deg"), "angular pose error the grazing slack allows for")
    surface_side: bool = _key(
        True,
        None,
        "a ray passing in front of a voxel's own surface (the side it was seen from) does not see through it",
    )
    surface_tolerance_m: float = _key(0.05, _closed(0.0, 5.0, "m"), "... unless it passes within this of the surface")
    surface_angle_deg: float = _key(
        0.0, _closed(0.0, 10.0, "deg"), "... plus this angular error between two sweeps' poses times the range"
    )
    cluster_share: float = _key(
        0.5,
        _closed(0.0, 1.0),
        "a connected cluster of a sweep's voxels is dynamic whole when this share of those with evidence is (0: off)",
    )


@dataclass(frozen=True, slots=True)
class Config:
    """The whole configuration."""

    sensor: SensorConfig = field(default_factory=SensorConfig)
    input: InputConfig = field(default_factory=InputConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    health: HealthConfig = field(default_factory=HealthConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)
    gnss: GnssConfig = field(default_factory=GnssConfig)
    georef: GeorefConfig = field(default_factory=GeorefConfig)
    dynamic: DynamicConfig = field(default_factory=DynamicConfig)


def key_specs() -> Iterator[tuple[str, tuple[KeySpec, ...]]]:
    """Every section name with the specs of its keys, in declaration order (the manual's tables)."""
    defaults = Config()
    for section in dataclasses.fields(defaults):
        values = getattr(defaults, section.name)
        yield (
            section.name,
            tuple(
                KeySpec(f"{section.name}.{f.name}", getattr(values, f.name), f.metadata["valid"], f.metadata["meaning"])
                for f in dataclasses.fields(values)
            ),
        )


def _spec_of(cls: type, name: str) -> Range | ListRange | Choices | None:
    return next(f.metadata["valid"] for f in dataclasses.fields(cls) if f.name == name)


def _check_value(path: str, value: Any, valid: Range | ListRange | Choices | None) -> None:
    """Raise :class:`ConfigError` (one line: dotted key, value, allowed values) unless ``value`` fits."""
    if isinstance(valid, Range):
        if not valid.contains(value):
            raise ConfigError(f"config {path}: {value!r} is out of range {valid}")
    elif isinstance(valid, ListRange):
        if not valid.length_ok(len(value)):
            raise ConfigError(f"config {path}: a list of {len(value)} is out of range {valid}")
        for i, entry in enumerate(value):
            entry_range = valid.entry_range(i)
            if not entry_range.contains(entry):
                raise ConfigError(f"config {path}{valid.entry_label(i)}: {entry!r} is out of range {entry_range}")
    elif isinstance(valid, Choices) and value not in valid.names:
        raise ConfigError(f"config {path}: {value!r} is not one of {valid}")


def _check_section(name: str, section: Any) -> None:
    for f in dataclasses.fields(section):
        _check_value(f"{name}.{f.name}", getattr(section, f.name), f.metadata["valid"])


def _check_relations(config: Config) -> None:
    """The cross-field rules the code relies on (each key is already within its own range)."""
    elevations = config.sensor.elevation_override_deg
    for i in range(1, len(elevations)):
        if elevations[i] <= elevations[i - 1]:
            raise ConfigError(
                f"config sensor.elevation_override_deg[{i}]: {elevations[i]!r} is not above the entry before it "
                f"({elevations[i - 1]!r}); the table must be strictly ascending"
            )
    sensor = config.sensor.resolved_model
    if config.sensor.min_range_m >= sensor.max_range_m:
        raise ConfigError(
            f"config sensor.min_range_m: {config.sensor.min_range_m!r} is not below the maximum range "
            f"{sensor.max_range_m!r} m (sensor.max_range_override_m, 0: the preset's)"
        )
    if config.segmentation.ground_rows > sensor.n_rings:
        raise ConfigError(
            f"config segmentation.ground_rows: {config.segmentation.ground_rows} exceeds the "
            f"{sensor.n_rings} rings of {sensor.name}"
        )
    if config.features.sharp_per_section > config.features.less_sharp_per_section:
        raise ConfigError(
            f"config features.sharp_per_section: {config.features.sharp_per_section} exceeds "
            f"features.less_sharp_per_section ({config.features.less_sharp_per_section}); "
            "sharp edges are the first of the less-sharp picks"
        )


def _coerce(value: Any, annotation: Any, path: str) -> Any:
    """Check ``value`` against a field annotation and convert it (int -> float, list -> tuple)."""
    origin = typing.get_origin(annotation)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"config {path}: expected a list, got {type(value).__name__}")
        (item_type, _ellipsis) = typing.get_args(annotation)
        return tuple(_coerce(v, item_type, f"{path}[{i}]") for i, v in enumerate(value))
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"config {path}: expected true/false, got {value!r}")
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"config {path}: expected an integer, got {value!r}")
        return value
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"config {path}: expected a number, got {value!r}")
        if isinstance(value, int) and abs(value) > 2**63:
            raise ConfigError(f"config {path}: an integer of {len(str(abs(value)))} digits is out of any range")
        if not math.isfinite(value):
            raise ConfigError(f"config {path}: expected a finite number, got {value!r}")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"config {path}: expected a string, got {value!r}")
        return value
    raise TypeError(f"unsupported config annotation {annotation!r} at {path}")


_RETIRED_KEYS = {
    "loop.normal_radius_m": "loop.icp_neighbours (the loop ICP's normals and covariances are fitted to "
    "that many nearest neighbours since it runs on small_gicp, docs/stages/loop-closure.md)",
    "mapping.degeneracy_threshold": "the [motion] section's uncertainties (a scan-to-submap direction is "
    "degenerate where the rows know it less well than the vehicle model does, docs/stages/odometry-mapping.md)",
    "health.degraded_after_m": "health.degraded_sigma_m (a scan is degraded by how uncertain its pose is, not by "
    "the travel with a direction left to the prior) and health.clear_after_m (the observed travel that clears the "
    "travel counters), docs/stages/health.md",
}
"""Keys of earlier releases that a config file may still hold: what replaced each."""


def _build(cls: type, data: dict[str, Any], path: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"config {path}: expected a table, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    for key in data:
        if key not in names:
            where = f"{path}.{key}" if path else key
            if where in _RETIRED_KEYS:
                raise ConfigError(f"config: key {where!r} is gone; it is replaced by {_RETIRED_KEYS[where]}")
            raise ConfigError(f"config: unknown key {where!r} (known: {', '.join(sorted(names))})")
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name not in data:
            continue
        where = f"{path}.{f.name}" if path else f.name
        hint = hints[f.name]
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            kwargs[f.name] = _build(hint, data[f.name], where)
        else:
            kwargs[f.name] = _coerce(data[f.name], hint, where)
    return cls(**kwargs)


def config_from_dict(data: dict[str, Any]) -> Config:
    """Build a validated :class:`Config` from a nested dict (as parsed from TOML): types, every
    key's range (:func:`key_specs`) and the cross-field rules; :class:`ConfigError` otherwise."""
    config = _build(Config, data, "")
    for section in dataclasses.fields(config):
        _check_section(section.name, getattr(config, section.name))
    _check_relations(config)
    return config


def config_with(config: Config, overrides: dict[str, dict[str, Any]]) -> Config:
    """``config`` with some keys replaced, validated as a file would be, e.g.
    ``config_with(config, {"mapping": {"map_voxel_m": 0.1}})`` (how command-line flags enter)."""
    data = dataclasses.asdict(config)
    for section, values in overrides.items():
        data.setdefault(section, {})
        if not isinstance(data[section], dict) or not isinstance(values, dict):
            raise ConfigError(f"config {section}: expected a table")
        data[section].update(values)
    return config_from_dict(data)


def load_config(path: str | Path | None) -> Config:
    """Load a TOML configuration file; ``None`` gives the defaults."""
    if path is None:
        return Config()
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path}: not UTF-8 text (byte {err.start})") from None
    except OSError as err:
        raise ConfigError(f"{path}: cannot read config file: {err.strerror}") from err
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from err
    except RecursionError:
        raise ConfigError(f"{path}: not valid TOML: arrays or tables nested too deeply") from None
    try:
        return config_from_dict(data)
    except ConfigError as err:
        raise ConfigError(f"{path}: {err}") from err


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        escaped = value.replace("\\", "\\\\").replace('"', '\\"')
        escaped = "".join(f"\\u{ord(c):04x}" if ord(c) < 0x20 or ord(c) == 0x7F else c for c in escaped)
        return f'"{escaped}"'
    if isinstance(value, tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} as TOML")


def _describe_sensor(sensor: SensorModel) -> str:
    """One line with a sensor's geometry, e.g. ``vlp16, 16 rings -15.0..15.0 deg, 1800 columns, ...``."""
    return (
        f"{sensor.name}, {sensor.n_rings} rings {sensor.elevation_deg[0]}..{sensor.elevation_deg[-1]} deg, "
        f"{sensor.n_columns} columns, {sensor.rotation_hz} Hz, max range {sensor.max_range_m} m"
    )


def config_to_toml(config: Config) -> str:
    """The configuration as TOML text that :func:`load_config` reads back to an equal object.

    Each numeric or choice key ends with a comment giving its allowed values; the ``[sensor]``
    section ends with a comment giving the resolved sensor geometry (preset plus overrides), so the
    numbers in force are visible even where an override is left at "preset".
    """
    lines = ["# lidar3d configuration (every key optional; these are the values in force, each followed by its range)"]
    for section in dataclasses.fields(config):
        lines.append("")
        lines.append(f"[{section.name}]")
        values = getattr(config, section.name)
        for f in dataclasses.fields(values):
            line = f"{f.name} = {_toml_value(getattr(values, f.name))}"
            valid = f.metadata["valid"]
            lines.append(f"{line}  # {valid}" if valid is not None else line)
        if isinstance(values, SensorConfig):
            lines.append("# 0 or [] in an *_override* key keeps the preset's value; the geometry in force:")
            lines.append(f"# {_describe_sensor(values.resolved_model)}")
    return "\n".join(lines) + "\n"
