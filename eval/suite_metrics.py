"""Scores of one trajectory for the suite: against the simulator's ground truth and its SPAN log.

Everything here calls :mod:`lidar3d.metrics`; the suite adds only the end-point drift and the
flattening into a JSON-ready dict:

* ``gt``: :func:`lidar3d.metrics.evaluate_trajectory` against the true lidar poses (dense, every
  10 ms), SE(3)-aligned: ATE 3-D / horizontal / vertical / rotation, KITTI RPE (100..800 m
  segments, % and deg/100 m), RPE over 10 m;
* ``span``: :func:`lidar3d.metrics.evaluate_against_span` against the simulated SPAN-CPT log with
  the rig's ``T_imu_lidar`` (the noisy INS solution a real drive would be scored against);
* ``end_drift``: the estimate anchored on its first associated pose (no global fit), the distance
  between its last associated position and the truth there, in metres and in % of the path length.
  The SE(3) fit of the ATE spreads drift over the whole run; this number shows what the end of
  the run has accumulated.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["end_point_drift", "loop_closures", "score_trajectory"]


def _nan_to_none(value: float) -> float | None:
    return None if value is None or (isinstance(value, float) and math.isnan(value)) else round(float(value), 4)


def end_point_drift(evaluation, estimate) -> dict:
    """Drift at the last associated pose with the estimate anchored on the first one.

    ``evaluation``: a :class:`lidar3d.metrics.Evaluation` of ``estimate`` (its reference poses and
    association indices are reused).
    """
    T_ref = evaluation.T_ref_lidar
    T_est = estimate.T_world_lidar[evaluation.estimate_index]
    anchor = T_ref[0] @ np.linalg.inv(T_est[0])
    end = anchor @ T_est[-1]
    error = end[:3, 3] - T_ref[-1][:3, 3]
    length = evaluation.path_length_m
    drift = float(np.linalg.norm(error))
    return {
        "m": round(drift, 4),
        "horizontal_m": round(float(np.linalg.norm(error[:2])), 4),
        "vertical_m": round(float(abs(error[2])), 4),
        "percent": round(100.0 * drift / length, 4) if length > 0 else None,
        "path_length_m": round(length, 3),
    }


def _evaluation_dict(evaluation) -> dict:
    ate = evaluation.ate
    distance = {
        f"{d.distance_m:g}m": {
            "translation_rmse_m": _nan_to_none(d.translation_m.rmse),
            "translation_percent": _nan_to_none(d.translation_percent),
        }
        for d in evaluation.distance_rpe
    }
    return {
        "associated": evaluation.n_associated,
        "of": evaluation.n_estimate,
        "path_length_m": round(evaluation.path_length_m, 3),
        "ate_rmse_m": {
            "3d": _nan_to_none(ate.translation_3d_m.rmse),
            "horizontal": _nan_to_none(ate.horizontal_m.rmse),
            "vertical": _nan_to_none(ate.vertical_m.rmse),
        },
        "ate_max_3d_m": _nan_to_none(ate.translation_3d_m.max),
        "ate_rotation_rmse_deg": _nan_to_none(ate.rotation_deg.rmse),
        "rpe_kitti": {
            "translation_percent": _nan_to_none(evaluation.kitti.translation_percent),
            "rotation_deg_per_100m": _nan_to_none(evaluation.kitti.rotation_deg_per_100m),
            "segments": evaluation.kitti.n,
        },
        "rpe_distance": distance,
    }


def score_trajectory(
    trajectory_path: Path,
    *,
    ground_truth_path: Path,
    span_log: Path,
    extrinsics: Path,
    report_dir: Path | None = None,
) -> dict:
    """Evaluate the TUM trajectory at ``trajectory_path`` against the truth and the SPAN log.

    Each part that fails (e.g. too few poses associated) is reported as ``{"error": message}``.
    With ``report_dir``, the SPAN evaluation's report (JSON, CSV, plots) is written there.
    """
    from lidar3d.errors import Lidar3dError
    from lidar3d.export.span_report import write_span_report
    from lidar3d.gnss.extrinsic import read_extrinsic
    from lidar3d.io.trajectory_io import read_tum
    from lidar3d.metrics import evaluate_against_span, evaluate_trajectory

    estimate = read_tum(trajectory_path)
    truth = read_tum(ground_truth_path)
    scores: dict = {"poses": len(estimate)}
    try:
        gt_eval = evaluate_trajectory(estimate, truth, align="se3", max_gap_s=0.05)
        scores["gt"] = _evaluation_dict(gt_eval)
        scores["end_drift"] = end_point_drift(gt_eval, estimate)
    except (Lidar3dError, ValueError) as err:
        scores["gt"] = {"error": str(err)}
        scores["end_drift"] = {"error": str(err)}
    try:
        span_eval = evaluate_against_span(
            estimate,
            span_log,
            T_imu_lidar=read_extrinsic(extrinsics),
            trajectory_source=str(trajectory_path),
        )
        if report_dir is not None:
            write_span_report(span_eval, report_dir)
        scores["span"] = _evaluation_dict(span_eval.evaluation)
    except (Lidar3dError, ValueError) as err:
        scores["span"] = {"error": str(err)}
    return scores


def loop_closures(counts: dict) -> int | None:
    """Accepted loop closures in a run's ``counts``: the ``loop_closures`` counter, else the sum
    of counters named ``loop_closures_*accepted*``; None when the pipeline reports none (odometry only)."""
    if "loop_closures" in counts:
        return int(counts["loop_closures"])
    accepted = [int(v) for k, v in counts.items() if k.startswith("loop_closure") and "accept" in k]
    return sum(accepted) if accepted else None
