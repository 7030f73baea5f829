"""``lidar3d eval``: score a lidar trajectory against NovAtel SPAN ground truth.

Library twin: :func:`lidar3d.metrics.span_eval.evaluate_span_files`, then
:func:`lidar3d.export.span_report.write_span_report` for the report files.
"""

from __future__ import annotations

import argparse

from lidar3d.cli.options import add_config_argument, add_output_arguments

_EPILOG = """\
examples:
  lidar3d eval out/trajectory_tum.txt --span drive.gps --extrinsics imu_lidar.toml --out out/eval
  lidar3d eval traj.kitti --span span.log --align yaw --time-offset 0.035 --out eval_yaw
  lidar3d eval sim/ground_truth_tum.txt --span sim/novatel_span.log --extrinsics sim/extrinsics.toml \
      --align none --origin 49.01135 8.4165 163.0 --out sim/eval      # georeferenced: no alignment

TRAJECTORY is TUM (t x y z qx qy qz qw) or KITTI (12 columns, stamps in <name>.times.txt), with
UNIX-time stamps of the bag clock. LOG is a NovAtel ASCII (#INSPVAXA, #INSPVAA, %INSPVASA, #BESTPOSA,
...) or binary (.gps, raw receiver stream) log, optionally gzipped. The reference is the INS pose
moved to the lidar: T_enu_lidar = T_enu_imu . T_imu_lidar. Writes report.json, errors.csv and PNG
plots into DIR.

A trajectory of a run made with --gnss-factors (georef.json beside it) that fused this very log is
reported as fused; --held-out scores only its poses in the periods the run held out (lidar3d run
--gnss-factors --gnss-hold-out S).
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "eval",
        help="evaluate a trajectory against NovAtel SPAN ground truth (ATE, RPE, report)",
        description="Evaluate a lidar trajectory against the INS solutions of a NovAtel SPAN log.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("trajectory", metavar="TRAJECTORY", help="estimated trajectory (TUM or KITTI)")
    parser.add_argument("--span", required=True, metavar="LOG", help="NovAtel SPAN log (ASCII or binary)")
    parser.add_argument("--extrinsics", metavar="FILE", help="T_imu_lidar, TOML or YAML (default: identity)")
    parser.add_argument(
        "--align", choices=("se3", "yaw", "none"), default=None, help="alignment (default: config, se3)"
    )
    parser.add_argument(
        "--time-offset",
        type=float,
        default=None,
        metavar="S",
        help="bag clock minus GPS-derived UNIX time, seconds (default: config, 0)",
    )
    parser.add_argument(
        "--origin",
        type=float,
        nargs=3,
        metavar=("LAT", "LON", "H"),
        default=None,
        help="ENU origin: WGS84 degrees and ellipsoidal height in m (default: config, else the first good fix)",
    )
    parser.add_argument(
        "--held-out",
        action="store_true",
        help="a trajectory fused with LOG: score only the poses in the held-out periods",
    )
    add_config_argument(parser, " ([gnss] section)")
    add_output_arguments(parser, what="output folder for the report", overwrite=None)
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lidar3d.cli.run_listing import format_file_listing
    from lidar3d.config import config_with, load_config
    from lidar3d.errors import ConfigError
    from lidar3d.export.span_report import format_span_table, write_span_report
    from lidar3d.io.run_folder import check_run_output
    from lidar3d.metrics.span_eval import evaluate_span_files

    config = load_config(args.config)
    check_run_output(args.trajectory)
    for flag, key, value in (("--time-offset", "time_offset_s", args.time_offset), ("--origin", "origin", args.origin)):
        if value is not None:
            try:
                config = config_with(config, {"gnss": {key: value}})
            except ConfigError as err:
                raise ConfigError(f"{flag}: {err}") from None
    fusion = _fusion_with(args.trajectory, args.span)
    if args.held_out and (fusion is None or fusion.hold_out_period_s <= 0.0):
        why = "was not fused with this log" if fusion is None else "fused every epoch (no --gnss-hold-out)"
        raise ConfigError(f"--held-out: {args.trajectory} {why}; there is nothing held out to score")
    result = evaluate_span_files(
        args.trajectory,
        args.span,
        extrinsics_path=args.extrinsics,
        align=args.align,
        config=config.gnss,
        fused_epochs=None if fusion is None else len(fusion.fused_stamps_ns),
        hold_out_period_s=0.0 if fusion is None else fusion.hold_out_period_s,
        held_out_only=args.held_out,
    )
    written = write_span_report(result, args.out)
    print(format_span_table(result))
    print(format_file_listing(written, args.out, prefix="eval/"))
    return 0


def _fusion_with(trajectory: str, span: str):
    """The GNSS fusion record of the run holding ``trajectory`` when that run fused ``span`` (same
    bytes), else None."""
    from pathlib import Path

    from lidar3d.georef.georeference import file_sha256, read_georeference

    georef_path = Path(trajectory).parent / "georef.json"
    if not georef_path.is_file():
        return None
    fusion = read_georeference(georef_path).fusion
    if fusion is None or fusion.span_sha256 != file_sha256(span):
        return None
    return fusion
