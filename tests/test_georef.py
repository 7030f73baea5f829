"""Georeference (georef.json), output CRSs and grid axes, GNSS factor gating and fusion, on synthetic data.

The CLI end to end (run --span, export, --gnss-factors) is in ``test_georef_cli.py``.
"""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar3d.config import GeorefConfig
from lidar3d.errors import GeoreferenceError
from lidar3d.georef import (
    CrsKind,
    GnssFusionRecord,
    enu_to_crs_points,
    enu_to_crs_poses,
    fit_georeference,
    read_georeference,
    resolve_crs,
    utm_epsg,
)
from lidar3d.georef.gnss_factors import fuse_gnss, select_gnss_factors
from lidar3d.gnss.enu import GeodeticOrigin
from lidar3d.gnss.reference import InsReference
from lidar3d.loop.pose_graph import fuse_positions
from lidar3d.records import Trajectory

ORIGIN = GeodeticOrigin(49.01135, 8.4165, 163.0)


def _pose(R: np.ndarray, t) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _drive(n: int = 200, radius_m: float = 40.0, dt_s: float = 0.5) -> Trajectory:
    """A lidar driving a quarter circle and a straight, gently climbing (world = ENU here)."""
    s = np.linspace(0.0, 1.0, n)
    angle = np.minimum(s * 2.0, 1.0) * np.pi / 2
    straight = np.maximum(s * 2.0 - 1.0, 0.0) * 60.0
    x = radius_m * np.sin(angle) + straight * np.cos(np.pi / 2)
    y = radius_m * (1 - np.cos(angle)) + straight
    z = 0.02 * np.arange(n)
    poses = np.array(
        [_pose(Rotation.from_euler("z", a).as_matrix(), (xi, yi, zi)) for a, xi, yi, zi in zip(angle, x, y, z)]
    )
    stamps = 1_700_000_000_000_000_000 + (np.arange(n) * dt_s * 1e9).astype(np.int64)
    return Trajectory(stamps, poses)


def _reference(truth_enu: Trajectory, std_m: float = 0.02) -> InsReference:
    n = len(truth_enu)
    return InsReference(
        stamps_ns=truth_enu.stamps_ns,
        T_enu_imu=truth_enu.T_world_lidar,
        origin=ORIGIN,
        ins_status=np.full(n, 3),
        position_type=np.full(n, 56),
        std_enu_m=np.full((n, 3), std_m),
        source_log="INSPVAX",
        n_solutions=n,
    )


def _T_enu_world() -> np.ndarray:
    """A tilted, turned and shifted SLAM frame (a lidar mounted 1.5 deg off level)."""
    return _pose(Rotation.from_euler("xyz", [1.5, -0.8, 37.0], degrees=True).as_matrix(), (12.0, -5.0, 1.2))


# -- CRS and grid axes ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("lat", "lon", "epsg"),
    [(49.0, 8.4, 32632), (-33.9, 151.2, 32756), (60.4, 5.3, 32632), (78.0, 15.0, 32633), (0.5, -179.9, 32601)],
)
def test_utm_zone_of_a_point_with_the_grid_exceptions(lat, lon, epsg):
    assert utm_epsg(lat, lon) == epsg


def test_projected_points_match_an_independent_conversion():
    """ENU -> UTM through LocalEnu + pyproj equals the simulator's PROJ topocentric pipeline + pyproj."""
    from pyproj import Transformer

    from lidar3d.sim.span import GeoOrigin, enu_to_geodetic

    p = np.array([[0.0, 0.0, 0.0], [250.0, -120.0, 4.0], [-380.0, 410.0, -2.5]])
    crs = resolve_crs("utm", ORIGIN, for_map=True)
    assert crs.name == "EPSG:32632" and crs.kind is CrsKind.PROJECTED
    lat, lon, h = enu_to_geodetic(p, GeoOrigin(ORIGIN.latitude_deg, ORIGIN.longitude_deg, ORIGIN.height_ellipsoid_m))
    e, n = Transformer.from_crs("EPSG:4326", "EPSG:32632", always_xy=True).transform(lon, lat)
    np.testing.assert_allclose(enu_to_crs_points(p, ORIGIN, crs), np.column_stack([e, n, h]), atol=1e-6)
    back = enu_to_crs_points(p, ORIGIN, resolve_crs("wgs84", ORIGIN, for_map=False))
    np.testing.assert_allclose(back, np.column_stack([lat, lon, h]), atol=1e-9)


