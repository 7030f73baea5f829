"""Range image, ground and clustering: synthetic unit cases and simulated evidence scans."""

from __future__ import annotations

import dataclasses
import logging

import numpy as np
import pytest
from frontend_sim import cell_truth, sample_scans

from lidar3d.config import Config, SegmentationConfig, SensorConfig
from lidar3d.errors import ConfigError
from lidar3d.features import run_front_end
from lidar3d.records import Scan
from lidar3d.segmentation import (
    R_base_lidar_from_mount,
    RangeImage,
    cluster_cells,
    ground_row_count,
    mark_ground,
    project_scan,
    segment_scan,
)
from lidar3d.sim import ObjectClass

CONFIG = Config()


@pytest.fixture(scope="module")
def scene():
    sim_scan = sample_scans("loop")[2]
    return sim_scan, segment_scan(sim_scan.scan, CONFIG.segmentation, CONFIG.sensor)


def _scan(points, ring=None):
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    n = len(points)
    ring = np.zeros(n) if ring is None else ring
    return Scan(stamp_ns=5, points=points, intensity=np.zeros(n), ring=ring, time_offset_s=np.zeros(n))


def test_projection_columns_follow_rep105_azimuth():
    # forward (+x) is the middle column, left (+y) three quarters, right (-y) one quarter, back the seam
    scan = _scan([[10, 0, 0], [0, 10, 0], [0, -10, 0], [-10, 0.001, 0], [-10, -0.001, 0]], ring=[8, 8, 8, 8, 8])
    image = project_scan(scan, CONFIG.sensor, CONFIG.segmentation)
    rows, _ = np.nonzero(image.occupied)
    assert set(rows) == {8}
    assert image.point_index[8, 900] == 0
    assert image.point_index[8, 1350] == 1
    assert image.point_index[8, 450] == 2
    assert image.point_index[8, 0] in (3, 4) and image.point_index[8, 1799] == -1  # both round to the seam
    assert image.range_m[8, 900] == pytest.approx(10.0)
    assert np.isnan(image.range_m[0, 0])
    np.testing.assert_array_equal(image.points[8, 1350], [0, 10, 0])


def test_projection_rows_from_ring_match_rows_from_elevation(scene):
    sim_scan, _ = scene
    scan = sim_scan.scan
    by_ring = project_scan(scan, CONFIG.sensor, CONFIG.segmentation)
    by_elevation = project_scan(scan, CONFIG.sensor, dataclasses.replace(CONFIG.segmentation, use_ring_field=False))
    occupied = by_ring.occupied
    np.testing.assert_array_equal(scan.ring[by_ring.point_index[occupied]], np.nonzero(occupied)[0])
    # the simulator fires exactly along the beam table: both ways give the same rows
    np.testing.assert_array_equal(by_elevation.occupied, occupied)


def test_projection_drops_points_out_of_range_and_off_table(caplog):
    points = [[0.5, 0, 0], [150.0, 0, 0], [np.nan, 0, 0], [10, 0, -0.0873], [10, 0, 10]]  # last: 45 deg up
    scan = _scan(points, ring=[7, 7, 7, 7, 99])  # ring 99 does not exist: rows from elevation instead
    with caplog.at_level(logging.WARNING):
        image = project_scan(scan, CONFIG.sensor, CONFIG.segmentation)
    assert "rows taken from elevation" in caplog.text
    assert sorted(image.point_index[image.occupied].tolist()) == [3]
    assert image.point_index[7, 900] == 3  # -0.5 deg: nearest beam is ring 7 (-1 deg)


def test_ground_rows_default_to_the_beams_below_the_horizon():
    from lidar3d.sensors import HDL32E, VLP16, VLP32C

    counts = [ground_row_count(SegmentationConfig(), s.elevation_rad) for s in (VLP16, HDL32E, VLP32C)]
    assert counts == [8, 23, 20]  # VLP-16: rows 0..7, LeGO-LOAM's groundScanInd = 7
    assert ground_row_count(SegmentationConfig(ground_rows=5), VLP16.elevation_rad) == 5


