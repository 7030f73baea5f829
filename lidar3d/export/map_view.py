"""Adapter: a run's map and trajectory as an image, without a display (``lidar3d view --png``).

Two panels side by side in one PNG: a top view (x right, y up, metres on the axes) and an oblique
view (orthographic, from the south-west, looking down at :data:`OBLIQUE_ELEVATION_DEG`). Map points
are coloured by height (``turbo``, clipped to the 2nd-98th percentile, colour bar in metres) and
drawn with a z-buffer (in the top view the highest point of a pixel shows, in the oblique view the
nearest); the trajectory is drawn on top as a white-edged red line, its start and end marked.

The raster is computed with NumPy (one sort over the points), matplotlib lays out the panels on an
Agg canvas. Library twin of ``lidar3d view --png``: :func:`write_view_png`.
"""

from __future__ import annotations

import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar3d.errors import OutputError
from lidar3d.io.atomic import write_bytes_atomic

__all__ = [
    "OBLIQUE_AZIMUTH_DEG",
    "OBLIQUE_ELEVATION_DEG",
    "TRAJECTORY_RGB",
    "RunView",
    "read_run_view",
    "render_view_png",
    "write_view_png",
]

#: The oblique camera: direction it looks in, degrees counter-clockwise from +x (45: towards the
#: north-east, from the south-west), and its elevation above the horizon, degrees.
OBLIQUE_AZIMUTH_DEG = 45.0
OBLIQUE_ELEVATION_DEG = 35.0
#: Colour of the trajectory line (RGB 0-1); no height colour of ``turbo`` is this saturated red.
TRAJECTORY_RGB = (0.9, 0.0, 0.05)
_BACKGROUND = 1.0  # white
_PANEL_PX = 660  # the longer side of each raster


@dataclass(frozen=True, slots=True)
class RunView:
    """What ``lidar3d view`` shows of a run folder.

    Attributes:
        points_m: (N,3) float64 map points, world frame, metres.
        trajectory_m: (M,3) float64 positions of the trajectory, world frame, metres.
        source: the run folder, for titles and messages.
    """

    points_m: np.ndarray
    trajectory_m: np.ndarray
    source: str

    def __post_init__(self) -> None:
        if self.points_m.ndim != 2 or self.points_m.shape[1] != 3:
            raise ValueError(f"points_m must be (N,3), got {self.points_m.shape}")
        if self.trajectory_m.ndim != 2 or self.trajectory_m.shape[1] != 3:
            raise ValueError(f"trajectory_m must be (M,3), got {self.trajectory_m.shape}")


def read_run_view(run_dir: str | Path, *, max_points: int = 2_000_000) -> RunView:
    """``map.pcd`` and ``trajectory_tum.txt`` of a run folder; a map over ``max_points`` is thinned
    to every k-th point (k the smallest that fits), so drawing stays fast.

    Raises:
        OutputError: the folder, its map or its trajectory is missing, or the map is empty.
    """
    from lidar3d.io.pcd import read_pcd
    from lidar3d.io.trajectory_io import read_tum

    folder = Path(run_dir)
    if not folder.is_dir():
        raise OutputError(f"{folder}: no such run folder")
    map_path, trajectory_path = folder / "map.pcd", folder / "trajectory_tum.txt"
    for path in (map_path, trajectory_path):
        if not path.is_file():
            raise OutputError(f"{path}: not found; is {folder} the output folder of 'lidar3d run'?")
    points, _fields = read_pcd(map_path)
    if len(points) == 0:
        raise OutputError(f"{map_path}: the map holds no point")
    step = max(1, -(-len(points) // max_points))
    trajectory = read_tum(trajectory_path)
    return RunView(
        np.asarray(points[::step], dtype=np.float64), np.asarray(trajectory.positions_m, np.float64), str(folder)
    )


def _oblique_rotation() -> np.ndarray:
    """(3,3) rotation from world to camera (x right, y up on screen, z towards the viewer)."""
    # Turn the viewing direction onto +y (a turn by 90 deg - azimuth), then tilt the camera down.
    azimuth, elevation = np.radians(90.0 - OBLIQUE_AZIMUTH_DEG), np.radians(OBLIQUE_ELEVATION_DEG)
    c, s = np.cos(azimuth), np.sin(azimuth)
    yaw = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    ce, se = np.cos(elevation), np.sin(elevation)
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, se, ce], [0.0, -ce, se]])
    return tilt @ yaw


