"""Configuration: one frozen dataclass section per stage, TOML in and out.

Defaults are LeGO-LOAM's VLP-16 values (``utility.h`` at commit 896a7a95, see
``shared/reference/lego-loam-and-peers.md``). A TOML file may override any subset; unknown keys
and wrongly typed values are rejected with the dotted path that is wrong.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import typing
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
    "Config",
    "FeatureConfig",
    "GnssConfig",
    "InputConfig",
    "LoopConfig",
    "MappingConfig",
    "OdometryConfig",
    "SegmentationConfig",
    "SensorConfig",
    "config_from_dict",
    "config_to_toml",
    "load_config",
]


@dataclass(frozen=True, slots=True)
class SensorConfig:
    """Sensor geometry: ``model`` names a preset of :data:`lidar3d.sensors.SENSOR_MODELS`; the
    ``*_override*`` fields replace single values of that preset, and their zero/empty default means
    "keep the preset's value". :attr:`resolved_model` is the geometry in force."""

    model: str = "vlp16"
    elevation_override_deg: tuple[float, ...] = ()  # beam elevation table (ascending); empty: the preset's
    n_columns_override: int = 0  # azimuth cells per sweep; 0: the preset's
    rotation_override_hz: float = 0.0  # sweeps per second; 0: the preset's
    max_range_override_m: float = 0.0  # farthest return kept; 0: the preset's rated range
    min_range_m: float = 1.0  # LeGO-LOAM sensorMinimumRange
    mount_pitch_deg: float = 0.0  # LeGO-LOAM sensorMountAngle
    mount_roll_deg: float = 0.0

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
    """How scans are read from bags."""

    topic: str = ""  # empty: auto-detect the only PointCloud2 topic


@dataclass(frozen=True, slots=True)
class SegmentationConfig:
    """Range-image ground segmentation and clustering (LeGO-LOAM imageProjection)."""

    ground_rows: int = 0  # 0: every beam below the horizon (VLP-16: rows 0..7, groundScanInd = 7)
    ground_angle_threshold_deg: float = 10.0
    ground_continuity: bool = True  # false: LeGO-LOAM's pairwise angle test alone
    ground_max_angle_change_deg: float = 5.0  # continuity: slope change between stacked pairs
    ground_height_slope_deg: float = 5.0  # continuity: a column's first run starts within margin +
    ground_height_margin_m: float = 0.2  # distance * tan(slope) of the scan's ground level
    ground_support_margin_m: float = 0.04  # contact: ground this close to its run's line stays ground
    ground_noise_m: float = 0.05  # continuity: height steps this small pass whatever their angle
    cluster_angle_deg: float = 60.0  # segmentTheta
    min_cluster_points: int = 30
    min_cluster_points_multi_ring: int = 5  # segmentValidPointNum
    min_cluster_rings: int = 3  # segmentValidLineNum
    ground_column_stride: int = 5  # ground kept on every 5th column in the segmented cloud
    outlier_column_stride: int = 5  # outlier cloud for mapping: every 5th column, rows >= ground_rows
    use_ring_field: bool = True  # rows from the ring field (useCloudRing); false: from elevation


@dataclass(frozen=True, slots=True)
class FeatureConfig:
    """Curvature features (LeGO-LOAM featureAssociation)."""

    curvature_half_window: int = 5
    edge_threshold: float = 0.1  # m^2, unnormalised curvature
    planar_threshold: float = 0.1
    sections_per_ring: int = 6
    sharp_per_section: int = 2
    less_sharp_per_section: int = 20
    flat_per_section: int = 4
    less_flat_voxel_m: float = 0.2
    occlusion_depth_m: float = 0.3
    parallel_beam_ratio: float = 0.02
    neighbour_max_column_gap: int = 10  # occlusion test and pick suppression stop at wider gaps


@dataclass(frozen=True, slots=True)
class OdometryConfig:
    """Scan-to-scan two-step odometry (LeGO-LOAM featureAssociation)."""

    max_iterations: int = 25  # per step
    rematch_every: int = 5  # correspondences recomputed every 5 iterations
    min_rows: int = 10
    degeneracy_threshold: float = 10.0
    search_radius_m: float = 5.0  # nearestFeatureSearchSqDist = 25 m^2
    min_previous_edges: int = 10
    min_previous_planes: int = 100


@dataclass(frozen=True, slots=True)
class MappingConfig:
    """Scan-to-submap refinement and keyframes (LeGO-LOAM mapOptmization, LIO-SAM keyframe rule)."""

    corner_voxel_m: float = 0.2
    surf_voxel_m: float = 0.4  # keyframe and submap surface clouds
    scan_surf_voxel_m: float = 0.8  # the current scan's surface points matched against the submap
    max_iterations: int = 10
    rematch_every: int = 2  # LeGO-LOAM rematches every iteration; every 2nd costs 25 % less, same accuracy
    min_rows: int = 50
    degeneracy_threshold: float = 100.0
    converge_rotation_deg: float = 0.05
    converge_translation_m: float = 0.0005
    # Submap planes: LeGO-LOAM fits 5 neighbours within 1 m; on a 16-beam scan those lie on one
    # or two ring lines, and the tilt noise of such small fits, shared by every scan matched
    # against the same keyframes, leaves a pitch offset of 0.2-0.5 deg (ours, loop and long).
    # 10 neighbours within 1.4 m cut it to 0.04-0.1 deg.
    plane_neighbours: int = 10
    plane_max_distance_m: float = 1.4
    level_normal_z: float = 0.9  # planes this level inform only z, roll, pitch (0: off)
    hold_yaw_min_degenerate: int = 2  # this many degenerate directions: yaw from the motion model (0: off)
    # Below this yaw rate the vehicle drives straight: degenerate directions take the motion
    # model's prediction and yaw may be held (above it the prediction lags the turn).
    straight_max_yaw_rate_deg_s: float = 5.0
    robust_scale_m: float = 0.05  # Geman-McClure scale; 0 selects LeGO-LOAM's 1 - 0.9|r| weight
    keyframe_distance_m: float = 1.0  # LIO-SAM surroundingkeyframeAddingDistThreshold
    keyframe_angle_deg: float = 11.46  # LIO-SAM 0.2 rad
    submap_radius_m: float = 50.0  # surroundingKeyframeSearchRadius
    submap_max_keyframes: int = 60
    submap_recent_keyframes: int = 10
    submap_cache_keyframes: int = 400
    submap_rebuild_every_keyframes: int = 3
    map_voxel_m: float = 0.2  # dense output map
    # A scan is registered deskewed with the motion model's prediction (the motion before it).
    # Once the next scan's pose is known, the motion over its own sweep is (forward difference);
    # when that moves some point of the sweep by redeskew_threshold_m more than the prediction did
    # (the angular part measured at redeskew_lever_m), the scan is deskewed again and re-registered
    # before it enters the map. Turn entries and exits, where the prediction lags a whole sweep.
    redeskew_threshold_m: float = 0.01
    redeskew_lever_m: float = 10.0
    redeskew_iterations: int = 4  # iteration limit of that second registration


@dataclass(frozen=True, slots=True)
class GnssConfig:
    """NovAtel SPAN ground truth and trajectory evaluation (lidar3d.gnss, lidar3d.metrics)."""

    leap_seconds: int = 18  # GPS - UTC; 18 s since 2017-01-01
    time_offset_s: float = 0.0  # bag clock minus GPS-derived UNIX time
    accepted_ins_statuses: tuple[str, ...] = ("INS_SOLUTION_GOOD",)
    require_fine_time: bool = True  # drop long-header solutions whose time status is below FINE
    max_association_gap_s: float = 0.2  # longest reference interval interpolated across
    origin: tuple[float, ...] = ()  # (lat_deg, lon_deg, h_ellipsoid_m); empty: first good fix
    align: str = "se3"  # se3 (Umeyama), yaw (4-DoF) or none
    rpe_segment_lengths_m: tuple[float, ...] = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
    rpe_step_s: float = 1.0  # KITTI: a segment start every 10 frames at 10 Hz
    rpe_distances_m: tuple[float, ...] = (10.0, 100.0)  # per fixed distance RPE (evo -d D -u m)


@dataclass(frozen=True, slots=True)
class LoopConfig:
    """Loop closure and pose graph (lidar3d.loop). Sources: LeGO-LOAM/LIO-SAM mapOptmization,
    hdl_graph_slam loop_detector, KISS-SLAM loop_closer (shared/reference/lego-loam-and-peers.md)."""

    enabled: bool = True
    search_radius_m: float = 7.0  # LeGO-LOAM historyKeyframeSearchRadius (LIO-SAM 15)
    horizontal_distance: bool = True  # hdl_graph_slam: (x, y) distance, blind to height drift
    min_time_gap_s: float = 30.0  # LeGO-LOAM / LIO-SAM historyKeyframeSearchTimeDiff
    max_candidates: int = 2  # verified per query keyframe, nearest first, until one is accepted
    cooldown_keyframes: int = 5  # after an accepted loop, skip this many query keyframes
    submap_neighbours: int = 10  # target = match +- this many keyframes (LeGO-LOAM +-25 at 0.3 m spacing)
    voxel_m: float = 0.4  # LeGO-LOAM loop target downsampling
    icp_method: str = "gicp"  # or "point_to_plane" (Open3D); GICP rotations were 10x closer on `long`
    icp_max_correspondence_m: tuple[float, ...] = (4.0, 2.0, 1.0, 0.5)  # coarse-to-fine stages
    icp_max_iterations: int = 30  # per stage
    normal_radius_m: float = 1.2  # target normals for point-to-plane
    min_source_points: int = 300  # LIO-SAM loop check
    min_target_points: int = 1000  # LIO-SAM loop check
    min_fitness: float = 0.7  # share of query points with a target point within the final distance
    max_rmse_m: float = 0.3  # inlier RMSE at the final distance (0.4 m voxel centroids: ~0.15 typical)
    min_overlap: float = 0.5  # voxel overlap |A & B| / min(|A|, |B|) (KISS-SLAM: 0.4)
    overlap_voxel_m: float = 1.0
    max_correction_m: float = 1.0  # ICP may move the guess this far ...
    correction_per_distance: float = 0.01  # ... plus 1 % of the path between the two keyframes
    max_correction_deg: float = 10.0
    information_points: int = 100  # effective independent correspondences behind the loop information
    min_sigma_translation_m: float = 0.02  # floor added to the loop covariance
    min_sigma_rotation_deg: float = 0.5  # one keyframe against a submap: trust its rotation to ~0.5 deg
    huber_k: float = 1.345  # Huber threshold on loop factors, in sigmas (hdl_graph_slam: 1.0)
    odometry_sigma_translation_m: float = 0.01  # per keyframe step (LeGO-LOAM/LIO-SAM variance 1e-4)
    odometry_sigma_rotation_deg: float = 0.05  # per keyframe step (LeGO-LOAM/LIO-SAM variance 1e-6 rad^2)
    relinearize_threshold: float = 0.01  # iSAM2 (LIO-SAM 0.1)
    extra_updates: int = 5  # iSAM2 updates after a loop (LIO-SAM 5)

    def __post_init__(self) -> None:
        if self.icp_method not in ("point_to_plane", "gicp"):
            raise ConfigError(f"config loop.icp_method: {self.icp_method!r} is not point_to_plane or gicp")
        if not self.icp_max_correspondence_m or min(self.icp_max_correspondence_m) <= 0:
            raise ConfigError("config loop.icp_max_correspondence_m: needs at least one positive distance")


@dataclass(frozen=True, slots=True)
class Config:
    """The whole configuration."""

    sensor: SensorConfig = field(default_factory=SensorConfig)
    input: InputConfig = field(default_factory=InputConfig)
    segmentation: SegmentationConfig = field(default_factory=SegmentationConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    mapping: MappingConfig = field(default_factory=MappingConfig)
    loop: LoopConfig = field(default_factory=LoopConfig)
    gnss: GnssConfig = field(default_factory=GnssConfig)


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
        if not math.isfinite(value):
            raise ConfigError(f"config {path}: expected a finite number, got {value!r}")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"config {path}: expected a string, got {value!r}")
        return value
    raise TypeError(f"unsupported config annotation {annotation!r} at {path}")


def _build(cls: type, data: dict[str, Any], path: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"config {path}: expected a table, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    for key in data:
        if key not in names:
            where = f"{path}.{key}" if path else key
            raise ConfigError(f"config: unknown key '{where}' (known: {', '.join(sorted(names))})")
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


def _validate(config: Config) -> Config:
    if config.sensor.model not in SENSOR_MODELS:
        raise ConfigError(
            f"config sensor.model: unknown model {config.sensor.model!r} (known: {', '.join(SENSOR_MODELS)})"
        )
    try:
        sensor = config.sensor.resolved_model
    except ValueError as err:
        raise ConfigError(f"config sensor: {err}") from err
    if config.segmentation.ground_rows > sensor.n_rings:
        raise ConfigError(
            f"config segmentation.ground_rows: {config.segmentation.ground_rows} exceeds the "
            f"{sensor.n_rings} rings of {sensor.name}"
        )
    return config


def config_from_dict(data: dict[str, Any]) -> Config:
    """Build a validated :class:`Config` from a nested dict (as parsed from TOML)."""
    return _validate(_build(Config, data, ""))


def load_config(path: str | Path | None) -> Config:
    """Load a TOML configuration file; ``None`` gives the defaults."""
    if path is None:
        return Config()
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except OSError as err:
        raise ConfigError(f"{path}: cannot read config file: {err.strerror}") from err
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ConfigError(f"{path}: not valid TOML: {err}") from err
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

    The ``[sensor]`` section ends with a comment giving the resolved sensor geometry (preset plus
    overrides), so the numbers in force are visible even where an override is left at "preset".
    """
    lines = ["# lidar3d configuration (every key optional; these are the values in force)"]
    for section in dataclasses.fields(config):
        lines.append("")
        lines.append(f"[{section.name}]")
        doc_fields = getattr(config, section.name)
        for f in dataclasses.fields(doc_fields):
            lines.append(f"{f.name} = {_toml_value(getattr(doc_fields, f.name))}")
        if isinstance(doc_fields, SensorConfig):
            lines.append("# 0 or [] in an *_override* key keeps the preset's value; the geometry in force:")
            lines.append(f"# {_describe_sensor(doc_fields.resolved_model)}")
    return "\n".join(lines) + "\n"