def _ground_scores(scenario, segmentation_config=CONFIG.segmentation):
    """Pooled ground precision and recall over the rows the ground test looks at."""
    hits = marked = truth_total = 0
    for sim_scan in sample_scans(scenario):
        segmentation = segment_scan(sim_scan.scan, segmentation_config, CONFIG.sensor)
        image = segmentation.image
        visible = image.occupied.copy()
        visible[ground_row_count(segmentation_config, image.row_elevation_rad) :] = False
        truth = (cell_truth(sim_scan, image) == 0) & visible
        mask = segmentation.ground_mask & visible
        hits += int((mask & truth).sum())
        marked += int(mask.sum())
        truth_total += int(truth.sum())
    return hits / marked, hits / truth_total


@pytest.mark.parametrize("scenario", ["loop", "hilly"])
def test_ground_precision_and_recall_on_simulated_scans(scenario):
    precision, recall = _ground_scores(scenario)
    assert precision >= 0.98 and recall >= 0.95, (precision, recall)


def test_lego_loam_ground_test_alone_is_available_and_less_precise():
    lego_loam = dataclasses.replace(CONFIG.segmentation, ground_continuity=False)
    precision, recall = _ground_scores("loop", lego_loam)
    assert recall >= 0.98 and precision < 0.95  # walls' feet and car roofs pass the pairwise test


@pytest.mark.parametrize("pitch_deg, roll_deg", [(12.0, 0.0), (0.0, -12.0), (8.0, 8.0)])
def test_mount_pitch_and_roll_are_undone_before_the_ground_test(scene, pitch_deg, roll_deg):
    sim_scan, segmentation = scene
    R_base_lidar = R_base_lidar_from_mount(roll_deg, pitch_deg)
    tilted = dataclasses.replace(sim_scan.scan, points=sim_scan.scan.points @ R_base_lidar)  # p_lidar = R^T p_base
    tilted_sensor = dataclasses.replace(CONFIG.sensor, mount_pitch_deg=pitch_deg, mount_roll_deg=roll_deg)
    naive = segment_scan(tilted, CONFIG.segmentation, CONFIG.sensor)
    compensated = segment_scan(tilted, CONFIG.segmentation, tilted_sensor)
    reference = segmentation.ground_mask.sum()
    # (tilting moves points between cells, so the counts differ slightly)
    assert abs(int(compensated.ground_mask.sum()) - int(reference)) <= 0.03 * reference
    assert naive.ground_mask.sum() < 0.85 * reference


def test_positive_pitch_means_nose_down():
    # ground ahead, seen from a nose-down lidar, rises in the lidar frame
    R = R_base_lidar_from_mount(0.0, 10.0)
    forward_in_lidar = R.T @ np.array([1.0, 0.0, 0.0])
    assert forward_in_lidar[2] > 0


def _object_shares(segmentation_config, scenario="loop"):
    """Per object class: the share of each object's cells outside the coarse ground (the cells the
    clustering sees) in its largest kept cluster;
    and the fraction of clusters whose cells come from one object (>= 95 %)."""
    shares: dict[int, list[float]] = {}
    pure = clusters = 0
    for sim_scan in sample_scans(scenario):
        segmentation = segment_scan(sim_scan.scan, segmentation_config, CONFIG.sensor)
        truth = cell_truth(sim_scan, segmentation.image)
        truth[segmentation.coarse_ground_mask] = -1
        for object_id in np.unique(truth[truth > 0]):
            cells = truth == object_id
            if cells.sum() < 30:  # big enough: 30 cells, LeGO-LOAM's always-valid cluster size
                continue
            labels, counts = np.unique(segmentation.cluster_label[cells], return_counts=True)
            share = counts[labels >= 0].max() / cells.sum() if (labels >= 0).any() else 0.0
            object_class = int(sim_scan.object_class[sim_scan.object_id == object_id][0])
            shares.setdefault(object_class, []).append(share)
        for label in range(segmentation.n_clusters):
            ids = truth[segmentation.cluster_label == label]
            ids = ids[ids >= 0]
            clusters += 1
            pure += np.bincount(ids).max() >= 0.95 * ids.size
    return shares, pure / clusters


def test_clusters_with_the_default_angle_are_pure():
    shares, purity = _object_shares(CONFIG.segmentation)
    assert purity >= 0.97
    # poles stay whole (most of a pole in one cluster); beta > 60 deg cuts surfaces seen at grazing
    # incidence (building walls, car sides, tree canopies) into column strips, see the README
    assert np.median(shares[int(ObjectClass.POLE)]) >= 0.9


