"""Adapter: the SPAN evaluation report — ``report.json``, per-pose ``errors.csv``, PNG plots, TUM files,
and the text table ``lidar3d eval`` prints.

Turns a :class:`~lidar3d.metrics.span_eval.SpanEvaluation` (computed by
:func:`~lidar3d.metrics.span_eval.evaluate_against_span`, which writes nothing) into files. Written
(atomically) into the output folder by :func:`write_span_report`:

* ``report.json``: inputs, settings, origin, alignment (used, requested, conditioning, note on a
  fallback), counts, warnings, ATE/RPE statistics (NaN -> null);
* ``errors.csv``: one row per associated pose: stamp, reference and aligned estimate ENU position,
  3-D/horizontal/vertical/rotation error, INS status, position type, GNSS quality class;
* ``reference_lidar_tum.txt`` / ``estimate_aligned_tum.txt``: the associated poses in ENU as TUM
  (so ``evo_ape tum reference_lidar_tum.txt estimate_aligned_tum.txt`` reproduces the ATE);
* ``top_view.png``, ``error_over_time.png``, ``rotation_error.png``, ``height_profile.png``
  (:mod:`lidar3d.export.span_plots`).
"""

from __future__ import annotations

import dataclasses
import io
import json
import math
from pathlib import Path

import numpy as np

from lidar3d.export.span_plots import span_plots
from lidar3d.gnss.novatel import QUALITY_CLASSES, InsStatus, quality_class
from lidar3d.io.atomic import write_bytes_atomic, write_text_atomic
from lidar3d.io.trajectory_io import write_tum
from lidar3d.metrics.span_eval import SpanEvaluation
from lidar3d.records import Trajectory

__all__ = ["format_span_table", "span_report_dict", "write_span_report"]


