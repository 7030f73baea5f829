"""Accuracy of ``lidar3d run`` on per-point time layouts, and the cost of a long stop (issue 15, bad input).

``layouts``: simulates a drive twice (header stamps at the sweep start and at the sweep end),
rewrites each bag in every time layout of docs/stages/input.md (no time field, no ring either,
all-zero times, absolute float64 seconds / float64 and uint64 nanoseconds, float32 seconds,
seconds since boot) and prints the ATE RMSE of ``lidar3d run --no-loop`` on each against the
simulator's ground truth (or the one-line error).

``stamps``: simulates one drive (stamps at the sweep start, times 0..T), rewrites the same points
with each header stamp moved to the sweep end (stamp + T, times -T..0, as the stock ROS velodyne
driver stamps) and prints the ATE RMSE and maximum of ``lidar3d run --no-loop`` on both, each
against the ground truth at its own stamps (interpolated).

``stop``: simulates the ``stops`` scenario with its first stop held for ``--hold`` seconds, runs
``lidar3d.run.run_bag`` on it and prints the drift while standing, the keyframes added, the scans
the health flags (while standing and in all), the wall seconds per stationary and per moving scan
and the peak memory.

Everything is written into a temporary folder (deleted afterwards, never committed). Usage::

    .venv/bin/python eval/bench_bad_input.py layouts --scenario loop --duration 25
    .venv/bin/python eval/bench_bad_input.py stamps --scenario loop --duration 20
    .venv/bin/python eval/bench_bad_input.py stop --hold 180
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from lidar3d.cli.main import main as cli_main  # noqa: E402
from lidar3d.io.bag_writer import write_cloud_bag, write_scan_bag  # noqa: E402
from lidar3d.io.health_csv import read_health_csv  # noqa: E402
from lidar3d.io.pointcloud2 import PointCloud2Parts, encode_fields  # noqa: E402
from lidar3d.io.scan_source import ScanSource  # noqa: E402
from lidar3d.io.trajectory_io import read_tum  # noqa: E402
from lidar3d.mapping.health import HealthFlag  # noqa: E402
from lidar3d.metrics.evaluation import evaluate_trajectory  # noqa: E402
from lidar3d.records import Scan  # noqa: E402


def cloud(scan: Scan, time_field: tuple[str, str, np.ndarray] | None, *, ring: bool = True) -> PointCloud2Parts:
    """``scan`` as x, y, z, intensity float32, ring uint16 (optional) and one time field (optional)."""
    fields = [("x", "f4", scan.points[:, 0]), ("y", "f4", scan.points[:, 1]), ("z", "f4", scan.points[:, 2])]
    fields.append(("intensity", "f4", scan.intensity))
    if ring:
        fields.append(("ring", "u2", scan.ring))
    if time_field is not None:
        fields.append(time_field)
    return encode_fields(scan.stamp_ns, fields)


def _ns(scan: Scan) -> np.ndarray:
    return scan.stamp_ns + np.round(scan.time_offset_s * 1e9).astype(np.int64)


LAYOUTS: dict[str, Callable[[Scan], PointCloud2Parts] | None] = {
    "time relative (as simulated)": None,
    "no time field": lambda s: cloud(s, None),
    "no time, no ring": lambda s: cloud(s, None, ring=False),
    "all-zero time": lambda s: cloud(s, ("time", "f4", np.zeros(len(s)))),
    "f64 epoch s": lambda s: cloud(s, ("timestamp", "f8", s.stamp_ns * 1e-9 + s.time_offset_s)),
    "f64 epoch ns": lambda s: cloud(s, ("timestamp", "f8", _ns(s).astype(np.float64))),
    "u64 epoch ns": lambda s: cloud(s, ("timestamp", "u8", _ns(s))),
    "f32 epoch s": lambda s: cloud(s, ("timestamp", "f4", s.stamp_ns * 1e-9 + s.time_offset_s)),
    "seconds since boot": lambda s: cloud(s, ("time", "f4", 1234.5 + s.time_offset_s)),
}


def _run_ate(bag: Path, ground_truth: Path, out: Path, *options: str) -> str:
    if cli_main(["-q", "run", str(bag), "--out", str(out), "--no-loop", *options]) != 0:
        return "error (one line, exit 1)"
    evaluation = evaluate_trajectory(read_tum(out / "trajectory_tum.txt"), read_tum(ground_truth))
    return f"{evaluation.ate.translation_3d_m.rmse:.4f} m"


def layouts(args: argparse.Namespace, work: Path) -> None:
    from lidar3d import sim

    config = work / "sweep_end.toml"
    config.write_text('[input]\nazimuth_stamp = "sweep_end"\n')
    print("| stamp | layout | ATE RMSE |\n|---|---|---:|")
    for stamp in (sim.StampMode.SWEEP_START, sim.StampMode.SWEEP_END):
        scenario = sim.get_scenario(args.scenario)
        params = dataclasses.replace(scenario.lidar, stamp=stamp)
        simulation = sim.Simulation(scenario, seed=args.seed, duration_s=args.duration, lidar=params)
        outputs = sim.write_simulation(simulation, work / stamp.value)
        with ScanSource(outputs.bag) as source:
            scans = list(source)
        runs: list[tuple[str, Callable[[Scan], PointCloud2Parts] | None, tuple[str, ...]]]
        runs = [(name, make, ()) for name, make in LAYOUTS.items()]
        if stamp is sim.StampMode.SWEEP_END:
            runs.append(
                ("no time field, azimuth_stamp = sweep_end", LAYOUTS["no time field"], ("--config", str(config)))
            )
        for index, (name, make, options) in enumerate(runs):
            bag = outputs.bag
            if make is not None:
                bag = work / f"{stamp.value}_{index}.bag"
                write_cloud_bag(bag, [make(scan) for scan in scans])
            ate = _run_ate(bag, outputs.ground_truth, work / f"run_{stamp.value}_{index}", *options)
            print(f"| {stamp.value} | {name} | {ate} |", flush=True)


def stamps(args: argparse.Namespace, work: Path) -> None:
    from lidar3d import sim

    simulation = sim.Simulation(args.scenario, seed=args.seed, duration_s=args.duration)
    outputs = sim.write_simulation(simulation, work / "drive")
    with ScanSource(outputs.bag) as source:
        scans = list(source)
    period_s = float(np.median(np.diff([s.stamp_ns for s in scans]))) * 1e-9
    end_bag = work / "sweep_end.bag"
    shift_ns = round(period_s * 1e9)
    write_scan_bag(
        end_bag,
        (Scan(s.stamp_ns + shift_ns, s.points, s.intensity, s.ring, s.time_offset_s - shift_ns * 1e-9) for s in scans),
    )
    print("| stamps | ATE RMSE | ATE max |\n|---|---:|---:|")
    for name, bag in (("sweep start, times 0..T", outputs.bag), ("sweep end, times -T..0", end_bag)):
        out = work / f"run_{bag.stem}"
        if cli_main(["-q", "run", str(bag), "--out", str(out), "--no-loop"]) != 0:
            print(f"| {name} | error | |")
            continue
        ate = evaluate_trajectory(read_tum(out / "trajectory_tum.txt"), read_tum(outputs.ground_truth)).ate
        print(
            f"| {name} | {ate.translation_3d_m.rmse * 1e3:.1f} mm | {ate.translation_3d_m.max * 1e3:.1f} mm |",
            flush=True,
        )


def stop(args: argparse.Namespace, work: Path) -> None:
    from lidar3d import sim
    from lidar3d.run import run_bag

    base = sim.get_scenario("stops")
    route = dataclasses.replace(base.route, stops=((43.0, args.hold),))
    scenario = dataclasses.replace(base, name=f"stop_{args.hold:g}s", route=route)
    whole = sim.Simulation(scenario, seed=args.seed)
    start_ns, end_ns = whole.stop_spans_ns()[0]
    duration_s = (end_ns - whole.start_time_ns) * 1e-9 + args.after
    outputs = sim.write_simulation(sim.Simulation(scenario, seed=args.seed, duration_s=duration_s), work / "sim")
    ticks: list[float] = []
    t0 = time.perf_counter()
    run_bag(outputs.bag, work / "run", on_scan=lambda done, total: ticks.append(time.perf_counter()))
    wall_s = time.perf_counter() - t0
    estimate = read_tum(work / "run" / "trajectory_tum.txt")
    standing = (estimate.stamps_ns >= start_ns) & (estimate.stamps_ns <= end_ns)
    position = estimate.T_world_lidar[standing, :3, 3]
    moved = np.linalg.norm(position - position[0], axis=1)
    rotation = estimate.T_world_lidar[standing, :3, :3]
    yaw = np.degrees(np.unwrap(np.arctan2(rotation[:, 1, 0], rotation[:, 0, 0])))
    keyframes = read_tum(work / "run" / "keyframes_tum.txt").stamps_ns
    _, health = read_health_csv(work / "run" / "health.csv")
    flagged = np.array([h.flag is not HealthFlag.OK for h in health])
    per_scan = np.diff(np.array(ticks))  # per_scan[i]: wall time of scan i + 1
    still = standing[1:]
    held_s = (end_ns - start_ns) * 1e-9
    figures = {
        "hold_s": held_s,
        "scans": int(len(estimate)),
        "stationary_scans": int(standing.sum()),
        "wall_s": round(wall_s, 1),
        "moved_end_m": round(float(moved[-1]), 4),
        "moved_max_m": round(float(moved.max()), 4),
        "drift_m_per_s": float(f"{moved[-1] / held_s:.2g}"),
        "yaw_change_deg": round(float(yaw[-1] - yaw[0]), 4),
        "keyframes_while_standing": int(np.count_nonzero((keyframes >= start_ns) & (keyframes <= end_ns))),
        "health_flagged_while_standing": int(np.count_nonzero(flagged & standing)),
        "health_flagged": int(np.count_nonzero(flagged)),
        "s_per_stationary_scan_median": round(float(np.median(per_scan[still])), 3),
        "s_per_moving_scan_median": round(float(np.median(per_scan[~still])), 3),
        "peak_rss_main_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024,
    }
    print(json.dumps(figures, indent=1))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    lay = sub.add_parser("layouts", help="ATE per time layout")
    lay.add_argument("--scenario", default="loop")
    lay.add_argument("--duration", type=float, default=25.0)
    lay.add_argument("--seed", type=int, default=0)
    stm = sub.add_parser("stamps", help="ATE with sweep-start and sweep-end stamps of the same points")
    stm.add_argument("--scenario", default="loop")
    stm.add_argument("--duration", type=float, default=20.0)
    stm.add_argument("--seed", type=int, default=0)
    stp = sub.add_parser("stop", help="drift and cost of a long stop")
    stp.add_argument("--hold", type=float, default=180.0, help="seconds standing still")
    stp.add_argument("--after", type=float, default=5.0, help="seconds of driving after the stop")
    stp.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bench_bad_input_") as tmp:
        {"layouts": layouts, "stamps": stamps, "stop": stop}[args.what](args, Path(tmp))
    return 0


if __name__ == "__main__":
    sys.exit(main())
