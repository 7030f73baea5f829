"""``lidar3d features``: write what the front end sees (ground, clusters, outliers, features) as PCDs.

Library twin: :func:`export_front_end`.
"""

from __future__ import annotations

import argparse
import logging
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from lidar3d.cli.options import (
    add_config_argument,
    add_output_arguments,
    add_scan_selection,
    add_topic_argument,
    apply_topic_argument,
    scan_selection,
)
from lidar3d.cli.packet_options import add_packet_arguments, apply_packet_arguments
from lidar3d.export.front_end import FRONT_END_FILES, write_front_end_scan

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "features",
        help="write the front end's ground, clusters, outliers and edge/planar features per scan as PCD",
        description=textwrap.fill(
            "Run the front end (range image, ground, clusters, edge/planar features) on the scans of a "
            "bag and write, per scan, a folder scan_NNNNNN/ (N = index of the scan in the bag) holding "
            + ", ".join(FRONT_END_FILES)
            + ", all in the lidar frame, and the configuration in force as config.toml. Prints the "
            "median time per sub-stage in ms per scan.",
            width=88,
        ),
        epilog=(
            "example:\n"
            "  lidar3d features run.bag --out fe --start 100 --max-scans 10\n"
            "  pcl_viewer fe/scan_000100/*.pcd"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("bags", nargs="+", metavar="BAG", help="ROS1 .bag file(s), ROS2 bag folder, or pcap file(s)")
    add_output_arguments(parser, what="output folder", overwrite=None)
    add_topic_argument(parser)
    add_config_argument(parser)
    add_scan_selection(parser)
    add_packet_arguments(parser)
    parser.set_defaults(func=run)


@dataclass(frozen=True, slots=True)
class FeaturesExportSummary:
    """What :func:`export_front_end` did.

    Attributes:
        scan_indices: index in the bag of each scan written.
        median_stage_ms: median wall time per sub-stage over those scans (ms per scan).
        median_total_ms: median of the per-scan total.
    """

    scan_indices: tuple[int, ...]
    median_stage_ms: dict[str, float]
    median_total_ms: float


def export_front_end(
    bags: Sequence[str | Path],
    out_dir: str | Path,
    *,
    scans: tuple[int, int | None] = (0, None),
    config=None,
) -> FeaturesExportSummary:
    """Run the front end on scans ``scans[0]`` to ``scans[1]`` (exclusive) of ``bags``; write PCDs.

    Writes ``out_dir/config.toml`` (the configuration in force) and ``out_dir/scan_NNNNNN/`` per scan.
    ``config`` is a :class:`lidar3d.config.Config` (defaults when None); ``config.input.topic``
    picks the topic.

    Raises:
        BagError: the bag cannot be read or has no (or an ambiguous) lidar topic.
        OutputError: an output cannot be written.
    """
    import numpy as np

    from lidar3d.config import Config, config_to_toml
    from lidar3d.features import STAGES, run_front_end
    from lidar3d.io.atomic import write_text_atomic
    from lidar3d.io.packet_source import input_config
    from lidar3d.io.scan_source import open_scan_source

    config = input_config(bags, config or Config())
    out_dir = Path(out_dir)
    start, stop = scans
    write_text_atomic(out_dir / "config.toml", config_to_toml(config))
    written: list[int] = []
    timings: list[dict[str, float]] = []
    with open_scan_source(bags, config) as source:
        n_scans = len(source)
        # Decoded as `lidar3d run` decodes them (same rings and times); scans before `start` are skipped cheaply.
        for index, scan in source.scans(start, stop):
            result = run_front_end(scan, config)
            write_front_end_scan(out_dir / f"scan_{index:06d}", result)
            written.append(index)
            timings.append(result.stage_ms)
            log.debug(
                "scan %d: %.1f ms, %d sharp, %d flat",
                index,
                result.total_ms,
                len(result.features.sharp),
                len(result.features.flat),
            )
    if not written:
        log.warning("no scan in the range %d:%s (%d scan(s) read)", start, "" if stop is None else stop, n_scans)
        return FeaturesExportSummary(scan_indices=(), median_stage_ms=dict.fromkeys(STAGES, 0.0), median_total_ms=0.0)
    median = {stage: float(np.median([t[stage] for t in timings])) for stage in STAGES}
    total = float(np.median([sum(t.values()) for t in timings]))
    return FeaturesExportSummary(scan_indices=tuple(written), median_stage_ms=median, median_total_ms=total)


def run(args: argparse.Namespace) -> int:
    from lidar3d.config import load_config

    config = apply_topic_argument(apply_packet_arguments(load_config(args.config), args), args)
    selection = scan_selection(args)
    summary = export_front_end(args.bags, args.out, scans=(selection.start, selection.stop), config=config)
    if not summary.scan_indices:
        print(f"no scan written to {args.out}")
        return 0
    first, last = summary.scan_indices[0], summary.scan_indices[-1]
    print(f"wrote {len(summary.scan_indices)} scan folder(s) scan_{first:06d}..scan_{last:06d} to {args.out}")
    print("median ms per scan:")
    for stage, ms in summary.median_stage_ms.items():
        print(f"  {stage:<12} {ms:8.2f}")
    print(f"  {'total':<12} {summary.median_total_ms:8.2f}")
    return 0
