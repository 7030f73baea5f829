"""The packets of one sweep -> a :class:`~lidar3d.records.Scan`, through ``velodyne-decoder``.

``velodyne-decoder`` (C++, BSD-3, validated by its author against VeloView) turns a sweep's
packets into points with the model's calibration: x, y, z in the sensor frame (REP-105: x
forward, y left, z up, as the ROS velodyne driver), intensity, the firing time of each point
relative to the first packet, the ring (laser ordered by elevation, 0 = lowest beam, as
velodyne_pointcloud numbers it) and the return type. :class:`PacketDecoder` adds what lidar3d
needs: which return of a dual-return sensor is kept, the stamp from the chosen clock, the minimum
range (dropped points counted) and the sanity stage (:mod:`lidar3d.io.scan_sanity`).

The stamp of a scan is the first packet's time, so the point times run from 0 to one sweep
period and the pose of the scan is the lidar pose at the sweep start (as for the simulator and
velodyne_pointcloud bags). With ``clock = "host"`` the first packet's host time (pcap capture
time, or the packet stamp in a bag); with ``"sensor"`` its own time stamp (microseconds past the
top of the hour, PPS-disciplined when the sensor has a GPS), placed in the hour of the host time
nearest to it (:func:`sensor_stamp_ns`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lidar3d.errors import PacketError
from lidar3d.io.packet_inputs import RawPacket
from lidar3d.io.pointcloud2 import DecodeStats, TimeSource
from lidar3d.io.scan_sanity import SanityCounts, sanitize_scan
from lidar3d.io.velodyne_packets import PRODUCT_IDS, PacketModel, ReturnMode, sensor_time_us
from lidar3d.records import Scan
from lidar3d.sensors import SENSOR_MODELS, SensorModel

__all__ = ["HOUR_NS", "PacketDecoder", "check_calibration", "sensor_stamp_ns"]

HOUR_NS = 3_600_000_000_000
_STRONGEST_FLAG = 1  # velodyne-decoder return_type: 1 strongest, 2 last, 3 both (the same point)
_LAST_FLAG = 2
#: velodyne-decoder drops returns nearer than this (a distance of 0 is "no return").
_DECODER_MIN_RANGE_M = 0.05
_DECODER_MAX_RANGE_M = 500.0
# Columns of velodyne-decoder's contiguous output (velodyne_decoder.PointField).
_COLUMN_INTENSITY, _COLUMN_TIME, _COLUMN_RING, _COLUMN_RETURN_TYPE = 3, 4, 6, 7


def sensor_stamp_ns(packet: RawPacket) -> int:
    """The packet's sensor time (us past the top of the hour) in the hour of its host time nearest to it."""
    candidate = packet.host_ns - packet.host_ns % HOUR_NS + sensor_time_us(packet.data) * 1000
    return min((candidate - HOUR_NS, candidate, candidate + HOUR_NS), key=lambda t: abs(t - packet.host_ns))


