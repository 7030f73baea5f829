"""The batch report: ``summary.csv``, ``summary.json`` and ``report.html`` in the batch folder.

One row per bag (:data:`ROW_FIELDS`). The HTML page is self-contained (inline CSS and JavaScript,
no network): a sortable table (click a column header; the order is kept in the address as
``#sort=<column>:asc|desc``, so a sorted view can be bookmarked or opened directly), links to
each bag's output folder and evaluation plots (relative, so the whole batch folder can be moved
or served as it is), thumbnails of each bag's top views, and in every empty cell the reason it is
empty (``path 42 m < 100 m`` where KITTI RPE has no segment, ``no SPAN log``, ``failed, see error``).
Every file is written atomically.
"""

from __future__ import annotations

import csv
import html
import io
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lidar3d.io.atomic import write_text_atomic
from lidar3d.summary import RunSummary

__all__ = ["ROW_FIELDS", "THUMBNAIL_PLOTS", "ReportPaths", "bag_row", "blank_reason", "write_report"]

ROW_FIELDS = (
    "name",
    "status",
    "scans",
    "keyframes",
    "length_m",
    "duration_s",
    "runtime_s",
    "scans_per_s",
    "loop_closures",
    "ate_rmse_m",
    "rpe_rmse_m",
    "rpe_kitti_percent",
    "map_points",
    "health",
    "health_ok_percent",
    "lost_m",
    "warnings",
    "span_log",
    "span_match",
    "bag",
    "output",
    "plots",
    "error",
    "note",
    "fingerprint",
)

# (field, header, kind) of the HTML table; kind "num" sorts numerically, empty cells last.
_COLUMNS = (
    ("name", "bag", "text"),
    ("status", "status", "text"),
    ("scans", "scans", "num"),
    ("length_m", "length [m]", "num"),
    ("runtime_s", "runtime [s]", "num"),
    ("scans_per_s", "scans/s", "num"),
    ("loop_closures", "loop closures", "num"),
    ("ate_rmse_m", "ATE RMSE [m]", "num"),
    ("rpe_rmse_m", "RPE {rpe} [m]", "num"),
    ("rpe_kitti_percent", "KITTI RPE [%]", "num"),
    ("health", "health", "num"),
    ("span_log", "SPAN log", "text"),
    ("plots", "plots", "text"),
    ("error", "error / note", "text"),
)


@dataclass(frozen=True, slots=True)
class ReportPaths:
    csv: Path
    json: Path
    html: Path


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or value is None:
        return None
    if isinstance(value, (int, float)) and math.isfinite(value):
        return value
    return None


def _rmse(stats: Any) -> float | None:
    return _number(stats.get("rmse")) if isinstance(stats, Mapping) else None


def _rpe(eval_report: Mapping[str, Any] | None, distance_m: float | None) -> tuple[float | None, float | None]:
    if not eval_report:
        return None, None
    kitti = eval_report.get("rpe_kitti") or {}
    kitti_pct = _number(kitti.get("translation_percent")) if isinstance(kitti, Mapping) else None
    by_distance = None
    for entry in eval_report.get("rpe_distance") or []:
        if isinstance(entry, Mapping) and (distance_m is None or entry.get("distance_m") == distance_m):
            by_distance = _rmse(entry.get("translation_m"))
            break
    return by_distance, kitti_pct


def _health(summary: RunSummary | None) -> tuple[str | None, float | None, float | None]:
    """(worst flag of the run, share of ok scans in %, metres lost) of a run's health; Nones without."""
    health = summary.health if summary is not None else None
    if health is None:
        return None, None, None
    worst = "lost" if health.lost_scans else "degraded" if health.degraded_scans else "ok"
    return worst, round(100.0 * health.ok_fraction, 2), health.lost_m


