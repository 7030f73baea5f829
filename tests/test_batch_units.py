"""Pieces of ``lidar3d batch``: discovery, fingerprints, SPAN-log matching, publishing, the report,
progress, option errors, and a worker process that dies (the local engine names the bag)."""

from __future__ import annotations

import csv
import io
import json
import os
import re
import shutil
import sys
from pathlib import Path

import pytest
from terminal import Terminal, screen_lines
from test_summary import example_summary

from lidar3d.batch import JobResult, JobStatus, content_fingerprint, discover_bags, job_fingerprint, run_batch
from lidar3d.batch import span_match as span_match_module
from lidar3d.batch.discovery import BagInput, bag_names
from lidar3d.batch.engines import run_local
from lidar3d.batch.fingerprint import EDGE_BYTES, N_SAMPLES, SAMPLE_BYTES
from lidar3d.batch.jobs import BagJob, process_job, publish_folder, staging_folders
from lidar3d.batch.progress import BatchProgress, ProgressDisplay, format_duration
from lidar3d.batch.report import ROW_FIELDS, bag_row, write_report
from lidar3d.batch.span_match import TimeRangeCache, match_span_logs, resolve_extrinsics
from lidar3d.cli.main import main
from lidar3d.errors import BagError, ConfigError, OutputError

S = 10**9


def touch(path: Path, data: bytes = b"#ROSBAG V2.0\n") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


# -- discovery ------------------------------------------------------------------------------------
@pytest.fixture
def tree(tmp_path):
    touch(tmp_path / "d" / "x" / "drive.bag")
    touch(tmp_path / "d" / "y" / "drive.bag")
    touch(tmp_path / "d" / "r2" / "metadata.yaml", b"rosbag2_bagfile_information: {}\n")
    touch(tmp_path / "d" / "r2" / "r2_0.db3", b"SQLite format 3\x00")
    touch(tmp_path / "d" / ".hidden" / "z.bag")
    touch(tmp_path / "d" / "lone.mcap", b"\x89MCAP0\r\n")
    touch(tmp_path / "d" / "notes.txt", b"not a bag")
    return tmp_path / "d"


def test_folders_are_searched_for_ros1_ros2_and_storage_files(tree):
    bags = discover_bags([tree])
    assert [(b.name, b.kind, b.path.relative_to(tree).as_posix()) for b in bags] == [
        ("lone", "ros2-storage", "lone.mcap"),
        ("r2", "ros2", "r2"),
        ("x__drive", "ros1", "x/drive.bag"),
        ("y__drive", "ros1", "y/drive.bag"),
    ]
    assert all(b.path.is_absolute() for b in bags)


def test_globs_files_and_ros2_folders_without_duplicates(tree):
    bags = discover_bags(
        [str(tree / "*" / "drive.bag"), tree / "x" / "drive.bag", tree / "r2", tree / "r2" / "r2_0.db3"]
    )
    assert [b.name for b in bags] == ["x__drive", "y__drive", "r2"]
    assert discover_bags([tree / "x" / "drive.bag"])[0].name == "drive"  # no collision, short name


def test_discovery_errors_name_the_input(tmp_path, tree):
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match=r"missing\.bag: no such file or folder"):
        discover_bags([tmp_path / "missing.bag"])
    with pytest.raises(BagError, match=r"empty: no bag in this folder"):
        discover_bags([tmp_path / "empty"])
    with pytest.raises(BagError, match=r"no bag matches this pattern"):
        discover_bags([str(tree / "*.nothing")])
    with pytest.raises(BagError, match="no input given"):
        discover_bags([])


def test_names_grow_only_where_they_collide():
    paths = [Path("/r/a/b/s.bag"), Path("/r/c/b/s.bag"), Path("/r/a/t.bag"), Path("/r/a/we ird.bag")]
    assert bag_names(paths, ["ros1"] * 4) == ["a__b__s", "c__b__s", "t", "we_ird"]
    assert bag_names([Path("/s.bag"), Path("/s.bag")], ["ros1"] * 2) == ["s", "s-2"]


