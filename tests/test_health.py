"""The per-scan health signal: the classifier on synthetic measures, its adapter from a TrackResult,
``health.csv``, the summary and warning of a run, the batch column, and ``eval/health_check.py``."""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from suite_header import SUITE_HEADER
from test_summary import example_summary

from lidar3d.batch.report import bag_row, write_report
from lidar3d.cli.main import main
from lidar3d.config import HealthConfig
from lidar3d.errors import SummaryError
from lidar3d.io.health_csv import HEALTH_COLUMNS, HealthFileError, read_health_csv, write_health_csv
from lidar3d.io.run_folder import RunFolderState, check_run_folder, publish_set
from lidar3d.io.trajectory_io import write_tum
from lidar3d.mapping.health import (
    HealthFlag,
    HealthMonitor,
    ScanHealth,
    ScanMeasures,
    flag_stretches,
    scan_measures,
    summarize_health,
)
from lidar3d.mapping.keyframes import Keyframe, Submap
from lidar3d.mapping.odometry import OdometryStep
from lidar3d.mapping.registration import PosePrior, SolveResult
from lidar3d.mapping.se3 import pose_from_xyz_rpy
from lidar3d.mapping.tracker import TrackResult
from lidar3d.records import Trajectory
from lidar3d.run_statistics import RunStatistics
from lidar3d.summary import HealthStretch, HealthSummary, RunSummary

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "eval"))
from health_check import check_health, local_drift_errors  # noqa: E402
from health_check import main as health_check_main  # noqa: E402

CONFIG = HealthConfig()
S = 10**9


def measures(step_m: float = 0.5, *, sigma_m: float = 0.002, registered: bool = True, **changes) -> ScanMeasures:
    """A scan moving ``step_m`` whose registration left ``sigma_m`` along its weakest direction,
    its pose known to 1 cm."""
    base = ScanMeasures(
        registered=registered,
        motion_model_only=False,
        n_rows=1500 if registered else 0,
        prior_axes=0 if registered else 6,
        weakest_sigma_m=sigma_m if registered else np.inf,
        step_m=step_m,
        odometry_disagreement_m=0.02,
        prediction_offset_m=0.02,
        pose_sigma_m=0.01,
    )
    return dataclasses.replace(base, **changes)


