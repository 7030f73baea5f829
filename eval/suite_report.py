"""Markdown tables of a suite run (``BENCHMARKS.md``), built from the rows ``run_suite.py`` collects.

A row is one (scenario, seed, method) run: ``{"scenario", "seed", "method", "status", "run",
"scores", "peak_rss_mib", "case": {...}}``. Peers sit beside lidar3d in every table; the wall-time
ratio is lidar3d's wall time divided by the peer's on the same bag (above 1: lidar3d is slower).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["METHOD_NAMES", "render_markdown"]

METHOD_NAMES = {"lidar3d": "lidar3d", "kiss-icp": "KISS-ICP", "genz-icp": "GenZ-ICP"}
DASH = "–"


def _get(d: dict | None, *path: str):
    for key in path:
        if not isinstance(d, dict) or key not in d:
            return None
        d = d[key]
    return d


def fmt_num(value, digits: int = 2, suffix: str = "") -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return DASH
    return f"{value:.{digits}f}{suffix}"


def _case_label(row: dict, multi_seed: bool) -> str:
    return f"{row['scenario']} s{row['seed']}" if multi_seed else row["scenario"]


def _cases(rows: Sequence[dict]) -> list[tuple[str, int]]:
    seen: list[tuple[str, int]] = []
    for row in rows:
        key = (row["scenario"], row["seed"])
        if key not in seen:
            seen.append(key)
    return seen


def _by_case(rows: Sequence[dict]) -> dict[tuple[str, int], dict[str, dict]]:
    table: dict[tuple[str, int], dict[str, dict]] = {}
    for row in rows:
        table.setdefault((row["scenario"], row["seed"]), {})[row["method"]] = row
    return table


def _ok(row: dict | None) -> bool:
    return row is not None and row.get("status") == "ok"


def wall_ratio(ours: dict | None, peer: dict | None) -> float | None:
    """lidar3d wall time / peer wall time on the same bag."""
    if not (_ok(ours) and _ok(peer)):
        return None
    a, b = _get(ours, "run", "wall_s"), _get(peer, "run", "wall_s")
    return a / b if a and b else None


def _triple(methods: Sequence[str], per_method: dict[str, dict], fmt) -> str:
    return " / ".join(
        fmt(per_method.get(m)) if _ok(per_method.get(m)) else ("failed" if per_method.get(m) else DASH) for m in methods
    )


def _drift_text(row: dict) -> str:
    m, pct = _get(row, "scores", "end_drift", "m"), _get(row, "scores", "end_drift", "percent")
    return DASH if m is None else f"{m:.2f} ({fmt_num(pct, 2)} %)"


def _loops_text(row: dict) -> str:
    if row["method"] != "lidar3d":
        return "n/a (odometry)"
    value = row.get("loop_closures")
    revisits = row.get("case", {}).get("revisit_events")
    context = "" if revisits is None else f" ({revisits} revisit{'s' if revisits != 1 else ''} in the drive)"
    check = row.get("closures") or {}
    if check.get("worst_m") is not None:
        context += f"; worst {100 * check['worst_m']:.1f} cm / {check['worst_deg']:.2f}°"
    loop_ms, wall_s = _get(row, "run", "loop_ms_total"), _get(row, "run", "wall_s")
    if loop_ms is not None and wall_s:
        context += f"; {loop_ms / 10 / wall_s:.1f} % of the run"
    return (DASH if value is None else str(value)) + context


def fmt_percent(value) -> str:
    return DASH if value is None else f"{100 * value:.1f} %"


def _health_lines(
    cases: list[tuple[str, int]], grid: dict[tuple[str, int], dict[str, dict]], multi_seed: bool
) -> list[str]:
    """The table of lidar3d's health flags scored against the truth (``eval/health_check.py``)."""
    rows = [row for case in cases if (row := grid[case].get("lidar3d")) is not None and _ok(row)]
    rows = [row for row in rows if isinstance(row.get("health"), dict)]
    if not rows:
        return []
    out = [
        "## lidar3d health signal against ground truth (`eval/health_check.py`)",
        "",
        "A scan is bad when the 10 m segment ending at it is off by more than 0.3 m once its start is aligned; "
        "recall: bad scans flagged degraded or lost (target >= 90 %); false flags: good scans flagged (target < 5 %).",
        "",
    ]
    cols = ["scenario", "scans ok / degraded / lost", "lost m", "bad scans", "recall", "false flags"]
    out += [_row(cols), _row(["---"] * len(cols))]
    for row in rows:
        check = row["health"]
        if "error" in check:
            out.append(_row([_case_label(row, multi_seed), f"error: {check['error'][:80]}", "", "", "", ""]))
            continue
        flags = check.get("flags", {})
        counts = " / ".join(str(flags.get(flag, 0)) for flag in ("ok", "degraded", "lost"))
        lost_m = _get(row, "run", "health", "lost_m")
        out.append(
            _row(
                [
                    _case_label(row, multi_seed),
                    counts,
                    fmt_num(lost_m, 1),
                    f"{check.get('bad')} of {check.get('scored')}",
                    fmt_percent(check.get("recall")),
                    fmt_percent(check.get("false_flag_rate")),
                ]
            )
        )
    out.append("")
    return out


