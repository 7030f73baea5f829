"""Adapter: the PNG plots of the SPAN evaluation report, readable at any error size.

* ``top_view.png``: every INS solution of the reference coloured by GNSS quality (small, underneath),
  the aligned estimate on top as a line coloured by its 3-D error (colour bar in metres), start and
  end marked; the title names the alignment and the ATE;
* ``error_over_time.png``: 3-D, horizontal and signed vertical position error over time;
* ``rotation_error.png``: the rotation error angle over time, with its RMSE;
* ``height_profile.png``: the reference and estimate heights as ENU up, i.e. metres above the
  tangent plane at the ENU origin (whose ellipsoidal height the title gives), over time.

Stretches without reference (gaps over 1 s) are not bridged. Matplotlib draws on an Agg canvas
(no display needed) and is imported only here, when a plot is drawn.
"""

from __future__ import annotations

import io

import numpy as np

from lidar3d.gnss.enu import LocalEnu
from lidar3d.gnss.gps_time import gps_to_unix_ns
from lidar3d.gnss.novatel import QUALITY_CLASSES, quality_class
from lidar3d.metrics.span_eval import SpanEvaluation

__all__ = ["ERROR_COLOUR_MAP", "QUALITY_COLOURS", "span_figures", "span_plots"]

QUALITY_COLOURS = {
    "RTK fixed": "#1a9850",
    "RTK float": "#91cf60",
    "PPP": "#4575b4",
    "DGNSS/SBAS": "#fdae61",
    "single": "#d73027",
    "INS only / none": "#7f7f7f",
}
#: Colour map of the estimate's error (dark: small, yellow: large), distinct from the quality colours.
ERROR_COLOUR_MAP = "plasma"


def _png(figure) -> bytes:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(figure)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=110)
    return buffer.getvalue()


