"""The 2-D occupancy grid: ray casting in a band above the local ground, the map_server files, and
``lidar3d grid`` end to end with its bad inputs.

The ray casting is a numba kernel; the NumPy version it replaced is kept below
(:class:`_ReferenceBuilder`) as its oracle: the same log-odds, bit for bit.
"""

import dataclasses

import numpy as np
import pytest

from lidar3d import sim
from lidar3d.cli.main import main
from lidar3d.errors import ConfigError
from lidar3d.grid import check_grid_options, grid_run
from lidar3d.io.map_server import (
    FREE_VALUE,
    OCCUPIED_VALUE,
    UNKNOWN_VALUE,
    read_map_server,
    trinary_image,
    write_map_server,
)
from lidar3d.io.run_folder import check_run_folder
from lidar3d.io.trajectory_io import read_tum
from lidar3d.mapping.occupancy_grid import (
    GridParams,
    GroundModel,
    LowestPerCell,
    OccupancyGridBuilder,
    lowest_per_cell,
)
from lidar3d.run import run_bag

# ---------------------------------------------------------------- ray casting on hand-made scenes


def _ground(height_of_xy) -> GroundModel:
    x, y = np.meshgrid(np.arange(-30.0, 31.0), np.arange(-30.0, 31.0), indexing="ij")
    xy = np.column_stack([x.ravel(), y.ravel()])
    return GroundModel.from_points(np.column_stack([xy, height_of_xy(xy)]))


def _wall(x_m: float, z_of_xy, heights) -> np.ndarray:
    y = np.linspace(-3.0, 3.0, 61)
    points = [np.column_stack([np.full_like(y, x_m), y, np.zeros_like(y)]) for _ in heights]
    for p, h in zip(points, heights):
        p[:, 2] = z_of_xy(p[:, :2]) + h
    return np.concatenate(points)


@pytest.mark.parametrize("slope", [0.0, 0.12], ids=["flat", "hill"])
def test_a_wall_is_occupied_the_way_to_it_free_and_behind_it_unknown(slope):
    def height(xy):
        return slope * xy[:, 0]

    params = GridParams(resolution_m=0.1)
    builder = OccupancyGridBuilder(params, _ground(height), np.array([[-20.0, -20.0], [20.0, 20.0]]))
    sensor = np.array([0.0, 0.0, 1.8])
    wall = _wall(10.0, height, (0.5, 1.0, 1.5))
    ground_hits = np.column_stack([np.linspace(2.0, 9.0, 50), np.zeros(50), np.zeros(50)])
    ground_hits[:, 2] = height(ground_hits[:, :2])  # the ground itself, up the hill, is no obstacle
    for _ in range(5):  # four sweeps take a cell below free_thresh (0.196)
        builder.add(sensor, np.concatenate([wall, ground_hits]))
    grid = builder.grid()
    i, j, inside = grid.cell_of(np.array([[10.0, 0.0], [5.0, 0.0], [9.0, 0.0], [13.0, 0.0], [5.0, 8.0]]))
    assert inside.all()
    p = grid.probability[i, j]
    assert p[0] > 0.9  # the wall
    assert p[1] < 0.2 and p[2] < 0.2  # the way to it, up the hill too
    assert not grid.observed[i[3], j[3]] and not grid.observed[i[4], j[4]]  # behind it, and off every beam


def test_points_outside_the_band_are_no_obstacle_and_occupied_wins_within_a_sweep():
    params = GridParams(resolution_m=0.2, band_m=(0.3, 2.0))
    builder = OccupancyGridBuilder(params, _ground(lambda xy: np.zeros(len(xy))), np.array([[-20, -20], [20, 20]]))
    sensor = np.array([0.0, 0.0, 1.0])
    low_curb = np.array([[6.0, 0.0, 0.1]])  # below the band
    overhang = np.array([[6.0, 3.0, 3.0]])  # above it
    obstacle = np.array([[8.0, -3.0, 1.0], [12.0, -4.5, 1.0]])  # the second beam passes the first point's cell
    builder.add(sensor, np.concatenate([low_curb, overhang, obstacle]))
    grid = builder.grid()
    i, j, _ = grid.cell_of(np.array([[6.0, 0.0], [6.0, 3.0], [8.0, -3.0]]))
    assert grid.log_odds[i[0], j[0]] <= 0 and grid.log_odds[i[1], j[1]] <= 0
    assert grid.log_odds[i[2], j[2]] == pytest.approx(params.hit_log_odds)


