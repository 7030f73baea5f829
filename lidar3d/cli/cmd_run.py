"""``lidar3d run``: SLAM over a recording."""

from __future__ import annotations

import argparse
import textwrap

from lidar3d.cli.options import (
    add_config_argument,
    add_gnss_fusion_arguments,
    add_output_arguments,
    add_scan_selection,
    add_slam_arguments,
    add_topic_argument,
    apply_gnss_fusion_arguments,
    apply_slam_arguments,
    scan_selection,
)
from lidar3d.cli.packet_options import add_packet_arguments, apply_packet_arguments


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "run",
        help="run SLAM on VLP-16 bag(s): trajectory of every scan and a dense map",
        description=textwrap.fill(
            "Run LeGO-LOAM-style SLAM over one recording (several ROS1 split files read as one "
            "stream). Writes trajectories (TUM, KITTI), map.pcd (the static map: moving objects, found by "
            "free-space ray casting, go to dynamic.pcd), summary.json and config.toml; a folder holding an "
            "earlier run's outputs is refused unless --overwrite is given. Ends with the list of "
            "files written and the headline figures.",
            width=88,
        ),
        epilog=(
            "examples:\n"
            "  lidar3d run drive.bag --out results/drive\n"
            "  lidar3d run drive_0.bag drive_1.bag --out results/drive --span span.log --extrinsics extrinsics.toml\n"
            "  lidar3d run rosbag2_folder --out results/r2 --topic /velodyne_points --max-scans 500\n"
            "  lidar3d run drive.bag --out results/fused --span span.log --extrinsics ext.toml --gnss-factors\n"
            "  lidar3d run drive.bag --out results/everything --keep-dynamic\n"
            "\n"
            "With --span the run also writes georef.json (the SLAM frame placed in ENU on WGS84), which\n"
            "'lidar3d export' uses to write the map and trajectory in UTM, EPSG:NNNN, ENU or WGS84."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("bags", nargs="+", metavar="BAG", help="ROS1 .bag file(s), ROS2 bag folder, or pcap file(s)")
    add_output_arguments(
        parser, what="output folder", overwrite="replace the outputs of an earlier run in DIR (default: refused)"
    )
    add_topic_argument(parser)
    add_config_argument(parser)
    add_scan_selection(parser)
    add_slam_arguments(parser)
    parser.add_argument(
        "--span", metavar="LOG", help="NovAtel SPAN log: evaluate the trajectory against it (default: none)"
    )
    parser.add_argument(
        "--extrinsics", metavar="FILE", help="lidar-to-IMU extrinsic for --span, TOML/YAML (default: identity)"
    )
    add_gnss_fusion_arguments(parser)
    add_packet_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lidar3d.cli.progress import ScanProgress
    from lidar3d.cli.run_listing import format_run_listing
    from lidar3d.config import load_config
    from lidar3d.errors import ConfigError
    from lidar3d.run import run_bag

    config = apply_slam_arguments(apply_packet_arguments(load_config(args.config), args), args)
    scans = scan_selection(args)
    if args.extrinsics and not args.span:
        raise ConfigError("--extrinsics needs --span")
    config = apply_gnss_fusion_arguments(config, args, span_given=bool(args.span), span_flag="--span")
    progress = ScanProgress("run", quiet=args.quiet)
    try:
        outcome = run_bag(
            args.bags,
            args.out,
            config,
            start=scans.start,
            max_scans=scans.max_scans,
            span_log=args.span,
            extrinsics=args.extrinsics,
            on_scan=progress.update,
            on_health=progress.note_health,
            overwrite=args.overwrite,
            gnss_factors=args.gnss_factors,
        )
    finally:
        progress.close()
    print(format_run_listing(outcome.summary, outcome.out_dir))
    return 0
