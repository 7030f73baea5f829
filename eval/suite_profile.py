"""Profile mode of the suite (``eval/run_suite.py --profile SCENARIO``): where lidar3d's time goes.

Runs :func:`lidar3d.run.run_bag` in this process on the cached scenario, under pyinstrument (a
sampling profiler, low overhead) when it is installed, else under cProfile, and prints

1. the time per pipeline stage (mean, median, p95 ms/scan and share of the summed stages), from the
   pipeline's own timers;
2. the functions that take the time: pyinstrument's call tree (filtered to frames above 1 %) and
   its flat list by own time, or cProfile's lists by cumulative and by own time.

The profile is kept in ``eval/results/profile_<scenario>_<UTC time>/`` (``profile.html`` and
``profile.txt`` for pyinstrument, ``profile.pstats`` for cProfile), beside the run's outputs.
"""

from __future__ import annotations

import argparse
import datetime as dt
import importlib.util
import io
import time
from pathlib import Path

import numpy as np
from suite_cache import ensure_scenario

__all__ = ["profile_scenario", "stage_table"]


def stage_table(timings_ms: dict[str, np.ndarray], wall_s: float, n_scans: int) -> str:
    """Per-stage timing as a fixed-width text table."""
    rows = []
    total = 0.0
    for name, values in timings_ms.items():
        v = np.asarray(values, dtype=np.float64)
        if v.size:
            rows.append((name, float(v.mean()), float(np.median(v)), float(np.percentile(v, 95)), float(v.sum())))
            total += float(v.sum())
    lines = [f"{'stage':<16}{'mean ms':>10}{'median ms':>11}{'p95 ms':>10}{'share':>8}"]
    for name, mean, median, p95, summed in sorted(rows, key=lambda r: -r[4]):
        share = 100.0 * summed / total if total else 0.0
        lines.append(f"{name:<16}{mean:>10.2f}{median:>11.2f}{p95:>10.2f}{share:>7.1f}%")
    per_scan = 1e3 * wall_s / n_scans if n_scans else float("nan")
    lines.append(f"{'sum of stages':<16}{total / max(n_scans, 1):>10.2f}   (bag reading is not a stage: wall - sum)")
    lines.append(
        f"{'wall':<16}{per_scan:>10.2f}   ({n_scans} scans in {wall_s:.1f} s, "
        f"{n_scans / wall_s if wall_s else 0:.1f} scans/s)"
    )
    return "\n".join(lines)


def _use_pyinstrument(choice: str) -> bool:
    available = importlib.util.find_spec("pyinstrument") is not None
    if choice == "pyinstrument" and not available:
        raise SystemExit("pyinstrument is not installed: pip install -e '.[eval]', or use --profiler cprofile")
    return available and choice != "cprofile"


def profile_scenario(args: argparse.Namespace) -> int:
    """Profile lidar3d on ``args.profile`` (with ``args.duration``, first seed); print the findings."""
    from lidar3d.run import run_bag

    seed = args.seeds[0]
    case = ensure_scenario(args.profile, seed, args.duration, cache_dir=args.cache_dir, regenerate=args.regenerate)
    stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    out_dir = Path(args.results_dir) / f"profile_{case.scenario}_s{seed}_{stamp}"
    out_dir.mkdir(parents=True, exist_ok=True)
    print(
        f"profiling lidar3d on {case.label}: {case.n_scans} scans, {case.path_length_m:.0f} m "
        f"({'first ' + format(args.duration, 'g') + ' s' if args.duration else 'full length'})",
        flush=True,
    )

    use_pyinstrument = _use_pyinstrument(args.profiler)
    t0 = time.perf_counter()
    if use_pyinstrument:
        from pyinstrument import Profiler
        from pyinstrument.renderers import ConsoleRenderer

        profiler = Profiler(interval=0.001)
        profiler.start()
        outcome = run_bag(case.bag, out_dir / "run", overwrite=True)
        profiler.stop()
        session = profiler.last_session
        tree = profiler.output(
            ConsoleRenderer(unicode=True, color=False, show_all=False, processor_options={"filter_threshold": 0.01})
        )
        flat = profiler.output(ConsoleRenderer(unicode=True, color=False, flat=True, flat_time="self"))
        flat = "\n".join(flat.splitlines()[: args.top + 8])
        (out_dir / "profile.html").write_text(profiler.output_html(), encoding="utf-8")
        (out_dir / "profile.txt").write_text(tree + "\n\n" + flat + "\n", encoding="utf-8")
        profiler_name = (
            f"pyinstrument, sampled every 1 ms: {session.sample_count} samples, CPU time "
            f"{session.cpu_time:.1f} s of {session.duration:.1f} s wall; the rest waited for a CPU "
            "or for I/O"
        )
        function_text = "call tree (frames over 1 % of the time):\n" + tree + "\nby own time:\n" + flat
    else:
        import cProfile
        import pstats

        profiler = cProfile.Profile()
        profiler.enable()
        outcome = run_bag(case.bag, out_dir / "run", overwrite=True)
        profiler.disable()
        profiler.dump_stats(str(out_dir / "profile.pstats"))
        texts = []
        for key in ("cumulative", "tottime"):
            buffer = io.StringIO()
            pstats.Stats(profiler, stream=buffer).strip_dirs().sort_stats(key).print_stats(args.top)
            texts.append(f"by {key}:\n{buffer.getvalue()}")
        profiler_name = "cProfile (deterministic; adds overhead to Python-heavy code)"
        function_text = "\n".join(texts)
    elapsed = time.perf_counter() - t0

    summary = outcome.summary
    print()
    print(f"== time per stage (pipeline timers; profiler: {profiler_name}) ==")
    print(stage_table(dict(outcome.result.timings_ms), summary.runtime_s, summary.scans))
    print(f"(profiled run took {elapsed:.1f} s including the final writes; outputs in {out_dir / 'run'})")
    print()
    print("== time per function ==")
    print(function_text)
    print(f"profile saved in {out_dir}")
    return 0
