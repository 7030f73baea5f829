"""The raw-packet options shared by ``run``, ``info``, ``features`` and ``convert`` (pcap files, VelodyneScan bags).

Each option sets one ``[input]`` key of the configuration (validated as a config file would be).
"""

from __future__ import annotations

import argparse
from typing import Any

__all__ = ["add_packet_arguments", "apply_packet_arguments"]

_MODELS = ("vlp16", "vlp32c", "hdl32e")


def add_packet_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--sensor``, ``--return``, ``--clock``, ``--calibration``, ``--ports``, ``--cut-azimuth``."""
    group = parser.add_argument_group("raw packets (pcap files, velodyne_msgs/VelodyneScan bags)")
    group.add_argument(
        "--sensor", choices=_MODELS, help="decode as this model (default: from the firing pattern and factory bytes)"
    )
    group.add_argument(
        "--return",
        dest="keep_return",
        choices=("strongest", "last", "both"),
        help="dual-return data: the return kept (default strongest)",
    )
    group.add_argument(
        "--clock", choices=("host", "sensor"), help="stamps from the host capture clock (default) or the sensor's"
    )
    group.add_argument("--calibration", metavar="YAML", help="velodyne_pointcloud calibration (default: built in)")
    group.add_argument("--ports", metavar="P[,P]", help="pcap: UDP destination ports of data packets (default 2368)")
    group.add_argument("--cut-azimuth", type=float, metavar="DEG", help="a sweep starts at this azimuth (default 0)")


def apply_packet_arguments(config: Any, args: argparse.Namespace) -> Any:
    """``config`` with the packet options given in ``args``; ``--sensor`` also sets ``sensor.model``.

    Raises:
        ConfigError: a value out of range, or ``--ports`` that are not integers.
    """
    from lidar3d.config import config_with
    from lidar3d.errors import ConfigError

    values: dict[str, Any] = {}
    if args.sensor:
        values["packet_model"] = args.sensor
    if args.keep_return:
        values["packet_return"] = args.keep_return
    if args.clock:
        values["packet_clock"] = args.clock
    if args.calibration:
        values["calibration"] = args.calibration
    if args.cut_azimuth is not None:
        values["cut_azimuth_deg"] = args.cut_azimuth
    if args.ports:
        try:
            values["data_ports"] = [int(port) for port in args.ports.split(",")]
        except ValueError:
            raise ConfigError(f"--ports: expected comma-separated integers, got {args.ports!r}") from None
    if not values:
        return config
    overrides: dict[str, dict[str, Any]] = {"input": values}
    if args.sensor:
        overrides["sensor"] = {"model": args.sensor}
    return config_with(config, overrides)