def render_markdown(rows: Sequence[dict], header: dict) -> str:
    """The whole ``BENCHMARKS.md`` text."""
    methods = [m for m in METHOD_NAMES if any(r["method"] == m for r in rows)]
    peers = [m for m in methods if m != "lidar3d"]
    multi_seed = len({r["seed"] for r in rows}) > 1
    cases = _cases(rows)
    grid = _by_case(rows)
    names = " / ".join(METHOD_NAMES[m] for m in methods)
    out: list[str] = ["# Benchmarks", ""]
    out += header_lines(header)

    # --- summary ---------------------------------------------------------------------------
    out += ["## Summary: lidar3d beside the peers", ""]
    cols = [
        "scenario",
        "length m",
        "scans",
        f"ATE 3-D m ({names})",
        f"RPE % ({names})",
        f"end drift m ({names})",
        f"scans/s ({names})",
    ]
    cols += [f"wall time lidar3d/{METHOD_NAMES[p]}" for p in peers]
    out += [_row(cols), _row(["---"] * len(cols))]
    for case in cases:
        per = grid[case]
        any_row = next(iter(per.values()))
        cells = [
            _case_label(any_row, multi_seed),
            fmt_num(any_row["case"]["path_length_m"], 0),
            str(any_row["case"]["n_scans"]),
            _triple(methods, per, lambda r: fmt_num(_get(r, "scores", "gt", "ate_rmse_m", "3d"), 2)),
            _triple(methods, per, lambda r: fmt_num(_get(r, "scores", "gt", "rpe_kitti", "translation_percent"), 2)),
            _triple(methods, per, lambda r: fmt_num(_get(r, "scores", "end_drift", "m"), 2)),
            _triple(methods, per, lambda r: fmt_num(_get(r, "run", "scans_per_s"), 1)),
        ]
        for p in peers:
            ratio = wall_ratio(per.get("lidar3d"), per.get(p))
            cells.append(DASH if ratio is None else f"{ratio:.2f}×")
        out.append(_row(cells))
    out.append("")

    # --- accuracy against ground truth ----------------------------------------------------
    out += ["## Accuracy against ground truth (SE(3)-aligned ATE RMSE; KITTI RPE over 100–800 m)", ""]
    cols = [
        "scenario",
        "method",
        "ATE 3-D m",
        "ATE horiz. m",
        "ATE vert. m",
        "ATE rot. deg",
        "RPE %",
        "RPE deg/100 m",
        "RPE 10 m %",
        "end drift m (% of length)",
        "loop closures",
    ]
    out += [_row(cols), _row(["---"] * len(cols))]
    for case in cases:
        for method in methods:
            row = grid[case].get(method)
            if row is None:
                continue
            label = _case_label(row, multi_seed)
            if not _ok(row):
                failure = f"failed: {row.get('error', '')[:80]}"
                out.append(_row([label, METHOD_NAMES[method], failure] + [""] * (len(cols) - 3)))
                continue
            gt = _get(row, "scores", "gt") or {}
            out.append(
                _row(
                    [
                        label,
                        METHOD_NAMES[method],
                        fmt_num(_get(gt, "ate_rmse_m", "3d"), 3),
                        fmt_num(_get(gt, "ate_rmse_m", "horizontal"), 3),
                        fmt_num(_get(gt, "ate_rmse_m", "vertical"), 3),
                        fmt_num(_get(gt, "ate_rotation_rmse_deg"), 2),
                        fmt_num(_get(gt, "rpe_kitti", "translation_percent"), 2),
                        fmt_num(_get(gt, "rpe_kitti", "rotation_deg_per_100m"), 2),
                        fmt_num(_get(gt, "rpe_distance", "10m", "translation_percent"), 2),
                        _drift_text(row),
                        _loops_text(row),
                    ]
                )
            )
    out.append("")

    # --- accuracy against the SPAN log -----------------------------------------------------
    out += ["## Accuracy against the simulated SPAN-CPT log (with the rig's T_imu_lidar)", ""]
    cols = ["scenario", "method", "poses associated", "ATE 3-D m", "ATE horiz. m", "ATE vert. m", "RPE %"]
    out += [_row(cols), _row(["---"] * len(cols))]
    for case in cases:
        for method in methods:
            row = grid[case].get(method)
            if not _ok(row):
                continue
            span = _get(row, "scores", "span") or {}
            if "error" in span:
                out.append(
                    _row(
                        [
                            _case_label(row, multi_seed),
                            METHOD_NAMES[method],
                            f"error: {span['error'][:80]}",
                            "",
                            "",
                            "",
                            "",
                        ]
                    )
                )
                continue
            out.append(
                _row(
                    [
                        _case_label(row, multi_seed),
                        METHOD_NAMES[method],
                        f"{span.get('associated', 0)} of {span.get('of', 0)}",
                        fmt_num(_get(span, "ate_rmse_m", "3d"), 3),
                        fmt_num(_get(span, "ate_rmse_m", "horizontal"), 3),
                        fmt_num(_get(span, "ate_rmse_m", "vertical"), 3),
                        fmt_num(_get(span, "rpe_kitti", "translation_percent"), 2),
                    ]
                )
            )
    out.append("")

    out += _health_lines(cases, grid, multi_seed)

    # --- speed and memory -------------------------------------------------------------------
    out += ["## Speed and memory", ""]
    cols = ["scenario", "method", "scans", "wall s", "scans/s", "ms/scan", "wall time lidar3d/this", "peak RSS MiB"]
    out += [_row(cols), _row(["---"] * len(cols))]
    for case in cases:
        ours = grid[case].get("lidar3d")
        for method in methods:
            row = grid[case].get(method)
            if not _ok(row):
                continue
            wall, n = _get(row, "run", "wall_s"), _get(row, "run", "scans")
            ratio = wall_ratio(ours, row) if method != "lidar3d" else None
            out.append(
                _row(
                    [
                        _case_label(row, multi_seed),
                        METHOD_NAMES[method],
                        str(n),
                        fmt_num(wall, 1),
                        fmt_num(_get(row, "run", "scans_per_s"), 1),
                        fmt_num(1e3 * wall / n if wall and n else None, 1),
                        (f"{ratio:.2f}×" if ratio is not None else (DASH if method != "lidar3d" else "1.00×")),
                        fmt_num(row.get("peak_rss_mib"), 0),
                    ]
                )
            )
    out.append("")

    out += speed_target_lines(cases, grid, multi_seed)

    # --- per stage ----------------------------------------------------------------------------
    stage_names: list[str] = []
    for row in rows:
        if row["method"] == "lidar3d" and _ok(row):
            for name in _get(row, "run", "stage_ms") or {}:
                if name not in stage_names:
                    stage_names.append(name)
    if stage_names:
        out += ["## lidar3d time per stage (mean ms/scan; median in `eval/results/.../results.json`)", ""]
        cols = ["scenario", *stage_names, "sum of stages", "wall ms/scan"]
        out += [_row(cols), _row(["---"] * len(cols))]
        for case in cases:
            row = grid[case].get("lidar3d")
            if not _ok(row):
                continue
            stages = _get(row, "run", "stage_ms") or {}
            means = [_get(stages, name, "mean") for name in stage_names]
            total = sum(v for v in means if v is not None)
            wall, n = _get(row, "run", "wall_s"), _get(row, "run", "scans")
            out.append(
                _row(
                    [
                        _case_label(row, multi_seed),
                        *(fmt_num(v, 1) for v in means),
                        fmt_num(total, 1),
                        fmt_num(1e3 * wall / n if wall and n else None, 1),
                    ]
                )
            )
        out.append("")
    if peers:
        out += ["Peers, mean ms/scan: reading + decoding the scan (same reader as lidar3d) / `register_frame`:", ""]
        cols = ["scenario", *(METHOD_NAMES[p] for p in peers)]
        out += [_row(cols), _row(["---"] * len(cols))]
        for case in cases:
            cells = []
            label = None
            for p in peers:
                row = grid[case].get(p)
                if _ok(row):
                    label = label or _case_label(row, multi_seed)
                    cells.append(
                        f"{fmt_num(_get(row, 'run', 'stage_ms', 'read', 'mean'), 1)} / "
                        f"{fmt_num(_get(row, 'run', 'stage_ms', 'register', 'mean'), 1)}"
                    )
                else:
                    cells.append(DASH)
            if label:
                out.append(_row([label, *cells]))
        out.append("")
    out += notes_lines(header)
    return "\n".join(out).rstrip() + "\n"


