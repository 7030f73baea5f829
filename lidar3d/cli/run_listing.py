"""What ``lidar3d run`` prints at its end: every file written, one line each with what it holds, then
the headline figures (scans, length, speed, loop closures, health, ATE when evaluated).

Built from the run's :class:`~lidar3d.summary.RunSummary` (its manifest of outputs), so the list is
exactly the set in the folder.
"""

from __future__ import annotations

from pathlib import Path

from lidar3d.summary import RunSummary

__all__ = ["OUTPUT_DESCRIPTIONS", "describe_output", "format_file_listing", "format_run_listing", "headline"]

#: What each file of a run folder holds, and the unit of its manifest ``rows`` count.
OUTPUT_DESCRIPTIONS: dict[str, tuple[str, str]] = {
    "trajectory_tum.txt": ("poses", "refined lidar pose of every scan, TUM (t x y z qx qy qz qw)"),
    "trajectory_kitti.txt": ("poses", "the same poses as KITTI 3x4 rows"),
    "trajectory_kitti.times.txt": ("stamps", "stamp of each KITTI row, seconds"),
    "trajectory_lidar_only_tum.txt": ("poses", "the trajectory before the GNSS factors, TUM"),
    "odometry_tum.txt": ("poses", "scan-to-scan odometry before mapping and loop closure, TUM"),
    "keyframes_tum.txt": ("poses", "keyframe poses, TUM"),
    "map.pcd": ("points", "static dense map with intensity, world frame ('lidar3d view' shows it)"),
    "dynamic.pcd": ("points", "points of moving objects taken out of map.pcd"),
    "health.csv": ("scans", "health of every scan: ok / degraded / lost, with its measures"),
    "loops.csv": ("candidates", "every verified loop candidate, accepted or not, with the reason"),
    "pose_graph.g2o": ("", "keyframe pose graph with the loop edges (g2o)"),
    "trajectory_loops.png": ("", "top view of the trajectory with the accepted loop closures"),
    "config.toml": ("", "the resolved configuration (rerun with --config)"),
    "georef.json": ("", "the SLAM frame placed in ENU on WGS84 ('lidar3d export' uses it)"),
    "summary.json": ("", "counts, timing, health, warnings and this list of files"),
    "eval/report.json": ("", "ATE/RPE statistics, alignment, GNSS quality counts"),
    "eval/errors.csv": ("", "per-pose reference, aligned estimate and their errors"),
    "eval/reference_lidar_tum.txt": ("", "reference poses moved to the lidar, ENU, TUM"),
    "eval/estimate_aligned_tum.txt": ("", "aligned estimate at the reference stamps, ENU, TUM"),
    "eval/top_view.png": ("", "top view: estimate coloured by error over the reference"),
    "eval/error_over_time.png": ("", "position error over time"),
    "eval/rotation_error.png": ("", "rotation error over time"),
    "eval/height_profile.png": ("", "height above the ENU origin over time"),
}


def describe_output(path: str, rows: int | None) -> tuple[str, str]:
    """The count (``"1200 poses"``, or ``""``) and the description of the file at ``path``."""
    unit, text = OUTPUT_DESCRIPTIONS.get(path, ("", ""))
    count = f"{rows} {unit or 'rows'}" if rows is not None else ""
    return count, text


def format_file_listing(paths, out_dir: Path | str, *, prefix: str = "") -> str:
    """``wrote N files to DIR/:`` and one line per file of ``paths`` (inside ``out_dir``) with what it
    holds; ``prefix`` is the files' folder inside a run folder (``"eval/"``), for their descriptions."""
    names = [Path(p).relative_to(out_dir).as_posix() for p in paths]
    width = max((len(name) for name in names), default=0)
    lines = [f"wrote {len(names)} files to {out_dir}/:"]
    lines += [f"  {name:<{width}}  {describe_output(prefix + name, None)[1]}".rstrip() for name in names]
    return "\n".join(lines)


def format_run_listing(summary: RunSummary, out_dir: Path | str) -> str:
    """The text ``lidar3d run`` ends with (see the module docstring)."""
    entries = [(e.path, e.rows) for e in summary.outputs] + [("summary.json", None)]
    width = max(len(path) for path, _ in entries)
    lines = [f"wrote {len(entries)} files to {out_dir}/:"]
    for path, rows in entries:
        count, text = describe_output(path, rows)
        lines.append(f"  {path:<{width}}  {count:>17}  {text}".rstrip())
    lines.extend(f"warning: {warning}" for warning in summary.warnings)
    if summary.evaluation is not None:
        lines.append(summary.evaluation.table)
    lines.append(headline(summary))
    return "\n".join(lines)


def headline(summary: RunSummary) -> str:
    """The figures a user looks at first: scans, length, runtime, speed, keyframes, loop closures and
    map points; the health counts; the ATE when the run was evaluated. One line each."""
    s = summary
    lines = [
        ("PARTIAL run: " if s.partial else "")
        + f"{s.scans} scans, {s.length_m:.1f} m, {s.runtime_s:.1f} s ({s.scans_per_s:.1f} scans/s), "
        f"{s.keyframes} keyframes, {s.loop_closures} loop closures, {s.map_points} map points"
        + (f", {s.dynamic_points} dynamic points removed" if s.dynamic_points is not None else "")
    ]
    if s.health is not None:
        h = s.health
        lines.append(
            f"health: {100 * h.ok_fraction:.0f} % of the scans ok, {h.degraded_scans} degraded, {h.lost_scans} lost"
        )
    if s.evaluation is not None:
        ate = s.evaluation.ate
        rmse = ate.translation_3d_m.rmse
        rotation = ate.rotation_deg.rmse
        lines.append(
            "ATE: "
            + ("-" if rmse is None else f"{rmse:.3f} m")
            + " rmse, rotation "
            + ("-" if rotation is None else f"{rotation:.3f} deg")
            + f" rmse (report in {s.evaluation.report})"
        )
    return "\n".join(lines)
