"""Benchmark of scan input: decode throughput and peak memory of reading VLP-16 bags.

Generates VLP-16-sized bags (16 x 1800 = 28,800 points a scan in the velodyne_pointcloud layout,
921,600 bytes of point data a scan) in a temporary folder (deleted afterwards, never committed),
then

* reads the whole bag through :class:`lidar3d.io.scan_source.ScanSource` (bag reading,
  deserialisation and decoding into ``Scan`` records) several times and reports the median
  throughput in scans per second, for each storage format;
* reads 1,000- and 3,000-scan ROS1 bags in fresh subprocesses and reports their peak resident
  memory (``ru_maxrss``), to show that memory does not grow with the bag's length.

Prints Markdown tables. Usage::

    .venv/bin/python eval/bench_io.py                 # 1,000 scans, 3 runs, 1,000 vs 3,000 for RSS
    .venv/bin/python eval/bench_io.py --scans 200 --runs 2 --memory-scans 200 600   # quick
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from lidar3d.io.bag_writer import write_cloud_bag  # noqa: E402
from lidar3d.io.pointcloud2 import encode_scan  # noqa: E402
from lidar3d.io.scan_source import ScanSource  # noqa: E402
from lidar3d.records import Scan  # noqa: E402
from lidar3d.sensors import VLP16  # noqa: E402

STAMP0_NS = 1_700_000_000_000_000_000
PERIOD_NS = 100_000_000


def synthetic_scans(n_scans: int, seed: int = 0) -> Iterator[Scan]:
    """VLP-16 sweeps: every beam at every 0.2-degree column, ranges varying per scan."""
    rng = np.random.default_rng(seed)
    n_rings, n_columns = VLP16.n_rings, VLP16.n_columns
    column = np.repeat(np.arange(n_columns), n_rings)
    ring = np.tile(np.arange(n_rings), n_columns)
    azimuth = column * (2.0 * np.pi / n_columns)
    elevation = VLP16.elevation_rad[ring]
    direction = np.stack(
        [np.cos(elevation) * np.cos(azimuth), -np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], axis=1
    )
    base_range = rng.uniform(2.0, 80.0, column.size)
    time_offset_s = column / n_columns * VLP16.sweep_period_s
    for i in range(n_scans):
        range_m = np.roll(base_range, 16 * i)
        yield Scan(
            stamp_ns=STAMP0_NS + i * PERIOD_NS,
            points=direction * range_m[:, None],
            intensity=(range_m * 3.0) % 256.0,
            ring=ring,
            time_offset_s=time_offset_s,
        )


def make_bag(path: Path, n_scans: int, storage: str) -> float:
    """Write the bag; returns its size in bytes."""
    write_cloud_bag(path, (encode_scan(s) for s in synthetic_scans(n_scans)), storage=storage)
    if path.is_dir():
        return float(sum(f.stat().st_size for f in path.iterdir()))
    return float(path.stat().st_size)


def read_bag(path: Path) -> tuple[int, int, float]:
    """Read every scan; returns (scans, points, seconds)."""
    start = time.perf_counter()
    n_scans = n_points = 0
    with ScanSource(path, min_range_m=1.0) as source:
        for scan in source:
            n_scans += 1
            n_points += len(scan)
    return n_scans, n_points, time.perf_counter() - start


def _memory_kib() -> tuple[int, int]:
    """(current RSS, peak RSS) of this process in KiB.

    Linux ``/proc/self/status`` VmRSS/VmHWM: the high-water mark starts afresh at exec, whereas
    ``ru_maxrss`` of a child also counts the forked copy of its parent before the exec.
    """
    try:
        fields = dict(line.split(":", 1) for line in Path("/proc/self/status").read_text().splitlines() if ":" in line)
        return int(fields["VmRSS"].split()[0]), int(fields["VmHWM"].split()[0])
    except (OSError, KeyError, ValueError):
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        return peak, peak


def _child(path: str) -> None:
    """Subprocess body: report RSS after imports and the peak after reading the bag."""
    baseline_kib, _ = _memory_kib()
    n_scans, _n_points, seconds = read_bag(Path(path))
    _, peak_kib = _memory_kib()
    print(json.dumps({"scans": n_scans, "baseline_kib": baseline_kib, "peak_kib": peak_kib, "seconds": seconds}))


def measure_rss(path: Path) -> dict:
    out = subprocess.run(
        [sys.executable, __file__, "--child", str(path)], check=True, capture_output=True, text=True
    ).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scans", type=int, default=1000, help="scans in the throughput bag (default 1000)")
    parser.add_argument("--runs", type=int, default=3, help="reads of the throughput bag; the median is reported")
    parser.add_argument(
        "--storage",
        nargs="+",
        default=["ros1", "ros2-sqlite3", "ros2-mcap"],
        choices=["ros1", "ros2-sqlite3", "ros2-mcap"],
    )
    parser.add_argument(
        "--memory-scans",
        type=int,
        nargs="+",
        default=[1000, 3000],
        help="bag lengths for the peak-RSS comparison (ROS1)",
    )
    parser.add_argument("--tmp", type=Path, default=None, help="folder for the temporary bags")
    parser.add_argument("--child", metavar="BAG", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        _child(args.child)
        return 0

    workdir = Path(tempfile.mkdtemp(prefix="lidar3d-bench-io-", dir=args.tmp))
    try:
        print(
            f"machine: {platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
            f"load average {os.getloadavg()[0]:.2f}"
        )
        print()
        print(f"| storage | scans | bag size | read + decode, scans/s (median of {args.runs}) | MB/s | points/s |")
        print("|---|---:|---:|---:|---:|---:|")
        for storage in args.storage:
            path = workdir / ("bench.bag" if storage == "ros1" else f"bench_{storage}")
            size = make_bag(path, args.scans, storage)
            runs = [read_bag(path) for _ in range(args.runs)]
            seconds = statistics.median(r[2] for r in runs)
            n_scans, n_points = runs[0][0], runs[0][1]
            print(
                f"| {storage} | {n_scans} | {size / 1e6:.0f} MB | {n_scans / seconds:.0f} | "
                f"{size / 1e6 / seconds:.0f} | {n_points / seconds / 1e6:.1f} M |",
                flush=True,
            )
            shutil.rmtree(path) if path.is_dir() else path.unlink()

        print()
        print("| ROS1 bag | bag size | RSS after imports | peak RSS while reading | growth |")
        print("|---:|---:|---:|---:|---:|")
        for n in args.memory_scans:
            path = workdir / f"memory_{n}.bag"
            size = make_bag(path, n, "ros1")
            result = measure_rss(path)
            assert result["scans"] == n
            base, peak = result["baseline_kib"] / 1024, result["peak_kib"] / 1024
            print(
                f"| {n} scans | {size / 1e6:.0f} MB | {base:.1f} MiB | {peak:.1f} MiB | {peak - base:.1f} MiB |",
                flush=True,
            )
            path.unlink()
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