def test_points_the_segmentation_calls_ground_are_no_obstacle_even_inside_the_band():
    # A slope the ground model under-estimates puts road points into the band: marked ground, they stay free.
    params = GridParams(resolution_m=0.2, band_m=(0.3, 2.0))
    bounds = np.array([[-20, -20], [20, 20]])
    sensor = np.array([0.0, 0.0, 1.8])
    road = np.array([[10.0, 0.0, 0.5], [10.0, 5.0, 0.5]])  # 0.5 m above the modelled ground
    grids = {}
    for marked in (False, True):
        builder = OccupancyGridBuilder(params, _ground(lambda xy: np.zeros(len(xy))), bounds)
        builder.add(sensor, road, np.array([marked, False]))
        grids[marked] = builder.grid()
    i, j, _ = grids[True].cell_of(road[:, :2])
    assert grids[False].log_odds[i[0], j[0]] > 0 and grids[True].log_odds[i[0], j[0]] <= 0
    assert grids[True].log_odds[i[1], j[1]] > 0  # the unmarked point is still an obstacle


def test_a_ground_mask_of_another_length_is_refused():
    builder = OccupancyGridBuilder(GridParams(), _ground(lambda xy: np.zeros(len(xy))), np.array([[-5, -5], [5, 5]]))
    with pytest.raises(ValueError, match=r"on_ground \(N,\), got \(2, 3\), \(3,\)"):
        builder.add(np.array([0.0, 0.0, 1.0]), np.ones((2, 3)), np.zeros(3, bool))


def test_log_odds_stay_clamped():
    params = GridParams(resolution_m=0.2, clamp_log_odds=2.0)
    builder = OccupancyGridBuilder(params, _ground(lambda xy: np.zeros(len(xy))), np.array([[-20, -20], [20, 20]]))
    for _ in range(20):
        builder.add(np.array([0.0, 0.0, 1.0]), np.array([[8.0, 0.0, 1.0]]))
    grid = builder.grid()
    assert grid.log_odds.max() == pytest.approx(2.0) and grid.log_odds.min() == pytest.approx(-2.0)


# ---------------------------------------------------------------- map_server files


def test_map_server_files_follow_its_conventions(tmp_path):
    probability = np.full((4, 3), 0.5)  # x = 4 cells, y = 3 cells
    probability[0, 0] = 0.9  # lowest x, lowest y: the lower-left pixel
    probability[3, 2] = 0.05  # highest x, highest y: the upper-right pixel
    image = trinary_image(probability)
    assert image.shape == (3, 4)
    assert image[2, 0] == OCCUPIED_VALUE and image[0, 3] == FREE_VALUE and image[1, 1] == UNKNOWN_VALUE
    pgm = write_map_server(tmp_path / "map.yaml", image, 0.25, np.array([-1.5, 2.0]))
    assert pgm.read_bytes().startswith(b"P5\n")
    text = (tmp_path / "map.yaml").read_text()
    for line in ("image: map.pgm", "mode: trinary", "resolution: 0.25", "origin: [-1.500000, 2.000000, 0.0]"):
        assert line in text
    assert "negate: 0" in text and "occupied_thresh: 0.65" in text and "free_thresh: 0.196" in text
    back = read_map_server(tmp_path / "map.yaml")
    np.testing.assert_array_equal(back.image, image)
    assert back.origin == (-1.5, 2.0, 0.0) and back.resolution_m == 0.25
    # map_server's reading: p = (255 - v) / 255, occupied above 0.65, free below 0.196, else unknown.
    p = (255 - back.image.astype(float)) / 255
    assert ((p > 0.65) == (back.image == OCCUPIED_VALUE)).all() and ((p < 0.196) == (back.image == FREE_VALUE)).all()