def assess_all(sequence: list[ScanMeasures], config: HealthConfig = CONFIG) -> list[ScanHealth]:
    monitor = HealthMonitor(config)
    return [monitor.assess(i * S // 10, m) for i, m in enumerate(sequence)]


def flags(health: list[ScanHealth]) -> str:
    return "".join(h.flag.value[0] for h in health)  # o, d, l


# -- the classifier -------------------------------------------------------------------------------------


def test_unobserved_travel_is_lost_at_the_documented_distance():
    # 0.5 m per scan: 10 m (lost_after_m) after 20 unobserved scans.
    blind = measures(sigma_m=10 * CONFIG.observed_sigma_m)
    health = assess_all([measures()] * 5 + [blind] * 24)
    assert flags(health) == "o" * 5 + "o" * 19 + "l" * 5
    assert [h.dead_reckoned_m for h in health[5:9]] == [h.blind_m for h in health[5:9]] == [0.5, 1.0, 1.5, 2.0]
    assert not any(h.observed for h in health[5:]) and all(h.observed for h in health[:5])


def test_an_uncertain_pose_is_degraded_from_the_documented_sigma():
    sigmas = [0.01, 0.05, CONFIG.degraded_sigma_m, 1.01 * CONFIG.degraded_sigma_m, 0.5, 0.05]
    assert flags(assess_all([measures(pose_sigma_m=s) for s in sigmas])) == "ooodd" + "o"
    # not measured (a table of an earlier release) is not evidence either way
    assert flags(assess_all([measures(pose_sigma_m=float("nan"))] * 3)) == "ooo"


def test_a_direction_taken_from_the_prior_is_counted_but_degrades_only_with_the_uncertainty():
    # Well observed but for one direction the registration took from the motion model: a forest
    # trail where the scans know it about as well as the vehicle model, the pose to 3 cm.
    one_from_prior = measures(prior_axes=1, pose_sigma_m=0.03)
    assert one_from_prior.observes_pose(CONFIG) and not one_from_prior.observes_every_direction(CONFIG)
    health = assess_all([measures()] * 5 + [one_from_prior] * 100 + [measures()] * 4)
    assert flags(health) == "o" * 109
    assert health[104].dead_reckoned_m == 50.0 and health[104].blind_m == 0.0
    drifting = [dataclasses.replace(one_from_prior, pose_sigma_m=0.02 * k) for k in range(10)]
    assert flags(assess_all(drifting)) == "oooooodddd"
    # Blind scans among them are counted apart: lost after 10 m of those alone.
    mixed = assess_all(([one_from_prior] * 3 + [measures(sigma_m=1.0)]) * 25)
    assert mixed[-1].blind_m == 12.5 and mixed[-1].flag is HealthFlag.LOST
    assert [h.flag for h in mixed].index(HealthFlag.LOST) == 79  # the 20th blind scan


def test_a_single_bad_scan_or_a_short_blind_patch_does_not_flag():
    bad_kinds = [
        measures(sigma_m=1.0),
        measures(registered=False),
        measures(motion_model_only=True),
        measures(odometry_disagreement_m=0.99 * CONFIG.jump_m),  # inconsistent, but within the tolerance
    ]
    for bad in bad_kinds:
        health = assess_all([measures()] * 10 + [bad] + [measures()] * 10)
        assert flags(health) == "o" * 21, bad
        assert not health[10].observed
    # Three blind scans at 0.5 m: 1.5 m.
    assert set(flags(assess_all([measures()] * 3 + [measures(sigma_m=1.0)] * 3 + [measures()] * 3))) == {"o"}


def test_a_step_the_odometry_contradicts_by_the_tolerance_degrades_the_travel_after_it():
    # blind_turn seed 2's turn exit: the refined step 0.64 m long, 0.96 m from the odometry's,
    # every other measure calm; the next 10 m of the trajectory carry that error.
    assert CONFIG.max_disagreement_m < CONFIG.jump_m
    jump = measures(odometry_disagreement_m=CONFIG.jump_m)
    health = assess_all([measures()] * 10 + [jump] + [measures()] * 30)
    window = int(CONFIG.jump_window_m / 0.5)  # scans of 0.5 m after the jump still within the window
    assert flags(health) == "o" * 10 + "d" * (1 + window) + "o" * (30 - window)
    # A standstill after it adds no travel: still degraded.
    stopped = assess_all([jump] + [measures(0.0)] * 50)
    assert set(flags(stopped)) == {"d"}
    off = dataclasses.replace(CONFIG, jump_window_m=0.0)
    assert flags(assess_all([measures()] * 3 + [jump] + [measures()] * 3, off)) == "ooo" + "d" + "ooo"


def test_observed_travel_clears_the_state_only_after_the_documented_distance():
    blind, seen = measures(sigma_m=1.0), measures()
    health = assess_all([blind] * 30 + [seen] * 3 + [blind] + [seen] * 4)
    # Lost after 20 blind scans; 1.5 m of observed travel is not enough, the blind scan restarts
    # the count; 4 x 0.5 m = 2 m (clear_after_m) of observed travel clears it on the last scan.
    assert flags(health) == "o" * 19 + "l" * 11 + "lll" + "l" + "lll" + "o"
    assert health[-1].dead_reckoned_m == 0.0


def test_a_standstill_without_registration_adds_no_travel():
    """Neither lost nor inconsistent (here with its pose known, as while it registers)."""
    assert set(flags(assess_all([measures(step_m=0.0, registered=False)] * 200))) == {"o"}


def test_thresholds_come_from_the_config():
    blind = measures(step_m=1.0, sigma_m=0.05, pose_sigma_m=0.2)
    strict = HealthConfig(observed_sigma_m=0.1, degraded_sigma_m=0.3, lost_after_m=3.0)
    assert flags(assess_all([blind] * 12)) == "d" * 9 + "lll"  # default: 0.1 m, 10 m
    assert flags(assess_all([blind] * 4, strict)) == "oooo"  # 0.05 m is observed under 0.1 m, 0.2 m under 0.3 m
    assert flags(assess_all([measures(step_m=1.0, sigma_m=0.5)] * 4, strict)) == "ooll"


# The window tests' arithmetic uses a 10 m window and floors of 0.1 deg and 0.05 m.
WINDOW = dataclasses.replace(CONFIG, consistency_window_m=10.0, heading_sigma_floor_deg=0.1, along_sigma_floor_m=0.05)


def heading(difference_deg: float, sigma_deg: float = 0.02, **changes) -> ScanMeasures:
    """A fully observed scan whose refined yaw step is ``difference_deg`` off the odometry's."""
    return measures(
        heading_difference_rad=np.radians(difference_deg), odometry_yaw_sigma_rad=np.radians(sigma_deg), **changes
    )


def test_a_scan_registered_against_keyframes_placed_while_lost_is_degraded_unless_it_came_from_trusted_tracking():
    # Coming out of a lost stretch: observed and confident, but its submap holds the keyframes that
    # were dead-reckoned, and it came from them: degraded until the submap moves on past them.
    blind = measures(sigma_m=10 * CONFIG.observed_sigma_m)
    on_lost_map = measures(lost_keyframes=3)
    health = flags(assess_all([blind] * 25 + [on_lost_map] * 10 + [measures()] * 2))
    clearing = int(CONFIG.clear_after_m / 0.5) - 1  # observed scans still lost before the state clears
    assert health == "o" * 19 + "l" * (6 + clearing) + "d" * (10 - clearing) + "oo"
    # Coming back to them from trusted tracking (a figure eight crossing a stretch that was lost):
    # a displaced map would pull the pose across the displacement, which the odometry contradicts;
    # while it does not, the keyframes agree with the map the scans came from.
    assert flags(assess_all([measures()] * 2 + [on_lost_map] * 3 + [measures()] * 2)) == "o" * 7
    jump = measures(odometry_disagreement_m=CONFIG.jump_m, lost_keyframes=3)
    window = int(CONFIG.jump_window_m / 0.5)
    health = flags(
        assess_all([measures()] * 2 + [on_lost_map] * 2 + [jump] + [on_lost_map] * (window + 5) + [measures()])
    )
    assert health == "oooo" + "d" * (1 + window + 5) + "o"  # once contradicted, not trusted while on them
    # Lost again while on them: the keyframes placed from then on are dead-reckoned too, so the
    # scans coming out of it are degraded, checked or not before.
    blind_on_map = dataclasses.replace(blind, lost_keyframes=3)
    health = flags(assess_all([measures()] * 2 + [on_lost_map] * 2 + [blind_on_map] * 25 + [on_lost_map] * 10))
    assert health == "o" * 4 + "o" * 19 + "l" * (6 + clearing) + "d" * (10 - clearing)
    # A lost scan stays lost whatever its submap holds.
    assert flags(assess_all([dataclasses.replace(blind, lost_keyframes=2)] * 25))[-1] == "l"


def _keyframe(index: int, x_m: float, lost: bool) -> Keyframe:
    rng = np.random.default_rng(index)
    wall = np.column_stack([rng.uniform(-5, 5, 300), np.full(300, 4.0), rng.uniform(0, 3, 300)])
    ground = np.column_stack([rng.uniform(-5, 5, 300), rng.uniform(-3, 3, 300), np.full(300, -1.8)])
    pose = pose_from_xyz_rpy(np.array([x_m, 0.0, 0.0, 0.0, 0.0, 0.0]))
    return Keyframe(index, index, index * S, pose, wall[:40], np.concatenate([wall, ground]), placed_lost=lost)


def test_the_submap_counts_the_keyframes_placed_while_lost_that_it_registers_against():
    submap = Submap(radius_m=20.0, max_keyframes=60, recent=2, corner_voxel_m=0.2, surf_voxel_m=0.4)
    assert submap.lost_keyframes_in_target() == 0  # no target yet
    for k in range(30):  # keyframes 10-14 were placed while lost, 1 m apart along x
        submap.add(_keyframe(k, float(k), 10 <= k < 15))
    submap.target(np.array([12.0, 0.0, 0.0]))
    assert submap.lost_keyframes_in_target() == 5
    submap.target(np.array([29.0, 0.0, 0.0]))  # within 20 m: keyframes 9.x-29; 10-14 among them
    assert submap.lost_keyframes_in_target() == 5
    far = Submap(radius_m=10.0, max_keyframes=60, recent=2, corner_voxel_m=0.2, surf_voxel_m=0.4)
    for k in range(30):
        far.add(_keyframe(k, float(k), 10 <= k < 15))
    far.target(np.array([29.0, 0.0, 0.0]))  # the lost ones are out of reach
    assert far.lost_keyframes_in_target() == 0
    # New clouds for a keyframe (deskewed again) keep the mark.
    submap.replace_clouds(12, *(c[:10] for c in (submap.keyframes[12].corner_points, submap.keyframes[12].surf_points)))
    assert submap.keyframes[12].placed_lost and not submap.keyframes[20].placed_lost
    submap.target(np.array([12.0, 0.0, 0.0]))
    assert submap.lost_keyframes_in_target() == 5


def test_a_steady_heading_pull_flags_degraded_once_it_exceeds_the_odometrys_uncertainty():
    # 0.05 deg a scan (blind_turn seed 1's pull), odometry sigma 0.02 deg a scan, 0.5 m steps: over
    # The 10 m window holds 20 scans: with n pulled scans in it z = 0.05 n / sqrt(0.02^2 20 + 0.1^2),
    # above 4 from n = 11: the 11th pulled scan, until the 9th scan after the pull ended.
    health = assess_all([heading(0.0)] * 30 + [heading(-0.05)] * 40 + [heading(0.0)] * 30, WINDOW)
    z = [h.heading_z for h in health]
    assert max(z[:30]) == 0.0
    assert z[40] == pytest.approx(0.05 * 11 / np.hypot(0.02 * np.sqrt(20), 0.1))
    assert flags(health) == "o" * 40 + "d" * 39 + "o" * 21
    assert all(h.dead_reckoned_m == 0.0 for h in health)  # the flag is the heading's alone
    # The same pull within what the odometry does not know is no evidence.
    assert set(flags(assess_all([heading(-0.05, sigma_deg=0.5)] * 60, WINDOW))) == {"o"}


def test_heading_noise_within_the_stated_uncertainty_rarely_flags():
    rng = np.random.default_rng(3)
    differences = rng.normal(0.0, 0.03, 4000)  # odometry sigma 0.03 deg a scan, as stated
    health = assess_all([heading(d, sigma_deg=0.03) for d in differences], WINDOW)
    assert max(h.heading_z for h in health) < CONFIG.max_consistency_z
    # A pull of 0.05 deg a scan on the same noise is found within the window (z about 6).
    pulled = assess_all([heading(d - 0.05, sigma_deg=0.03) for d in differences[:200]], WINDOW)
    assert np.mean([h.flag is HealthFlag.DEGRADED for h in pulled[40:]]) > 0.9


def test_scans_without_an_odometry_yaw_add_nothing_and_the_window_is_travel():
    unmeasured = heading(5.0, sigma_deg=np.inf)
    assert set(flags(assess_all([unmeasured] * 50, WINDOW))) == {"o"}
    # Standing still (no travel) adds nothing and keeps the window as it was: a long stop's noise
    # never raises the flag, and the drift before it is still there after it.
    still = heading(-0.05, step_m=0.0)
    health = assess_all([heading(0.0)] * 25 + [still] * 400, WINDOW)
    assert {h.heading_z for h in health[25:]} == {health[24].heading_z} and set(flags(health)) == {"o"}
    health = assess_all([heading(-0.05)] * 25 + [still] * 40 + [heading(0.0)], WINDOW)
    assert all(h.flag is HealthFlag.DEGRADED for h in health[15:])
    strict = dataclasses.replace(CONFIG, consistency_window_m=1.0, heading_sigma_floor_deg=0.0)
    short = assess_all([heading(-0.05)] * 10, strict)  # 1 m: the last two scans
    assert short[-1].heading_z == pytest.approx(0.1 / (0.02 * np.sqrt(2)))


def test_steps_shorter_than_the_odometrys_flag_through_the_along_track_window():
    # Each refined step 24 mm shorter than the odometry's (blind_turn seed 1's), odometry sigma
    # 10 mm a step: with n short steps among the window's 20, z = 0.024 n / sqrt(0.01^2 20 + 0.05^2),
    # above 4 from n = 12.
    short = measures(along_difference_m=-0.024, odometry_along_sigma_m=0.01)
    health = assess_all([measures(odometry_along_sigma_m=0.01)] * 30 + [short] * 30, WINDOW)
    assert [h.flag for h in health].index(HealthFlag.DEGRADED) == 30 + 11
    assert health[-1].along_z == pytest.approx(0.024 * 20 / np.hypot(0.01 * np.sqrt(20), 0.05))
    assert all(h.heading_z == 0.0 for h in health)
    # Unobserved along-track (inf sigma) is no evidence.
    assert set(flags(assess_all([measures(along_difference_m=-0.5)] * 60, WINDOW))) == {"o"}
    # Braking: the constant-velocity guess ran 50 mm long, the odometry moved back 20 mm of it and
    # its step stays 30 mm longer than the refined one. Up to travel_share (1) of the 20 mm it moved
    # is put down to its stopping short: 10 mm a step remain, z = 0.2 / sqrt(20 0.01^2 + 0.05^2) = 3.
    braking = measures(along_difference_m=-0.03, odometry_along_sigma_m=0.01, odometry_along_travel_m=-0.02)
    health = assess_all([braking] * 40, WINDOW)
    assert health[-1].along_z == pytest.approx(0.2 / np.sqrt(20 * 1e-4 + 0.05**2))
    assert set(flags(health)) == {"o"}
    assert assess_all([braking] * 40, dataclasses.replace(WINDOW, travel_share=0.0))[-1].flag is HealthFlag.DEGRADED
    # The other way round (blind_turn seed 1): the guess came from the short refined steps, the
    # odometry moved 20 mm forward from it and the refined step is 30 mm shorter: nothing is put
    # down to a shortfall, z = 0.6 / sqrt(0.002 + 0.0025) = 8.9.
    biased = measures(along_difference_m=-0.03, odometry_along_sigma_m=0.01, odometry_along_travel_m=0.02)
    assert assess_all([biased] * 40, WINDOW)[-1].along_z == pytest.approx(0.6 / np.sqrt(20 * 1e-4 + 0.05**2))


# -- the adapter from the tracker ---------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class _Posed:
    stamp_ns: int
    T_world_lidar: np.ndarray
    T_world_odom: np.ndarray


def _track(
    T_world_lidar,
    T_world_odom,
    registration,
    *,
    twist=None,
    stamp_ns=S // 10,
    prior=None,
    odometry_step=None,
) -> TrackResult:
    return TrackResult(
        stamp_ns=stamp_ns,
        T_world_lidar=T_world_lidar,
        T_world_odom=T_world_odom,
        motion_model_only=False,
        registration=registration,
        prior=prior,
        heading_observed=True,
        deskew_twist=np.zeros(6) if twist is None else twist,
        settled=None,
        timings_ms={},
        odometry_step=odometry_step,
    )


def test_measures_of_a_tracked_scan():
    previous = _Posed(0, np.eye(4), np.eye(4))
    refined = pose_from_xyz_rpy(np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
    odometry = pose_from_xyz_rpy(np.array([1.1, 0.0, 0.0, 0.0, 0.0, np.radians(0.5)]))  # 0.1 m and 0.5 deg off
    registration = SolveResult(refined, 5, True, 1234, 1, 100.0)
    twist = np.array([9.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # 0.9 m in 0.1 s: 0.1 m short
    # The odometry's edge rows: 2 cm along x (the step's direction), 5 cm across, 0.001 rad of yaw;
    # it moved 3 cm forward and 0.2 deg from its guess.
    edge_information = np.diag([0.02**-2, 0.05**-2, 0.0, 0.0, 0.0, 0.001**-2])
    step = OdometryStep(odometry, False, 300, 100, True, edge_information, np.radians(0.2), np.array([0.03, 0.0]))
    track = _track(refined, odometry, registration, twist=twist, odometry_step=step)
    m = scan_measures(track, previous, CONFIG)
    assert m.registered and m.n_rows == 1234 and m.prior_axes == 1
    assert m.heading_difference_rad == pytest.approx(np.radians(-0.5))
    assert m.odometry_yaw_sigma_rad == pytest.approx(0.001) and m.odometry_yaw_travel_rad == pytest.approx(
        np.radians(0.2)
    )
    assert m.along_difference_m == pytest.approx(-0.1) and m.odometry_along_sigma_m == pytest.approx(0.02)
    assert m.odometry_along_travel_m == pytest.approx(0.03)
    assert scan_measures(_track(refined, odometry, registration), previous, CONFIG).odometry_along_sigma_m == np.inf
    assert m.weakest_sigma_m == pytest.approx(CONFIG.residual_sigma_m / 10.0)
    assert m.step_m == pytest.approx(1.0)
    assert m.odometry_disagreement_m == pytest.approx(0.1 + CONFIG.lever_m * np.radians(0.5))
    assert m.prediction_offset_m == pytest.approx(0.1)
    assert m.observes_pose(CONFIG)
    assert not m.observes_pose(dataclasses.replace(CONFIG, observed_sigma_m=0.004))
    assert not m.observes_pose(dataclasses.replace(CONFIG, max_disagreement_m=0.15))


def test_prior_axes_count_the_axes_the_motion_prior_decided():
    """With a prior, an axis counts when the scan removed less than half of the prior's variance
    there: here the scan says nothing about x and little about yaw, and much about the rest."""
    refined = np.eye(4)
    prior = PosePrior(np.eye(4), np.diag([1e4, 1e4, 1e4, 1e6, 1e6, 1e6]))
    information = np.diag([0.0, 1e6, 1e6, 1e8, 1e8, 0.5e6])
    registration = SolveResult(refined, 5, True, 1234, 0, 500.0, information, 0.02)
    m = scan_measures(_track(refined, refined, registration, prior=prior), None, CONFIG)
    assert m.prior_axes == 2
    assert m.weakest_sigma_m == pytest.approx(0.02 / np.sqrt(500.0))  # the measured residual sigma


def test_a_direction_the_rows_do_not_see_has_an_infinite_sigma():
    """An eigenvalue within rounding of zero (a direction projected out of the rows) is reported
    as an infinite sigma, not as a length of 1e148 m."""
    for rounding_zero in (1e-296, 6e-15):
        registration = SolveResult(np.eye(4), 5, True, 3357, 1, rounding_zero, np.eye(6), 0.02)
        m = scan_measures(_track(np.eye(4), np.eye(4), registration), None, CONFIG)
        assert m.registered and m.weakest_sigma_m == np.inf
    registration = SolveResult(np.eye(4), 5, True, 3357, 1, 1e-6, np.eye(6), 0.02)
    m = scan_measures(_track(np.eye(4), np.eye(4), registration), None, CONFIG)
    assert m.weakest_sigma_m == pytest.approx(20.0)


def test_measures_without_registration_or_previous_scan():
    m = scan_measures(_track(np.eye(4), np.eye(4), None), None, CONFIG)
    assert not m.registered and m.weakest_sigma_m == np.inf and m.prior_axes == 6 and m.n_rows == 0
    assert m.step_m == m.odometry_disagreement_m == m.prediction_offset_m == m.heading_difference_rad == 0.0
    assert m.odometry_yaw_sigma_rad == m.odometry_along_sigma_m == np.inf and m.along_difference_m == 0.0
    assert not m.observes_pose(CONFIG)


# -- stretches and summary ------------------------------------------------------------------------------


def _health_with(flag_text: str) -> list[ScanHealth]:
    by_letter = {f.value[0]: f for f in HealthFlag}
    return [ScanHealth(i * S, measures(), True, 0.0, 0.0, by_letter[c]) for i, c in enumerate(flag_text)]


def test_stretches_and_summary_measure_the_lost_scans_on_the_trajectory():
    assert flag_stretches([], HealthFlag.LOST) == []
    health = _health_with("oollldoll")
    assert flag_stretches([h.flag for h in health], HealthFlag.LOST) == [(2, 4), (7, 8)]
    positions = np.cumsum(np.full((9, 3), [1.0, 0.0, 0.0]), axis=0)  # 1 m per scan
    summary = summarize_health(health, np.arange(9) + 100, positions)
    assert (summary.ok_scans, summary.degraded_scans, summary.lost_scans, summary.scans) == (3, 1, 5, 9)
    assert summary.ok_fraction == pytest.approx(0.3333)
    first, second = summary.lost_stretches
    assert (first.first_scan, first.last_scan, first.start_stamp_ns, first.end_stamp_ns) == (102, 104, 2 * S, 4 * S)
    assert first.length_m == 3.0 and second.length_m == 2.0 and summary.lost_m == 5.0
    (degraded,) = summary.degraded_stretches
    assert (degraded.first_scan, degraded.last_scan, degraded.length_m, summary.degraded_m) == (105, 105, 1.0, 1.0)
    assert summarize_health([], [], np.zeros((0, 3))) == HealthSummary(0, 0, 0, 1.0, 0.0, ())


def _lost_summary(n_stretches: int) -> HealthSummary:
    stretches = tuple(HealthStretch(10 * i, 10 * i + 4, i * S, i * S + 4, 12.5) for i in range(n_stretches))
    return HealthSummary(50, 0, 5 * n_stretches, 0.5, 12.5 * n_stretches, stretches)


def test_a_run_with_lost_stretches_ends_with_one_warning_line():
    stats = RunStatistics()
    assert stats.warnings(10) == () and stats.warnings(10, _lost_summary(0)) == ()
    (line,) = stats.warnings(10, _lost_summary(1))
    assert line == (
        "health: lost on 1 stretch (12.5 m, 9 % of the scans): scans 0-4 (12.5 m); "
        "poses there may be metres wrong, see health.csv"
    )
    (line,) = stats.warnings(10, _lost_summary(7))
    assert line.startswith("health: lost on 7 stretches (87.5 m, 41 % of the scans): scans 0-4 (12.5 m), 10-14")
    assert "40-44 (12.5 m), and 2 more; poses there" in line and "\n" not in line


def test_degraded_stretches_get_a_warning_line_of_their_own():
    stretch = HealthStretch(20, 29, 20 * S, 29 * S, 8.5)
    lost_and_degraded = dataclasses.replace(
        _lost_summary(1), degraded_scans=10, degraded_m=8.5, degraded_stretches=(stretch,)
    )
    lost_line, degraded_line = RunStatistics().warnings(10, lost_and_degraded)
    assert lost_line.startswith("health: lost on 1 stretch")
    assert degraded_line == (
        "health: degraded on 1 stretch (8.5 m, 15 % of the scans): scans 20-29 (8.5 m); "
        "poses there may be decimetres to metres wrong, see health.csv"
    )


def test_summary_json_round_trip_keeps_the_health():
    summary = example_summary(health=_lost_summary(2))
    text = summary.to_json()
    assert RunSummary.from_json(text) == summary and RunSummary.from_json(text).to_json() == text
    data = json.loads(text)
    assert list(data["health"]) == [
        "ok_scans",
        "degraded_scans",
        "lost_scans",
        "ok_fraction",
        "lost_m",
        "lost_stretches",
        "degraded_m",
        "degraded_stretches",
    ]
    assert data["health"]["lost_stretches"][1] == {
        "first_scan": 10,
        "last_scan": 14,
        "start_stamp_ns": S,
        "end_stamp_ns": S + 4,
        "length_m": 12.5,
    }
    # A summary written before the degraded stretches were counted reads as having none.
    older = json.loads(text)
    del older["health"]["degraded_m"], older["health"]["degraded_stretches"]
    assert RunSummary.from_json(json.dumps(older)) == summary
    data["health"]["lost_stretches"][0]["length_m"] = "far"
    with pytest.raises(SummaryError, match=r"^s\.json: 'health\.lost_stretches\[0\]\.length_m' must be a number"):
        RunSummary.from_json(json.dumps(data), source="s.json")


# -- health.csv -----------------------------------------------------------------------------------------


def test_health_csv_round_trip(tmp_path):
    blind = measures(sigma_m=1.0)
    health = assess_all([measures(registered=False, step_m=0.0)] + [measures()] * 3 + [blind] * 30)
    path = tmp_path / "health.csv"
    write_health_csv(path, np.arange(34) + 7, health)
    lines = path.read_text().splitlines()
    assert lines[0] == ",".join(HEALTH_COLUMNS) and len(lines) == 35
    assert lines[1].startswith("7,0,ok,0,0.000,0.000,0,0,0,6,inf,")
    scans, back = read_health_csv(path)
    assert list(scans) == list(range(7, 41)) and [h.flag for h in back] == [h.flag for h in health]
    assert [h.measures for h in back] == [h.measures for h in health]  # these values print exactly in 6 digits


def test_a_health_csv_without_the_pose_uncertainty_is_read(tmp_path):
    path = tmp_path / "health.csv"
    write_health_csv(path, [0, 1], assess_all([measures(lost_keyframes=2), measures(lost_keyframes=2)]))
    lines = [line.rsplit(",", 2)[0] for line in path.read_text().splitlines()]
    path.write_text("\n".join(lines) + "\n")
    _, health = read_health_csv(path)
    assert [np.isnan(h.measures.pose_sigma_m) for h in health] == [True, True]
    assert health[1].measures.n_rows == 1500 and health[1].along_z == 0.0 and health[1].measures.lost_keyframes == 0


def test_a_health_csv_without_the_lost_keyframes_is_read(tmp_path):
    path = tmp_path / "health.csv"
    write_health_csv(path, [0], assess_all([measures(lost_keyframes=2, pose_sigma_m=0.03)]))
    assert path.read_text().splitlines()[1].endswith(",0.03,2")
    lines = [line.rsplit(",", 1)[0] for line in path.read_text().splitlines()]
    path.write_text("\n".join(lines) + "\n")
    _, (health,) = read_health_csv(path)
    assert health.measures.lost_keyframes == 0 and health.measures.pose_sigma_m == 0.03


def test_scan_measures_take_the_pose_sigma_from_its_covariance():
    covariance = np.diag([1e-8, 4e-6, 1e-6, 0.0025, 0.01, 0.0001])  # [w, v]: 2 mrad yaw, 0.1 m along y
    m = scan_measures(_track(np.eye(4), np.eye(4), None), None, CONFIG, covariance)
    assert m.pose_sigma_m == pytest.approx(0.1 + CONFIG.lever_m * 0.002)
    assert np.isnan(scan_measures(_track(np.eye(4), np.eye(4), None), None, CONFIG).pose_sigma_m)


def test_an_earlier_releases_health_csv_is_read_without_the_consistency_measures(tmp_path):
    path = tmp_path / "health.csv"
    earlier = HEALTH_COLUMNS[: HEALTH_COLUMNS.index("heading_difference_deg")]
    path.write_text(",".join(earlier) + "\n3,100,degraded,0,2.500,0.000,1,0,800,1,0.004,0.5,0.01,0.02,0.9\n")
    scans, (health,) = read_health_csv(path)
    assert list(scans) == [3] and health.flag is HealthFlag.DEGRADED and health.dead_reckoned_m == 2.5
    m = health.measures
    assert m.n_rows == 800 and m.probe_share == 0.9 and m.odometry_yaw_sigma_rad == m.odometry_along_sigma_m == np.inf
    assert m.heading_difference_rad == m.along_difference_m == health.heading_z == health.along_z == 0.0


@pytest.mark.parametrize(
    "text, message",
    [
        ("a,b\n", r"not a health table"),
        (",".join(HEALTH_COLUMNS) + "\n1,2,3\n", rf"health\.csv:2: 3 columns, expected {len(HEALTH_COLUMNS)}"),
        (
            ",".join(HEALTH_COLUMNS) + "\n0,0,fine,1,0,0,1,0,5,0,0.1,0,0,0,1,0,inf,0,0,inf,0,0,0,0.01,0\n",
            r"health\.csv:2: flag 'fine' is not one of",
        ),
        (
            ",".join(HEALTH_COLUMNS) + "\n0,0,ok,yes,0,0,1,0,5,0,0.1,0,0,0,1,0,inf,0,0,inf,0,0,0,0.01,0\n",
            r"health\.csv:2: 'yes' is not 0 or 1",
        ),
        (
            ",".join(HEALTH_COLUMNS) + "\n0,0,ok,1,0,0,1,0,5,0,0.1,0,0,0,1,0,inf,0,0,inf,0,0,0,0.01,-1\n",
            r"health\.csv:2: '-1' is not a count",
        ),
    ],
)
def test_a_malformed_health_csv_names_the_file_and_line(tmp_path, text, message):
    path = tmp_path / "health.csv"
    path.write_text(text)
    with pytest.raises(HealthFileError, match=message):
        read_health_csv(path)
    with pytest.raises(HealthFileError, match=r"missing\.csv: cannot read the health table"):
        read_health_csv(tmp_path / "missing.csv")


# -- a run end to end ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    sim = pytest.importorskip("lidar3d.sim")
    return sim.simulate("loop", tmp_path_factory.mktemp("sim") / "loop", seed=0, duration_s=2.5)


def _check_folder_health(out: Path) -> RunSummary:
    check = check_run_folder(out)
    assert check.state is RunFolderState.CONSISTENT, check.problems
    summary = check.summary
    assert summary is not None and summary.health is not None
    counted, entry = summary.health, summary.output("health.csv")
    scans, health = read_health_csv(out / "health.csv")
    assert entry is not None and entry.rows == summary.scans == len(health)
    counts = {flag: sum(row.flag is flag for row in health) for flag in HealthFlag}
    assert (counted.ok_scans, counted.degraded_scans, counted.lost_scans) == tuple(counts[f] for f in HealthFlag)
    assert counted.lost_scans == sum(s.last_scan - s.first_scan + 1 for s in counted.lost_stretches)
    assert list(scans) == list(range(len(health)))
    return summary


@pytest.fixture(scope="module")
def default_run(simulated, tmp_path_factory):
    """``lidar3d run`` with the default health settings: its folder and what it printed."""
    out = tmp_path_factory.mktemp("run") / "out"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        assert main(["-q", "run", str(simulated.bag), "--out", str(out), "--no-loop"]) == 0
    return out, printed.getvalue()


def test_a_run_writes_health_csv_consistent_with_its_summary(default_run):
    out, printed = default_run
    summary = _check_folder_health(out)
    assert summary.health.ok_fraction == 1.0 and summary.health.lost_stretches == ()
    assert not any(w.startswith("health:") for w in summary.warnings)
    assert "health: 100 % of the scans ok, 0 degraded, 0 lost" in printed and "warning: health" not in printed


def _run_observing_nothing(bag: Path, tmp_path: Path, lost_after_m: float) -> RunSummary:
    """``lidar3d run`` (exit 0) where nothing counts as observed and any uncertainty of the pose makes
    a scan degraded, ``lost_after_m`` lost; the checked summary of its folder."""
    config = tmp_path / "observing_nothing.toml"
    config.write_text(f"[health]\nobserved_sigma_m = 1e-9\ndegraded_sigma_m = 1e-9\nlost_after_m = {lost_after_m}\n")
    out = tmp_path / "out"
    assert main(["-q", "run", str(bag), "--out", str(out), "--no-loop", "--config", str(config)]) == 0
    return _check_folder_health(out)


def test_a_run_with_lost_stretches_exits_0_and_says_so(simulated, tmp_path, capsys):
    summary = _run_observing_nothing(simulated.bag, tmp_path, lost_after_m=0.02)
    # Its keyframes were placed while lost, and the later scans registered against them.
    _, health = read_health_csv(tmp_path / "out" / "health.csv")
    assert health[0].measures.lost_keyframes == 0 and health[-1].measures.lost_keyframes >= 3
    (stretch,) = summary.health.lost_stretches
    assert stretch.last_scan == summary.scans - 1 and stretch.length_m > 5.0
    warnings = [w for w in summary.warnings if w.startswith("health: lost")]
    assert len(warnings) == 1 and f"scans {stretch.first_scan}-{stretch.last_scan}" in warnings[0]
    printed = capsys.readouterr().out
    assert printed.count("warning: health: lost on 1 stretch") == 1
    # The batch report shows it in its health column.
    row = bag_row(name="sim", bag=simulated.bag, status="done", batch_dir=tmp_path, summary=summary)
    assert row["health"] == "lost" and row["lost_m"] == summary.health.lost_m
    page = write_report(tmp_path, [row], {"out_dir": str(tmp_path)}).html.read_text()
    assert f"lost {summary.health.lost_m:.1f} m: ok" in page and 'class="health-lost"' in page


def test_a_run_with_degraded_stretches_says_so_in_its_own_line(simulated, tmp_path, capsys):
    summary = _run_observing_nothing(simulated.bag, tmp_path, lost_after_m=1e6)  # none is lost
    (stretch,) = summary.health.degraded_stretches
    assert summary.health.lost_stretches == () and stretch.last_scan == summary.scans - 1
    assert summary.health.degraded_m == stretch.length_m > 5.0
    printed = capsys.readouterr().out
    assert printed.count(f"warning: health: degraded on 1 stretch ({stretch.length_m:.1f} m") == 1
    assert "warning: health: lost" not in printed


def test_the_batch_report_has_a_health_column(tmp_path):
    healthy = example_summary(health=HealthSummary(80, 0, 0, 1.0, 0.0))
    degraded = example_summary(health=HealthSummary(74, 6, 0, 0.925, 0.0))
    rows = [
        bag_row(name=name, bag=Path(f"/b/{name}.bag"), status="done", batch_dir=tmp_path, summary=summary)
        for name, summary in (("a", healthy), ("b", degraded), ("c", example_summary(health=None)))
    ]
    assert [(r["health"], r["health_ok_percent"], r["lost_m"]) for r in rows] == [
        ("ok", 100.0, 0.0),
        ("degraded", 92.5, 0.0),
        (None, None, None),
    ]
    paths = write_report(tmp_path, rows, {"out_dir": str(tmp_path)})
    page = paths.html.read_text()
    assert '<button type="button">health</button>' in page
    assert 'data-value="100.0">ok 100 %</td>' in page and "degraded: ok 92 %" in page
    assert paths.csv.read_text().splitlines()[2].count(",degraded,92.5,0.0,") == 1


# -- eval/health_check.py ------------------------------------------------------------------------------


def test_local_drift_is_the_error_of_the_segment_ending_at_each_scan():
    truth = np.tile(np.eye(4), (40, 1, 1))
    truth[:, 0, 3] = np.arange(40.0)  # 1 m per scan along x
    estimate = truth.copy()
    estimate[20:, 0, 3] = 19.0 + 1.05 * (np.arange(20, 40) - 19.0)  # 5 % too long from scan 20 on
    estimate[:, :3, 3] += [5.0, -3.0, 1.0]  # another world frame: aligned away per segment
    errors = local_drift_errors(estimate, truth, 10.0)
    assert np.isnan(errors[:10]).all() and errors[10:20] == pytest.approx(0.0, abs=1e-12)
    assert errors[25] == pytest.approx(0.3) and errors[29:] == pytest.approx(0.5)


def _synthetic_run(folder: Path, truth: Trajectory, estimate: Trajectory, health: list[ScanHealth]) -> None:
    n = len(health)

    def write(staging: Path) -> None:
        write_tum(staging / "trajectory_tum.txt", estimate)
        write_health_csv(staging / "health.csv", range(n), health)

    summary = example_summary(scans=n, keyframes=0, map_points=0, loop_candidates=0)
    publish_set(folder, summary, write, rows={"trajectory_tum.txt": n, "health.csv": n})


def test_health_check_scores_recall_and_false_flags(tmp_path, capsys):
    stamps = np.arange(40, dtype=np.int64) * S // 10 + 1_700_000_000 * S
    truth_poses = np.tile(np.eye(4), (40, 1, 1))
    truth_poses[:, 0, 3] = np.arange(40.0)
    estimate_poses = truth_poses.copy()
    estimate_poses[20:, 0, 3] = 19.0 + 1.04 * (np.arange(20, 40) - 19.0)  # bad from scan 27 (0.32 m)
    truth, estimate = Trajectory(stamps, truth_poses), Trajectory(stamps, estimate_poses)
    # Flagged from scan 18 (two good scans flagged early) to 37 (two bad scans missed at the end).
    health = [dataclasses.replace(h, stamp_ns=int(t)) for h, t in zip(_health_with("o" * 18 + "d" * 20 + "oo"), stamps)]
    _synthetic_run(tmp_path / "run", truth, estimate, health)
    write_tum(tmp_path / "truth.txt", truth)
    report = check_health(tmp_path / "run", tmp_path / "truth.txt")
    assert (report["scans"], report["scored"], report["bad"], report["good"]) == (40, 30, 13, 17)
    assert report["recall"] == pytest.approx(11 / 13, abs=1e-4) and report["bad_flagged"] == 11
    assert report["false_flag_rate"] == pytest.approx(9 / 17, abs=1e-4) and report["good_flagged"] == 9
    assert not report["recall_met"] and not report["false_flag_met"]
    assert report["flags"] == {"ok": 20, "degraded": 20, "lost": 0}
    assert (
        health_check_main([str(tmp_path / "run"), str(tmp_path / "truth.txt"), "--json", str(tmp_path / "h.json")]) == 2
    )
    printed = capsys.readouterr().out
    assert "recall 84.6 % (11 of 13 flagged; target >= 90 %: NOT met)" in printed
    assert json.loads((tmp_path / "h.json").read_text())["bad"] == 13
    assert health_check_main([str(tmp_path / "missing"), str(tmp_path / "truth.txt")]) == 1
    assert "error:" in capsys.readouterr().err


def test_health_check_on_a_simulated_run_meets_the_targets(simulated, default_run):
    out, _ = default_run
    report = check_health(out, simulated.ground_truth.parent, segment_m=5.0)
    assert report["scored"] > 0 and report["bad"] == 0 and report["false_flag_rate"] == 0.0
    assert report["recall"] is None and report["recall_met"] and report["false_flag_met"]


def test_the_batch_line_of_a_bag_with_lost_stretches_says_so():
    from lidar3d.batch import JobResult, JobStatus
    from lidar3d.batch.progress import BatchProgress, ProgressDisplay

    progress = BatchProgress({"a": 100})
    progress.started("a")
    progress.finished_job(JobResult("a", JobStatus.DONE, summary=example_summary(scans=55, health=_lost_summary(1))))
    stream = io.StringIO()
    display = ProgressDisplay(progress, stream)
    display.finished(progress.results["a"])
    display.close()
    assert "a: 55 scans, " in stream.getvalue() and "; health: lost over 12.5 m" in stream.getvalue()


def test_the_suite_tables_hold_the_health_check():
    from suite_report import render_markdown

    header = SUITE_HEADER
    row = {
        "scenario": "blind_turn",
        "seed": 0,
        "method": "lidar3d",
        "status": "ok",
        "case": {"path_length_m": 422.0, "n_scans": 700, "revisit_events": 0},
        "run": {"scans": 700, "wall_s": 150.0, "scans_per_s": 4.6, "health": {"lost_m": 199.6}},
        "scores": {},
        "peak_rss_mib": 500.0,
        "health": {
            "flags": {"ok": 328, "degraded": 14, "lost": 358},
            "bad": 364,
            "scored": 672,
            "recall": 1.0,
            "false_flag_rate": 0.0262,
        },
    }
    markdown = render_markdown([row], header)
    assert "## lidar3d health signal against ground truth" in markdown
    assert "| blind_turn | 328 / 14 / 358 | 199.6 | 364 of 672 | 100.0 % | 2.6 % |" in markdown
    no_check = render_markdown([{**row, "health": None}], header)
    assert "health signal" not in no_check
