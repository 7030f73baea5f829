"""``lidar3d view`` without a display: the rendered PNG is judged by its pixels (issue 22).

The run folder is built by hand: a flat ground at z = 0 west of x = 0, a 6 m high block east of it,
and a straight trajectory along y = 0. In the top view the block must be drawn in the high end of
the colour map and the ground in the low end, and the trajectory's red must lie on y = 0.
"""

from __future__ import annotations

import io

import numpy as np
import pytest
from matplotlib import colormaps

from lidar3d.cli.main import main
from lidar3d.export.map_view import TRAJECTORY_RGB, read_run_view, render_view_png
from lidar3d.io.pcd import write_pcd
from lidar3d.io.trajectory_io import write_tum
from lidar3d.records import Trajectory


def _run_folder(folder):
    rng = np.random.default_rng(0)
    ground = np.column_stack([rng.uniform(-40, 0, 40000), rng.uniform(-20, 20, 40000), np.zeros(40000)])
    block = np.column_stack([rng.uniform(0, 40, 40000), rng.uniform(-20, 20, 40000), np.full(40000, 6.0)])
    folder.mkdir()
    write_pcd(folder / "map.pcd", np.vstack([ground, block]), intensity=np.ones(80000, np.float32))
    n = 50
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, 0, 3] = np.linspace(-30, 30, n)
    poses[:, 2, 3] = 7.0
    write_tum(folder / "trajectory_tum.txt", Trajectory(np.arange(n, dtype=np.int64) * 100_000_000, poses))
    return folder


def _pixels(png: bytes) -> np.ndarray:
    from matplotlib.image import imread

    return imread(io.BytesIO(png), format="png")[:, :, :3]


def _near(image: np.ndarray, rgb, tolerance: float = 0.08) -> np.ndarray:
    return np.all(np.abs(image - np.asarray(rgb)) < tolerance, axis=-1)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    folder = _run_folder(tmp_path_factory.mktemp("view") / "run")
    return _pixels(render_view_png(read_run_view(folder)))


def test_top_and_oblique_views_colour_the_map_by_height(rendered):
    height, width, _ = rendered.shape
    assert (width, height) == (1400, 640)
    low, high = colormaps["turbo"](0.0)[:3], colormaps["turbo"](1.0)[:3]
    left, right = rendered[:, : width // 2], rendered[:, width // 2 :]
    for panel in (left, right):
        assert _near(panel, low, 0.1).sum() > 5000, "ground (low end of the colour map) missing"
        assert _near(panel, high, 0.1).sum() > 5000, "block (high end of the colour map) missing"
    # Top view: the ground lies west (left), the block east (right) of x = 0.
    low_columns = np.nonzero(_near(left, low, 0.1))[1]
    high_columns = np.nonzero(_near(left, high, 0.1))[1]
    assert np.median(low_columns) < np.median(high_columns) - 100


def test_trajectory_is_drawn_on_top_in_both_views(rendered):
    width = rendered.shape[1]
    red = _near(rendered, TRAJECTORY_RGB, 0.12)
    left, right = red[:, : width // 2], red[:, width // 2 :]
    assert left.sum() > 300 and right.sum() > 300
    rows = np.nonzero(left)[0]
    on_line = np.abs(rows - np.median(rows)) <= 4  # the rest: the legend's sample of the line
    assert on_line.mean() > 0.85, "the straight trajectory along y = 0 is one thin horizontal line"
    columns = np.nonzero(left)[1][on_line]
    assert columns.max() - columns.min() > 250  # 60 m of a ~90 m wide view


def test_cli_writes_the_png_and_says_where(tmp_path, capsys, monkeypatch):
    folder = _run_folder(tmp_path / "run")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["view", str(folder), "--max-points", "20000"]) == 0
    default = tmp_path / "run_view.png"
    assert capsys.readouterr().out.startswith(f"wrote {default} (no display")
    assert _pixels(default.read_bytes()).std() > 0.1  # not a blank image
    assert main(["-q", "view", str(folder), "--png", str(tmp_path / "v.png")]) == 0
    assert (tmp_path / "v.png").stat().st_size > 10000


def test_a_folder_without_a_map_is_one_clear_error(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["view", str(tmp_path / "empty"), "--png", str(tmp_path / "v.png")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("lidar3d view: error: ") and "map.pcd: not found" in err and "\n" not in err
