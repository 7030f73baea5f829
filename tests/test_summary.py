"""The run summary record: JSON round trips, the layout of ``summary.json``, and every kind of bad file."""

from __future__ import annotations

import dataclasses
import json

import pytest

from lidar3d.errors import Lidar3dError, SummaryError
from lidar3d.summary import (
    AteSummary,
    ErrorSummary,
    EvaluationSummary,
    HealthStretch,
    HealthSummary,
    InputStatistics,
    OutputFile,
    RunCounts,
    RunSummary,
    StageMedians,
    read_summary,
)

# The keys of summary.json in order, as lidar3d wrote them before RunSummary existed.
TOP_LEVEL_KEYS = [
    "lidar3d_version",
    "inputs",
    "topic",
    "partial",
    "scans",
    "keyframes",
    "length_m",
    "duration_s",
    "runtime_s",
    "scans_per_s",
    "stage_ms_median",
    "map_points",
    "loop_closures",
    "loop_candidates",
    "loop_ms_total",
    "counts",
    "warnings",
    "pose_stamp",
]


def error_summary(rmse: float | None = 0.25, n: int = 68) -> ErrorSummary:
    return ErrorSummary(rmse=rmse, mean=0.2, median=0.19, std=0.05, min=0.01, max=0.6, n=n)


def example_summary(**changes) -> RunSummary:
    """A complete summary (every optional block present) with ``changes`` applied."""
    summary = RunSummary(
        lidar3d_version="0.1.0",
        inputs=("drive_0.bag", "drive_1.bag"),
        topic="/velodyne_points",
        partial=False,
        scans=80,
        keyframes=35,
        length_m=42.948,
        duration_s=7.9,
        runtime_s=15.193,
        scans_per_s=5.27,
        stage_ms_median=StageMedians(
            read=2.108,
            projection=10.995,
            ground=16.052,
            clustering=13.763,
            smoothness=1.574,
            selection=14.833,
            deskew=2.862,
            odometry=20.118,
            mapping=70.647,
            map_update=17.915,
            redeskew=0.055,
            dense_map=21.004,
        ),
        map_points=155082,
        loop_closures=2,
        loop_candidates=5,
        loop_ms_total=58.3,
        counts=RunCounts(scans=80, redeskewed_scans=39, loop_closures=2, dropped_duplicate_stamps=1),
        warnings=("scans 2-3: too few features, pose from the motion model",),
        pose_stamp="header stamp of each scan (sweep start for the velodyne driver)",
        input_stats=InputStatistics(
            points_kept=2178288,
            nonfinite_dropped=3,
            below_min_range_dropped=0,
            absurd_coordinates_dropped=2,
            outlier_times_dropped=1,
            messages_lost=0,
            scans_timed_from_azimuth=80,
        ),
        map_rebuild_s=3.5,
        evaluation=EvaluationSummary(
            report="out/eval",
            table="  ATE    rmse\n  3-D    0.250",
            ate=AteSummary(error_summary(), error_summary(0.2), error_summary(0.1), error_summary(0.6)),
        ),
        evaluation_error=None,
    )
    return dataclasses.replace(summary, **changes)


# -- round trips and layout ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "summary",
    [
        example_summary(),
        example_summary(evaluation=None, evaluation_error="evaluation against span.log failed: no overlap"),
        example_summary(input_stats=None, map_rebuild_s=None, evaluation=None, partial=True),
        example_summary(
            outputs=(OutputFile("eval/report.json", 812, "0" * 64), OutputFile("map.pcd", 1_861_232, "ab" * 32, 155082))
        ),
        example_summary(
            evaluation=dataclasses.replace(example_summary().evaluation, ate=AteSummary(*[error_summary(None, 0)] * 4))
        ),
        example_summary(
            health=HealthSummary(
                62,
                4,
                14,
                0.775,
                31.25,
                (HealthStretch(40, 53, 1_715_677_204_000_000_000, 1_715_677_205_300_000_000, 31.25),),
            )
        ),
        example_summary(health=HealthSummary(80, 0, 0, 1.0, 0.0)),
        example_summary(dynamic_points=1234),
    ],
    ids=[
        "complete",
        "evaluation-error",
        "checkpoint",
        "manifest",
        "no-associated-pose",
        "health-lost",
        "health-ok",
        "dynamic-removal",
    ],
)
def test_json_round_trip_gives_the_same_record_and_text(summary, tmp_path):
    text = summary.to_json()
    assert RunSummary.from_json(text) == summary
    assert RunSummary.from_json(text).to_json() == text
    path = tmp_path / "summary.json"
    path.write_text(text)
    assert read_summary(path) == summary


