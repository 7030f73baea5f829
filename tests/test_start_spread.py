"""eval/start_spread.py: lidar3d from several start scans of one drive, and the spread of its ATE."""

import json
import sys
from pathlib import Path

import pytest

from lidar3d.io.trajectory_io import read_tum

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "eval"))
start_spread = pytest.importorskip("start_spread")


def _record(ate_m, max_m):
    return {"status": "ok", "scores": {"gt": {"ate_rmse_m": {"3d": ate_m}, "ate_max_3d_m": max_m}}}


def test_the_figures_give_each_start_its_ate_and_the_spread_over_them():
    figures = start_spread.drive_figures(
        {2: _record(0.8, 2.0), 0: _record(0.4, 1.2), 1: {"status": "failed", "error": "x"}, 3: _record(0.5, 1.0)}
    )
    assert list(figures["starts"]) == [0, 1, 2, 3]
    assert figures["starts"][1] == {"ate_m": None, "max_m": None, "status": "failed"}
    assert figures["median_ate_m"] == 0.5 and figures["min_ate_m"] == 0.4 and figures["max_ate_m"] == 0.8
    assert figures["spread"] == pytest.approx(2.0)
    table = start_spread.render({"long_s1": figures}, [0, 1, 2, 3], "header")
    assert "| long_s1 | 0.400 / 1.20 | failed / failed | 0.800 / 2.00 | 0.500 / 1.00 | 0.500 | x2.00 |" in table
    partial = start_spread.render({"long_s1": start_spread.drive_figures({2: _record(0.8, 2.0)})}, [0, 2], "h")
    assert "| long_s1 | – | 0.800 / 2.00 | 0.800 | x1.00 |" in partial  # start 0 not run yet


def test_a_drive_run_from_two_start_scans_is_scored_per_start(tmp_path, capsys):
    """End to end on 1.5 s of ``loop``: both starts run in their own process and are scored; the
    later start's trajectory begins that many scans later."""
    out = tmp_path / "spread"
    code = start_spread.main(
        ["--scenarios", "loop", "--seeds", "0", "--starts", "3", "0", "--duration", "1.5"]
        + ["--cache-dir", str(tmp_path / "cache"), "--out", str(out), "--no-loop"]
    )
    assert code == 0
    results = json.loads((out / "results.json").read_text())
    assert results["complete"] and results["runs_finished"] == results["runs"] == 2
    figures = results["drives"]["loop_s0"]
    assert [figures["starts"][k]["status"] for k in ("0", "3")] == ["ok", "ok"]
    assert 0 < figures["min_ate_m"] <= figures["median_ate_m"] <= figures["max_ate_m"] < 0.2
    first_ns = [read_tum(out / "loop_s0" / f"start{k}" / "trajectory_tum.txt").stamps_ns[0] for k in (0, 3)]
    assert first_ns[1] - first_ns[0] == pytest.approx(0.3e9, abs=0.01e9)  # three 0.1 s sweeps later
    assert "| loop_s0 |" in capsys.readouterr().out and (out / "start_spread.md").is_file()

    # an interrupted spread is finished with --resume: what finished is not run again
    (out / "loop_s0" / "start3" / "record.json").unlink()
    before = (out / "loop_s0" / "start0" / "trajectory_tum.txt").stat().st_mtime_ns
    code = start_spread.main(
        ["--scenarios", "loop", "--seeds", "0", "--starts", "3", "0", "--duration", "1.5"]
        + ["--cache-dir", str(tmp_path / "cache"), "--out", str(out), "--no-loop", "--resume"]
    )
    assert code == 0
    assert (out / "loop_s0" / "start0" / "trajectory_tum.txt").stat().st_mtime_ns == before  # reused
    assert (out / "loop_s0" / "start3" / "record.json").is_file()  # run again
    again = json.loads((out / "results.json").read_text())["drives"]["loop_s0"]
    assert again["starts"] == figures["starts"]


def test_a_negative_start_is_refused_in_one_line(capsys):
    with pytest.raises(SystemExit) as exit_info:
        start_spread.main(["--starts", "-1"])
    assert exit_info.value.code == 2
    assert "--starts: a start scan is at least 0, not -1" in capsys.readouterr().err


def test_a_saved_record_is_reused_only_for_the_same_finished_task(tmp_path):
    run_suite = pytest.importorskip("run_suite")
    task = {"method": "lidar3d", "bag": "/x/scans.bag", "loop_closure": True, "start": 1}
    assert run_suite.saved_record(tmp_path, task) is None  # none saved
    (tmp_path / run_suite.RECORD_NAME).write_text("{not json")
    assert run_suite.saved_record(tmp_path, task) is None  # unreadable (a write cut short)
    (tmp_path / run_suite.RECORD_NAME).write_text(json.dumps({"status": "ok", "task": task, "scores": {}}))
    assert run_suite.saved_record(tmp_path, task)["scores"] == {}
    assert run_suite.saved_record(tmp_path, {**task, "start": 2}) is None  # another start
    assert run_suite.saved_record(tmp_path, {**task, "loop_closure": False}) is None  # other options
    (tmp_path / run_suite.RECORD_NAME).write_text(json.dumps({"status": "failed", "task": task}))
    assert run_suite.saved_record(tmp_path, task) is None  # failed runs are run again
