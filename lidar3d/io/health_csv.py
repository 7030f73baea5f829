"""``health.csv``: the health of every scan of a run, one row per pose of the trajectory.

Columns (:data:`HEALTH_COLUMNS`): ``scan`` (input scan number), ``stamp_ns``, ``flag`` (ok /
degraded / lost), ``observed`` (0/1: the scan observed every direction of its pose),
``dead_reckoned_m`` and ``blind_m`` (travel with some direction dead-reckoned, and with the pose not
observed, since the pose was last fully observed), then the scan's measures: ``registered``,
``motion_model_only`` (0/1), ``rows``, ``prior_axes``, ``weakest_sigma_m`` (``inf`` when the
registration did not run), ``step_m``, ``odometry_disagreement_m``, ``prediction_offset_m``, ``probe_share`` (0 when the
registration did not run), ``heading_difference_deg`` (the refined step's yaw minus the odometry
step's), ``odometry_yaw_sigma_deg`` (``inf`` when the odometry measured no yaw),
``odometry_yaw_travel_deg`` (the yaw the odometry moved from its guess), ``along_difference_m``,
``odometry_along_sigma_m`` and ``odometry_along_travel_m`` (the same along the step), ``heading_z``
and ``along_z`` (how far the two parted over ``health.consistency_window_m``, in standard deviations),
``pose_sigma_m`` (the pose's standard deviation relative to the map, ``nan`` in tables of earlier
releases), ``lost_keyframes`` (keyframes placed while lost in the submap the scan was registered
against; 0 in tables of earlier releases). See
:mod:`lidar3d.mapping.health` for what each means.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lidar3d.errors import Lidar3dError
from lidar3d.io.atomic import write_text_atomic
from lidar3d.mapping.health import HealthFlag, ScanHealth, ScanMeasures

__all__ = ["HEALTH_COLUMNS", "HealthFileError", "read_health_csv", "write_health_csv"]

HEALTH_COLUMNS = (
    "scan",
    "stamp_ns",
    "flag",
    "observed",
    "dead_reckoned_m",
    "blind_m",
    "registered",
    "motion_model_only",
    "rows",
    "prior_axes",
    "weakest_sigma_m",
    "step_m",
    "odometry_disagreement_m",
    "prediction_offset_m",
    "probe_share",
    "heading_difference_deg",
    "odometry_yaw_sigma_deg",
    "odometry_yaw_travel_deg",
    "along_difference_m",
    "odometry_along_sigma_m",
    "odometry_along_travel_m",
    "heading_z",
    "along_z",
    "pose_sigma_m",
    "lost_keyframes",
)

#: The columns of earlier releases' tables, without the consistency test's, the pose uncertainty
#: or the lost keyframes: still read (those measures at their "not measured" defaults), so older
#: run folders can be scored.
_EARLIER_COLUMNS = (
    HEALTH_COLUMNS[: HEALTH_COLUMNS.index("heading_difference_deg")],
    HEALTH_COLUMNS[: HEALTH_COLUMNS.index("pose_sigma_m")],
    HEALTH_COLUMNS[: HEALTH_COLUMNS.index("lost_keyframes")],
)
_NOT_MEASURED = {
    "heading_difference_deg": "0",
    "odometry_yaw_sigma_deg": "inf",
    "odometry_yaw_travel_deg": "0",
    "along_difference_m": "0",
    "odometry_along_sigma_m": "inf",
    "odometry_along_travel_m": "0",
    "heading_z": "0",
    "along_z": "0",
    "pose_sigma_m": "nan",
    "lost_keyframes": "0",
}


class HealthFileError(Lidar3dError):
    """A ``health.csv`` is missing or malformed."""


def _number(value: float) -> str:
    return format(value, ".6g")


def write_health_csv(path: str | Path, scan_indices: Sequence[int] | np.ndarray, health: Sequence[ScanHealth]) -> None:
    """Write one row per scan (``scan_indices[i]`` is the input scan number of ``health[i]``), atomically."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(HEALTH_COLUMNS)
    for scan, h in zip(scan_indices, health, strict=True):
        m = h.measures
        writer.writerow(
            (
                int(scan),
                int(h.stamp_ns),
                h.flag.value,
                int(h.observed),
                f"{h.dead_reckoned_m:.3f}",
                f"{h.blind_m:.3f}",
                int(m.registered),
                int(m.motion_model_only),
                m.n_rows,
                m.prior_axes,
                _number(m.weakest_sigma_m),
                _number(m.step_m),
                _number(m.odometry_disagreement_m),
                _number(m.prediction_offset_m),
                _number(m.probe_share),
                _number(np.degrees(m.heading_difference_rad)),
                _number(np.degrees(m.odometry_yaw_sigma_rad)),
                _number(np.degrees(m.odometry_yaw_travel_rad)),
                _number(m.along_difference_m),
                _number(m.odometry_along_sigma_m),
                _number(m.odometry_along_travel_m),
                _number(h.heading_z),
                _number(h.along_z),
                _number(m.pose_sigma_m),
                m.lost_keyframes,
            )
        )
    write_text_atomic(path, buffer.getvalue())


