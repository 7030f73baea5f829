"""The suite's speed report (issue 17): process-tree RSS and the table beside KISS-ICP."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from suite_header import SUITE_HEADER

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "eval"))


def _row(method: str, process_wall_s: float, tree_mib: float, stage_ms: dict, composite_ms: dict | None = None) -> dict:
    return {
        "scenario": "loop",
        "seed": 0,
        "method": method,
        "status": "ok",
        "case": {"path_length_m": 421.0, "n_scans": 690, "revisit_events": 1},
        "run": {"scans": 690, "wall_s": process_wall_s - 2.0, "scans_per_s": 30.0, "stage_ms": stage_ms}
        | ({"composite_ms": composite_ms} if composite_ms else {}),
        "scores": {},
        "process_wall_s": process_wall_s,
        "peak_rss_mib": tree_mib - 100.0,
        "peak_tree_rss_mib": tree_mib,
        "cpu_s": process_wall_s * 1.5,
    }


def test_the_speed_table_puts_lidar3d_beside_kiss_icp():
    from suite_report import render_markdown

    def stats(median: float) -> dict:
        return {"mean": median, "median": median, "p95": 2 * median, "n": 690}

    ours = _row(
        "lidar3d",
        30.0,
        612.0,
        {"deskew": stats(1.5), "odometry": stats(6.0), "mapping": stats(12.0), "redeskew": stats(0.1)}
        | {"map_update": stats(9.0)},
        {"front_end": stats(14.0)},
    )
    kiss = _row("kiss-icp", 20.0, 118.0, {"read": stats(3.0), "register": stats(15.0)})
    markdown = render_markdown([ours, kiss], SUITE_HEADER)
    assert "## Speed against KISS-ICP" in markdown
    assert (
        "| loop | 690 | 30.0 | 20.0 | 1.50× | 45.0 / 30.0 | 14.0 | 1.5 | 6.0 | 12.0 | 0.1 (0.2) | 9.0 | 612 / 118 |"
        in markdown
    )
    alone = render_markdown([ours], SUITE_HEADER)  # without the peer: its cells are dashes
    assert "| loop | 690 | 30.0 | – | – | 45.0 / – | 14.0 |" in alone


@pytest.mark.skipif(not Path("/proc/self/status").is_file(), reason="reads /proc")
def test_tree_rss_counts_the_children():
    from run_suite import tree_rss_kib

    code = (
        "import time, subprocess, sys; "
        "c = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(30)']); time.sleep(30)"
    )
    parent = subprocess.Popen([sys.executable, "-c", code])
    try:
        deadline = time.monotonic() + 20.0
        alone = own = 0
        while time.monotonic() < deadline:
            own = _vm_rss_kib(parent.pid)
            alone = tree_rss_kib(parent.pid)
            if alone > own + 1000:  # the child interpreter is up
                break
            time.sleep(0.1)
        assert alone > own + 1000
    finally:
        for pid in _descendants(parent.pid):
            os.kill(pid, 9)
        parent.kill()
        parent.wait()
    assert tree_rss_kib(parent.pid) == 0  # gone: nothing to count


def _vm_rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def _descendants(pid: int) -> list[int]:
    from run_suite import _children

    return _children(pid)
