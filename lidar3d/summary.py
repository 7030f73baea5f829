"""The run summary: :class:`RunSummary`, the typed form of a run folder's ``summary.json``.

``lidar3d run`` (:func:`lidar3d.run.run_bag`) builds one and writes :meth:`RunSummary.to_json`;
everything that reads a run folder (CLI, batch, evaluation scripts) goes through
:func:`read_summary` / :meth:`RunSummary.from_json`, which validate the file and name what is
wrong in one line (:class:`~lidar3d.errors.SummaryError`). Nothing else reads ``summary.json`` by key.

Layout of ``summary.json`` (keys in this order; optional keys are left out when they do not apply)::

    lidar3d_version, inputs, topic, partial, scans, keyframes, length_m, duration_s, runtime_s,
    scans_per_s, stage_ms_median {read, projection, ground, clustering, smoothness, selection,
    deskew, odometry, mapping, map_update[, redeskew, dense_map]}, map_points, loop_closures, loop_candidates,
    loop_ms_total, counts {scans[, redeskewed_scans, motion_model_scans, degenerate_scans,
    loop_closures, dropped_duplicate_stamps, dropped_out_of_order_stamps]}, warnings, pose_stamp
    [, health {ok_scans, degraded_scans, lost_scans, ok_fraction, lost_m, lost_stretches [{first_scan,
    last_scan, start_stamp_ns, end_stamp_ns, length_m}, ...], degraded_m, degraded_stretches [...]}]
    [, input_stats {points_kept, nonfinite_dropped, below_min_range_dropped, absurd_coordinates_dropped,
    outlier_times_dropped, messages_lost, scans_timed_from_azimuth}]
    [, map_rebuild_s] [, evaluation {report, table, ate {translation_3d_m, horizontal_m,
    vertical_m, rotation_deg: {rmse, mean, median, std, min, max, n}}}] [, evaluation_error]
    [, outputs {<path>: {size_bytes, sha256[, rows]}, ...}]

``outputs`` is the manifest of the run folder: every file of the set beside ``summary.json``
(relative path, ``/``-separated), with what it holds. :mod:`lidar3d.io.run_folder` publishes a
set and tells whether a folder is consistent with its summary.

This module uses the standard library only: the batch runner imports it before worker processes
have limited their BLAS threads.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from lidar3d.errors import SummaryError

__all__ = [
    "AteSummary",
    "ErrorSummary",
    "EvaluationSummary",
    "HealthStretch",
    "HealthSummary",
    "InputStatistics",
    "OutputFile",
    "RunCounts",
    "RunSummary",
    "StageMedians",
    "read_summary",
]

_T = TypeVar("_T")


class _JsonObject:
    """A JSON object being parsed: typed access by key, errors that name the file and the dotted key."""

    def __init__(self, data: Any, key: str, source: str) -> None:
        self.source = source
        self.key = key
        if not isinstance(data, dict):
            raise self.error(f"'{key}' must be an object, got {_describe(data)}" if key else "not a JSON object")
        self.data = data
        self.used: set[str] = set()

    def error(self, message: str) -> SummaryError:
        return SummaryError(f"{self.source}: {message}")

    def dotted(self, name: str) -> str:
        return f"{self.key}.{name}" if self.key else name

    def _get(self, name: str, check: Callable[[Any], bool], kind: str, required: bool) -> Any:
        self.used.add(name)
        if name not in self.data:
            if required:
                raise self.error(f"key '{self.dotted(name)}' is missing")
            return None
        value = self.data[name]
        if not check(value):
            raise self.error(f"'{self.dotted(name)}' must be {kind}, got {_describe(value)}")
        return value

    def text(self, name: str) -> str:
        return self._get(name, lambda v: isinstance(v, str), "a string", True)

    def optional_text(self, name: str) -> str | None:
        return self._get(name, lambda v: isinstance(v, str), "a string", False)

    def flag(self, name: str) -> bool:
        return self._get(name, lambda v: isinstance(v, bool), "true or false", True)

    def integer(self, name: str) -> int:
        return self._get(name, _is_integer, "an integer", True)

    def optional_integer(self, name: str) -> int | None:
        return self._get(name, _is_integer, "an integer", False)

    def number(self, name: str) -> float:
        return float(self._get(name, _is_number, "a number", True))

    def optional_number(self, name: str) -> float | None:
        value = self._get(name, _is_number, "a number", False)
        return None if value is None else float(value)

    def number_or_null(self, name: str) -> float | None:
        """A required key whose value is a number or null (a statistic of no samples)."""
        value = self._get(name, lambda v: v is None or _is_number(v), "a number or null", True)
        return None if value is None else float(value)

    def texts(self, name: str) -> tuple[str, ...]:
        return tuple(self._get(name, _is_list_of_strings, "a list of strings", True))

    def record(self, name: str, parse: Callable[[_JsonObject], _T]) -> _T:
        self.used.add(name)
        if name not in self.data:
            raise self.error(f"key '{self.dotted(name)}' is missing")
        return parse(_JsonObject(self.data[name], self.dotted(name), self.source))

    def optional_record(self, name: str, parse: Callable[[_JsonObject], _T]) -> _T | None:
        return self.record(name, parse) if name in self.data else None

    def records(self, name: str, parse: Callable[[_JsonObject], _T]) -> tuple[_T, ...]:
        """A required list of objects, each parsed by ``parse`` (errors name ``key[i]``)."""
        items = self._get(name, lambda v: isinstance(v, list), "a list", True)
        return tuple(parse(_JsonObject(item, f"{self.dotted(name)}[{i}]", self.source)) for i, item in enumerate(items))

    def optional_records(self, name: str, parse: Callable[[_JsonObject], _T]) -> tuple[_T, ...]:
        """:meth:`records`, or no record when the key is absent."""
        return self.records(name, parse) if name in self.data else ()

    def finish(self) -> None:
        """Reject keys that no field took (a misspelt or foreign key)."""
        unknown = [name for name in self.data if name not in self.used]
        if unknown:
            raise self.error(f"unknown key '{self.dotted(unknown[0])}'")


def _is_integer(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_list_of_strings(value: Any) -> bool:
    return isinstance(value, list) and all(isinstance(item, str) for item in value)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _describe(value: Any) -> str:
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


@dataclass(frozen=True, slots=True)
class StageMedians:
    """Median wall time per scan of each stage, milliseconds, rounded to 0.001 ms.

    Attributes:
        read: reading and decoding the scan from the bag (0 when no scan was read).
        projection, ground, clustering, smoothness, selection: the front-end sub-stages
            (range image, ground segmentation, clustering, smoothness, feature selection).
        deskew: deskewing the features with the predicted motion.
        odometry: scan-to-scan odometry.
        mapping: scan-to-submap refinement.
        map_update: publishing the scan into the submap and the dense map.
        redeskew: re-registration of the previous scan with its forward motion (None: never ran).
        dense_map: adding a settled sweep to the dense map (deskewing, the dynamic-object filter,
            the voxel maps), in the map's worker thread beside the tracking (None: not recorded).
    """

    read: float
    projection: float
    ground: float
    clustering: float
    smoothness: float
    selection: float
    deskew: float
    odometry: float
    mapping: float
    map_update: float
    redeskew: float | None = None
    dense_map: float | None = None

    def as_dict(self) -> dict[str, float]:
        """Stage name -> median ms, as ``summary.json`` holds it (stages that never ran left out)."""
        medians = {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}
        return {stage: ms for stage, ms in medians.items() if ms is not None}

    @classmethod
    def _parse(cls, obj: _JsonObject) -> StageMedians:
        optional = ("redeskew", "dense_map")
        required = {
            field.name: obj.number(field.name) for field in dataclasses.fields(cls) if field.name not in optional
        }
        parsed = cls(**required, redeskew=obj.optional_number("redeskew"), dense_map=obj.optional_number("dense_map"))
        obj.finish()
        return parsed


@dataclass(frozen=True, slots=True)
class RunCounts:
    """The pipeline's event counters over the run (a counter that never fired is 0).

    Attributes:
        scans: scans processed (dropped stamps excluded).
        redeskewed_scans: scans re-registered with their forward motion.
        motion_model_scans: scans whose pose came from the motion model (too few features).
        degenerate_scans: scans whose registration left some direction unconstrained.
        loop_closures: accepted loop closures.
        dropped_duplicate_stamps: scans dropped because their stamp repeated the previous one.
        dropped_out_of_order_stamps: scans dropped because their stamp went backwards.
    """

    scans: int = 0
    redeskewed_scans: int = 0
    motion_model_scans: int = 0
    degenerate_scans: int = 0
    loop_closures: int = 0
    dropped_duplicate_stamps: int = 0
    dropped_out_of_order_stamps: int = 0

    def as_dict(self) -> dict[str, int]:
        """Counter name -> count, as ``summary.json`` holds it (counters that never fired left out)."""
        counts = {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}
        return {name: count for name, count in counts.items() if count}

    @classmethod
    def _parse(cls, obj: _JsonObject) -> RunCounts:
        values = {field.name: obj.optional_integer(field.name) for field in dataclasses.fields(cls)}
        obj.finish()
        return cls(**{name: value for name, value in values.items() if value is not None})


@dataclass(frozen=True, slots=True)
class InputStatistics:
    """What reading the input dropped and kept, over the whole run (counts).

    Attributes:
        points_kept: points that entered the front end.
        nonfinite_dropped: points dropped for a NaN or infinite coordinate.
        below_min_range_dropped: points dropped for being closer than the sensor's minimum range.
        absurd_coordinates_dropped: points dropped for a coordinate no sensor measures (beyond 1 km,
            or twice the sensor's maximum range when that is farther).
        outlier_times_dropped: points dropped for a non-finite time or one more than 1.5 sweep
            periods from the scan's stamp.
        messages_lost: messages lost to damage in the bag (recovered bags).
        scans_timed_from_azimuth: scans without a usable per-point time field (none, all one value
            such as zeros, or absolute times too coarse), whose point times were derived from the
            azimuth, taking the header stamp as the sweep start.
    """

    points_kept: int
    nonfinite_dropped: int
    below_min_range_dropped: int
    absurd_coordinates_dropped: int
    outlier_times_dropped: int
    messages_lost: int
    scans_timed_from_azimuth: int

    def as_dict(self) -> dict[str, int]:
        return {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}

    def damage_warning(self) -> str | None:
        """One warning line when points were dropped as damaged (absurd coordinates, outlier times);
        None otherwise. Non-finite points alone make no warning: drivers write NaN for missing
        returns in organised clouds."""
        if not (self.absurd_coordinates_dropped or self.outlier_times_dropped):
            return None
        return (
            f"input sanity: dropped {self.absurd_coordinates_dropped} points with absurd coordinates and "
            f"{self.outlier_times_dropped} with point times outside the sweep ({self.nonfinite_dropped} "
            "non-finite points also dropped); see input_stats in summary.json"
        )

    def timing_warning(self) -> str | None:
        """One warning line when point times were derived from the azimuth for some scans; None otherwise."""
        if not self.scans_timed_from_azimuth:
            return None
        return (
            f"input: {self.scans_timed_from_azimuth} scans had no usable per-point times (no time field, one "
            "value for every point, or absolute times too coarse); their point times were derived from the "
            "azimuth, with the header stamp taken as input.azimuth_stamp says; see input_stats in summary.json"
        )

    @classmethod
    def _parse(cls, obj: _JsonObject) -> InputStatistics:
        parsed = cls(**{field.name: obj.integer(field.name) for field in dataclasses.fields(cls)})
        obj.finish()
        return parsed


@dataclass(frozen=True, slots=True)
class HealthStretch:
    """A stretch of consecutive scans given one flag (lost, or degraded) by the health signal.

    Attributes:
        first_scan, last_scan: input scan numbers of its first and last scan (as in the warnings).
        start_stamp_ns, end_stamp_ns: stamps of those scans.
        length_m: path length of the trajectory over the stretch, from the scan before it to its last
            scan, metres (rounded to 1 mm).
    """

    first_scan: int
    last_scan: int
    start_stamp_ns: int
    end_stamp_ns: int
    length_m: float

    def as_dict(self) -> dict[str, int | float]:
        return {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}

    @classmethod
    def _parse(cls, obj: _JsonObject) -> HealthStretch:
        parsed = cls(
            first_scan=obj.integer("first_scan"),
            last_scan=obj.integer("last_scan"),
            start_stamp_ns=obj.integer("start_stamp_ns"),
            end_stamp_ns=obj.integer("end_stamp_ns"),
            length_m=obj.number("length_m"),
        )
        obj.finish()
        return parsed


@dataclass(frozen=True, slots=True)
class HealthSummary:
    """The per-scan health flags of a run (``health.csv``), counted.

    Attributes:
        ok_scans, degraded_scans, lost_scans: scans with each flag (they add up to the run's scans).
        ok_fraction: ``ok_scans`` / scans (rounded to 0.0001; 1.0 for a run without scans).
        lost_m: path length over the lost stretches, metres (rounded to 1 mm).
        lost_stretches: every stretch of consecutive lost scans, in order.
        degraded_m, degraded_stretches: the same for the degraded scans (a summary written before
            this field existed reads as 0.0 and no stretch).
    """

    ok_scans: int
    degraded_scans: int
    lost_scans: int
    ok_fraction: float
    lost_m: float
    lost_stretches: tuple[HealthStretch, ...] = ()
    degraded_m: float = 0.0
    degraded_stretches: tuple[HealthStretch, ...] = ()

    @property
    def scans(self) -> int:
        return self.ok_scans + self.degraded_scans + self.lost_scans

    def as_dict(self) -> dict[str, Any]:
        data: dict[str, Any] = {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}
        data["lost_stretches"] = [stretch.as_dict() for stretch in self.lost_stretches]
        data["degraded_stretches"] = [stretch.as_dict() for stretch in self.degraded_stretches]
        return data

    @classmethod
    def _parse(cls, obj: _JsonObject) -> HealthSummary:
        parsed = cls(
            ok_scans=obj.integer("ok_scans"),
            degraded_scans=obj.integer("degraded_scans"),
            lost_scans=obj.integer("lost_scans"),
            ok_fraction=obj.number("ok_fraction"),
            lost_m=obj.number("lost_m"),
            lost_stretches=obj.records("lost_stretches", HealthStretch._parse),
            degraded_m=obj.optional_number("degraded_m") or 0.0,
            degraded_stretches=obj.optional_records("degraded_stretches", HealthStretch._parse),
        )
        obj.finish()
        return parsed


@dataclass(frozen=True, slots=True)
class ErrorSummary:
    """Statistics of one error over the associated poses, in the unit its name in :class:`AteSummary`
    gives (m or deg); every statistic but ``n`` is None when no pose was associated."""

    rmse: float | None
    mean: float | None
    median: float | None
    std: float | None
    min: float | None
    max: float | None
    n: int

    def as_dict(self) -> dict[str, float | int | None]:
        return {field.name: getattr(self, field.name) for field in dataclasses.fields(self)}

    @classmethod
    def _parse(cls, obj: _JsonObject) -> ErrorSummary:
        parsed = cls(
            rmse=obj.number_or_null("rmse"),
            mean=obj.number_or_null("mean"),
            median=obj.number_or_null("median"),
            std=obj.number_or_null("std"),
            min=obj.number_or_null("min"),
            max=obj.number_or_null("max"),
            n=obj.integer("n"),
        )
        obj.finish()
        return parsed


@dataclass(frozen=True, slots=True)
class AteSummary:
    """Absolute trajectory error against the GNSS/INS reference, after alignment.

    Attributes:
        translation_3d_m: 3-D position error, metres.
        horizontal_m: east-north position error, metres.
        vertical_m: height error, metres.
        rotation_deg: rotation error angle, degrees.
    """

    translation_3d_m: ErrorSummary
    horizontal_m: ErrorSummary
    vertical_m: ErrorSummary
    rotation_deg: ErrorSummary

    def as_dict(self) -> dict[str, dict[str, float | int | None]]:
        return {field.name: getattr(self, field.name).as_dict() for field in dataclasses.fields(self)}

    @classmethod
    def _parse(cls, obj: _JsonObject) -> AteSummary:
        parsed = cls(**{field.name: obj.record(field.name, ErrorSummary._parse) for field in dataclasses.fields(cls)})
        obj.finish()
        return parsed


@dataclass(frozen=True, slots=True)
class EvaluationSummary:
    """The evaluation against a SPAN log, as the run's summary keeps it.

    Attributes:
        report: folder of the full evaluation report (``report.json``, CSV, plots).
        table: the ATE/RPE table as printed by ``lidar3d run``, several lines.
        ate: the ATE statistics (the ``ate`` section of ``report.json``).
    """

    report: str
    table: str
    ate: AteSummary

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, source: str | Path = "evaluation") -> EvaluationSummary:
        """The record of the JSON-like dict ``{"report", "table", "ate"}``; raises :class:`SummaryError`."""
        return cls._parse(_JsonObject(dict(data), "", str(source)))

    def as_dict(self) -> dict[str, Any]:
        return {"report": self.report, "table": self.table, "ate": self.ate.as_dict()}

    @classmethod
    def _parse(cls, obj: _JsonObject) -> EvaluationSummary:
        parsed = cls(report=obj.text("report"), table=obj.text("table"), ate=obj.record("ate", AteSummary._parse))
        obj.finish()
        return parsed


@dataclass(frozen=True, slots=True)
class OutputFile:
    """One file of a run folder, as the folder's summary describes it.

    Attributes:
        path: relative to the run folder, ``/``-separated (``"map.pcd"``, ``"eval/report.json"``).
        size_bytes: size of the file, bytes.
        sha256: SHA-256 of the file's content, 64 lower-case hex digits.
        rows: what the file holds, counted: poses of a trajectory file, points of ``map.pcd``,
            candidates of ``loops.csv`` (None for other files).
    """

    path: str
    size_bytes: int
    sha256: str
    rows: int | None = None

    def __post_init__(self) -> None:
        parts = self.path.split("/")
        if not self.path or "\\" in self.path or any(part in ("", ".", "..") or part.startswith(".") for part in parts):
            raise SummaryError(f"output path {self.path!r} is not a plain relative path inside the run folder")

    def as_dict(self) -> dict[str, int | str]:
        data: dict[str, int | str] = {"size_bytes": self.size_bytes, "sha256": self.sha256}
        if self.rows is not None:
            data["rows"] = self.rows
        return data

    @classmethod
    def _parse(cls, path: str, obj: _JsonObject) -> OutputFile:
        sha256 = obj.text("sha256")
        if len(sha256) != 64 or any(c not in "0123456789abcdef" for c in sha256):
            raise obj.error(f"'{obj.dotted('sha256')}' must be 64 lower-case hex digits")
        try:
            parsed = cls(
                path=path, size_bytes=obj.integer("size_bytes"), sha256=sha256, rows=obj.optional_integer("rows")
            )
        except SummaryError as err:
            raise obj.error(str(err)) from None
        obj.finish()
        return parsed


def _parse_outputs(obj: _JsonObject) -> tuple[OutputFile, ...]:
    """The ``outputs`` manifest: path -> file record, in the order written."""

    def parser(path: str) -> Callable[[_JsonObject], OutputFile]:
        return lambda entry: OutputFile._parse(path, entry)

    files = tuple(obj.record(path, parser(path)) for path in obj.data)
    obj.finish()
    return files


@dataclass(frozen=True, slots=True)
class RunSummary:
    """What one run did, as written to ``summary.json`` (see the module docstring for the layout).

    Attributes:
        lidar3d_version: version of lidar3d that made the run.
        inputs: the input bag path(s), as given.
        topic: the PointCloud2 topic read ("" when no bag opened).
        partial: True when the run stopped before the end of its input (checkpoint, error, Ctrl-C).
        scans: scans with a pose in the trajectory.
        keyframes: keyframes selected.
        length_m: path length of the trajectory, metres (rounded to 1 mm).
        duration_s: time from the first to the last scan, seconds (rounded to 1 ms).
        runtime_s: wall time of the run up to this summary, seconds (rounded to 1 ms).
        scans_per_s: ``scans / runtime_s``, scans per second (rounded to 0.01).
        stage_ms_median: median milliseconds per scan of each stage.
        map_points: points of the dense map (``map.pcd``).
        loop_closures: accepted loop closures.
        loop_candidates: verified loop candidates, accepted or rejected (``loops.csv``).
        loop_ms_total: time spent in loop detection and the pose graph, milliseconds (rounded to 0.1).
        counts: the pipeline's event counters.
        warnings: warnings of the run, one line each.
        pose_stamp: which instant of a scan each pose belongs to, in words.
        health: the per-scan health flags counted, with the lost stretches (None: a summary from
            before the health signal).
        input_stats: what reading the input dropped and kept (None until the input was read to its end).
        map_rebuild_s: time to place the dense map again from its keyframe pieces after loop
            closures, seconds, rounded to 1 ms (None: no loop closed).
        dynamic_points: points of ``dynamic.pcd``, the points the dynamic-object removal took out of
            ``map.pcd`` (None: removal off, ``lidar3d run --keep-dynamic``, or a summary from before it).
        evaluation: the evaluation against a SPAN log (None: not evaluated).
        evaluation_error: why the evaluation failed, one line (None: it did not fail; set by a batch).
        outputs: the manifest of the run folder: every other file of the set, with its size, hash
            and rows, sorted by path (empty: not published yet, or a summary from before manifests).
    """

    lidar3d_version: str
    inputs: tuple[str, ...]
    topic: str
    partial: bool
    scans: int
    keyframes: int
    length_m: float
    duration_s: float
    runtime_s: float
    scans_per_s: float
    stage_ms_median: StageMedians
    map_points: int
    loop_closures: int
    loop_candidates: int
    loop_ms_total: float
    counts: RunCounts
    warnings: tuple[str, ...]
    pose_stamp: str
    health: HealthSummary | None = None
    input_stats: InputStatistics | None = None
    map_rebuild_s: float | None = None
    dynamic_points: int | None = None
    evaluation: EvaluationSummary | None = None
    evaluation_error: str | None = None
    outputs: tuple[OutputFile, ...] = ()

    def output(self, path: str) -> OutputFile | None:
        """The manifest entry of ``path`` (relative to the run folder), None when not in the set."""
        return next((entry for entry in self.outputs if entry.path == path), None)

    def to_json(self) -> str:
        """The text of ``summary.json``: indented by 2, ending with a newline; optional keys that
        are None left out."""
        data: dict[str, Any] = {
            "lidar3d_version": self.lidar3d_version,
            "inputs": list(self.inputs),
            "topic": self.topic,
            "partial": self.partial,
            "scans": self.scans,
            "keyframes": self.keyframes,
            "length_m": self.length_m,
            "duration_s": self.duration_s,
            "runtime_s": self.runtime_s,
            "scans_per_s": self.scans_per_s,
            "stage_ms_median": self.stage_ms_median.as_dict(),
            "map_points": self.map_points,
            "loop_closures": self.loop_closures,
            "loop_candidates": self.loop_candidates,
            "loop_ms_total": self.loop_ms_total,
            "counts": self.counts.as_dict(),
            "warnings": list(self.warnings),
            "pose_stamp": self.pose_stamp,
        }
        if self.health is not None:
            data["health"] = self.health.as_dict()
        if self.input_stats is not None:
            data["input_stats"] = self.input_stats.as_dict()
        if self.map_rebuild_s is not None:
            data["map_rebuild_s"] = self.map_rebuild_s
        if self.dynamic_points is not None:
            data["dynamic_points"] = self.dynamic_points
        if self.evaluation is not None:
            data["evaluation"] = self.evaluation.as_dict()
        if self.evaluation_error is not None:
            data["evaluation_error"] = self.evaluation_error
        if self.outputs:
            data["outputs"] = {entry.path: entry.as_dict() for entry in self.outputs}
        return json.dumps(data, indent=2) + "\n"

    @classmethod
    def from_json(cls, text: str, *, source: str | Path = "summary.json") -> RunSummary:
        """Parse and validate the text of a ``summary.json``; ``source`` names it in errors.

        Raises:
            SummaryError: not JSON, a key missing, unknown or of the wrong type (one line naming
                ``source`` and the dotted key).
        """
        name = str(source)
        try:
            data = json.loads(text)
        except ValueError as err:
            raise SummaryError(f"{name}: not valid JSON ({err})") from err
        obj = _JsonObject(data, "", name)
        summary = cls(
            lidar3d_version=obj.text("lidar3d_version"),
            inputs=obj.texts("inputs"),
            topic=obj.text("topic"),
            partial=obj.flag("partial"),
            scans=obj.integer("scans"),
            keyframes=obj.integer("keyframes"),
            length_m=obj.number("length_m"),
            duration_s=obj.number("duration_s"),
            runtime_s=obj.number("runtime_s"),
            scans_per_s=obj.number("scans_per_s"),
            stage_ms_median=obj.record("stage_ms_median", StageMedians._parse),
            map_points=obj.integer("map_points"),
            loop_closures=obj.integer("loop_closures"),
            loop_candidates=obj.integer("loop_candidates"),
            loop_ms_total=obj.number("loop_ms_total"),
            counts=obj.record("counts", RunCounts._parse),
            warnings=obj.texts("warnings"),
            pose_stamp=obj.text("pose_stamp"),
            health=obj.optional_record("health", HealthSummary._parse),
            input_stats=obj.optional_record("input_stats", InputStatistics._parse),
            map_rebuild_s=obj.optional_number("map_rebuild_s"),
            dynamic_points=obj.optional_integer("dynamic_points"),
            evaluation=obj.optional_record("evaluation", EvaluationSummary._parse),
            evaluation_error=obj.optional_text("evaluation_error"),
            outputs=obj.optional_record("outputs", _parse_outputs) or (),
        )
        obj.finish()
        return summary


def read_summary(path: str | Path) -> RunSummary:
    """The :class:`RunSummary` in the file ``path`` (a run folder's ``summary.json``).

    Raises:
        SummaryError: the file cannot be read or is not a valid summary (one line naming it).
    """
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as err:
        raise SummaryError(f"{path}: cannot read the run summary ({err.strerror or err})") from err
    return RunSummary.from_json(text, source=path)