def _flag(text: str) -> HealthFlag:
    try:
        return HealthFlag(text)
    except ValueError:
        raise ValueError(f"flag {text!r} is not one of {', '.join(f.value for f in HealthFlag)}") from None


def _boolean(text: str) -> bool:
    if text not in ("0", "1"):
        raise ValueError(f"{text!r} is not 0 or 1")
    return text == "1"


def _count(text: str) -> int:
    value = int(text)
    if value < 0:
        raise ValueError(f"{text!r} is not a count")
    return value


def _row(row: dict[str, str]) -> tuple[int, ScanHealth]:
    measures = ScanMeasures(
        registered=_boolean(row["registered"]),
        motion_model_only=_boolean(row["motion_model_only"]),
        n_rows=int(row["rows"]),
        prior_axes=int(row["prior_axes"]),
        weakest_sigma_m=float(row["weakest_sigma_m"]),
        step_m=float(row["step_m"]),
        odometry_disagreement_m=float(row["odometry_disagreement_m"]),
        prediction_offset_m=float(row["prediction_offset_m"]),
        probe_share=float(row["probe_share"]),
        heading_difference_rad=float(np.radians(float(row["heading_difference_deg"]))),
        odometry_yaw_sigma_rad=float(np.radians(float(row["odometry_yaw_sigma_deg"]))),
        odometry_yaw_travel_rad=float(np.radians(float(row["odometry_yaw_travel_deg"]))),
        along_difference_m=float(row["along_difference_m"]),
        odometry_along_sigma_m=float(row["odometry_along_sigma_m"]),
        odometry_along_travel_m=float(row["odometry_along_travel_m"]),
        pose_sigma_m=float(row["pose_sigma_m"]),
        lost_keyframes=_count(row["lost_keyframes"]),
    )
    health = ScanHealth(
        stamp_ns=int(row["stamp_ns"]),
        measures=measures,
        observed=_boolean(row["observed"]),
        dead_reckoned_m=float(row["dead_reckoned_m"]),
        blind_m=float(row["blind_m"]),
        flag=_flag(row["flag"]),
        heading_z=float(row["heading_z"]),
        along_z=float(row["along_z"]),
    )
    return int(row["scan"]), health


def read_health_csv(path: str | Path) -> tuple[np.ndarray, tuple[ScanHealth, ...]]:
    """The (N,) input scan numbers and the health of every row of a ``health.csv``.

    A table of an earlier release (:data:`HEALTH_COLUMNS` without the consistency test's columns,
    without ``pose_sigma_m`` or without ``lost_keyframes``) is read too, those measures at their
    "not measured" values.

    Raises:
        HealthFileError: the file is missing, its header is neither :data:`HEALTH_COLUMNS` nor an
            earlier one, or a row is malformed (one line naming the file and the line).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        raise HealthFileError(f"{path}: cannot read the health table ({err.strerror or err})") from err
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    columns = tuple(header) if header is not None else ()
    if columns != HEALTH_COLUMNS and columns not in _EARLIER_COLUMNS:
        raise HealthFileError(f"{path}: not a health table (the first line must be {','.join(HEALTH_COLUMNS)})")
    scans: list[int] = []
    health: list[ScanHealth] = []
    for lineno, values in enumerate(reader, start=2):
        if len(values) != len(columns):
            raise HealthFileError(f"{path}:{lineno}: {len(values)} columns, expected {len(columns)}")
        try:
            scan, row = _row(_NOT_MEASURED | dict(zip(columns, values)))
        except ValueError as err:
            raise HealthFileError(f"{path}:{lineno}: {err}") from None
        scans.append(scan)
        health.append(row)
    return np.array(scans, dtype=np.int64), tuple(health)
