"""Dynamic-object removal and the occupancy grid measured on the simulator's drives (issue 20).

Removal (``--removal SCENARIO...``, default the scenarios with traffic): every sweep is simulated
with what each point hit; the filter decides its points twice, once placed with the exact poses
(each point with the true pose at its firing time: the oracle) and once with the poses of a
``lidar3d run`` on the same drive. Each decision is then scored on the points' TRUE positions at
0.2 m voxels: a voxel that only moving objects occupied is *removed* when no point of it stayed in
the static map, a voxel with a static point is *kept* when one of its static points stayed. The
removal is also given by the nearest range a moving voxel was seen from (0-20, 20-40, 40+ m: beyond
40 m the VLP-16's rings are more than 1.4 m apart, and a later ray passes within the pass tolerance
of a voxel seen there only by chance).

Grid (``--grid SCENARIO...``, default loop and hilly): ``lidar3d run`` then ``lidar3d grid`` on the
drive; scored against the true obstacles: the points the simulator's exact rays hit on static
objects inside the band above the TRUE terrain, as 2-D cells (moved into the run's frame by the first
pose). Precision: occupied cells within 40 m of the path that lie within one cell (also: two cells)
of a true obstacle cell; recall: true obstacle cells within 25 m of the path that are occupied
within one cell (two cells); path free: cells of the driven path (true lidar positions) that are
free. The grid is made from lidar3d's poses, so their error (ATE) counts against it.

    .venv/bin/python eval/dynamic_removal.py --duration 30 --out eval/results/dynamic
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from lidar3d.config import Config  # noqa: E402
from lidar3d.io.trajectory_io import read_tum  # noqa: E402
from lidar3d.mapping.deskew import deskew_scan, twist_between  # noqa: E402
from lidar3d.mapping.free_space import DynamicFilter, PlacedSweep, outvoted_voxels  # noqa: E402
from lidar3d.mapping.se3 import invert, transform_points  # noqa: E402
from lidar3d.mapping.voxel import voxel_keys  # noqa: E402
from lidar3d.sim import DYNAMIC_CLASSES, Simulation, write_simulation  # noqa: E402

VOXEL_M = 0.2
RANGE_BANDS_M = (0.0, 20.0, 40.0, np.inf)  # the removal is also reported by the range a voxel was seen from


def _decide(config: Config, placed: list[PlacedSweep]) -> np.ndarray:
    """Per point (all sweeps concatenated): removed from the static map (filter, then the vote)."""
    model = config.sensor.resolved_model
    dynamic_filter = DynamicFilter(config.dynamic, model.elevation_deg, model.n_columns)
    flags = []
    for sweep in placed:
        flags += [d.dynamic for d in dynamic_filter.add(sweep)]
    flags += [d.dynamic for d in dynamic_filter.flush()]
    dynamic = np.concatenate(flags)
    keys = voxel_keys(np.concatenate([s.points_world for s in placed]), config.mapping.map_voxel_m)
    static_keys, static_counts = np.unique(keys[~dynamic], return_counts=True)
    dynamic_keys, dynamic_counts = np.unique(keys[dynamic], return_counts=True)
    outvoted = outvoted_voxels(static_keys, static_counts, dynamic_keys, dynamic_counts, config.dynamic.vote_ratio)
    return dynamic | np.isin(keys, outvoted)


def _removed_by_range(keys: np.ndarray, seen_from_m: np.ndarray, dynamic_only: np.ndarray, stayed: np.ndarray) -> dict:
    """Share of the dynamic-only voxels removed, by the nearest range (m) any of their points was
    seen from: {band: [voxels, removed share]} for the bands of ``RANGE_BANDS_M``."""
    inside = np.isin(keys, dynamic_only)
    voxels, inverse = np.unique(keys[inside], return_inverse=True)
    nearest = np.full(voxels.size, np.inf)
    np.minimum.at(nearest, inverse, seen_from_m[inside])
    left = np.isin(voxels, stayed)
    bands = {}
    for low, high in itertools.pairwise(RANGE_BANDS_M):
        band = (nearest >= low) & (nearest < high)
        name = f"{low:g}-{high:g}" if np.isfinite(high) else f"{low:g}+"
        bands[name] = [int(band.sum()), round(float(1.0 - left[band].mean()), 4) if band.any() else None]
    return bands


def _score(true_world: np.ndarray, moving: np.ndarray, removed: np.ndarray, seen_from_m: np.ndarray) -> dict:
    """Removal and keeping scored on the points' TRUE positions (N,3) at ``VOXEL_M`` voxels;
    ``seen_from_m`` (N,): each point's range from the sensor as it fired the point."""
    keys = voxel_keys(true_world, VOXEL_M)
    static = np.unique(keys[~moving])
    dynamic_only = np.setdiff1d(np.unique(keys[moving]), static)
    stayed = np.unique(keys[~removed])
    stayed_static = np.unique(keys[~removed & ~moving])
    return {
        "dynamic_only_voxels": int(dynamic_only.size),
        "dynamic_removed": round(float(1.0 - np.isin(dynamic_only, stayed).mean()), 4) if dynamic_only.size else None,
        "dynamic_removed_by_range_m": _removed_by_range(keys, seen_from_m, dynamic_only, stayed),
        "static_voxels": int(static.size),
        "static_kept": round(float(np.isin(static, stayed_static).mean()), 4) if static.size else None,
        "points_removed": int(removed.sum()),
        "points": int(removed.size),
    }


