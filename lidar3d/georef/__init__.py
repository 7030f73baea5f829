"""Georeferencing: a run's SLAM frame placed on the WGS84 ellipsoid, output CRSs, GNSS position factors.

* :mod:`~lidar3d.georef.georeference`: ``T_enu_world`` fitted to the INS reference (``georef.json``);
* :mod:`~lidar3d.georef.crs`: UTM / EPSG / ENU / WGS84 outputs, grid axes and meridian convergence;
* :mod:`~lidar3d.georef.gnss_factors`: GNSS epochs chosen and gated for the pose graph.

Computation only, as :mod:`lidar3d.gnss` and :mod:`lidar3d.metrics`: the files are written by
:mod:`lidar3d.export.georef_export` and :mod:`lidar3d.run`.
"""

from lidar3d.georef.crs import CrsKind, GridPoses, OutputCrs, enu_to_crs_points, enu_to_crs_poses, resolve_crs, utm_epsg
from lidar3d.georef.georeference import (
    GEOREF_FORMAT,
    FitResidual,
    Georeference,
    GnssFusionRecord,
    file_sha256,
    fit_georeference,
    held_out_mask,
    read_georeference,
)

__all__ = [
    "GEOREF_FORMAT",
    "CrsKind",
    "FitResidual",
    "Georeference",
    "GnssFusionRecord",
    "GridPoses",
    "OutputCrs",
    "enu_to_crs_points",
    "enu_to_crs_poses",
    "file_sha256",
    "fit_georeference",
    "held_out_mask",
    "read_georeference",
    "resolve_crs",
    "utm_epsg",
]
