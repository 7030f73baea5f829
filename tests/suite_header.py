"""A minimal run header for the suite report renderer (eval/suite_report.py) in tests."""

from __future__ import annotations

SUITE_HEADER = {
    "command": "eval/run_suite.py",
    "date_utc": "2026-12-01 23:00 UTC",
    "elapsed_min": 1.0,
    "cpu": "cpu",
    "n_cpus": 2,
    "memory_gib": 4.0,
    "load_start": "0.1",
    "load_end": "0.1",
    "lidar3d_version": "0",
    "commit": "`abc`",
    "python": "3.11",
    "peer_versions": {},
    "seeds": [0],
    "durations_text": "full length",
    "jobs": 1,
    "peer_fractions": {},
    "quick_command": "q",
    "skipped": [],
}
