"""``eval/closure_check.py``: each loop measurement of a run folder scored against the truth."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from lidar3d.errors import Lidar3dError
from lidar3d.io.trajectory_io import write_tum
from lidar3d.loop.pose_graph import GraphEdge, format_g2o
from lidar3d.mapping.se3 import exp_se3, invert
from lidar3d.records import Trajectory

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "eval"))
from closure_check import check_closures  # noqa: E402
from closure_check import main as closure_check_main  # noqa: E402
from suite_report import _loops_text  # noqa: E402

S = 1_000_000_000


def _circle(stamps_ns: np.ndarray) -> np.ndarray:
    """(N,4,4) true poses on a 20 m circle, facing along it, one turn in 100 s."""
    angle = 2 * np.pi * (stamps_ns - stamps_ns[0]) / (100 * S)
    T = np.repeat(np.eye(4)[None], len(stamps_ns), axis=0)
    T[:, 0, 0] = T[:, 1, 1] = np.cos(angle + np.pi / 2)
    T[:, 1, 0] = np.sin(angle + np.pi / 2)
    T[:, 0, 1] = -T[:, 1, 0]
    T[:, :3, 3] = np.column_stack([20 * np.cos(angle), 20 * np.sin(angle), np.zeros_like(angle)])
    return T


def _run(
    tmp_path: Path, loop_errors: list[np.ndarray], more_loops: tuple[tuple[int, int, np.ndarray], ...] = ()
) -> tuple[Path, Path]:
    """A run folder with keyframes every 5 s of a 110 s drive (keyframe k at 5k s) and a loop edge
    per error (keyframe 20 + i against keyframe i, its measurement the truth times the error), and
    one per ``(match, query, error)`` of ``more_loops``; and the truth file."""
    truth_stamps = np.arange(0, 111 * S, S // 10, dtype=np.int64) + 1_700_000_000 * S
    truth = _circle(truth_stamps)
    keyframe_stamps = truth_stamps[::50]
    keyframes = truth[::50]
    run = tmp_path / "run"
    run.mkdir()
    write_tum(run / "keyframes_tum.txt", Trajectory(keyframe_stamps, keyframes))
    write_tum(tmp_path / "truth.txt", Trajectory(truth_stamps, truth))
    edges = [
        GraphEdge(k - 1, k, invert(keyframes[k - 1]) @ keyframes[k], np.eye(6), "odometry")
        for k in range(1, len(keyframes))
    ]
    loops = [(i, 20 + i, error) for i, error in enumerate(loop_errors)] + list(more_loops)
    for match, query, error in loops:
        T_true = invert(keyframes[match]) @ keyframes[query]
        edges.append(GraphEdge(match, query, T_true @ error, np.eye(6), "loop"))
    (run / "pose_graph.g2o").write_text(format_g2o(keyframes, edges), encoding="utf-8")
    return run, tmp_path / "truth.txt"


def test_closure_errors_against_the_truth(tmp_path, capsys):
    small = exp_se3(np.array([0.03, 0.0, 0.0, 0.0, 0.0, np.radians(0.1)]))  # (v, w)
    slid = exp_se3(np.array([0.0, 0.25, 0.0, 0.0, 0.0, 0.0]))  # 25 cm sideways
    run, truth = _run(tmp_path, [small, slid])
    report = check_closures(run, truth)
    assert report["closures"] == 2 and not report["met"]
    assert report["worst_m"] == pytest.approx(0.25, abs=1e-3)
    assert report["worst_deg"] == pytest.approx(0.1, abs=1e-3)
    first = report["edges"][0]
    assert (first["query"], first["match"]) == (20, 0)
    assert first["error_m"] == pytest.approx(0.03, abs=1e-3)
    assert closure_check_main([str(run), str(truth)]) == 2
    assert "worst 25.0 cm" in capsys.readouterr().out
    text = _loops_text(
        {"method": "lidar3d", "loop_closures": 2, "closures": report, "run": {"wall_s": 10.0, "loop_ms_total": 500.0}}
    )
    assert text == "2; worst 25.0 cm / 0.10°; 5.0 % of the run"


def test_each_revisit_is_closed_only_by_a_right_closure_inside_it(tmp_path, capsys):
    """The simulator's revisits (metadata.json beside the truth): a revisit is closed when a closure
    of a keyframe inside it (its query stamps, inclusive, 5 ms of slack), to a keyframe before it,
    is within the target (20 cm, 1 deg)."""
    import json

    slid = exp_se3(np.array([0.0, 0.25, 0.0, 0.0, 0.0, 0.0]))
    turned = exp_se3(np.array([0.05, 0.0, 0.0, 0.0, 0.0, np.radians(2.0)]))
    more = (
        (13, 15, np.eye(4)),  # 75 s -> 65 s: both inside the revisit 64.9-75.1 s, so it closes nothing
        (2, 16, np.eye(4)),  # 80 s, 5 ms (the slack) after the revisit's last query stamp 79.995 s
        (3, 17, np.eye(4)),  # 85 s, 10 ms before the revisit 85.01-87 s
        (4, 18, turned),  # 90 s: 5 cm but 2 deg off
    )
    run, truth = _run(tmp_path, [np.eye(4), slid], more)  # and keyframes 20, 21 (100 s, 105 s) -> 0, 1
    start = 1_700_000_000 * S

    def revisit(first_s: float, last_s: float) -> dict:
        stamps = [start + round(t * S) for t in np.linspace(first_s, last_s, round((last_s - first_s) * 10) + 1)]
        pairs = [{"query_stamp_ns": stamp} for stamp in stamps]
        return {"query_first": round(first_s * 10), "query_last": round(last_s * 10), "pairs": pairs}

    spans = [(99.0, 101.0), (104.0, 106.0), (107.0, 109.0), (64.9, 75.1), (78.0, 79.995), (85.01, 87.0), (89.0, 91.0)]
    metadata = {"format": "lidar3d-sim/1", "revisits": [revisit(a, b) for a, b in spans]}
    (tmp_path / "metadata.json").write_text(json.dumps(metadata))
    report = check_closures(run, truth)
    closed = [(r["keyframes"], r["closures"], r["right"], r["closed"]) for r in report["revisits"]]
    assert closed == [
        (1, 1, 1, True),
        (1, 1, 0, False),  # 25 cm off
        (0, 0, 0, False),  # no keyframe inside
        (3, 0, 0, False),  # the only closure is to a keyframe inside the revisit
        (1, 1, 1, True),
        (0, 0, 0, False),
        (1, 1, 0, False),  # 2 deg off
    ]
    assert report["revisits_closed"] == 2
    assert closure_check_main([str(run), str(truth)]) == 2
    assert "revisits closed right: 2 of 7 (2 with no keyframe inside)" in capsys.readouterr().out


def test_revisits_are_reported_without_closures_and_only_from_the_simulators_metadata(tmp_path, capsys):
    import json

    from closure_check import format_report

    run, truth = _run(tmp_path, [])
    revisit = {"query_first": 990, "query_last": 1010, "pairs": [{"query_stamp_ns": (1_700_000_000 + 100) * S}]}
    (tmp_path / "metadata.json").write_text(json.dumps({"format": "lidar3d-sim/1", "revisits": [revisit]}))
    report = check_closures(run, truth)
    assert format_report(report) == "no loop closures\n  revisits closed right: 0 of 1"
    (tmp_path / "metadata.json").write_text(json.dumps({"revisits": [revisit]}))  # not the simulator's
    assert check_closures(run, truth)["revisits"] is None
    (tmp_path / "metadata.json").unlink()
    assert check_closures(run, truth)["revisits"] is None
    (tmp_path / "metadata.json").write_text("{not json")
    assert closure_check_main([str(run), str(truth)]) == 1
    err = capsys.readouterr().err
    assert "metadata.json: cannot read the simulator's metadata" in err and len(err.strip().splitlines()) == 1


def test_good_closures_meet_the_target_and_bad_folders_say_why(tmp_path, capsys):
    run, truth = _run(tmp_path, [np.eye(4)])
    report = check_closures(run, truth)
    assert report["met"] and report["worst_m"] == pytest.approx(0.0, abs=1e-4)
    assert closure_check_main([str(run), str(truth)]) == 0
    keyframes = (run / "keyframes_tum.txt").read_text().splitlines()
    first = keyframes[1].split()
    for shift_s, accepted in ((-0.001, True), (-0.05, False)):  # a jittered first stamp; one truly outside
        shifted = [" ".join([f"{float(first[0]) + shift_s:.6f}", *first[1:]])]
        (run / "keyframes_tum.txt").write_text("\n".join([keyframes[0], *shifted, *keyframes[2:]]) + "\n")
        if accepted:
            assert check_closures(run, truth)["met"]
        else:
            with pytest.raises(Lidar3dError, match="outside the truth's time span"):
                check_closures(run, truth)
    (run / "keyframes_tum.txt").write_text("\n".join(keyframes) + "\n")
    with pytest.raises(Lidar3dError, match=r"no pose_graph\.g2o"):
        check_closures(tmp_path, truth)
    lines = (run / "pose_graph.g2o").read_text().splitlines()
    (run / "pose_graph.g2o").write_text("\n".join(lines + ["EDGE_SE3:QUAT 0 99 0 0 0 0 0 0 1"]))
    with pytest.raises(Lidar3dError, match=r"beyond keyframes_tum\.txt"):
        check_closures(run, truth)
    (run / "pose_graph.g2o").write_text("\n".join(lines + ["EDGE_SE3:QUAT 0 x"]))
    assert closure_check_main([str(run), str(truth)]) == 1
    assert "malformed edge" in capsys.readouterr().err


def test_the_sweep_fit_follows_smooth_motion_and_leaves_out_vibration():
    """On smooth motion the sweep fit is the true pose; a roll of 0.3 deg at 20 Hz, at its peak at
    the stamp, is in the instant pose and (nearly) not in the fit."""
    from closure_check import sweep_fitted_poses
    from scipy.spatial.transform import Rotation

    stamps = np.arange(0, 20 * S, S // 1000, dtype=np.int64)  # 1 kHz
    smooth = _circle(stamps)
    at = np.array([2 * S, 7 * S + S // 4], dtype=np.int64)
    assert np.allclose(sweep_fitted_poses(Trajectory(stamps, smooth), at, 0.1), smooth[at // (S // 1000)], atol=1e-4)
    roll = np.radians(0.3) * np.cos(2 * np.pi * 20 * (stamps - at[0]) / S)
    vibrating = smooth.copy()
    vibrating[:, :3, :3] = smooth[:, :3, :3] @ Rotation.from_rotvec(np.outer(roll, [1.0, 0.0, 0.0])).as_matrix()
    fitted = sweep_fitted_poses(Trajectory(stamps, vibrating), at[:1], 0.1)[0]
    instant = vibrating[at[0] // (S // 1000)]
    truth = smooth[at[0] // (S // 1000)]
    angle = lambda T: np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1)))  # noqa: E731
    assert angle(invert(truth) @ instant) == pytest.approx(0.3, abs=1e-3)
    assert angle(invert(truth) @ fitted) < 0.06
