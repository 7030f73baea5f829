"""``lidar3d grid``: a ROS map_server occupancy grid (YAML + PGM) and a PNG preview of a finished run.

Library twin: :func:`lidar3d.grid.grid_run`.
"""

from __future__ import annotations

import argparse

_EPILOG = """\
examples:
  lidar3d grid results/drive --out results/drive/grid
  lidar3d grid results/drive --out grid_5cm --resolution 0.05 --band 0.2 1.5

Reads the run's poses, config.toml, map.pcd (the local ground) and dynamic.pcd (moving objects,
left out), and the run's input bag(s) again. Writes map.yaml + map.pgm (map_server: mode trinary,
occupied 0 / free 254 / unknown 205, negate 0, occupied_thresh 0.65, free_thresh 0.196, origin =
lower-left pixel) and map.png into DIR. A partial run is gridded as far as it goes (with a warning).
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "grid",
        help="2-D occupancy grid of a run for navigation (ROS map_server YAML + PGM, PNG preview)",
        description=(
            "Ray cast every scan of a finished run into a 2-D log-odds occupancy grid, counting what lies in "
            "a height band above the local ground (so the band follows hills); moving objects are left out."
        ),
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("run_dir", metavar="RUN_DIR", help="output folder of 'lidar3d run'")
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder for map.yaml, map.pgm, map.png")
    parser.add_argument("--resolution", type=float, default=0.1, metavar="M", help="cell size in metres (default: 0.1)")
    parser.add_argument(
        "--band",
        type=float,
        nargs=2,
        default=(0.3, 2.0),
        metavar=("LOW", "HIGH"),
        help="heights above the local ground that hold obstacles, metres (default: 0.3 2.0)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lidar3d.cli.progress import ScanProgress
    from lidar3d.grid import check_grid_options, grid_run

    check_grid_options(args.resolution, tuple(args.band))  # bad options fail before any reading
    progress = ScanProgress("grid", quiet=args.quiet)
    try:
        outcome = grid_run(
            args.run_dir, args.out, resolution_m=args.resolution, band_m=tuple(args.band), on_scan=progress.update
        )
    finally:
        progress.close()
    grid = outcome.grid
    nx, ny = grid.log_odds.shape
    occupied = int((grid.probability > 0.65).sum())
    free = int((grid.observed & (grid.probability < 0.196)).sum())
    print(
        f"{outcome.scans} scans gridded in {outcome.runtime_s:.1f} s: {nx} x {ny} cells of {grid.resolution_m:g} m, "
        f"{occupied} occupied, {free} free; {outcome.dynamic_points_left_out} moving-object points left out"
    )
    if outcome.partial:
        print("warning: the run is partial (it stopped before the end of its input); the grid covers its scans")
    for path in (outcome.yaml, outcome.pgm, outcome.png):
        print(f"  {path}")
    return 0
