"""End to end: the simulator's SPAN log evaluated against the simulator's ground truth.

The three files are written exactly as ``lidar3d simulate`` writes them (ground truth TUM, SPAN
ASCII log, extrinsic TOML), without ray casting the bag.
"""

import json

import numpy as np
import pytest

from lidar3d.cli.main import main
from lidar3d.gnss import read_extrinsic, read_span_log, write_extrinsic
from lidar3d.io.trajectory_io import write_tum

sim = pytest.importorskip("lidar3d.sim")


def _write(simulation, folder):
    folder.mkdir()
    write_tum(folder / "ground_truth_tum.txt", simulation.ground_truth)
    (folder / "novatel_span.log").write_bytes("".join(simulation.span_log_lines()).encode("ascii"))
    write_extrinsic(folder / "extrinsics.toml", simulation.T_imu_lidar)
    return folder


def _eval(folder, capsys, *extra):
    out = folder / ("eval" + "_".join(extra).replace("-", "").replace(" ", ""))
    code = main(
        [
            "-q",
            "eval",
            str(folder / "ground_truth_tum.txt"),
            "--span",
            str(folder / "novatel_span.log"),
            "--extrinsics",
            str(folder / "extrinsics.toml"),
            "--out",
            str(out),
            *extra,
        ]
    )
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return json.loads((out / "report.json").read_text())


@pytest.fixture(scope="module")
def loop():
    return sim.Simulation("loop", seed=0)


def _origin_args(simulation):
    o = simulation.span_params.origin
    return ["--origin", repr(o.latitude_deg), repr(o.longitude_deg), repr(o.height_m)]


def test_simulated_log_parses_cleanly(loop, tmp_path):
    folder = _write(loop, tmp_path / "sim")
    log = read_span_log(folder / "novatel_span.log")
    assert log.stats.bad_crc == 0 and log.stats.bad_format == 0 and log.stats.truncated == 0
    assert set(log.stats.decoded) == {"INSPVAX", "BESTPOS"} and not log.stats.ignored
    assert np.allclose(read_extrinsic(folder / "extrinsics.toml"), loop.T_imu_lidar, atol=1e-12)


def test_ate_at_the_log_noise_level(loop, tmp_path, capsys):
    folder = _write(loop, tmp_path / "sim")
    for extra in ([], ["--align", "yaw"], ["--align", "none", *_origin_args(loop)]):
        report = _eval(folder, capsys, *extra)
        ate = report["ate"]["translation_3d_m"]
        # INSPVAX errors: RTK-fixed sigma 1.2 cm horizontal, 2 cm vertical (about 2.6 cm 3-D)
        assert 0.005 < ate["rmse"] < 0.045, extra
        assert ate["max"] < 0.1
        assert report["ate"]["rotation_deg"]["rmse"] < 0.1
        assert report["association"]["gnss_quality"] == {"RTK fixed": report["association"]["associated_poses"]}
    assert report["association"]["associated_poses"] > 0.7 * len(loop)  # degraded stretch left out


def test_noise_free_log_reproduces_ground_truth(tmp_path, capsys):
    exact = sim.SpanParams(noise=False, degraded_window=(1.0, 1.0))
    simulation = sim.Simulation("loop", seed=0, duration_s=30.0, span=exact)
    folder = _write(simulation, tmp_path / "exact")
    report = _eval(folder, capsys, "--align", "none", *_origin_args(simulation))
    # only the printed precision of the ASCII log remains (1e-11 deg, 0.1 mm, 1e-9 deg)
    assert report["ate"]["translation_3d_m"]["max"] < 2e-4
    assert report["ate"]["rotation_deg"]["max"] < 1e-5
    assert report["association"]["associated_poses"] == len(simulation)