def process_wall_ratio(ours: dict | None, peer: dict | None) -> float | None:
    """lidar3d's whole-process wall time / the peer's, on the same bag in the same suite run."""
    if not (_ok(ours) and _ok(peer)):
        return None
    a, b = ours.get("process_wall_s"), peer.get("process_wall_s") if peer else None
    return a / b if a and b else None


def speed_target_lines(cases: Sequence, grid: dict, multi_seed: bool) -> list[str]:
    """The table of issue 17's targets: lidar3d beside KISS-ICP on each bag, per-stage medians
    (ms/scan) and the peak RSS of each run's whole process tree."""
    rows = [(case, grid[case].get("lidar3d"), grid[case].get("kiss-icp")) for case in cases]
    rows = [(case, ours, kiss) for case, ours, kiss in rows if _ok(ours)]
    if not rows:
        return []
    out = [
        "## Speed against KISS-ICP (targets: wall ratio <= 1, front end <= 5 ms, mapping <= 8 ms)",
        "",
        "Wall time of the whole process (start, imports, bag reading, every output written) on the same bag "
        "in this suite run, and the CPU time of its process tree (user + system; KISS-ICP's threads and "
        "lidar3d's two processes alike), which a busy machine disturbs less; "
        "stage columns are lidar3d's medians in ms/scan (front end: its five stages "
        "summed per scan, in the prefetch process); peak RSS is the sampled sum over the process tree "
        "(lidar3d's prefetch process included).",
        "",
    ]
    cols = [
        "scenario",
        "scans",
        "lidar3d s",
        "KISS-ICP s",
        "lidar3d/KISS-ICP",
        "CPU s lidar3d / KISS-ICP",
        "front end",
        "deskew",
        "odometry",
        "mapping",
        "redeskew (p95)",
        "map update",
        "tree RSS MiB lidar3d / KISS-ICP",
    ]
    out += [_row(cols), _row(["---"] * len(cols))]
    for _case, ours, kiss in rows:
        ratio = process_wall_ratio(ours, kiss)
        stages = _get(ours, "run", "stage_ms") or {}

        def median(name: str, stats: dict = stages) -> str:
            return fmt_num(_get(stats, name, "median"), 1)

        out.append(
            _row(
                [
                    _case_label(ours, multi_seed),
                    str(_get(ours, "run", "scans")),
                    fmt_num(ours.get("process_wall_s"), 1),
                    fmt_num(kiss.get("process_wall_s"), 1) if _ok(kiss) else DASH,
                    f"{ratio:.2f}×" if ratio is not None else DASH,
                    f"{fmt_num(ours.get('cpu_s'), 1)} / " + (fmt_num(kiss.get("cpu_s"), 1) if _ok(kiss) else DASH),
                    median("front_end", _get(ours, "run", "composite_ms") or {}),
                    median("deskew"),
                    median("odometry"),
                    median("mapping"),
                    f"{median('redeskew')} ({fmt_num(_get(stages, 'redeskew', 'p95'), 1)})",
                    median("map_update"),
                    f"{fmt_num(ours.get('peak_tree_rss_mib'), 0)} / "
                    + (fmt_num(kiss.get("peak_tree_rss_mib"), 0) if _ok(kiss) else DASH),
                ]
            )
        )
    out.append("")
    return out


