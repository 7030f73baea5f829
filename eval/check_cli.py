"""The shared ending of the truth checks' command lines (``health_check.py``, ``closure_check.py``)."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from lidar3d.errors import Lidar3dError  # noqa: E402

__all__ = ["report_and_exit_code"]


def report_and_exit_code(
    check: Callable[[], dict], format_report: Callable[[dict], str], met: Callable[[dict], bool], json_path: Path | None
) -> int:
    """Run ``check``, print its report (and write it as JSON to ``json_path``); the exit code: 0 when
    ``met``, 2 when not, 1 with one line on stderr when the inputs are unusable."""
    try:
        report = check()
    except Lidar3dError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    print(format_report(report))
    if json_path is not None:
        json_path.write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    return 0 if met(report) else 2
