"""Loop-closure outputs: loops.csv, pose_graph.g2o and the top-view PNG."""

from __future__ import annotations

import csv

import numpy as np

from lidar3d.export.loop_report import (
    LOOPS_CSV_COLUMNS,
    loops_csv_text,
    top_view_png,
    write_loops_csv,
    write_pose_graph_g2o,
)
from lidar3d.loop import LoopCandidate, PoseGraph, Verdict

S = 1_000_000_000


def _candidate(query, match, verdict, reason, fitness=0.9) -> LoopCandidate:
    info = np.eye(6) * 100.0 if verdict is Verdict.ACCEPTED else np.zeros((6, 6))
    return LoopCandidate(
        query=query,
        match=match,
        query_stamp_ns=100 * S + query,
        match_stamp_ns=10 * S + match,
        distance_m=1.25,
        fitness=fitness,
        inlier_rmse_m=0.12,
        overlap=0.8,
        correction_m=0.4,
        correction_deg=0.5,
        verdict=verdict,
        reason=reason,
        T_match_query=np.eye(4),
        information=info,
    )


def test_loops_csv_has_every_candidate_with_its_reason(tmp_path):
    candidates = [
        _candidate(40, 2, Verdict.ACCEPTED, "fitness 0.900, RMSE 0.120 m"),
        _candidate(41, 3, Verdict.LOW_FITNESS, 'fitness 0.31 < 0.7, "quoted"', fitness=0.31),
        _candidate(42, 3, Verdict.TOO_FEW_POINTS, "12 source / 5000 target points", fitness=float("nan")),
    ]
    path = write_loops_csv(tmp_path / "loops.csv", candidates)
    rows = list(csv.DictReader(path.open()))
    assert tuple(rows[0].keys()) == LOOPS_CSV_COLUMNS
    assert [r["accepted"] for r in rows] == ["1", "0", "0"]
    assert [r["verdict"] for r in rows] == ["accepted", "low_fitness", "too_few_points"]
    assert rows[1]["reason"] == 'fitness 0.31 < 0.7, "quoted"'
    assert rows[2]["fitness"] == ""  # not computed
    assert rows[0]["time_gap_s"] == "90.000" and rows[0]["query_keyframe"] == "40"
    assert loops_csv_text([]).strip() == ",".join(LOOPS_CSV_COLUMNS)


def test_g2o_and_top_view_files(tmp_path):
    graph = PoseGraph()
    poses = [np.eye(4)]
    graph.add_keyframe(0, poses[0])
    for k in range(1, 6):
        T = np.eye(4)
        T[0, 3] = float(k)
        poses.append(T)
        graph.add_keyframe(k, T, np.linalg.inv(poses[k - 1]) @ T, np.full(6, 0.01))
    g2o = write_pose_graph_g2o(tmp_path / "pose_graph.g2o", graph.g2o_text())
    assert g2o.read_text().count("VERTEX_SE3:QUAT") == 6
    closures = [_candidate(5, 0, Verdict.ACCEPTED, "ok"), _candidate(4, 0, Verdict.LOW_OVERLAP, "no")]
    positions = np.array(poses)[:, :3, 3]
    data = top_view_png(positions, positions, closures, before_m=positions + 0.1, reference_m=positions)
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    assert not list(tmp_path.glob(".*tmp*"))  # atomic writes leave no temporaries


def test_top_view_title_is_honest_and_closures_are_visible():
    """Issue 22: no "with loop closures" when there were none; a closure whose keyframes lie 2 cm
    apart is still drawn as a ring around each end, numbered."""
    from lidar3d.export.loop_report import top_view_figure

    positions = np.column_stack([np.linspace(0, 50, 51), np.zeros(51), np.zeros(51)])
    keyframes = positions.copy()
    keyframes[50] = keyframes[0] + [0.02, 0.0, 0.0]  # back at the start: a 2 cm closure
    none = top_view_figure(positions, keyframes, [_candidate(50, 0, Verdict.LOW_OVERLAP, "no")])
    assert none.axes[0].get_title() == "trajectory (top view): no loop closure accepted"
    one = top_view_figure(positions, keyframes, [_candidate(50, 0, Verdict.ACCEPTED, "ok")])
    ax = one.axes[0]
    assert ax.get_title() == "trajectory (top view) with 1 loop closure"
    rings = [line for line in ax.get_lines() if line.get_marker() == "o" and line.get_markersize() >= 10]
    assert len(rings) == 1 and len(rings[0].get_xdata()) == 2
    assert [text.get_text() for text in ax.texts] == ["1"]
