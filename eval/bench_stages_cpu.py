"""CPU time per pipeline stage of a whole ``run_bag``, for before/after comparisons on a busy machine.

Runs :func:`lidar3d.run.run_bag` on the first ``--scans`` scans of a bag with the front end in the
same process (``prefetch=False``) and every stage timer measuring this thread's CPU time
(``time.thread_time``) instead of the wall clock, so that other processes competing for the cores
disturb the figures much less than they disturb wall time (they still share caches: compare
versions alternately in one session, never against figures of another day). Prints one JSON line:
the run's CPU seconds, the median and the sum of each stage, and the front end's five stages summed
per scan. The outputs land in ``--out`` (the trajectory can be compared byte for byte).

Usage (docs/performance.md)::

    .venv/bin/python eval/bench_stages_cpu.py eval/cache/loop_s0_full/scans.bag --scans 250 --out /tmp/a
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("bag", type=Path)
    parser.add_argument("--scans", type=int, default=250, help="first N scans (default 250; 0: all)")
    parser.add_argument("--out", type=Path, required=True, help="run folder (overwritten)")
    args = parser.parse_args(argv)

    time.perf_counter = time.thread_time  # every stage clock (and the checkpoint interval) in CPU time
    import numpy as np

    from lidar3d.features.frontend import STAGES as FRONT_END_STAGES
    from lidar3d.run import run_bag

    t0 = time.thread_time()
    outcome = run_bag(args.bag, args.out, max_scans=args.scans or None, overwrite=True, prefetch=False)
    cpu_s = time.thread_time() - t0
    timings = {name: np.asarray(ms) for name, ms in outcome.result.timings_ms.items()}
    front_end = np.sum([timings[name] for name in FRONT_END_STAGES if name in timings], axis=0)
    record = {
        "bag": str(args.bag),
        "scans": outcome.summary.scans,
        "cpu_s": round(cpu_s, 2),
        "median_ms": {name: round(float(np.median(ms)), 2) for name, ms in timings.items()}
        | {"front_end": round(float(np.median(front_end)), 2)},
        "sum_s": {name: round(float(ms.sum()) / 1e3, 2) for name, ms in timings.items()},
    }
    print(json.dumps(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
