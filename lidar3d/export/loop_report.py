"""Adapter: loop-closure outputs on disk — ``loops.csv``, ``pose_graph.g2o``, the top-view PNG's bytes.

Writes files atomically through :mod:`lidar3d.io.atomic`, from the records of :mod:`lidar3d.loop`
(pure computation, which does not import this module). Matplotlib is imported only when a plot is
drawn, on an Agg canvas (no display needed).
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from lidar3d.io.atomic import write_text_atomic
from lidar3d.loop.records import LoopCandidate

__all__ = [
    "LOOPS_CSV_COLUMNS",
    "loops_csv_text",
    "top_view_figure",
    "top_view_png",
    "write_loops_csv",
    "write_pose_graph_g2o",
]

LOOPS_CSV_COLUMNS = (
    "query_keyframe",
    "match_keyframe",
    "source",
    "query_stamp_ns",
    "match_stamp_ns",
    "time_gap_s",
    "distance_m",
    "fitness",
    "inlier_rmse_m",
    "overlap",
    "correction_m",
    "correction_deg",
    "accepted",
    "verdict",
    "reason",
)


def _number(value: float, digits: int) -> str:
    return "" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _quote(text: str) -> str:
    return '"' + text.replace('"', '""') + '"'


def loops_csv_text(candidates: Sequence[LoopCandidate]) -> str:
    """CSV text with one row per verified candidate (header :data:`LOOPS_CSV_COLUMNS`).

    Metrics that were not computed (ICP did not run) are empty cells.
    """
    lines = [",".join(LOOPS_CSV_COLUMNS)]
    for c in candidates:
        lines.append(
            ",".join(
                [
                    str(c.query),
                    str(c.match),
                    c.source,
                    str(c.query_stamp_ns),
                    str(c.match_stamp_ns),
                    f"{c.time_gap_s:.3f}",
                    _number(c.distance_m, 3),
                    _number(c.fitness, 4),
                    _number(c.inlier_rmse_m, 4),
                    _number(c.overlap, 4),
                    _number(c.correction_m, 3),
                    _number(c.correction_deg, 3),
                    "1" if c.accepted else "0",
                    c.verdict.value,
                    _quote(c.reason),
                ]
            )
        )
    return "\n".join(lines) + "\n"


def write_loops_csv(path: str | Path, candidates: Sequence[LoopCandidate]) -> Path:
    """Write ``loops.csv`` atomically; returns the path."""
    write_text_atomic(path, loops_csv_text(candidates))
    return Path(path)


def write_pose_graph_g2o(path: str | Path, g2o_text: str) -> Path:
    """Write the pose graph (text from :meth:`lidar3d.loop.pose_graph.PoseGraph.g2o_text`) atomically."""
    write_text_atomic(path, g2o_text)
    return Path(path)


def top_view_png(*args, **kwargs) -> bytes:
    """PNG bytes of :func:`top_view_figure` (same arguments)."""
    buffer = io.BytesIO()
    top_view_figure(*args, **kwargs).savefig(buffer, format="png", dpi=110)
    return buffer.getvalue()


def top_view_figure(
    positions_m: np.ndarray,
    keyframe_positions_m: np.ndarray,
    closures: Sequence[LoopCandidate],
    *,
    before_m: np.ndarray | None = None,
    reference_m: np.ndarray | None = None,
    title: str | None = None,
):
    """A matplotlib figure (Agg canvas): the corrected trajectory in x-y, each accepted loop closure
    as a numbered segment between its two keyframes with a ring around each end (visible even when
    the two lie a few centimetres apart, as a good closure's do), optionally the trajectory before
    closure and a reference.

    Args:
        positions_m: (N,3) corrected positions (scans), world frame.
        keyframe_positions_m: (K,3) corrected keyframe positions (closure end points).
        closures: accepted candidates (others are ignored).
        before_m: (M,3) positions before closure, drawn thin and grey.
        reference_m: (R,3) reference positions (e.g. ground truth in the same frame), dashed.
        title: figure title; by default it says how many closures there were (or that there were none).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    positions_m = np.asarray(positions_m, dtype=np.float64).reshape(-1, 3)
    keyframe_positions_m = np.asarray(keyframe_positions_m, dtype=np.float64).reshape(-1, 3)
    accepted = [c for c in closures if c.accepted and max(c.query, c.match) < len(keyframe_positions_m)]
    if title is None:
        title = (
            f"trajectory (top view) with {len(accepted)} loop closure{'s' * (len(accepted) != 1)}"
            if accepted
            else "trajectory (top view): no loop closure accepted"
        )
    figure = Figure(figsize=(7, 6.5))
    FigureCanvasAgg(figure)
    ax = figure.add_subplot(1, 1, 1)
    if reference_m is not None and len(reference_m):
        ref = np.asarray(reference_m).reshape(-1, 3)
        ax.plot(ref[:, 0], ref[:, 1], "--", color="0.3", lw=1.0, label="reference", zorder=1)
    if before_m is not None and len(before_m):
        before = np.asarray(before_m).reshape(-1, 3)
        ax.plot(before[:, 0], before[:, 1], color="0.65", lw=1.0, label="before loop closure", zorder=1)
    if len(positions_m):
        ax.plot(positions_m[:, 0], positions_m[:, 1], color="tab:blue", lw=1.4, label="trajectory", zorder=2)
        ax.plot(positions_m[0, 0], positions_m[0, 1], "o", color="tab:green", ms=6, label="start", zorder=4)
        ax.plot(positions_m[-1, 0], positions_m[-1, 1], "s", color="tab:red", ms=6, label="end", zorder=4)
    for number, c in enumerate(accepted, start=1):
        a, b = keyframe_positions_m[c.match], keyframe_positions_m[c.query]
        label = f"loop closures ({len(accepted)}): match - query keyframe" if number == 1 else None
        ax.plot([a[0], b[0]], [a[1], b[1]], "-", color="tab:orange", lw=3.0, zorder=3, label=label)
        ax.plot([a[0], b[0]], [a[1], b[1]], "o", ms=11, mfc="none", mec="tab:orange", mew=2.0, zorder=3)
        ax.annotate(
            str(number),
            (b[0], b[1]),
            xytext=(7, 7),
            textcoords="offset points",
            fontsize=8,
            color="tab:orange",
            fontweight="bold",
            zorder=5,
        )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    ax.grid(True, lw=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize=8)
    return figure
