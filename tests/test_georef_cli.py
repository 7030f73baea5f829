"""``lidar3d run --span`` (georef.json), ``lidar3d export`` and ``--gnss-factors`` end to end, in process.

One simulated folder (3 s of the ``loop`` scenario) per module; two runs on it: plain with ``--span``,
and fused with ``--gnss-factors`` against a copy of the log with an unflagged 50 m jump.
"""

import json

import numpy as np
import pytest

from lidar3d.cli.main import main
from lidar3d.io.trajectory_io import read_tum
from lidar3d.summary import read_summary

sim = pytest.importorskip("lidar3d.sim")
laspy = pytest.importorskip("laspy")


@pytest.fixture(scope="module")
def simulated(tmp_path_factory):
    return sim.simulate("loop", tmp_path_factory.mktemp("sim") / "loop", seed=0, duration_s=3.0)


def _run(*argv):
    return main(["-q", "run", *map(str, argv)])


@pytest.fixture(scope="module")
def georeferenced(simulated, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "plain"
    assert _run(simulated.bag, "--out", out, "--span", simulated.span_log, "--extrinsics", simulated.extrinsics) == 0
    return out


@pytest.fixture(scope="module")
def jump_log(simulated, tmp_path_factory):
    """The simulated log with INSPVAX/BESTPOS 50 m east of the truth for 0.5 s, still INS_SOLUTION_GOOD."""
    lines = simulated.span_log.read_bytes().decode("ascii").splitlines(keepends=True)
    first = float(next(line for line in lines if line.startswith("#INSPVAXA")).split(",")[6])
    path = tmp_path_factory.mktemp("log") / "jump.log"
    path.write_bytes("".join(sim.span.shift_positions(lines, first + 1.5, first + 2.0, 50.0, 0.0)).encode("ascii"))
    return path


@pytest.fixture(scope="module")
def fused(simulated, jump_log, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "fused"
    code = _run(simulated.bag, "--out", out, "--span", jump_log, "--extrinsics", simulated.extrinsics, "--gnss-factors")
    assert code == 0
    return out


def _export(run_dir, crs, out):
    return main(["-q", "export", str(run_dir), "--crs", crs, "--out", str(out)])


def _truth_in(crs_epsg: int, simulated):
    """The simulator's ground truth converted independently: its PROJ topocentric pipeline, then pyproj."""
    from pyproj import Transformer

    meta = json.loads(simulated.metadata.read_text())["origin"]
    origin = sim.span.GeoOrigin(meta["latitude_deg"], meta["longitude_deg"], meta["height_ellipsoid_m"])
    truth = read_tum(simulated.ground_truth)
    lat, lon, h = sim.span.enu_to_geodetic(truth.positions_m, origin)
    e, n = Transformer.from_crs("EPSG:4326", f"EPSG:{crs_epsg}", always_xy=True).transform(lon, lat)
    return truth.stamps_ns, np.column_stack([e, n, h])


def test_run_with_span_writes_a_georeference_in_its_manifest(georeferenced):
    georef = json.loads((georeferenced / "georef.json").read_text())
    assert georef["format"] == "lidar3d-georef/1" and georef["method"] == "yaw"
    assert georef["epochs_used"] >= 20 and georef["residual"]["rmse_m"] < 0.05
    assert georef["gnss_factors"] is None
    assert np.asarray(georef["T_enu_world"]).shape == (4, 4)
    summary = read_summary(georeferenced / "summary.json")
    assert summary.output("georef.json") is not None


def test_exported_utm_trajectory_matches_the_truth(georeferenced, simulated, tmp_path):
    assert _export(georeferenced, "utm", tmp_path / "t.tum") == 0
    rows = np.loadtxt(tmp_path / "t.tum", comments="#")
    stamps, truth = _truth_in(32632, simulated)
    exported = read_tum(georeferenced / "trajectory_tum.txt")  # the same stamps as the export
    assert len(rows) == len(exported)
    common = np.isin(stamps, exported.stamps_ns)
    error = rows[:, 1:4] - truth[common]
    assert np.sqrt(np.mean(np.sum(error[:, :2] ** 2, axis=1))) < 0.10
    assert np.sqrt(np.mean(error[:, 2] ** 2)) < 0.15


def test_exported_laz_has_the_crs_and_lies_on_the_route(georeferenced, simulated, tmp_path):
    from pyproj import CRS

    assert _export(georeferenced, "utm", tmp_path / "map.laz") == 0
    las = laspy.read(tmp_path / "map.laz")
    assert str(las.header.version) == "1.4" and las.header.global_encoding.wkt
    assert las.header.parse_crs().equals(CRS.from_epsg(32632), ignore_axis_order=True)
    assert len(las.x) == read_summary(georeferenced / "summary.json").map_points
    assert las.header.scales.tolist() == [0.001, 0.001, 0.001]
    # every point is "return 1 of 1" and the header counts them so (LAS 1.4 wants 1-15, not 0)
    assert np.all(las.return_number == 1) and np.all(las.number_of_returns == 1)
    assert las.header.number_of_points_by_return[0] == len(las.x)
    _, truth = _truth_in(32632, simulated)
    centre = np.array([np.median(las.x), np.median(las.y)])
    assert np.linalg.norm(centre - truth[:, :2].mean(axis=0)) < 60.0  # the points surround the route


@pytest.mark.parametrize("name", ["map.las", "map.pcd", "map.ply"])
def test_other_map_formats_keep_millimetres_at_utm_magnitudes(georeferenced, tmp_path, name):
    assert _export(georeferenced, "utm", tmp_path / "ref.laz") == 0
    assert _export(georeferenced, "utm", tmp_path / name) == 0
    reference = laspy.read(tmp_path / "ref.laz")
    xyz_ref = np.column_stack([reference.x, reference.y, reference.z])
    if name.endswith(".las"):
        other = laspy.read(tmp_path / name)
        xyz = np.column_stack([other.x, other.y, other.z])
    else:
        data = (tmp_path / name).read_bytes()
        marker = b"DATA binary\n" if name.endswith(".pcd") else b"end_header\n"
        body = data[data.index(marker) + len(marker) :]
        record = np.frombuffer(body, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("i", "<f4")])
        xyz = np.column_stack([record["x"], record["y"], record["z"]])
        assert b"EPSG:32632" in data[: data.index(marker)]
    np.testing.assert_allclose(xyz, xyz_ref, atol=0.0006)


def test_wgs84_csv_and_enu_outputs(georeferenced, simulated, tmp_path):
    assert _export(georeferenced, "wgs84", tmp_path / "t.csv") == 0
    header = (tmp_path / "t.csv").read_text().splitlines()[0].split(",")
    assert header[:4] == ["stamp_s", "latitude_deg", "longitude_deg", "height_ellipsoid_m"]
    rows = np.loadtxt(tmp_path / "t.csv", delimiter=",", skiprows=1)
    assert abs(rows[0, 1] - 49.0113) < 0.001 and abs(rows[0, 2] - 8.417) < 0.001
    assert _export(georeferenced, "enu", tmp_path / "t.tum") == 0
    enu = np.loadtxt(tmp_path / "t.tum", comments="#")
    assert np.linalg.norm(enu[0, 1:3]) < 1.0  # the ENU origin is the first good fix, near the start


@pytest.mark.parametrize(
    ("crs", "name", "message"),
    [
        ("EPSG:99999", "m.laz", r"EPSG:99999: unknown EPSG code"),
        ("EPSG:4326", "m.laz", r"geographic CRS; a map needs a projected CRS"),
        ("wgs84", "m.las", r"a geographic CRS cannot hold a map"),
        ("wgs84", "t.tum", r"TUM needs metric coordinates"),
        ("utm", "m.xyz", r"output extension '\.xyz' is not supported"),
    ],
)
def test_export_bad_input_is_one_line(georeferenced, tmp_path, capsys, crs, name, message):
    assert _export(georeferenced, crs, tmp_path / name) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert __import__("re").search(message, err), err
    assert not (tmp_path / name).exists()


def test_export_of_a_run_without_span_says_a_log_is_needed(simulated, tmp_path, capsys):
    out = tmp_path / "nospan"
    assert _run(simulated.bag, "--out", out, "--max-scans", 5) == 0
    assert _export(out, "utm", tmp_path / "m.laz") == 1
    assert "no georef.json: a georeference needs a SPAN log" in capsys.readouterr().err


def test_gnss_factors_reject_the_jump_and_disclose_the_fusion(fused, georeferenced, jump_log, simulated, capsys):
    georef = json.loads((fused / "georef.json").read_text())
    factors = georef["gnss_factors"]
    assert factors["fused_epochs"] >= 3 and factors["rejected_consistency"] >= 1
    summary = read_summary(fused / "summary.json")
    assert any("rejected as inconsistent" in w for w in summary.warnings)
    assert summary.output("trajectory_lidar_only_tum.txt") is not None
    report = json.loads((fused / "eval" / "report.json").read_text())
    assert "fused with this log" in report["fusion"]["note"]
    # fused poses never follow the jump: within 0.3 m of the truth at every pose
    truth = read_tum(simulated.ground_truth)
    fused_traj = read_tum(fused / "trajectory_tum.txt")
    lidar_only = read_tum(fused / "trajectory_lidar_only_tum.txt")
    assert len(fused_traj) == len(lidar_only)
    T = np.asarray(georef["T_enu_world"])
    meta = json.loads(simulated.metadata.read_text())["origin"]
    from lidar3d.gnss.enu import GeodeticOrigin, LocalEnu

    o = georef["origin"]
    lat, lon, h = LocalEnu(GeodeticOrigin(o["latitude_deg"], o["longitude_deg"], o["height_ellipsoid_m"])).to_geodetic(
        fused_traj.positions_m @ T[:3, :3].T + T[:3, 3]
    )
    p_sim = LocalEnu(GeodeticOrigin(meta["latitude_deg"], meta["longitude_deg"], meta["height_ellipsoid_m"])).to_enu(
        lat, lon, h
    )
    truth_at = truth.positions_m[np.isin(truth.stamps_ns, fused_traj.stamps_ns)]
    assert np.linalg.norm(p_sim - truth_at, axis=1).max() < 0.3
    # lidar3d eval on the fused trajectory against the same log says so; --held-out needs a hold-out
    eval_out = fused / "eval_again"
    argv = ["-q", "eval", str(fused / "trajectory_tum.txt"), "--span", str(jump_log), "--out", str(eval_out)]
    assert main([*argv, "--extrinsics", str(simulated.extrinsics)]) == 0
    assert "note: the trajectory was fused with this log" in capsys.readouterr().out
    assert main([*argv, "--held-out"]) == 1
    assert "fused every epoch" in capsys.readouterr().err
    # the plain run's trajectory was never fused: no note
    assert (
        main(
            [
                "-q",
                "eval",
                str(georeferenced / "trajectory_tum.txt"),
                "--span",
                str(jump_log),
                "--out",
                str(georeferenced / "e2"),
            ]
        )
        == 0
    )
    assert "fused with this log" not in capsys.readouterr().out


def test_gnss_factors_need_span(simulated, tmp_path, capsys):
    assert _run(simulated.bag, "--out", tmp_path / "x", "--gnss-factors") == 1
    assert "--gnss-factors needs --span" in capsys.readouterr().err
    assert _run(simulated.bag, "--out", tmp_path / "y", "--span", simulated.span_log, "--gnss-hold-out", "1") == 1
    assert "--gnss-hold-out needs --gnss-factors" in capsys.readouterr().err


def test_hold_out_fuses_even_seconds_and_scores_the_odd_ones(simulated, tmp_path, capsys):
    out = tmp_path / "held"
    code = _run(
        simulated.bag,
        "--out",
        out,
        "--span",
        simulated.span_log,
        "--extrinsics",
        simulated.extrinsics,
        "--gnss-factors",
        "--gnss-hold-out",
        "1",
    )
    assert code == 0
    factors = json.loads((out / "georef.json").read_text())["gnss_factors"]
    assert factors["hold_out_period_s"] == 1.0 and factors["rejected_hold_out"] > 0
    assert all((s // 1_000_000_000) % 2 == 0 for s in factors["fused_stamps_ns"])
    fusion = json.loads((out / "eval" / "report.json").read_text())["fusion"]
    assert fusion["held_out_only"] and 0 < fusion["poses_scored"] < fusion["poses_total"]
    capsys.readouterr()
    argv = ["-q", "eval", str(out / "trajectory_tum.txt"), "--span", str(simulated.span_log), "--held-out"]
    assert main([*argv, "--extrinsics", str(simulated.extrinsics), "--out", str(tmp_path / "e")]) == 0
    assert "scored on the held-out epochs only" in capsys.readouterr().out
