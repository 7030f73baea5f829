"""One decoding for every command: ``run``, ``features`` and ``info`` assign a bag the same rings.

The bag is written with its ring field numbered from the top beam down (as Ouster drivers do), so
decoding has to renumber it by elevation; a second bag holds the same scans numbered as
``velodyne_pointcloud`` numbers them (0 = lowest beam), the truth.
"""

from __future__ import annotations

import numpy as np
import pytest
from frontend_sim import sample_scans
from test_io_pointcloud2 import build_parts

from lidar3d.cli.main import main
from lidar3d.config import Config
from lidar3d.features import run_front_end
from lidar3d.io.bag_info import bag_info
from lidar3d.io.bag_writer import write_cloud_bag, write_scan_bag
from lidar3d.io.pcd import read_pcd
from lidar3d.io.scan_source import open_scan_source

VELODYNE_LAYOUT = [
    ("x", 0, "f4"),
    ("y", 4, "f4"),
    ("z", 8, "f4"),
    ("intensity", 16, "f4"),
    ("ring", 20, "u2"),
    ("time", 24, "f4"),
]
FEATURE_FILES = {
    "edge_sharp.pcd": "sharp",
    "edge_less_sharp.pcd": "less_sharp",
    "planar_flat.pcd": "flat",
    "planar_less_flat.pcd": "less_flat",
}


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bags")
    scans = [sim_scan.scan for sim_scan in sample_scans("loop")[:4]]
    truth, top_down, ringless = folder / "truth.bag", folder / "top_down.bag", folder / "ringless.bag"
    write_scan_bag(truth, scans)
    write_cloud_bag(top_down, (build_parts(s, VELODYNE_LAYOUT, 32, values={"ring": 15 - s.ring}) for s in scans))
    no_ring = [field for field in VELODYNE_LAYOUT if field[0] != "ring"]
    write_cloud_bag(ringless, (build_parts(s, no_ring, 32) for s in scans))
    return {"truth": truth, "top_down": top_down, "ringless": ringless}


def test_features_and_run_assign_the_same_rings(bags, tmp_path):
    truth, top_down = bags["truth"], bags["top_down"]
    # --start 1 --max-scans 2: the ring numbering is judged on scan 0, which features skips
    for bag in (truth, top_down):
        assert main(["features", str(bag), "--out", str(tmp_path / bag.stem), "--start", "1", "--max-scans", "2"]) == 0
    with open_scan_source(top_down, Config()) as source:  # what `lidar3d run` reads
        run_scans = list(source)
    for index in (1, 2):
        run_features = run_front_end(run_scans[index], Config()).features
        for name, attribute in FEATURE_FILES.items():
            points, fields = read_pcd(tmp_path / "top_down" / f"scan_{index:06d}" / name)
            cloud = getattr(run_features, attribute)
            np.testing.assert_array_equal(fields["ring"], cloud.ring)
            np.testing.assert_array_equal(points, cloud.points.astype(np.float32))
            # and the renumbered rings are the true ones
            truth_points, truth_fields = read_pcd(tmp_path / "truth" / f"scan_{index:06d}" / name)
            np.testing.assert_array_equal(fields["ring"], truth_fields["ring"])
            np.testing.assert_array_equal(points, truth_points)


def test_info_counts_the_rings_run_assigns(bags):
    truth, top_down = bags["truth"], bags["top_down"]
    info, truth_info = bag_info(top_down), bag_info(truth)
    assert (info.n_rings, info.sensor_model) == (truth_info.n_rings, truth_info.sensor_model) == (16, "vlp16")


@pytest.mark.parametrize("name", ["top_down", "ringless"])
def test_scans_in_a_range_are_decoded_as_in_a_full_pass(bags, name):
    with open_scan_source(bags[name]) as source:
        full = list(source)
    with open_scan_source(bags[name]) as source:
        ranged = list(source.scans(2, 4))
        assert source.stats.n_scans == 2  # the scans before the range are not counted
    assert [index for index, _scan in ranged] == [2, 3]
    for (_index, scan), want in zip(ranged, full[2:]):
        np.testing.assert_array_equal(scan.ring, want.ring)
        np.testing.assert_array_equal(scan.points, want.points)
        np.testing.assert_array_equal(scan.time_offset_s, want.time_offset_s)