def removal(scenario: str, seed: int, duration_s: float | None, work: Path) -> dict:
    config = Config()
    sim = Simulation(scenario, seed=seed, duration_s=duration_s)
    out = write_simulation(sim, work / f"{scenario}_sim", overwrite=True)
    from lidar3d.run import run_bag

    t0 = time.perf_counter()
    run_bag(out.bag, work / f"{scenario}_run", config, prefetch=False, overwrite=True)
    run_s = time.perf_counter() - t0
    trajectory = read_tum(work / f"{scenario}_run" / "trajectory_tum.txt")
    stamps, poses = trajectory.stamps_ns, trajectory.T_world_lidar
    T_true_run = sim.ground_truth.T_world_lidar[0] @ invert(poses[0])
    exact, estimated, true_world, moving, seen_from = [], [], [], [], []
    for simulated in sim.scans():
        i = int(np.searchsorted(stamps, simulated.scan.stamp_ns))
        if i >= len(stamps) or stamps[i] != simulated.scan.stamp_ns:
            continue
        a, b = (i, i + 1) if i + 1 < len(stamps) else (i - 1, i)
        final = deskew_scan(simulated.scan, twist_between(poses[a], poses[b], (stamps[b] - stamps[a]) * 1e-9))
        r = np.linalg.norm(final.points, axis=1)
        keep = (r >= config.sensor.min_range_m) & (r <= config.sensor.resolved_model.max_range_m)
        world = sim.points_world(simulated)[keep]
        T = simulated.T_world_lidar
        local = (world - T[:3, 3]) @ T[:3, :3]
        ring, intensity = simulated.scan.ring[keep], simulated.scan.intensity[keep]
        exact.append(PlacedSweep(local, world, ring, intensity, T))
        estimated.append(
            PlacedSweep(final.points[keep], transform_points(poses[i], final.points[keep]), ring, intensity, poses[i])
        )
        true_world.append(world)
        seen_from.append(np.linalg.norm(simulated.scan.points[keep], axis=1))  # from where the sensor fired it
        moving.append(np.isin(simulated.object_class[keep], [int(c) for c in DYNAMIC_CLASSES]))
    true_all, moving_all, seen_all = np.concatenate(true_world), np.concatenate(moving), np.concatenate(seen_from)
    t0 = time.perf_counter()
    exact_removed = _decide(config, exact)
    filter_s = time.perf_counter() - t0
    result = {
        "scenario": scenario,
        "seed": seed,
        "scans": len(exact),
        "exact_poses": _score(true_all, moving_all, exact_removed, seen_all),
        "lidar3d_poses": _score(true_all, moving_all, _decide(config, estimated), seen_all),
        "run_s": round(run_s, 1),
        "filter_s_exact": round(filter_s, 2),
        "T_true_run_translation_m": [round(v, 3) for v in T_true_run[:3, 3]],
    }
    return result


