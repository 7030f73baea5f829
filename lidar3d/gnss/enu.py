"""WGS84 geodetic coordinates to a local east-north-up (ENU) frame, with pyproj.

Route (``shared/reference/gnss-and-metrics.md`` section 2): geodetic (lat, lon, ellipsoidal h) to
ECEF with pyproj EPSG:4979 -> EPSG:4978 (``always_xy``: lon, lat order), then the ECEF -> ENU
rotation at the origin,

    R_enu_ecef = [[-sin lon0,           cos lon0,          0      ],
                  [-sin lat0 cos lon0, -sin lat0 sin lon0, cos lat0],
                  [ cos lat0 cos lon0,  cos lat0 sin lon0, sin lat0]]

    p_enu = R_enu_ecef (p_ecef - p0_ecef).

This reproduces the MathWorks/Octave ``geodetic2enu`` examples and the EPSG Guidance Note 7-2
topocentric example (EPSG:15594). Feed ellipsoidal heights, never heights above mean sea level.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from lidar3d.errors import GnssError

__all__ = ["HEIGHT_RANGE_M", "GeodeticOrigin", "LocalEnu", "R_enu_ecef", "geodetic_problem"]

# Ellipsoidal heights a land or air vehicle can have: below the Dead Sea shore (-430 m) and the
# geoid's lowest undulation (-106 m) with margin, up to high-altitude flight. A decoded height
# outside is a corrupt value, not a position.
HEIGHT_RANGE_M = (-1000.0, 20000.0)


@lru_cache(maxsize=1)
def _to_ecef():
    from pyproj import Transformer

    return Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


@lru_cache(maxsize=1)
def _to_geodetic():
    from pyproj import Transformer

    return Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)


def R_enu_ecef(latitude_deg, longitude_deg) -> np.ndarray:
    """(..., 3, 3) rotation taking ECEF vectors into the ENU frame at the given point(s)."""
    lat = np.radians(np.asarray(latitude_deg, float))
    lon = np.radians(np.asarray(longitude_deg, float))
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    zero = np.zeros_like(lat)
    rows = [
        np.stack([-so, co, zero], axis=-1),
        np.stack([-sl * co, -sl * so, cl], axis=-1),
        np.stack([cl * co, cl * so, sl], axis=-1),
    ]
    return np.stack(rows, axis=-2)


def geodetic_problem(latitude_deg: float, longitude_deg: float, height_ellipsoid_m: float) -> str | None:
    """Why a WGS84 position is unusable, in a few words, or ``None`` when it is usable.

    Usable: all three finite, |latitude| <= 90 deg, |longitude| <= 180 deg, ellipsoidal height in
    :data:`HEIGHT_RANGE_M`.
    """
    values = {"latitude_deg": latitude_deg, "longitude_deg": longitude_deg, "height_ellipsoid_m": height_ellipsoid_m}
    for name, value in values.items():
        if not np.isfinite(value):
            return f"{name} {value} is not finite"
    if not -90.0 <= latitude_deg <= 90.0:
        return f"latitude_deg {latitude_deg} outside [-90, 90]"
    if not -180.0 <= longitude_deg <= 180.0:
        return f"longitude_deg {longitude_deg} outside [-180, 180]"
    low, high = HEIGHT_RANGE_M
    if not low <= height_ellipsoid_m <= high:
        return f"height_ellipsoid_m {height_ellipsoid_m} outside [{low:g}, {high:g}] m"
    return None


@dataclass(frozen=True, slots=True)
class GeodeticOrigin:
    """Origin of a local ENU frame: WGS84 latitude/longitude (degrees) and ellipsoidal height (m).

    Raises :class:`~lidar3d.errors.GnssError` for a position :func:`geodetic_problem` refuses.
    """

    latitude_deg: float
    longitude_deg: float
    height_ellipsoid_m: float

    def __post_init__(self) -> None:
        for name in ("latitude_deg", "longitude_deg", "height_ellipsoid_m"):
            try:
                value = float(getattr(self, name))
            except (TypeError, ValueError):
                raise GnssError(f"ENU origin: {name} {getattr(self, name)!r} is not a number") from None
            object.__setattr__(self, name, value)
        problem = geodetic_problem(self.latitude_deg, self.longitude_deg, self.height_ellipsoid_m)
        if problem is not None:
            raise GnssError(f"ENU origin: {problem}")


class LocalEnu:
    """A local ENU frame at a fixed origin: converts geodetic positions and local-level rotations."""

    def __init__(self, origin: GeodeticOrigin) -> None:
        self.origin = origin
        self.R_enu_ecef = R_enu_ecef(origin.latitude_deg, origin.longitude_deg)
        x0, y0, z0 = _to_ecef().transform(origin.longitude_deg, origin.latitude_deg, origin.height_ellipsoid_m)
        self.origin_ecef_m = np.array([x0, y0, z0], dtype=float)

    def to_enu(self, latitude_deg, longitude_deg, height_ellipsoid_m) -> np.ndarray:
        """(N, 3) ENU positions in metres of geodetic points (arrays of N, or scalars -> (1, 3))."""
        lat = np.atleast_1d(np.asarray(latitude_deg, float))
        lon = np.atleast_1d(np.asarray(longitude_deg, float))
        h = np.atleast_1d(np.asarray(height_ellipsoid_m, float))
        x, y, z = _to_ecef().transform(lon, lat, h)
        delta = np.stack([np.asarray(x), np.asarray(y), np.asarray(z)], axis=-1) - self.origin_ecef_m
        return delta @ self.R_enu_ecef.T

    def to_geodetic(self, p_enu_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Inverse of :meth:`to_enu`: (latitude_deg, longitude_deg, height_ellipsoid_m) arrays."""
        p = np.atleast_2d(np.asarray(p_enu_m, float))
        ecef = p @ self.R_enu_ecef + self.origin_ecef_m
        lon, lat, h = _to_geodetic().transform(ecef[:, 0], ecef[:, 1], ecef[:, 2])
        return np.asarray(lat), np.asarray(lon), np.asarray(h)

    def R_enu_local(self, latitude_deg, longitude_deg) -> np.ndarray:
        """(N, 3, 3) rotation from the local-level ENU frame at each point into this frame.

        Local level tilts against the origin's by the angle between the two normals (about 0.009 deg
        per km), which matters for attitudes far from the origin.
        """
        R_local_ecef = R_enu_ecef(np.atleast_1d(latitude_deg), np.atleast_1d(longitude_deg))
        return self.R_enu_ecef @ np.swapaxes(R_local_ecef, -1, -2)
