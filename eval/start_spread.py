"""Start-offset spread: how far one drive's figures move when lidar3d starts a few scans later.

A run that skips the bag's first scan (``lidar3d run --start 1``) is the same drive, the same
method and the same configuration; a method that holds each pose by what the scans observe gives
it nearly the same trajectory. On stretches where a direction is barely observed (open land, a
featureless canyon) the estimate instead follows whatever small differences it meets, and the ATE
of one run is one draw from a wide distribution: on `blind_turn` seed 2 a one-scan offset took
it from 0.41 to 0.78 m, on `long` seed 1 from 0.09 to 0.52 m (2026-12-07, docs/benchmarks.md).
A change judged on one run per drive is then judged on noise. This runs lidar3d on each cached
suite drive from several start scans (each in its own process, as the suite does) and reports,
per drive, the ATE and worst pose error at each start, their median, and the spread (largest
over smallest ATE). Compare two versions of the code by their medians, and read a difference
within the spread as no difference. Usage::

    .venv/bin/python eval/start_spread.py --scenarios blind_turn long --seeds 0 1 2 --starts 0 1 2
    .venv/bin/python eval/start_spread.py --scenarios loop --seeds 0 --starts 0 5 --duration 20 --jobs 2

Writes ``results.json`` and ``start_spread.md`` to ``--out`` (default
``eval/results/start_spread_<UTC time>/``), again after every run that finishes (marked partial
until the last), and each run's scored record beside its outputs; ``--resume`` with the same
``--out`` finishes an interrupted one without running again what it finished.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
for entry in (str(REPO), str(HERE)):
    if entry not in sys.path:
        sys.path.insert(0, entry)

from run_suite import DEFAULT_RESULTS, SCENARIOS, run_scored, run_tasks  # noqa: E402
from suite_cache import DEFAULT_CACHE, ensure_scenario  # noqa: E402

from lidar3d.io.atomic import write_text_atomic  # noqa: E402


def drive_figures(records: dict[int, dict]) -> dict:
    """Per start scan the ATE and worst pose error (m) of its record, and over the starts that
    finished: the median ATE, the smallest and largest, and their ratio (the spread)."""
    per_start = {}
    for start, record in sorted(records.items()):
        gt = record.get("scores", {}).get("gt", {}) if record.get("status") == "ok" else {}
        ate = gt.get("ate_rmse_m", {}).get("3d")
        per_start[start] = {"ate_m": ate, "max_m": gt.get("ate_max_3d_m"), "status": record.get("status")}
    ates = [v["ate_m"] for v in per_start.values() if v["ate_m"] is not None]
    summary = {
        "median_ate_m": statistics.median(ates) if ates else None,
        "min_ate_m": min(ates) if ates else None,
        "max_ate_m": max(ates) if ates else None,
        "spread": max(ates) / min(ates) if ates and min(ates) > 0 else None,
    }
    return {"starts": per_start, **summary}


def _cell(value: float | None, digits: int = 3) -> str:
    return "failed" if value is None else f"{value:.{digits}f}"


def render(figures: dict[str, dict], starts: list[int], header: str) -> str:
    """The Markdown table of :func:`drive_figures` per drive (``scenario_sSEED``); a start not run
    (yet) is a dash."""
    lines = [
        header,
        "",
        "| drive | " + " | ".join(f"start {k}: ATE / max (m)" for k in starts) + " | median ATE | spread |",
        "|---|" + "---:|" * (len(starts) + 2),
    ]
    for drive, f in figures.items():
        cells = [
            f"{_cell(f['starts'][k]['ate_m'])} / {_cell(f['starts'][k]['max_m'], 2)}" if k in f["starts"] else "–"
            for k in starts
        ]
        spread = "–" if f["spread"] is None else f"x{f['spread']:.2f}"
        lines.append(f"| {drive} | " + " | ".join(cells) + f" | {_cell(f['median_ate_m'])} | {spread} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", nargs="+", choices=SCENARIOS, default=list(SCENARIOS))
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--starts", nargs="+", type=int, default=[0, 1, 2], help="first scans (default 0 1 2)")
    parser.add_argument("--duration", type=float, default=None, help="simulate only the first S seconds")
    parser.add_argument("--no-loop", action="store_true", help="lidar3d with loop closure off")
    parser.add_argument("--jobs", type=int, default=1, help="runs at a time")
    parser.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE)
    parser.add_argument("--out", type=Path, help="results folder (default eval/results/start_spread_<UTC time>)")
    parser.add_argument(
        "--resume", action="store_true", help="runs that finished in --out with the same options are not run again"
    )
    args = parser.parse_args(argv)
    if args.resume and args.out is None:
        parser.error("--resume needs the --out folder of the run to finish")
    if any(k < 0 for k in args.starts):
        parser.error(f"--starts: a start scan is at least 0, not {min(args.starts)}")
    if args.jobs < 1:
        parser.error(f"--jobs: at least 1, not {args.jobs}")
    starts = sorted(set(args.starts))
    out = args.out or DEFAULT_RESULTS / time.strftime("start_spread_%Y%m%dT%H%M%SZ", time.gmtime())
    cases = {
        f"{name}_s{seed}": ensure_scenario(name, seed, args.duration, cache_dir=args.cache_dir)
        for name in args.scenarios
        for seed in args.seeds
    }
    tasks = [(drive, k) for drive in cases for k in starts]

    def work(task: tuple[str, int]) -> dict:
        drive, start = task
        print(f"{drive} start {start}: lidar3d", file=sys.stderr, flush=True)
        return run_scored(
            "lidar3d",
            cases[drive],
            out / drive / f"start{start}",
            genz_deskew=True,
            timeout_s=None,
            loop_closure=not args.no_loop,
            start=start,
            resume=args.resume,
        )

    loop = "loop closure off" if args.no_loop else "loop closure on"

    def publish(records: dict[tuple[str, int], dict], complete: bool) -> str:
        """results.json and start_spread.md from the runs finished so far (written after each)."""
        figures = {
            drive: drive_figures({k: records[(drive, k)] for k in starts if (drive, k) in records})
            for drive in cases
            if any((drive, k) in records for k in starts)
        }
        out.mkdir(parents=True, exist_ok=True)
        done = f"{len(records)} of {len(tasks)} runs"
        summary = {"complete": complete, "runs_finished": len(records), "runs": len(tasks), "drives": figures}
        write_text_atomic(out / "results.json", json.dumps(summary, indent=1) + "\n")
        note = "" if complete else f" **partial: {done} finished**"
        table = render(figures, starts, f"lidar3d from start scans {', '.join(map(str, starts))} ({loop}):{note}")
        write_text_atomic(out / "start_spread.md", table)
        return table

    records = run_tasks(tasks, work, args.jobs, lambda so_far: publish(so_far, complete=False))
    print(publish(records, complete=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