# -- fingerprints -----------------------------------------------------------------------------------
def test_content_fingerprint_follows_content_not_names_or_times(tmp_path):
    big = bytearray(os.urandom(5 * EDGE_BYTES))
    a = touch(tmp_path / "a.bag", bytes(big))
    b = tmp_path / "copy.bag"
    shutil.copy(a, b)
    os.utime(b, (1, 1))
    assert content_fingerprint(a) == content_fingerprint(b)  # another name and mtime: same bag
    sampled = EDGE_BYTES + (len(big) - 2 * EDGE_BYTES) // (N_SAMPLES + 1)  # centre of the first interior sample
    for offset in (10, len(big) - 10, sampled):  # header, tail, a sampled interior block
        changed = bytearray(big)
        changed[offset] ^= 0xFF
        touch(b, bytes(changed))
        assert content_fingerprint(b) != content_fingerprint(a), offset
    changed = bytearray(big)
    changed[sampled + SAMPLE_BYTES] ^= 0xFF  # between samples: the documented blind spot (use --overwrite)
    touch(b, bytes(changed))
    assert content_fingerprint(b) == content_fingerprint(a)
    touch(b, bytes(big) + b"x")
    assert content_fingerprint(b) != content_fingerprint(a)
    small = touch(tmp_path / "small.bag", b"abc")
    before = content_fingerprint(small)
    touch(small, b"abd")
    assert content_fingerprint(small) != before
    with pytest.raises(BagError, match="no such file"):
        content_fingerprint(tmp_path / "nope")


def test_folder_fingerprint_covers_every_file(tree):
    before = content_fingerprint(tree / "r2")
    touch(tree / "r2" / "r2_0.db3", b"SQLite format 3\x00changed")
    assert content_fingerprint(tree / "r2") != before


def test_job_fingerprint_changes_with_config_logs_and_version():
    base = {"span_fingerprint": "s", "extrinsics_fingerprint": None, "version": "1"}
    reference = job_fingerprint("bag", "[odometry]\nx = 1\n", **base)
    assert reference == job_fingerprint("bag", "[odometry]\nx = 1\n", **base)
    assert reference != job_fingerprint("bag", "[odometry]\nx = 2\n", **base)
    assert reference != job_fingerprint("bag2", "[odometry]\nx = 1\n", **base)
    assert reference != job_fingerprint("bag", "[odometry]\nx = 1\n", **{**base, "span_fingerprint": None})
    assert reference != job_fingerprint("bag", "[odometry]\nx = 1\n", **{**base, "extrinsics_fingerprint": "e"})
    assert reference != job_fingerprint("bag", "[odometry]\nx = 1\n", **{**base, "version": "2"})


# -- SPAN log matching ------------------------------------------------------------------------------
def _bag(path: Path, name: str | None = None) -> BagInput:
    return BagInput(path, name or path.stem, "ros1")


def test_pattern_matching_with_placeholders(tmp_path):
    one = _bag(touch(tmp_path / "day1" / "drive.bag"))
    two = _bag(touch(tmp_path / "day2" / "other.bag"))
    touch(tmp_path / "day1" / "drive.gps", b"")
    touch(tmp_path / "logs" / "day2.log", b"")
    matches = match_span_logs([one, two], span_pattern="{stem}.gps")
    assert matches["drive"].span_log == tmp_path / "day1" / "drive.gps" and matches["drive"].how == "pattern"
    assert matches["other"].span_log is None and matches["other"].how.startswith("no file ")
    pattern = str(tmp_path / "logs" / "{folder}.log")
    assert match_span_logs([two], span_pattern=pattern)["other"].span_log == tmp_path / "logs" / "day2.log"
    with pytest.raises(ConfigError, match=r"unknown placeholder \{oops\}"):
        match_span_logs([one], span_pattern="{oops}.log")
    with pytest.raises(ConfigError, match="not both"):
        match_span_logs([one], span_pattern="x", span_dir=tmp_path)
    assert match_span_logs([one])["drive"].span_log is None


