"""``lidar3d convert``: raw packets (or any bag lidar3d reads) to a PointCloud2 bag.

Library twin: :func:`lidar3d.io.convert.convert_to_bag`.
"""

from __future__ import annotations

import argparse

from lidar3d.cli.packet_options import add_packet_arguments, apply_packet_arguments


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "convert",
        help="decode raw Velodyne packets (pcap, VelodyneScan bag) into a PointCloud2 bag",
        description=(
            "Decode every sweep of INPUT as 'lidar3d run' does and write it as sensor_msgs/PointCloud2 in the "
            "velodyne_pointcloud layout (x y z intensity ring time; time in seconds from the header stamp, "
            "which for raw packets is the sweep start). INPUT: pcap file(s), a bag with a "
            "velodyne_msgs/VelodyneScan topic, or any PointCloud2 bag (rewritten in that layout, stamps kept)."
        ),
        epilog=(
            "examples:\n"
            "  lidar3d convert drive.pcap --out drive.bag\n"
            "  lidar3d convert packets_bag/ --out clouds --storage ros2-mcap --return last\n"
            "  lidar3d convert capture.pcap --out capture.bag --sensor vlp16 --clock sensor --ports 2368,2369"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("inputs", nargs="+", metavar="INPUT", help="pcap file(s) or bag")
    parser.add_argument("--out", required=True, metavar="BAG", help="output bag (.bag: ROS1; else a ROS2 folder)")
    parser.add_argument(
        "--storage", choices=("ros1", "ros2-sqlite3", "ros2-mcap"), help="output storage (default: from --out)"
    )
    parser.add_argument("--topic", metavar="T", help="input topic (default: the only lidar topic)")
    parser.add_argument("--out-topic", default="/velodyne_points", metavar="T", help="output topic")
    parser.add_argument("--frame-id", default="velodyne", metavar="F", help="header frame of the clouds")
    parser.add_argument(
        "--min-range", type=float, default=0.0, metavar="M", help="drop returns nearer than M metres (default 0)"
    )
    parser.add_argument("--config", metavar="FILE", help="TOML configuration (default: built-in values)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output bag")
    add_packet_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lidar3d.config import config_with, load_config
    from lidar3d.io.convert import convert_to_bag

    config = apply_packet_arguments(load_config(args.config), args)
    overrides = {"sensor": {"min_range_m": args.min_range}}
    if args.topic:
        overrides["input"] = {"topic": args.topic}
    config = config_with(config, overrides)
    summary = convert_to_bag(
        args.inputs,
        args.out,
        config,
        storage=args.storage,
        topic=args.out_topic,
        frame_id=args.frame_id,
        overwrite=args.overwrite,
    )
    print(
        f"wrote {summary.n_scans} scans ({summary.n_points} points) to {summary.path} "
        f"({summary.storage}, {summary.topic})"
    )
    return 0
