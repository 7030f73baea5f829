"""``lidar3d batch``: SLAM over many bags, resumable, with one report."""

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
        "batch",
        help="run SLAM on many bags (local processes or Ray), resumable, with an HTML report",
        description=textwrap.fill(
            "Run SLAM on every bag found in INPUTS, each exactly as 'lidar3d run' would, into "
            "OUT/<name>/. A bag's folder appears only when complete; re-running the same command "
            "skips finished bags (same content, configuration, options and SPAN log), so a killed or "
            "interrupted batch resumes; --overwrite redoes them. Every per-bag option of 'lidar3d run' "
            "(--topic, --start, --max-scans, --map-voxel, --no-loop, --loop-source, --keep-dynamic, "
            "--gnss-factors, the raw-packet options) applies to every bag. Writes OUT/summary.csv, "
            "OUT/summary.json and OUT/report.html.",
            width=88,
        ),
        epilog=(
            "examples:\n"
            "  lidar3d batch /data/drives --out results/batch\n"
            "  lidar3d batch /data/drives --out results/quick --topic /velodyne_points --max-scans 300 --no-loop\n"
            "  lidar3d batch '/data/2024-05-*/*.bag' --out results/may --span-dir /data/span --extrinsics rig.toml\n"
            "  lidar3d batch /data/sims --out results/sims --span-pattern novatel_span.log "
            "--extrinsics '{parent}/extrinsics.toml'\n"
            "  RAY_AUTH_MODE=token lidar3d batch /shared/bags --out /shared/results --engine ray "
            "--ray-address HOST:6379\n"
            "\n"
            "patterns (--span-pattern, --extrinsics): {stem} bag name without .bag, {name} batch output\n"
            "name, {parent} the bag's folder, {folder} that folder's name; relative paths are taken\n"
            "relative to the bag's folder; glob characters allowed.\n"
            "exit status: 0 every bag finished, 1 some bag failed (see the report), 130 interrupted."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("inputs", nargs="+", metavar="INPUT", help="bag, ROS2 bag folder, folder to search, or glob")
    add_output_arguments(
        parser, what="batch output folder", overwrite="redo and replace bags already up to date (default: skipped)"
    )
    add_topic_argument(parser)
    add_config_argument(parser, " for every bag")
    add_scan_selection(parser)
    add_slam_arguments(parser)
    span = parser.add_mutually_exclusive_group()
    span.add_argument(
        "--span-dir",
        metavar="DIR",
        help="folder of SPAN logs, matched to bags by time overlap (default: no evaluation)",
    )
    span.add_argument(
        "--span-pattern", metavar="PATTERN", help="SPAN log path per bag, e.g. '{stem}.gps' (default: no evaluation)"
    )
    parser.add_argument(
        "--extrinsics", metavar="FILE", help="lidar-to-IMU extrinsic file, or per-bag pattern (default: identity)"
    )
    add_gnss_fusion_arguments(parser)
    cluster = parser.add_argument_group("where the bags run")
    cluster.add_argument("--workers", type=int, metavar="N", help="bags in parallel (default: all CPUs)")
    cluster.add_argument("--engine", choices=("local", "ray"), default="local", help="local process pool or Ray")
    cluster.add_argument(
        "--ray-address",
        metavar="ADDR",
        help="existing Ray cluster: 'auto', HOST:6379, 'ray://HOST:10001' (default: start a local Ray)",
    )
    add_packet_arguments(parser)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import sys

    from lidar3d.batch import BatchProgress, JobResult, JobStatus, ProgressDisplay, RunOptions, run_batch
    from lidar3d.config import load_config

    config = apply_slam_arguments(apply_packet_arguments(load_config(args.config), args), args)
    scans = scan_selection(args)
    config = apply_gnss_fusion_arguments(
        config, args, span_given=bool(args.span_dir or args.span_pattern), span_flag="--span-dir or --span-pattern"
    )
    run_options = RunOptions(start=scans.start, max_scans=scans.max_scans, gnss_factors=args.gnss_factors)
    display: list[ProgressDisplay] = []

    def on_progress(event: str, progress: BatchProgress, result: JobResult | None) -> None:
        if event == "start" and not args.quiet:
            if progress.up_to_date:
                print(f"{progress.up_to_date} of {progress.total} bags up to date, skipped", file=sys.stderr)
            display.append(ProgressDisplay(progress))
        elif not display:
            return
        elif event == "finished" and result is not None:
            display[0].finished(result)
        elif event == "update":
            display[0].update()
        elif event == "end":
            display[0].close()

    # SIGTERM interrupts the batch as Ctrl-C does (lidar3d.cli.main): its bags are marked, it can resume.
    outcome = run_batch(
        args.inputs,
        args.out,
        config,
        span_dir=args.span_dir,
        span_pattern=args.span_pattern,
        extrinsics=args.extrinsics,
        workers=args.workers,
        engine=args.engine,
        ray_address=args.ray_address,
        force=args.overwrite,
        run_options=run_options,
        on_progress=on_progress,
    )

    counts = {status: n for status, n in outcome.counts.items() if n}
    print(f"{len(outcome.rows)} bags: " + ", ".join(f"{n} {status}" for status, n in counts.items()))
    for row in outcome.rows:
        if row["status"] == JobStatus.FAILED.value:
            print(f"failed: {row['name']}: {row['error']}")
    print(f"report: {outcome.report.html}")
    if outcome.interrupted:
        finished = outcome.names(JobStatus.DONE) + outcome.names(JobStatus.UP_TO_DATE)
        stopped = outcome.names(JobStatus.INTERRUPTED)
        waiting = outcome.names(JobStatus.NOT_STARTED)
        print(
            f"lidar3d batch: interrupted; finished: {', '.join(finished) or 'none'}; "
            f"stopped: {', '.join(stopped) or 'none'}; not started: {', '.join(waiting) or 'none'}. "
            "Run the same command again to resume.",
            file=sys.stderr,
        )
        return 130
    return 0 if outcome.ok else 1