def test_time_overlap_picks_the_longest_overlap_and_caches_spans(tmp_path, monkeypatch):
    bags = [_bag(touch(tmp_path / "bags" / f"{n}.bag", n.encode())) for n in ("early", "late", "never")]
    bag_ranges = {"early": (100 * S, 200 * S), "late": (1000 * S, 1100 * S), "never": (5000 * S, 5100 * S)}
    logs = tmp_path / "logs"
    touch(logs / "morning.log", b"1")
    touch(logs / "noon.log", b"2")
    touch(logs / "evening.txt", b"3")
    touch(logs / "rig.yaml", b"not a log")
    touch(logs / "stray.bag.part", b"#ROSBAG V2.0\n")  # bag bytes: never read as a log
    log_ranges = {"morning.log": (0, 150 * S), "noon.log": (120 * S, 1010 * S), "evening.txt": (1050 * S, 2000 * S)}
    reads: list[str] = []

    def fake_log_range(path, gnss_config=None):
        reads.append(Path(path).name)
        return log_ranges[Path(path).name]

    monkeypatch.setattr(span_match_module, "bag_time_range", lambda path: bag_ranges[Path(path).stem])
    monkeypatch.setattr(span_match_module, "log_time_range", fake_log_range)
    cache_path = tmp_path / "cache.json"
    matches = match_span_logs(bags, span_dir=logs, cache=TimeRangeCache(cache_path))
    assert matches["early"].span_log == (logs / "noon.log").resolve()  # 80 s beats 50 s
    assert matches["early"].how == "time overlap 80.0 s (80% of the bag)"
    assert matches["late"].span_log == (logs / "evening.txt").resolve()
    assert matches["never"].span_log is None and "overlaps the bag" in matches["never"].how
    assert sorted(reads) == ["evening.txt", "morning.log", "noon.log"]

    monkeypatch.setattr(span_match_module, "log_time_range", lambda *a: pytest.fail("read again"))
    monkeypatch.setattr(span_match_module, "bag_time_range", lambda *a: pytest.fail("read again"))
    again = match_span_logs(bags, span_dir=logs, cache=TimeRangeCache(cache_path))
    assert again == matches
    with pytest.raises(ConfigError, match="no such folder"):
        match_span_logs(bags, span_dir=tmp_path / "nowhere")


def test_extrinsics_one_file_or_a_pattern(tmp_path):
    bag = _bag(touch(tmp_path / "d" / "drive.bag"))
    rig = touch(tmp_path / "rig.toml", b"")
    assert resolve_extrinsics(rig, [bag]) == {"drive": rig.resolve()}
    assert resolve_extrinsics("{parent}/extrinsics.toml", [bag]) == {"drive": tmp_path / "d" / "extrinsics.toml"}
    assert resolve_extrinsics(None, [bag]) == {"drive": None}
    with pytest.raises(ConfigError, match="no such file"):
        resolve_extrinsics(tmp_path / "missing.toml", [bag])


# -- publishing ---------------------------------------------------------------------------------------
def test_publish_replaces_a_previous_folder_and_leaves_no_staging(tmp_path):
    final = tmp_path / "bag"
    touch(final / "old.txt", b"old")
    staging = tmp_path / ".bag.partial-1234"
    touch(staging / "new.txt", b"new")
    touch(tmp_path / ".other.partial-99" / "x", b"")
    assert [p.name for p in staging_folders(tmp_path)] == [".bag.partial-1234", ".other.partial-99"]
    publish_folder(staging, final)
    assert sorted(p.name for p in final.iterdir()) == ["new.txt"]
    assert [p.name for p in staging_folders(tmp_path)] == [".other.partial-99"]


def test_a_failing_bag_comes_back_as_a_result_and_leaves_nothing(tmp_path):
    bad = touch(tmp_path / "bad.bag", b"#ROSBAG V2.0\n" + bytes(range(256)) * 8)
    job = BagJob("bad", bad, tmp_path / "out" / "bad", "", "sha256:0")
    result = process_job(job)
    assert result.status is JobStatus.FAILED
    assert "not a readable ROS1 bag" in result.error
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