def _row(cells: Sequence[str]) -> str:
    return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"


def header_lines(header: dict) -> list[str]:
    lines = [
        f"Produced by `{header['command']}` on {header['date_utc']} in {header['elapsed_min']:.1f} min.",
        "",
        f"* Machine: {header['cpu']}, {header['n_cpus']} logical CPUs, {header['memory_gib']:.0f} GiB; "
        f"load average {header['load_start']} at start, {header['load_end']} at the end"
        + (
            " — **the CPU was shared with other work while this ran; timings are indicative**."
            if header.get("shared_cpu")
            else "."
        ),
        f"* lidar3d {header['lidar3d_version']} at commit {header['commit']}; Python {header['python']}; "
        + "; ".join(f"{k} {v}" for k, v in header["peer_versions"].items())
        + ".",
        *(
            ["* Libraries: " + ", ".join(f"{k} {v}" for k, v in header["library_versions"].items()) + "."]
            if "library_versions" in header
            else []
        ),
        f"* Data: simulated VLP-16 drives (`lidar3d.sim`), seed(s) {', '.join(map(str, header['seeds']))}; "
        f"{header['durations_text']}.",
        f"* Runs: one process per (scenario, method), {header['jobs']} at a time; peak RSS is that process's "
        "own high-water mark (`VmHWM`; it includes the Python interpreter and imports).",
        "",
    ]
    return lines


