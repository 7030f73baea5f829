"""Peak memory of `lidar3d run` on a 1,000-scan and a 3,000-scan VLP-16 bag.

The bags are made from the simulator's `loop` scenario driven several times round: one lap is
the scans from the start to the scan whose pose comes back nearest to the first one (a few
centimetres away), and laps are repeated with their stamps carried on. Each run is a separate
`lidar3d run` process; the peak is the largest sum of the resident set sizes of that process and
its children (the prefetch and dense-map processes), sampled every 0.2 s; the peaks of the main
process and of its children alone are given beside it. Beside the summed RSS the tree's PSS
(proportional set size, ``/proc/PID/smaps_rollup``) is sampled too: a page two processes share (the
libraries, NumPy's and numba's code) counts once in it, and in each process's RSS. ``--bag``
measures given bags instead (e.g. the evaluation cache's drives, ``--max-scans`` to cut them). Usage:

    .venv/bin/python eval/bench_memory.py [--scans 1000 3000] [--keep DIR]
    .venv/bin/python eval/bench_memory.py --bag eval/cache/figure_eight_s0_full/scans.bag --max-scans 1400
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


def _tree_memory_kib(pid: int) -> tuple[int, int, int]:
    """Resident set size of ``pid`` and all its descendants, of ``pid`` alone, and the tree's
    proportional set size (shared pages divided among the processes that map them), in KiB."""
    total = own = proportional = 0
    pending = [pid]
    while pending:
        p = pending.pop()
        try:
            rollup = Path(f"/proc/{p}/smaps_rollup").read_text()
            children = Path(f"/proc/{p}/task/{p}/children").read_text().split()
        except OSError:
            continue
        fields = dict(line.split(":", 1) for line in rollup.splitlines()[1:])
        rss, pss = int(fields["Rss"].split()[0]), int(fields["Pss"].split()[0])
        total += rss
        proportional += pss
        own = rss if p == pid else own
        pending.extend(int(c) for c in children)
    return total, own, proportional


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


def measure(bag: Path, out: Path, extra: list[str] | None = None) -> dict:
    """Run ``lidar3d run`` on ``bag`` (with ``extra`` arguments) and sample its memory."""
    command = [sys.executable, "-m", "lidar3d.cli.main", "-q", "run", str(bag), "--out", str(out), "--overwrite"]
    command += extra or []
    t0 = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    peak = peak_main = peak_children = peak_pss = 0
    while process.poll() is None:
        total, own, proportional = _tree_memory_kib(process.pid)
        peak, peak_main, peak_children = max(peak, total), max(peak_main, own), max(peak_children, total - own)
        peak_pss = max(peak_pss, proportional)
        time.sleep(0.2)
    wall = time.perf_counter() - t0
    if process.returncode != 0:
        raise SystemExit(f"lidar3d run failed: {process.communicate()[1]}")
    summary = read_summary(out / "summary.json")
    return {
        "scans": summary.scans,
        "peak_rss_mib": round(peak / 1024, 1),
        "peak_pss_mib": round(peak_pss / 1024, 1),
        "main_mib": round(peak_main / 1024, 1),
        "children_mib": round(peak_children / 1024, 1),
        "wall_s": round(wall, 1),
        "keyframes": summary.keyframes,
        "loop_closures": summary.loop_closures,
        "map_rebuild_s": summary.map_rebuild_s,
        "map_points": summary.map_points,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, nargs="+", default=[1000, 3000])
    parser.add_argument("--bag", type=Path, nargs="+", help="measure these bags instead of the repeated loop")
    parser.add_argument("--max-scans", type=int, help="with --bag: stop after this many scans")
    parser.add_argument("--keep", type=Path, help="keep bags and outputs here (default: a temporary folder)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        rows = []
        if args.bag:
            extra = ["--max-scans", str(args.max_scans)] if args.max_scans else []
            for i, bag in enumerate(args.bag):
                rows.append({"bag": str(bag), **measure(bag, root / f"run_bag{i}", extra)})
                print(f"{bag}: {rows[-1]}", file=sys.stderr)
        for n in [] if args.bag else args.scans:
            bag = root / f"loop_x{n}.bag"
            make_bag(bag, n)
            rows.append({"bag": f"loop x{n}", **measure(bag, root / f"run_{n}")})
            bag.unlink()
            print(f"{n} scans: {rows[-1]}", file=sys.stderr)
    print(
        "| bag | scans | peak RSS, process tree (MiB) | peak PSS, process tree (MiB) | main (MiB) "
        "| children (MiB) | keyframes | loop closures | map placed again (s) | map points | wall (s) |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['bag']} | {r['scans']} | {r['peak_rss_mib']} | {r['peak_pss_mib']} | {r['main_mib']} "
            f"| {r['children_mib']} "
            f"| {r['keyframes']} | {r['loop_closures']} | {r['map_rebuild_s']} | {r['map_points']} | {r['wall_s']} |"
        )
    if len(rows) >= 2:
        print(
            f"\nratio {rows[-1]['scans']} / {rows[0]['scans']} scans: "
            f"{rows[-1]['peak_rss_mib'] / rows[0]['peak_rss_mib']:.2f}"
        )


if __name__ == "__main__":
    main()
