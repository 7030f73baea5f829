"""``lidar3d info``: what a bag holds (library twin: :func:`lidar3d.io.bag_info.bag_info`)."""

from __future__ import annotations

import argparse
import dataclasses

from lidar3d.cli.options import add_config_argument, add_topic_argument
from lidar3d.cli.packet_options import add_packet_arguments, apply_packet_arguments


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "info",
        help="show the topics, lidar topic, point fields and sensor model of bags",
        description=(
            "For each bag (a ROS1 .bag file or a ROS2 bag folder, sqlite3 or mcap): its topics with "
            "message types and counts, duration, the detected lidar (PointCloud2) topic, its point "
            "fields, the sensor model guessed from the rings, and the first/last header stamps. For raw "
            "Velodyne packets (a pcap file, a velodyne_msgs/VelodyneScan bag): the model, return mode, "
            "rotation rate, scans, duration, clocks, position-packet (NMEA) status and, for pcap, the UDP ports."
        ),
        epilog=(
            "example:\n"
            "  lidar3d info recording.bag\n"
            "  lidar3d info run_0.bag run_1.bag --topic /velodyne_points\n"
            "  lidar3d info rosbag2_2024_05_01/\n"
            "  lidar3d info capture.pcap --sensor vlp16"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("bags", nargs="+", metavar="BAG", help="ROS1 .bag file, ROS2 bag folder, or pcap file")
    add_topic_argument(parser)
    add_config_argument(parser, " (sensor model, minimum range)")
    add_packet_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lidar3d.config import load_config
    from lidar3d.io.bag_info import bag_info, format_bag_info
    from lidar3d.io.packet_info import format_packet_info, packet_info
    from lidar3d.io.packet_source import is_packet_input

    config = apply_packet_arguments(load_config(args.config), args)
    topic = args.topic or config.input.topic or None
    if topic:
        config = dataclasses.replace(config, input=dataclasses.replace(config.input, topic=topic))
    for index, bag in enumerate(args.bags):
        if is_packet_input([bag], topic):
            report = format_packet_info(packet_info(bag, config))
        else:
            info = bag_info(
                bag, topic=topic, sensor=config.sensor.resolved_model, min_range_m=config.sensor.min_range_m
            )
            report = format_bag_info(info)
        print(("\n" if index else "") + report, flush=True)
    return 0
