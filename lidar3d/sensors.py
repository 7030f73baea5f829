"""Spinning-lidar sensor models: beam elevation tables, columns per sweep and rotation rate.

Nothing downstream hard-codes 16 rings: the range image, ring derivation and the simulator all read
a :class:`SensorModel`. Elevation tables are sorted ascending, so ring r is the r-th lowest beam,
which is how the ROS ``velodyne_pointcloud`` driver numbers its ``ring`` field.

Sources: Velodyne VLP-16 user manual (16 beams, -15..+15 deg in 2 deg steps, 0.2 deg azimuth
resolution at 600 rpm, 100 m range), HDL-32E manual (32 beams, -30.67..+10.67 deg in 4/3 deg steps,
about 0.16 deg at 600 rpm, 100 m), VLP-32C manual (32 beams, non-uniform -25..+15 deg, 0.2 deg at
600 rpm, 200 m).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SENSOR_MODELS", "SensorModel", "guess_sensor_model", "sensor_model"]


@dataclass(frozen=True, slots=True)
class SensorModel:
    """Geometry of a spinning multi-beam lidar.

    Attributes:
        name: preset key (``vlp16``, ``hdl32e``, ``vlp32c``).
        elevation_deg: beam elevations, ascending; index = ring.
        n_columns: azimuth cells per sweep in the range image (360 / horizontal resolution).
        rotation_hz: sweeps per second.
        max_range_m: the sensor's rated range.
    """

    name: str
    elevation_deg: tuple[float, ...]
    n_columns: int
    rotation_hz: float
    max_range_m: float

    def __post_init__(self) -> None:
        if list(self.elevation_deg) != sorted(self.elevation_deg):
            raise ValueError(f"{self.name}: elevation_deg must be ascending")
        if self.n_columns <= 0 or self.rotation_hz <= 0:
            raise ValueError(f"{self.name}: n_columns and rotation_hz must be positive")

    @property
    def n_rings(self) -> int:
        return len(self.elevation_deg)

    @property
    def elevation_rad(self) -> np.ndarray:
        return np.deg2rad(np.asarray(self.elevation_deg, dtype=np.float64))

    @property
    def azimuth_resolution_deg(self) -> float:
        return 360.0 / self.n_columns

    @property
    def sweep_period_s(self) -> float:
        return 1.0 / self.rotation_hz

    def ring_from_elevation(self, elevation_rad: np.ndarray) -> np.ndarray:
        """Ring index (uint16) of the beam nearest in elevation to each given angle."""
        table = self.elevation_rad
        idx = np.searchsorted(table, elevation_rad)
        idx = np.clip(idx, 1, len(table) - 1)
        lower = table[idx - 1]
        upper = table[idx]
        idx = idx - ((elevation_rad - lower) < (upper - elevation_rad))
        return idx.astype(np.uint16)


VLP16 = SensorModel(
    name="vlp16",
    elevation_deg=tuple(float(e) for e in range(-15, 16, 2)),
    n_columns=1800,
    rotation_hz=10.0,
    max_range_m=100.0,
)

HDL32E = SensorModel(
    name="hdl32e",
    elevation_deg=tuple(round(-30.67 + i * 4.0 / 3.0, 2) for i in range(32)),
    n_columns=2250,
    rotation_hz=10.0,
    max_range_m=100.0,
)

VLP32C = SensorModel(
    name="vlp32c",
    elevation_deg=(
        -25.0,
        -15.639,
        -11.31,
        -8.843,
        -7.254,
        -6.148,
        -5.333,
        -4.667,
        -4.0,
        -3.667,
        -3.333,
        -3.0,
        -2.667,
        -2.333,
        -2.0,
        -1.667,
        -1.333,
        -1.0,
        -0.667,
        -0.333,
        0.0,
        0.333,
        0.667,
        1.0,
        1.333,
        1.667,
        2.333,
        3.333,
        4.667,
        7.0,
        10.333,
        15.0,
    ),
    n_columns=1800,
    rotation_hz=10.0,
    max_range_m=200.0,
)

SENSOR_MODELS: dict[str, SensorModel] = {m.name: m for m in (VLP16, HDL32E, VLP32C)}


def sensor_model(name: str) -> SensorModel:
    """The preset called ``name``; raises ``KeyError`` listing the presets otherwise."""
    try:
        return SENSOR_MODELS[name]
    except KeyError:
        raise KeyError(f"unknown sensor model {name!r}; known: {', '.join(SENSOR_MODELS)}") from None


def guess_sensor_model(n_rings: int, elevation_span_deg: float | None = None) -> SensorModel | None:
    """Guess the preset from the number of distinct rings (and, for 32 beams, the elevation span).

    Returns None when nothing matches. HDL-32E spans about 41 degrees, VLP-32C about 40 but with
    its lowest beam at -25 degrees; the span alone separates them poorly, so the lowest elevation
    decides when given (pass ``elevation_span_deg`` as the measured minimum elevation).
    """
    if n_rings == 16:
        return VLP16
    if n_rings == 32:
        if elevation_span_deg is not None and elevation_span_deg > -27.5:
            return VLP32C
        return HDL32E
    return None
