"""Write a simulated drive into a folder, and :func:`simulate`, the library twin of ``lidar3d simulate``.

Folder contents (every file written atomically; ``metadata.json`` last, so its presence marks a
complete folder):

===========================  ==========================================================================
``scans.bag``                ROS1 bag, ``/velodyne_points`` (sensor_msgs/PointCloud2, velodyne layout,
                             frame ``velodyne``, stamp = sweep start or end, see ``metadata.json``
                             ``stamps``); ``scans/`` for ROS2 (a bag folder)
``ground_truth_tum.txt``     true lidar pose at every scan stamp, TUM (world = local ENU at the origin)
``novatel_span.log``         NovAtel SPAN-CPT ASCII: #INSPVAXA 20 Hz, #BESTPOSA 1 Hz, CRC-32, CR LF
``extrinsics.toml``          ``T_imu_lidar`` (lidar pose in the SPAN vehicle frame)
``metadata.json``            scenario, seed, sensor, counts, length, duration, stamps, stops, origin,
                             revisits, world (triangles, objects, glass, moving actors), parameters
``point_labels.npz``         only with ``labels=True`` (``lidar3d simulate --labels``): what every point
                             of the bag hit, in bag order (:func:`read_point_labels`); ``metadata.json``
                             then names it under ``files.labels``
===========================  ==========================================================================

Without labels the folder is byte for byte what it always was.
"""

from __future__ import annotations

import dataclasses
import json
import logging
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

import numpy as np

from lidar3d.errors import OutputError, SimulationError
from lidar3d.gnss.extrinsic import write_extrinsic
from lidar3d.io.atomic import write_bytes_atomic, write_text_atomic
from lidar3d.io.bag_writer import write_scan_bag
from lidar3d.io.trajectory_io import write_tum
from lidar3d.sensors import SensorModel
from lidar3d.sim.lidar import LidarParams, StampMode
from lidar3d.sim.rig import RigParams
from lidar3d.sim.scenarios import DEFAULT_SCENARIO, Scenario
from lidar3d.sim.simulation import Simulation
from lidar3d.sim.span import SpanParams
from lidar3d.sim.trajectory import group_revisits
from lidar3d.sim.world import DYNAMIC_CLASSES, ObjectClass

__all__ = [
    "LABELS_NAME",
    "OUTPUT_NAMES",
    "BagFormat",
    "PointLabels",
    "SimulationOutputs",
    "read_point_labels",
    "simulate",
    "write_simulation",
]

logger = logging.getLogger(__name__)

TOPIC = "/velodyne_points"
FRAME_ID = "velodyne"
OUTPUT_NAMES = {
    "ground_truth": "ground_truth_tum.txt",
    "span_log": "novatel_span.log",
    "extrinsics": "extrinsics.toml",
    "metadata": "metadata.json",
}
LABELS_NAME = "point_labels.npz"


class BagFormat(str, Enum):
    """Bag flavours: ``ros2`` is ROS2 with the sqlite3 storage."""

    ROS1 = "ros1"
    ROS2 = "ros2"
    ROS2_MCAP = "ros2-mcap"

    @property
    def storage(self) -> str:
        return {"ros1": "ros1", "ros2": "ros2-sqlite3", "ros2-mcap": "ros2-mcap"}[self.value]

    @property
    def file_name(self) -> str:
        return "scans.bag" if self is BagFormat.ROS1 else "scans"


@dataclass(frozen=True, slots=True)
class SimulationOutputs:
    """Paths of one simulation folder and a few numbers about it."""

    out_dir: Path
    bag: Path
    ground_truth: Path
    span_log: Path
    extrinsics: Path
    metadata: Path
    n_scans: int
    n_points: int
    labels: Path | None = None


@dataclass(frozen=True, slots=True)
class PointLabels:
    """What every point of a simulated bag hit (``point_labels.npz``), in bag order.

    Attributes:
        stamps_ns: (S,) header stamp of each scan.
        n_points: (S,) points of each scan (the labels of scan k follow those of scans 0..k-1).
        object_id: (N,) int32 object each point hit (0 = ground; ids after the world's objects are moving actors).
        object_class: (N,) uint8 :class:`~lidar3d.sim.world.ObjectClass` of that object.
    """

    stamps_ns: np.ndarray
    n_points: np.ndarray
    object_id: np.ndarray
    object_class: np.ndarray

    @property
    def dynamic_mask(self) -> np.ndarray:
        """(N,) bool: the point lies on a moving car or a pedestrian."""
        return np.isin(self.object_class, [int(c) for c in DYNAMIC_CLASSES])

    def of_scan(self, index: int) -> slice:
        """The slice of the labels of scan ``index``."""
        start = int(self.n_points[:index].sum())
        return slice(start, start + int(self.n_points[index]))