def test_the_preview_shrinks_a_large_grid_keeping_every_obstacle_and_draws_the_path():
    import io

    from PIL import Image

    from lidar3d.export.grid_preview import _MARGIN_PX, MAX_SIDE_PX, grid_preview_png

    image = np.full((1500, 3000), FREE_VALUE, np.uint8)  # 150 x 300 m of 0.1 m cells: shrunk 3 times
    image[700, 1201] = OCCUPIED_VALUE  # one obstacle cell
    image[:, :10] = UNKNOWN_VALUE
    path = np.array([[-100.0, 20.0], [100.0, 20.0]])  # y = 20 m: row (50 - 20) / 0.1 = 300
    png = grid_preview_png(image, 0.1, np.array([-150.0, -100.0]), path, title="t")
    preview = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))
    gray = preview[..., 0].astype(int)
    is_map = (preview[..., 0] == preview[..., 1]) & (preview[..., 1] == preview[..., 2])
    assert MAX_SIDE_PX // 2 < preview.shape[1] < MAX_SIDE_PX + 200
    assert ((gray == OCCUPIED_VALUE) & is_map).sum() >= 1  # the lone obstacle survives the shrinking
    assert ((gray == UNKNOWN_VALUE) & is_map).sum() >= 3 * 500  # the unknown strip, 10 cells wide
    orange = (preview[..., 0] == 255) & (preview[..., 1] == 127) & (preview[..., 2] == 14)
    top_px, metres_per_px = _MARGIN_PX[1], 0.3  # the map's first row, below the title; shrunk 3 times
    path_row = top_px + round((50.0 - 20.0) / metres_per_px)  # the map's top edge is y = -100 + 150 m
    assert orange[path_row - 1 : path_row + 2].sum() >= 200.0 / metres_per_px  # the 200 m of path


# ---------------------------------------------------------------- lidar3d grid end to end


@pytest.fixture(scope="module")
def loop_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("grid")
    simulated = sim.simulate("loop", folder / "sim", seed=0, duration_s=2.0)
    run_bag(simulated.bag, folder / "run", prefetch=False)
    return simulated, folder / "run"


def test_grid_command_writes_a_map_whose_path_is_free(loop_run, tmp_path, capsys):
    _, run = loop_run
    assert main(["-q", "grid", str(run), "--out", str(tmp_path / "g")]) == 0
    out = capsys.readouterr().out
    assert "scans gridded" in out and "map.yaml" in out
    grid_map = read_map_server(tmp_path / "g" / "map.yaml")
    assert set(np.unique(grid_map.image)) <= {OCCUPIED_VALUE, FREE_VALUE, UNKNOWN_VALUE}
    assert (tmp_path / "g" / "map.png").read_bytes().startswith(b"\x89PNG")
    rows = grid_map.image.shape[0]
    path = read_tum(run / "trajectory_tum.txt").positions_m[:, :2]
    col = np.floor((path[:, 0] - grid_map.origin[0]) / grid_map.resolution_m).astype(int)
    row = rows - 1 - np.floor((path[:, 1] - grid_map.origin[1]) / grid_map.resolution_m).astype(int)
    assert (grid_map.image[row, col] == FREE_VALUE).mean() >= 0.99
    assert (grid_map.image == OCCUPIED_VALUE).sum() > 100  # the block's facades
    assert check_run_folder(run).state.value == "consistent"  # the run folder is left as it was


def test_a_partial_run_is_gridded_as_far_as_it_goes(loop_run, tmp_path, capsys):
    simulated, _ = loop_run

    def stop(done, total):
        if done == 8:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_bag(simulated.bag, tmp_path / "partial", on_scan=stop, prefetch=False)
    outcome = grid_run(tmp_path / "partial", tmp_path / "g")
    assert outcome.partial and 0 < outcome.scans <= 8
    assert main(["-q", "grid", str(tmp_path / "partial"), "--out", str(tmp_path / "g2")]) == 0
    assert "partial" in capsys.readouterr().out


