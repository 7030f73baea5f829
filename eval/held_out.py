"""Held-out drives: the suite's layouts driven in ways the suite's scenarios never are, on other seeds.

The suite's scenarios (``eval/run_suite.py``) are what lidar3d's design was measured on; a figure
published from them is a figure on the drives it was tuned with. These variants keep a scenario's
street layout and change how it is driven and sensed: other speed profiles (up to 15 m/s, random
speed changes where the original cruises, a stop), vibration where the original has none,
per-laser calibration error, stamp jitter, dropped packets and sweep-end stamps where the original
is clean, and seeds the suite does not use (default 10 and 11, so new towns around the same
streets). Nothing in lidar3d was chosen on them: run them after a change, and read a regression
here as a change that fitted the suite.

Each variant is simulated once and cached under ``eval/cache/held_out/`` (keyed like the suite's
cache, with the variant's full definition), each method runs in its own process as in the suite,
and the table gives per drive: ATE (RMSE, SE(3)-aligned), the worst pose error, the worst 10 m
stretch (local drift), the health flags against the truth, and the best peer's ATE. Usage::

    .venv/bin/python eval/held_out.py                                  # every variant, seeds 10 11
    .venv/bin/python eval/held_out.py --variants f8_var --seeds 10 --no-peers
    .venv/bin/python eval/held_out.py --no-loop                         # loop closure off

``results.json`` and ``held_out.md`` are written again after every run that finishes (the table
marked partial until the last), each run's scored record is saved beside its outputs, and
``--resume`` with the same ``--out`` finishes an interrupted run without repeating what finished.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
for entry in (str(REPO), str(HERE)):
    if entry not in sys.path:
        sys.path.insert(0, entry)

from run_suite import DEFAULT_RESULTS, run_scored, run_tasks  # noqa: E402
from suite_cache import DEFAULT_CACHE, CachedScenario, ensure_scenario  # noqa: E402
from suite_peers import PEERS  # noqa: E402
from suite_report import fmt_num, fmt_percent  # noqa: E402

from lidar3d.io.atomic import write_text_atomic  # noqa: E402
from lidar3d.sim.lidar import StampMode  # noqa: E402
from lidar3d.sim.scenarios import SCENARIOS, Scenario  # noqa: E402

_IMPERFECT = {
    "elevation_error_sigma_deg": 0.05,
    "range_bias_sigma_m": 0.004,
    "stamp_jitter_s": 0.001,
    "dropped_wedge_probability": 0.02,
}

# name: (layout of, what it tests, changes to the route, changes to the sensor, stamps)
VARIANTS: dict[str, tuple[str, str, dict, dict]] = {
    "fast15": (
        "fast",
        "`fast`'s corners at a random 6-15 m/s, vibration, calibration error, jitter, dropped packets",
        {
            "cruise_speed_mps": 15.0,
            "random_speed_min_mps": 6.0,
            "corner_radius_m": 10.0,
            "max_lateral_accel_mps2": 5.0,
            "max_accel_mps2": 3.0,
            "max_decel_mps2": 4.0,
            "vibration_deg": 0.15,
            "vibration_heave_m": 0.001,
        },
        {**_IMPERFECT},
    ),
    "loop_var": (
        "loop",
        "`loop` at a random 2-11 m/s with a 5 s stop, vibration, calibration error, sweep-end stamps",
        {
            "cruise_speed_mps": 11.0,
            "random_speed_min_mps": 2.0,
            "max_accel_mps2": 2.5,
            "max_decel_mps2": 3.5,
            "vibration_deg": 0.2,
            "vibration_heave_m": 0.001,
            "stops": ((150.0, 5.0),),
        },
        {**_IMPERFECT, "stamp": StampMode.SWEEP_END},
    ),
    "hilly_fast": (
        "hilly",
        "`hilly`'s slopes at a random 4-12 m/s, 0.25 deg vibration, calibration error",
        {"cruise_speed_mps": 12.0, "random_speed_min_mps": 4.0, "max_accel_mps2": 2.0, "vibration_deg": 0.25},
        {**_IMPERFECT},
    ),
    "blind_fast": (
        "blind_turn",
        "`blind_turn`'s open land and blind turn at a random 4-11 m/s, vibration, calibration error",
        {
            "cruise_speed_mps": 11.0,
            "random_speed_min_mps": 4.0,
            "max_accel_mps2": 2.0,
            "vibration_deg": 0.2,
            "vibration_heave_m": 0.001,
        },
        {**_IMPERFECT},
    ),
    "f8_var": (
        "figure_eight",
        "`figure_eight`'s open field and sharp turn at a random 3-8 m/s instead of its set speeds",
        {"speed_targets": (), "cruise_speed_mps": 8.0, "random_speed_min_mps": 3.0, "max_accel_mps2": 2.0},
        {},
    ),
}
DEFAULT_SEEDS = (10, 11)
CACHE = DEFAULT_CACHE / "held_out"


def variant_scenario(name: str) -> Scenario:
    """The :class:`Scenario` of variant ``name``: its base scenario with the route and sensor changed."""
    base_name, description, route, lidar = VARIANTS[name]
    base = SCENARIOS[base_name]
    sensor = dataclasses.replace(base.lidar, **lidar)
    return dataclasses.replace(
        base, name=name, description=description, route=dataclasses.replace(base.route, **route), lidar=sensor
    )


def _run_drive(case: CachedScenario, method: str, out_dir: Path, loop_closure: bool, resume: bool) -> dict:
    return run_scored(
        method, case, out_dir, genz_deskew=True, timeout_s=3600.0, loop_closure=loop_closure, resume=resume
    )


def _row(variant: str, seed: int, records: dict[str, dict]) -> str:
    ours = records["lidar3d"]
    gt = ours.get("scores", {}).get("gt", {})
    if ours["status"] != "ok" or "error" in gt:
        return f"| {variant} | {seed} | failed: {ours.get('error') or gt.get('error')} | | | | |"
    peers = [
        r["scores"]["gt"]["ate_rmse_m"]["3d"]
        for m, r in records.items()
        if m != "lidar3d" and r["status"] == "ok" and "error" not in r["scores"]["gt"]
    ]
    health = ours.get("health", {})
    flags = (
        f"{fmt_percent(health.get('recall'))} / {fmt_percent(health.get('false_flag_rate'))} ({health.get('bad', 0)})"
    )
    cells = [
        fmt_num(gt["ate_rmse_m"]["3d"], 3, " m"),
        fmt_num(gt["ate_max_3d_m"], 2, " m"),
        fmt_num(health.get("worst_local_drift_m"), 2, " m"),
        fmt_num(min(peers) if peers else None, 3, " m"),
        flags,
    ]
    return f"| {variant} | {seed} | " + " | ".join(cells) + " |"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--variants", nargs="+", choices=sorted(VARIANTS), default=list(VARIANTS))
    parser.add_argument("--seeds", nargs="+", type=int, default=list(DEFAULT_SEEDS))
    parser.add_argument("--no-peers", action="store_true", help="run lidar3d only")
    parser.add_argument("--no-loop", action="store_true", help="lidar3d with loop closure off")
    parser.add_argument("--jobs", type=int, default=1, help="runs at a time (timings are not compared here)")
    parser.add_argument("--out", type=Path, help="results folder (default eval/results/held_out_<UTC time>)")
    parser.add_argument(
        "--resume", action="store_true", help="runs that finished in --out with the same options are not run again"
    )
    args = parser.parse_args(argv)
    if args.resume and args.out is None:
        parser.error("--resume needs the --out folder of the run to finish")
    out = args.out or DEFAULT_RESULTS / time.strftime("held_out_%Y%m%dT%H%M%SZ", time.gmtime())
    methods = ["lidar3d"] + ([] if args.no_peers else list(PEERS))
    cases = {
        (v, s): ensure_scenario(variant_scenario(v), s, cache_dir=CACHE) for v in args.variants for s in args.seeds
    }
    tasks = [(v, s, m) for (v, s) in cases for m in methods]

    def work(task: tuple[str, int, str]) -> dict:
        variant, seed, method = task
        print(f"{variant} seed {seed}: {method}", file=sys.stderr, flush=True)
        return _run_drive(
            cases[(variant, seed)], method, out / f"{variant}_s{seed}" / method, not args.no_loop, args.resume
        )

    def publish(records: dict[tuple[str, int, str], dict], complete: bool) -> str:
        """results.json (every run finished so far) and held_out.md (every drive whose methods all
        finished), written after each run."""
        out.mkdir(parents=True, exist_ok=True)
        write_text_atomic(
            out / "results.json",
            json.dumps({f"{v}_s{s}_{m}": r for (v, s, m), r in records.items()}, indent=1, default=str) + "\n",
        )
        note = "" if complete else f" **partial: {len(records)} of {len(tasks)} runs finished**"
        lines = [
            f"Held-out drives ({'loop closure off' if args.no_loop else 'loop closure on'}):{note}",
            "",
            "| variant | seed | ATE | max error | worst 10 m | best peer ATE "
            "| health recall / false flags (bad scans) |",
            "|---|---:|---:|---:|---:|---:|---|",
        ]
        for variant, seed in cases:
            if all((variant, seed, m) in records for m in methods):
                lines.append(_row(variant, seed, {m: records[(variant, seed, m)] for m in methods}))
        lines += ["", *(f"* `{v}`: {VARIANTS[v][1]}" for v in args.variants)]
        write_text_atomic(out / "held_out.md", "\n".join(lines) + "\n")
        return "\n".join(lines)

    records = run_tasks(tasks, work, max(1, args.jobs), lambda so_far: publish(so_far, complete=False))
    print(publish(records, complete=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