def test_each_object_is_one_cluster_with_a_10_degree_angle():
    # Bogoslavskyi & Stachniss's own threshold (10 deg) keeps compact objects whole
    shares, purity = _object_shares(dataclasses.replace(CONFIG.segmentation, cluster_angle_deg=10.0))
    for object_class in (ObjectClass.POLE, ObjectClass.TREE, ObjectClass.CAR):
        assert np.mean(np.asarray(shares[int(object_class)]) >= 0.9) >= 0.8, object_class.name
    assert purity >= 0.7  # touching buildings and trees in front of facades merge


def test_isolated_noise_is_rejected(scene):
    sim_scan, _ = scene
    scan = sim_scan.scan
    image = project_scan(scan, CONFIG.sensor, CONFIG.segmentation)
    row = 14  # +13 deg: mostly sky
    sky = np.flatnonzero(~image.occupied[row - 1 : row + 2].any(axis=0))
    rng = np.random.default_rng(0)
    columns = rng.choice(sky[(sky > 10) & (sky < 1790)], 20, replace=False)
    azimuth = (columns - 900) * np.deg2rad(0.2)
    elevation = np.deg2rad(13.0)
    range_m = rng.uniform(15.0, 40.0, 20)
    noise = np.stack([np.cos(azimuth), np.sin(azimuth), np.full(20, np.tan(elevation))], axis=1)
    noise *= (range_m * np.cos(elevation))[:, None]
    noisy = Scan(
        stamp_ns=scan.stamp_ns,
        points=np.concatenate([scan.points, noise]),
        intensity=np.concatenate([scan.intensity, np.zeros(20)]),
        ring=np.concatenate([scan.ring, np.full(20, row)]),
        time_offset_s=np.concatenate([scan.time_offset_s, np.zeros(20)]),
    )
    segmentation = segment_scan(noisy, CONFIG.segmentation, CONFIG.sensor)
    cells = (np.full(20, row), columns)
    np.testing.assert_array_equal(segmentation.image.point_index[cells], np.arange(len(scan), len(scan) + 20))
    assert segmentation.outlier_mask[cells].all()
    assert (segmentation.cluster_label[cells] == -1).all()


def _image(range_m: np.ndarray, elevation_deg=None) -> RangeImage:
    rows, columns = range_m.shape
    elevation = np.deg2rad(np.arange(rows) * 2.0 - 15.0 if elevation_deg is None else elevation_deg)
    return RangeImage(
        range_m=range_m,
        point_index=np.where(np.isnan(range_m), -1, np.arange(range_m.size).reshape(range_m.shape)),
        points=np.zeros(range_m.shape + (3,)),
        row_elevation_rad=elevation,
        azimuth_resolution_rad=np.deg2rad(360.0 / columns),
    )


def test_clusters_wrap_around_the_seam():
    range_m = np.full((16, 1800), np.nan)
    range_m[9:14, [1797, 1798, 1799, 0, 1, 2]] = 8.0  # 30 cells across the seam
    label, outlier = cluster_cells(_image(range_m), np.zeros((16, 1800), dtype=bool), SegmentationConfig())
    assert set(label[~np.isnan(range_m)].tolist()) == {0}
    assert not outlier.any()


@pytest.mark.parametrize(
    "rows, columns, kept",
    [
        (1, 30, True),  # >= 30 points
        (1, 29, False),
        (3, 2, True),  # 6 points on 3 rows
        (2, 10, False),  # 20 points on 2 rows
        (5, 1, True),  # 5 points on 5 rows
        (4, 1, False),  # 4 points on 4 rows
    ],
)
def test_cluster_validity_rule(rows, columns, kept):
    range_m = np.full((16, 1800), np.nan)
    range_m[10 : 10 + rows, 100 : 100 + columns] = 8.0
    label, outlier = cluster_cells(_image(range_m), np.zeros((16, 1800), dtype=bool), SegmentationConfig())
    cells = ~np.isnan(range_m)
    assert np.all(label[cells] >= 0) == kept
    assert np.all(outlier[cells]) == (not kept)