def test_a_partial_run_without_a_map_yet_is_gridded_from_its_scans(loop_run, tmp_path, capsys):
    """A run stopped (SIGTERM, power) before its first map checkpoint published poses but no
    map.pcd: the grid needs only the poses and the scans."""
    import shutil

    from lidar3d.io.run_folder import publish_set
    from lidar3d.summary import read_summary

    _, run = loop_run
    folder = tmp_path / "no_map"
    shutil.copytree(run, folder)
    summary = read_summary(folder / "summary.json")
    keep = [entry.path for entry in summary.outputs if entry.path not in ("map.pcd", "dynamic.pcd")]
    publish_set(folder, dataclasses.replace(summary, partial=True), keep=keep)
    assert not (folder / "map.pcd").exists()
    assert main(["-q", "grid", str(folder), "--out", str(tmp_path / "g")]) == 0
    assert "partial" in capsys.readouterr().out
    assert (tmp_path / "g" / "map.pgm").exists()


@pytest.mark.parametrize(
    "options, message",
    [
        (["--band", "1.0", "1.0"], "--band 1 1 is empty"),
        (["--band", "2.0", "0.3"], "--band 2 0.3 is inverted"),
        (["--resolution", "0"], "--resolution must be > 0 m"),
        (["--resolution", "-0.1"], "--resolution must be > 0 m"),
    ],
)
def test_bad_options_give_one_line(loop_run, tmp_path, capsys, options, message):
    _, run = loop_run
    assert main(["grid", str(run), "--out", str(tmp_path / "g"), *options]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("lidar3d grid: error: ") and message in err and "\n" not in err
    with pytest.raises(ConfigError):
        check_grid_options(0.1, (2.0, 0.3))


@pytest.mark.parametrize("case", ["missing", "empty", "not a run", "damaged"])
def test_a_folder_that_is_no_finished_run_gives_one_line(loop_run, tmp_path, capsys, case):
    _, run = loop_run
    folder = tmp_path / "folder"
    if case == "empty":
        folder.mkdir()
    elif case == "not a run":
        folder.mkdir()
        (folder / "notes.txt").write_text("hello")
    elif case == "damaged":
        import shutil

        shutil.copytree(run, folder)
        (folder / "trajectory_tum.txt").write_text("garbage\n")
    assert main(["grid", str(folder), "--out", str(tmp_path / "g")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("lidar3d grid: error: ") and str(folder) in err and "\n" not in err


def test_a_run_whose_bag_is_gone_names_it(loop_run, tmp_path, capsys):
    import shutil

    from lidar3d.io.run_folder import publish_set
    from lidar3d.summary import read_summary

    _, run = loop_run
    folder = tmp_path / "moved"
    shutil.copytree(run, folder)
    summary = read_summary(folder / "summary.json")
    keep = [entry.path for entry in summary.outputs]
    publish_set(folder, dataclasses.replace(summary, inputs=("/nowhere/drive.bag",)), keep=keep)
    assert main(["grid", str(folder), "--out", str(tmp_path / "g")]) == 1
    assert "/nowhere/drive.bag" in capsys.readouterr().err


# ---------------------------------------------------------------- the kernel against the array version


class _ReferenceBuilder(OccupancyGridBuilder):
    """The ray casting as it was, in NumPy (whole arrays per sweep): the oracle of the kernel."""

    def add(self, origin_world, points_world, on_ground=None):
        p = self.params
        ground = self.ground
        low, high = p.band_m
        sweep = self._n_sweeps
        self._n_sweeps += 1
        if not len(points_world):
            return
        delta = points_world[:, :2] - origin_world[:2]
        length = np.hypot(delta[:, 0], delta[:, 1])
        ok = (length > p.resolution_m) & (length <= p.max_range_m)
        points_world, delta, length = points_world[ok], delta[ok], length[ok]
        not_ground = np.ones(len(points_world), bool) if on_ground is None else ~np.asarray(on_ground, bool)[ok]
        h0 = float(origin_world[2] - ground.height_at(origin_world[None, :2])[0])
        h1 = points_world[:, 2] - ground.height_at(points_world[:, :2])
        slope = h1 - h0
        with np.errstate(divide="ignore", invalid="ignore"):
            s_low, s_high = (low - h0) / slope, (high - h0) / slope
        s_enter = np.where(slope > 0, s_low, s_high)
        s_leave = np.where(slope > 0, s_high, s_low)
        flat = np.abs(slope) < 1e-9
        inside_at_start = (h0 >= low) & (h0 <= high)
        s_enter = np.where(flat, 0.0 if inside_at_start else np.inf, np.clip(s_enter, 0.0, None))
        s_leave = np.where(flat, 1.0 if inside_at_start else -np.inf, np.minimum(s_leave, 1.0))
        end_free = length - p.resolution_m
        free_from = s_enter * length
        free_to = np.minimum(s_leave * length, end_free)
        occupied = (h1 >= low) & (h1 <= high) & not_ground
        blocked_at = np.where(occupied, end_free, np.inf)
        free_cells = self._free_cells(origin_world[:2], delta, free_from, free_to, blocked_at)
        xy = points_world[occupied, :2]
        ij = np.floor((xy - self.origin_xy_m) / p.resolution_m).astype(np.int64)
        inside = (ij[:, 0] >= 0) & (ij[:, 1] >= 0) & (ij[:, 0] < self.shape[0]) & (ij[:, 1] < self.shape[1])
        hit_cells = ij[inside, 0] * self.shape[1] + ij[inside, 1]
        mark, log_odds = self._mark, self._log_odds
        if free_cells.size:
            mark[free_cells] = sweep
            log_odds[free_cells] = np.maximum(log_odds[free_cells] + p.miss_log_odds, -p.clamp_log_odds)
        if hit_cells.size:
            step = np.where(mark[hit_cells] == sweep, p.hit_log_odds - p.miss_log_odds, p.hit_log_odds)
            log_odds[hit_cells] = np.minimum(log_odds[hit_cells] + step, p.clamp_log_odds)
            mark[hit_cells] = sweep

    def _free_cells(self, origin_xy, delta, free_from, free_to, blocked_at):
        p = self.params
        n_bins = p.azimuth_bins
        azimuth = np.arctan2(delta[:, 1], delta[:, 0])
        bins = (np.floor((azimuth + np.pi) * (n_bins / (2 * np.pi))).astype(np.int64)) % n_bins
        order = np.argsort(bins, kind="stable")
        sorted_bins = bins[order]
        first = np.flatnonzero(np.r_[True, sorted_bins[1:] != sorted_bins[:-1]])
        useful = free_to > free_from
        start = np.full(n_bins, np.inf)
        reach = np.zeros(n_bins)
        if first.size:
            start[sorted_bins[first]] = np.minimum.reduceat(np.where(useful, free_from, np.inf)[order], first)
            reach[sorted_bins[first]] = np.minimum(
                np.maximum.reduceat(np.where(useful, free_to, 0.0)[order], first),
                np.minimum.reduceat(blocked_at[order], first),
            )
        step = p.resolution_m
        spread_m = 2 * np.pi / n_bins
        cells = []
        level, far = 0, np.inf
        while far > step:
            near = 0.7 * step / (spread_m * 2 ** (level + 1)) if level < 12 else 0.0
            chosen = np.arange(0, n_bins, 2**level)
            lo = np.maximum(start[chosen], near)
            hi = np.minimum(reach[chosen], far)
            keep = hi > lo
            if keep.any():
                cells.append(self._cast(origin_xy, chosen[keep], lo[keep], hi[keep]))
            level, far = level + 1, near
        return np.concatenate(cells) if cells else np.zeros(0, np.int64)

    def _cast(self, origin_xy, bins, lo, hi):
        step = self.params.resolution_m
        first = np.ceil(lo / step).astype(np.int64)
        count = np.floor(hi / step).astype(np.int64) - first + 1
        ok = count > 0
        bins, first, count = bins[ok], first[ok], count[ok]
        ray = np.repeat(np.arange(bins.size), count)
        index = (np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count - first, count)).astype(np.float32)
        angle = (bins + 0.5) * (2 * np.pi / self.params.azimuth_bins) - np.pi
        start = (origin_xy - self.origin_xy_m) / step
        nx, ny = self.shape
        i = np.clip((start[0] + np.cos(angle).astype(np.float32)[ray] * index).astype(np.int64), 0, nx - 1)
        j = np.clip((start[1] + np.sin(angle).astype(np.float32)[ray] * index).astype(np.int64), 0, ny - 1)
        return i * ny + j


@pytest.mark.parametrize(
    "params",
    [GridParams(), GridParams(resolution_m=0.05, band_m=(0.2, 1.5)), GridParams(resolution_m=0.25, clamp_log_odds=2.0)],
    ids=["defaults", "fine", "coarse"],
)
def test_the_ray_casting_kernel_gives_the_array_version_s_log_odds_bit_for_bit(params):
    # Random sweeps over a hilly ground: walls, ground hits, beams at the sensor's own height (flat),
    # points beyond the range and outside the grid, some points marked ground; enough to clamp.
    rng = np.random.default_rng(7)

    def height(xy):
        return 0.1 * xy[:, 0] - 0.04 * xy[:, 1] + 0.3 * np.sin(xy[:, 0] / 5.0)

    ground = _ground(height)
    bounds = np.array([[-25.0, -20.0], [25.0, 20.0]])
    builders = [cls(params, ground, bounds) for cls in (OccupancyGridBuilder, _ReferenceBuilder)]
    posts_xy = rng.uniform(-15.0, 15.0, (200, 2))  # seen by every sweep
    posts = np.column_stack([posts_xy, height(posts_xy) + 1.0])
    for sweep in range(30):
        sensor = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), 0.0])
        sensor[2] = height(sensor[None, :2])[0] + 1.8
        n = 4000
        azimuth = rng.uniform(-np.pi, np.pi, n)
        distance = rng.choice([rng.uniform(0.0, 50.0), 12.0], n) * rng.uniform(0.2, 1.0, n)
        xy = sensor[:2] + distance[:, None] * np.column_stack([np.cos(azimuth), np.sin(azimuth)])
        z = height(xy) + rng.choice([0.0, 0.5, 1.0, 2.5], n) + rng.normal(0.0, 0.05, n)
        # beams level with the sensor's height above the ground: the "flat" case
        z[: n // 20] = ground.height_at(xy[: n // 20]) + sensor[2] - ground.height_at(sensor[None, :2])[0]
        points = np.concatenate([np.column_stack([xy, z]), posts])
        on_ground = rng.random(len(points)) < 0.3 if sweep % 2 else None
        for builder in builders:
            builder.add(sensor, points, on_ground)
        if sweep == 3:
            for builder in builders:
                builder.add(sensor, np.zeros((0, 3)))
    new, reference = (builder.grid() for builder in builders)
    np.testing.assert_array_equal(new.log_odds, reference.log_odds)
    np.testing.assert_array_equal(new.observed, reference.observed)
    assert (new.log_odds == params.clamp_log_odds).any() and (new.log_odds == -params.clamp_log_odds).any()


def test_lidar3d_grid_writes_the_array_version_s_map_byte_for_byte(loop_run, tmp_path, monkeypatch):
    """With no obstacle tops noted (the array version has no such rule) the command's map is the
    array version's, byte for byte."""
    _, run = loop_run
    monkeypatch.setattr(OccupancyGridBuilder, "note_obstacles", lambda self, points, on_ground=None: None)
    new = grid_run(run, tmp_path / "new")
    monkeypatch.setattr("lidar3d.grid.OccupancyGridBuilder", _ReferenceBuilder)
    reference = grid_run(run, tmp_path / "reference")
    np.testing.assert_array_equal(new.grid.log_odds, reference.grid.log_odds)
    assert new.pgm.read_bytes() == reference.pgm.read_bytes()
    assert new.yaml.read_bytes() == reference.yaml.read_bytes()


def test_a_beam_over_a_car_roof_does_not_free_it_one_through_the_car_s_space_does():
    """A car's roof 1.45 m above flat ground, 10-12 m ahead of a sensor 1.8 m up, and a wall 30 m
    ahead: beams to the wall pass over the roof inside the band. With the roof's points noted first,
    the roof stays occupied; once the car has gone, beams through its space below the roof free it."""
    ground = _ground(lambda xy: np.zeros(len(xy)))
    params = GridParams()
    bounds = np.array([[-5.0, -5.0], [35.0, 5.0]])
    sensor = np.array([0.0, 0.0, 1.8])
    y = np.linspace(-0.5, 0.5, 21)
    roof = np.array([[x, yy, 1.45] for x in np.arange(10.05, 12.0, 0.1) for yy in y])
    wall = np.array([[30.0, yy * 3.0, 1.9] for yy in np.linspace(-0.5, 0.5, 61)])
    roof_cells = (np.floor((roof[:, 0] + 5.0) / 0.1).astype(int), np.floor((roof[:, 1] + 5.0) / 0.1).astype(int))
    for noted, occupied_share in ((False, 0.05), (True, 0.95)):
        builder = OccupancyGridBuilder(params, ground, bounds)
        if noted:
            builder.note_obstacles(np.vstack([roof, wall]))
        builder.add(sensor, roof)  # the roof's own returns, once
        for _ in range(10):
            builder.add(sensor, wall)  # beams over the roof, 1.83-1.84 m above the ground there
        share = (builder.grid().log_odds[roof_cells] > 0.62).mean()
        assert (share >= occupied_share) if noted else (share <= occupied_share), (noted, share)
    # The car gone: beams 1.22-1.32 m above the ground where it stood (below its roof), to a low wall.
    low_wall = wall.copy()
    low_wall[:, 2] = 0.35
    for _ in range(10):
        builder.add(sensor, low_wall)
    assert (builder.grid().log_odds[roof_cells] < 0).mean() > 0.5


def test_a_roof_in_a_dip_is_judged_by_the_beam_s_true_height_and_a_low_top_can_still_be_freed():
    """The ground dips 0.9 m around x = 10 m, a roof stands 1.45 m above the dip: a beam from the
    sensor (1.8 m up at x = 0) to the road at x = 19 m passes 0.3 m over the roof, though its height
    above the ground line drawn from sensor to road says 0.85 m. A cell whose only obstacle stood
    0.35 m up (under band low + margin, where no beam is cast) is freed by a beam in the band just
    over it (0.36 m)."""

    def dip(xy):
        return -0.9 * np.exp(-(((xy[:, 0] - 11.0) / 2.0) ** 2))

    ground = _ground(dip)
    bounds = np.array([[-5.0, -5.0], [35.0, 5.0]])
    y = np.linspace(-0.5, 0.5, 21)
    roof_xy = np.array([[x, yy] for x in np.arange(10.05, 12.0, 0.1) for yy in y])
    roof = np.column_stack([roof_xy, dip(roof_xy) + 1.45])
    road_xy = np.column_stack([np.full(61, 19.0), np.linspace(-0.9, 0.9, 61)])
    road = np.column_stack([road_xy, dip(road_xy)])
    sensor = np.array([0.0, 0.0, dip(np.zeros((1, 2)))[0] + 1.8])
    builder = OccupancyGridBuilder(GridParams(), ground, bounds)
    builder.note_obstacles(roof)
    builder.add(sensor, roof)
    for _ in range(10):
        builder.add(sensor, road)
    cells = builder.grid().cell_of(roof[:, :2])
    assert (builder.grid().log_odds[cells[0], cells[1]] > 0.62).mean() > 0.95
    # A low obstacle once (0.35 m up), then beams in the band through its cell.
    flat = _ground(lambda xy: np.zeros(len(xy)))
    builder = OccupancyGridBuilder(GridParams(), flat, bounds)
    low = np.array([[8.05, 0.05, 0.35]])
    builder.note_obstacles(low)
    builder.add(np.array([0.0, 0.0, 1.8]), low)
    beyond = np.column_stack([np.full(41, 8.4), np.linspace(-0.2, 0.2, 41), np.full(41, 0.3)])  # 0.36 m over it
    for _ in range(10):
        builder.add(np.array([0.0, 0.0, 1.8]), beyond)
    assert builder.grid().log_odds[130, 50] < 0


# ---------------------------------------------------------------- the local ground model


def test_the_ground_model_follows_a_slope_and_ignores_a_car_on_it():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-20.0, 20.0, (20000, 2))
    xy = xy[np.abs(xy[:, 1]) < 8.0]  # a road 16 m wide; beyond it nothing was seen (filled)

    def terrain(q):
        return 0.14 * q[:, 0] + 0.05 * q[:, 1]  # 8 degrees up the road, 3 across

    ground = np.column_stack([xy, terrain(xy) + rng.normal(0.0, 0.01, len(xy))])
    car_xy = np.column_stack([rng.uniform(4.0, 8.0, 300), rng.uniform(-1.0, 1.0, 300)])
    car = np.column_stack([car_xy, terrain(car_xy) + 0.4])  # the underside of a car, marked ground by mistake
    model = GroundModel.from_points(lowest_per_cell(np.concatenate([ground, car]), 1.0), 1.0)
    query = np.array([[0.3, 0.7], [6.0, 0.0], [-15.2, 4.4], [10.0, 12.0]])  # road, under the car, far, off the road
    np.testing.assert_allclose(model.height_at(query[:3]), terrain(query[:3]), atol=0.06)
    assert abs(model.height_at(query[3:])[0] - terrain(query[3:])[0]) < 0.3  # the slope continued past the edge
    # The old model (the lowest point of the 3x3 cells around) was 0.2 m low here: road 0.3 m up would be an obstacle.
    assert (model.height_at(query[:1]) > terrain(query[:1]) - 0.06).all()


