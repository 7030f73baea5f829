"""One method on one bag, in its own process: the unit of work of ``eval/run_suite.py``.

The suite starts this script once per (scenario, seed, method), so that each run's peak resident
memory is its own and no run inherits another's caches. The peak is the process's ``VmHWM``
(recorded in ``run.json``; see :func:`vm_hwm_kib`), with the parent's ``os.wait4`` ``ru_maxrss``
kept beside it.
It writes into ``--out``:

* ``trajectory_tum.txt``: the method's poses, each stamped at the instant it describes
  (lidar3d: the header stamp, i.e. sweep start; peers: see :mod:`suite_peers`);
* ``run.json``: scans, wall time, per-stage timing (mean, median, p95 ms/scan), counts, settings.

lidar3d runs through :func:`lidar3d.run.run_bag` (its usual outputs land in the same folder).
Usage (normally called by the suite)::

    .venv/bin/python eval/suite_worker.py --method lidar3d --bag eval/cache/loop_s0_full/scans.bag --out /tmp/x
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
for entry in (str(REPO), str(HERE)):
    if entry not in sys.path:
        sys.path.insert(0, entry)

METHODS = ("lidar3d", "kiss-icp", "genz-icp")


def vm_hwm_kib() -> int | None:
    """This process's peak resident set (``VmHWM`` of ``/proc/self/status``, KiB), or None off Linux.

    Unlike ``ru_maxrss``, which after fork + exec starts from the parent's resident size at the
    fork (the kernel carries the old address space's high-water mark over the exec), ``VmHWM``
    belongs to the address space the exec created, so it is this program's own peak.
    """
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


def _stage_stats(samples_ms: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    out = {}
    for name, values in samples_ms.items():
        v = np.asarray(values, dtype=np.float64)
        if v.size:
            out[name] = {
                "mean": round(float(v.mean()), 3),
                "median": round(float(np.median(v)), 3),
                "p95": round(float(np.percentile(v, 95)), 3),
                "n": int(v.size),
            }
    return out


def run_lidar3d(bag: Path, out: Path, max_scans: int | None, loop_closure: bool = True, start: int = 0) -> dict:
    import dataclasses

    from lidar3d.config import Config
    from lidar3d.features.frontend import STAGES as FRONT_END_STAGES
    from lidar3d.run import run_bag

    config = Config()
    if not loop_closure:
        config = dataclasses.replace(config, loop=dataclasses.replace(config.loop, enabled=False))
    outcome = run_bag(bag, out, start=start, max_scans=max_scans, config=config, overwrite=True)
    summary = outcome.summary
    timings = {k: np.asarray(v) for k, v in outcome.result.timings_ms.items()}
    front_end = [timings[name] for name in FRONT_END_STAGES if name in timings]
    per_scan = {"front_end": np.sum(front_end, axis=0)} if front_end else {}
    return {
        "method": "lidar3d",
        "scans": summary.scans,
        "wall_s": summary.runtime_s,
        "scans_per_s": summary.scans_per_s,
        "stage_ms": _stage_stats(timings),
        # per scan, the front-end stages summed (they run in the prefetch process, beside the others)
        "composite_ms": _stage_stats(per_scan),
        "stage_ms_median_summary": summary.stage_ms_median.as_dict(),
        "counts": summary.counts.as_dict(),
        "loop_ms_total": summary.loop_ms_total,
        "keyframes": summary.keyframes,
        "warnings": list(summary.warnings),
        "health": summary.health.as_dict() if summary.health is not None else None,
        "pose_instant": "header stamp (sweep start)",
        "settings": {
            "config": "lidar3d defaults (see config.toml)" + ("" if loop_closure else ", loop closure off"),
            "start": start,
        },
    }


def run_peer_method(method: str, bag: Path, out: Path, max_scans: int | None, genz_deskew: bool) -> dict:
    from suite_peers import run_peer

    from lidar3d.io.trajectory_io import write_tum
    from lidar3d.records import Trajectory

    run = run_peer(method, bag, max_scans=max_scans, genz_deskew=genz_deskew)
    write_tum(out / "trajectory_tum.txt", Trajectory(run.stamps_ns, run.T_world_lidar))
    n = int(len(run.stamps_ns))
    offsets_ms = (run.stamps_ns - run.header_stamps_ns) * 1e-6
    return {
        "method": method,
        "scans": n,
        "wall_s": round(run.wall_s, 3),
        "scans_per_s": round(n / run.wall_s, 2) if run.wall_s > 0 else 0.0,
        "stage_ms": _stage_stats({"read": run.read_ms, "register": run.register_ms}),
        "counts": {"scans": n},
        "pose_instant": f"sweep fraction {run.reference_fraction:g} (0 = start, 1 = end)",
        "pose_offset_ms_median": round(float(np.median(offsets_ms)), 3) if n else None,
        "reference_fraction": run.reference_fraction,
        "settings": run.settings,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--method", choices=METHODS, required=True)
    parser.add_argument("--bag", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--max-scans", type=int, default=None)
    parser.add_argument("--genz-no-deskew", action="store_true", help="run GenZ-ICP with its preset's deskew off")
    parser.add_argument("--no-loop", action="store_true", help="run lidar3d with loop closure off")
    parser.add_argument("--start", type=int, default=0, help="lidar3d skips the bag's first N scans")
    args = parser.parse_args(argv)

    import logging

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    if args.method == "lidar3d":
        record = run_lidar3d(args.bag, args.out, args.max_scans, loop_closure=not args.no_loop, start=args.start)
    else:
        record = run_peer_method(args.method, args.bag, args.out, args.max_scans, not args.genz_no_deskew)
    record["process_s"] = round(time.perf_counter() - t0, 3)
    record["self_maxrss_kib"] = int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
    record["vm_hwm_kib"] = vm_hwm_kib()
    tmp = args.out / "run.json.tmp"
    tmp.write_text(json.dumps(record, indent=1, default=float) + "\n", encoding="utf-8")
    tmp.replace(args.out / "run.json")
    return 0


if __name__ == "__main__":
    sys.exit(main())
