"""``lidar3d info``: what a bag holds (library twin: :func:`lidar3d.io.bag_info.bag_info`)."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "info",
        help="show the topics, lidar topic, point fields and sensor model of bags",
        description=(
            "For each bag (a ROS1 .bag file or a ROS2 bag folder, sqlite3 or mcap): its topics with "
            "message types and counts, duration, the detected lidar (PointCloud2) topic, its point "
            "fields, the sensor model guessed from the rings, and the first/last header stamps."
        ),
        epilog=(
            "example:\n"
            "  lidar3d info recording.bag\n"
            "  lidar3d info run_0.bag run_1.bag --topic /velodyne_points\n"
            "  lidar3d info rosbag2_2024_05_01/"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("bags", nargs="+", metavar="BAG", help="ROS1 .bag file or ROS2 bag folder")
    parser.add_argument("--topic", metavar="T", help="PointCloud2 topic (default: the only one in the bag)")
    parser.add_argument("--config", metavar="FILE", help="TOML configuration (sensor model, minimum range)")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lidar3d.config import load_config
    from lidar3d.io.bag_info import bag_info, format_bag_info

    config = load_config(args.config)
    topic = args.topic or config.input.topic or None
    for index, bag in enumerate(args.bags):
        info = bag_info(bag, topic=topic, sensor=config.sensor.resolved_model, min_range_m=config.sensor.min_range_m)
        report = format_bag_info(info)
        print(("\n" if index else "") + report, flush=True)
    return 0
