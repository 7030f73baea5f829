"""``lidar3d features``: per-scan folders of PCDs from a bag written in the test."""

from __future__ import annotations

import numpy as np
import pytest
from frontend_sim import sample_scans

from lidar3d.cli.main import main
from lidar3d.io.bag_writer import write_scan_bag
from lidar3d.io.pcd import read_pcd
from lidar3d.records import Scan

FILES = {
    "ground.pcd",
    "lifted.pcd",
    "clusters.pcd",
    "outliers.pcd",
    "edge_sharp.pcd",
    "edge_less_sharp.pcd",
    "planar_flat.pcd",
    "planar_less_flat.pcd",
}


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    path = tmp_path_factory.mktemp("bag") / "scene.bag"
    scans = [sim_scan.scan for sim_scan in sample_scans("loop")[:3]]
    one_ring = Scan(
        stamp_ns=scans[-1].stamp_ns + 10**8,
        points=[[10.0, 0.1 * k, -1.0] for k in range(40)],
        intensity=np.zeros(40),
        ring=np.full(40, 2),
        time_offset_s=np.zeros(40),
    )
    write_scan_bag(path, [*scans, one_ring])
    return path, scans


def test_writes_one_folder_per_selected_scan(bag, tmp_path, capsys):
    path, scans = bag
    out = tmp_path / "fe"
    assert main(["features", str(path), "--out", str(out), "--start", "1", "--max-scans", "2"]) == 0
    printed = capsys.readouterr().out
    for stage in ("projection", "ground", "clustering", "smoothness", "selection", "total"):
        assert stage in printed
    assert sorted(p.name for p in out.iterdir()) == ["config.toml", "scan_000001", "scan_000002"]
    folder = out / "scan_000001"
    assert {p.name for p in folder.iterdir()} == FILES
    clusters, fields = read_pcd(folder / "clusters.pcd")
    assert len(clusters) > 100 and fields["label"].dtype.kind == "i" and fields["label"].min() == 0
    ground, _ = read_pcd(folder / "ground.pcd")
    assert np.median(ground[:, 2]) < -1.5  # lidar frame: the ground lies below the sensor
    sharp, _ = read_pcd(folder / "edge_sharp.pcd")
    less_sharp, _ = read_pcd(folder / "edge_less_sharp.pcd")
    assert 0 < len(sharp) < len(less_sharp)
    # points are the scan's own (lidar frame), stored as float32
    scan_points = scans[1].points.astype(np.float32)
    assert np.isin(
        sharp.astype(np.float32).view([("", np.float32)] * 3), scan_points.view([("", np.float32)] * 3)
    ).all()


def test_unusable_scan_gives_header_only_pcds(bag, tmp_path, caplog):
    path, _ = bag
    out = tmp_path / "fe"
    assert main(["features", str(path), "--out", str(out), "--start", "3"]) == 0
    folder = out / "scan_000003"
    assert {p.name for p in folder.iterdir()} == FILES
    header = (folder / "edge_sharp.pcd").read_text()
    assert "POINTS 0" in header and "FIELDS x y z ring" in header


def test_bad_scan_selection_is_rejected(bag, tmp_path, capsys):
    path, _ = bag
    assert main(["features", str(path), "--out", str(tmp_path / "x"), "--max-scans", "0"]) == 1
    assert capsys.readouterr().err.strip() == "lidar3d features: error: --max-scans must be 1 or more, got 0"


def test_missing_bag_is_one_clear_error(tmp_path, capsys):
    assert main(["features", str(tmp_path / "none.bag"), "--out", str(tmp_path / "x")]) == 1
    assert "lidar3d features: error:" in capsys.readouterr().err