def _clean(value):
    """JSON-safe copy: NaN/inf -> None, numpy scalars -> Python, tuples -> lists."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return _clean(value.tolist())
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    return value


def _quality(result: SpanEvaluation) -> tuple[np.ndarray, np.ndarray, list[str]]:
    index = result.evaluation.reference_index
    status = result.reference.ins_status[index]
    position_type = result.reference.position_type[index]
    classes = [quality_class(int(p)) for p in position_type]
    return status, position_type, classes


def span_report_dict(result: SpanEvaluation) -> dict:
    """The JSON report as a dict (see the module docstring)."""
    ev = result.evaluation
    ref = result.reference
    _status, _ptype, classes = _quality(result)
    counts = {c: classes.count(c) for c in QUALITY_CLASSES if classes.count(c)}
    stats = result.log.stats
    return _clean(
        {
            "inputs": {"trajectory": result.trajectory_source, "span_log": result.span_source},
            "settings": dataclasses.asdict(result.config),
            "T_imu_lidar": result.T_imu_lidar,
            "origin": dataclasses.asdict(ref.origin),
            "log": {
                "decoded": dict(stats.decoded),
                "ignored": dict(stats.ignored),
                "bad_crc": stats.bad_crc,
                "bad_format": stats.bad_format,
                "out_of_range": stats.out_of_range,
                "truncated": stats.truncated,
                "problems": list(stats.problems),
            },
            "reference": {
                "source_log": ref.source_log,
                "solutions_in_log": ref.n_solutions,
                "solutions_kept": len(ref),
                "span_s": list(ref.span_s),
                "median_std_enu_m": np.nanmedian(ref.std_enu_m, axis=0)
                if np.isfinite(ref.std_enu_m).any()
                else [None, None, None],
            },
            "association": {
                "estimate_poses": ev.n_estimate,
                "associated_poses": ev.n_associated,
                "max_gap_s": ev.max_gap_s,
                "path_length_m": ev.path_length_m,
                "gnss_quality": counts,
            },
            "alignment": {
                "mode": ev.alignment.value,
                "requested": ev.alignment_requested.value,
                "conditioning": ev.alignment_conditioning,
                "note": ev.alignment_note,
                "T_reference_estimate": ev.T_reference_estimate,
            },
            "warnings": list(result.warnings),
            **(
                {}
                if result.fusion is None
                else {"fusion": {**dataclasses.asdict(result.fusion), "note": result.fusion.line()}}
            ),
            "ate": dataclasses.asdict(ev.ate),
            "rpe_kitti": dataclasses.asdict(ev.kitti),
            "rpe_distance": [dataclasses.asdict(d) for d in ev.distance_rpe],
        }
    )


def _csv(result: SpanEvaluation) -> str:
    ev = result.evaluation
    status, position_type, classes = _quality(result)
    out = io.StringIO()
    out.write(
        "stamp_s,ref_east_m,ref_north_m,ref_up_m,est_east_m,est_north_m,est_up_m,"
        "error_3d_m,error_horizontal_m,error_vertical_m,error_rotation_deg,ins_status,position_type,gnss_quality\n"
    )
    ref_p = ev.T_ref_lidar[:, :3, 3]
    est_p = ev.T_ref_lidar_estimate[:, :3, 3]
    e = ev.errors
    for k in range(ev.n_associated):
        seconds, nanos = divmod(int(ev.stamps_ns[k]), 1_000_000_000)
        try:
            status_name = InsStatus(int(status[k])).name
        except ValueError:
            status_name = str(int(status[k]))
        type_name = "" if position_type[k] < 0 else _position_type_name(int(position_type[k]))
        out.write(
            f"{seconds}.{nanos:09d},{ref_p[k, 0]:.4f},{ref_p[k, 1]:.4f},{ref_p[k, 2]:.4f},"
            f"{est_p[k, 0]:.4f},{est_p[k, 1]:.4f},{est_p[k, 2]:.4f},"
            f"{e.translation_3d_m[k]:.5f},{e.horizontal_m[k]:.5f},{e.signed_vertical_m[k]:.5f},"
            f"{e.rotation_deg[k]:.5f},{status_name},{type_name},{classes[k]}\n"
        )
    return out.getvalue()


def _position_type_name(code: int) -> str:
    from lidar3d.gnss.novatel import PositionType

    try:
        return PositionType(code).name
    except ValueError:
        return str(code)


def write_span_report(result: SpanEvaluation, out_dir: str | Path) -> list[Path]:
    """Write the report files into ``out_dir`` (created if needed); returns their paths."""
    out = Path(out_dir)
    ev = result.evaluation
    written = []
    path = out / "report.json"
    write_text_atomic(path, json.dumps(span_report_dict(result), indent=2, allow_nan=False) + "\n")
    written.append(path)
    path = out / "errors.csv"
    write_text_atomic(path, _csv(result))
    written.append(path)
    tum_files = (("reference_lidar_tum.txt", ev.T_ref_lidar), ("estimate_aligned_tum.txt", ev.T_ref_lidar_estimate))
    for name, poses in tum_files:
        path = out / name
        write_tum(path, Trajectory(ev.stamps_ns, poses))
        written.append(path)
    for name, data in span_plots(result).items():
        path = out / name
        write_bytes_atomic(path, data)
        written.append(path)
    return written


def _row(label: str, stats, scale: float = 1.0, digits: int = 3) -> str:
    values = [stats.rmse, stats.mean, stats.median, stats.max]
    cells = " ".join(f"{v * scale:>9.{digits}f}" if math.isfinite(v) else f"{'-':>9}" for v in values)
    return f"  {label:<22}{cells}"


def format_span_table(result: SpanEvaluation) -> str:
    """A short text table of the results (what ``lidar3d eval`` prints)."""
    ev = result.evaluation
    ref = result.reference
    o = ref.origin
    lines = [
        f"reference: {len(ref)} of {ref.n_solutions} {ref.source_log} solutions; origin "
        f"{o.latitude_deg:.8f} {o.longitude_deg:.8f} {o.height_ellipsoid_m:.3f} m (ellipsoidal)",
        f"associated: {ev.n_associated} of {ev.n_estimate} poses (max gap {ev.max_gap_s:g} s), "
        f"path {ev.path_length_m:.1f} m, alignment {ev.alignment.value}",
        f"  {'ATE':<22}{'rmse':>9} {'mean':>9} {'median':>9} {'max':>9}",
        _row("3-D [m]", ev.ate.translation_3d_m),
        _row("horizontal [m]", ev.ate.horizontal_m),
        _row("vertical [m]", ev.ate.vertical_m),
        _row("rotation [deg]", ev.ate.rotation_deg),
    ]
    for d in ev.distance_rpe:
        lines.append(_row(f"RPE {d.distance_m:g} m [m]", d.translation_m))
    k = ev.kitti
    if k.n:
        lines.append(
            f"  KITTI RPE (100-800 m): {k.translation_percent:.3f} % , {k.rotation_deg_per_100m:.4f} deg/100 m "
            f"({k.n} segments)"
        )
    else:
        lines.append("  KITTI RPE: no segment of 100 m or more")
    lines.extend(f"warning: {line}" for line in result.warnings)
    if result.fusion is not None:
        lines.append(f"note: {result.fusion.line()}")
    return "\n".join(lines)
