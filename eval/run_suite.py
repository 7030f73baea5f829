"""Evaluation suite: lidar3d and its peers on the simulated scenarios, scored and tabulated.

For every scenario (and seed):

1. the simulation is generated once and cached under ``eval/cache/`` (:mod:`suite_cache`);
2. lidar3d (``lidar3d.run.run_bag``) and the peers KISS-ICP and GenZ-ICP (:mod:`suite_peers`) each
   run on its bag in a fresh process (:mod:`suite_worker`), whose peak RSS is recorded (its
   ``VmHWM``; the ``ru_maxrss`` that ``os.wait4`` returns is kept beside it);
3. each trajectory is scored against the ground truth and the simulated SPAN-CPT log
   (:mod:`suite_metrics`), and lidar3d's health flags against the truth (:mod:`health_check`);
4. everything lands in ``eval/results/<UTC time>/`` (``results.json``, per-run outputs, SPAN
   reports, ``benchmarks.md``) and the tables in ``BENCHMARKS.md`` at the repository root
   (:mod:`suite_report`).

Usage::

    .venv/bin/python eval/run_suite.py                          # everything, full length (make bench)
    .venv/bin/python eval/run_suite.py --scenarios loop --duration 10 --no-peers
    .venv/bin/python eval/run_suite.py --profile fast --duration 20   # where the time goes

Peers need the ``eval`` extra (``pip install -e ".[eval]"``); a peer that is not installed is
skipped with a note. ``--profile SCENARIO`` runs lidar3d in-process under pyinstrument (cProfile
when pyinstrument is missing) and prints time per stage and per function instead of the suite.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import shlex
import subprocess
import sys
import time
from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
for entry in (str(REPO), str(HERE)):
    if entry not in sys.path:
        sys.path.insert(0, entry)

from closure_check import check_closures  # noqa: E402
from health_check import check_health  # noqa: E402
from suite_cache import DEFAULT_CACHE, CachedScenario, ensure_scenario, installed_version, installed_versions  # noqa: E402
from suite_metrics import loop_closures, score_trajectory  # noqa: E402
from suite_peers import PEERS  # noqa: E402
from suite_report import METHOD_NAMES, render_markdown  # noqa: E402

from lidar3d.errors import Lidar3dError  # noqa: E402
from lidar3d.io.atomic import write_text_atomic  # noqa: E402

SCENARIOS = ("loop", "long", "hilly", "fast", "stops", "blind_turn", "figure_eight", "city_traffic", "forest_trail")
DEFAULT_RESULTS = REPO / "eval" / "results"
DEFAULT_BENCHMARKS = REPO / "BENCHMARKS.md"
QUICK_COMMAND = ".venv/bin/python eval/run_suite.py --duration 20"
# The numeric stack behind lidar3d's figures, recorded in every results header (`make bench` installs
# the versions of eval/constraints.txt).
LIBRARIES = ("numpy", "scipy", "numba", "pykdtree", "small_gicp", "gtsam", "open3d", "rosbags")


def _log(message: str) -> None:
    print(f"[{dt.datetime.now(dt.timezone.utc):%H:%M:%S}] {message}", flush=True)


# --- running one method in its own process ------------------------------------------------------

TREE_SAMPLE_S = 0.1


def _children(pid: int) -> list[int]:
    """The child processes of ``pid`` (from every thread's ``children`` list; empty when gone)."""
    kids: list[int] = []
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            kids += [int(k) for k in (task / "children").read_text().split()]
    except OSError:
        pass
    return kids


def tree_rss_kib(pid: int) -> int:
    """Resident set (``VmRSS``, KiB) of ``pid`` and all its descendants, summed (0 off Linux).

    lidar3d reads the bag and runs the front end in a second process (``lidar3d.prefetch``), so a
    run's memory is the sum over the tree; a process's own ``VmHWM`` or ``ru_maxrss`` misses the
    child. Pages shared between the processes (the libraries both load) count once per process.
    """
    total = 0
    todo = [pid]
    while todo:
        current = todo.pop()
        try:
            for line in Path(f"/proc/{current}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1])
                    break
        except (OSError, ValueError, IndexError):
            continue
        todo += _children(current)
    return total


def run_worker(
    method: str,
    case: CachedScenario,
    out_dir: Path,
    *,
    genz_deskew: bool,
    timeout_s: float | None,
    loop_closure: bool = True,
    max_scans: int | None = None,
    start: int = 0,
) -> dict:
    """Run ``suite_worker.py`` for one method (on the first ``max_scans`` scans of the bag when
    given; lidar3d from scan ``start``); returns its ``run.json`` plus exit status, wall time of
    the whole process, its own peak RSS and the peak RSS of its process tree (:func:`tree_rss_kib`,
    sampled every ``TREE_SAMPLE_S``)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    command = [
        sys.executable,
        str(HERE / "suite_worker.py"),
        "--method",
        method,
        "--bag",
        str(case.bag),
        "--out",
        str(out_dir),
    ]
    if method == "genz-icp" and not genz_deskew:
        command.append("--genz-no-deskew")
    if method == "lidar3d" and not loop_closure:
        command.append("--no-loop")
    if max_scans is not None:
        command += ["--max-scans", str(max_scans)]
    if start:
        command += ["--start", str(start)]
    env = dict(os.environ, PYTHONWARNINGS="ignore")
    log_path = out_dir / "worker.log"
    t0 = time.perf_counter()
    peak_tree_kib = 0
    with open(log_path, "wb") as log_file:
        process = subprocess.Popen(command, stdout=log_file, stderr=subprocess.STDOUT, cwd=REPO, env=env)
        deadline = None if timeout_s is None else t0 + timeout_s
        while True:
            peak_tree_kib = max(peak_tree_kib, tree_rss_kib(process.pid))
            pid, status, usage = os.wait4(process.pid, os.WNOHANG)
            if pid:
                break
            if deadline is not None and time.perf_counter() > deadline:
                process.kill()
                pid, status, usage = os.wait4(process.pid, 0)
                break
            time.sleep(TREE_SAMPLE_S)
    process.returncode = os.waitstatus_to_exitcode(status)
    elapsed = time.perf_counter() - t0
    record: dict = {
        "exit_code": process.returncode,
        "process_wall_s": round(elapsed, 3),
        "peak_rss_mib": round(usage.ru_maxrss / 1024.0, 1),  # ru_maxrss is in KiB on Linux
        "cpu_s": round(usage.ru_utime + usage.ru_stime, 3),
        "peak_tree_rss_mib": round(peak_tree_kib / 1024.0, 1),
        "log": str(log_path),
    }
    run_json = out_dir / "run.json"
    if process.returncode == 0 and run_json.is_file():
        record["run"] = json.loads(run_json.read_text(encoding="utf-8"))
        record["status"] = "ok"
        hwm = record["run"].get("vm_hwm_kib")
        if hwm:  # the process's own peak; ru_maxrss also counts the parent's size at the fork
            record["ru_maxrss_mib"] = record["peak_rss_mib"]
            record["peak_rss_mib"] = round(hwm / 1024.0, 1)
    else:
        tail = log_path.read_text(encoding="utf-8", errors="replace").strip().splitlines()[-5:]
        timed_out = deadline is not None and elapsed >= (timeout_s or 0)
        record["status"] = "failed"
        record["error"] = ("timed out; " if timed_out else f"exit code {process.returncode}; ") + " | ".join(tail)
    return record


RECORD_NAME = "record.json"


def run_scored(
    method: str, case: CachedScenario, out_dir: Path, *, resume: bool = False, **worker_options: Any
) -> dict:
    """:func:`run_worker` with ``worker_options``, then its run scored in place
    (:func:`evaluate_run`); a scoring failure marks the record failed instead of raising, so it is
    reported in the table and never hides the other runs.

    The scored record is saved as ``out_dir/record.json`` as soon as it exists, so a benchmark
    stopped halfway keeps every run it finished. With ``resume``, a run whose saved record
    finished (status ok) with the same method, bag and options is not run again: its record is
    returned instead (:func:`saved_record`), marked ``resumed``."""
    task = {"method": method, "bag": str(case.bag), **worker_options}
    if resume and (saved := saved_record(out_dir, task)) is not None:
        return {**saved, "resumed": True}
    record = run_worker(method, case, out_dir, **worker_options)
    if record["status"] == "ok":
        try:
            evaluate_run(record, case, out_dir, method)
        except Exception as err:
            record["status"] = "failed"
            record["error"] = f"evaluation: {type(err).__name__}: {err}"
    record["task"] = task
    write_text_atomic(out_dir / RECORD_NAME, json.dumps(record, indent=1, default=str) + "\n")
    return record


def run_tasks(
    tasks: Sequence[Hashable],
    work: Callable[[Any], dict],
    jobs: int,
    after_each: Callable[[dict], None] | None = None,
) -> dict:
    """``work(task)`` for every task, ``jobs`` at a time; returns ``{task: record}``. After each
    finishes, ``after_each`` gets the records so far (where a tool rewrites its partial results)."""
    records: dict = {}
    with ThreadPoolExecutor(max_workers=jobs) as pool:
        futures = {pool.submit(work, task): task for task in tasks}
        for future in as_completed(futures):
            records[futures[future]] = future.result()
            if after_each is not None:
                after_each(records)
    return records


def saved_record(out_dir: Path, task: dict) -> dict | None:
    """The record :func:`run_scored` saved in ``out_dir`` for the same ``task`` (method, bag and
    worker options, compared as JSON would store them) if that run finished; None otherwise
    (none saved, unreadable, failed, or another task)."""
    try:
        record = json.loads((out_dir / RECORD_NAME).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    same_task = record.get("task") == json.loads(json.dumps(task, default=str))
    return record if same_task and record.get("status") == "ok" else None


def evaluate_run(record: dict, case: CachedScenario, out_dir: Path, method: str) -> None:
    """Score a finished run in ``record`` (its trajectory against the truth and the SPAN log; lidar3d's
    health flags too), in place."""
    trajectory = out_dir / "trajectory_tum.txt"
    record["scores"] = score_trajectory(
        trajectory,
        ground_truth_path=case.ground_truth_dense,
        span_log=case.span_log,
        extrinsics=case.extrinsics,
        report_dir=out_dir / "span_eval",
    )
    record["loop_closures"] = loop_closures(record["run"].get("counts", {}))
    if method == "lidar3d":
        try:
            record["health"] = check_health(out_dir, case.ground_truth_dense)
        except Lidar3dError as err:  # reported in the health table, never hides the other scores
            record["health"] = {"error": str(err)}
        if (out_dir / "pose_graph.g2o").is_file():
            try:
                record["closures"] = check_closures(out_dir, case.ground_truth_dense)
            except Lidar3dError as err:
                record["closures"] = {"error": str(err)}


# --- header facts ------------------------------------------------------------------------------


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _memory_gib() -> float:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (ValueError, OSError):
        return float("nan")


def _commit() -> str:
    try:
        sha = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=REPO,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        untracked = subprocess.run(
            ["git", "status", "--porcelain"], cwd=REPO, capture_output=True, text=True, check=True
        ).stdout.strip()
        return f"`{sha}`" + (" with uncommitted changes" if dirty or untracked else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown (not a git checkout)"


def _busy(load_text: str, n_cpus: int) -> bool:
    """Whether the 1-minute load average before the suite started says other work was running."""
    try:
        return float(load_text.split()[0]) >= 0.25 * n_cpus
    except (ValueError, IndexError):
        return False


def _load() -> str:
    try:
        return " ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "n/a"


# --- the suite -------------------------------------------------------------------------------------


def run_suite(args: argparse.Namespace) -> int:
    t_start = time.perf_counter()
    started = dt.datetime.now(dt.timezone.utc)
    load_start = _load()
    methods = [] if args.peers_only else ["lidar3d"]
    skipped: list[str] = []
    if not args.no_peers:
        for peer in args.peers:
            if installed_version(peer) is None:
                skipped.append(f"{METHOD_NAMES[peer]} is not installed (pip install -e '.[eval]')")
            else:
                methods.append(peer)
    for note in skipped:
        _log(f"note: {note}; skipped")

    run_dir = args.resume or args.results_dir / started.strftime("%Y%m%dT%H%M%SZ")
    run_dir.mkdir(parents=True, exist_ok=True)
    cases: list[CachedScenario] = []
    for scenario in args.scenarios:
        for seed in args.seeds:
            t0 = time.perf_counter()
            case = ensure_scenario(scenario, seed, args.duration, cache_dir=args.cache_dir, regenerate=args.regenerate)
            verb = "generated" if case.generated else "cached"
            where = case.folder.relative_to(REPO) if case.folder.is_relative_to(REPO) else case.folder
            _log(
                f"{case.label}: {verb} {where} ({case.n_scans} scans, {case.path_length_m:.0f} m) "
                f"in {time.perf_counter() - t0:.1f} s"
            )
            cases.append(case)

    tasks = [(case, method) for case in cases for method in methods]

    def work(task: tuple[CachedScenario, str]) -> dict:
        case, method = task
        out_dir = run_dir / f"{case.scenario}_s{case.seed}" / method
        _log(f"{case.label}: {METHOD_NAMES[method]} running")
        record = run_scored(
            method,
            case,
            out_dir,
            genz_deskew=not args.genz_no_deskew,
            timeout_s=args.timeout,
            loop_closure=not args.no_loop,
            max_scans=args.max_scans,
            resume=args.resume is not None,
        )
        record.update(
            scenario=case.scenario,
            seed=case.seed,
            method=method,
            case={
                "n_scans": case.n_scans,
                "path_length_m": case.path_length_m,
                "duration_s": case.sim_duration_s,
                "revisit_events": case.revisit_events,
                "folder": str(case.folder),
            },
        )
        if record["status"] == "ok":
            ate = record["scores"].get("gt", {}).get("ate_rmse_m", {}).get("3d")
            _log(
                f"{case.label}: {METHOD_NAMES[method]} done: {record['run']['scans']} scans, "
                f"{record['run']['wall_s']:.1f} s, {record['run']['scans_per_s']:.1f} scans/s, "
                f"ATE {ate if ate is not None else 'n/a'} m, peak RSS {record['peak_rss_mib']:.0f} MiB"
                + (" (finished earlier: its saved record)" if record.get("resumed") else "")
            )
        else:
            _log(f"{case.label}: {METHOD_NAMES[method]} FAILED: {record['error']}")
        return record

    if args.jobs > 1:
        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            rows = list(pool.map(work, tasks))
    else:
        rows = [work(task) for task in tasks]

    elapsed_min = (time.perf_counter() - t_start) / 60.0
    load_end = _load()
    fractions = {}
    for row in rows:
        if row["status"] == "ok" and "reference_fraction" in row["run"]:
            fractions[row["method"]] = row["run"]["reference_fraction"]
    durations_text = (
        "full length of each scenario"
        if args.duration is None
        else f"**only the first {args.duration:g} s of each scenario** (a shortened run, not the full suite)"
    )
    if args.max_scans is not None:
        durations_text += f"; **every method ran on the first {args.max_scans} scans of each bag only**"
    peer_versions = {METHOD_NAMES[p]: (installed_version(p) or "not installed") for p in PEERS}
    n_cpus = os.cpu_count() or 1
    header = {
        "command": args.command_text,
        "date_utc": started.strftime("%Y-%m-%d %H:%M UTC"),
        "elapsed_min": elapsed_min,
        "cpu": _cpu_model(),
        "n_cpus": n_cpus,
        "memory_gib": _memory_gib(),
        "load_start": load_start,
        "load_end": load_end,
        "shared_cpu": args.shared_cpu or _busy(load_start, n_cpus),
        "lidar3d_version": _lidar3d_version(),
        "commit": _commit(),
        "python": platform.python_version(),
        "peer_versions": peer_versions,
        "library_versions": installed_versions(LIBRARIES),
        "seeds": args.seeds,
        "durations_text": durations_text,
        "jobs": args.jobs,
        "peer_fractions": fractions,
        "quick_command": QUICK_COMMAND,
        "skipped": skipped,
    }
    markdown = render_markdown(rows, header)
    (run_dir / "results.json").write_text(
        json.dumps({"header": header, "rows": rows}, indent=1, default=str) + "\n", encoding="utf-8"
    )
    (run_dir / "benchmarks.md").write_text(markdown, encoding="utf-8")
    if args.benchmarks is not None:
        tmp = args.benchmarks.with_name(args.benchmarks.name + ".tmp")
        tmp.write_text(markdown, encoding="utf-8")
        tmp.replace(args.benchmarks)
        _log(f"wrote {args.benchmarks}")
    _log(f"results in {run_dir} ({elapsed_min:.1f} min)")
    print()
    print(markdown)
    return 0 if all(r["status"] == "ok" for r in rows) else 1


def _lidar3d_version() -> str:
    from lidar3d import __version__

    return __version__


# --- command line ---------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="eval/run_suite.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--scenarios",
        nargs="+",
        choices=SCENARIOS,
        default=list(SCENARIOS),
        metavar="NAME",
        help=f"scenarios to run (default: all of {', '.join(SCENARIOS)})",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="simulate only the first S seconds of each scenario (quick runs); default: full length",
    )
    parser.add_argument(
        "--max-scans",
        type=int,
        default=None,
        metavar="N",
        help="run every method on the first N scans of each bag only (quick side-by-side timing)",
    )
    parser.add_argument("--seeds", type=int, nargs="+", default=[0], metavar="N", help="simulation seeds (default: 0)")
    parser.add_argument("--no-peers", action="store_true", help="run lidar3d only")
    parser.add_argument(
        "--peers-only", action="store_true", help="run the peers only (their results do not depend on lidar3d's code)"
    )
    parser.add_argument(
        "--no-loop",
        action="store_true",
        help="lidar3d with loop closure off (odometry and mapping alone, as the odometry targets are set)",
    )
    parser.add_argument(
        "--peers",
        nargs="+",
        choices=list(PEERS),
        default=list(PEERS),
        metavar="PEER",
        help="peers to run beside lidar3d (default: kiss-icp genz-icp)",
    )
    parser.add_argument(
        "--genz-no-deskew",
        action="store_true",
        help="run GenZ-ICP with its outdoor preset's deskew: false (default: deskew on)",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=1,
        metavar="N",
        help="runs at a time (default 1; more makes the timings compete for the CPU)",
    )
    parser.add_argument("--timeout", type=float, default=None, metavar="S", help="give up a single run after S seconds")
    parser.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE, help="simulation cache (default: eval/cache)")
    parser.add_argument("--regenerate", action="store_true", help="regenerate the cached simulations")
    parser.add_argument("--results-dir", type=Path, default=DEFAULT_RESULTS, help="default: eval/results")
    parser.add_argument(
        "--resume",
        type=Path,
        metavar="RUN_DIR",
        help="finish an interrupted suite in its folder (eval/results/<UTC time>): runs it finished with the "
        "same options are scored from their saved record.json, the rest are run",
    )
    parser.add_argument(
        "--benchmarks",
        type=Path,
        default=DEFAULT_BENCHMARKS,
        help="Markdown table to write (default: BENCHMARKS.md at the repository root)",
    )
    parser.add_argument(
        "--no-benchmarks",
        dest="benchmarks",
        action="store_const",
        const=None,
        help="leave BENCHMARKS.md alone (tables still go to the results folder)",
    )
    parser.add_argument(
        "--shared-cpu",
        action="store_true",
        help="state in BENCHMARKS.md that the CPU was shared with other work during the run",
    )
    parser.add_argument(
        "--render",
        type=Path,
        metavar="RESULTS_JSON",
        help="only rewrite the tables from an earlier run's results.json (no runs)",
    )
    parser.add_argument(
        "--profile",
        choices=SCENARIOS,
        metavar="SCENARIO",
        help="profile lidar3d on one scenario (time per stage and per function) instead of the suite",
    )
    parser.add_argument(
        "--profiler",
        choices=("auto", "pyinstrument", "cprofile"),
        default="auto",
        help="profile mode: pyinstrument if installed (auto), or cProfile",
    )
    parser.add_argument("--top", type=int, default=30, help="profile mode: functions to list (default 30)")
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    if args.jobs < 1:
        raise SystemExit("--jobs must be at least 1")
    if args.max_scans is not None and args.max_scans < 1:
        raise SystemExit("--max-scans must be at least 1")
    if args.duration is not None and args.duration <= 0:
        raise SystemExit("--duration must be positive")
    if args.resume is not None and not args.resume.is_dir():
        raise SystemExit(f"--resume {args.resume}: not a folder of an earlier suite run")
    args.command_text = " ".join([".venv/bin/python eval/run_suite.py", *(shlex.quote(a) for a in argv)]).strip()
    if args.profile:
        from suite_profile import profile_scenario

        return profile_scenario(args)
    if args.render:
        return render_results(args.render, args.benchmarks)
    return run_suite(args)


def render_results(results_json: Path, benchmarks: Path | None) -> int:
    """Rewrite ``benchmarks.md`` beside ``results_json`` (and ``benchmarks``) from its rows."""
    data = json.loads(Path(results_json).read_text(encoding="utf-8"))
    markdown = render_markdown(data["rows"], data["header"])
    Path(results_json).with_name("benchmarks.md").write_text(markdown, encoding="utf-8")
    if benchmarks is not None:
        benchmarks.write_text(markdown, encoding="utf-8")
    print(markdown)
    return 0


if __name__ == "__main__":
    sys.exit(main())
