"""Kill test: SIGKILL ``lidar3d run`` at random moments; every folder left must be a consistent set.

Simulates a bag once (``loop`` scenario, ``--duration`` seconds), times one run that is not killed,
then starts ``lidar3d run`` as a subprocess into a fresh folder per trial and SIGKILLs it at a
seeded random moment: most trials uniformly over the measured duration, the others (``--final-write``)
during the final write (the last publication, from the moment its complete trajectory appears in
the staging folder, to the exit; as measured on the unkilled run): half of them uniformly over it,
half in its last second. Each folder left behind must hold either
no outputs or a set that

* a reader accepts (:func:`lidar3d.io.run_folder.read_run_folder`, which first finishes a
  publication the kill interrupted; such trials are counted as "pending" in the table);
* is consistent with its summary: every file the manifest names exists with its size and SHA-256,
  nothing else is in the folder, and the rows agree (trajectories: ``scans`` / ``keyframes``,
  ``map.pcd``: ``map_points``, ``loops.csv``: ``loop_candidates``);
* loads: every trajectory through ``read_trajectory``, the map through ``read_pcd``, the summary
  through ``read_summary``.

Prints a table and a verdict; exits 1 when any trial is inconsistent::

    python eval/kill_test.py --trials 20 --seed 0 --duration 30 --work /tmp/kill_test
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from lidar3d.errors import Lidar3dError
from lidar3d.io.health_csv import read_health_csv
from lidar3d.io.pcd import read_pcd
from lidar3d.io.run_folder import (
    STAGING_NAME,
    SUMMARY_NAME,
    RunFolderState,
    check_run_folder,
    read_run_folder,
)
from lidar3d.io.trajectory_io import read_trajectory
from lidar3d.summary import RunSummary, read_summary

TRAJECTORIES = ("trajectory_tum.txt", "trajectory_kitti.txt", "odometry_tum.txt", "keyframes_tum.txt")


@dataclass(frozen=True, slots=True)
class Trial:
    """One killed run and the verdict on the folder it left."""

    index: int
    kill_at_s: float  # seconds from the start to the kill
    when: str  # the moment aimed at, in words
    state: str  # state on disk right after the kill (before any reader touched it)
    scans: int | None
    partial: bool | None
    consistent: bool
    problem: str


def run_command(bag: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "lidar3d.cli.main", "-q", "run", str(bag), "--out", str(out)]


def all_files(folder: Path) -> list[str]:
    """Every file under ``folder`` (hidden ones too), relative, ``/``-separated."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


def verify_folder(folder: Path) -> tuple[RunSummary | None, str]:
    """The folder's summary (None: no outputs) and a problem ("" when the folder is consistent)."""
    try:
        summary = read_run_folder(folder, verify_content=True) if folder.exists() else None
    except Lidar3dError as err:
        if "no run outputs" not in str(err):
            return None, str(err)
        summary = None
    if summary is None:
        left = all_files(folder) if folder.exists() else []
        return None, f"no summary, but {left[0]}" if left else ""
    check = check_run_folder(folder, verify_content=True)
    if check.state is not RunFolderState.CONSISTENT:
        return summary, "; ".join(check.problems)
    unnamed = sorted(set(all_files(folder)) - {entry.path for entry in summary.outputs} - {SUMMARY_NAME})
    if unnamed:
        return summary, f"not named by the summary: {', '.join(unnamed)}"
    if read_summary(folder / SUMMARY_NAME) != summary:
        return summary, "summary.json changed while checking"
    expected = {"keyframes_tum.txt": summary.keyframes}
    for name in TRAJECTORIES:
        if summary.output(name) is None:
            return summary, f"{name}: not in the set"
        rows = len(read_trajectory(folder / name))
        if rows != expected.get(name, summary.scans) or rows != summary.output(name).rows:
            return summary, f"{name}: {rows} poses, summary says {expected.get(name, summary.scans)}"
    if summary.output("map.pcd") is not None:
        points, _ = read_pcd(folder / "map.pcd")
        if len(points) != summary.map_points:
            return summary, f"map.pcd: {len(points)} points, summary says {summary.map_points}"
    elif summary.map_points != 0:
        return summary, f"no map.pcd, summary says {summary.map_points} points"
    if summary.output("loops.csv") is not None:
        rows = len((folder / "loops.csv").read_text(encoding="utf-8").splitlines()) - 1
        if rows != summary.loop_candidates:
            return summary, f"loops.csv: {rows} rows, summary says {summary.loop_candidates}"
    if summary.output("health.csv") is not None:
        try:
            _, health = read_health_csv(folder / "health.csv")
        except Lidar3dError as err:
            return summary, str(err)
        lost = sum(h.flag.value == "lost" for h in health)
        if summary.health is None or (len(health), lost) != (summary.health.scans, summary.health.lost_scans):
            return summary, f"health.csv: {len(health)} rows, {lost} lost; the summary's health disagrees"
    return summary, ""


def disk_state(folder: Path) -> str:
    """What the kill left, before a reader finishes an interrupted publication."""
    if not folder.exists():
        return "no folder"
    if (folder / STAGING_NAME / SUMMARY_NAME).is_file():
        return "pending"
    state = check_run_folder(folder, verify_content=True).state.value
    return state + (" + staging" if (folder / STAGING_NAME).exists() else "")