def test_json_layout_is_the_one_summary_json_always_had():
    data = json.loads(example_summary().to_json())
    assert list(data) == [*TOP_LEVEL_KEYS, "input_stats", "map_rebuild_s", "evaluation"]
    assert list(data["stage_ms_median"])[:2] == ["read", "projection"] and data["stage_ms_median"]["redeskew"] == 0.055
    assert data["counts"] == {"scans": 80, "redeskewed_scans": 39, "loop_closures": 2, "dropped_duplicate_stamps": 1}
    assert data["inputs"] == ["drive_0.bag", "drive_1.bag"] and isinstance(data["warnings"], list)
    assert list(data["evaluation"]) == ["report", "table", "ate"]
    assert list(data["evaluation"]["ate"]) == ["translation_3d_m", "horizontal_m", "vertical_m", "rotation_deg"]
    assert list(data["evaluation"]["ate"]["vertical_m"]) == ["rmse", "mean", "median", "std", "min", "max", "n"]
    # Optional parts that do not apply are left out, not written as null.
    short = json.loads(example_summary(input_stats=None, map_rebuild_s=None, evaluation=None).to_json())
    assert list(short) == TOP_LEVEL_KEYS
    with_dynamic = json.loads(example_summary(dynamic_points=7).to_json())
    assert list(with_dynamic)[-3:] == ["map_rebuild_s", "dynamic_points", "evaluation"]
    assert with_dynamic["dynamic_points"] == 7
    no_redeskew = dataclasses.replace(example_summary().stage_ms_median, redeskew=None)
    assert "redeskew" not in json.loads(example_summary(stage_ms_median=no_redeskew).to_json())["stage_ms_median"]


def test_a_summary_written_by_run_bag_parses_and_is_rewritten_byte_for_byte(tmp_path):
    from lidar3d.run import run_bag

    sim = pytest.importorskip("lidar3d.sim")
    simulated = sim.simulate("loop", tmp_path / "sim", seed=0, duration_s=2.0)
    out = tmp_path / "out"
    outcome = run_bag(simulated.bag, out, span_log=simulated.span_log, extrinsics=simulated.extrinsics, prefetch=False)
    text = (out / "summary.json").read_text()
    summary = read_summary(out / "summary.json")
    assert summary == outcome.summary and summary.to_json() == text
    assert list(json.loads(text)) == [
        *TOP_LEVEL_KEYS,
        "health",
        "input_stats",
        "dynamic_points",
        "evaluation",
        "outputs",
    ]
    assert summary.health is not None and summary.health.scans == summary.scans
    assert summary.output("health.csv").rows == summary.scans
    paths = [entry.path for entry in summary.outputs]
    assert paths == sorted(paths) and {"config.toml", "eval/report.json", "map.pcd", "trajectory_tum.txt"} <= set(paths)
    assert summary.output("trajectory_tum.txt").rows == summary.scans
    assert summary.scans == summary.counts.scans == len(outcome.result.trajectory) > 0 and summary.partial is False
    assert summary.evaluation is not None and summary.evaluation.report == str(out / "eval")
    report = json.loads((out / "eval" / "report.json").read_text())
    assert summary.evaluation.ate.as_dict() == report["ate"]


def test_evaluation_from_dict_takes_the_dict_run_bag_builds():
    evaluation = example_summary().evaluation
    assert EvaluationSummary.from_dict(evaluation.as_dict()) == evaluation
    with pytest.raises(SummaryError, match=r"^evaluation: key 'ate.rotation_deg' is missing$"):
        data = evaluation.as_dict()
        del data["ate"]["rotation_deg"]
        EvaluationSummary.from_dict(data)


def test_integers_are_accepted_where_numbers_are_expected():
    data = json.loads(example_summary().to_json())
    data["duration_s"] = 8
    summary = RunSummary.from_json(json.dumps(data))
    assert summary.duration_s == 8.0 and isinstance(summary.duration_s, float)


# -- errors ----------------------------------------------------------------------------------------------


