"""Does the health flag mark the scans whose estimate is wrong? A run folder scored against the truth.

For every scan of the run whose ground truth is known, the *local drift* is the position error of
the trajectory segment of ``--segment`` metres (10; travelled on the truth) that ends at that scan,
once the segment's first pose is aligned with the truth:

    e_i = | (T_ref[j] T_est[j]^-1 T_est[i]).t - T_ref[i].t |,   j = the last scan >= segment_m before i

A scan is *bad* when ``e_i > --max-error`` (0.3 m: "off by more than 0.3 m per 10 m", issue 15) and
*flagged* when ``health.csv`` marks it degraded or lost. The report gives the recall (bad scans
flagged; target >= 0.9) and the false flag rate (good scans flagged; target < 5 %). Scans in the
first segment of the drive (no full segment behind them) are not scored.

Usage::

    .venv/bin/python eval/health_check.py out/blind_turn sim/blind_turn            # a simulation folder
    .venv/bin/python eval/health_check.py out/blind_turn sim/blind_turn/ground_truth_tum.txt --json h.json

``eval/run_suite.py`` runs it on every lidar3d run (``health`` in ``results.json``, the health table
of ``BENCHMARKS.md``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from check_cli import report_and_exit_code  # noqa: E402

from lidar3d.errors import Lidar3dError  # noqa: E402

__all__ = ["FALSE_FLAG_TARGET", "RECALL_TARGET", "check_health", "format_report", "local_drift_errors", "main"]

RECALL_TARGET = 0.9
FALSE_FLAG_TARGET = 0.05
TRUTH_NAME = "ground_truth_tum.txt"


def local_drift_errors(T_estimate: np.ndarray, T_reference: np.ndarray, segment_m: float) -> np.ndarray:
    """(N,) local drift of each pose: the error of the ``segment_m`` segment ending there (see the
    module docstring), metres; NaN for poses less than ``segment_m`` from the first one.

    Args:
        T_estimate: (N,4,4) estimated poses (any world frame).
        T_reference: (N,4,4) true poses at the same stamps.
    """
    positions = T_reference[:, :3, 3]
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(positions, axis=0), axis=1))])
    start = np.searchsorted(travelled, travelled - segment_m, side="right") - 1
    errors = np.full(len(T_estimate), np.nan)
    for i in np.flatnonzero((start >= 0) & (travelled >= segment_m)):
        j = start[i]
        anchor = T_reference[j] @ np.linalg.inv(T_estimate[j])
        errors[i] = float(np.linalg.norm((anchor @ T_estimate[i])[:3, 3] - positions[i]))
    return errors


def _truth_path(truth: Path) -> Path:
    return truth / TRUTH_NAME if truth.is_dir() else truth


def _ratio(numerator: int, denominator: int) -> float | None:
    return round(numerator / denominator, 4) if denominator else None


def check_health(run_dir: str | Path, truth: str | Path, *, segment_m: float = 10.0, max_error_m: float = 0.3) -> dict:
    """Score the health flags of the run folder ``run_dir`` against the true poses in ``truth`` (a TUM
    file, or a simulation folder holding ``ground_truth_tum.txt``).

    Returns a JSON-ready dict: scans, scans scored, bad and good scans, flagged among each, ``recall``
    and ``false_flag_rate`` (None when there is no bad, or no good, scan), the worst local drift,
    and whether each target is met.

    Raises:
        Lidar3dError: an unreadable or inconsistent run folder, health table or truth (one line).
    """
    from lidar3d.io.health_csv import read_health_csv
    from lidar3d.io.run_folder import read_run_folder
    from lidar3d.io.trajectory_io import read_tum
    from lidar3d.mapping.health import HealthFlag
    from lidar3d.metrics.association import associate

    run_dir = Path(run_dir)
    read_run_folder(run_dir)  # a consistent set: health.csv belongs to trajectory_tum.txt
    estimate = read_tum(run_dir / "trajectory_tum.txt")
    _, health = read_health_csv(run_dir / "health.csv")
    stamps = np.array([h.stamp_ns for h in health], dtype=np.int64)
    if not np.array_equal(stamps, estimate.stamps_ns):
        raise Lidar3dError(f"{run_dir / 'health.csv'}: its stamps are not those of trajectory_tum.txt")
    pairs = associate(estimate, read_tum(_truth_path(Path(truth))), max_gap_s=0.2)
    errors = local_drift_errors(pairs.T_world_estimate, pairs.T_world_reference, segment_m)
    flagged = np.array([health[i].flag is not HealthFlag.OK for i in pairs.estimate_index], dtype=bool)
    scored = ~np.isnan(errors)
    bad = scored & (errors > max_error_m)
    good = scored & ~bad
    recall = _ratio(int((flagged & bad).sum()), int(bad.sum()))
    false_flag_rate = _ratio(int((flagged & good).sum()), int(good.sum()))
    return {
        "run": str(run_dir),
        "segment_m": segment_m,
        "max_error_m": max_error_m,
        "scans": len(health),
        "scored": int(scored.sum()),
        "bad": int(bad.sum()),
        "bad_flagged": int((flagged & bad).sum()),
        "good": int(good.sum()),
        "good_flagged": int((flagged & good).sum()),
        "recall": recall,
        "false_flag_rate": false_flag_rate,
        "worst_local_drift_m": round(float(np.nanmax(errors)), 4) if scored.any() else None,
        "flags": {flag.value: sum(h.flag is flag for h in health) for flag in HealthFlag},
        "recall_met": recall is None or recall >= RECALL_TARGET,
        "false_flag_met": false_flag_rate is None or false_flag_rate < FALSE_FLAG_TARGET,
    }


def format_report(report: dict) -> str:
    """The report as a few lines of text."""

    def percent(value: float | None) -> str:
        return "n/a" if value is None else f"{100 * value:.1f} %"

    def verdict(met: bool) -> str:
        return "met" if met else "NOT met"

    flags = ", ".join(f"{n} {flag}" for flag, n in report["flags"].items())
    return "\n".join(
        [
            f"{report['run']}: {report['scans']} scans ({flags}), {report['scored']} scored",
            f"  bad scans (local drift > {report['max_error_m']:g} m per {report['segment_m']:g} m): "
            f"{report['bad']}, worst {report['worst_local_drift_m']} m",
            f"  recall {percent(report['recall'])} ({report['bad_flagged']} of {report['bad']} flagged; "
            f"target >= {100 * RECALL_TARGET:.0f} %: {verdict(report['recall_met'])})",
            f"  false flags {percent(report['false_flag_rate'])} ({report['good_flagged']} of {report['good']} "
            f"good scans; target < {100 * FALSE_FLAG_TARGET:.0f} %: {verdict(report['false_flag_met'])})",
        ]
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="eval/health_check.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run_dir", type=Path, help="run folder of lidar3d run (with health.csv)")
    parser.add_argument("truth", type=Path, help="true poses: a TUM file or a simulation folder")
    parser.add_argument("--segment", type=float, default=10.0, metavar="M", help="segment length in metres (10)")
    parser.add_argument("--max-error", type=float, default=0.3, metavar="M", help="bad above this error, m (0.3)")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the report as JSON")
    args = parser.parse_args(argv)
    return report_and_exit_code(
        lambda: check_health(args.run_dir, args.truth, segment_m=args.segment, max_error_m=args.max_error),
        format_report,
        lambda report: bool(report["recall_met"] and report["false_flag_met"]),
        args.json,
    )


if __name__ == "__main__":
    sys.exit(main())