def bag_row(
    *,
    name: str,
    bag: Path,
    status: str,
    batch_dir: Path,
    summary: RunSummary | None = None,
    eval_report: Mapping[str, Any] | None = None,
    span_log: Path | None = None,
    span_match: str = "",
    error: str | None = None,
    note: str | None = None,
    fingerprint: str = "",
    rpe_distance_m: float | None = None,
) -> dict[str, Any]:
    """One report row. Metrics come from the bag's run summary and ``eval/report.json``;
    plots are the PNG files of the bag's folder and of its ``eval/`` folder."""
    s = summary
    folder = batch_dir / name
    pngs = [*sorted(folder.glob("*.png")), *sorted((folder / "eval").glob("*.png"))] if s is not None else []
    plots = [p.relative_to(batch_dir).as_posix() for p in pngs]  # loop top view, then evaluation plots
    ate = s.evaluation.ate if s is not None and s.evaluation is not None else None
    rpe_m, rpe_pct = _rpe(eval_report, rpe_distance_m)
    health, health_ok_percent, lost_m = _health(s)
    return {
        "name": name,
        "status": status,
        "scans": s.scans if s is not None else None,
        "keyframes": s.keyframes if s is not None else None,
        "length_m": _number(s.length_m) if s is not None else None,
        "duration_s": _number(s.duration_s) if s is not None else None,
        "runtime_s": _number(s.runtime_s) if s is not None else None,
        "scans_per_s": _number(s.scans_per_s) if s is not None else None,
        "loop_closures": s.loop_closures if s is not None else None,
        "ate_rmse_m": _number(ate.translation_3d_m.rmse) if ate is not None else None,
        "rpe_rmse_m": rpe_m,
        "rpe_kitti_percent": rpe_pct,
        "map_points": s.map_points if s is not None else None,
        "health": health,
        "health_ok_percent": health_ok_percent,
        "lost_m": lost_m,
        "warnings": len(s.warnings) if s is not None else None,
        "span_log": str(span_log) if span_log else None,
        "span_match": span_match,
        "bag": str(bag),
        "output": f"{name}/" if s is not None else None,
        "plots": plots,
        "error": error,
        "note": note or (s.evaluation_error if s is not None else None),
        "fingerprint": fingerprint,
    }


def _csv_text(rows: Sequence[Mapping[str, Any]]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=ROW_FIELDS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (";".join(v) if isinstance(v, list) else ("" if v is None else v)) for k, v in row.items()})
    return buffer.getvalue()


def _fmt(value: Any, digits: int) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