def check_calibration(path: str | Path, model: PacketModel) -> None:
    """Raise unless ``path`` is a velodyne_pointcloud calibration YAML with as many lasers as ``model``.

    Raises:
        PacketError: missing or unreadable file, not YAML, no ``lasers`` list, or a laser count
            (``num_lasers`` or the list's length) other than the model's.
    """
    import yaml

    path = Path(path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise PacketError(f"{path}: cannot read the calibration: {err.strerror}") from err
    except (yaml.YAMLError, UnicodeDecodeError) as err:
        raise PacketError(f"{path}: calibration is not YAML: {str(err).splitlines()[0]}") from err
    lasers = data.get("lasers") if isinstance(data, dict) else None
    if not isinstance(lasers, list) or not lasers:
        raise PacketError(f"{path}: not a velodyne_pointcloud calibration (no 'lasers' list)")
    count = int(data.get("num_lasers", len(lasers)))
    expected = SENSOR_MODELS[model.value].n_rings
    if count != expected or len(lasers) != expected:
        raise PacketError(
            f"{path}: calibration has {len(lasers)} lasers (num_lasers {count}), the {model.value} has {expected}"
        )


def _decoder_model(model: PacketModel) -> Any:
    import velodyne_decoder as vd

    return {
        PacketModel.VLP16: vd.Model.VLP16,
        PacketModel.VLP32C: vd.Model.VLP32C,
        PacketModel.HDL32E: vd.Model.HDL32E,
    }[model]


class PacketDecoder:
    """Decodes the sweeps of one stream (see the module docstring); one decoder per pass.

    Args:
        model: the model decoded as.
        return_mode: the stream's return mode; in dual mode ``keep`` chooses the return kept.
        keep: ``"strongest"``, ``"last"`` or ``"both"`` (dual-return streams only).
        clock: ``"host"`` or ``"sensor"``.
        sensor: sanity limits (maximum range, sweep period).
        min_range_m: nearer points are dropped and counted.
        calibration: a velodyne_pointcloud YAML, or None for the model's built-in table.
    """

    def __init__(
        self,
        model: PacketModel,
        *,
        return_mode: ReturnMode | None,
        keep: str,
        clock: str,
        sensor: SensorModel,
        min_range_m: float,
        calibration: str | Path | None = None,
    ) -> None:
        import velodyne_decoder as vd

        self.sensor = sensor
        self.min_range_m = float(min_range_m)
        self.clock = clock
        self._flag = (
            {"strongest": _STRONGEST_FLAG, "last": _LAST_FLAG}.get(keep) if return_mode is ReturnMode.DUAL else None
        )
        options: dict[str, Any] = {
            "model": _decoder_model(model),
            "min_range": _DECODER_MIN_RANGE_M,
            "max_range": _DECODER_MAX_RANGE_M,
            "timestamp_first_packet": True,
        }
        if calibration:
            check_calibration(calibration, model)
            options["calibration"] = vd.Calibration.read(str(calibration))
        self._product = bytes([next(byte for byte, named in PRODUCT_IDS.items() if named is model)])
        self._vd = vd
        self._decoder = vd.ScanDecoder(vd.Config(**options))

    def stamp_ns(self, packet: RawPacket) -> int:
        """The stamp a sweep starting with ``packet`` gets, by the decoder's clock."""
        return sensor_stamp_ns(packet) if self.clock == "sensor" else packet.host_ns

    def decode(self, packets: Sequence[RawPacket]) -> tuple[Scan, DecodeStats, SanityCounts]:
        """The sane scan of one sweep's packets, what the minimum range dropped and what the sanity stage dropped.

        Raises:
            PacketError: velodyne-decoder refuses the packets.
        """
        vd = self._vd
        batch = vd.PacketVector()
        product = self._product
        for packet in packets:
            data = packet.data
            if data[1205:] != product:  # a product byte that disagrees with the firing pattern (or --sensor)
                data = data[:1205] + product
            batch.append(vd.VelodynePacket(packet.host_ns * 1e-9, data))
        try:
            _stamp, cloud = self._decoder.decode(batch, False)  # (N, 8) float32: x y z intensity time column ring type
        except Exception as err:  # the C++ decoder raises RuntimeError/ValueError on packets it cannot read
            raise PacketError(f"velodyne-decoder cannot decode the sweep: {err}") from err
        if self._flag is not None:
            cloud = cloud[(cloud[:, _COLUMN_RETURN_TYPE].astype(np.uint8) & self._flag) != 0]
        n_input = len(cloud)
        points = cloud[:, :3].astype(np.float64)
        intensity = cloud[:, _COLUMN_INTENSITY]
        ring = cloud[:, _COLUMN_RING].astype(np.uint16)
        time_s = cloud[:, _COLUMN_TIME].astype(np.float64)
        far = np.einsum("ij,ij->i", points, points) >= self.min_range_m * self.min_range_m
        n_near = n_input - int(np.count_nonzero(far))
        if n_near:
            points, intensity, ring, time_s = points[far], intensity[far], ring[far], time_s[far]
        scan = Scan(self.stamp_ns(packets[0]), points, intensity, ring, time_s)
        sane, counts = sanitize_scan(scan, self.sensor)
        return sane, DecodeStats(n_input, n_near, TimeSource.RELATIVE), counts