def test_grid_axes_apply_the_meridian_convergence():
    """A lidar looking true north looks grid north + gamma: checked by projecting a step along its x axis."""
    crs = resolve_crs("utm", ORIGIN, for_map=True)
    R_north = Rotation.from_euler("z", 90.0, degrees=True).as_matrix()  # x axis -> ENU north
    T = np.array([_pose(R_north, (0.0, 0.0, 0.0)), _pose(R_north, (0.0, 0.0, 0.0))])
    T[1, :3, 3] = R_north[:, 0] * 1.0  # one metre along the x axis
    poses = enu_to_crs_poses(T, ORIGIN, crs)
    step = poses.positions[1] - poses.positions[0]
    x_axis = poses.R_grid_lidar[0][:, 0]
    assert poses.convergence_deg[0] == pytest.approx(-0.44, abs=0.01)  # west of the 9 deg E central meridian
    assert np.degrees(np.arctan2(x_axis[0], x_axis[1])) == pytest.approx(0.44, abs=0.01)
    np.testing.assert_allclose(x_axis[:2], step[:2] / np.linalg.norm(step[:2]), atol=2e-6)
    assert poses.scale_factor[0] == pytest.approx(0.99962, abs=1e-5)


@pytest.mark.parametrize(
    ("spec", "for_map", "message"),
    [
        ("EPSG:99999", True, r"EPSG:99999: unknown EPSG code"),
        ("EPSG:4326", True, r"geographic CRS; a map needs a projected CRS"),
        ("EPSG:4326", False, r"geographic CRS; use --crs wgs84"),
        ("wgs84", True, r"a geographic CRS cannot hold a map"),
        ("EPSG:5773", True, r"not a plain projected CRS"),
        ("mercator", False, r"unknown CRS \(choose utm, EPSG:NNNN, enu or wgs84\)"),
    ],
)
def test_unusable_crs_are_refused_in_one_line(spec, for_map, message):
    with pytest.raises(GeoreferenceError, match=message) as info:
        resolve_crs(spec, ORIGIN, for_map=for_map)
    assert "\n" not in str(info.value)


def test_any_projected_epsg_code_is_accepted():
    crs = resolve_crs("epsg:25832", ORIGIN, for_map=True)
    assert crs.epsg == 25832 and "ETRS89" in crs.wkt and crs.wkt.startswith("PROJCS")


# -- the fit ------------------------------------------------------------------------------------


@pytest.mark.parametrize("method", ["yaw", "se3"])
def test_fit_recovers_a_tilted_slam_frame(method):
    truth = _drive()
    T_enu_world = _T_enu_world()
    estimate = Trajectory(truth.stamps_ns, np.linalg.inv(T_enu_world) @ truth.T_world_lidar)
    georef = fit_georeference(estimate, _reference(truth), method=method)
    np.testing.assert_allclose(georef.T_enu_world, T_enu_world, atol=1e-7)
    assert georef.method == method and georef.residual.rmse_m < 1e-6
    assert georef.epochs_used == len(truth) and georef.epochs_rejected == 0


def test_yaw_fit_levels_from_attitude_on_a_straight_drive_where_se3_falls_back():
    truth = _drive()
    straight = Trajectory(truth.stamps_ns[150:], truth.T_world_lidar[150:])
    estimate = Trajectory(straight.stamps_ns, np.linalg.inv(_T_enu_world()) @ straight.T_world_lidar)
    georef = fit_georeference(estimate, _reference(straight), method="se3")
    assert georef.method == "yaw" and "ill-conditioned" in georef.note
    np.testing.assert_allclose(georef.T_enu_world, _T_enu_world(), atol=1e-7)


