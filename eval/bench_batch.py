"""Benchmark of ``lidar3d batch``: the same bags with 1 worker and with N workers (default 2).

Simulates ``--bags`` drives (``--duration`` seconds each, different seeds) into a temporary folder,
then times :func:`lidar3d.batch.run_batch` (local engine, fresh output folder each time) with 1
worker and with ``--workers`` workers, alternating the order over ``--runs`` rounds, and reports
the median wall times and the speed-up (and the fastest rounds'). Wall time includes starting the worker processes (each
imports the SLAM stack once). With more than one worker every job runs with one BLAS/OpenMP
thread, so N processes use N cores; a single worker keeps the default threading and so uses a
little more than one core (about 1.25 on the 2-core test machine), which lowers the apparent
speed-up: ``--single-thread-baseline`` pins the 1-worker run to one BLAS/OpenMP thread as well
(run_bag's scan-prefetch thread still runs). The outputs of
both settings are checked to be identical.

Other processes on the machine slow it down unevenly: for every timed batch the script prints
how many cores other processes kept busy meanwhile (from /proc/stat minus this process and its
workers, plus time stolen by the hypervisor) and the load average; report them with the figure. Usage::

    .venv/bin/python eval/bench_batch.py                    # 4 bags x 8 s, 1 vs 2 workers, 1 round
    .venv/bin/python eval/bench_batch.py --runs 3 --json results/bench_batch.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

# Only light imports at the top: spawned workers re-import this file before limiting BLAS threads.
from lidar3d.batch import run_batch  # noqa: E402
from lidar3d.batch.jobs import THREAD_VARIABLES  # noqa: E402

OUTPUTS = ("trajectory_tum.txt", "odometry_tum.txt", "keyframes_tum.txt", "map.pcd")


def simulate_bags(folder: Path, n_bags: int, duration_s: float, scenario: str) -> int:
    """``folder/bag_<k>/scans.bag`` for k < n_bags; returns the total number of scans."""
    from lidar3d.sim import simulate

    return sum(simulate(scenario, folder / f"bag_{k}", seed=k, duration_s=duration_s).n_scans for k in range(n_bags))


def _cpu_counters() -> tuple[float, float, float]:
    """(busy, steal) CPU seconds of the whole machine from /proc/stat, and this process + children."""
    ticks = os.sysconf("SC_CLK_TCK")
    busy = steal = 0.0
    try:
        with open("/proc/stat") as handle:
            fields = [int(v) for v in handle.readline().split()[1:]]
        user, nice, system, _idle, _iowait, irq, softirq, steal_ticks = (fields + [0] * 8)[:8]
        busy, steal = (user + nice + system + irq + softirq) / ticks, steal_ticks / ticks
    except OSError:
        pass
    own = sum(
        getattr(resource.getrusage(who), f)
        for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
        for f in ("ru_utime", "ru_stime")
    )
    return busy, steal, own


def timed_batch(data: Path, out: Path, workers: int, single_thread: bool = False) -> tuple[float, float, float]:
    """Wall seconds, and the CPU seconds used meanwhile by other processes and stolen by the host.

    ``single_thread``: the workers inherit BLAS/OpenMP thread variables set to 1 (the batch itself
    sets them only with more than one worker).
    """
    saved = {name: os.environ.get(name) for name in THREAD_VARIABLES}
    if single_thread:
        os.environ.update(dict.fromkeys(THREAD_VARIABLES, "1"))
    busy0, steal0, own0 = _cpu_counters()
    began = time.perf_counter()
    try:
        outcome = run_batch([data], out, workers=workers)
    finally:
        for name, value in saved.items():
            if value is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = value
    wall = time.perf_counter() - began
    busy1, steal1, own1 = _cpu_counters()
    if not outcome.ok:
        raise SystemExit(f"batch with {workers} worker(s) did not finish every bag: {outcome.counts}")
    return wall, max(0.0, (busy1 - busy0) - (own1 - own0)), steal1 - steal0


def same_outputs(a: Path, b: Path) -> bool:
    names = sorted(p.name for p in a.iterdir() if p.is_dir() and not p.name.startswith("."))
    return all((a / n / f).read_bytes() == (b / n / f).read_bytes() for n in names for f in OUTPUTS)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bags", type=int, default=4, help="number of bags (default 4)")
    parser.add_argument("--duration", type=float, default=8.0, help="seconds per bag (default 8, 80 scans)")
    parser.add_argument("--workers", type=int, default=2, help="parallel workers to compare with 1 (default 2)")
    parser.add_argument("--runs", type=int, default=1, help="rounds; the median is reported (default 1)")
    parser.add_argument("--scenario", default="loop", help="simulation scenario (default loop)")
    parser.add_argument(
        "--single-thread-baseline",
        action="store_true",
        help="run the 1-worker batch with one BLAS/OpenMP thread too (by default it may use more cores)",
    )
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = parser.parse_args(argv)

    root = Path(tempfile.mkdtemp(prefix="bench_batch_"))
    try:
        data = root / "data"
        n_scans = simulate_bags(data, args.bags, args.duration, args.scenario)
        walls: dict[int, list[float]] = {1: [], args.workers: []}
        others: dict[int, list[float]] = {1: [], args.workers: []}
        loads = []
        identical = True
        for run in range(args.runs):
            order = (1, args.workers) if run % 2 == 0 else (args.workers, 1)
            before = os.getloadavg()
            for workers in order:
                single = args.single_thread_baseline and workers == 1
                wall, other_cpu_s, steal_s = timed_batch(data, root / f"out_{run}_{workers}", workers, single)
                walls[workers].append(wall)
                others[workers].append((other_cpu_s + steal_s) / wall)
            loads.append((before, os.getloadavg()))
            identical &= same_outputs(root / f"out_{run}_1", root / f"out_{run}_{args.workers}")
            for workers in order:
                shutil.rmtree(root / f"out_{run}_{workers}")
            print(
                f"round {run + 1}: 1 worker {walls[1][-1]:.1f} s, "
                f"{args.workers} workers {walls[args.workers][-1]:.1f} s, "
                f"load average {before[0]:.1f} -> {loads[-1][1][0]:.1f}, cores busy with other work (incl. steal) "
                f"{others[1][-1]:.2f} / {others[args.workers][-1]:.2f}",
                file=sys.stderr,
            )
    finally:
        shutil.rmtree(root, ignore_errors=True)

    one, many = statistics.median(walls[1]), statistics.median(walls[args.workers])
    best_one, best_many = min(walls[1]), min(walls[args.workers])
    result = {
        "bags": args.bags,
        "scans": n_scans,
        "duration_s_per_bag": args.duration,
        "workers": args.workers,
        "wall_s_1_worker": walls[1],
        f"wall_s_{args.workers}_workers": walls[args.workers],
        "speedup": one / many,
        "speedup_best": best_one / best_many,
        "scans_per_s_1_worker": n_scans / one,
        f"scans_per_s_{args.workers}_workers": n_scans / many,
        "single_thread_baseline": args.single_thread_baseline,
        "identical_outputs": identical,
        "load_average_1min_before_after": [[round(b[0], 2), round(a[0], 2)] for b, a in loads],
        "other_cores_busy_1_worker": [round(v, 2) for v in others[1]],
        f"other_cores_busy_{args.workers}_workers": [round(v, 2) for v in others[args.workers]],
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "machine": platform.machine(),
    }
    print("| bags | scans | workers | wall [s] | scans/s | speed-up |")
    print("|---:|---:|---:|---:|---:|---:|")
    print(f"| {args.bags} | {n_scans} | 1 | {one:.1f} | {n_scans / one:.1f} | 1.00 |")
    print(f"| {args.bags} | {n_scans} | {args.workers} | {many:.1f} | {n_scans / many:.1f} | {one / many:.2f} |")
    print(
        f"\nmedian of {args.runs} round(s); fastest rounds: {best_one:.1f} s vs {best_many:.1f} s, "
        f"speed-up {best_one / best_many:.2f}"
    )
    print(
        f"outputs identical: {identical}; {os.cpu_count()} CPUs; load average (1 min) before/after each round: "
        f"{result['load_average_1min_before_after']}"
    )
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 0 if identical else 1


if __name__ == "__main__":
    sys.exit(main())
