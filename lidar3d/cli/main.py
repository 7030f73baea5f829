"""The ``lidar3d`` command line.

Each subcommand lives in its own module ``lidar3d/cli/cmd_<name>.py`` that defines
``register(subparsers)``; the module must import nothing heavy at its top (import inside ``run``),
so ``lidar3d --help`` stays instant. Every subcommand has a library-function twin.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import pkgutil
import sys
from collections.abc import Sequence

from lidar3d import __version__, stop_signals
from lidar3d.cli.options import HelpFormatter, add_global_arguments
from lidar3d.errors import Lidar3dError

__all__ = ["build_parser", "entry_point", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lidar3d",
        description="LiDAR SLAM for Velodyne VLP-16 recordings, in the style of LeGO-LOAM.",
    )
    parser.add_argument("--version", action="version", version=f"lidar3d {__version__}")
    add_global_arguments(parser, top_level=True)
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    package = importlib.import_module("lidar3d.cli")
    for info in sorted(pkgutil.iter_modules(package.__path__), key=lambda m: m.name):
        if info.name.startswith("cmd_"):
            importlib.import_module(f"lidar3d.cli.{info.name}").register(subparsers)
    for subparser in subparsers.choices.values():
        add_global_arguments(subparser, top_level=False)
        subparser.formatter_class = HelpFormatter  # every subcommand keeps its epilog as written
    return parser


def _configure_logging(verbose: bool, quiet: bool) -> None:
    """Log records of ``lidar3d.*`` to stderr, each on its own line above any progress bar."""
    from lidar3d.cli.progress import ProgressSafeHandler

    level = logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO
    handler = ProgressSafeHandler()
    handler.setFormatter(logging.Formatter("%(levelname)s: %(message)s"))
    root = logging.getLogger("lidar3d")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = False


def main(argv: Sequence[str] | None = None) -> int:
    """Run the CLI in process; returns the exit code (0 ok, 1 known error, 130 interrupted, 143
    terminated by SIGTERM, 141 the reader of stdout went away, as in ``lidar3d info BAG | head``)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 1
    _configure_logging(args.verbose, args.quiet)
    try:
        with stop_signals.sigterm_as_interrupt():
            code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's exit
        return code
    except BrokenPipeError:
        _silence_stdout()
        return 128 + 13  # as a process ended by SIGPIPE
    except Lidar3dError as err:
        print(f"lidar3d {args.command}: error: {err}", file=sys.stderr)
        return 1
    except stop_signals.Terminated:
        print(f"lidar3d {args.command}: terminated (SIGTERM); finished outputs are kept", file=sys.stderr)
        return 128 + 15
    except KeyboardInterrupt:
        print(f"lidar3d {args.command}: interrupted; finished outputs are kept", file=sys.stderr)
        return 130


def _silence_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's final flush of the closed pipe stays quiet."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # stdout without a file descriptor (in-process tests)
        pass


def entry_point() -> None:  # pragma: no cover - thin wrapper for the console script
    sys.exit(main())


if __name__ == "__main__":
    sys.exit(main())
