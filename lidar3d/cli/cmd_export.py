"""``lidar3d export``: a run's map or trajectory in a coordinate reference system (UTM, EPSG, ENU, WGS84)."""

from __future__ import annotations

import argparse

_EPILOG = """\
examples:
  lidar3d export results/drive --crs utm --out drive_map.laz
  lidar3d export results/drive --crs EPSG:25832 --out drive_map.las
  lidar3d export results/drive --crs utm --out drive_traj.tum
  lidar3d export results/drive --crs wgs84 --out drive_traj.csv
  lidar3d export results/drive --crs enu --out drive_map.ply

RUN_DIR is the output folder of 'lidar3d run ... --span LOG' (its georef.json places the SLAM frame
on WGS84). FILE's extension picks the content: .laz/.las (the map, LAS 1.4 with the CRS as WKT,
1 mm scaled integers), .pcd/.ply (the map, 64-bit float coordinates), .tum (the trajectory: stamp,
easting, northing, ellipsoidal height, quaternion in the grid axes), .csv (the trajectory with
named columns; latitude/longitude/height for wgs84). Heights are WGS84 ellipsoidal; orientations
are in grid axes (meridian convergence applied). See docs/georeference.md.
"""


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "export",
        help="write a run's map (LAZ/LAS/PCD/PLY) or trajectory (TUM/CSV) in UTM, EPSG:NNNN, ENU or WGS84",
        description="Export the map or trajectory of a georeferenced run in a coordinate reference system.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("run_dir", metavar="RUN_DIR", help="output folder of 'lidar3d run --span'")
    parser.add_argument(
        "--crs", required=True, metavar="CRS", help="utm (zone of the origin), EPSG:NNNN (projected), enu or wgs84"
    )
    parser.add_argument("--out", required=True, metavar="FILE", help="output file: .laz .las .pcd .ply .tum .csv")
    parser.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lidar3d.export.georef_export import export_run

    outcome = export_run(args.run_dir, args.crs, args.out)
    low, high = outcome.bounds_min, outcome.bounds_max
    what = "points" if outcome.kind == "map" else "poses"
    names = outcome.crs.axis_names
    print(f"{outcome.count} {what} in {outcome.crs.name} written to {outcome.out} ({outcome.seconds:.1f} s)")
    if outcome.count:
        print("bounds: " + ", ".join(f"{name} {lo:.3f} .. {hi:.3f}" for name, lo, hi in zip(names, low, high)))
    return 0
