"""``lidar3d view``: look at a run's map and trajectory.

Library twins: :func:`lidar3d.export.map_view.write_view_png` (no display needed) and
:func:`lidar3d.export.map_window.show_view_window` (an Open3D window).
"""

from __future__ import annotations

import argparse
import textwrap


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "view",
        help="look at a run's map and trajectory: Open3D window, or a PNG without a display",
        description=textwrap.fill(
            "Show map.pcd coloured by height with the trajectory on top. With a display (DISPLAY or "
            "WAYLAND_DISPLAY set, macOS, Windows) in an Open3D window (mouse: rotate, wheel: zoom, "
            "shift+drag: pan, h: help). With --png, or when there is no display, render a top view and "
            "an oblique view into a PNG instead.",
            width=88,
        ),
        epilog=(
            "examples:\n"
            "  lidar3d view results/drive\n"
            "  lidar3d view results/drive --png drive.png\n"
            "  ssh server lidar3d view results/drive     # no display: writes results/drive_view.png"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("run_dir", metavar="RUN_DIR", help="output folder of 'lidar3d run'")
    parser.add_argument(
        "--png",
        metavar="FILE",
        help="write the rendered views to FILE instead of opening a window "
        "(default without a display: RUN_DIR_view.png beside the folder)",
    )
    parser.add_argument(
        "--max-points",
        type=int,
        default=2_000_000,
        metavar="N",
        help="draw at most N map points (every k-th point of a larger map)",
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from lidar3d.errors import ConfigError
    from lidar3d.export.map_view import read_run_view, write_view_png
    from lidar3d.export.map_window import display_available, show_view_window

    if args.max_points < 1:
        raise ConfigError(f"--max-points must be 1 or more, got {args.max_points}")
    if args.png is None and display_available():
        show_view_window(read_run_view(args.run_dir, max_points=args.max_points))
        return 0
    folder = Path(args.run_dir)
    png = Path(args.png) if args.png else folder.parent / f"{folder.resolve().name}_view.png"
    write_view_png(folder, png, max_points=args.max_points)
    print(f"wrote {png}" + ("" if args.png else " (no display: rendered instead of a window)"))
    return 0
