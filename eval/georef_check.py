"""Measure the georeferencing targets of issue 19 on simulated drives (numbers for docs/georeference.md).

1. ``loop`` (~420 m): ``lidar3d run --span``, then ``lidar3d export --crs utm`` of the trajectory (TUM)
   and the map (LAZ, timed). The exported trajectory is compared with the simulator's ground truth
   converted independently (the simulator's PROJ topocentric pipeline to WGS84, then pyproj to UTM):
   horizontal and vertical RMSE. The LAZ file is opened with laspy (and PDAL when its Python package
   is importable): LAS version, CRS, point count, share of points within 60 m of the route.
2. ``city_traffic`` (~520 m with a 160 m walled canyon): ``lidar3d run --span LOG --gnss-factors``
   on a copy of the log with an unflagged 50 m jump (INS_SOLUTION_GOOD, 5 s inside the canyon). ATE
   against the ground truth of the lidar-only trajectory (``trajectory_lidar_only_tum.txt``) and of
   the fused one, the jump's epochs rejected, and the LAZ export time of its ~1,100-scan map.

Usage (from the repository root; each drive runs once, niced)::

    nice -n 10 .venv/bin/python eval/georef_check.py --out /tmp/georef_check

The simulated drives come from ``eval/cache/<scenario>_s0_full`` (``--cache``) when the suite has cached them, else
they are simulated into ``--out``. Results: ``--out/georef_check.json`` and a printed table.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from lidar3d.cli.main import main as lidar3d_main
from lidar3d.gnss.enu import GeodeticOrigin, LocalEnu
from lidar3d.io.trajectory_io import read_tum
from lidar3d.metrics.evaluation import evaluate_trajectory
from lidar3d.records import Trajectory
from lidar3d.sim.span import GeoOrigin, enu_to_geodetic, shift_positions

REPO = Path(__file__).resolve().parents[1]
JUMP_WINDOW_S = (45.0, 50.0)  # seconds after the log's first epoch: inside the canyon, GNSS good
JUMP_EAST_M = 50.0


CACHE = [REPO / "eval" / "cache"]


def _case(scenario: str, out: Path) -> Path:
    cached = CACHE[0] / f"{scenario}_s0_full"
    if (cached / "metadata.json").is_file():
        return cached
    from lidar3d.sim import simulate

    return simulate(scenario, out / f"sim_{scenario}", seed=0).out_dir


def _cli(*argv) -> None:
    code = lidar3d_main(["-q", *map(str, argv)])
    if code != 0:
        raise SystemExit(f"lidar3d {argv[0]} failed with exit code {code}")


def _sim_origin(case: Path) -> GeoOrigin:
    meta = json.loads((case / "metadata.json").read_text())["origin"]
    return GeoOrigin(meta["latitude_deg"], meta["longitude_deg"], meta["height_ellipsoid_m"])


def _truth_utm(case: Path, epsg: int) -> Trajectory:
    """Ground truth positions in UTM (converted independently of lidar3d.georef), as a Trajectory."""
    from pyproj import Transformer

    truth = read_tum(case / "ground_truth_tum.txt")
    lat, lon, h = enu_to_geodetic(truth.positions_m, _sim_origin(case))
    e, n = Transformer.from_crs("EPSG:4326", f"EPSG:{epsg}", always_xy=True).transform(lon, lat)
    poses = truth.T_world_lidar.copy()
    poses[:, :3, 3] = np.column_stack([e, n, h])
    return Trajectory(truth.stamps_ns, poses)


def _laz_check(path: Path, truth_xy: np.ndarray) -> dict:
    import laspy
    from scipy.spatial import cKDTree

    las = laspy.read(path)
    crs = las.header.parse_crs()
    xy = np.column_stack([las.x, las.y])
    distance, _ = cKDTree(truth_xy).query(xy[:: max(1, len(xy) // 200_000)])
    result = {
        "las_version": str(las.header.version),
        "point_format": las.header.point_format.id,
        "wkt_bit": bool(las.header.global_encoding.wkt),
        "crs_epsg": crs.to_epsg() if crs is not None else None,
        "crs_name": crs.name if crs is not None else None,
        "points": int(len(xy)),
        "within_60m_of_route": float(np.mean(distance < 60.0)),
        "pdal": "not importable (no PDAL wheel on PyPI for this platform, no Debian package in this image)",
    }
    try:
        import pdal

        pipeline = pdal.Reader.las(filename=str(path)).pipeline()
        pipeline.execute()
        result["pdal"] = f"read {len(pipeline.arrays[0])} points, srs {pipeline.srswkt2[:60]}..."
    except ImportError:
        pass
    return result


def _timed_run(case: Path, run: Path, span_log: Path, *options: str) -> float:
    """Wall seconds of ``lidar3d run`` on the case's bag with ``span_log`` and its extrinsics."""
    t0 = time.perf_counter()
    _cli(
        "run",
        case / "scans.bag",
        "--out",
        run,
        "--span",
        span_log,
        "--extrinsics",
        case / "extrinsics.toml",
        *options,
        "--overwrite",
    )
    return time.perf_counter() - t0


