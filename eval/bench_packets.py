"""Decoding speed of raw Velodyne packets: scans per second through lidar3d's packet scan source.

For each real capture in ``../shared/data/real`` (see its SOURCES.md) the source is opened once and
its sweeps are read ``--passes`` times (pcap or bag reading, sweep assembly, velodyne-decoder,
return selection, minimum range and the sanity stage: everything ``lidar3d run`` does before the
front end), timed by the wall clock and by the process's CPU time (which a shared, loaded machine
disturbs less). Also timed: velodyne-decoder's own ``read_pcap`` on the pcap files, the floor of
any wrapper around it. Prints a markdown table (docs/benchmarks.md#raw-packet-decoding). Usage::

    .venv/bin/python eval/bench_packets.py --passes 30
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from lidar3d.config import Config  # noqa: E402
from lidar3d.io.packet_source import PacketScanSource  # noqa: E402

REAL = REPO.parent / "shared" / "data" / "real"
CAPTURES = (
    ("VLP-16, strongest", REAL / "mrpt" / "sample_velodyne_vlp16_gps.pcap"),
    ("VLP-16, dual (both returns decoded, strongest kept)", REAL / "nebula" / "vlp16" / "1673400471837873222"),
    ("VLP-32C, strongest (half-turn messages)", REAL / "nebula" / "vlp32" / "1713492677464078412"),
    ("HDL-32E, strongest", REAL / "rust-lidar-utils" / "hdl32_example.pcap"),
)


def _time_source(path: Path, passes: int) -> tuple[int, float, float, int]:
    """Scans per pass, wall and CPU seconds per scan (best pass) and points per scan."""
    with PacketScanSource(path, Config(), quiet=True) as source:
        best_wall = best_cpu = float("inf")
        n_scans = n_points = 0
        for _ in range(passes):
            t0, c0 = time.perf_counter(), time.process_time()
            scans = [scan for _index, scan in source.scans()]
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            n_scans, n_points = len(scans), sum(len(s) for s in scans)
            best_wall = min(best_wall, wall / max(n_scans, 1))
            best_cpu = min(best_cpu, cpu / max(n_scans, 1))
    return n_scans, best_wall, best_cpu, n_points // max(n_scans, 1)


def _time_velodyne_decoder(path: Path, passes: int) -> float:
    """CPU seconds per scan of velodyne-decoder's own pcap reader (best pass)."""
    import velodyne_decoder as vd

    best = float("inf")
    for _ in range(passes):
        c0 = time.process_time()
        n = sum(1 for _stamp, _points in vd.read_pcap(str(path), vd.Config(), as_pcl_structs=True))
        best = min(best, (time.process_time() - c0) / n)
    return best


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--passes", type=int, default=30, help="passes over each capture (best one counts)")
    args = parser.parse_args(argv)
    print(f"load average before: {os.getloadavg()[0]:.1f} ({os.cpu_count()} cores)")
    print("| capture | scans | points/scan | scans/s (wall) | scans per CPU s | read_pcap scans per CPU s |")
    print("|---|---:|---:|---:|---:|---:|")
    for name, path in CAPTURES:
        if not path.exists():
            print(f"| {name} | absent: {path} | | | |")
            continue
        n_scans, wall_s, cpu_s, points = _time_source(path, args.passes)
        floor = f"{1.0 / _time_velodyne_decoder(path, args.passes):.0f}" if path.suffix == ".pcap" else "-"
        print(f"| {name} | {n_scans} | {points} | {1.0 / wall_s:.0f} | {1.0 / cpu_s:.0f} | {floor} |", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