def test_depth_step_splits_clusters_but_vertical_alpha_uses_the_elevation_table():
    range_m = np.full((16, 1800), np.nan)
    range_m[10:13, 100:120] = 8.0
    range_m[10:13, 120:140] = 20.0  # a depth jump: beta ~ 0
    label, _ = cluster_cells(_image(range_m), np.zeros((16, 1800), dtype=bool), SegmentationConfig())
    assert label[10, 100] != label[10, 139] and label[10, 100] >= 0 and label[10, 139] >= 0
    # rows 10 and 11 only 0.1 deg apart with a 0.5 m range step: beta small, not joined
    rng = np.full((16, 1800), np.nan)
    rng[10, 100:140] = 8.0
    rng[11, 100:140] = 8.5
    elevation = np.arange(16) * 2.0 - 15.0
    elevation[11] = elevation[10] + 0.1
    label, _ = cluster_cells(_image(rng, elevation), np.zeros((16, 1800), dtype=bool), SegmentationConfig())
    assert label[10, 100] != label[11, 100]


def test_segmented_cloud_layout(scene):
    sim_scan, segmentation = scene
    n_columns = segmentation.image.shape[1]
    flat = segmentation.row * n_columns + segmentation.column
    assert np.all(np.diff(flat) > 0)  # row-major, one point per cell
    for r in range(16):
        block = slice(segmentation.ring_start[r], segmentation.ring_end[r])
        assert np.all(segmentation.row[block] == r)
    assert segmentation.ring_end[-1] == len(segmentation)
    ground_columns = segmentation.column[segmentation.is_coarse_ground]
    assert np.all((ground_columns % 5 == 0) | (ground_columns <= 5) | (ground_columns >= n_columns - 5))
    assert np.all(
        ~segmentation.is_coarse_ground | segmentation.coarse_ground_mask[segmentation.row, segmentation.column]
    )
    kept = segmentation.cluster_label[segmentation.row, segmentation.column] >= 0
    np.testing.assert_array_equal(kept | segmentation.is_coarse_ground, True)
    np.testing.assert_allclose(segmentation.points, sim_scan.scan.points[segmentation.scan_index])
    np.testing.assert_allclose(segmentation.range_m, np.linalg.norm(segmentation.points, axis=1))
    # the outlier cloud: rejected cells above the ground rows, every 5th column
    image = segmentation.image
    rows = segmentation.outlier_row
    assert rows.size > 0 and np.all(rows >= 8)
    cells = segmentation.outlier_mask & (np.arange(n_columns) % 5 == 0)[None, :]
    cells[:8] = False
    np.testing.assert_array_equal(np.sort(segmentation.outlier_scan_index), np.sort(image.point_index[cells]))


def test_cluster_angle_must_be_below_90():
    image = _image(np.full((16, 1800), np.nan))
    with pytest.raises(ConfigError, match=r"segmentation\.cluster_angle_deg: must be in \(0, 90\)"):
        cluster_cells(image, np.zeros((16, 1800), dtype=bool), SegmentationConfig(cluster_angle_deg=90.0))


@pytest.mark.parametrize(
    "points, ring, reason",
    [
        (np.zeros((0, 3)), np.zeros(0), "it has no points"),
        ([[10.0, float(k), -1.0] for k in range(50)], np.full(50, 3), "its points lie on a single ring"),
        ([[0.1, 0.0, 0.0], [0.2, 0.1, 0.0], [500.0, 0.0, 0.0]], [1, 2, 3], "no point lies within the sensor's range"),
    ],
    ids=["empty", "single-ring", "out-of-range"],
)
def test_unusable_scans_give_empty_results_and_a_warning(points, ring, reason, caplog):
    scan = _scan(points, ring=ring)
    with caplog.at_level(logging.WARNING, logger="lidar3d"):
        result = run_front_end(scan, CONFIG)
    assert reason in caplog.text
    assert result.features.is_empty and len(result.features.outliers) == 0
    assert len(result.segmentation) == 0 and result.segmentation.n_clusters == 0
    assert result.features.stamp_ns == 5


def test_sensor_config_min_range_applies():
    scan = _scan([[1.5, 0, 0], [3.0, 0.1, 0]], ring=[8, 8])
    image = project_scan(scan, SensorConfig(min_range_m=2.0), CONFIG.segmentation)
    assert image.point_index[image.occupied].tolist() == [1]


def test_ground_angles_are_validated():
    image = _image(np.full((16, 1800), np.nan))
    with pytest.raises(ConfigError, match=r"segmentation\.ground_max_angle_change_deg: must be in \(0, 90\)"):
        mark_ground(image, SegmentationConfig(ground_max_angle_change_deg=0.0), SensorConfig())
    with pytest.raises(ConfigError, match=r"segmentation\.ground_angle_threshold_deg"):
        mark_ground(image, SegmentationConfig(ground_angle_threshold_deg=90.0), SensorConfig())