# -- report and progress ---------------------------------------------------------------------------------
def test_report_files_escape_and_keep_every_field(tmp_path):
    rows = [
        bag_row(name="a<script>", bag=Path("/b/a.bag"), status="failed", batch_dir=tmp_path, error="bad & <worse>"),
        bag_row(
            name="b",
            bag=Path("/b/b.bag"),
            status="done",
            batch_dir=tmp_path,
            summary=example_summary(scans=20, length_m=5.5, runtime_s=2.0, scans_per_s=10.0, loop_closures=2),
            eval_report={
                "rpe_kitti": {"translation_percent": 1.5},
                "rpe_distance": [{"distance_m": 10.0, "translation_m": {"rmse": 0.1}}],
            },
            rpe_distance_m=10.0,
        ),
    ]
    assert rows[1]["loop_closures"] == 2 and rows[1]["ate_rmse_m"] == 0.25
    assert rows[1]["rpe_rmse_m"] == 0.1 and rows[1]["rpe_kitti_percent"] == 1.5
    meta = {
        "out_dir": str(tmp_path),
        "engine": "local",
        "rpe_distance_m": 10.0,
        "totals": {"bags": 2, "by_status": {"done": 1, "failed": 1}, "scans": 20, "length_m": 5.5},
    }
    paths = write_report(tmp_path, rows, meta)
    page = paths.html.read_text()
    assert "a<script>" not in page and "a&lt;script&gt;" in page and "bad &amp; &lt;worse&gt;" in page
    assert "RPE 10 m [m]" in page and 'data-value="0.25"' in page
    table = list(csv.DictReader(io.StringIO(paths.csv.read_text())))
    assert tuple(table[0]) == ROW_FIELDS and table[1]["ate_rmse_m"] == "0.25"
    assert json.loads(paths.json.read_text())["bags"][0]["error"] == "bad & <worse>"


def test_progress_counts_rates_and_time_left():
    progress = BatchProgress({"a": 100, "b": 300}, up_to_date=1)
    assert progress.total == 3 and progress.eta_s is None
    progress.started("a")
    progress.scan("a", 5, 10)
    assert progress.scans_done == 5 and progress.eta_s > 0
    progress.finished_job(JobResult("a", JobStatus.DONE, summary=example_summary(scans=10)))
    progress.finished_job(JobResult("b", JobStatus.FAILED, error="x"))
    assert progress.finished == 3 and progress.scans_done == 10
    assert progress.line().startswith("batch: 3/3 bags (1 up to date, 1 failed)")
    stream = io.StringIO()
    display = ProgressDisplay(progress, stream)
    display.finished(progress.results["b"])
    display.close()
    assert "FAILED      b: x" in stream.getvalue()
    assert "\r" not in stream.getvalue()  # off a terminal: the lines only, no bar
    assert re.fullmatch(
        r"batch: 3/3 bags \(1 up to date, 1 failed\), [\d.]+ scans/s", stream.getvalue().splitlines()[-1]
    )
    assert [format_duration(s) for s in (42, 200, 7500)] == ["42 s", "3 min 20 s", "2 h 05 min"]


def test_progress_bar_on_a_terminal_keeps_bag_lines_apart_and_ends_with_one_status_line():
    progress = BatchProgress({"a": 100, "b": 300})
    terminal = Terminal()
    display = ProgressDisplay(progress, terminal)
    progress.started("a")
    progress.started("b")
    progress.scan("a", 5, 10)
    display.update()
    progress.scan("b", 3, 30)
    progress.finished_job(JobResult("a", JobStatus.DONE, summary=example_summary(scans=10)))
    display.finished(progress.results["a"])  # the bag's line, then the bar redrawn below it
    lines = screen_lines(terminal.getvalue())
    assert lines[0].startswith("[1/2] done        a: 10 scans")
    # 100 + 300 * 3/30 of 400 bytes processed: 32.5 %
    bar = r"batch: 1/2 bags, 1 running \|[#0-9]+ *\|  32%, [\d.]+ scans/s, about .* left"
    assert re.fullmatch(bar, lines[1]), lines
    progress.finished_job(JobResult("b", JobStatus.FAILED, error="x"))
    display.finished(progress.results["b"])
    display.close()
    lines = screen_lines(terminal.getvalue())
    assert lines[1] == "[2/2] FAILED      b: x"
    assert len(lines) == 3 and re.fullmatch(r"batch: 2/2 bags \(1 failed\), [\d.]+ scans/s", lines[2]), lines