def read_point_labels(path: str | Path) -> PointLabels:
    """Read a ``point_labels.npz`` (or the folder holding one).

    Raises:
        OutputError: missing, unreadable, or its arrays do not fit together (one line).
    """
    path = Path(path)
    if path.is_dir():
        path = path / LABELS_NAME
    try:
        with np.load(path) as data:
            labels = PointLabels(data["stamps_ns"], data["n_points"], data["object_id"], data["object_class"])
    except (OSError, KeyError, ValueError) as err:
        raise OutputError(f"{path}: not a point label file ({err})") from None
    n = int(labels.n_points.sum())
    if (
        labels.object_id.shape != (n,)
        or labels.object_class.shape != (n,)
        or labels.stamps_ns.shape != labels.n_points.shape
    ):
        raise OutputError(f"{path}: the label arrays do not fit together")
    return labels


def _jsonable(value):
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.integer, np.floating)):
        return value.item()
    if isinstance(value, Enum):
        return value.value
    return value


def _metadata(sim: Simulation, bag_format: BagFormat, n_points: int) -> dict:
    gt = sim.ground_truth
    speed = np.linalg.norm(sim.motion.velocity_at(sim.route_seconds(gt.stamps_ns)), axis=1)
    events = group_revisits(sim.revisits())
    origin = sim.span_params.origin
    degraded = sim.degraded_gnss_span_ns()
    return {
        "format": "lidar3d-sim/1",
        "scenario": sim.scenario.name,
        "description": sim.scenario.description,
        "seed": sim.seed,
        "sensor": sim.sensor.name,
        "n_scans": len(sim),
        "n_points": n_points,
        "scan_period_s": sim.scan_period_ns * 1e-9,
        "first_stamp_ns": int(gt.stamps_ns[0]),
        "last_stamp_ns": int(gt.stamps_ns[-1]),
        "duration_s": sim.duration_s,
        "path_length_m": gt.path_length_m,
        "speed_mps": {"min": float(speed.min()), "mean": float(speed.mean()), "max": float(speed.max())},
        "stamps": _stamp_metadata(sim),
        "stops": [{"start_ns": int(start_ns), "end_ns": int(end_ns)} for start_ns, end_ns in sim.stop_spans_ns()],
        "frames": {
            "world": "local ENU (x east, y north, z up) at the geographic origin",
            "lidar": "REP-105 (x forward, y left, z up), frame_id velodyne",
            "imu": "SPAN vehicle frame (x right, y forward, z up)",
        },
        "origin": {
            "latitude_deg": origin.latitude_deg,
            "longitude_deg": origin.longitude_deg,
            "height_ellipsoid_m": origin.height_m,
            "undulation_m": origin.undulation_m,
        },
        "T_imu_lidar": sim.T_imu_lidar.tolist(),
        "imu_to_antenna_m": list(sim.rig.imu_to_antenna_m),
        "gnss": {
            "leap_seconds": sim.span_params.leap_seconds,
            "inspvax_rate_hz": sim.span_params.inspvax_rate_hz,
            "bestpos_rate_hz": sim.span_params.bestpos_rate_hz,
            "noise": sim.span_params.noise,
            "degraded_start_ns": degraded[0],
            "degraded_end_ns": degraded[1],
            "bag_clock_minus_utc_s": 0.0,
        },
        "files": {
            "bag": bag_format.file_name,
            "bag_format": bag_format.value,
            "topic": TOPIC,
            "frame_id": FRAME_ID,
            **OUTPUT_NAMES,
        },
        "revisits": [
            {
                "query_first": e[0].query_index,
                "query_last": e[-1].query_index,
                "match_first": e[0].match_index,
                "min_distance_m": min(p.distance_m for p in e),
                "pairs": [_jsonable(p) for p in e],
            }
            for e in events
        ],
        "world": {
            "n_triangles": int(len(sim.world.triangles)),
            "n_objects": sim.world.n_objects,
            "block_kinds": sim.world.block_kind.tolist(),
            "n_glass_triangles": int(np.count_nonzero(sim.world.triangle_glass)),
            "moving_actors": _actor_counts(sim),
        },
        "parameters": {
            "scenario": _jsonable(sim.scenario),
            "lidar": _jsonable(sim.lidar_params),
            "span": _jsonable(sim.span_params),
            "rig": _jsonable(sim.rig),
            "start_time_ns": sim.start_time_ns,
        },
    }


def _actor_counts(sim: Simulation) -> dict:
    """How many moving cars and pedestrians share the drive (their ids follow the world's objects)."""
    classes = [] if sim.traffic is None else sim.traffic.object_class.tolist()
    return {
        "moving_cars": classes.count(int(ObjectClass.MOVING_CAR)),
        "pedestrians": classes.count(int(ObjectClass.PEDESTRIAN)),
        "first_object_id": len(sim.world.object_class),
    }


def _stamp_metadata(sim: Simulation) -> dict:
    mode = StampMode(sim.lidar_params.stamp)
    marks = {
        StampMode.SWEEP_START: "firing time of the sweep's first column; point times 0..T after the sweep start",
        StampMode.SWEEP_END: "firing time of the sweep's last column; point times -T..0 relative to it",
    }[mode]
    return {
        "mode": mode.value,
        "header_stamp": marks,
        "jitter_s": sim.lidar_params.stamp_jitter_s,
        "jitter": "stamp = true instant + uniform error in [-jitter, +jitter]; point times are relative to "
        "the true instant, not to the stamp",
        "ground_truth": "true lidar pose at each header stamp",
    }


