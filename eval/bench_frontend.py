"""Benchmark of the front end: median ms per scan of each sub-stage on simulated scans.

Sub-stages (as :func:`lidar3d.features.run_front_end` times them): projection (range image),
ground, clustering (components, validity, segmented cloud), smoothness (curvature, occlusion and
beam-parallel rejection), selection (sharp / less sharp / flat picks, less-flat voxel filter), and
their total (wall clock), and the process CPU time per scan (which other processes on the machine
disturb much less than the wall clock). The front end runs as the SLAM runs it
(:func:`lidar3d.features.prepare_scan`: the ground label's surface check skipped; ``lidar3d
features`` runs it, 0.6 ms a scan more). The scans are generated first (not timed), then each is run
through the front end once after one warm-up scan. Single-threaded NumPy/SciPy work: report the
median and say what else was running.

Prints a Markdown table (and JSON with ``--json``). Usage::

    .venv/bin/python eval/bench_frontend.py                       # 300 VLP-16 scans of "loop"
    .venv/bin/python eval/bench_frontend.py --scans 100 --sensor hdl32e --scenario hilly
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from lidar3d.config import Config  # noqa: E402
from lidar3d.features import STAGES, run_front_end  # noqa: E402
from lidar3d.sim import Simulation  # noqa: E402


def bench(scenario: str, sensor: str, n_scans: int, seed: int) -> dict:
    sim = Simulation(scenario, seed=seed, sensor=sensor)
    if len(sim) < n_scans:
        raise SystemExit(f"scenario {scenario} has only {len(sim)} scans")
    scans = [s.scan for s in sim.scans(0, n_scans)]
    config = replace(Config(), sensor=replace(Config().sensor, model=sensor))
    run_front_end(scans[0], config, surface_check=False)  # warm-up: imports, first allocations
    per_stage: dict[str, list[float]] = {stage: [] for stage in STAGES}
    totals, cpu = [], []
    features = {"sharp": 0, "less_sharp": 0, "flat": 0, "less_flat": 0}
    for scan in scans:
        began = time.process_time()
        result = run_front_end(scan, config, surface_check=False)
        cpu.append((time.process_time() - began) * 1e3)
        for stage in STAGES:
            per_stage[stage].append(result.stage_ms[stage])
        totals.append(result.total_ms)
        for name in features:
            features[name] += len(getattr(result.features, name))
    return {
        "scenario": scenario,
        "sensor": sensor,
        "scans": n_scans,
        "points_per_scan": statistics.mean(len(s) for s in scans),
        "median_ms": {stage: statistics.median(v) for stage, v in per_stage.items()},
        "median_total_ms": statistics.median(totals),
        "p90_total_ms": sorted(totals)[int(0.9 * (len(totals) - 1))],
        "median_cpu_ms": statistics.median(cpu),
        "features_per_scan": {name: count / n_scans for name, count in features.items()},
    }


def markdown(results: list[dict]) -> str:
    head = "| scenario | sensor | points/scan | " + " | ".join(STAGES) + " | total | p90 total | CPU total |"
    rule = "|" + "---|" * (len(STAGES) + 6)
    rows = [head, rule]
    for r in results:
        cells = [r["scenario"], r["sensor"], f"{r['points_per_scan']:.0f}"]
        cells += [f"{r['median_ms'][stage]:.2f}" for stage in STAGES]
        cells += [f"**{r['median_total_ms']:.2f}**", f"{r['p90_total_ms']:.2f}", f"{r['median_cpu_ms']:.2f}"]
        rows.append("| " + " | ".join(cells) + " |")
    return "\n".join(rows)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", action="append", help="simulator scenario (repeatable; default loop)")
    parser.add_argument("--sensor", default="vlp16", help="vlp16, hdl32e or vlp32c")
    parser.add_argument("--scans", type=int, default=300, help="scans per scenario")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print JSON instead of Markdown")
    args = parser.parse_args(argv)
    results = [bench(s, args.sensor, args.scans, args.seed) for s in (args.scenario or ["loop"])]
    if args.json:
        print(json.dumps(results, indent=2))
    else:
        print(
            f"front end, median ms per scan ({platform.processor() or platform.machine()}, "
            f"{os.cpu_count()} CPUs, Python {platform.python_version()})\n"
        )
        print(markdown(results))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
