"""``lidar3d run``: SLAM over a recording."""

from __future__ import annotations

import argparse

from lidar3d.cli.packet_options import add_packet_arguments, apply_packet_arguments


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "run",
        help="run SLAM on VLP-16 bag(s): trajectory of every scan and a dense map",
        description=(
            "Run LeGO-LOAM-style SLAM over one recording (several ROS1 split files read as one "
            "stream). Writes trajectories (TUM, KITTI), map.pcd (the static map: moving objects, found by "
            "free-space ray casting, go to dynamic.pcd), summary.json and config.toml; a folder holding an "
            "earlier run's outputs is refused unless --overwrite is given."
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
    parser.add_argument("--out", required=True, metavar="DIR", help="output folder")
    parser.add_argument("--topic", metavar="T", help="PointCloud2 topic (default: the only one)")
    parser.add_argument("--config", metavar="FILE", help="TOML configuration (see 'lidar3d config')")
    parser.add_argument("--start", type=int, default=0, metavar="N", help="skip the first N scans")
    parser.add_argument("--max-scans", type=int, metavar="N", help="process at most N scans")
    parser.add_argument("--map-voxel", type=float, metavar="M", help="voxel size of map.pcd in metres")
    parser.add_argument("--no-loop", action="store_true", help="turn loop closure off")
    parser.add_argument(
        "--loop-source",
        choices=("distance", "place", "both"),
        help="loop candidates from the distance gate, place recognition (Scan Context) or both "
        "(default: the config's loop.source, both)",
    )
    parser.add_argument(
        "--keep-dynamic",
        action="store_true",
        help="keep moving objects in map.pcd (no dynamic.pcd; config dynamic.enabled = false)",
    )
    parser.add_argument("--span", metavar="LOG", help="NovAtel SPAN log: evaluate the trajectory against it")
    parser.add_argument("--extrinsics", metavar="FILE", help="lidar-to-IMU extrinsic for --span (TOML/YAML)")
    parser.add_argument(
        "--gnss-factors",
        action="store_true",
        help="fuse the --span log's good epochs as position factors in the pose graph (jumps rejected)",
    )
    parser.add_argument(
        "--gnss-hold-out",
        type=float,
        metavar="S",
        help="with --gnss-factors: fuse only even S-second periods, score the odd ones (georef.hold_out_period_s)",
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="replace the outputs of an earlier run in DIR (else refused)"
    )
    add_packet_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import dataclasses

    from lidar3d.cli.progress import ScanProgress
    from lidar3d.config import config_with, load_config
    from lidar3d.errors import ConfigError
    from lidar3d.run import run_bag

    config = apply_packet_arguments(load_config(args.config), args)
    if args.topic:
        config = dataclasses.replace(config, input=dataclasses.replace(config.input, topic=args.topic))
    if args.no_loop:
        config = dataclasses.replace(config, loop=dataclasses.replace(config.loop, enabled=False))
    if args.loop_source:
        config = dataclasses.replace(config, loop=dataclasses.replace(config.loop, source=args.loop_source))
    if args.keep_dynamic:
        config = dataclasses.replace(config, dynamic=dataclasses.replace(config.dynamic, enabled=False))
    if args.map_voxel is not None:
        try:
            config = config_with(config, {"mapping": {"map_voxel_m": args.map_voxel}})
        except ConfigError as err:
            raise ConfigError(f"--map-voxel: {err}") from None
    if args.start < 0:
        raise ConfigError(f"--start must be 0 or more, got {args.start}")
    if args.max_scans is not None and args.max_scans <= 0:
        raise ConfigError(f"--max-scans must be 1 or more, got {args.max_scans}")
    if args.extrinsics and not args.span:
        raise ConfigError("--extrinsics needs --span")
    if args.gnss_factors and not args.span:
        raise ConfigError("--gnss-factors needs --span (the log to fuse)")
    if args.gnss_hold_out is not None:
        if not args.gnss_factors:
            raise ConfigError("--gnss-hold-out needs --gnss-factors")
        try:
            config = config_with(config, {"georef": {"hold_out_period_s": args.gnss_hold_out}})
        except ConfigError as err:
            raise ConfigError(f"--gnss-hold-out: {err}") from None
    progress = ScanProgress("run", quiet=args.quiet)
    try:
        outcome = run_bag(
            args.bags,
            args.out,
            config,
            start=args.start,
            max_scans=args.max_scans,
            span_log=args.span,
            extrinsics=args.extrinsics,
            on_scan=progress.update,
            on_health=progress.note_health,
            overwrite=args.overwrite,
            gnss_factors=args.gnss_factors,
        )
    finally:
        progress.close()
    s = outcome.summary
    print(
        f"{s.scans} scans, {s.length_m:.1f} m, {s.runtime_s:.1f} s ({s.scans_per_s:.1f} scans/s), "
        f"{s.keyframes} keyframes, {s.loop_closures} loop closures, {s.map_points} map points"
        + (f", {s.dynamic_points} dynamic points removed" if s.dynamic_points is not None else "")
    )
    if s.health is not None:
        h = s.health
        print(f"health: {100 * h.ok_fraction:.0f} % of the scans ok, {h.degraded_scans} degraded, {h.lost_scans} lost")
    for warning in s.warnings:
        print(f"warning: {warning}")
    if s.evaluation is not None:
        print(s.evaluation.table)
    print(f"outputs in {outcome.out_dir}/")
    return 0