def grid(scenario: str, seed: int, duration_s: float | None, work: Path) -> dict:
    from scipy import ndimage

    from lidar3d.grid import grid_run
    from lidar3d.run import run_bag

    sim = Simulation(scenario, seed=seed, duration_s=duration_s)
    out = write_simulation(sim, work / f"{scenario}_gsim", overwrite=True)
    run_dir = work / f"{scenario}_grun"
    run_bag(out.bag, run_dir, prefetch=False, overwrite=True)
    t0 = time.perf_counter()
    outcome = grid_run(run_dir, work / f"{scenario}_grid")
    grid_s = time.perf_counter() - t0
    trajectory = read_tum(run_dir / "trajectory_tum.txt")
    T_run_true = trajectory.T_world_lidar[0] @ invert(sim.ground_truth.T_world_lidar[0])
    low, high = 0.3, 2.0
    truth = []
    for simulated in sim.scans():
        static = ~np.isin(simulated.object_class, [int(c) for c in DYNAMIC_CLASSES]) & (simulated.object_id != 0)
        world = sim.points_world(simulated)[static]
        height = world[:, 2] - sim.world.terrain.height_m(world[:, 0], world[:, 1])
        truth.append(world[(height >= low) & (height <= high)])
    truth_run = transform_points(T_run_true, np.concatenate(truth))
    g = outcome.grid
    true_cells = np.zeros(g.log_odds.shape, bool)
    i, j, inside = g.cell_of(truth_run[:, :2])
    true_cells[i[inside], j[inside]] = True
    near_truth = ndimage.binary_dilation(true_cells, iterations=1)
    occupied = g.observed & (g.probability > 0.65)
    near_occupied = ndimage.binary_dilation(occupied, iterations=1)
    near_truth_2 = ndimage.binary_dilation(true_cells, iterations=2)
    near_occupied_2 = ndimage.binary_dilation(occupied, iterations=2)
    centres = g.origin_xy_m + (np.indices(g.log_odds.shape).reshape(2, -1).T + 0.5) * g.resolution_m
    true_path = transform_points(T_run_true, sim.ground_truth.T_world_lidar[:, :3, 3])[:, :2]
    from scipy.spatial import cKDTree

    distance = cKDTree(true_path).query(centres, distance_upper_bound=41.0)[0].reshape(g.log_odds.shape)
    within40, within25 = distance <= 40.0, distance <= 25.0
    pi, pj, pin = g.cell_of(true_path)
    free = g.observed & (g.probability < 0.196)
    return {
        "scenario": scenario,
        "seed": seed,
        "scans": outcome.scans,
        "grid_s": round(grid_s, 1),
        "precision_40m": round(float(near_truth[occupied & within40].mean()), 4),
        "recall_25m": round(float(near_occupied[true_cells & within25].mean()), 4),
        "path_free": round(float(free[pi[pin], pj[pin]].mean()), 4),
        "precision_40m_2cells": round(float(near_truth_2[occupied & within40].mean()), 4),
        "recall_25m_2cells": round(float(near_occupied_2[true_cells & within25].mean()), 4),
        "occupied_cells_40m": int((occupied & within40).sum()),
        "true_cells_25m": int((true_cells & within25).sum()),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--removal", nargs="*", default=["city_traffic", "forest_trail"], metavar="SCENARIO")
    parser.add_argument("--grid", nargs="*", default=["loop", "hilly"], metavar="SCENARIO")
    parser.add_argument("--duration", type=float, default=None, metavar="S", help="first S seconds of each drive")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=REPO / "eval" / "results" / "dynamic", metavar="DIR")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    results: dict = {"duration_s": args.duration, "removal": [], "grid": []}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.removal:
            results["removal"].append(removal(name, args.seed, args.duration, Path(tmp)))
            print(json.dumps(results["removal"][-1]), flush=True)
        for name in args.grid:
            results["grid"].append(grid(name, args.seed, args.duration, Path(tmp)))
            print(json.dumps(results["grid"][-1]), flush=True)
    (args.out / "dynamic_removal.json").write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
