"""A run folder is always one consistent set (issue 21, defects 7 and 8).

Unit tests of :mod:`lidar3d.io.run_folder` (publication, a kill before and inside the swap,
checks), ``lidar3d run`` refusing or replacing an earlier run, checkpoints, and the small kill test:
``lidar3d run`` SIGKILLed at chosen moments of a 3 s bag (mid-run, while the final map is being
staged, inside the final swap), every folder left checked as ``eval/kill_test.py`` does.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from test_summary import example_summary

import lidar3d.gnss.reference as reference_module
import lidar3d.io.run_folder as run_folder
import lidar3d.metrics.span_eval as span_eval
import lidar3d.run as run_module
from lidar3d.cli.main import main
from lidar3d.config import Config
from lidar3d.errors import OutputError
from lidar3d.gnss.reference import span_reference
from lidar3d.io.run_folder import (
    STAGING_NAME,
    RunFolderState,
    check_run_folder,
    check_run_output,
    complete_publication,
    publish_set,
    read_run_folder,
)
from lidar3d.pipeline import SlamPipeline
from lidar3d.run import run_bag
from lidar3d.summary import read_summary

sim = pytest.importorskip("lidar3d.sim")
REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "eval"))
from kill_test import verify_folder  # noqa: E402


def _summary(scans: int, **changes):
    return example_summary(scans=scans, keyframes=1, map_points=0, loop_candidates=0, partial=True, **changes)


def _writer(files: dict[str, str]):
    def write(staging: Path) -> None:
        for name, text in files.items():
            (staging / name).parent.mkdir(parents=True, exist_ok=True)
            (staging / name).write_text(text)

    return write


def _publish_two_rows(folder: Path, tag: str):
    files = {"trajectory_tum.txt": f"{tag}1\n{tag}2\n", "keyframes_tum.txt": f"{tag}1\n", "pose_graph.g2o": tag}
    rows = {"trajectory_tum.txt": 2, "keyframes_tum.txt": 1}
    return publish_set(folder, _summary(2), _writer(files), rows=rows)


# -- publication -----------------------------------------------------------------------------------


def test_a_published_set_is_consistent_and_named_in_the_summary(tmp_path):
    published = _publish_two_rows(tmp_path, "a")
    assert [entry.path for entry in published.outputs] == ["keyframes_tum.txt", "pose_graph.g2o", "trajectory_tum.txt"]
    assert read_summary(tmp_path / "summary.json") == published
    assert published.output("trajectory_tum.txt").rows == 2 and published.output("pose_graph.g2o").rows is None
    check = check_run_folder(tmp_path)
    assert check.state is RunFolderState.CONSISTENT and check.problems == () and check.unnamed == ()
    assert not (tmp_path / STAGING_NAME).exists()


def test_a_new_set_removes_the_files_of_the_previous_one(tmp_path):
    _publish_two_rows(tmp_path, "a")
    (tmp_path / "eval").mkdir()
    (tmp_path / "eval" / "report.json").write_text("{}")  # an earlier run's report
    publish_set(tmp_path, _summary(1), _writer({"trajectory_tum.txt": "b1\n"}), rows={"trajectory_tum.txt": 1})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json", "trajectory_tum.txt"]
    assert check_run_folder(tmp_path).state is RunFolderState.CONSISTENT


def test_kept_files_are_carried_over_unchanged(tmp_path):
    first = _publish_two_rows(tmp_path, "a")
    second = publish_set(
        tmp_path,
        _summary(2),
        _writer({"trajectory_tum.txt": "c1\nc2\n"}),
        rows={"trajectory_tum.txt": 2},
        keep=["pose_graph.g2o"],
    )
    assert second.output("pose_graph.g2o") == first.output("pose_graph.g2o")
    assert not (tmp_path / "keyframes_tum.txt").exists()
    with pytest.raises(OutputError, match=r"cannot keep map\.pcd: it is not in the published set"):
        publish_set(tmp_path, _summary(2), keep=["map.pcd"])


class Killed(BaseException):
    """Stands for SIGKILL: nothing after it runs."""


def test_a_kill_before_the_commit_leaves_the_previous_set(tmp_path):
    first = _publish_two_rows(tmp_path, "a")

    def dying(staging: Path) -> None:
        (staging / "trajectory_tum.txt").write_text("b1\nb2\nb3\n")
        raise Killed

    with pytest.raises(Killed):
        publish_set(tmp_path, _summary(3), dying)
    assert (tmp_path / STAGING_NAME).is_dir()
    check = check_run_folder(tmp_path)
    assert check.state is RunFolderState.CONSISTENT and check.summary == first
    assert read_run_folder(tmp_path) == first and not (tmp_path / STAGING_NAME).exists()


def test_a_kill_inside_the_swap_is_finished_by_the_next_reader(tmp_path, monkeypatch):
    _publish_two_rows(tmp_path, "a")
    replace = os.replace
    calls = []

    def dying_replace(src, dst):
        calls.append(dst)
        if len(calls) == 2:  # one staged file moved, then the kill
            raise Killed
        replace(src, dst)

    monkeypatch.setattr(run_folder.os, "replace", dying_replace)
    with pytest.raises(Killed):
        files = {"trajectory_tum.txt": "b\nb\nb\n", "keyframes_tum.txt": "b\n"}
        publish_set(tmp_path, _summary(3), _writer(files), rows={"trajectory_tum.txt": 3, "keyframes_tum.txt": 1})
    monkeypatch.setattr(run_folder.os, "replace", replace)
    check = check_run_folder(tmp_path)
    assert check.state is RunFolderState.PENDING
    assert complete_publication(tmp_path) is True
    summary = read_run_folder(tmp_path, verify_content=True)
    assert summary.scans == 3 and (tmp_path / "trajectory_tum.txt").read_text() == "b\nb\nb\n"
    assert not (tmp_path / "pose_graph.g2o").exists()  # the old set's file the new one does not hold


def test_checks_name_what_is_wrong(tmp_path):
    published = _publish_two_rows(tmp_path, "a")
    (tmp_path / "trajectory_tum.txt").write_text("a1\na2\na3\n")
    (tmp_path / "loops.csv").write_text("stray\n")
    check = check_run_folder(tmp_path)
    assert check.state is RunFolderState.INCONSISTENT and check.unnamed == ("loops.csv",)
    assert check.problems == ("trajectory_tum.txt: 9 bytes, the summary says 6",)
    (tmp_path / "trajectory_tum.txt").write_text("a1\nX2\n")  # same size, other content
    assert check_run_folder(tmp_path, verify_content=False).state is RunFolderState.CONSISTENT
    assert check_run_folder(tmp_path).problems == ("trajectory_tum.txt: content differs from the summary's SHA-256",)
    with pytest.raises(
        OutputError, match=r"trajectory_tum\.txt: not the file its run folder's summary\.json describes"
    ):
        check_run_output(tmp_path / "trajectory_tum.txt")
    text = json.loads(published.to_json())
    text["scans"] = 5
    (tmp_path / "summary.json").write_text(json.dumps(text))
    assert "trajectory_tum.txt: 2 rows, the summary's counts say 5" in check_run_folder(tmp_path).problems
    (tmp_path / "summary.json").unlink()
    assert check_run_folder(tmp_path).problems == ("outputs without summary.json",)
    assert check_run_folder(tmp_path / "none").state is RunFolderState.EMPTY


# -- lidar3d run -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    return sim.simulate("loop", tmp_path_factory.mktemp("sim") / "loop", seed=0, duration_s=3.0)


def test_a_run_folder_is_consistent_with_every_output_named(simulated, tmp_path, monkeypatch):
    # The SPAN log's reference is built (and its summary logged) once, for the georeference and the
    # evaluation both.
    built = []

    def counted_span_reference(*args, **kwargs):
        built.append(args[0])
        return span_reference(*args, **kwargs)

    monkeypatch.setattr(reference_module, "span_reference", counted_span_reference)
    monkeypatch.setattr(span_eval, "span_reference", counted_span_reference)
    out = tmp_path / "out"
    assert (
        main(
            ["-q", "run", str(simulated.bag), "--out", str(out), "--max-scans", "8", "--span", str(simulated.span_log)]
        )
        == 0
    )
    check = check_run_folder(out)
    assert check.state is RunFolderState.CONSISTENT and check.unnamed == ()
    names = {entry.path for entry in check.summary.outputs}
    assert {"config.toml", "map.pcd", "trajectory_kitti.times.txt", "eval/report.json"} <= names
    assert check.summary.output("map.pcd").rows == check.summary.map_points > 0
    assert verify_folder(out)[1] == ""
    assert len(built) == 1


def test_a_rerun_into_an_old_folder_is_refused_without_overwrite(simulated, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["-q", "run", str(simulated.bag), "--out", str(out), "--max-scans", "4"]) == 0
    before = (out / "summary.json").read_text()
    capsys.readouterr()
    assert main(["-q", "run", str(simulated.bag), "--out", str(out), "--max-scans", "5"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert err == [
        f"lidar3d run: error: {out}: already holds the outputs of a run (config.toml); pass --overwrite to replace them"
    ]
    assert (out / "summary.json").read_text() == before


def test_a_rerun_with_overwrite_replaces_the_whole_set(simulated, tmp_path):
    out = tmp_path / "out"
    assert (
        main(
            ["-q", "run", str(simulated.bag), "--out", str(out), "--max-scans", "6", "--span", str(simulated.span_log)]
        )
        == 0
    )
    for name in ("loops.csv", "pose_graph.g2o", "trajectory_loops.png"):  # as an earlier run with loops left them
        (out / name).write_text("old\n")
    assert (out / "eval" / "report.json").is_file()
    assert (
        main(["-q", "run", str(simulated.bag), "--out", str(out), "--max-scans", "5", "--no-loop", "--overwrite"]) == 0
    )
    left = sorted(p.relative_to(out).as_posix() for p in out.rglob("*"))
    assert "eval" not in left and "loops.csv" not in left and "pose_graph.g2o" not in left
    summary, problem = verify_folder(out)
    assert problem == "" and summary.scans == 5 and summary.evaluation is None


def test_checkpoints_without_the_map_keep_the_last_map_and_its_count(simulated, tmp_path):
    out = tmp_path / "out"
    seen = []

    def on_scan(done, total):
        if done >= 2:
            summary, problem = verify_folder(out)
            seen.append((problem, summary.scans, summary.map_points, (out / "map.pcd").exists()))

    run_bag(simulated.bag, out, max_scans=4, on_scan=on_scan, checkpoint_every_s=0.0, map_checkpoint_every_s=math.inf)
    assert seen == [("", n, 0, False) for n in range(1, 4)]  # no map published yet: 0 map points
    summary, problem = verify_folder(out)
    assert problem == "" and summary.partial is False and summary.map_points > 0


def test_eval_refuses_a_trajectory_its_folder_does_not_describe(simulated, tmp_path, capsys):
    out = tmp_path / "out"
    run_bag(simulated.bag, out, max_scans=4, prefetch=False)
    (out / "trajectory_tum.txt").write_text("1.0 0 0 0 0 0 0 1\n")  # another run's file
    code = main(
        ["eval", str(out / "trajectory_tum.txt"), "--span", str(simulated.span_log), "--out", str(tmp_path / "e")]
    )
    assert code == 1
    assert "not the file its run folder's summary.json describes (trajectory_tum.txt:" in capsys.readouterr().err


def test_a_closed_stdout_pipe_exits_quietly():
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader (head) is gone before anything is written
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(
        [sys.executable, "-m", "lidar3d.cli.main", "config"],
        stdout=write_end,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    os.close(write_end)
    assert (done.returncode, done.stderr) == (141, "")


# -- the kill test, small ----------------------------------------------------------------------------

# run_bag in a subprocess, checkpointing after every scan (maps only at the end); the hook named by
# argv[3] announces its moment in a marker file and then hangs until the test SIGKILLs the process.
DRIVER = textwrap.dedent(
    """
    import os, sys, time
    from pathlib import Path
    import lidar3d.io.run_folder as run_folder
    import lidar3d.run as run
    bag, out, hook, marker = sys.argv[1], Path(sys.argv[2]), sys.argv[3], Path(sys.argv[4])

    def hang():
        marker.write_text("now")
        time.sleep(120)

    def on_scan(done, total):
        if hook == "scan" and done == 6:
            hang()

    write_pcd = run.write_pcd
    def slow_write_pcd(path, *args, **kwargs):
        write_pcd(path, *args, **kwargs)
        if hook == "map":  # the final map is in staging, not yet committed
            hang()
    run.write_pcd = slow_write_pcd

    replace = os.replace
    def slow_replace(src, dst):
        replace(src, dst)
        if hook == "swap" and Path(dst).name == "map.pcd" and Path(dst).parent == out:
            hang()  # the final set is committed and half swapped in
    run_folder.os.replace = slow_replace

    run.run_bag(bag, out, max_scans=10, on_scan=on_scan, checkpoint_every_s=0.0,
                map_checkpoint_every_s=float("inf"), prefetch=False)
    """
)


def _kill_at_hook(bag: Path, out: Path, hook: str) -> None:
    marker = out.parent / f"{hook}.marker"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    process = subprocess.Popen([sys.executable, "-c", DRIVER, str(bag), str(out), hook, str(marker)], env=env)
    try:
        deadline = time.monotonic() + 90
        while not marker.exists():
            assert process.poll() is None, f"the run ended before the {hook} hook"
            assert time.monotonic() < deadline, f"the {hook} hook never came"
            time.sleep(0.02)
        os.kill(process.pid, signal.SIGKILL)
    finally:
        process.kill()
        process.wait()


@pytest.mark.parametrize(
    "hook, disk_state, scans, partial",
    [
        ("scan", RunFolderState.CONSISTENT, 5, True),
        ("map", RunFolderState.CONSISTENT, 10, True),
        ("swap", RunFolderState.PENDING, 10, False),
    ],
    ids=["mid-run", "staging-the-final-map", "inside-the-final-swap"],
)
def test_a_sigkilled_run_leaves_a_consistent_set(hook, disk_state, scans, partial, simulated, tmp_path):
    out = tmp_path / "out"
    _kill_at_hook(simulated.bag, out, hook)
    assert check_run_folder(out).state is disk_state
    summary, problem = verify_folder(out)  # finishes an interrupted swap, as every reader does
    assert problem == ""
    assert (summary.scans, summary.partial) == (scans, partial)
    assert not (out / STAGING_NAME).exists()
    if hook == "swap":
        reference = tmp_path / "reference"
        run_bag(simulated.bag, reference, max_scans=10, prefetch=False)
        for name in ("trajectory_tum.txt", "map.pcd", "keyframes_tum.txt"):
            assert (out / name).read_bytes() == (reference / name).read_bytes(), name


def test_the_final_top_view_is_drawn_once_while_the_map_is_waited_for(simulated, tmp_path, monkeypatch):
    """The top view is drawn in a thread of its own as soon as the poses are final, while the
    pipeline waits for the map, and that drawing is the one published; a trajectory that changes
    after it, or a drawing that failed, is drawn again."""
    events = []
    started = threading.Event()
    drawn = run_module._top_view_png
    finish = SlamPipeline.finish

    def counted_drawing(result):
        events.append(("draw", len(result.trajectory), threading.current_thread().name))
        started.set()
        return drawn(result)

    def noted_finish(self):
        events.append(("map wait begins; drawing under way", started.wait(timeout=30)))
        finish(self)

    monkeypatch.setattr(run_module, "_top_view_png", counted_drawing)
    monkeypatch.setattr(SlamPipeline, "finish", noted_finish)
    out = tmp_path / "out"
    run_bag(simulated.bag, out, max_scans=6, prefetch=False)
    assert sorted(events, key=str) == [("draw", 6, "lidar3d-top-view"), ("map wait begins; drawing under way", True)]
    assert (out / "trajectory_loops.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    publisher = run_module._RunPublisher(tmp_path / "other", Config())
    result = SimpleNamespace(pose_graph_g2o="x", trajectory=SimpleNamespace(positions_m=np.zeros((3, 3))))
    monkeypatch.setattr(run_module, "_top_view_png", lambda r: r.trajectory.positions_m.tobytes())
    publisher.draw_top_view_meanwhile(result).join()
    assert publisher._top_view_png(result) == np.zeros((3, 3)).tobytes()
    moved = SimpleNamespace(pose_graph_g2o="x", trajectory=SimpleNamespace(positions_m=np.ones((3, 3))))
    assert publisher._top_view_png(moved) == np.ones((3, 3)).tobytes()

    failing = run_module._RunPublisher(tmp_path / "third", Config())
    monkeypatch.setattr(run_module, "_top_view_png", lambda r: 1 / 0)
    failing.draw_top_view_meanwhile(result).join()  # the thread fails quietly ...
    monkeypatch.setattr(run_module, "_top_view_png", lambda r: b"again")
    assert failing._top_view_png(result) == b"again"  # ... and the publication draws again
