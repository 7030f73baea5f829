"""The option vocabulary shared by the subcommands: one name, one meaning, one help text each.

``run``, ``batch``, ``features``, ``info``, ``eval`` and ``simulate`` take their common options from
here, so ``--topic``, ``--config``, ``--out``, ``--overwrite``, the scan selection (``--start``,
``--max-scans``), loop closure (``--no-loop``, ``--loop-source``), ``--map-voxel`` and ``--keep-dynamic``
are spelled, defaulted and checked the same everywhere. ``-v``/``-q`` are accepted before or after
the subcommand. Every option's help states its default (:class:`HelpFormatter` adds it where the
text does not). Nothing heavy is imported at module level (``lidar3d --help`` stays instant).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Any

__all__ = [
    "MAP_VOXEL_DEFAULT_M",
    "HelpFormatter",
    "ScanSelection",
    "add_config_argument",
    "add_global_arguments",
    "add_gnss_fusion_arguments",
    "add_output_arguments",
    "add_scan_selection",
    "add_slam_arguments",
    "add_topic_argument",
    "apply_gnss_fusion_arguments",
    "apply_slam_arguments",
    "apply_topic_argument",
    "scan_selection",
]

#: The default of ``mapping.map_voxel_m`` as the help shows it (a test checks it against the config).
MAP_VOXEL_DEFAULT_M = 0.2


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the description and epilog as written and ends every option's help with its default
    (``(default: 0)``, or ``(required)``) unless the help already names one; flags and options without a value
    (default None) must say in words what happens when they are not given."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if action.required and action.option_strings:
            return text if "required" in text else f"{text} (required)"
        if "default" in text or default is None or default is False or default is argparse.SUPPRESS:
            return text
        shown = " ".join(map(str, default)) if isinstance(default, (list, tuple)) else default
        return f"{text} (default: {shown})"


def add_global_arguments(parser: argparse.ArgumentParser, *, top_level: bool) -> None:
    """``-v/--verbose`` and ``-q/--quiet``: on the top-level parser with default False, on each
    subparser with no default (so one given before the subcommand is not reset after it)."""
    default: Any = False if top_level else argparse.SUPPRESS
    group = parser.add_argument_group("output verbosity (before or after the subcommand)")
    group.add_argument("-v", "--verbose", action="store_true", default=default, help="log debug messages too")
    group.add_argument(
        "-q", "--quiet", action="store_true", default=default, help="log warnings and errors only, no progress bar"
    )


def add_topic_argument(parser: argparse.ArgumentParser) -> None:
    """``--topic T``: the PointCloud2 topic (config ``input.topic``)."""
    parser.add_argument(
        "--topic", metavar="T", help="PointCloud2 topic (default: the config's input.topic, else the only one)"
    )


def apply_topic_argument(config: Any, args: argparse.Namespace) -> Any:
    """``config`` with ``input.topic`` set from ``--topic`` when given."""
    if not args.topic:
        return config
    import dataclasses

    return dataclasses.replace(config, input=dataclasses.replace(config.input, topic=args.topic))


def add_config_argument(parser: argparse.ArgumentParser, what: str = "") -> None:
    """``--config FILE``: a TOML configuration (see ``lidar3d config``)."""
    parser.add_argument(
        "--config",
        metavar="FILE",
        help=f"TOML configuration{what} (default: built-in values; 'lidar3d config' prints them)",
    )


def add_output_arguments(parser: argparse.ArgumentParser, *, what: str, overwrite: str | None) -> None:
    """``--out DIR`` (required) and, when ``overwrite`` gives its help (with its default), ``--overwrite``."""
    parser.add_argument("--out", required=True, metavar="DIR", help=what)
    if overwrite is not None:
        parser.add_argument("--overwrite", action="store_true", help=overwrite)


def add_scan_selection(parser: argparse.ArgumentParser) -> None:
    """``--start N`` and ``--max-scans N``: which scans of the recording are read."""
    parser.add_argument("--start", type=int, default=0, metavar="N", help="skip the first N scans")
    parser.add_argument("--max-scans", type=int, metavar="N", help="process at most N scans (default: all)")


@dataclass(frozen=True, slots=True)
class ScanSelection:
    """The scans chosen by ``--start``/``--max-scans``: skip ``start`` scans, then read at most
    ``max_scans`` (None: all)."""

    start: int = 0
    max_scans: int | None = None

    @property
    def stop(self) -> int | None:
        """Index one past the last scan chosen (None: to the end)."""
        return None if self.max_scans is None else self.start + self.max_scans


def scan_selection(args: argparse.Namespace) -> ScanSelection:
    """The checked scan selection of ``args``.

    Raises:
        ConfigError: ``--start`` below 0 or ``--max-scans`` below 1.
    """
    from lidar3d.errors import ConfigError

    if args.start < 0:
        raise ConfigError(f"--start must be 0 or more, got {args.start}")
    if args.max_scans is not None and args.max_scans <= 0:
        raise ConfigError(f"--max-scans must be 1 or more, got {args.max_scans}")
    return ScanSelection(args.start, args.max_scans)


def add_slam_arguments(parser: argparse.ArgumentParser) -> None:
    """``--map-voxel``, ``--no-loop``, ``--loop-source``, ``--keep-dynamic``: the per-run SLAM switches."""
    parser.add_argument(
        "--map-voxel",
        type=float,
        metavar="M",
        help=f"voxel size of map.pcd in metres (default: the config's mapping.map_voxel_m, {MAP_VOXEL_DEFAULT_M})",
    )
    loop = parser.add_mutually_exclusive_group()
    loop.add_argument("--no-loop", action="store_true", help="turn loop closure off (default: on, loop.enabled)")
    loop.add_argument(
        "--loop-source",
        choices=("distance", "place", "both"),
        help="loop candidates from the distance gate, place recognition (Scan Context) or both "
        "(default: the config's loop.source, both)",
    )
    parser.add_argument(
        "--keep-dynamic",
        action="store_true",
        help="keep moving objects in map.pcd, write no dynamic.pcd (default: removed; config dynamic.enabled)",
    )


def apply_slam_arguments(config: Any, args: argparse.Namespace) -> Any:
    """``config`` with the options of :func:`add_slam_arguments` (and ``--topic``) applied.

    Raises:
        ConfigError: ``--map-voxel`` out of range (naming the flag).
    """
    import dataclasses

    from lidar3d.config import config_with
    from lidar3d.errors import ConfigError

    config = apply_topic_argument(config, args)
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
    return config


def add_gnss_fusion_arguments(parser: argparse.ArgumentParser) -> None:
    """``--gnss-factors`` and ``--gnss-hold-out S``."""
    parser.add_argument(
        "--gnss-factors",
        action="store_true",
        help="fuse the SPAN log's good epochs as position factors in the pose graph, jumps rejected (default: off)",
    )
    parser.add_argument(
        "--gnss-hold-out",
        type=float,
        metavar="S",
        help="with --gnss-factors: fuse only even S-second periods, score the odd ones "
        "(default: the config's georef.hold_out_period_s, 0: fuse all)",
    )


def apply_gnss_fusion_arguments(config: Any, args: argparse.Namespace, *, span_given: bool, span_flag: str) -> Any:
    """``config`` with ``--gnss-hold-out`` applied, after checking the flags go together.

    Raises:
        ConfigError: ``--gnss-factors`` without a SPAN log, ``--gnss-hold-out`` without
            ``--gnss-factors``, or a hold-out period out of range.
    """
    from lidar3d.config import config_with
    from lidar3d.errors import ConfigError

    if args.gnss_factors and not span_given:
        raise ConfigError(f"--gnss-factors needs {span_flag} (the log to fuse)")
    if args.gnss_hold_out is None:
        return config
    if not args.gnss_factors:
        raise ConfigError("--gnss-hold-out needs --gnss-factors")
    try:
        return config_with(config, {"georef": {"hold_out_period_s": args.gnss_hold_out}})
    except ConfigError as err:
        raise ConfigError(f"--gnss-hold-out: {err}") from None
