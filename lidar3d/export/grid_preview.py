"""PNG preview of an occupancy grid: the map_server image in metres, with the driven path.

Matplotlib is imported only when a preview is drawn.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lidar3d.io.atomic import write_bytes_atomic

__all__ = ["grid_preview_png", "write_grid_preview"]


def grid_preview_png(
    image: np.ndarray, resolution_m: float, origin_xy_m: np.ndarray, path_xy_m: np.ndarray, *, title: str
) -> bytes:
    """PNG bytes of the map_server ``image`` (rows, cols; row 0 = highest y) placed in world metres,
    with the (N,2) driven path in colour."""
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    rows, cols = image.shape
    x0, y0 = float(origin_xy_m[0]), float(origin_xy_m[1])
    extent = (x0, x0 + cols * resolution_m, y0, y0 + rows * resolution_m)
    aspect = rows / max(cols, 1)
    figure = Figure(figsize=(9.0, float(np.clip(9.0 * aspect, 3.0, 14.0))), dpi=110)
    FigureCanvasAgg(figure)
    ax = figure.add_subplot(1, 1, 1)
    ax.imshow(image, cmap="gray", vmin=0, vmax=255, extent=extent, interpolation="nearest", origin="upper")
    if len(path_xy_m):
        ax.plot(path_xy_m[:, 0], path_xy_m[:, 1], color="tab:orange", lw=1.0, label="driven path")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title, fontsize=10)
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png")
    return buffer.getvalue()


def write_grid_preview(path: str | Path, *args, **kwargs) -> Path:
    """Write :func:`grid_preview_png` to ``path`` atomically; returns the path."""
    write_bytes_atomic(path, grid_preview_png(*args, **kwargs))
    return Path(path)