def test_fit_drops_a_position_jump():
    truth = _drive()
    reference_poses = truth.T_world_lidar.copy()
    reference_poses[100:110, 0, 3] += 50.0
    reference = _reference(Trajectory(truth.stamps_ns, reference_poses))
    estimate = Trajectory(truth.stamps_ns, np.linalg.inv(_T_enu_world()) @ truth.T_world_lidar)
    georef = fit_georeference(estimate, reference)
    assert georef.epochs_rejected == 10
    np.testing.assert_allclose(georef.T_enu_world, _T_enu_world(), atol=1e-7)


def test_fit_needs_overlap():
    truth = _drive()
    late = Trajectory(truth.stamps_ns + 10**12, truth.T_world_lidar)
    with pytest.raises(GeoreferenceError, match=r"no georeference"):
        fit_georeference(late, _reference(truth))


def test_georef_json_round_trip(tmp_path):
    truth = _drive()
    georef = fit_georeference(truth, _reference(truth), span_source="span.log", span_sha256="ab" * 32)
    fusion = GnssFusionRecord("span.log", "ab" * 32, truth.stamps_ns[::10], 200, 1, 2, 3, 1.0)
    import dataclasses

    georef = dataclasses.replace(georef, fusion=fusion)
    path = tmp_path / "georef.json"
    path.write_text(georef.to_json())
    back = read_georeference(path)
    assert back.to_dict() == georef.to_dict()
    assert json.loads(path.read_text())["origin"]["datum"] == "WGS84"


def test_georef_json_errors(tmp_path):
    with pytest.raises(GeoreferenceError, match=r"no georef\.json: a georeference needs a SPAN log"):
        read_georeference(tmp_path / "georef.json")
    (tmp_path / "georef.json").write_text('{"format": "other"}')
    with pytest.raises(GeoreferenceError, match=r"georef\.json: not a lidar3d georeference"):
        read_georeference(tmp_path / "georef.json")


# -- GNSS factors -------------------------------------------------------------------------------


def _drifted(truth: Trajectory, scale: float = 0.97) -> Trajectory:
    """The truth with a 3 % along-track scale drift (a lidar in a featureless canyon)."""
    poses = truth.T_world_lidar.copy()
    poses[:, :3, 3] *= scale
    return Trajectory(truth.stamps_ns, poses)


def test_gate_rejects_a_50_m_jump_and_keeps_the_rest():
    truth = _drive()
    poses = truth.T_world_lidar.copy()
    poses[120:126, 0, 3] += 50.0
    selection = select_gnss_factors(
        truth, _reference(Trajectory(truth.stamps_ns, poses)), np.eye(4), np.eye(4), GeorefConfig(factor_spacing_m=0.0)
    )
    assert selection.rejected_consistency == 6
    assert not set(range(120, 126)) & set(selection.keyframe_index.tolist())
    assert len(selection) == len(truth) - 6
    assert all("jumped 50.00 m away from the odometry" in line for line in selection.rejections)


