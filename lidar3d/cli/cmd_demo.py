"""``lidar3d demo``: simulate -> run -> eval on the built-in demo scenario."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "demo",
        help="simulate the demo drive, run SLAM on it and evaluate against its SPAN log",
        description=(
            "The whole job on built-in demo data: simulate a VLP-16 drive (bag, ground truth, "
            "NovAtel SPAN-CPT log), run SLAM on the bag, evaluate the trajectory against the "
            "SPAN log, and print where the map, trajectory, plots and report are."
        ),
        epilog="example:\n  lidar3d demo --out demo_output --scenario loop --duration 30",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--out", default="demo_output", metavar="DIR", help="output folder (default: demo_output)")
    parser.add_argument("--scenario", default="loop", help="simulator scenario (default: loop)")
    parser.add_argument(
        "--duration", type=float, metavar="S", help="simulate only the first S seconds (default: the whole route)"
    )
    parser.add_argument("--seed", type=int, default=0, help="simulation seed (default: 0)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from lidar3d.cli.progress import ScanProgress
    from lidar3d.run import run_bag
    from lidar3d.sim import simulate

    out = Path(args.out)
    sim_dir = out / "simulation"
    print(f"simulating scenario '{args.scenario}' (seed {args.seed}) into {sim_dir}/ ...")
    outputs = simulate(args.scenario, sim_dir, seed=args.seed, duration_s=args.duration, overwrite=True)
    slam_dir = out / "slam"
    progress = ScanProgress("slam", quiet=args.quiet)
    try:
        outcome = run_bag(
            outputs.bag,
            slam_dir,
            span_log=outputs.span_log,
            extrinsics=outputs.extrinsics,
            on_scan=progress.update,
            on_health=progress.note_health,
            overwrite=True,  # as the simulation above: the demo folder is its own
        )
    finally:
        progress.close()
    s = outcome.summary
    print(f"{s.scans} scans, {s.length_m:.1f} m in {s.runtime_s:.1f} s ({s.scans_per_s:.1f} scans/s)")
    if s.evaluation is not None:
        print(s.evaluation.table)
    print("outputs:")
    print(f"  map:          {slam_dir / 'map.pcd'}")
    print(f"  trajectory:   {slam_dir / 'trajectory_tum.txt'} (and trajectory_kitti.txt)")
    print(f"  report:       {slam_dir / 'eval' / 'report.json'}")
    print(f"  plots:        {slam_dir / 'eval'}/*.png")
    print(f"  summary:      {slam_dir / 'summary.json'}")
    print(f"  ground truth: {outputs.ground_truth}")
    return 0