def test_lowest_per_cell_keeps_one_point_per_cell():
    points = np.array([[0.2, 0.2, 1.0], [0.8, 0.1, 0.5], [1.5, 0.5, 2.0], [-0.5, 0.5, 3.0]])
    lowest = lowest_per_cell(points, 1.0)
    assert sorted(map(tuple, lowest)) == sorted([(0.8, 0.1, 0.5), (1.5, 0.5, 2.0), (-0.5, 0.5, 3.0)])
    assert lowest_per_cell(np.zeros((0, 3)), 1.0).shape == (0, 3)


def test_the_lowest_per_cell_gathered_cloud_by_cloud_is_that_of_all_clouds_at_once():
    rng = np.random.default_rng(5)
    clouds = []
    for _ in range(12):
        cloud = np.column_stack([rng.uniform(-30.0, 40.0, (3000, 2)), rng.integers(0, 4, 3000) * 0.5])
        cloud[:50, :2] = np.floor(cloud[:50, :2]) + 0.25  # equal heights in a cell: the first added stays
        cloud[50:60, :2] = np.floor(cloud[50:60, :2])  # on the cell's edge
        clouds.append(cloud)
    clouds.append(np.zeros((0, 3)))
    lowest = LowestPerCell(np.array([[-30.0, -30.0], [40.0, 40.0]]), 1.0)
    for cloud in clouds:
        lowest.add(cloud)
    every = np.concatenate(clouds)
    np.testing.assert_array_equal(lowest.points(), lowest_per_cell(every, 1.0))
    # as grid_run gathered it before: each cloud's lowest, then the lowest of those
    per_cloud = np.concatenate([lowest_per_cell(cloud, 1.0) for cloud in clouds])
    np.testing.assert_array_equal(lowest.points(), lowest_per_cell(per_cloud, 1.0))
    with pytest.raises(ValueError, match="1 of 2 points lie outside the bounds"):
        lowest.add(np.array([[0.0, 0.0, 0.0], [45.0, 0.0, 0.0]]))
