"""Output coordinate reference systems: UTM, any projected EPSG code, local ENU, WGS84; grid axes and convergence.

An export names its CRS as ``utm`` (the WGS84 / UTM zone of the georeference origin: EPSG:326zz
north, 327zz south, with the Norway and Svalbard exceptions), ``EPSG:NNNN`` (a projected CRS that
pyproj knows), ``enu`` (the run's local ENU frame) or ``wgs84`` (latitude, longitude, ellipsoidal
height; trajectories only).

Positions go ENU -> ECEF -> WGS84 geodetic (:meth:`lidar3d.gnss.enu.LocalEnu.to_geodetic`) -> the
projection (pyproj, ``always_xy``). Heights stay **ellipsoidal** (WGS84) in every CRS: no geoid is
applied (a geoid model is a grid file PROJ may not have offline).

Grid axes. In a projected CRS, grid north differs from true north by the **meridian convergence**
gamma (pyproj ``Proj.get_factors(...).meridian_convergence``: the angle from true north to grid north,
negative west of a UTM zone's central meridian in the northern hemisphere). A direction with true
azimuth alpha has grid azimuth alpha - gamma, so a counter-clockwise yaw in the east-north plane
becomes yaw + gamma:

    R_grid_local = Rz(gamma),   R_grid_lidar = R_grid_local(p) R_local_enu(p) R_enu_lidar,

with R_local_enu(p) the (tiny) tilt between the ENU frame at the origin and the local level at the
point p (about 0.009 deg per km). Distances in grid coordinates are scaled by the point scale factor
k (0.9996 on a UTM central meridian, up to about 1.001 at a zone's edge).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from lidar3d.errors import GeoreferenceError
from lidar3d.gnss.enu import GeodeticOrigin, LocalEnu

__all__ = ["CrsKind", "GridPoses", "OutputCrs", "enu_to_crs_points", "enu_to_crs_poses", "resolve_crs", "utm_epsg"]


class CrsKind(str, enum.Enum):
    """How output coordinates are expressed."""

    PROJECTED = "projected"  # utm or EPSG:NNNN: easting, northing, ellipsoidal height
    ENU = "enu"  # the run's local ENU frame: east, north, up in metres from the origin
    WGS84 = "wgs84"  # latitude, longitude (degrees), ellipsoidal height (m)


def utm_epsg(latitude_deg: float, longitude_deg: float) -> int:
    """EPSG code of the WGS84 / UTM zone holding a point (326zz north, 327zz south).

    Zone = floor((lon + 180) / 6) + 1, with the exceptions of the UTM grid: 32V widened over
    south-western Norway (56-64 N, 3-12 E) and the Svalbard zones 31X, 33X, 35X, 37X (72-84 N).
    """
    lon = ((longitude_deg + 180.0) % 360.0) - 180.0
    zone = int(math.floor((lon + 180.0) / 6.0)) + 1
    zone = min(zone, 60)
    if 56.0 <= latitude_deg < 64.0 and 3.0 <= lon < 12.0:
        zone = 32
    if 72.0 <= latitude_deg < 84.0 and 0.0 <= lon < 42.0:
        zone = 31 if lon < 9.0 else 33 if lon < 21.0 else 35 if lon < 33.0 else 37
    return (32600 if latitude_deg >= 0.0 else 32700) + zone


@dataclass(frozen=True, slots=True)
class OutputCrs:
    """A resolved output CRS.

    Attributes:
        kind: projected, ENU or WGS84.
        name: what the user asked for, resolved (``EPSG:32632``, ``enu``, ``wgs84``).
        epsg: the EPSG code (projected and WGS84: 4979), else None.
        wkt: OGC WKT 1 (GDAL flavour) of the CRS, for LAS files and headers; for ENU a local CS
            that names the origin.
        axis_names: the three coordinate names, in order.
    """

    kind: CrsKind
    name: str
    epsg: int | None
    wkt: str
    axis_names: tuple[str, str, str]

    @property
    def is_projected(self) -> bool:
        return self.kind is CrsKind.PROJECTED


def _enu_wkt(origin: GeodeticOrigin) -> str:
    label = (
        f"lidar3d local ENU, origin lat {origin.latitude_deg:.9f} lon {origin.longitude_deg:.9f} "
        f"h {origin.height_ellipsoid_m:.3f} m (WGS84 ellipsoidal)"
    )
    return (
        f'LOCAL_CS["{label}",LOCAL_DATUM["lidar3d ENU origin",0],UNIT["metre",1],'
        'AXIS["Easting",EAST],AXIS["Northing",NORTH]]'
    )


@lru_cache(maxsize=16)
def _pyproj_crs(epsg: int):
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    try:
        return CRS.from_epsg(epsg)
    except CRSError:
        raise GeoreferenceError(f"--crs EPSG:{epsg}: unknown EPSG code (not in the PROJ database)") from None


def resolve_crs(spec: str, origin: GeodeticOrigin, *, for_map: bool) -> OutputCrs:
    """The output CRS named ``spec`` (``utm``, ``EPSG:NNNN``, ``enu``, ``wgs84``; case-insensitive).

    Raises :class:`GeoreferenceError` (one line) for an unknown name or EPSG code, a geographic or
    non-projected EPSG CRS, and ``wgs84`` for a map (``for_map``): a point cloud needs metric axes.
    """
    text = spec.strip()
    lower = text.lower()
    if lower == "enu":
        return OutputCrs(CrsKind.ENU, "enu", None, _enu_wkt(origin), ("east_m", "north_m", "up_m"))
    if lower == "wgs84":
        if for_map:
            raise GeoreferenceError(
                "--crs wgs84: a geographic CRS cannot hold a map (degrees are no point-cloud axes); "
                "use utm, a projected EPSG:NNNN or enu"
            )
        wkt = _pyproj_crs(4979).to_wkt()  # WKT 1 has no 3-D geographic CRS
        return OutputCrs(CrsKind.WGS84, "wgs84", 4979, wkt, ("latitude_deg", "longitude_deg", "height_ellipsoid_m"))
    if lower == "utm":
        epsg = utm_epsg(origin.latitude_deg, origin.longitude_deg)
    elif lower.startswith("epsg:") and lower[5:].isdigit():
        epsg = int(lower[5:])
    else:
        raise GeoreferenceError(f"--crs {spec}: unknown CRS (choose utm, EPSG:NNNN, enu or wgs84)")
    crs = _pyproj_crs(epsg)
    if crs.is_geographic:
        raise GeoreferenceError(
            f"--crs EPSG:{epsg}: {crs.name} is a geographic CRS; "
            + ("a map needs a projected CRS (utm or a projected EPSG code)" if for_map else "use --crs wgs84")
        )
    if not crs.is_projected or crs.is_compound or crs.is_vertical:
        raise GeoreferenceError(
            f"--crs EPSG:{epsg}: {crs.name} is not a plain projected CRS (compound, vertical or other); "
            "heights are written ellipsoidal, so give the horizontal projected CRS"
        )
    return OutputCrs(
        CrsKind.PROJECTED, f"EPSG:{epsg}", epsg, crs.to_wkt("WKT1_GDAL"), ("easting_m", "northing_m", "height_m")
    )


@lru_cache(maxsize=16)
def _to_grid(epsg: int):
    from pyproj import Transformer

    return Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True)


@dataclass(frozen=True, slots=True)
class GridPoses:
    """Poses expressed in an output CRS.

    Attributes:
        positions: (N, 3) coordinates in ``OutputCrs.axis_names`` order.
        R_grid_lidar: (N, 3, 3) lidar orientation in the output axes (x east/grid east, y north/grid
            north, z up); for WGS84 the local level ENU frame at each point.
        convergence_deg: (N,) meridian convergence gamma (0 for ENU and WGS84).
        scale_factor: (N,) point scale factor k (1 for ENU and WGS84).
    """

    positions: np.ndarray
    R_grid_lidar: np.ndarray
    convergence_deg: np.ndarray
    scale_factor: np.ndarray


def _rz(angle_rad: np.ndarray) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    R = np.zeros((len(c), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


def enu_to_crs_points(p_enu_m: np.ndarray, origin: GeodeticOrigin, crs: OutputCrs) -> np.ndarray:
    """(N, 3) ENU points in ``crs`` coordinates (float64)."""
    p = np.asarray(p_enu_m, dtype=np.float64).reshape(-1, 3)
    if crs.kind is CrsKind.ENU:
        return p.copy()
    lat, lon, h = LocalEnu(origin).to_geodetic(p)
    if crs.kind is CrsKind.WGS84:
        return np.column_stack([lat, lon, h])
    assert crs.epsg is not None
    x, y = _to_grid(crs.epsg).transform(lon, lat)
    return np.column_stack([np.asarray(x), np.asarray(y), h])


def enu_to_crs_poses(T_enu_lidar: np.ndarray, origin: GeodeticOrigin, crs: OutputCrs) -> GridPoses:
    """Lidar poses (N, 4, 4) in ENU at ``origin`` expressed in ``crs`` (positions and grid-axis attitude)."""
    from pyproj import Proj

    T = np.asarray(T_enu_lidar, dtype=np.float64).reshape(-1, 4, 4)
    n = len(T)
    positions = enu_to_crs_points(T[:, :3, 3], origin, crs)
    if crs.kind is CrsKind.ENU:
        return GridPoses(positions, T[:, :3, :3].copy(), np.zeros(n), np.ones(n))
    enu = LocalEnu(origin)
    lat, lon, _ = enu.to_geodetic(T[:, :3, 3])
    R_local_enu = np.swapaxes(enu.R_enu_local(lat, lon), 1, 2)
    R_local_lidar = R_local_enu @ T[:, :3, :3]
    if crs.kind is CrsKind.WGS84:
        return GridPoses(positions, R_local_lidar, np.zeros(n), np.ones(n))
    factors = Proj(_pyproj_crs(crs.epsg)).get_factors(lon, lat)
    gamma = np.asarray(factors.meridian_convergence, dtype=np.float64).reshape(n)
    k = np.asarray(factors.meridional_scale, dtype=np.float64).reshape(n)
    return GridPoses(positions, _rz(np.radians(gamma)) @ R_local_lidar, gamma, k)