def _broken(change) -> str:
    data = json.loads(example_summary().to_json())
    change(data)
    return json.dumps(data)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d.pop("scans"), "key 'scans' is missing"),
        (lambda d: d.update(scans="80"), "'scans' must be an integer, got \"80\""),
        (lambda d: d.update(scans=80.0), "'scans' must be an integer, got 80.0"),
        (lambda d: d.update(partial=0), "'partial' must be true or false, got 0"),
        (lambda d: d.update(length_m=True), "'length_m' must be a number, got true"),
        (lambda d: d.update(inputs="drive.bag"), "'inputs' must be a list of strings, got \"drive.bag\""),
        (lambda d: d.update(warnings=[1]), "'warnings' must be a list of strings, got \\[1\\]"),
        (lambda d: d.update(stage_ms_median=[]), "'stage_ms_median' must be an object, got \\[\\]"),
        (lambda d: d["stage_ms_median"].pop("mapping"), "key 'stage_ms_median.mapping' is missing"),
        (lambda d: d["stage_ms_median"].update(tracking=1.0), "unknown key 'stage_ms_median.tracking'"),
        (lambda d: d["counts"].update(scans=-0.5), "'counts.scans' must be an integer, got -0.5"),
        (lambda d: d["input_stats"].pop("messages_lost"), "key 'input_stats.messages_lost' is missing"),
        (
            lambda d: d["input_stats"].pop("scans_timed_from_azimuth"),
            "key 'input_stats.scans_timed_from_azimuth' is missing",
        ),
        (
            lambda d: d["input_stats"].pop("outlier_times_dropped"),
            "key 'input_stats.outlier_times_dropped' is missing",
        ),
        (
            lambda d: d["evaluation"]["ate"]["translation_3d_m"].update(rmse="x"),
            "'evaluation.ate.translation_3d_m.rmse' must be a number or null, got \"x\"",
        ),
        (lambda d: d["evaluation"].update(table=None), "'evaluation.table' must be a string, got null"),
        (lambda d: d.update(evaluation_error=3), "'evaluation_error' must be a string, got 3"),
        (lambda d: d.update(scan_count=80), "unknown key 'scan_count'"),
        (lambda d: d.update(outputs=[]), "'outputs' must be an object, got \\[\\]"),
        (lambda d: d.update(outputs={"map.pcd": {"size_bytes": 1}}), "key 'outputs.map.pcd.sha256' is missing"),
        (
            lambda d: d.update(outputs={"map.pcd": {"size_bytes": 1, "sha256": "ABC"}}),
            "'outputs.map.pcd.sha256' must be 64 lower-case hex digits",
        ),
        (
            lambda d: d.update(outputs={"../map.pcd": {"size_bytes": 1, "sha256": "0" * 64}}),
            "output path '../map.pcd' is not a plain relative path inside the run folder",
        ),
        (
            lambda d: d.update(outputs={"map.pcd": {"size_bytes": 1, "sha256": "0" * 64, "points": 3}}),
            "unknown key 'outputs.map.pcd.points'",
        ),
    ],
)
def test_a_malformed_summary_names_the_file_and_the_key(change, message):
    with pytest.raises(SummaryError, match=rf"^runs/a/summary\.json: {message}$"):
        RunSummary.from_json(_broken(change), source="runs/a/summary.json")


def test_files_that_are_not_summaries(tmp_path):
    path = tmp_path / "summary.json"
    with pytest.raises(SummaryError, match=r"summary\.json: cannot read the run summary \(No such file"):
        read_summary(path)
    path.write_text('{"scans": 8,')
    with pytest.raises(SummaryError, match=r"summary\.json: not valid JSON \(Expecting"):
        read_summary(path)
    path.write_text("[1, 2]")
    with pytest.raises(SummaryError, match=r"summary\.json: not a JSON object$"):
        read_summary(path)
    path.write_text("{}")
    with pytest.raises(Lidar3dError, match=r"summary\.json: key 'lidar3d_version' is missing$"):
        read_summary(path)


def test_input_statistics_warn_about_damaged_points_only():
    clean = InputStatistics(
        points_kept=10,
        nonfinite_dropped=4,
        below_min_range_dropped=5,
        absurd_coordinates_dropped=0,
        outlier_times_dropped=0,
        messages_lost=0,
        scans_timed_from_azimuth=10,
    )
    assert clean.damage_warning() is None  # NaN for missing returns is what drivers write
    damaged = dataclasses.replace(clean, absurd_coordinates_dropped=2, outlier_times_dropped=1)
    assert damaged.damage_warning() == (
        "input sanity: dropped 2 points with absurd coordinates and 1 with point times outside the sweep "
        "(4 non-finite points also dropped); see input_stats in summary.json"
    )
