"""Wrong loop closures injected into a run: how far do they move the trajectory? (issue 16 target:
10 % of closures wrong by 2-20 m move the ATE by less than 5 cm).

Each drive runs twice in-process on its cached ``make bench`` bag, loop closure on, the same
configuration otherwise:

1. clean: the accepted closures are counted (``M``);
2. injected, once per ``--seeds`` value: ``max(1, round(fraction * M))`` of the accepted
   verifications, chosen at random by the seed among the first ``M``, have their measured
   relative pose ``T_match_query`` shifted by a random horizontal offset of 2-20 m (uniform
   length, uniform direction) before the loop closer sees them: a perceptual alias that passed
   every ICP gate (fitness, overlap, correction). The consistency checks, the pose graph's Huber
   loss and its outlier test then do what they do.

The ATE (SE(3)-aligned, against the simulator's ground truth) of both runs and their difference are
printed and written to ``--out`` as JSON. The injection wraps the verification of one
:class:`Injector` standing in for ``lidar3d.loop.closer._verify`` during the run; nothing in ``lidar3d`` changes.

Usage (from the repository root)::

    nice -n 10 .venv/bin/python eval/loop_injection.py --scenarios loop hilly --out /tmp/injection.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE.parent) not in sys.path:
    sys.path.insert(0, str(HERE.parent))

from lidar3d.config import Config  # noqa: E402
from lidar3d.io.scan_source import open_scan_source  # noqa: E402
from lidar3d.io.trajectory_io import read_tum  # noqa: E402
from lidar3d.loop import closer as closer_module  # noqa: E402
from lidar3d.loop.records import LoopCandidate  # noqa: E402
from lidar3d.metrics.evaluation import evaluate_trajectory  # noqa: E402
from lidar3d.pipeline import SlamPipeline  # noqa: E402

__all__ = ["Injector", "main", "run_drive"]

OFFSET_RANGE_M = (2.0, 20.0)


class Injector:
    """Stands in for the loop closer's verification (``lidar3d.loop.closer._verify``) during a run:
    the accepted verifications number ``corrupt`` (0-based, in acceptance order) come out with
    ``T_match_query`` shifted by the matching horizontal offset."""

    def __init__(self, corrupt: dict[int, np.ndarray]) -> None:
        self._corrupt = corrupt
        self._verify = closer_module._verify
        self.n_verified_accepted = 0
        self.injected: list[tuple[int, int, float]] = []  # (query, match, offset length m)

    def __call__(self, *args, **kwargs) -> LoopCandidate:
        record = self._verify(*args, **kwargs)
        if not record.accepted:
            return record
        number = self.n_verified_accepted
        self.n_verified_accepted += 1
        offset = self._corrupt.get(number)
        if offset is None:
            return record
        T = record.T_match_query.copy()
        T[:3, 3] += offset
        self.injected.append((record.query, record.match, float(np.linalg.norm(offset))))
        return dataclasses.replace(record, T_match_query=T)


def run_drive(bag: Path, corrupt: dict[int, np.ndarray]) -> tuple[object, Injector]:
    """Run the pipeline on ``bag`` with loop closure on, its verifications passed through an
    :class:`Injector` of ``corrupt``; returns (result, the injector)."""
    config = Config()
    injector = Injector(corrupt)
    closer_module._verify = injector
    try:
        pipeline = SlamPipeline(config)
        with open_scan_source(bag, config) as source:
            for _, scan in source.scans():
                pipeline.process(scan)
        pipeline.finish()
        return pipeline.result(), injector
    finally:
        closer_module._verify = injector._verify


def _ate_m(result, truth) -> float:
    return float(evaluate_trajectory(result.trajectory, truth, align="se3").ate.translation_3d_m.rmse)


def _offsets(rng: np.random.Generator, count: int, among: int) -> dict[int, np.ndarray]:
    chosen = rng.choice(among, size=min(count, among), replace=False)
    offsets = {}
    for number in sorted(int(c) for c in chosen):
        length = rng.uniform(*OFFSET_RANGE_M)
        heading = rng.uniform(0.0, 2.0 * np.pi)
        offsets[number] = np.array([length * np.cos(heading), length * np.sin(heading), 0.0])
    return offsets


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenarios", nargs="+", default=["loop", "hilly"])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="one injected run per seed")
    parser.add_argument("--fraction", type=float, default=0.1, help="share of the accepted closures corrupted")
    parser.add_argument("--cache", type=Path, default=HERE / "cache", help="the suite's cached drives")
    parser.add_argument("--out", type=Path, default=None, help="write the results as JSON here")
    args = parser.parse_args(argv)
    rows = []
    for scenario in args.scenarios:
        case = args.cache / f"{scenario}_s0_full"
        if not (case / "scans.bag").is_file():
            print(f"{case}: no cached drive (run make bench first)", file=sys.stderr)
            return 1
        truth = read_tum(case / "ground_truth_tum.txt")
        clean, clean_closer = run_drive(case / "scans.bag", {})
        accepted = clean_closer.n_verified_accepted
        if accepted == 0:
            rows.append({"scenario": scenario, "accepted": 0, "note": "no closure to corrupt"})
            continue
        ate_clean = _ate_m(clean, truth)
        for seed in args.seeds:
            corrupt = _offsets(np.random.default_rng(seed), max(1, round(args.fraction * accepted)), accepted)
            injected, closer = run_drive(case / "scans.bag", corrupt)
            verdicts = {(c.query, c.match): c.verdict.value for c in injected.loop_candidates}
            row = {
                "scenario": scenario,
                "seed": seed,
                "accepted_clean": accepted,
                "closures_clean": int(clean.counts.get("loop_closures", 0)),
                "closures_injected_run": int(injected.counts.get("loop_closures", 0)),
                "injected": [
                    {"query": q, "match": m, "offset_m": length, "verdict": verdicts.get((q, m), "?")}
                    for q, m, length in closer.injected
                ],
                "ate_clean_m": ate_clean,
                "ate_injected_m": _ate_m(injected, truth),
            }
            row["ate_change_m"] = row["ate_injected_m"] - ate_clean
            rows.append(row)
            offsets = ", ".join(
                f"{i['query']}->{i['match']} {i['offset_m']:.1f} m ({i['verdict']})" for i in row["injected"]
            )
            print(
                f"{scenario} seed {seed}: {accepted} accepted verifications clean; "
                f"injected {offsets or 'none reached'}; "
                f"ATE {ate_clean:.3f} -> {row['ate_injected_m']:.3f} m ({row['ate_change_m']:+.3f} m); closures "
                f"{row['closures_clean']} -> {row['closures_injected_run']}",
                flush=True,
            )
    if args.out is not None:
        args.out.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
