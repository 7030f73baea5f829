"""Check that a change leaves lidar3d's estimates as they were: run, then compare two runs.

A refactoring promises identical behaviour. This script records, for each scenario, the exact
poses ``lidar3d run`` produced (refined trajectory, odometry and keyframes, as float64 ``.npy``,
not the rounded text files), and compares two such records pose by pose::

    # at the commit before the change (e.g. in a git worktree of it):
    PYTHONPATH=. .venv/bin/python eval/trajectory_identity.py run --out /tmp/before
    # at the commit after it:
    .venv/bin/python eval/trajectory_identity.py run --out /tmp/after
    .venv/bin/python eval/trajectory_identity.py compare /tmp/before /tmp/after

``--no-loop`` runs odometry and mapping alone. ``compare`` prints the largest position (m) and
rotation (rad) difference per scenario and file and exits 1 when any exceeds ``--tolerance-m``
(default 1e-9 m; rotations are held to the same number in radians) or when the pose counts or
stamps differ.

The scenarios (default ``loop hilly fast``, full length, seed 0) are taken from the evaluation
suite's simulation cache (``eval/cache``, see ``suite_cache.py``), so both runs see the same bags.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

RECORDS = ("trajectory", "odometry", "keyframes")


def _run(args: argparse.Namespace) -> int:
    import dataclasses

    from suite_cache import DEFAULT_CACHE, ensure_scenario

    import lidar3d
    from lidar3d.config import Config
    from lidar3d.run import run_bag

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    print(f"lidar3d from {Path(lidar3d.__file__).parent}", flush=True)
    for name in args.scenarios:
        cached = ensure_scenario(name, args.seed, args.duration, cache_dir=Path(args.cache or DEFAULT_CACHE))
        run_dir = out / name
        config = Config()
        if args.no_loop:
            config = dataclasses.replace(config, loop=dataclasses.replace(config.loop, enabled=False))
        outcome = run_bag(cached.bag, run_dir, config=config, prefetch=False, overwrite=True)
        result = outcome.result
        for record in RECORDS:
            trajectory = getattr(result, record)
            np.save(run_dir / f"{record}_stamps_ns.npy", trajectory.stamps_ns)
            np.save(run_dir / f"{record}_T.npy", trajectory.T_world_lidar)
        counts = {"scans": len(result.trajectory), "keyframes": len(result.keyframes)}
        (run_dir / "identity.json").write_text(json.dumps(counts) + "\n", encoding="utf-8")
        print(f"{name}: {counts['scans']} scans, {counts['keyframes']} keyframes -> {run_dir}", flush=True)
    return 0


def _rotation_angle_rad(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """(N,) angle between (N,3,3) rotations, ``||Ra - Rb||_F / sqrt(2)``: the angle of
    ``Ra^T Rb`` to first order, and, unlike ``arccos`` of its trace, exact near zero (the trace
    form cannot resolve angles below ~1e-8 rad in float64)."""
    return np.linalg.norm(Ra - Rb, axis=(1, 2)) / np.sqrt(2.0)


def _compare(args: argparse.Namespace) -> int:
    a_root, b_root = Path(args.before), Path(args.after)
    worst = 0.0
    failed = False
    names = sorted(p.name for p in a_root.iterdir() if (p / "identity.json").is_file())
    if not names:
        print(f"{a_root}: no recorded scenario", file=sys.stderr)
        return 1
    for name in names:
        for record in RECORDS:
            paths = [root / name / f"{record}_{{}}.npy" for root in (a_root, b_root)]
            if not all(Path(str(p).format("T")).is_file() for p in paths):
                print(f"{name} {record}: missing in one of the runs")
                failed = True
                continue
            stamps_a, stamps_b = (np.load(str(p).format("stamps_ns")) for p in paths)
            Ta, Tb = (np.load(str(p).format("T")) for p in paths)
            if len(stamps_a) != len(stamps_b) or np.any(stamps_a != stamps_b):
                print(f"{name} {record}: poses differ in number or stamps ({len(stamps_a)} vs {len(stamps_b)})")
                failed = True
                continue
            dpos = float(np.max(np.linalg.norm(Ta[:, :3, 3] - Tb[:, :3, 3], axis=1))) if len(Ta) else 0.0
            drot = float(np.max(_rotation_angle_rad(Ta[:, :3, :3], Tb[:, :3, :3]))) if len(Ta) else 0.0
            worst = max(worst, dpos, drot)
            ok = dpos <= args.tolerance_m and drot <= args.tolerance_m
            failed |= not ok
            verdict = "ok" if ok else "DIFFERENT"
            print(
                f"{name:>6} {record:<10} {len(Ta):5d} poses  max |dp| {dpos:.3e} m  max |dR| {drot:.3e} rad  {verdict}"
            )
    print(f"largest difference {worst:.3e}; {'FAILED' if failed else 'identical within'} {args.tolerance_m:g}")
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run lidar3d on the scenarios and record its exact poses")
    run.add_argument("--out", required=True, help="folder for the records (one subfolder per scenario)")
    run.add_argument("--scenarios", nargs="+", default=["loop", "hilly", "fast"])
    run.add_argument("--seed", type=int, default=0)
    run.add_argument("--duration", type=float, default=None, help="first seconds only (default: full length)")
    run.add_argument("--cache", default=None, help="simulation cache folder (default: eval/cache)")
    run.add_argument("--no-loop", action="store_true", help="loop closure off (odometry and mapping alone)")
    run.set_defaults(func=_run)
    compare = sub.add_parser("compare", help="compare two records pose by pose")
    compare.add_argument("before")
    compare.add_argument("after")
    compare.add_argument("--tolerance-m", type=float, default=1e-9)
    compare.set_defaults(func=_compare)
    args = parser.parse_args(argv)
    return int(args.func(args))


if __name__ == "__main__":
    raise SystemExit(main())