def write_simulation(
    sim: Simulation,
    out_dir: str | Path,
    *,
    bag_format: str | BagFormat = BagFormat.ROS1,
    overwrite: bool = False,
    labels: bool = False,
) -> SimulationOutputs:
    """Generate every scan of ``sim`` and write the output folder (with ``labels``, also
    ``point_labels.npz``: what each point hit).

    Raises:
        OutputError: the folder already holds a simulation and ``overwrite`` is false, or a file
            cannot be written.
        SimulationError: unknown bag format.
    """
    try:
        fmt = BagFormat(bag_format)
    except ValueError:
        known = ", ".join(f.value for f in BagFormat)
        raise SimulationError(f"unknown bag format {bag_format!r}; choose one of: {known}") from None
    out = Path(out_dir)
    paths = {key: out / name for key, name in OUTPUT_NAMES.items()}
    bag = out / fmt.file_name
    existing = [p for p in (*paths.values(), bag) if p.exists()]
    if existing and not overwrite:
        raise OutputError(
            f"{out}: already holds simulation outputs ({existing[0].name}); pass --overwrite to replace them"
        )
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder")
    n_points = 0
    label_parts: list[tuple[int, np.ndarray, np.ndarray]] = []

    def counted():
        nonlocal n_points
        for simulated in sim.scans():
            n_points += len(simulated.scan)
            if labels:
                label_parts.append((simulated.scan.stamp_ns, simulated.object_id, simulated.object_class))
            if simulated.index % 100 == 0:
                logger.debug("scan %d / %d", simulated.index, len(sim))
            yield simulated.scan

    logger.info(
        "simulating %s (seed %d, %s): %d scans over %.1f s",
        sim.scenario.name,
        sim.seed,
        sim.sensor.name,
        len(sim),
        sim.duration_s,
    )
    write_scan_bag(bag, counted(), topic=TOPIC, frame_id=FRAME_ID, storage=fmt.storage, overwrite=overwrite)
    write_tum(paths["ground_truth"], sim.ground_truth)
    write_bytes_atomic(paths["span_log"], "".join(sim.span_log_lines()).encode("ascii"))
    write_extrinsic(paths["extrinsics"], sim.T_imu_lidar)
    metadata = _metadata(sim, fmt, n_points)
    labels_path = None
    if labels:
        labels_path = out / LABELS_NAME
        _write_labels(labels_path, label_parts)
        metadata["files"]["labels"] = LABELS_NAME
    write_text_atomic(paths["metadata"], json.dumps(metadata, indent=1) + "\n")
    logger.info("wrote %s (%d scans, %d points)", out, len(sim), n_points)
    return SimulationOutputs(
        out_dir=out,
        bag=bag,
        ground_truth=paths["ground_truth"],
        span_log=paths["span_log"],
        extrinsics=paths["extrinsics"],
        metadata=paths["metadata"],
        n_scans=len(sim),
        n_points=n_points,
        labels=labels_path,
    )


def _write_labels(path: Path, parts: list[tuple[int, np.ndarray, np.ndarray]]) -> None:
    import io

    buffer = io.BytesIO()
    np.savez_compressed(
        buffer,
        stamps_ns=np.array([stamp for stamp, _, _ in parts], dtype=np.int64),
        n_points=np.array([len(ids) for _, ids, _ in parts], dtype=np.int64),
        object_id=np.concatenate([ids for _, ids, _ in parts]).astype(np.int32) if parts else np.zeros(0, np.int32),
        object_class=np.concatenate([c for _, _, c in parts]).astype(np.uint8) if parts else np.zeros(0, np.uint8),
    )
    write_bytes_atomic(path, buffer.getvalue())


def simulate(
    scenario: str | Scenario = DEFAULT_SCENARIO,
    out_dir: str | Path = "sim_output",
    *,
    seed: int = 0,
    duration_s: float | None = None,
    bag_format: str | BagFormat = BagFormat.ROS1,
    sensor: str | SensorModel = "vlp16",
    overwrite: bool = False,
    lidar: LidarParams | None = None,
    span: SpanParams | None = None,
    rig: RigParams | None = None,
    labels: bool = False,
) -> SimulationOutputs:
    """Simulate ``scenario`` and write its folder; the library twin of ``lidar3d simulate``
    (``labels``: also ``point_labels.npz``, what each point hit).

    Example:
        >>> outputs = simulate("loop", "out/loop", seed=0, duration_s=20.0)  # doctest: +SKIP
        >>> outputs.bag
        PosixPath('out/loop/scans.bag')
    """
    sim = Simulation(scenario, seed=seed, duration_s=duration_s, sensor=sensor, lidar=lidar, span=span, rig=rig)
    return write_simulation(sim, out_dir, bag_format=bag_format, overwrite=overwrite, labels=labels)
