"""``lidar3d batch``: SLAM over many bags, resumable, with one report."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "batch",
        help="run SLAM on many bags (local processes or Ray), resumable, with an HTML report",
        description=(
            "Run SLAM on every bag found in INPUTS, each exactly as 'lidar3d run' would, into "
            "OUT/<name>/. A bag's folder appears only when complete; re-running the same command "
            "skips finished bags (same content, configuration and SPAN log), so a killed or "
            "interrupted batch resumes. Writes OUT/summary.csv, OUT/summary.json and OUT/report.html."
        ),
        epilog=(
            "examples:\n"
            "  lidar3d batch /data/drives --out results/batch\n"
            "  lidar3d batch '/data/2024-05-*/*.bag' --out results/may --span-dir /data/span --extrinsics rig.toml\n"
            "  lidar3d batch /data/sims --out results/sims --span-pattern novatel_span.log "
            "--extrinsics '{parent}/extrinsics.toml'\n"
            "  lidar3d batch /shared/bags --out /shared/results --engine ray --ray-address auto\n"
            "\n"
            "patterns (--span-pattern, --extrinsics): {stem} bag name without .bag, {name} batch output\n"
            "name, {parent} the bag's folder, {folder} that folder's name; relative paths are taken\n"
            "relative to the bag's folder; glob characters allowed.\n"
            "exit status: 0 every bag finished, 1 some bag failed (see the report), 130 interrupted."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("inputs", nargs="+", metavar="INPUT", help="bag, ROS2 bag folder, folder to search, or glob")
    parser.add_argument("--out", required=True, metavar="DIR", help="batch output folder")
    span = parser.add_mutually_exclusive_group()
    span.add_argument("--span-dir", metavar="DIR", help="folder of SPAN logs, matched to bags by time overlap")
    span.add_argument("--span-pattern", metavar="PATTERN", help="SPAN log path per bag, e.g. '{stem}.gps'")
    parser.add_argument("--extrinsics", metavar="FILE", help="lidar-to-IMU extrinsic file (or per-bag pattern)")
    parser.add_argument("--workers", type=int, metavar="N", help="bags in parallel (default: all CPUs)")
    parser.add_argument(
        "--engine", choices=("local", "ray"), default="local", help="local process pool (default) or Ray"
    )
    parser.add_argument("--ray-address", metavar="ADDR", help="existing Ray cluster ('auto', 'ray://host:10001')")
    parser.add_argument("--config", metavar="FILE", help="TOML configuration for every bag (see 'lidar3d config')")
    parser.add_argument("--force", action="store_true", help="redo bags that are already up to date")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import signal
    import sys

    from lidar3d.batch import BatchProgress, JobResult, JobStatus, ProgressDisplay, run_batch
    from lidar3d.config import load_config

    config = load_config(args.config)
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

    def on_sigterm(signum: int, frame: object) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, on_sigterm)
    try:
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
            force=args.force,
            on_progress=on_progress,
        )
    finally:
        signal.signal(signal.SIGTERM, previous)

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
