"""Are the accepted loop closures right? Each loop measurement of a run scored against the truth.

Every loop edge of the run's ``pose_graph.g2o`` (an edge between keyframes that are not
neighbours) is a measurement ``T_match_query``: the query keyframe's pose in the match keyframe's
frame, as the verification's ICP found it. Its error is ``inv(T_true) @ T_measured``, with
``T_true = inv(T_ref(match)) @ T_ref(query)`` interpolated from the true poses at the two keyframes'
stamps (``keyframes_tum.txt``); the report gives the translation (m) and rotation (deg) of each and
the worst (issue 16: "the worst accepted closure within 0.2 m / 1 deg of the truth").

Usage::

    .venv/bin/python eval/closure_check.py out/city sim/city          # a simulation folder
    .venv/bin/python eval/closure_check.py out/city sim/city/ground_truth_dense_tum.txt --json c.json

``eval/run_suite.py`` runs it on every lidar3d run with loop closure (``closures`` in
``results.json``, the worst closure in the tables of ``BENCHMARKS.md``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from check_cli import report_and_exit_code  # noqa: E402

from lidar3d.errors import Lidar3dError  # noqa: E402

__all__ = ["MAX_ERROR_DEG", "MAX_ERROR_M", "check_closures", "format_report", "loop_edges", "main"]

MAX_ERROR_M = 0.2  # issue 16's bound on the worst accepted closure ...
MAX_ERROR_DEG = 1.0  # ... and its rotation
TRUTH_NAMES = ("ground_truth_dense_tum.txt", "ground_truth_tum.txt")


def loop_edges(g2o_path: Path) -> list[tuple[int, int, np.ndarray]]:
    """``(source, target, T_source_target)`` of every edge of a g2o file between keyframes that
    are not neighbours (the loop factors; odometry edges join ``k`` and ``k + 1``)."""
    from scipy.spatial.transform import Rotation

    edges = []
    try:
        lines = g2o_path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as err:
        raise Lidar3dError(f"{g2o_path}: cannot read the pose graph ({err})") from err
    for lineno, line in enumerate(lines, 1):
        fields = line.split()
        if not fields or fields[0] != "EDGE_SE3:QUAT":
            continue
        try:
            source, target = int(fields[1]), int(fields[2])
            values = np.array([float(v) for v in fields[3:10]])
        except (IndexError, ValueError) as err:
            raise Lidar3dError(f"{g2o_path}:{lineno}: malformed edge ({err})") from err
        if abs(target - source) == 1:
            continue
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(values[3:7]).as_matrix()
        T[:3, 3] = values[:3]
        edges.append((source, target, T))
    return edges


def _truth_path(truth: Path) -> Path:
    if not truth.is_dir():
        return truth
    for name in TRUTH_NAMES:
        if (truth / name).is_file():
            return truth / name
    raise Lidar3dError(f"{truth}: no {' or '.join(TRUTH_NAMES)} in this folder")


def check_closures(run_dir: str | Path, truth: str | Path) -> dict:
    """Score the loop measurements of the run folder ``run_dir`` against the true poses in
    ``truth`` (a TUM file, or a simulation folder holding one).

    Returns a JSON-ready dict: ``closures`` (count), ``worst_m`` / ``worst_deg`` (None without
    closures), ``met`` (worst within 0.2 m and 1 deg), and ``edges`` (query, match, error m, deg).

    Raises:
        Lidar3dError: a missing or malformed ``pose_graph.g2o``, ``keyframes_tum.txt`` or truth.
    """
    from lidar3d.io.trajectory_io import read_tum
    from lidar3d.mapping.se3 import interpolate_poses, invert

    run_dir = Path(run_dir)
    graph = run_dir / "pose_graph.g2o"
    if not graph.is_file():
        raise Lidar3dError(f"{run_dir}: no pose_graph.g2o (a run with loop closure writes one)")
    keyframes = read_tum(run_dir / "keyframes_tum.txt")
    reference = read_tum(_truth_path(Path(truth)))
    edges = loop_edges(graph)
    if any(max(a, b) >= len(keyframes) for a, b, _ in edges):
        raise Lidar3dError(f"{graph}: an edge names a keyframe beyond keyframes_tum.txt's {len(keyframes)}")
    stamps = keyframes.stamps_ns
    if len(stamps) and (stamps[0] < reference.stamps_ns[0] or stamps[-1] > reference.stamps_ns[-1]):
        raise Lidar3dError(f"{run_dir / 'keyframes_tum.txt'}: keyframes outside the truth's time span")
    true_poses = (
        interpolate_poses(reference.stamps_ns, reference.T_world_lidar, stamps) if len(stamps) else np.zeros((0, 4, 4))
    )
    scored = []
    for source, target, T_measured in edges:
        T_true = invert(true_poses[source]) @ true_poses[target]
        error = invert(T_true) @ T_measured
        angle = np.degrees(np.arccos(np.clip((np.trace(error[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
        scored.append(
            {
                "match": source,
                "query": target,
                "error_m": float(np.linalg.norm(error[:3, 3])),
                "error_deg": float(angle),
            }
        )
    worst_m = max((e["error_m"] for e in scored), default=None)
    worst_deg = max((e["error_deg"] for e in scored), default=None)
    return {
        "closures": len(scored),
        "worst_m": None if worst_m is None else round(worst_m, 4),
        "worst_deg": None if worst_deg is None else round(worst_deg, 3),
        "met": worst_m is None or (worst_m <= MAX_ERROR_M and worst_deg is not None and worst_deg <= MAX_ERROR_DEG),
        "edges": scored,
    }


def format_report(report: dict) -> str:
    """A few lines: the count, the worst errors and the three worst closures."""
    if not report["closures"]:
        return "no loop closures"
    lines = [
        f"{report['closures']} loop closures; worst {report['worst_m'] * 100:.1f} cm, {report['worst_deg']:.2f} deg "
        f"(target {MAX_ERROR_M * 100:g} cm / {MAX_ERROR_DEG:g} deg: {'met' if report['met'] else 'not met'})"
    ]
    for e in sorted(report["edges"], key=lambda e: -e["error_m"])[:3]:
        lines.append(f"  keyframe {e['query']} -> {e['match']}: {e['error_m'] * 100:.1f} cm, {e['error_deg']:.2f} deg")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="eval/closure_check.py", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run_dir", type=Path, help="run folder of lidar3d run (with pose_graph.g2o)")
    parser.add_argument("truth", type=Path, help="true poses: a TUM file or a simulation folder")
    parser.add_argument("--json", type=Path, metavar="FILE", help="also write the report as JSON")
    args = parser.parse_args(argv)
    return report_and_exit_code(
        lambda: check_closures(args.run_dir, args.truth), format_report, lambda report: bool(report["met"]), args.json
    )


if __name__ == "__main__":
    sys.exit(main())