def _loop(out: Path) -> dict:
    case = _case("loop", out)
    run = out / "loop_run"
    run_s = _timed_run(case, run, case / "novatel_span.log")
    _cli("export", run, "--crs", "utm", "--out", out / "loop_trajectory.tum")
    t0 = time.perf_counter()
    _cli("export", run, "--crs", "utm", "--out", out / "loop_map.laz")
    laz_s = time.perf_counter() - t0
    rows = np.loadtxt(out / "loop_trajectory.tum", comments="#")
    truth = _truth_utm(case, 32632)
    exported = read_tum(run / "trajectory_tum.txt")
    index = np.searchsorted(truth.stamps_ns, exported.stamps_ns)
    assert (truth.stamps_ns[index] == exported.stamps_ns).all(), "ground truth lacks a scan stamp"
    error = rows[:, 1:4] - truth.positions_m[index]
    georef = json.loads((run / "georef.json").read_text())
    return {
        "scenario": "loop",
        "scans": len(exported),
        "path_m": float(np.linalg.norm(np.diff(truth.positions_m, axis=0), axis=1).sum()),
        "run_s": run_s,
        "georef_method": georef["method"],
        "georef_epochs": georef["epochs_used"],
        "georef_residual_m": georef["residual"],
        "utm_horizontal_rmse_m": float(np.sqrt(np.mean(np.sum(error[:, :2] ** 2, axis=1)))),
        "utm_vertical_rmse_m": float(np.sqrt(np.mean(error[:, 2] ** 2))),
        "utm_horizontal_max_m": float(np.linalg.norm(error[:, :2], axis=1).max()),
        "laz_export_s": laz_s,
        "laz": _laz_check(out / "loop_map.laz", truth.positions_m[:, :2]),
    }


def _jump_log(case: Path, out: Path) -> Path:
    lines = (case / "novatel_span.log").read_bytes().decode("ascii").splitlines(keepends=True)
    first = float(next(line for line in lines if line.startswith("#INSPVAXA")).split(",")[6])
    start, end = first + JUMP_WINDOW_S[0], first + JUMP_WINDOW_S[1]
    path = out / "city_traffic_jump.log"
    path.write_bytes("".join(shift_positions(lines, start, end, JUMP_EAST_M, 0.0)).encode("ascii"))
    return path


def _georeferenced_error(run: Path, trajectory: Trajectory, case: Path) -> float:
    """3-D RMSE with no alignment at all: the run's georef.json maps the trajectory to the truth's ENU."""
    georef = json.loads((run / "georef.json").read_text())
    T = np.asarray(georef["T_enu_world"])
    o = georef["origin"]
    p = trajectory.positions_m @ T[:3, :3].T + T[:3, 3]
    lat, lon, h = LocalEnu(GeodeticOrigin(o["latitude_deg"], o["longitude_deg"], o["height_ellipsoid_m"])).to_geodetic(
        p
    )
    sim = _sim_origin(case)
    p_sim = LocalEnu(GeodeticOrigin(sim.latitude_deg, sim.longitude_deg, sim.height_m)).to_enu(lat, lon, h)
    truth = read_tum(case / "ground_truth_tum.txt")
    index = np.searchsorted(truth.stamps_ns, trajectory.stamps_ns)
    return float(np.sqrt(np.mean(np.sum((p_sim - truth.positions_m[index]) ** 2, axis=1))))


def _city(out: Path) -> dict:
    case = _case("city_traffic", out)
    log = _jump_log(case, out)
    run = out / "city_fused_run"
    run_s = _timed_run(case, run, log, "--gnss-factors")
    t0 = time.perf_counter()
    _cli("export", run, "--crs", "utm", "--out", out / "city_map.laz")
    laz_s = time.perf_counter() - t0
    truth = read_tum(case / "ground_truth_tum.txt")
    result: dict = {"scenario": "city_traffic", "run_s": run_s, "laz_export_s": laz_s}
    for label, name in (("lidar_only", "trajectory_lidar_only_tum.txt"), ("fused", "trajectory_tum.txt")):
        trajectory = read_tum(run / name)
        evaluation = evaluate_trajectory(trajectory, truth, align="se3")
        result[label] = {
            "ate_se3_m": evaluation.ate.translation_3d_m.rmse,
            "ate_se3_max_m": evaluation.ate.translation_3d_m.max,
            "georeferenced_rmse_m": _georeferenced_error(run, trajectory, case),
        }
    georef = json.loads((run / "georef.json").read_text())
    factors = georef["gnss_factors"]
    stamps = np.asarray(factors["fused_stamps_ns"]) * 1e-9
    first_log_s = read_tum(case / "ground_truth_tum.txt").stamps_ns[0] * 1e-9
    summary = json.loads((run / "summary.json").read_text())
    result.update(
        scans=summary["scans"],
        map_points=summary["map_points"],
        fused_epochs=factors["fused_epochs"],
        rejected_consistency=factors["rejected_consistency"],
        candidates=factors["candidates"],
        fused_inside_jump=int(
            np.sum((stamps >= first_log_s + JUMP_WINDOW_S[0]) & (stamps < first_log_s + JUMP_WINDOW_S[1]))
        ),
        warnings=summary["warnings"],
    )
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="working folder")
    parser.add_argument("--only", choices=("loop", "city_traffic"), help="run one of the two")
    parser.add_argument("--cache", type=Path, default=CACHE[0], help="the suite's cache of simulated drives")
    args = parser.parse_args()
    CACHE[0] = args.cache
    args.out.mkdir(parents=True, exist_ok=True)
    results = {}
    if args.only in (None, "loop"):
        results["loop"] = _loop(args.out)
        print(json.dumps(results["loop"], indent=2))
    if args.only in (None, "city_traffic"):
        results["city_traffic"] = _city(args.out)
        print(json.dumps(results["city_traffic"], indent=2))
    (args.out / "georef_check.json").write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