def _raster(
    screen_xy: np.ndarray, depth: np.ndarray, rgb: np.ndarray, bounds: tuple[float, float, float, float]
) -> np.ndarray:
    """(H,W,3) image of the points at ``screen_xy`` (metres on screen), nearest (largest ``depth``)
    point per pixel, each point splatted to 2x2 pixels; ``bounds`` = (x0, x1, y0, y1) of the image."""
    x0, x1, y0, y1 = bounds
    scale = _PANEL_PX / max(x1 - x0, y1 - y0)
    width, height = max(1, round((x1 - x0) * scale)), max(1, round((y1 - y0) * scale))
    image = np.full((height, width, 3), _BACKGROUND, dtype=np.float64)
    column = np.clip(((screen_xy[:, 0] - x0) * scale).astype(np.int64), 0, width - 1)
    row = np.clip(((y1 - screen_xy[:, 1]) * scale).astype(np.int64), 0, height - 1)
    order = np.argsort(depth, kind="stable")  # far first: nearer points are written later and win
    for d_row, d_col in ((0, 0), (0, 1), (1, 0), (1, 1)):
        r, c = np.clip(row + d_row, 0, height - 1), np.clip(column + d_col, 0, width - 1)
        flat = r[order] * width + c[order]
        # The last write per pixel is the nearest point: keep it explicitly (NumPy's fancy
        # assignment does not promise an order for repeated indices).
        last = np.unique(flat[::-1], return_index=True)[1]
        keep = len(flat) - 1 - last
        image.reshape(-1, 3)[flat[keep]] = rgb[order][keep]
    return image


def _bounds(xy: np.ndarray, margin: float = 0.04) -> tuple[float, float, float, float]:
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    pad = margin * max(float((hi - lo).max()), 1.0)
    return float(lo[0] - pad), float(hi[0] + pad), float(lo[1] - pad), float(hi[1] + pad)


def render_view_png(view: RunView, *, dpi: int = 100) -> bytes:
    """PNG bytes of the two panels (see the module docstring)."""
    from matplotlib import colormaps
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.figure import Figure

    points, trajectory = view.points_m, view.trajectory_m
    z = points[:, 2]
    low, high = (float(v) for v in np.percentile(z, [2.0, 98.0]))
    norm = Normalize(low, high if high > low else low + 1.0)
    colour_map = colormaps["turbo"]
    rgb = colour_map(norm(z))[:, :3]
    figure = Figure(figsize=(14.0, 6.4), layout="constrained")
    FigureCanvasAgg(figure)
    top, oblique = figure.subplots(1, 2)

    both = np.vstack([points[:, :2], trajectory[:, :2]]) if len(trajectory) else points[:, :2]
    bounds = _bounds(both)
    top.imshow(_raster(points[:, :2], z, rgb, bounds), extent=bounds, interpolation="nearest", origin="upper")
    _draw_trajectory(top, trajectory[:, :2])
    top.set_xlabel("x [m]")
    top.set_ylabel("y [m]")
    top.set_title(f"top view: {len(points)} map points, {len(trajectory)} poses", fontsize=10)

    rotation = _oblique_rotation()
    camera = points @ rotation.T
    path = trajectory @ rotation.T if len(trajectory) else np.zeros((0, 3))
    screen = np.vstack([camera[:, :2], path[:, :2]]) if len(path) else camera[:, :2]
    oblique_bounds = _bounds(screen)
    oblique.imshow(
        _raster(camera[:, :2], camera[:, 2], rgb, oblique_bounds),
        extent=oblique_bounds,
        interpolation="nearest",
        origin="upper",
    )
    _draw_trajectory(oblique, path[:, :2])
    oblique.set_xticks([])
    oblique.set_yticks([])
    oblique.set_title(
        f"oblique view from the south-west, {OBLIQUE_ELEVATION_DEG:.0f} deg above the horizon", fontsize=10
    )
    bar = figure.colorbar(ScalarMappable(norm, colour_map), ax=[top, oblique], shrink=0.8, aspect=30)
    bar.set_label("height z [m] (2nd-98th percentile)")
    figure.suptitle(f"lidar3d view {view.source}", fontsize=11)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()


def _draw_trajectory(ax, xy: np.ndarray) -> None:
    if not len(xy):
        return
    ax.plot(xy[:, 0], xy[:, 1], "-", color="white", lw=4.0, solid_capstyle="round")
    ax.plot(xy[:, 0], xy[:, 1], "-", color=TRAJECTORY_RGB, lw=2.0, solid_capstyle="round", label="trajectory")
    ax.plot(xy[0, 0], xy[0, 1], "o", ms=8, mfc="white", mec="black", mew=1.5, label="start")
    ax.plot(xy[-1, 0], xy[-1, 1], "s", ms=8, mfc="white", mec="black", mew=1.5, label="end")
    ax.legend(loc="lower right", fontsize=8, framealpha=0.85)


def write_view_png(run_dir: str | Path, png_path: str | Path, *, max_points: int = 2_000_000) -> Path:
    """Render the run folder's map and trajectory into ``png_path`` (atomically); returns the path.

    Raises:
        OutputError: see :func:`read_run_view`; the PNG cannot be written.
    """
    write_bytes_atomic(png_path, render_view_png(read_run_view(run_dir, max_points=max_points)))
    return Path(png_path)
