"""A `lidar3d run` stopped from outside: SIGTERM stops it as Ctrl-C does (exit 143, one line), and
its child processes (prefetch, dense map) end with it, also when it is killed outright."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lidar3d import sim


@pytest.fixture(scope="module")
def bag(tmp_path_factory) -> Path:
    # 12 s (120 scans): the runs take several seconds more than the 1-2 s after which they are stopped
    return sim.simulate("loop", tmp_path_factory.mktemp("sim") / "loop", seed=0, duration_s=12.0).bag


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


def _ended(pid: int) -> bool:
    """The process is gone, or a zombie nobody has reaped yet."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return True
    return "\nState:\tZ" in status


def _start_run(bag: Path, out: Path) -> tuple[subprocess.Popen, list[int]]:
    """`lidar3d run` started in a process group of its own, once it has both its children (their pids)."""
    process = subprocess.Popen(
        [sys.executable, "-m", "lidar3d.cli.main", "run", str(bag), "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    deadline = time.monotonic() + 60
    while len(children := [c for c in _children(process.pid) if "spawn_main" in _cmdline(c)]) < 2:
        if process.poll() is not None or time.monotonic() > deadline:
            process.kill()
            pytest.fail(f"the run ended or never started its children:\n{process.communicate()[1]}")
        time.sleep(0.02)
    return process, children


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def _wait_ended(pids: list[int], timeout_s: float) -> list[int]:
    """The pids still running after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while (alive := [p for p in pids if not _ended(p)]) and time.monotonic() < deadline:
        time.sleep(0.05)
    return alive


pytestmark = pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads /proc (Linux)")


@pytest.mark.parametrize("how", ["once", "to the process group", "twice"])
def test_sigterm_stops_a_run_as_ctrl_c_does(how, bag, tmp_path):
    """Once the run has its children, SIGTERM to the run, to its process group (as a scheduler or
    systemd sends it; the children leave the stop to the run), or twice in a row."""
    out = tmp_path / "out"
    process, children = _start_run(bag, out)
    time.sleep(2.0)  # some scans in
    if how == "to the process group":
        os.killpg(process.pid, signal.SIGTERM)
    else:
        process.send_signal(signal.SIGTERM)
    if how == "twice":
        time.sleep(0.05)
        with contextlib.suppress(ProcessLookupError):
            process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 143, stderr
    assert "Traceback" not in stderr
    assert stderr.strip().splitlines()[-1] == "lidar3d run: terminated (SIGTERM); finished outputs are kept"
    assert _wait_ended(children, 10.0) == []
    summary = json.loads((out / "summary.json").read_text())
    poses = [line for line in (out / "trajectory_tum.txt").read_text().splitlines() if not line.startswith("#")]
    assert summary["partial"] is True and summary["scans"] == len(poses) > 0


def test_the_children_of_a_killed_run_end_too(bag, tmp_path):
    process, children = _start_run(bag, tmp_path / "out")
    os.kill(process.pid, signal.SIGKILL)
    process.communicate(timeout=30)
    alive = _wait_ended(children, 10.0)
    for pid in alive:  # do not leave them behind for the next test
        os.kill(pid, signal.SIGKILL)
    assert alive == []


def _has_open(pid: int, path: Path) -> bool:
    try:
        return any(os.readlink(fd) == str(path) for fd in Path(f"/proc/{pid}/fd").iterdir())
    except OSError:
        return False


def test_a_run_whose_map_process_dies_keeps_its_poses(bag, tmp_path):
    """The dense map's process killed mid-run: one line and exit 1, and the poses tracked so far
    are published (without a map) as a partial run."""
    out = tmp_path / "out"
    process, children = _start_run(bag, out)
    deadline = time.monotonic() + 30
    while not (readers := [c for c in children if _has_open(c, bag.resolve())]) and time.monotonic() < deadline:
        time.sleep(0.02)  # the prefetch process is the one with the bag open
    assert len(readers) == 1, "the prefetch process never opened the bag"
    (map_process,) = [c for c in children if c not in readers]
    time.sleep(1.0)  # some scans in
    os.kill(map_process, signal.SIGKILL)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 1, stderr
    assert "Traceback" not in stderr
    line = "lidar3d run: error: the dense map process ended unexpectedly (exit code -9)"
    assert stderr.strip().splitlines()[-1] == line
    summary = json.loads((out / "summary.json").read_text())
    poses = [line for line in (out / "trajectory_tum.txt").read_text().splitlines() if not line.startswith("#")]
    assert summary["partial"] is True and summary["scans"] == len(poses) > 0
    assert summary["map_points"] == 0 and not (out / "map.pcd").exists()
    assert _wait_ended(children, 10.0) == []