def notes_lines(header: dict) -> list[str]:
    return [
        "## How it is measured",
        "",
        "* **lidar3d** runs through `lidar3d.run.run_bag` with default configuration; its poses are stamped "
        "at each scan's header stamp (sweep start), like the ground truth.",
        "* **KISS-ICP** (library defaults) and **GenZ-ICP** (`outdoor` preset, deskew on) run through their "
        "Python APIs on the same bag, read by the same `ScanSource`, with per-point times normalised to 0..1. "
        "Each peer's pose is stamped at the instant of the sweep it describes — KISS-ICP deskews to the "
        "sweep end, GenZ-ICP to its middle (probed from the installed preprocessors: "
        + ", ".join(f"{METHOD_NAMES.get(k, k)} {v:g}" for k, v in header.get("peer_fractions", {}).items())
        + ") — and compared with the ground truth at that instant.",
        "* **ATE**: RMSE after an SE(3) (Umeyama, no scale) alignment of the positions, 3-D, horizontal, "
        "vertical, rotation (the rotation part is meaningful only when the path turns: on a straight stretch "
        "the positions leave the roll about it free). "
        "**RPE %**: KITTI devkit segments of 100–800 m (`–` when the drive is shorter than 100 m); "
        "**RPE 10 m %**: relative error over consecutive 10 m stretches. **End drift**: the estimate "
        "anchored on its first pose, position error at its last pose, in m and % of the path length.",
        "* **SPAN**: the same metrics against the simulated NovAtel SPAN-CPT log (INSPVAX 20 Hz with "
        "realistic GNSS/INS noise and an outage), through `lidar3d.metrics.evaluate_against_span` with the "
        "rig's lidar-to-IMU extrinsic; it shows the scores a real drive would get against its INS.",
        "* **Wall time**: the processing loop, bag reading included, process start and imports excluded "
        "(lidar3d: `summary.json` `runtime_s`; peers: the same loop around `register_frame`). "
        "The ratio is lidar3d's wall time over the peer's (above 1: lidar3d is slower).",
        "* Loop closures: accepted loop closures as lidar3d's `counts` report them (`–` while the pipeline "
        "reports none), beside the number of revisits the simulator lists for the drive (places passed "
        "again more than 30 s later within 5 m), the worst loop measurement against the truth "
        "(`eval/closure_check.py`; issue 16's target: 20 cm / 1°) and the share of lidar3d's wall time spent "
        "in loop closure (`loop_ms_total`; target at most 10 %); the peers are odometry only.",
        "",
        f"Reproduce: `make bench` (all scenarios, full length), or `{header['quick_command']}` for a quick look. "
        "Raw results, per-run outputs and SPAN reports: `eval/results/<run>/`.",
    ]
