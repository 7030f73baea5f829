"""Ground segmentation against the simulator's labels: precision and recall, by range band and cause.

Runs :func:`lidar3d.segmentation.segment_scan` on simulated scans (every scan of each window, for
each scenario and seed) and compares its ground mask with the simulator's per-point labels (object
id 0 is the ground). Every occupied range-image cell counts, on every row: a cell marked ground
that hit an object is a false positive, a ground cell not marked is a false negative. Reported
overall, per range band (range from the lidar, metres), and, for the false ground, by the class of
the object hit, its range band and its row, so one sees where precision is lost.

Prints Markdown tables (and JSON with ``--json``). Usage::

    .venv/bin/python eval/ground_check.py                                  # defaults below
    .venv/bin/python eval/ground_check.py --scenarios loop --seeds 0 --windows 100:160
    .venv/bin/python eval/ground_check.py --set segmentation.ground_continuity=false   # LeGO-LOAM's test
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from lidar3d.config import Config, SegmentationConfig  # noqa: E402
from lidar3d.segmentation import segment_scan  # noqa: E402
from lidar3d.sim import ObjectClass, Simulation  # noqa: E402

SCENARIOS = ("loop", "hilly", "stops", "fast")
SEEDS = (0, 1, 2)
WINDOWS = ((20, 80), (100, 160), (250, 310))
SCAN_PERIOD_S = 0.1
RANGE_BANDS_M = (0.0, 10.0, 20.0, 40.0, np.inf)
BAND_NAMES = ("0-10", "10-20", "20-40", "40+")


@dataclass(slots=True)
class GroundCounts:
    """Cell counts of one group of scans: true ground marked, marked, true ground; per range band."""

    hits: np.ndarray = field(default_factory=lambda: np.zeros(len(BAND_NAMES), dtype=np.int64))
    marked: np.ndarray = field(default_factory=lambda: np.zeros(len(BAND_NAMES), dtype=np.int64))
    truth: np.ndarray = field(default_factory=lambda: np.zeros(len(BAND_NAMES), dtype=np.int64))
    false_by_class: Counter = field(default_factory=Counter)
    false_by_band: Counter = field(default_factory=Counter)
    false_by_row: Counter = field(default_factory=Counter)
    missed_by_row: Counter = field(default_factory=Counter)

    def add(self, other: GroundCounts) -> None:
        self.hits += other.hits
        self.marked += other.marked
        self.truth += other.truth
        for name in ("false_by_class", "false_by_band", "false_by_row", "missed_by_row"):
            getattr(self, name).update(getattr(other, name))

    def precision(self, band: int | None = None) -> float:
        hits, marked = (self.hits.sum(), self.marked.sum()) if band is None else (self.hits[band], self.marked[band])
        return float(hits / marked) if marked else float("nan")

    def recall(self, band: int | None = None) -> float:
        hits, truth = (self.hits.sum(), self.truth.sum()) if band is None else (self.hits[band], self.truth[band])
        return float(hits / truth) if truth else float("nan")


def score_cells(ground_mask: np.ndarray, object_id: np.ndarray, range_m: np.ndarray, rows: np.ndarray) -> GroundCounts:
    """Counts of the occupied cells given as flat arrays: marked ground, true object id, range, row."""
    counts = GroundCounts()
    band = np.digitize(range_m, RANGE_BANDS_M[1:-1])
    truth = object_id == 0
    counts.hits = np.bincount(band[ground_mask & truth], minlength=len(BAND_NAMES))
    counts.marked = np.bincount(band[ground_mask], minlength=len(BAND_NAMES))
    counts.truth = np.bincount(band[truth], minlength=len(BAND_NAMES))
    false = ground_mask & ~truth
    counts.false_by_band.update(BAND_NAMES[b] for b in band[false])
    counts.false_by_row.update(rows[false].tolist())
    counts.missed_by_row.update(rows[truth & ~ground_mask].tolist())
    return counts


def check_window(
    sim: Simulation, first: int, last: int, config: SegmentationConfig, sensor_config
) -> tuple[GroundCounts, Counter]:
    counts, false_class = GroundCounts(), Counter[str]()
    for index in range(first, min(last + 1, len(sim))):
        sim_scan = sim.scan(index)
        segmentation = segment_scan(sim_scan.scan, config, sensor_config)
        image = segmentation.image
        occupied = image.occupied
        point_index = image.point_index[occupied]
        marked = segmentation.ground_mask[occupied]
        object_id = sim_scan.object_id[point_index]
        rows = np.nonzero(occupied)[0]
        scan_counts = score_cells(marked, object_id, image.range_m[occupied], rows)
        false = marked & (object_id != 0)
        false_class.update(ObjectClass(int(c)).name.lower() for c in sim_scan.object_class[point_index[false]])
        counts.add(scan_counts)
    return counts, false_class


def _parse_window(text: str) -> tuple[int, int]:
    first, _, last = text.partition(":")
    return int(first), int(last)


def _config(overrides: Sequence[str]) -> Config:
    config = Config()
    for item in overrides:
        key, _, value = item.partition("=")
        section, _, name = key.partition(".")
        current = getattr(getattr(config, section), name)
        parsed: object = value.lower() == "true" if isinstance(current, bool) else type(current)(value)
        config = replace(config, **{section: replace(getattr(config, section), **{name: parsed})})
    return config


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    parser.add_argument("--seeds", nargs="+", type=int, default=list(SEEDS))
    parser.add_argument(
        "--windows", nargs="+", type=_parse_window, default=list(WINDOWS), help="scan ranges first:last"
    )
    parser.add_argument("--set", nargs="*", default=[], metavar="SECTION.KEY=VALUE", help="config overrides")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    config = _config(args.set)
    duration_s = (max(last for _, last in args.windows) + 2) * SCAN_PERIOD_S
    results = {}
    total = GroundCounts()
    for scenario in args.scenarios:
        scenario_counts, scenario_false = GroundCounts(), Counter[str]()
        for seed in args.seeds:
            sim = Simulation(scenario, seed=seed, duration_s=duration_s)
            for first, last in args.windows:
                counts, false_class = check_window(sim, first, last, config.segmentation, config.sensor)
                scenario_counts.add(counts)
                scenario_false.update(false_class)
                print(
                    f"{scenario} seed {seed} scans {first}-{last}: precision {counts.precision():.4f} "
                    f"recall {counts.recall():.4f}",
                    file=sys.stderr,
                )
        scenario_counts.false_by_class = scenario_false
        total.add(scenario_counts)
        results[scenario] = scenario_counts
    results["all"] = total
    if args.json:
        print(json.dumps({name: _as_json(c) for name, c in results.items()}, indent=2))
        return 0
    print("| scenario | precision | recall | " + " | ".join(f"P / R {b} m" for b in BAND_NAMES) + " |")
    print("|---|---|---|" + "---|" * len(BAND_NAMES))
    for name, c in results.items():
        bands = " | ".join(f"{c.precision(b):.3f} / {c.recall(b):.3f}" for b in range(len(BAND_NAMES)))
        print(f"| {name} | {c.precision():.4f} | {c.recall():.4f} | {bands} |")
    print()
    print("| scenario | false ground by class | by range band | by row | missed ground by row |")
    print("|---|---|---|---|---|")
    for name, c in results.items():
        print(
            f"| {name} | {_top(c.false_by_class)} | {_top(c.false_by_band)} | {_top(c.false_by_row)} "
            f"| {_top(c.missed_by_row)} |"
        )
    return 0


def _top(counter: Counter, n: int = 5) -> str:
    return ", ".join(f"{key}: {count}" for key, count in counter.most_common(n))


def _as_json(c: GroundCounts) -> dict:
    return {
        "precision": c.precision(),
        "recall": c.recall(),
        "bands": {
            b: {
                "precision": c.precision(i),
                "recall": c.recall(i),
                "marked": int(c.marked[i]),
                "truth": int(c.truth[i]),
            }
            for i, b in enumerate(BAND_NAMES)
        },
        "false_by_class": dict(c.false_by_class),
        "false_by_band": dict(c.false_by_band),
        "false_by_row": {str(k): v for k, v in sorted(c.false_by_row.items())},
        "missed_by_row": {str(k): v for k, v in sorted(c.missed_by_row.items())},
    }


if __name__ == "__main__":
    raise SystemExit(main())
