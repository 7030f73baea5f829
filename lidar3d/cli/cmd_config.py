"""``lidar3d config``: print the configuration in force as TOML."""

from __future__ import annotations

import argparse


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "config",
        help="print the default (or a file's resolved) configuration as TOML",
        description="Print the configuration as TOML: the defaults, or a file's values merged over them.",
        epilog="example:\n  lidar3d config > my.toml     # edit, then: lidar3d run BAG --config my.toml",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--config", metavar="FILE", help="TOML file to resolve and validate (default: none, the built-in values)"
    )
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lidar3d.config import config_to_toml, load_config

    print(config_to_toml(load_config(args.config)), end="")
    return 0