# -- options --------------------------------------------------------------------------------------------
def test_option_errors(tmp_path, tree, monkeypatch, capsys):
    out = tmp_path / "out"
    with pytest.raises(ConfigError, match="not both"):
        run_batch([tree], out, span_dir=tmp_path, span_pattern="x")
    with pytest.raises(ConfigError, match="at least 1"):
        run_batch([tree], out, workers=0)
    with pytest.raises(ConfigError, match="needs --engine ray"):
        run_batch([tree], out, ray_address="auto")
    with pytest.raises(ConfigError, match="unknown engine 'spark'"):
        run_batch([tree], out, engine="spark")
    with pytest.raises(ConfigError, match="would replace the bag"):
        run_batch([tree / "r2"], tree)
    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ConfigError, match=r"needs Ray: pip install 'lidar3d\[ray\]'"):
        run_batch([tree / "x" / "drive.bag"], out, engine="ray")
    assert main(["batch", str(tmp_path / "missing"), "--out", str(out)]) == 1
    assert "lidar3d batch: error: " in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["batch", str(tree), "--out", str(out), "--span-dir", "a", "--span-pattern", "b"])


def test_one_batch_per_folder(tmp_path, tree):
    import fcntl

    out = tmp_path / "out"
    (out / ".batch").mkdir(parents=True)
    with open(out / ".batch" / "lock", "a+") as handle:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(OutputError, match="another lidar3d batch is writing to this folder"):
            run_batch([tree / "x" / "drive.bag"], out)


# -- a worker process that dies -----------------------------------------------------------------------
def crash_or_succeed(job, should_stop=None, on_scan=None):
    """Stand-in job function (imported by name in spawned workers): kills its process for 'crash*'."""
    if job.name.startswith("crash"):
        os._exit(3)
    if on_scan is not None:
        on_scan(job.name, 1, 1)
    return JobResult(job.name, JobStatus.DONE, summary=example_summary(scans=1))


class ListSink:
    def __init__(self) -> None:
        self.results: dict[str, JobResult] = {}

    def started(self, name):
        pass

    def scan(self, name, done, total):
        pass

    def finished(self, result):
        self.results[result.name] = result


def test_a_worker_that_dies_fails_only_its_own_bag(tmp_path):
    jobs = [BagJob(n, tmp_path / f"{n}.bag", tmp_path / n, "", "x") for n in ("one", "crash", "two", "three")]
    sink = ListSink()
    assert run_local(jobs, sink, workers=2, job_function=crash_or_succeed) is False
    assert {n: r.status for n, r in sink.results.items()} == {
        "one": JobStatus.DONE,
        "crash": JobStatus.FAILED,
        "two": JobStatus.DONE,
        "three": JobStatus.DONE,
    }
    assert "worker process died" in sink.results["crash"].error


def test_report_has_thumbnails_and_a_reason_in_every_blank_cell(tmp_path):
    """Issue 22: the top views as thumbnails; no empty cell without a word on why it is empty."""
    for plot in ("short/trajectory_loops.png", "short/eval/top_view.png", "short/eval/rotation_error.png"):
        (tmp_path / plot).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / plot).write_bytes(b"png")
    evaluated = example_summary(length_m=42.0)
    rows = [
        bag_row(name="bad", bag=Path("/b/bad.bag"), status="failed", batch_dir=tmp_path, error="not a bag"),
        bag_row(
            name="short",
            bag=Path("/b/short.bag"),
            status="done",
            batch_dir=tmp_path,
            summary=evaluated,
            eval_report={"rpe_kitti": {"n": 0, "translation_percent": None}, "rpe_distance": []},
            span_log=Path("/logs/short.gps"),
            rpe_distance_m=100.0,
        ),
        bag_row(
            name="plain",
            bag=Path("/b/plain.bag"),
            status="done",
            batch_dir=tmp_path,
            summary=example_summary(evaluation=None),
            span_match="no file /b/plain.gps",
        ),
        bag_row(name="later", bag=Path("/b/later.bag"), status="not started", batch_dir=tmp_path),
    ]
    meta = {"out_dir": str(tmp_path), "rpe_distance_m": 100.0, "totals": {}}
    page = write_report(tmp_path, rows, meta).html.read_text()
    assert page.count("<img ") == 2 and '<img src="short/trajectory_loops.png"' in page
    assert '<img src="short/eval/top_view.png"' in page and 'href="short/eval/rotation_error.png"' in page
    assert "path 42 m &lt; 100 m" in page  # KITTI RPE and RPE 100 m of a 42 m drive
    assert "no SPAN log" in page and "no file plain.gps" in page and "not run" in page
    assert re.search(r"<td[^>]*>\s*</td>", page) is None, "an empty cell without its reason"
