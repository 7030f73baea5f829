"""``lidar3d batch`` end to end with the local engine on tiny simulated drives (2 s each).

One corrupt bag among them; SPAN logs matched by time overlap; a re-run skips, ``--overwrite`` redoes;
Ctrl-C stops cleanly, a SIGKILL mid-batch is resumed without redoing finished bags; the HTML
report is opened in headless Chromium (skipped when it is not installed).
"""

from __future__ import annotations

import csv
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lidar3d.batch import JobStatus, run_batch
from lidar3d.batch.jobs import JOB_FILE
from lidar3d.cli.main import main
from lidar3d.io.run_folder import RunFolderState, check_run_folder
from lidar3d.summary import read_summary

DURATION_S = 2.0
HOUR_NS = 3600 * 10**9
GOOD = ("a", "b", "c")  # c is a ROS2 bag folder
NAMES = {"a": "a__scans", "b": "b__scans", "c": "c__scans", "bad": "bad__scans"}
OUTPUTS = ("trajectory_tum.txt", "trajectory_kitti.txt", "odometry_tum.txt", "keyframes_tum.txt", "map.pcd")


def simulate_bags(root: Path, names=GOOD, *, with_corrupt: bool = True, durations_s: dict | None = None) -> Path:
    """``root/data/<name>/`` drives an hour apart (ROS1, ``c`` ROS2), their logs in ``root/spans``;
    each ``DURATION_S`` long unless ``durations_s`` says otherwise."""
    from lidar3d.sim import DEFAULT_START_TIME_NS, Simulation, write_simulation

    data, spans = root / "data", root / "spans"
    spans.mkdir(parents=True)
    for index, name in enumerate(names):
        duration_s = (durations_s or {}).get(name, DURATION_S)
        sim = Simulation(
            "loop", seed=index, duration_s=duration_s, start_time_ns=DEFAULT_START_TIME_NS + index * HOUR_NS
        )
        outputs = write_simulation(sim, data / name, bag_format="ros2" if name == "c" else "ros1")
        shutil.copy(outputs.span_log, spans / f"span_{name}.log")
    if with_corrupt:
        (data / "bad").mkdir()
        rng = random.Random(8)
        (data / "bad" / "scans.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(rng.randrange(256) for _ in range(20000)))
    return data


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    return simulate_bags(tmp_path_factory.mktemp("batch"))


@pytest.fixture(scope="module")
def first_run(drives):
    out = drives.parent / "out"
    outcome = run_batch(
        [drives],
        out,
        span_dir=drives.parent / "spans",
        extrinsics=drives / "a" / "extrinsics.toml",
        workers=2,
    )
    return outcome


def _rows(out: Path) -> dict[str, dict]:
    return {row["name"]: row for row in json.loads((out / "summary.json").read_text())["bags"]}


def _mtime(path: Path) -> int:
    return path.stat().st_mtime_ns


def test_corrupt_bag_is_reported_and_the_others_finish(first_run, drives):
    out = first_run.out_dir
    assert first_run.counts["done"] == 3 and first_run.counts["failed"] == 1
    assert first_run.names(JobStatus.FAILED) == [NAMES["bad"]]
    rows = _rows(out)
    assert re.search(r"bad/scans\.bag: not a readable ROS1 bag", rows[NAMES["bad"]]["error"])
    assert not (out / NAMES["bad"]).exists()
    for name in GOOD:
        folder = out / NAMES[name]
        row = rows[NAMES[name]]
        assert row["status"] == "done" and row["scans"] == 20 and row["length_m"] > 1.0
        assert row["span_log"].endswith(f"span_{name}.log") and "time overlap" in row["span_match"]
        assert row["ate_rmse_m"] is not None and row["ate_rmse_m"] < 1.0
        assert row["plots"] and all((out / p).is_file() for p in row["plots"])
        for output in (*OUTPUTS, "summary.json", "config.toml", JOB_FILE, "eval/report.json"):
            assert (folder / output).is_file(), output
        summary = read_summary(folder / "summary.json")
        assert summary.partial is False
        assert summary.evaluation is not None
        assert summary.evaluation.report == str(folder / "eval")  # staging path rewritten
        check = check_run_folder(folder, extra=(JOB_FILE,))  # ... and the manifest with it
        assert check.state is RunFolderState.CONSISTENT and check.unnamed == ()
    assert not [p for p in out.iterdir() if ".partial-" in p.name or ".old-" in p.name]
    with open(out / "summary.csv", newline="") as handle:
        table = list(csv.DictReader(handle))
    assert [r["name"] for r in table] == [NAMES[n] for n in ("a", "b", "bad", "c")]
    assert {r["status"] for r in table} == {"done", "failed"}
    html = (out / "report.html").read_text()
    assert html.count('<tr class="bag"') == 4 and "<script>" in html and "http" not in html.split("<body>")[1]


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def _dump_dom(browser: str, url: str, profile: Path) -> str:
    command = [
        browser,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        f"--user-data-dir={profile}",
        "--dump-dom",
        url,
    ]
    done = subprocess.run(command, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


@pytest.mark.skipif(_chromium() is None, reason="headless Chromium not installed (Debian package 'chromium')")
def test_report_renders_and_sorts_in_chromium(first_run, tmp_path):
    report = first_run.report.html
    expected = _rows(first_run.out_dir)
    url = report.as_uri()
    dom = _dump_dom(_chromium(), url + "#sort=ate_rmse_m:desc", tmp_path / "profile")
    order = re.findall(r'<tr class="bag" data-name="([^"]+)"', dom)
    assert sorted(order) == sorted(expected)  # every row rendered
    assert 'data-sort="ate_rmse_m:desc"' in dom  # the page's script ran
    ates = [expected[name]["ate_rmse_m"] for name in order]
    numbers = [a for a in ates if a is not None]
    assert numbers == sorted(numbers, reverse=True) and ates[-1] is None  # bags without ATE last
    assert re.search(
        r'data-key="ate_rmse_m"[^>]*aria-sort="descending"|aria-sort="descending"[^>]*data-key="ate_rmse_m"', dom
    )

    dom = _dump_dom(_chromium(), url + "#sort=name:asc", tmp_path / "profile")
    order = re.findall(r'<tr class="bag" data-name="([^"]+)"', dom)
    assert order == sorted(expected)


def test_rerun_skips_finished_bags_and_overwrite_redoes_them(first_run, drives):
    out = first_run.out_dir
    stamps = {n: _mtime(out / NAMES[n] / JOB_FILE) for n in GOOD}
    trajectories = {n: (out / NAMES[n] / "trajectory_tum.txt").read_bytes() for n in GOOD}
    args = [
        "batch",
        str(drives),
        "--out",
        str(out),
        "--span-dir",
        str(drives.parent / "spans"),
        "--extrinsics",
        str(drives / "a" / "extrinsics.toml"),
        "--workers",
        "2",
    ]

    assert main(args) == 1  # the corrupt bag still fails
    rows = _rows(out)
    assert {rows[NAMES[n]]["status"] for n in GOOD} == {"up to date"}
    assert rows[NAMES["bad"]]["status"] == "failed"
    assert {n: _mtime(out / NAMES[n] / JOB_FILE) for n in GOOD} == stamps

    # --overwrite on two of them (the same names, as they still collide): both redone, c left alone.
    assert main(["batch", str(drives / "a"), str(drives / "b"), *args[2:], "--overwrite"]) == 0
    rows = _rows(out)
    assert set(rows) == {NAMES["a"], NAMES["b"]}
    assert {row["status"] for row in rows.values()} == {"done"}
    for name in ("a", "b"):
        assert _mtime(out / NAMES[name] / JOB_FILE) != stamps[name]
        assert (out / NAMES[name] / "trajectory_tum.txt").read_bytes() == trajectories[name]
    assert _mtime(out / NAMES["c"] / JOB_FILE) == stamps["c"]


def _interactive_sigint() -> None:
    """In the child before exec: SIGINT as a terminal gives it. A test run started in the background
    of a non-interactive shell (a CI script, ``cmd &``) ignores SIGINT, the child would inherit that,
    and Python keeps an inherited SIG_IGN, so the test's Ctrl-C would never arrive."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start_cli(args: list[str]) -> subprocess.Popen:
    code = "import sys; from lidar3d.cli.main import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.Popen(
        [sys.executable, "-c", code, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group: signals reach the workers as Ctrl-C would
        preexec_fn=_interactive_sigint,
    )


def _wait_for(condition, process: subprocess.Popen, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not condition():
        if process.poll() is not None:
            out, err = process.communicate()
            pytest.fail(f"batch ended early ({process.returncode}):\n{out}\n{err}")
        if time.monotonic() > deadline:
            os.killpg(process.pid, signal.SIGKILL)
            pytest.fail("timed out waiting for the batch")
        time.sleep(0.05)


def test_ctrl_c_then_kill_then_resume_redoes_only_unfinished_bags(tmp_path):
    # b and c run for several seconds each, so the signals below land while they run even on a
    # loaded machine (with 2 s bags the whole batch could finish before the test saw "a" done).
    drives = simulate_bags(tmp_path / "drives", with_corrupt=False, durations_s={"b": 8.0, "c": 8.0})
    out = tmp_path / "out"
    args = ["batch", *(str(drives / n) for n in GOOD), "--out", str(out), "--workers", "1"]
    published = lambda name: (out / NAMES[name] / JOB_FILE).exists()  # noqa: E731

    # 1. Ctrl-C once the first bag is published: a clean stop that says what finished.
    process = _start_cli(args)
    _wait_for(lambda: published("a"), process)
    os.killpg(process.pid, signal.SIGINT)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    assert re.search(r"interrupted; finished: a__scans; stopped: .*; not started: .*c__scans", stderr)
    rows = _rows(out)
    assert rows[NAMES["a"]]["status"] == "done"
    assert rows[NAMES["c"]]["status"] == "not started"
    assert rows[NAMES["b"]]["status"] in ("interrupted", "not started")
    assert not published("b") and not published("c")
    assert not [p for p in out.iterdir() if ".partial-" in p.name]
    first = _mtime(out / NAMES["a"] / JOB_FILE)

    # 2. Run again and SIGKILL everything as soon as the next bag is published.
    process = _start_cli(args)
    _wait_for(lambda: published("b"), process)
    os.killpg(process.pid, signal.SIGKILL)
    process.communicate(timeout=60)
    assert _mtime(out / NAMES["a"] / JOB_FILE) == first  # not redone
    second = _mtime(out / NAMES["b"] / JOB_FILE)
    assert not published("c")

    # 3. Resume: only c runs.
    assert main(args) == 0
    rows = _rows(out)
    assert [rows[NAMES[n]]["status"] for n in GOOD] == ["up to date", "up to date", "done"]
    assert _mtime(out / NAMES["a"] / JOB_FILE) == first and _mtime(out / NAMES["b"] / JOB_FILE) == second
    assert all((out / NAMES[n] / "trajectory_tum.txt").is_file() for n in GOOD)
    assert not [p for p in out.iterdir() if ".partial-" in p.name or ".old-" in p.name]


def test_a_failed_evaluation_still_publishes_the_slam_outputs(drives, tmp_path):
    wrong_log = drives.parent / "spans" / "span_b.log"  # b's drive, an hour after a's
    outcome = run_batch([drives / "a"], tmp_path / "out", span_pattern=str(wrong_log), workers=1)
    (row,) = outcome.rows
    assert row["status"] == "done" and row["error"] is None
    assert row["note"].startswith(f"evaluation against {wrong_log} failed: no time overlap")
    assert row["ate_rmse_m"] is None and row["scans"] == 20
    folder = outcome.out_dir / row["name"]
    assert all((folder / output).is_file() for output in OUTPUTS)
    assert json.loads((folder / JOB_FILE).read_text())["note"] == row["note"]
    check = check_run_folder(folder, extra=(JOB_FILE,))
    assert check.state is RunFolderState.CONSISTENT and check.summary.evaluation_error is not None


def test_a_folder_that_is_not_the_set_its_summary_describes_is_not_up_to_date(drives, tmp_path):
    first = run_batch([drives / "a"], tmp_path / "out", workers=1)
    folder = first.out_dir / first.rows[0]["name"]
    assert run_batch([drives / "a"], tmp_path / "out", workers=1).counts["up to date"] == 1
    with open(folder / "map.pcd", "ab") as handle:  # damaged (or replaced) after publication
        handle.write(b"\0")
    again = run_batch([drives / "a"], tmp_path / "out", workers=1)
    assert again.counts["done"] == 1
    assert check_run_folder(folder, extra=(JOB_FILE,)).state is RunFolderState.CONSISTENT
