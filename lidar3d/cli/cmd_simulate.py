"""``lidar3d simulate``: a VLP-16 drive through a procedural world, with ground truth and a SPAN log.

Library twin: :func:`lidar3d.sim.simulate`.
"""

from __future__ import annotations

import argparse

from lidar3d.cli.options import add_output_arguments

# Kept here (not imported from lidar3d.sim) so that ``lidar3d --help`` stays instant; a test checks
# that this table matches lidar3d.sim.SCENARIOS.
SCENARIO_HELP = {
    "loop": "~420 m loop around a city block, back past the start (default)",
    "long": "~1.4 km, three revisits and a 240 m feature-poor stretch of open land",
    "hilly": "~500 m loop over hills with slopes up to 8 degrees",
    "fast": "~700 m at up to 10 m/s with sharp 90-degree corners",
    "stops": "~400 m town drive at 2-9 m/s with three stops of 3-6 s, vibration and calibration error",
    "blind_turn": "~520 m: 240 m of open land at 4.5-8 m/s ending in a 90-degree turn on open land",
    "figure_eight": "~800 m figure eight: a 200 m open field ending in a sharp turn, then 4.6-5.0 m/s",
    "city_traffic": "~515 m city loop with traffic, pedestrians, glass facades and a 160 m walled canyon",
    "forest_trail": "~500 m rough forest trail: scattered-leaf crowns, 0.3 deg vibration, speed changes",
}


def register(subparsers: argparse._SubParsersAction) -> None:
    scenarios = "\n".join(f"  {name:<12} {text}" for name, text in SCENARIO_HELP.items())
    parser = subparsers.add_parser(
        "simulate",
        help="simulate a lidar drive: bag, ground truth, NovAtel SPAN log, extrinsics",
        description=(
            "Simulate a Velodyne drive through a procedural town and write a folder with the bag "
            "(/velodyne_points), the lidar ground truth (TUM), a NovAtel SPAN-CPT ASCII log "
            "(INSPVAXA 20 Hz, BESTPOSA 1 Hz), the lidar-to-IMU extrinsics and metadata.json."
        ),
        epilog=(
            f"scenarios:\n{scenarios}\n\n"
            "example:\n"
            "  lidar3d simulate loop --out sim/loop --seed 1 --duration 30\n"
            "  lidar3d simulate city_traffic --out sim/city --duration 20 --labels\n"
            "  lidar3d simulate hilly --out sim/hilly --format ros2 --sensor vlp32c"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "scenario",
        nargs="?",
        default="loop",
        choices=sorted(SCENARIO_HELP),
        metavar="SCENARIO",
        help="scenario name (default: loop)",
    )
    add_output_arguments(
        parser, what="output folder", overwrite="replace the outputs of an earlier simulation in DIR (default: refused)"
    )
    parser.add_argument("--seed", type=int, default=0, help="world, noise and GNSS error seed (default: 0)")
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="simulate only the first S seconds (default: the whole route)",
    )
    parser.add_argument(
        "--format",
        choices=("ros1", "ros2", "ros2-mcap"),
        default="ros1",
        help="bag format; ros2 uses sqlite3 storage (default: ros1)",
    )
    parser.add_argument(
        "--sensor", choices=("vlp16", "hdl32e", "vlp32c"), default="vlp16", help="sensor preset (default: vlp16)"
    )
    parser.add_argument(
        "--labels",
        action="store_true",
        help="also write point_labels.npz: the object id and class every point hit (moving cars, pedestrians...)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lidar3d.sim import simulate

    outputs = simulate(
        args.scenario,
        args.out,
        seed=args.seed,
        duration_s=args.duration,
        bag_format=args.format,
        sensor=args.sensor,
        overwrite=args.overwrite,
        labels=args.labels,
    )
    print(f"{outputs.n_scans} scans, {outputs.n_points} points -> {outputs.out_dir}")
    written = (
        outputs.bag,
        outputs.ground_truth,
        outputs.span_log,
        outputs.extrinsics,
        outputs.metadata,
        outputs.labels,
    )
    for path in (p for p in written if p is not None):
        print(f"  {path}")
    return 0
