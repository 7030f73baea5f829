"""Benchmark of the simulator: scans generated per second, and the whole ``simulate`` folder.

* generation: :meth:`lidar3d.sim.Simulation.scan` for a run of consecutive scans (per-column poses,
  ray casting through Open3D, noise, labels, ``Scan`` records), after one warm-up scan that builds
  the ray-casting scene; the median over several runs, per sensor preset;
* end to end: :func:`lidar3d.sim.simulate` into a temporary folder (deleted afterwards): generation,
  ROS1 bag, ground truth, SPAN log, metadata.

Prints Markdown tables (and JSON with ``--json``). Other processes on the machine slow it down:
report the median and say what else was running. Usage::

    .venv/bin/python eval/bench_sim.py                      # 200 scans x 5 runs, loop scenario
    .venv/bin/python eval/bench_sim.py --scans 50 --runs 3  # quick
"""

from __future__ import annotations

import argparse
import json
import os
import platform
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

from lidar3d.sim import Simulation, simulate  # noqa: E402


def bench_generation(scenario: str, sensor: str, n_scans: int, runs: int, seed: int) -> dict:
    sim = Simulation(scenario, seed=seed, sensor=sensor)
    if len(sim) < n_scans + 1:
        raise SystemExit(f"scenario {scenario} has only {len(sim)} scans")
    sim.scan(0)  # builds the ray-casting scene (not part of the per-scan cost)
    rates, points = [], 0
    for run in range(runs):
        start = 1 + (run * n_scans) % (len(sim) - n_scans)
        began = time.perf_counter()
        points = sum(len(s.scan) for s in sim.scans(start, start + n_scans))
        rates.append(n_scans / (time.perf_counter() - began))
    return {
        "sensor": sensor,
        "scans_per_s_median": statistics.median(rates),
        "scans_per_s_runs": rates,
        "points_per_scan": points / n_scans,
    }


def bench_end_to_end(scenario: str, duration_s: float, runs: int, seed: int) -> dict:
    times, n_scans = [], 0
    for _ in range(runs):
        folder = Path(tempfile.mkdtemp(prefix="bench_sim_"))
        try:
            began = time.perf_counter()
            outputs = simulate(scenario, folder / "out", seed=seed, duration_s=duration_s)
            times.append(time.perf_counter() - began)
            n_scans = outputs.n_scans
            bag_mb = outputs.bag.stat().st_size / 1e6
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    return {
        "scans": n_scans,
        "seconds_median": statistics.median(times),
        "scans_per_s_median": n_scans / statistics.median(times),
        "bag_mb": bag_mb,
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="loop")
    parser.add_argument("--scans", type=int, default=200, help="scans per generation run")
    parser.add_argument("--runs", type=int, default=5, help="generation runs (median reported)")
    parser.add_argument("--sensors", nargs="+", default=["vlp16", "hdl32e", "vlp32c"])
    parser.add_argument("--e2e-duration", type=float, default=20.0, help="seconds simulated end to end")
    parser.add_argument("--e2e-runs", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    args = parser.parse_args(argv)

    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}"
    generation = [bench_generation(args.scenario, s, args.scans, args.runs, args.seed) for s in args.sensors]
    end_to_end = bench_end_to_end(args.scenario, args.e2e_duration, args.e2e_runs, args.seed)

    print(f"Simulator benchmark, scenario `{args.scenario}` ({machine})\n")
    print(f"Generation ({args.scans} scans per run, median of {args.runs} runs):\n")
    print("| sensor | scans/s (median) | runs | points/scan |")
    print("|---|---:|---|---:|")
    for g in generation:
        runs = ", ".join(f"{r:.0f}" for r in g["scans_per_s_runs"])
        print(f"| {g['sensor']} | {g['scans_per_s_median']:.0f} | {runs} | {g['points_per_scan']:.0f} |")
    print(
        f"\nEnd to end (`simulate`, {end_to_end['scans']} scans, ROS1 bag of {end_to_end['bag_mb']:.0f} MB, "
        f"median of {args.e2e_runs}): {end_to_end['seconds_median']:.2f} s, "
        f"{end_to_end['scans_per_s_median']:.0f} scans/s"
    )
    if args.json:
        Path(args.json).write_text(
            json.dumps({"machine": machine, "generation": generation, "end_to_end": end_to_end}, indent=1) + "\n"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