def _all_solutions(result: SpanEvaluation) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ENU positions (of the IMU) of every INS solution of the reference's log type, their GNSS
    quality class, and whether the reference kept them."""
    ref = result.reference
    group = ("INSPVAX",) if ref.source_log == "INSPVAX" else ("INSPVA", "INSPVAS")
    messages = [m for m in result.log.ins if m.log in group and m.gps_week > 0]
    if not messages:
        return np.zeros((0, 3)), np.zeros(0, dtype=object), np.zeros(0, dtype=bool)
    enu = LocalEnu(ref.origin).to_enu(
        [m.latitude_deg for m in messages],
        [m.longitude_deg for m in messages],
        [m.height_ellipsoid_m for m in messages],
    )
    stamps = gps_to_unix_ns(
        [m.gps_week for m in messages],
        [m.gps_seconds for m in messages],
        result.config.leap_seconds,
        result.config.time_offset_s,
    )
    kept = np.isin(stamps, ref.stamps_ns)
    if ref.source_log == "INSPVAX":
        codes = [-1 if m.position_type is None else int(m.position_type) for m in messages]
    else:  # INSPVA/INSPVAS: the position type the reference took from the nearest BESTPOS
        index = np.searchsorted(ref.stamps_ns, stamps).clip(0, len(ref) - 1)
        codes = [int(ref.position_type[i]) for i in index]
    labels = np.array([quality_class(code) for code in codes], dtype=object)
    return enu, labels, kept


def _gaps(stamps_ns: np.ndarray) -> np.ndarray:
    """Indices where the associated poses have a gap over 1 s (a line is broken there)."""
    return np.flatnonzero(np.diff(stamps_ns) > 1_000_000_000) + 1


def _broken(values: np.ndarray, stamps_ns: np.ndarray) -> np.ndarray:
    """``values`` as float with NaN inserted at the gaps, so plotted lines do not bridge them."""
    values = np.asarray(values, dtype=float).copy()
    gaps = _gaps(stamps_ns)
    return np.insert(values, gaps, np.nan, axis=0) if len(gaps) else values


def _top_view(result: SpanEvaluation):
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    ev = result.evaluation
    est_p = ev.T_ref_lidar_estimate[:, :3, 3]
    error = np.asarray(ev.errors.translation_3d_m, dtype=float)
    figure = Figure(figsize=(7.5, 6))
    ax = figure.add_subplot(1, 1, 1)
    all_enu, all_classes, all_kept = _all_solutions(result)
    for label in QUALITY_CLASSES:
        for kept, marker, suffix in ((True, "o", ""), (False, "x", " (rejected: INS status / time)")):
            mask = (all_classes == label) & (all_kept == kept)
            if mask.any():
                ax.scatter(
                    all_enu[mask, 0],
                    all_enu[mask, 1],
                    s=8,
                    marker=marker,
                    linewidths=0.6,
                    c=QUALITY_COLOURS[label],
                    alpha=0.45,
                    zorder=1,
                    label=f"reference {result.reference.source_log}: {label}{suffix}",
                )
    # One segment per pair of consecutive associated poses, none across a gap, coloured by the
    # mean error of its two ends.
    segments = np.stack([est_p[:-1, :2], est_p[1:, :2]], axis=1)
    keep = np.ones(len(segments), dtype=bool)
    keep[_gaps(ev.stamps_ns) - 1] = False
    segment_error = 0.5 * (error[:-1] + error[1:])
    upper = float(np.nanmax(error)) if len(error) and np.isfinite(error).any() else 1.0
    lines = LineCollection(
        list(segments[keep]), array=segment_error[keep], cmap=ERROR_COLOUR_MAP, linewidths=2.6, zorder=3
    )
    lines.set_clim(0.0, max(upper, 1e-6))
    ax.add_collection(lines)
    colour_bar = figure.colorbar(lines, ax=ax, shrink=0.8, pad=0.02)
    colour_bar.set_label("estimate: 3-D position error [m]")
    if len(est_p):
        ax.plot(est_p[0, 0], est_p[0, 1], "o", ms=7, mfc="none", mec="black", mew=1.5, zorder=4, label="start")
        ax.plot(est_p[-1, 0], est_p[-1, 1], "s", ms=7, mfc="none", mec="black", mew=1.5, zorder=4, label="end")
    ax.plot([], [], "-", color="#7e03a8", lw=2.2, label=f"estimate ({ev.alignment.value}-aligned), by error")
    ax.autoscale_view()
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, linewidth=0.3)
    ax.legend(fontsize=7, loc="best", framealpha=0.85)
    ax.set_title(
        f"top view, estimate over reference: ATE rmse {ev.ate.translation_3d_m.rmse:.3f} m, "
        f"max {ev.ate.translation_3d_m.max:.3f} m",
        fontsize=10,
    )
    return figure


def _error_over_time(result: SpanEvaluation, t_s: np.ndarray):
    from matplotlib.figure import Figure

    ev = result.evaluation
    figure = Figure(figsize=(8, 4))
    ax = figure.add_subplot(1, 1, 1)
    ax.plot(t_s, _broken(ev.errors.translation_3d_m, ev.stamps_ns), label="3-D", linewidth=0.9)
    ax.plot(t_s, _broken(ev.errors.horizontal_m, ev.stamps_ns), label="horizontal", linewidth=0.9)
    ax.plot(t_s, _broken(ev.errors.signed_vertical_m, ev.stamps_ns), label="vertical (signed)", linewidth=0.9)
    ax.axhline(0.0, color="0.5", linewidth=0.5)
    ax.set_xlabel("time since the first associated pose [s]")
    ax.set_ylabel("error [m]")
    ax.grid(True, linewidth=0.3)
    ax.legend(fontsize=8)
    ax.set_title(f"absolute position error ({ev.alignment.value}-aligned), rmse {ev.ate.translation_3d_m.rmse:.3f} m")
    return figure


def _rotation_error(result: SpanEvaluation, t_s: np.ndarray):
    from matplotlib.figure import Figure

    ev = result.evaluation
    figure = Figure(figsize=(8, 4))
    ax = figure.add_subplot(1, 1, 1)
    rotation = np.asarray(ev.errors.rotation_deg, dtype=float)
    ax.plot(t_s, _broken(rotation, ev.stamps_ns), color="tab:purple", linewidth=0.9)
    ax.set_xlabel("time since the first associated pose [s]")
    ax.set_ylabel("rotation error [deg]")
    top = float(np.nanmax(rotation)) if np.isfinite(rotation).any() else 1.0
    ax.set_ylim(0.0, 1.15 * max(top, 1e-3))
    ax.grid(True, linewidth=0.3)
    ax.set_title(
        f"absolute rotation error (angle of R_ref^T R_est), rmse {ev.ate.rotation_deg.rmse:.3f} deg", fontsize=10
    )
    return figure


def _height_profile(result: SpanEvaluation, t_s: np.ndarray):
    from matplotlib.figure import Figure

    ev = result.evaluation
    figure = Figure(figsize=(8, 4))
    ax = figure.add_subplot(1, 1, 1)
    ax.plot(t_s, _broken(ev.T_ref_lidar[:, 2, 3], ev.stamps_ns), label="reference", linewidth=1.6, color="0.45")
    ax.plot(
        t_s,
        _broken(ev.T_ref_lidar_estimate[:, 2, 3], ev.stamps_ns),
        label=f"estimate ({ev.alignment.value}-aligned)",
        linewidth=1.0,
        color="tab:orange",
    )
    ax.set_xlabel("time since the first associated pose [s]")
    ax.set_ylabel("ENU up, above the origin [m]")
    ax.grid(True, linewidth=0.3)
    ax.legend(fontsize=8)
    origin_height = result.reference.origin.height_ellipsoid_m
    ax.set_title(f"height profile: ENU up relative to the origin (origin at {origin_height:.2f} m ellipsoidal)")
    return figure


def span_figures(result: SpanEvaluation) -> dict:
    """The report's plots as matplotlib figures (Agg canvas), by file name."""
    ev = result.evaluation
    t_s = _broken((ev.stamps_ns - ev.stamps_ns[0]) / 1e9, ev.stamps_ns)
    return {
        "top_view.png": _top_view(result),
        "error_over_time.png": _error_over_time(result, t_s),
        "rotation_error.png": _rotation_error(result, t_s),
        "height_profile.png": _height_profile(result, t_s),
    }


def span_plots(result: SpanEvaluation) -> dict[str, bytes]:
    """The report's plots as PNG bytes, by file name (see the module docstring)."""
    return {name: _png(figure) for name, figure in span_figures(result).items()}
