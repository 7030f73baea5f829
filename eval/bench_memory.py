"""Peak memory of `lidar3d run` on a 1,000-scan and a 3,000-scan VLP-16 bag.

The bags are made from the simulator's `loop` scenario driven several times round: one lap is
the scans from the start to the scan whose pose comes back nearest to the first one (a few
centimetres away), and laps are repeated with their stamps carried on. Each run is a separate
`lidar3d run` process; the peak is the largest sum of the resident set sizes of that process and
its children (the prefetch process), sampled every 0.2 s. Usage:

    .venv/bin/python eval/bench_memory.py [--scans 1000 3000] [--keep DIR]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lidar3d.io.bag_writer import write_scan_bag
from lidar3d.records import Scan
from lidar3d.sim import Simulation
from lidar3d.summary import read_summary


def _tree_rss_kib(pid: int) -> int:
    """Resident set size of ``pid`` and all its descendants, in KiB."""
    total = 0
    pending = [pid]
    while pending:
        p = pending.pop()
        try:
            status = Path(f"/proc/{p}/status").read_text()
            children = Path(f"/proc/{p}/task/{p}/children").read_text().split()
        except OSError:
            continue
        for line in status.splitlines():
            if line.startswith("VmRSS:"):
                total += int(line.split()[1])
        pending.extend(int(c) for c in children)
    return total


def make_bag(path: Path, n_scans: int) -> None:
    sim = Simulation("loop", seed=0)
    period = sim.scan_period_ns
    positions = sim.ground_truth.positions_m
    half = len(sim) // 2
    lap = half + int(np.argmin(np.linalg.norm(positions[half:] - positions[0], axis=1)))

    def scans():
        for i in range(n_scans):
            s = sim.scan(i % lap).scan
            yield Scan(sim.stamps_ns[0] + i * period, s.points, s.intensity, s.ring, s.time_offset_s)

    write_scan_bag(path, scans(), storage="ros1")


def measure(bag: Path, out: Path) -> dict:
    command = [sys.executable, "-m", "lidar3d.cli.main", "-q", "run", str(bag), "--out", str(out), "--overwrite"]
    t0 = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    peak = 0
    while process.poll() is None:
        peak = max(peak, _tree_rss_kib(process.pid))
        time.sleep(0.2)
    wall = time.perf_counter() - t0
    if process.returncode != 0:
        raise SystemExit(f"lidar3d run failed: {process.stderr.read()}")
    summary = read_summary(out / "summary.json")
    return {
        "scans": summary.scans,
        "peak_rss_mib": round(peak / 1024, 1),
        "wall_s": round(wall, 1),
        "keyframes": summary.keyframes,
        "map_points": summary.map_points,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, nargs="+", default=[1000, 3000])
    parser.add_argument("--keep", type=Path, help="keep bags and outputs here (default: a temporary folder)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        rows = []
        for n in args.scans:
            bag = root / f"loop_x{n}.bag"
            make_bag(bag, n)
            rows.append(measure(bag, root / f"run_{n}"))
            bag.unlink()
            print(f"{n} scans: {rows[-1]}", file=sys.stderr)
    print("| scans | peak RSS (MiB) | keyframes | map points | wall (s) |")
    print("|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['scans']} | {r['peak_rss_mib']} | {r['keyframes']} | {r['map_points']} | {r['wall_s']} |")
    if len(rows) >= 2:
        print(
            f"\nratio {rows[-1]['scans']} / {rows[0]['scans']} scans: "
            f"{rows[-1]['peak_rss_mib'] / rows[0]['peak_rss_mib']:.2f}"
        )


if __name__ == "__main__":
    main()