def test_gate_status_quality_spacing_and_hold_out():
    truth = _drive()
    reference = _reference(truth)
    std = reference.std_enu_m.copy()
    std[:20] = 3.0  # single-point quality
    import dataclasses

    reference = dataclasses.replace(reference, std_enu_m=std)
    config = GeorefConfig(factor_spacing_m=0.0, hold_out_period_s=1.0)
    selection = select_gnss_factors(truth, reference, np.eye(4), np.eye(4), config)
    assert selection.rejected_quality == 20
    held = (truth.stamps_ns[selection.keyframe_index] // 1_000_000_000) % 2 == 1
    assert not held.any() and selection.rejected_hold_out > 0
    spaced = select_gnss_factors(truth, _reference(truth), np.eye(4), np.eye(4), GeorefConfig(factor_spacing_m=5.0))
    assert np.diff(truth.positions_m[spaced.keyframe_index], axis=0).__abs__().sum(axis=1).min() > 4.9


def test_gate_trusts_the_gnss_over_a_drifting_lidar_and_after_an_outage_but_not_in_a_lasting_jump():
    truth = _drive()
    fast_drift = _drifted(truth, 0.8)  # 20 % short: the lidar in a featureless canyon
    steady = select_gnss_factors(
        fast_drift, _reference(truth), np.eye(4), np.eye(4), GeorefConfig(factor_spacing_m=0.0)
    )
    assert steady.rejected_consistency == 0 and len(steady) == len(truth)
    drifted = _drifted(truth, 0.6)  # 40 % drift: more than the gate allows across a long outage
    keep = np.r_[0:60, 140:200]  # an outage of 80 epochs
    reference = _reference(Trajectory(truth.stamps_ns[keep], truth.T_world_lidar[keep]))
    selection = select_gnss_factors(drifted, reference, np.eye(4), np.eye(4), GeorefConfig(factor_spacing_m=0.0))
    assert selection.rejected_consistency == 0 and len(selection) == len(keep)
    poses = truth.T_world_lidar.copy()
    poses[100:, 1, 3] += 50.0  # a jump that lasts to the end
    lasting = select_gnss_factors(
        truth, _reference(Trajectory(truth.stamps_ns, poses)), np.eye(4), np.eye(4), GeorefConfig(factor_spacing_m=0.0)
    )
    assert lasting.rejected_consistency == 100 and lasting.keyframe_index.max() < 100


def test_fusion_pulls_a_drifted_trajectory_onto_the_gnss():
    truth = _drive()
    drifted = _drifted(truth)
    fusion = fuse_gnss(drifted, drifted, _reference(truth), np.eye(4), np.eye(4), GeorefConfig(factor_spacing_m=0.0))
    before = np.linalg.norm(drifted.positions_m - truth.positions_m, axis=1)
    after = np.linalg.norm(fusion.trajectory.positions_m - truth.positions_m, axis=1)
    assert before.max() > 2.0
    assert np.sqrt(np.mean(after**2)) < 0.1


def test_fuse_positions_refuses_too_few_measurements():
    with pytest.raises(ValueError, match=r"at least 3 measurements"):
        fuse_positions(np.tile(np.eye(4), (3, 1, 1)), np.full((2, 6), 0.1), [0, 1], np.zeros((2, 3)), np.ones((2, 3)))


def test_held_out_scoring_keeps_only_odd_periods():
    from lidar3d.metrics.span_eval import fusion_disclosure

    truth = _drive(n=40, dt_s=0.25)  # 10 s
    disclosure, scored = fusion_disclosure(truth, 12, 1.0)
    assert disclosure.held_out_only and disclosure.poses_total == 40
    assert ((scored.stamps_ns // 1_000_000_000) % 2 == 1).all() and len(scored) == 20
    assert "held-out epochs only (20 of 40 poses" in disclosure.line()
    everything, same = fusion_disclosure(truth, 12, 0.0)
    assert not everything.held_out_only and len(same) == 40 and "not independent" in everything.line()


def test_numpy_pcd_reader_equals_open3d_and_refuses_a_truncated_file(tmp_path):
    from lidar3d.errors import OutputError
    from lidar3d.io.pcd import read_pcd, read_pcd_fields, write_pcd

    rng = np.random.default_rng(3)
    points = rng.normal(size=(500, 3)) * 100.0
    write_pcd(tmp_path / "m.pcd", points, intensity=rng.uniform(0, 255, 500))
    a, fa = read_pcd(tmp_path / "m.pcd")
    b, fb = read_pcd_fields(tmp_path / "m.pcd")
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(fa["intensity"].reshape(-1), fb["intensity"])
    data = (tmp_path / "m.pcd").read_bytes()
    (tmp_path / "cut.pcd").write_bytes(data[:-100])
    with pytest.raises(OutputError, match=r"cut\.pcd: truncated point cloud \(493 of 500 points\)"):
        read_pcd_fields(tmp_path / "cut.pcd")
    write_pcd(tmp_path / "empty.pcd", np.zeros((0, 3)), intensity=np.zeros(0), label=np.zeros(0, np.int32))
    points, fields = read_pcd_fields(tmp_path / "empty.pcd")  # header only, DATA ascii: no Open3D needed
    assert points.shape == (0, 3) and points.dtype == np.float64
    assert fields["intensity"].dtype == np.float32 and fields["label"].dtype == np.int32
    assert len(fields["intensity"]) == len(fields["label"]) == 0