_DIGITS = {"length_m": 1, "runtime_s": 1, "scans_per_s": 1, "ate_rmse_m": 3, "rpe_rmse_m": 3, "rpe_kitti_percent": 2}

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;margin:1.2rem;color:#1d2329;background:#fff}
h1{font-size:1.4rem;margin:0 0 .3rem}
p.meta{color:#5b6670;margin:.2rem 0 1rem}
ul.totals{display:flex;gap:1.2rem;list-style:none;padding:0;margin:0 0 1rem}
ul.totals li{background:#f2f4f6;border-radius:6px;padding:.4rem .8rem}
div.table{overflow-x:auto;padding-right:.5rem}
table{border-collapse:collapse;width:100%;font-size:.85rem}
th,td{border-bottom:1px solid #e1e5e9;padding:.3rem .4rem;text-align:left;vertical-align:top}
td.health-ok,td.health-lost,td.health-degraded{white-space:nowrap}
td.num{text-align:right;font-variant-numeric:tabular-nums}
th{background:#f7f8fa;position:sticky;top:0;vertical-align:bottom}
th button{all:unset;cursor:pointer;font-weight:600}
th button:focus-visible{outline:2px solid #3b82f6}
th[aria-sort=ascending] button::after{content:" \\25B2";font-size:.7em}
th[aria-sort=descending] button::after{content:" \\25BC";font-size:.7em}
tr:hover td{background:#fafbfc}
.status{border-radius:4px;padding:.05rem .4rem;font-size:.8rem;white-space:nowrap}
.status-done{background:#dcfce7;color:#166534}
.status-up-to-date{background:#e0f2fe;color:#075985}
.status-failed{background:#fee2e2;color:#991b1b}
.status-interrupted,.status-not-started{background:#fef9c3;color:#854d0e}
td.health-lost{color:#991b1b;font-weight:600}
td.health-degraded{color:#854d0e}
td.error{color:#991b1b;max-width:15rem;word-break:break-word}
td.note{color:#854d0e;max-width:15rem;word-break:break-word}
td.path{max-width:9rem;overflow-wrap:anywhere;color:#5b6670}
td.plots{width:11.5rem;min-width:11.5rem}
td.plots a.thumb{display:inline-block;vertical-align:top;margin:0 .25rem .25rem 0}
td.plots img{height:74px;width:auto;max-width:84px;object-fit:contain;display:block;
border:1px solid #d5dae0;border-radius:3px;background:#fff}
td.plots a.link{white-space:nowrap;display:inline-block;margin-right:.5rem;font-size:.8rem}
span.why{color:#8a949e;font-size:.75rem;font-style:italic}
a{color:#1d4ed8}
"""

_JS = """
(function () {
  var table = document.getElementById("bags");
  var body = table.tBodies[0];
  var heads = Array.prototype.slice.call(table.tHead.rows[0].cells);
  function key(cell, kind) {
    var v = cell.getAttribute("data-value");
    if (kind === "num") { return (v === null || v === "") ? null : parseFloat(v); }
    return (v === null ? cell.textContent : v).toLowerCase();
  }
  function sortBy(column, direction) {
    var index = -1;
    heads.forEach(function (h, i) { if (h.getAttribute("data-key") === column) { index = i; } });
    if (index < 0) { return false; }
    var kind = heads[index].getAttribute("data-kind");
    var rows = Array.prototype.slice.call(body.rows).map(function (row, i) {
      return {row: row, key: key(row.cells[index], kind), i: i};
    });
    rows.sort(function (a, b) {
      if (a.key === null || b.key === null) {
        if (a.key === b.key) { return a.i - b.i; }
        return a.key === null ? 1 : -1;
      }
      var c = a.key < b.key ? -1 : (a.key > b.key ? 1 : 0);
      if (direction === "desc") { c = -c; }
      return c !== 0 ? c : a.i - b.i;
    });
    rows.forEach(function (r) { body.appendChild(r.row); });
    heads.forEach(function (h) { h.removeAttribute("aria-sort"); });
    heads[index].setAttribute("aria-sort", direction === "desc" ? "descending" : "ascending");
    table.setAttribute("data-sort", column + ":" + direction);
    return true;
  }
  heads.forEach(function (h) {
    h.querySelector("button").addEventListener("click", function () {
      var column = h.getAttribute("data-key");
      var direction = table.getAttribute("data-sort") === column + ":asc" ? "desc" : "asc";
      sortBy(column, direction);
      try { history.replaceState(null, "", "#sort=" + column + ":" + direction); } catch (e) { /* file: URLs */ }
    });
  });
  function fromAddress() {
    var m = /^#sort=([A-Za-z0-9_]+):(asc|desc)$/.exec(window.location.hash);
    if (m) { sortBy(m[1], m[2]); }
  }
  window.addEventListener("hashchange", fromAddress);
  fromAddress();
})();
"""


def _cell(field: str, kind: str, row: Mapping[str, Any], meta: Mapping[str, Any]) -> str:
    value = row.get(field)
    esc = html.escape
    reason = blank_reason(field, row, meta)
    if reason is not None:
        css = ' class="num"' if kind == "num" else ""
        title = esc(str(row.get("span_match") or "")) if field == "span_log" else esc(reason)
        return f'<td{css} data-value="" title="{title}"><span class="why">{esc(reason)}</span></td>'
    if field == "name":
        target = row.get("output")
        label = esc(str(value))
        inner = f'<a href="{esc(str(target))}">{label}</a>' if target else label
        return f'<td data-value="{esc(str(value))}" title="{esc(str(row.get("bag") or ""))}">{inner}</td>'
    if field == "status":
        css = "status-" + str(value).replace(" ", "-")
        return f'<td data-value="{esc(str(value))}"><span class="status {css}">{esc(str(value))}</span></td>'
    if field == "plots":
        return _plots_cell(row)
    if field == "span_log":
        text = Path(value).name if value else ""
        title = f"{esc(str(value or ''))} ({esc(str(row.get('span_match') or ''))})"
        return f'<td class="path" data-value="{esc(text)}" title="{title}">{esc(text)}</td>'
    if field == "error":
        text = row.get("error") or row.get("note") or ""
        css = "error" if row.get("error") else "note"
        return f'<td class="{css}" data-value="{esc(text)}">{esc(text)}</td>'
    if field == "health":
        return _health_cell(row)
    if kind == "num":
        number = _number(value)
        shown = _fmt(value, _DIGITS.get(field, 3))
        data = "" if number is None else repr(number)
        return f'<td class="num" data-value="{data}">{esc(shown)}</td>'
    return f'<td data-value="{esc(str(value or ""))}">{esc(str(value or ""))}</td>'


#: Plots shown as thumbnails in the report (the others as links), in this order.
THUMBNAIL_PLOTS = ("trajectory_loops.png", "eval/top_view.png")
#: KITTI RPE averages over segments of 100 to 800 m: a shorter path has none.
_KITTI_SHORTEST_M = 100.0


def blank_reason(field: str, row: Mapping[str, Any], meta: Mapping[str, Any]) -> str | None:
    """Why the report cell ``field`` of ``row`` is empty, in a few words; None when it has a value
    (or is a cell that always has one)."""
    if field in ("name", "status"):
        return None
    status = row.get("status")
    if field == "error":
        return None if row.get("error") or row.get("note") else "none"
    if field == "span_log":
        return None if row.get("span_log") else _short(str(row.get("span_match") or "no SPAN log requested"))
    if row.get("output") is None:
        return {"not started": "not run"}.get(str(status), str(status))
    if field == "plots":
        return None if row.get("plots") else "none written"
    if field == "health":
        return None if row.get("health") is not None else "not recorded (older run)"
    if row.get(field) is not None:
        return None
    if field in ("ate_rmse_m", "rpe_rmse_m", "rpe_kitti_percent"):
        if not row.get("span_log"):
            return "no SPAN log"
        if row.get("note"):
            return "evaluation failed"
        length = _number(row.get("length_m")) or 0.0
        if field == "rpe_kitti_percent":
            return f"path {length:.0f} m < {_KITTI_SHORTEST_M:.0f} m"
        distance = _number(meta.get("rpe_distance_m"))
        if field == "rpe_rmse_m" and distance is not None and length < distance:
            return f"path {length:.0f} m < {distance:g} m"
        return "no pose pairs"
    return "not computed"


def _short(text: str) -> str:
    """``text`` with its absolute paths cut to their file names (the full text is in the row's data)."""
    return " ".join(Path(word).name if word.startswith("/") else word for word in text.split(" "))


def _plots_cell(row: Mapping[str, Any]) -> str:
    """Thumbnails of the top views (:data:`THUMBNAIL_PLOTS`), links to the other plots."""
    esc = html.escape
    plots = list(row.get("plots") or [])
    name = str(row.get("name"))
    thumbs = [f"{name}/{p}" for p in THUMBNAIL_PLOTS if f"{name}/{p}" in plots]
    others = [p for p in plots if p not in thumbs]
    parts = [
        f'<a class="thumb" href="{esc(p)}" title="{esc(Path(p).name)}">'
        f'<img src="{esc(p)}" alt="{esc(Path(p).stem.replace("_", " "))}" loading="lazy"></a>'
        for p in thumbs
    ]
    parts += [f'<a class="link" href="{esc(p)}">{esc(Path(p).stem.replace("_", " "))}</a>' for p in others]
    return f'<td class="plots" data-value="{len(plots)}">{"".join(parts)}</td>'


def _health_cell(row: Mapping[str, Any]) -> str:
    """``ok 100 %``, ``degraded: ok 93 %`` or ``lost 62.3 m: ok 71 %``; sorted by the share of ok scans."""
    flag, percent = row.get("health"), _number(row.get("health_ok_percent"))
    if flag is None or percent is None:
        return '<td data-value=""></td>'
    text = f"ok {percent:.0f} %"
    if flag == "lost":
        text = f"lost {_fmt(row.get('lost_m'), 1)} m: {text}"
    elif flag == "degraded":
        text = f"degraded: {text}"
    esc = html.escape
    return f'<td class="health-{esc(str(flag))}" data-value="{percent!r}">{esc(text)}</td>'


def _html_text(rows: Sequence[Mapping[str, Any]], meta: Mapping[str, Any]) -> str:
    esc = html.escape
    rpe_label = f"{meta['rpe_distance_m']:g} m" if meta.get("rpe_distance_m") else "distance"
    heads = "".join(
        f'<th data-key="{f}" data-kind="{k}" scope="col">'
        f'<button type="button">{esc(h.format(rpe=rpe_label))}</button></th>'
        for f, h, k in _COLUMNS
    )
    body = "\n".join(
        f'<tr class="bag" data-name="{esc(str(r["name"]))}">'
        + "".join(_cell(f, k, r, meta) for f, _, k in _COLUMNS)
        + "</tr>"
        for r in rows
    )
    totals = meta.get("totals", {})
    counts = totals.get("by_status", {})
    items = [f"<li><b>{totals.get('bags', len(rows))}</b> bags</li>"]
    items += [f"<li><b>{n}</b> {esc(status)}</li>" for status, n in counts.items() if n]
    items.append(f"<li><b>{totals.get('scans', 0)}</b> scans</li>")
    items.append(f"<li><b>{totals.get('length_m', 0.0):.1f}</b> m</li>")
    title = f"lidar3d batch report: {meta.get('out_dir', '')}"
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{esc(title)}</title>\n<style>{_CSS}</style>\n</head>\n<body>\n"
        f'<h1>lidar3d batch report</h1>\n<p class="meta">{esc(str(meta.get("out_dir", "")))} &middot; '
        f"written {esc(str(meta.get('written_utc', '')))} &middot; engine {esc(str(meta.get('engine', '')))} &middot; "
        f"lidar3d {esc(str(meta.get('lidar3d_version', '')))}"
        + (" &middot; <b>interrupted</b>" if meta.get("interrupted") else "")
        + "</p>\n"
        f'<ul class="totals">{"".join(items)}</ul>\n'
        f'<div class="table"><table id="bags">\n<thead><tr>{heads}</tr></thead>\n<tbody>\n{body}\n</tbody>\n'
        "</table></div>\n"
        f"<script>{_JS}</script>\n</body>\n</html>\n"
    )


def write_report(batch_dir: Path, rows: Sequence[Mapping[str, Any]], meta: Mapping[str, Any]) -> ReportPaths:
    """Write the three report files into ``batch_dir``, each atomically; returns their paths."""
    paths = ReportPaths(batch_dir / "summary.csv", batch_dir / "summary.json", batch_dir / "report.html")
    write_text_atomic(paths.csv, _csv_text(rows))
    write_text_atomic(paths.json, json.dumps({**meta, "bags": list(rows)}, indent=2) + "\n")
    write_text_atomic(paths.html, _html_text(rows, meta))
    return paths
