"""The dense map after loop closure: placed again from its keyframe pieces vs rebuilt from the bag (issue 17).

One ``SlamPipeline`` run over a simulated drive with loop closures (its pieces spilled to disk, as
``lidar3d run`` does); then, on the same final trajectory, the map is also rebuilt the way it was
before pieces existed: every scan read from the bag again, deskewed, placed with its corrected pose
and filtered for moving objects again. Both maps are scored against the *truth map*: the same bag
placed with the simulator's true poses (aligned onto the run's trajectory, SE(3) Umeyama), through
the same dense map and dynamic filter. Per map: the distance of each map point to the nearest
truth-map point (median, p90, p99, share beyond 0.5 m), the distance of each truth-map point to the
map (its coverage), and the point counts; and the distance between the two maps both ways. Times:
the placement (``SlamResult.map_rebuild_s``) against the rebuild, in the same process.

    .venv/bin/python eval/map_placement.py eval/cache/loop_s0_full [--max-scans N] [--json OUT]

The folder is a simulated drive (``lidar3d simulate`` or the evaluation cache): ``scans.bag`` and
``ground_truth_tum.txt``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from lidar3d.config import Config  # noqa: E402
from lidar3d.io.piece_spill import SpilledPieceStore  # noqa: E402
from lidar3d.io.scan_source import open_scan_source  # noqa: E402
from lidar3d.io.trajectory_io import read_tum  # noqa: E402
from lidar3d.mapping.dense_map import build_dense_map  # noqa: E402
from lidar3d.metrics.alignment import umeyama_se3  # noqa: E402
from lidar3d.pipeline import SlamPipeline, SpillStores  # noqa: E402
from lidar3d.prefetch import open_prepared_scans  # noqa: E402
from lidar3d.records import Trajectory  # noqa: E402


def _distances(points: np.ndarray, to: cKDTree) -> dict:
    d = to.query(points)[0]
    return {
        "median_m": round(float(np.median(d)), 4),
        "p90_m": round(float(np.quantile(d, 0.9)), 4),
        "p99_m": round(float(np.quantile(d, 0.99)), 4),
        "beyond_0.5m": round(float(np.mean(d > 0.5)), 5),
    }


def _scores(name: str, points: np.ndarray, n_dynamic: int, truth_points: np.ndarray, truth_tree: cKDTree) -> dict:
    """The scores of a static map ``points`` (M,3) whose dynamic map holds ``n_dynamic`` points."""
    return {
        "map": name,
        "static_points": len(points),
        "dynamic_points": n_dynamic,
        "to_truth": _distances(points, truth_tree),
        "truth_coverage": _distances(truth_points, cKDTree(points)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("drive", type=Path, help="simulated drive folder (scans.bag, ground_truth_tum.txt)")
    parser.add_argument("--max-scans", type=int)
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args()
    bag = args.drive / "scans.bag"
    config = Config()
    t0 = time.perf_counter()
    with SpilledPieceStore() as store:
        pipeline = SlamPipeline(config, SpillStores(pieces=store))
        with open_prepared_scans([bag], config, max_scans=args.max_scans) as stream:
            for prepared, _ in stream:
                pipeline.process(prepared)
        pipeline.finish()
        spilled_mb = store.nbytes / 1e6
        n_pieces = len(store)
    result = pipeline.result()
    run_s = time.perf_counter() - t0
    n = len(result.trajectory)
    print(f"run: {n} scans, {result.counts.get('loop_closures', 0)} loop closures, {run_s:.1f} s", file=sys.stderr)
    if result.map_rebuild_s is None:
        raise SystemExit(f"{bag}: no loop closure in this drive, nothing to place again")

    t0 = time.perf_counter()
    with open_scan_source([bag], config) as source:
        rebuilt = build_dense_map(itertools.islice(source, n), result.trajectory, config)
    rebuild_s = time.perf_counter() - t0

    truth = read_tum(args.drive / "ground_truth_tum.txt")
    at = np.searchsorted(truth.stamps_ns, result.trajectory.stamps_ns)
    truth = Trajectory(truth.stamps_ns[at], truth.T_world_lidar[at])
    T_run_truth = umeyama_se3(truth.positions_m, result.trajectory.positions_m)
    truth = Trajectory(truth.stamps_ns, T_run_truth @ truth.T_world_lidar)
    with open_scan_source([bag], config) as source:
        truth_map = build_dense_map(itertools.islice(source, n), truth, config)
    truth_points = truth_map.static.points_and_intensity()[0]
    truth_tree = cKDTree(truth_points)

    placed_points = result.map_points
    rebuilt_points = rebuilt.static.points_and_intensity()[0]
    ate = np.linalg.norm(result.trajectory.positions_m - truth.positions_m, axis=1)
    report = {
        "drive": str(args.drive),
        "scans": n,
        "keyframes": len(result.keyframes),
        "loop_closures": int(result.counts.get("loop_closures", 0)),
        "ate_rmse_m": round(float(np.sqrt(np.mean(ate**2))), 4),
        "run_s": round(run_s, 1),
        "placed_again_s": result.map_rebuild_s,
        "rebuilt_from_bag_s": round(rebuild_s, 3),
        "pieces": n_pieces,
        "spilled_mb": round(spilled_mb, 1),
        "maps": [
            _scores("placed from pieces", placed_points, len(result.dynamic_points), truth_points, truth_tree),
            _scores("rebuilt from the bag", rebuilt_points, len(rebuilt.dynamic), truth_points, truth_tree),
        ],
        "placed_to_rebuilt": _distances(placed_points, cKDTree(rebuilt_points)),
        "rebuilt_to_placed": _distances(rebuilt_points, cKDTree(placed_points)),
        "truth_static_points": len(truth_points),
    }
    text = json.dumps(report, indent=1)
    print(text)
    if args.json is not None:
        args.json.write_text(text + "\n")


if __name__ == "__main__":
    main()