def _final_write_started(out: Path, n_scans: int) -> bool:
    """The final publication is being staged: a trajectory of every scan is in the staging folder."""
    try:
        lines = (out / STAGING_NAME / "trajectory_tum.txt").read_bytes().splitlines()
    except OSError:
        return False
    return sum(1 for line in lines if line and not line.startswith(b"#")) == n_scans


def run_and_kill(
    command: list[str], out: Path, delay_s: float, n_scans: int | None
) -> tuple[bool, float, float | None]:
    """Start ``command`` and SIGKILL it ``delay_s`` after its start (``final_size`` None) or after its
    final write started (a staged trajectory of ``n_scans`` poses).

    Returns:
        (killed: it was still running then, seconds from the start to the kill or to its end,
        seconds from the start to the start of its final write, None when not seen).
    """
    t0 = time.perf_counter()
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = math.inf if n_scans is not None else t0 + delay_s
    t_final = None
    while process.poll() is None and time.perf_counter() < deadline:
        if t_final is None and n_scans is not None and _final_write_started(out, n_scans):
            t_final = time.perf_counter() - t0
            deadline = time.perf_counter() + delay_s
        time.sleep(0.002)
    killed = process.poll() is None
    if killed:
        os.kill(process.pid, signal.SIGKILL)
    process.wait()
    elapsed = time.perf_counter() - t0
    with contextlib.suppress(ProcessLookupError):  # the prefetch worker this run started (same session) goes too
        os.killpg(process.pid, signal.SIGKILL)
    return killed, elapsed, t_final


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("--final-write", type=int, default=6, help="trials killed during the final write")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--duration", type=float, default=30.0, help="seconds of the simulated drive")
    parser.add_argument("--work", type=Path, default=None, help="working folder (default: a temporary one)")
    args = parser.parse_args(argv)

    from lidar3d.sim import simulate

    work = args.work or Path(tempfile.mkdtemp(prefix="lidar3d_kill_"))
    work.mkdir(parents=True, exist_ok=True)
    t_total = time.perf_counter()
    simulated = simulate("loop", work / "sim", seed=0, duration_s=args.duration, overwrite=True)
    reference = work / "reference"
    shutil.rmtree(reference, ignore_errors=True)
    # The unkilled run: its duration, and when its final write starts.
    _, run_s, t_final = run_and_kill(run_command(simulated.bag, reference), reference, math.inf, simulated.n_scans)
    ref_summary, problem = verify_folder(reference)
    if ref_summary is None or problem or ref_summary.partial or ref_summary.scans != simulated.n_scans:
        print(f"the unkilled run is not complete and consistent: {problem}")
        return 1
    final_write_s = run_s - (t_final if t_final is not None else run_s - 1.0)
    print(
        f"bag: {args.duration:g} s, {ref_summary.scans} scans; unkilled run {run_s:.1f} s, "
        f"its final write (last publication and exit) {final_write_s:.2f} s"
    )

    rng = random.Random(args.seed)
    n_late = min(args.final_write, args.trials)
    plan = [(rng.uniform(0.0, run_s), None) for _ in range(args.trials - n_late)]
    # Half of them over the whole final write, half in its last second (the commit, the swap, the exit).
    plan += [
        (rng.uniform(0.0 if i % 2 else max(0.0, final_write_s - 1.0), final_write_s), simulated.n_scans)
        for i in range(n_late)
    ]
    trials = []
    for index, (delay_s, final) in enumerate(plan):
        out = work / f"trial_{index:02d}"
        shutil.rmtree(out, ignore_errors=True)
        killed, elapsed, _ = run_and_kill(run_command(simulated.bag, out), out, delay_s, final)
        when = f"final write +{delay_s:.2f} s" if final is not None else f"{delay_s / run_s:.0%} of the run"
        state = disk_state(out) if killed else "finished first"
        summary, problem = verify_folder(out)
        scans = summary.scans if summary else None
        partial = summary.partial if summary else None
        trials.append(Trial(index, elapsed, when, state, scans, partial, not problem, problem))

    print(f"{'trial':>5} {'kill at s':>9}  {'aimed at':<22} {'left on disk':<24} {'scans':>5} {'partial':>7}  verdict")
    for t in trials:
        scans = "-" if t.scans is None else str(t.scans)
        partial = "-" if t.partial is None else str(t.partial).lower()
        verdict = "consistent" if t.consistent else f"INCONSISTENT: {t.problem}"
        print(f"{t.index:>5} {t.kill_at_s:>9.2f}  {t.when:<22} {t.state:<24} {scans:>5} {partial:>7}  {verdict}")
    good = sum(t.consistent for t in trials)
    pending = sum(t.state.startswith("pending") for t in trials)
    killed = sum(t.state != "finished first" for t in trials)
    print(
        f"verdict: {good}/{len(trials)} consistent, {killed} killed before the end ({pending} of them inside a "
        f"swap, finished by the reader); total {time.perf_counter() - t_total:.0f} s"
    )
    return 0 if good == len(trials) else 1


if __name__ == "__main__":
    sys.exit(main())
