"""Adapter: a run's map and trajectory in an Open3D window (``lidar3d view`` with a display).

Open3D types stay inside this module. The map is coloured by height as in
:mod:`lidar3d.export.map_view` (``turbo``, 2nd-98th percentile); the trajectory is a red line set.
"""

from __future__ import annotations

import os
import sys
from typing import Any

import numpy as np

from lidar3d.export.map_view import TRAJECTORY_RGB, RunView

__all__ = ["display_available", "show_view_window"]


def display_available() -> bool:
    """Whether a window can be opened: always on macOS and Windows, on Linux and other X11/Wayland
    systems when ``DISPLAY`` or ``WAYLAND_DISPLAY`` is set."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def show_view_window(view: RunView) -> None:  # pragma: no cover - needs a display
    """Open an Open3D window with the map and the trajectory; returns when it is closed."""
    import open3d as o3d
    from matplotlib import colormaps

    z = view.points_m[:, 2]
    low, high = np.percentile(z, [2.0, 98.0])
    shade = np.clip((z - low) / max(float(high - low), 1e-6), 0.0, 1.0)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(view.points_m))
    cloud.colors = o3d.utility.Vector3dVector(colormaps["turbo"](shade)[:, :3])
    geometries: list[Any] = [cloud]
    if len(view.trajectory_m) > 1:
        lines = o3d.geometry.LineSet(
            o3d.utility.Vector3dVector(view.trajectory_m),
            o3d.utility.Vector2iVector(
                np.column_stack([np.arange(len(view.trajectory_m) - 1), np.arange(1, len(view.trajectory_m))])
            ),
        )
        lines.paint_uniform_color(TRAJECTORY_RGB)
        geometries.append(lines)
    o3d.visualization.draw_geometries(geometries, window_name=f"lidar3d view {view.source}", width=1400, height=900)
