"""scripts/ensure_system_deps.sh waits for the package manager's lock (issue 21, defect 11).

The script is sourced (functions only) with its lock paths pointed at files in tmp_path; another
process holds an fcntl lock on one of them, as dpkg and apt-get do. No root, no apt-get: a fake
apt-get on PATH records its arguments.
"""

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "ensure_system_deps.sh"

pytestmark = pytest.mark.skipif(sys.platform != "linux", reason="fcntl locks as dpkg takes them: Linux only")

_HOLDER = """
import fcntl, os, sys, time
fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT)
fcntl.lockf(fd, fcntl.LOCK_EX)
print("held", flush=True)
time.sleep(float(sys.argv[2]))
"""


def _hold(path: Path, seconds: float) -> subprocess.Popen:
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(path), str(seconds)], stdout=subprocess.PIPE, text=True
    )
    assert holder.stdout.readline().strip() == "held"
    return holder


def _bash(commands: str, locks: list[Path], timeout_s: int, env_extra=None) -> subprocess.CompletedProcess:
    env = dict(
        os.environ,
        LIDAR3D_APT_LOCKS=" ".join(map(str, locks)),
        LIDAR3D_APT_LOCK_TIMEOUT_S=str(timeout_s),
        LIDAR3D_APT_LOCK_POLL_S="0.2",
        **(env_extra or {}),
    )
    script = f'source "{SCRIPT}" "{sys.executable}"\n{commands}\n'
    return subprocess.run(["bash", "-c", script], check=False, env=env, capture_output=True, text=True, timeout=60)


def test_free_locks_pass_silently(tmp_path):
    locks = [tmp_path / "lock-frontend", tmp_path / "missing-lock"]
    locks[0].touch()
    result = _bash("wait_for_apt_locks; echo free", locks, timeout_s=2)
    assert (result.returncode, result.stdout, result.stderr) == (0, "free\n", "")


def test_held_lock_gives_up_after_the_timeout_with_one_line(tmp_path):
    locks = [tmp_path / "lock-frontend", tmp_path / "lock"]
    holder = _hold(locks[1], 30)
    try:
        start = time.monotonic()
        result = _bash("wait_for_apt_locks; echo free", locks, timeout_s=2)
        elapsed = time.monotonic() - start
    finally:
        holder.kill()
        holder.wait()
    assert result.returncode == 1 and result.stdout == ""
    lines = result.stderr.splitlines()
    assert len(lines) == 2, result.stderr
    assert lines[0] == (
        f"lidar3d: waiting up to 2 s for the package manager: {locks[1]} is held by another apt-get "
        "or dpkg (on a fresh machine: unattended upgrades at first boot)"
    )
    assert lines[1] == (
        f"lidar3d: gave up after 2 s waiting for {locks[1]} (another apt-get or dpkg, e.g. "
        "unattended-upgrades, still holds it); rerun when it has finished"
    )
    assert 0.9 < elapsed < 20  # bash SECONDS counts whole seconds


def test_waits_until_the_lock_is_released_saying_so_once(tmp_path):
    lock = tmp_path / "lock-frontend"
    holder = _hold(lock, 1.5)
    try:
        result = _bash("wait_for_apt_locks; echo free", [lock], timeout_s=30)
    finally:
        holder.wait()
    assert result.returncode == 0 and result.stdout == "free\n"
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("lidar3d: waiting up to 30 s for the package")


def test_apt_get_is_given_the_remaining_lock_timeout(tmp_path):
    fake_bin = tmp_path / "bin"
    fake_bin.mkdir()
    record = tmp_path / "apt-args"
    fake = fake_bin / "apt-get"
    fake.write_text(f'#!/bin/sh\necho "$@" >> "{record}"\n')
    fake.chmod(0o755)
    lock = tmp_path / "lock"
    lock.touch()
    env = {"PATH": f"{fake_bin}{os.pathsep}{os.environ['PATH']}"}
    result = _bash("apt_get update -qq && apt_get install -y -qq libusb-1.0-0", [lock], timeout_s=120, env_extra=env)
    assert result.returncode == 0, result.stderr
    calls = record.read_text().splitlines()
    assert len(calls) == 2
    for call, tail in zip(calls, ["update -qq", "install -y -qq libusb-1.0-0"]):
        option, value, rest = call.split(" ", 2)
        assert option == "-o" and value.startswith("DPkg::Lock::Timeout=") and rest == tail
        assert 100 <= int(value.split("=")[1]) <= 120
